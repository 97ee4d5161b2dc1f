//! Compare-real: rendered frames against real frames of logged poses, beside the pose-blind
//! baseline. `rig compare-real` runs it on the MultiDiffSense example with the sensor
//! simulator as the renderer.
//!
//! - [`RealSample`]: one object of a MultiDiffSense-layout folder ([`RealSample::object_ids`]
//!   lists them; any number of objects and of frames): the real frames per sensor, their poses
//!   from the MDS pose log (read by
//!   [`crate::dataset::export`], whose docs fix the depth convention: indentation =
//!   [`MDS_CONTACT_DEPTH_MM`] minus the logged z) and the object's mesh.
//! - [`compare_sensor`] renders each frame's pose through a calibration with a [`Renderer`]
//!   (the caller's: compare-real itself knows no simulator) and scores it with SSIM against the
//!   real frame, over the whole frame and over the contact region, next to the pose-blind
//!   baseline (the mean of the sensor's other real frames).
//! - No-contact look: per pixel, the median of the sensor's real frames whose rendered
//!   footprint (dilated by [`FOOTPRINT_MARGIN_PX`]) does not cover that pixel (all frames where
//!   every frame covers it); the sample has no real no-contact frame.
//! - Contact region of a frame: pixels whose summed absolute RGB difference from the
//!   no-contact look exceeds [`CONTACT_THRESHOLD`]. Footprint IoU: its overlap with the rendered
//!   footprint, a check of the calibration independent of the renderer.
//! - The renderer may start from a measured no-contact look: the per-pixel median of the
//!   sensor's *other* real frames ([`simulator_reference`], leave one out).
//! - [`PreparedSensor`] holds what does not depend on the renderer (depth maps, contact
//!   regions, baselines, references), so a fit can score many candidate renderers:
//!   [`fit_parameters`] searches a parameter vector for the best mean contact-region SSIM over
//!   some frames, and [`cross_validate`] fits on all frames but one and scores the one left out.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use image::{Rgb, RgbImage, imageops};

use crate::calibration::model::Calibration;
use crate::dataset::DatasetError;
use crate::dataset::export::{MDS_CONTACT_DEPTH_MM, MdsRow, import_mds};
use crate::geometry::DepthMap;
use crate::geometry::raster::render_depth;
use crate::geometry::stl::{Mesh, StlError};
use crate::imaging::{difference_mask, dilate_mask, iou, mean_image, median_image, median_image_excluding};
use crate::metrics::{MetricsError, ssim, ssim_masked};
use crate::pose::Pose;
use crate::sensor::SensorKind;

/// Margin around a rendered footprint that counts as "touched" for the no-contact estimate, px.
pub const FOOTPRINT_MARGIN_PX: u32 = 16;
/// Summed |RGB| difference from the no-contact look that makes a pixel part of the contact region.
pub const CONTACT_THRESHOLD: u32 = 60;
/// Most frames read per object and sensor (the per-pixel statistics hold them all in memory).
pub const MAX_FRAMES_PER_SENSOR: usize = 1000;
/// Frames smaller than this on a side are refused.
const MIN_SIDE_PX: u32 = 16;

