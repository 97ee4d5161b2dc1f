//! Fitting a [`Calibration`] to real frames of a known object at known poses.
//!
//! Each frame comes with the pose the rig logged and the object's mesh. For a candidate
//! calibration we render the object's contact footprint (pixels where the depth map is
//! positive) and score how well it lines up with a feature map of the real frame:
//!
//! - [`FitTarget::Edges`]: the gradient magnitude of the frame, against the footprint's
//!   outline. For see-through skins (ViTac, ViTacTip) the pressed object's outline is the
//!   sharpest structure that moves with the pose; glare and the fixed background do not.
//! - [`FitTarget::Difference`]: `|frame - reference|` (a no-contact estimate), blurred, against
//!   the filled footprint. For marker-only skins (TacTip) the object is invisible and only the
//!   marker displacement around the contact shows.
//!
//! The score is the Pearson correlation between the rendered indicator and the feature map,
//! averaged over the frames; it rewards overlap and penalises both a footprint that is too
//! small (few pixels) and one that is too large (dilutes the mean). The search: a coarse grid
//! over scale, rotation, mirroring and the pose correction at half the working size (plus any
//! [`ContactFitOptions::extra_starts`]), a pattern search (coordinate steps halving on
//! failure) from the best starts there, again at the working size from the best of those, and
//! optionally once more at [`ContactFitOptions::final_size`]. Parameters: centre, scale (same magnitude on both axes, optionally mirrored),
//! rotation and a pose correction (gain and angle, see
//! [`Calibration::pose_xy_correction`]).
//!
//! The residual reported per frame is the mean distance, in pixels of the full-size image, from
//! the rendered outline to the nearest strong feature pixel (top 5 % of the feature map),
//! capped at [`RESIDUAL_CAP_PX`].
//!
//! [`fit_sensor`] fits one sensor of a rig with the target its skin calls for
//! ([`target_for`]), seeded with the fits of the rig's other sensors ([`FIT_ORDER`]).

use image::{GrayImage, RgbImage, imageops};

use super::{Calibration, FitRecord};
use crate::geometry::raster::render_depth;
use crate::geometry::stl::Mesh;
use crate::imaging::{self, BoxBorder, median_image, summed_channel_difference};
use crate::pose::Pose;
use crate::sensor::SensorKind;

/// Largest residual counted per outline pixel, px (full-size image).
pub const RESIDUAL_CAP_PX: f64 = 40.0;

/// One real frame with the pose it was taken at (render convention of
/// [`crate::geometry::raster`]: `z_mm` is the indentation).
#[derive(Debug, Clone)]
pub struct FitFrame {
    pub name: String,
    pub pose: Pose,
    pub image: RgbImage,
}

/// What in the real frames the rendered footprint should line up with.
#[derive(Debug, Clone)]
pub enum FitTarget {
    /// Image gradient against the footprint outline.
    Edges,
    /// Difference from a no-contact reference image against the filled footprint.
    Difference { reference: RgbImage },
}

/// Search settings.
#[derive(Debug, Clone)]
pub struct ContactFitOptions {
    /// Working image width and height, px (frames are resized to it).
    pub work_size: u32,
    /// Scales to start from, px/mm at full size.
    pub start_scales_px_per_mm: Vec<f64>,
    /// Fit the pose correction (gain and angle); otherwise keep `fixed_pose_correction`.
    pub fit_pose_correction: bool,
    /// The pose correction used when it is not fitted (`None`: the rigid model, identity).
    /// Must be a rotation times a gain.
    pub fixed_pose_correction: Option<[[f64; 2]; 2]>,
    /// Starts refined by the pattern search.
    pub refine_best: usize,
    /// Pattern-search evaluations per start.
    pub max_evaluations: usize,
    /// Extra starting points, e.g. the fit of another sensor on the same rig (any size).
    pub extra_starts: Vec<Calibration>,
    /// If larger than `work_size`: a last pattern search at this size (e.g. the frames' own).
    pub final_size: Option<u32>,
}