/// Why a comparison cannot run.
#[derive(Debug, thiserror::Error)]
pub enum CompareRealError {
    #[error(transparent)]
    Mesh(#[from] StlError),
    #[error(transparent)]
    PoseLog(#[from] DatasetError),
    #[error("{path}: image_name {name:?} is not frame_<i>_0.png")]
    FrameName { path: PathBuf, name: String },
    #[error("reading {path}: {source}")]
    Image {
        path: PathBuf,
        #[source]
        source: image::ImageError,
    },
    #[error("{path}: {width}x{height} differs from the sensor's other frames ({expected_width}x{expected_height})")]
    FrameSize { path: PathBuf, width: u32, height: u32, expected_width: u32, expected_height: u32 },
    #[error("{path}: {width}x{height} is too small to compare")]
    TooSmall { path: PathBuf, width: u32, height: u32 },
    #[error("no pose row for frame {index} (its image is there, the pose log has no frame_{index}_0.png)")]
    NoPose { index: usize },
    #[error("{dir}: no object found (a MultiDiffSense-layout folder has csv/<id>.csv and stl/<id>.stl for each object)")]
    NoObjects { dir: PathBuf },
    #[error("{dir}: more than {max} frames; compare fewer at a time")]
    TooManyFrames { dir: PathBuf, max: usize },
    #[error("listing {path}: {source}")]
    ReadDir {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{sensor}: need at least two real frames, have {frames}")]
    TooFewFrames { sensor: &'static str, frames: usize },
    #[error(transparent)]
    Metrics(#[from] MetricsError),
    #[error("creating {path}: {source}")]
    CreateDir {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("writing {path}: {source}")]
    Write {
        path: PathBuf,
        #[source]
        source: image::ImageError,
    },
}

/// One object of a real sample: the object, the pose log and the frames (MultiDiffSense's
/// layout: `stl/<id>.stl`, `csv/<id>.csv`, `tactile/<id>/<Sensor>/target/<id>_<Sensor>_<i>.png`
/// for any frame indices `i`).
pub struct RealSample {
    /// The object id (`1`): the stem of its CSV and STL files.
    pub object: String,
    pub mesh: Mesh,
    /// The pose log's rows by image index.
    pub rows: BTreeMap<usize, MdsRow>,
    /// Frames per sensor, (image index, image), in index order; all of one size per sensor.
    pub frames: BTreeMap<SensorKind, Vec<(usize, RgbImage)>>,
}

impl RealSample {
    /// The object ids of a MultiDiffSense-layout folder: the stems of `csv/<id>.csv` that have
    /// an `stl/<id>.stl`, in order (numerically when both are numbers).
    pub fn object_ids(dir: &Path) -> Result<Vec<String>, CompareRealError> {
        let csv_dir = dir.join("csv");
        let mut ids: Vec<String> = list_dir(&csv_dir)?
            .into_iter()
            .filter_map(|name| name.strip_suffix(".csv").map(str::to_string))
            .filter(|id| !id.is_empty() && !id.starts_with('.') && dir.join("stl").join(format!("{id}.stl")).is_file())
            .collect();
        ids.sort_by(|a, b| match (a.parse::<u64>(), b.parse::<u64>()) {
            (Ok(x), Ok(y)) => x.cmp(&y),
            _ => a.cmp(b),
        });
        Ok(ids)
    }

    /// Loads the first object of the folder ([`Self::object_ids`]).
    pub fn load(dir: &Path) -> Result<Self, CompareRealError> {
        let ids = Self::object_ids(dir)?;
        let id = ids.first().ok_or_else(|| CompareRealError::NoObjects { dir: dir.to_path_buf() })?;
        Self::load_object(dir, id)
    }

    /// Loads object `id` of the folder: every frame `tactile/<id>/<Sensor>/target/<id>_<Sensor>_<i>.png`
    /// there is, for each sensor (a sensor without a folder has no frames).
    pub fn load_object(dir: &Path, id: &str) -> Result<Self, CompareRealError> {
        let mesh = Mesh::load(dir.join(format!("stl/{id}.stl")))?;
        let csv = dir.join(format!("csv/{id}.csv"));
        let mut rows = BTreeMap::new();
        for row in import_mds(&csv)? {
            let index = row.frame_index().ok_or_else(|| CompareRealError::FrameName { path: csv.clone(), name: row.image_name.clone() })?;
            rows.insert(index as usize, row);
        }
        let mut frames = BTreeMap::new();
        for sensor in SensorKind::ALL {
            let name = sensor.label();
            let target = dir.join(format!("tactile/{id}/{name}/target"));
            let prefix = format!("{id}_{name}_");
            let mut indices: Vec<usize> = if target.is_dir() {
                list_dir(&target)?.iter().filter_map(|f| f.strip_prefix(&prefix)?.strip_suffix(".png")?.parse::<usize>().ok()).collect()
            } else {
                Vec::new()
            };
            indices.sort_unstable();
            indices.dedup();
            if indices.len() > MAX_FRAMES_PER_SENSOR {
                return Err(CompareRealError::TooManyFrames { dir: target, max: MAX_FRAMES_PER_SENSOR });
            }
            let mut list: Vec<(usize, RgbImage)> = Vec::new();
            for i in indices {
                let path = target.join(format!("{prefix}{i}.png"));
                // Below the sample folder with no symlink, bounded, pixel count checked first.
                let rel = format!("tactile/{id}/{name}/target/{prefix}{i}.png");
                let bytes = crate::dataset::durable::read_below(dir, Path::new(&rel), crate::dataset::durable::MAX_IMAGE_BYTES)?;
                let img = crate::dataset::durable::decode_image(&bytes)
                    .map_err(|reason| crate::dataset::DatasetError::BadImage { path: path.clone(), reason })?
                    .to_rgb8();
                // The per-pixel statistics need one size per sensor.
                if let Some((_, first)) = list.first()
                    && first.dimensions() != img.dimensions()
                {
                    return Err(CompareRealError::FrameSize {
                        path,
                        width: img.width(),
                        height: img.height(),
                        expected_width: first.width(),
                        expected_height: first.height(),
                    });
                }
                if img.width() < MIN_SIDE_PX || img.height() < MIN_SIDE_PX {
                    return Err(CompareRealError::TooSmall { path, width: img.width(), height: img.height() });
                }
                list.push((i, img));
            }
            frames.insert(sensor, list);
        }
        Ok(Self { object: id.to_string(), mesh, rows, frames })
    }

    /// Keeps only the frames whose image index `keep` accepts (every sensor).
    pub fn retain_frames(&mut self, keep: impl Fn(usize) -> bool) {
        for list in self.frames.values_mut() {
            list.retain(|(i, _)| keep(*i));
        }
    }

    /// The frames of `sensor` (image index, image), in index order.
    pub fn frames_of(&self, sensor: SensorKind) -> &[(usize, RgbImage)] {
        self.frames.get(&sensor).map(Vec::as_slice).unwrap_or(&[])
    }

    /// The work-frame pose of frame `index` in rig's convention (z = the indentation beyond
    /// the contact depth, [`MdsRow::work_pose`]).
    pub fn work_pose(&self, index: usize) -> Result<Pose, CompareRealError> {
        self.rows.get(&index).map(MdsRow::work_pose).ok_or(CompareRealError::NoPose { index })
    }

    /// The render pose of frame `index` (z = the skin indentation, [`MdsRow::render_pose`] at
    /// [`MDS_CONTACT_DEPTH_MM`]).
    pub fn render_pose(&self, index: usize) -> Result<Pose, CompareRealError> {
        self.rows.get(&index).map(|r| r.render_pose(MDS_CONTACT_DEPTH_MM)).ok_or(CompareRealError::NoPose { index })
    }

    /// The frames of `sensor` named as on disk (`<id>_<Sensor>_<i>.png`) with their pose:
    /// `pose_of` is [`Self::work_pose`] or [`Self::render_pose`].
    pub fn posed_frames(
        &self,
        sensor: SensorKind,
        pose_of: impl Fn(&Self, usize) -> Result<Pose, CompareRealError>,
    ) -> Result<Vec<(String, Pose, RgbImage)>, CompareRealError> {
        self.frames_of(sensor)
            .iter()
            .map(|(i, img)| Ok((format!("{}_{}_{i}.png", self.object, sensor.label()), pose_of(self, *i)?, img.clone())))
            .collect()
    }
}

/// What is compared with the real frames: renders what `sensor` shows for a depth map through
/// a calibration, with a noise seed, starting from a measured no-contact look when one is
/// given; `None` when it cannot render.
pub type Renderer<'a> = dyn Fn(&DepthMap, &Calibration, u64, Option<&RgbImage>) -> Option<RgbImage> + 'a;

/// Scores of one frame. The renderer's columns are `None` when it could not render.
#[derive(Debug, Clone, Copy)]
pub struct FrameScores {
    pub index: usize,
    /// Share of the frame in the contact region.
    pub contact_fraction: f64,
    /// Overlap of the contact region with the rendered footprint.
    pub footprint_iou: f64,
    pub baseline_whole: f64,
    pub baseline_contact: f64,
    pub sim_whole: Option<f64>,
    pub sim_contact: Option<f64>,
}

/// How [`compare_sensor`] runs.
#[derive(Debug, Clone, Default)]
pub struct CompareOptions {
    /// Start the renderer from the measured no-contact look of the other frames
    /// ([`simulator_reference`]); otherwise it renders its own modelled look.
    pub measured_reference: bool,
    /// Write side-by-side panels (real | baseline | footprint | contact region | rendered) and
    /// the no-contact look into this folder.
    pub panels: Option<PathBuf>,
}

/// The measured no-contact look the renderer starts from: the per-pixel median of the *other*
/// real frames of the sensor only (leave one out: the renderer never sees the frame it is
/// scored on, and has the same information as the baseline). One median over the same frames
/// everywhere keeps the pins whole (they shift a little between frames; switching frame sets
/// per pixel, as the footprint-aware no-contact look does, tears them).
pub fn simulator_reference(others: &[&RgbImage]) -> RgbImage {
    median_image(others)
}

/// Compares one sensor's frames with what `render` makes of their poses through `calib`.
pub fn compare_sensor(
    sample: &RealSample,
    sensor: SensorKind,
    calib: &Calibration,
    render: &Renderer,
    options: &CompareOptions,
) -> Result<Vec<FrameScores>, CompareRealError> {
    let prepared = PreparedSensor::new(sample, sensor, calib, options.measured_reference)?;
    if let Some(dir) = &options.panels {
        std::fs::create_dir_all(dir).map_err(|source| CompareRealError::CreateDir { path: dir.clone(), source })?;
    }
    let mut scores = Vec::new();
    for frame in &prepared.frames {
        let sim = render(&frame.depth, &prepared.calib, frame.index as u64, frame.reference.as_ref());
        let masked = |img: &RgbImage| ssim_masked(&frame.real, img, &frame.mask).ok();
        scores.push(FrameScores {
            index: frame.index,
            contact_fraction: frame.contact_fraction(),
            footprint_iou: iou(&frame.footprint, &frame.mask),
            baseline_whole: ssim(&frame.real, &frame.baseline)?,
            baseline_contact: frame.baseline_contact,
            sim_whole: sim.as_ref().map(|s| ssim(&frame.real, s)).transpose()?,
            sim_contact: sim.as_ref().and_then(masked),
        });
        if let Some(dir) = &options.panels {
            let name = format!("{}_{sensor}_{}.png", sample.object, frame.index);
            save(&panel(&frame.real, &frame.baseline, &frame.footprint, &frame.mask, sim.as_ref()), &dir.join(name))?;
        }
    }
    if let Some(dir) = &options.panels {
        save(&prepared.no_contact, &dir.join(format!("{}_{sensor}_no_contact.png", sample.object)))?;
    }
    Ok(scores)
}

/// One real frame made ready for scoring renderers against it.
pub struct PreparedFrame {
    /// The image index.
    pub index: usize,
    pub real: RgbImage,
    /// The object's depth map at the frame's pose.
    pub depth: DepthMap,
    /// Where the rendered object touches the skin.
    pub footprint: Vec<bool>,
    /// The contact region (pixels differing from the no-contact look).
    pub mask: Vec<bool>,
    /// The pose-blind baseline: the mean of the other frames.
    pub baseline: RgbImage,
    /// The baseline's contact-region SSIM.
    pub baseline_contact: f64,
    /// The measured no-contact look a renderer starts from, when asked for.
    pub reference: Option<RgbImage>,
}

impl PreparedFrame {
    /// Share of the frame in the contact region.
    pub fn contact_fraction(&self) -> f64 {
        self.mask.iter().filter(|&&m| m).count() as f64 / self.mask.len().max(1) as f64
    }
}

/// One sensor's frames with everything that does not depend on the renderer.
pub struct PreparedSensor {
    pub sensor: SensorKind,
    /// The calibration scaled to the frames.
    pub calib: Calibration,
    pub no_contact: RgbImage,
    pub frames: Vec<PreparedFrame>,
}

impl PreparedSensor {
    /// Renders the depth maps and works out the no-contact look, the contact regions, the
    /// baselines and (with `measured_reference`) the renderer's references.
    pub fn new(sample: &RealSample, sensor: SensorKind, calib: &Calibration, measured_reference: bool) -> Result<Self, CompareRealError> {
        let list = sample.frames_of(sensor);
        if list.len() < 2 {
            return Err(CompareRealError::TooFewFrames { sensor: sensor.label(), frames: list.len() });
        }
        let (w, h) = list[0].1.dimensions();
        let calib = calib.scaled_to(w, h);
        let mut depths = Vec::new();
        let mut footprints = Vec::new();
        for (i, _) in list {
            let d = render_depth(&sample.mesh, &sample.render_pose(*i)?, &calib, w, h, 2);
            footprints.push(d.height_mm.iter().map(|&v| v > 0.0).collect::<Vec<bool>>());
            depths.push(d);
        }
        let covered: Vec<Vec<bool>> =
            footprints.iter().map(|f| dilate_mask(f, w as usize, h as usize, FOOTPRINT_MARGIN_PX as usize)).collect();
        let all: Vec<&RgbImage> = list.iter().map(|(_, img)| img).collect();
        let no_contact = median_image_excluding(&all, &covered);
        let mut frames = Vec::new();
        for (k, ((index, real), (depth, footprint))) in list.iter().zip(depths.into_iter().zip(footprints)).enumerate() {
            let others: Vec<&RgbImage> = all.iter().enumerate().filter(|(j, _)| *j != k).map(|(_, f)| *f).collect();
            let baseline = mean_image(&others);
            let mask = difference_mask(real, &no_contact, CONTACT_THRESHOLD);
            let baseline_contact = ssim_masked(real, &baseline, &mask).unwrap_or(f64::NAN);
            let reference = measured_reference.then(|| simulator_reference(&others));
            frames.push(PreparedFrame { index: *index, real: real.clone(), depth, footprint, mask, baseline, baseline_contact, reference });
        }
        Ok(Self { sensor, calib, no_contact, frames })
    }

    /// The contact-region SSIM of what `render` makes of frame `k` (`None` when it cannot
    /// render or the region is empty).
    pub fn contact_ssim(&self, k: usize, render: &Renderer) -> Option<f64> {
        let f = self.frames.get(k)?;
        let sim = render(&f.depth, &self.calib, f.index as u64, f.reference.as_ref())?;
        ssim_masked(&f.real, &sim, &f.mask).ok().filter(|v| v.is_finite())
    }

    /// Mean absolute difference of what `render` makes of frame `k` from the real frame over
    /// its contact region, 8-bit levels per channel (the fit's residual).
    pub fn contact_residual(&self, k: usize, render: &Renderer) -> Option<f64> {
        let f = self.frames.get(k)?;
        let sim = render(&f.depth, &self.calib, f.index as u64, f.reference.as_ref())?;
        let (mut sum, mut n) = (0.0f64, 0usize);
        for ((a, b), &m) in f.real.pixels().zip(sim.pixels()).zip(&f.mask) {
            if m {
                sum += (0..3).map(|c| (a.0[c] as f64 - b.0[c] as f64).abs()).sum::<f64>() / 3.0;
                n += 1;
            }
        }
        (n > 0).then(|| sum / n as f64)
    }
}

/// A renderer with parameters: renders as [`Renderer`] with the parameter vector given first.
pub type ParametricRenderer<'a> = dyn Fn(&[f64], &DepthMap, &Calibration, u64, Option<&RgbImage>) -> Option<RgbImage> + 'a;

/// The range a fit may search for one parameter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ParameterRange {
    pub min: f64,
    pub max: f64,
}

/// What a fit found.
#[derive(Debug, Clone, PartialEq)]
pub struct FitOutcome {
    pub parameters: Vec<f64>,
    /// Mean contact-region SSIM over the frames fitted on.
    pub score: f64,
    /// Candidates rendered and scored.
    pub evaluations: usize,
}

/// Rounds of the pattern search before it gives up (each halves the steps that found nothing).
const FIT_ROUNDS: usize = 5;

/// Values per parameter of the coarse scan that comes before the pattern search.
const SCAN_POINTS: usize = 9;

/// Sweeps of the coarse scan over all the parameters.
const SCAN_SWEEPS: usize = 2;

/// Fits `start` (one value per range) to the frames `train` (indices into
/// `prepared.frames`). First a coarse scan: each parameter in turn is set to the best of
/// `SCAN_POINTS` values spread evenly over its range, the others held, in
/// `SCAN_SWEEPS` sweeps (the contact SSIM has several local peaks, and a local search alone
/// ended in a different one on each fold of a cross-validation). Then a pattern search: each
/// parameter in turn is moved a step either way and kept where the mean contact-region SSIM
/// rises; a parameter's step halves after a pass that found nothing, starting at half the
/// scan's spacing. Deterministic; a candidate that cannot render scores nothing.
pub fn fit_parameters(
    prepared: &PreparedSensor,
    train: &[usize],
    start: &[f64],
    ranges: &[ParameterRange],
    render: &ParametricRenderer,
) -> FitOutcome {
    let mut evaluations = 0usize;
    let mut score_of = |p: &[f64]| {
        evaluations += 1;
        let renderer = |d: &DepthMap, c: &Calibration, seed: u64, r: Option<&RgbImage>| render(p, d, c, seed, r);
        let scores: Vec<f64> = train.iter().filter_map(|&k| prepared.contact_ssim(k, &renderer)).collect();
        if scores.len() == train.len() && !scores.is_empty() { scores.iter().sum::<f64>() / scores.len() as f64 } else { f64::NEG_INFINITY }
    };
    let clamp = |v: f64, r: &ParameterRange| if v.is_finite() { v.clamp(r.min, r.max) } else { r.min };
    let mut best: Vec<f64> = start.iter().zip(ranges).map(|(v, r)| clamp(*v, r)).collect();
    let mut best_score = score_of(&best);
    let spacing = |r: &ParameterRange| (r.max - r.min) / (SCAN_POINTS - 1) as f64;
    for _ in 0..SCAN_SWEEPS {
        for i in 0..best.len() {
            for j in 0..SCAN_POINTS {
                let mut candidate = best.clone();
                candidate[i] = clamp(ranges[i].min + j as f64 * spacing(&ranges[i]), &ranges[i]);
                if candidate[i] == best[i] {
                    continue;
                }
                let score = score_of(&candidate);
                if score > best_score + 1e-5 {
                    (best, best_score) = (candidate, score);
                }
            }
        }
    }
    let mut steps: Vec<f64> = ranges.iter().map(|r| 0.5 * spacing(r)).collect();
    for _ in 0..FIT_ROUNDS {
        for i in 0..best.len() {
            let mut moved = false;
            for dir in [1.0, -1.0] {
                loop {
                    let mut candidate = best.clone();
                    candidate[i] = clamp(best[i] + dir * steps[i], &ranges[i]);
                    if candidate[i] == best[i] {
                        break;
                    }
                    let score = score_of(&candidate);
                    if score > best_score + 1e-5 {
                        (best, best_score, moved) = (candidate, score, true);
                    } else {
                        break;
                    }
                }
            }
            if !moved {
                steps[i] *= 0.5;
            }
        }
    }
    FitOutcome { parameters: best, score: best_score, evaluations }
}

/// One fold of a leave-one-out cross-validation.
#[derive(Debug, Clone, PartialEq)]
pub struct HeldOutScore {
    /// The image index of the frame left out.
    pub index: usize,
    /// The parameters fitted on the other frames.
    pub parameters: Vec<f64>,
    /// Their contact-region SSIM on the frame left out.
    pub sim_contact: f64,
    /// The baseline's on that frame.
    pub baseline_contact: f64,
}

/// Leave-one-out cross-validation of [`fit_parameters`]: for each frame, fits on the others
/// and scores the frame left out.
pub fn cross_validate(
    prepared: &PreparedSensor,
    start: &[f64],
    ranges: &[ParameterRange],
    render: &ParametricRenderer,
) -> Vec<HeldOutScore> {
    (0..prepared.frames.len())
        .map(|k| {
            let train: Vec<usize> = (0..prepared.frames.len()).filter(|&j| j != k).collect();
            let fit = fit_parameters(prepared, &train, start, ranges, render);
            let renderer = |d: &DepthMap, c: &Calibration, seed: u64, r: Option<&RgbImage>| render(&fit.parameters, d, c, seed, r);
            HeldOutScore {
                index: prepared.frames[k].index,
                sim_contact: prepared.contact_ssim(k, &renderer).unwrap_or(f64::NAN),
                baseline_contact: prepared.frames[k].baseline_contact,
                parameters: fit.parameters,
            }
        })
        .collect()
}

/// The names of the entries of `dir`, sorted (names that are not UTF-8 are left out).
fn list_dir(dir: &Path) -> Result<Vec<String>, CompareRealError> {
    let err = |source| CompareRealError::ReadDir { path: dir.to_path_buf(), source };
    let mut names = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(err)? {
        if let Ok(name) = entry.map_err(err)?.file_name().into_string() {
            names.push(name);
        }
    }
    names.sort();
    Ok(names)
}

fn save(image: &RgbImage, path: &Path) -> Result<(), CompareRealError> {
    image.save(path).map_err(|source| CompareRealError::Write { path: path.to_path_buf(), source })
}

/// real | baseline | real with footprint outline | contact region | rendered (if any).
fn panel(real: &RgbImage, baseline: &RgbImage, footprint: &[bool], mask: &[bool], sim: Option<&RgbImage>) -> RgbImage {
    let (w, h) = real.dimensions();
    let mut overlay = real.clone();
    for (i, px) in overlay.pixels_mut().enumerate() {
        if footprint[i] {
            px.0 = [px.0[0] / 2 + 127, px.0[1] / 2, px.0[2] / 2];
        }
    }
    let region = RgbImage::from_fn(w, h, |x, y| {
        let i = (y * w + x) as usize;
        match (mask[i], footprint[i]) {
            (true, true) => Rgb([255, 255, 255]),
            (true, false) => Rgb([0, 160, 255]),
            (false, true) => Rgb([255, 60, 0]),
            (false, false) => Rgb([0, 0, 0]),
        }
    });
    let mut tiles = vec![real.clone(), baseline.clone(), overlay, region];
    if let Some(s) = sim {
        tiles.push(s.clone());
    }
    let mut out = RgbImage::new(w * tiles.len() as u32, h);
    for (k, t) in tiles.iter().enumerate() {
        imageops::replace(&mut out, t, (k as u32 * w) as i64, 0);
    }
    out
}