impl Default for ContactFitOptions {
    fn default() -> Self {
        Self {
            work_size: 256,
            start_scales_px_per_mm: vec![9.0, 13.0, 18.0],
            fit_pose_correction: true,
            fixed_pose_correction: None,
            refine_best: 6,
            max_evaluations: 400,
            extra_starts: Vec::new(),
            final_size: None,
        }
    }
}

/// Why a fit cannot run.
#[derive(Debug, thiserror::Error)]
pub enum ContactFitError {
    #[error("no frames to fit")]
    NoFrames,
    #[error("frame {name} is {width}x{height}, the others {expected_width}x{expected_height}")]
    FrameSize { name: String, width: u32, height: u32, expected_width: u32, expected_height: u32 },
    #[error("reference image is {width}x{height}, the frames {expected_width}x{expected_height}")]
    ReferenceSize { width: u32, height: u32, expected_width: u32, expected_height: u32 },
}

/// A fitted calibration with its quality.
#[derive(Debug, Clone)]
pub struct ContactFit {
    /// Full-size calibration with its [`FitRecord`] filled in.
    pub calibration: Calibration,
    /// Mean correlation over the frames (1 = perfect overlap).
    pub score: f64,
    /// Per frame: mean outline-to-feature distance, px at full size.
    pub residuals_px: Vec<f64>,
}

/// Search parameters: centre (px at work size), scale magnitude (px/mm at work size),
/// rotation (deg), correction gain and angle (deg); mirror is fixed per start.
#[derive(Debug, Clone, Copy)]
struct Params {
    v: [f64; 6],
    mirror: bool,
}

impl Params {
    /// Parameters of an existing calibration (at the size it is scaled to).
    fn from_calibration(c: &Calibration) -> Params {
        let [mut sx, mut sy] = c.scale_px_per_mm;
        let mut rot = c.rotation_deg;
        // [-s, +-s] is [s, -+s] turned by 180 degrees.
        if sx < 0.0 {
            sx = -sx;
            sy = -sy;
            rot += 180.0;
        }
        let (gain, ang) = correction_gain_angle(c.pose_xy_correction.unwrap_or([[1.0, 0.0], [0.0, 1.0]]));
        Params { v: [c.centre_px[0], c.centre_px[1], sx, rot, gain, ang], mirror: sy < 0.0 }
    }

    /// The same parameters for an image `k` times larger.
    fn rescaled(&self, k: f64) -> Params {
        let mut q = *self;
        q.v[0] *= k;
        q.v[1] *= k;
        q.v[2] *= k;
        q
    }

    fn calibration(&self, size: u32) -> Calibration {
        let [cx, cy, s, rot, gain, ang] = self.v;
        let (sn, cs) = ang.to_radians().sin_cos();
        Calibration {
            centre_px: [cx, cy],
            scale_px_per_mm: [s, if self.mirror { -s } else { s }],
            rotation_deg: crate::pose::wrap_deg(rot),
            image_size: [size, size],
            depth_scale_per_mm: 0.0,
            fit: None,
            pose_xy_correction: Some([[gain * cs, -gain * sn], [gain * sn, gain * cs]]),
        }
    }
}

/// Gain and angle (deg) of a correction matrix `gain * R(angle)` (from its first column).
pub fn correction_gain_angle(m: [[f64; 2]; 2]) -> (f64, f64) {
    let [[a, _], [c, _]] = m;
    ((a * a + c * c).sqrt(), c.atan2(a).to_degrees())
}

/// Feature maps of the frames at work size, each normalised to zero mean and unit variance.
struct Features {
    size: u32,
    maps: Vec<Vec<f32>>,
    /// Top-5 % pixels per frame (for residuals).
    strong: Vec<Vec<bool>>,
    outline: bool,
}

/// The order the sensors of one rig are fitted in: the sharpest outlines first, so their
/// result seeds the others ([`fit_sensor`]).
pub const FIT_ORDER: [SensorKind; 3] = [SensorKind::ViTacTip, SensorKind::ViTac, SensorKind::TacTip];

/// What a sensor's frames are fitted against: the outlines for the see-through skins, the
/// difference from the frames' per-pixel median for TacTip (whose object is hidden).
pub fn target_for(sensor: SensorKind, frames: &[&RgbImage]) -> FitTarget {
    match sensor {
        SensorKind::TacTip => FitTarget::Difference { reference: median_image(frames) },
        SensorKind::ViTac | SensorKind::ViTacTip => FitTarget::Edges,
    }
}

/// Fits a calibration to one sensor's `frames` (render poses, all one size; the result is at
/// that size), also starting from `seeds`: the fits of the same rig's other sensors. With
/// seeds, TacTip keeps their mean pose correction: markers alone barely constrain it, and it
/// belongs to the pose log (shared by all sensors), not to the camera.
pub fn fit_sensor(mesh: &Mesh, sensor: SensorKind, frames: &[FitFrame], seeds: &[Calibration]) -> Result<ContactFit, ContactFitError> {
    let first = frames.first().ok_or(ContactFitError::NoFrames)?;
    let images: Vec<&RgbImage> = frames.iter().map(|f| &f.image).collect();
    let target = target_for(sensor, &images);
    let mut opts =
        ContactFitOptions { extra_starts: seeds.to_vec(), final_size: Some(first.image.width()), ..ContactFitOptions::default() };
    if sensor == SensorKind::TacTip && !seeds.is_empty() {
        opts.fit_pose_correction = false;
        opts.fixed_pose_correction = Some(mean_correction(seeds));
    }
    fit_contact(mesh, frames, &target, &opts)
}

/// Element-wise mean of the seeds' pose corrections (identity where a seed has none).
fn mean_correction(seeds: &[Calibration]) -> [[f64; 2]; 2] {
    let mut m = [[0.0; 2]; 2];
    for c in seeds {
        let s = c.pose_xy_correction.unwrap_or([[1.0, 0.0], [0.0, 1.0]]);
        for r in 0..2 {
            for k in 0..2 {
                m[r][k] += s[r][k] / seeds.len() as f64;
            }
        }
    }
    m
}

/// Fits a calibration for `frames` of `mesh` (all the same size; the result is for that size).
pub fn fit_contact(mesh: &Mesh, frames: &[FitFrame], target: &FitTarget, opts: &ContactFitOptions) -> Result<ContactFit, ContactFitError> {
    let first = frames.first().ok_or(ContactFitError::NoFrames)?;
    let (fw, fh) = first.image.dimensions();
    for f in frames {
        if f.image.dimensions() != (fw, fh) {
            return Err(ContactFitError::FrameSize {
                name: f.name.clone(),
                width: f.image.width(),
                height: f.image.height(),
                expected_width: fw,
                expected_height: fh,
            });
        }
    }
    if let FitTarget::Difference { reference } = target
        && reference.dimensions() != (fw, fh)
    {
        return Err(ContactFitError::ReferenceSize {
            width: reference.width(),
            height: reference.height(),
            expected_width: fw,
            expected_height: fh,
        });
    }
    let size = opts.work_size.max(64);
    let coarse_size = size / 2;
    let coarse = build_features(frames, target, coarse_size);
    let features = build_features(frames, target, size);
    let k = coarse_size as f64 / fw as f64;

    // Coarse grid at half the working size, where the blurred features give wide basins.
    let mut starts = Vec::new();
    let fixed = correction_gain_angle(opts.fixed_pose_correction.unwrap_or([[1.0, 0.0], [0.0, 1.0]]));
    let corr_angles: Vec<f64> = if opts.fit_pose_correction { (-6..=6).map(|i| i as f64 * 10.0).collect() } else { vec![fixed.1] };
    let gains: Vec<f64> = if opts.fit_pose_correction { vec![0.3, 0.45, 0.6, 0.8, 1.0] } else { vec![fixed.0] };
    for &s in &opts.start_scales_px_per_mm {
        for rot in (0..12).map(|i| i as f64 * 30.0) {
            for mirror in [false, true] {
                for &gain in &gains {
                    for &ang in &corr_angles {
                        let p = Params { v: [coarse_size as f64 / 2.0, coarse_size as f64 / 2.0, s * k, rot, gain, ang], mirror };
                        starts.push((score(mesh, frames, &coarse, &p), p));
                    }
                }
            }
        }
    }
    for c in &opts.extra_starts {
        let mut p = Params::from_calibration(&c.scaled_to(coarse_size, coarse_size));
        if !opts.fit_pose_correction {
            (p.v[4], p.v[5]) = fixed;
        }
        starts.push((score(mesh, frames, &coarse, &p), p));
    }
    starts.sort_by(|a, b| b.0.total_cmp(&a.0));
    // Refine the best starts coarse, then the best of those at the working size.
    let mut refined: Vec<(f64, Params)> =
        starts.iter().take(opts.refine_best.max(1) * 2).map(|&(sc, p)| pattern_search(mesh, frames, &coarse, p, sc, opts)).collect();
    refined.sort_by(|a, b| b.0.total_cmp(&a.0));
    let mut best: Option<(f64, Params)> = None;
    for &(_, p) in refined.iter().take(opts.refine_best.max(1)) {
        let p = p.rescaled(size as f64 / coarse_size as f64);
        let fine = pattern_search(mesh, frames, &features, p, score(mesh, frames, &features, &p), opts);
        if best.is_none_or(|b| fine.0 > b.0) {
            best = Some(fine);
        }
    }
    let Some(mut best) = best else { return Err(ContactFitError::NoFrames) };
    let mut size = size;
    let mut features = features;
    if let Some(final_size) = opts.final_size.filter(|&f| f > size) {
        let fine = build_features(frames, target, final_size);
        let p = best.1.rescaled(final_size as f64 / size as f64);
        let start = score(mesh, frames, &fine, &p);
        let few = ContactFitOptions { max_evaluations: opts.max_evaluations / 2, ..opts.clone() };
        best = pattern_search(mesh, frames, &fine, p, start, &few);
        (size, features) = (final_size, fine);
    }
    let (best_score, best_params) = best;
    let mut calib = best_params.calibration(size).scaled_to(fw, fh);
    if !opts.fit_pose_correction {
        calib.pose_xy_correction = opts.fixed_pose_correction;
    }
    let residuals_px = residuals(mesh, frames, &features, &best_params, fw as f64 / size as f64);
    let rms = (residuals_px.iter().map(|r| r * r).sum::<f64>() / residuals_px.len() as f64).sqrt();
    calib.fit = Some(FitRecord {
        method: format!(
            "contact-overlap ({}): pattern search maximising the correlation of the rendered footprint with the real frames",
            if features.outline { "edges" } else { "difference" }
        ),
        frames: frames.iter().map(|f| f.name.clone()).collect(),
        points: Vec::new(),
        residuals_px: residuals_px.clone(),
        rms_px: Some(rms),
        iou: Vec::new(),
        notes: format!(
            "mean correlation {best_score:.3}; pose correction gain {:.3}, angle {:.1} deg ({}); residual = mean outline-to-feature distance, capped at {RESIDUAL_CAP_PX} px",
            best_params.v[4],
            best_params.v[5],
            if opts.fit_pose_correction { "fitted" } else { "fixed" },
        ),
    });
    Ok(ContactFit { calibration: calib, score: best_score, residuals_px })
}

fn pattern_search(
    mesh: &Mesh,
    frames: &[FitFrame],
    f: &Features,
    start: Params,
    start_score: f64,
    opts: &ContactFitOptions,
) -> (f64, Params) {
    let mut p = start;
    let mut best = start_score;
    let mut step = [4.0, 4.0, 0.08 * start.v[2], 4.0, 0.05, 5.0];
    let free: Vec<usize> = if opts.fit_pose_correction { (0..6).collect() } else { (0..4).collect() };
    let mut evals = 0;
    while evals < opts.max_evaluations {
        let mut improved = false;
        for &i in &free {
            for sign in [1.0, -1.0] {
                let mut q = p;
                q.v[i] += sign * step[i];
                if q.v[2] <= 0.5 || q.v[4] <= 0.05 {
                    continue;
                }
                let s = score(mesh, frames, f, &q);
                evals += 1;
                if s > best {
                    best = s;
                    p = q;
                    improved = true;
                }
            }
        }
        if !improved {
            for s in &mut step {
                *s *= 0.5;
            }
            if step[0] < 0.1 {
                break;
            }
        }
    }
    (best, p)
}

fn build_features(frames: &[FitFrame], target: &FitTarget, size: u32) -> Features {
    let grey_small = |img: &RgbImage| -> Vec<f32> {
        let small = imageops::resize(img, size, size, imageops::FilterType::Triangle);
        small.pixels().map(|p| (p.0[0] as f32 + p.0[1] as f32 + p.0[2] as f32) / 3.0).collect()
    };
    let n = size as usize;
    let (maps, outline): (Vec<Vec<f32>>, bool) = match target {
        FitTarget::Edges => (frames.iter().map(|f| box_blur(&sobel(&box_blur(&grey_small(&f.image), n, 1), n), n, 2)).collect(), true),
        FitTarget::Difference { reference } => {
            let small_ref = imageops::resize(reference, size, size, imageops::FilterType::Triangle);
            let maps = frames
                .iter()
                .map(|f| {
                    let small = imageops::resize(&f.image, size, size, imageops::FilterType::Triangle);
                    // Sums of three 8-bit differences: exact in f32.
                    let d: Vec<f32> = summed_channel_difference(&small, &small_ref).into_iter().map(|v| v as f32).collect();
                    box_blur(&d, n, 3)
                })
                .collect();
            (maps, false)
        }
    };
    let strong = maps
        .iter()
        .map(|m| {
            let mut sorted = m.clone();
            sorted.sort_by(f32::total_cmp);
            let thr = sorted[(sorted.len() * 95) / 100];
            m.iter().map(|&v| v >= thr && v > 0.0).collect()
        })
        .collect();
    let maps = maps.into_iter().map(standardise).collect();
    Features { size, maps, strong, outline }
}

fn standardise(m: Vec<f32>) -> Vec<f32> {
    let n = m.len().max(1) as f64;
    let mean = m.iter().map(|&v| v as f64).sum::<f64>() / n;
    let var = m.iter().map(|&v| (v as f64 - mean).powi(2)).sum::<f64>() / n;
    let sd = var.sqrt().max(1e-9);
    m.into_iter().map(|v| ((v as f64 - mean) / sd) as f32).collect()
}

/// The shrinking-window box blur ([`BoxBorder::Shrink`]) of an `n` x `n` map, as a new map.
fn box_blur(src: &[f32], n: usize, r: usize) -> Vec<f32> {
    let mut out = src.to_vec();
    imaging::box_blur(&mut out, n, n, r, BoxBorder::Shrink);
    out
}

fn sobel(g: &[f32], n: usize) -> Vec<f32> {
    let mut out = vec![0.0; g.len()];
    for y in 1..n.saturating_sub(1) {
        for x in 1..n - 1 {
            let p = |dx: isize, dy: isize| g[(y as isize + dy) as usize * n + (x as isize + dx) as usize];
            let gx = p(1, -1) + 2.0 * p(1, 0) + p(1, 1) - p(-1, -1) - 2.0 * p(-1, 0) - p(-1, 1);
            let gy = p(-1, 1) + 2.0 * p(0, 1) + p(1, 1) - p(-1, -1) - 2.0 * p(0, -1) - p(1, -1);
            out[y * n + x] = (gx * gx + gy * gy).sqrt();
        }
    }
    out
}

/// Contact footprint (height > 0) of one frame at work size.
fn footprint(mesh: &Mesh, pose: &Pose, calib: &Calibration, size: u32) -> Vec<bool> {
    render_depth(mesh, pose, calib, size, size, 1).height_mm.iter().map(|&h| h > 0.0).collect()
}

/// Outline of a footprint, thickened by one pixel on each side.
fn outline_of(mask: &[bool], n: usize) -> Vec<bool> {
    let mut edge = vec![false; mask.len()];
    for y in 0..n {
        for x in 0..n {
            if !mask[y * n + x] {
                continue;
            }
            let outside =
                |xx: isize, yy: isize| xx >= 0 && yy >= 0 && (xx as usize) < n && (yy as usize) < n && !mask[yy as usize * n + xx as usize];
            let (xi, yi) = (x as isize, y as isize);
            if outside(xi - 1, yi) || outside(xi + 1, yi) || outside(xi, yi - 1) || outside(xi, yi + 1) {
                for dy in -1isize..=1 {
                    for dx in -1isize..=1 {
                        let (xx, yy) = (xi + dx, yi + dy);
                        if xx >= 0 && yy >= 0 && (xx as usize) < n && (yy as usize) < n {
                            edge[yy as usize * n + xx as usize] = true;
                        }
                    }
                }
            }
        }
    }
    edge
}

fn indicator(mesh: &Mesh, frame: &FitFrame, f: &Features, calib: &Calibration) -> Vec<bool> {
    let mask = footprint(mesh, &frame.pose, calib, f.size);
    if f.outline { outline_of(&mask, f.size as usize) } else { mask }
}

/// Mean over frames of the correlation between indicator and standardised feature map.
fn score(mesh: &Mesh, frames: &[FitFrame], f: &Features, p: &Params) -> f64 {
    let calib = p.calibration(f.size);
    let mut total = 0.0;
    for (frame, map) in frames.iter().zip(&f.maps) {
        let ind = indicator(mesh, frame, f, &calib);
        let (mut sum_in, mut count) = (0.0f64, 0usize);
        for (i, &on) in ind.iter().enumerate() {
            if on {
                sum_in += map[i] as f64;
                count += 1;
            }
        }
        let n = ind.len() as f64;
        if count == 0 || count as f64 >= n {
            continue;
        }
        // Map has mean 0, sd 1: corr = mean_in * sqrt(p / (1 - p)).
        let frac = count as f64 / n;
        total += (sum_in / count as f64) * (frac / (1.0 - frac)).sqrt();
    }
    total / frames.len() as f64
}

fn residuals(mesh: &Mesh, frames: &[FitFrame], f: &Features, p: &Params, to_full: f64) -> Vec<f64> {
    let calib = p.calibration(f.size);
    let n = f.size as usize;
    let cap = (RESIDUAL_CAP_PX / to_full).ceil() as isize;
    frames
        .iter()
        .zip(&f.strong)
        .map(|(frame, strong)| {
            let mask = footprint(mesh, &frame.pose, &calib, f.size);
            let ind = if f.outline { outline_of(&mask, n) } else { mask };
            let (mut sum, mut count) = (0.0, 0usize);
            for y in 0..n as isize {
                for x in 0..n as isize {
                    if !ind[y as usize * n + x as usize] {
                        continue;
                    }
                    let mut d2 = f64::INFINITY;
                    for dy in -cap..=cap {
                        for dx in -cap..=cap {
                            let (xx, yy) = (x + dx, y + dy);
                            if xx >= 0 && yy >= 0 && (xx as usize) < n && (yy as usize) < n && strong[yy as usize * n + xx as usize] {
                                d2 = d2.min((dx * dx + dy * dy) as f64);
                            }
                        }
                    }
                    sum += (d2.sqrt() * to_full).min(RESIDUAL_CAP_PX);
                    count += 1;
                }
            }
            if count == 0 { RESIDUAL_CAP_PX } else { sum / count as f64 }
        })
        .collect()
}

/// Grey image of a standardised map, for looking at what the fit saw (debug output).
pub fn feature_preview(frames: &[FitFrame], target: &FitTarget, size: u32) -> Vec<GrayImage> {
    let f = build_features(frames, target, size);
    f.maps
        .iter()
        .map(|m| GrayImage::from_fn(size, size, |x, y| image::Luma([(m[(y * size + x) as usize] * 40.0 + 64.0).clamp(0.0, 255.0) as u8])))
        .collect()
}
