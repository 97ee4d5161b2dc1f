//! Contact detection: where in the image the indenter (or object) presses, to sub-pixel.
//!
//! Against the no-contact reference frame: the per-pixel change (largest of the three channel
//! differences), smoothed by a box blur applied three times (close to a Gaussian, and wide
//! enough that a marker skin's discrete pins merge into one blob), a noise floor (median plus
//! a multiple of the median absolute deviation of the smoothed change), and the connected
//! region around the strongest change above `floor + fraction * (peak - floor)`. The contact
//! is that region's centroid weighted by how far each pixel rises above the threshold, which
//! lands between pixels (sub-pixel) and does not depend on where the peak pixel happens to be.
//!
//! That centroid follows the brightness of the skin behind the contact: on the see-through
//! skins (ViTac, ViTacTip) the object and its glow push pixels towards white, which changes a
//! darker pixel more, so the darker rim of the field of view pulls it outwards, more at
//! deeper presses (1.5 and 0.56 px residual on the simulated sensors, and a depth term
//! three and two times the truth). [`detect_imprint`] is used there instead: the blend towards
//! white (`(F - R) / (255 - R)`, which does not depend on the skin's brightness), the markers
//! filled by a closing, and the centre of the imprint's outline: the steepest fall of the
//! blend along rays from a first guess, fitted with a circle (the indenter is a sphere), which
//! a gain varying across the image barely moves.
//!
//! On marker skins ([`detect_marker_contact`]) the pins are found in both images, matched,
//! each match refined on the images themselves (Lucas-Kanade with a gain that may vary across
//! the pin, since a pressed skin is shaded), and the contact is the centre their displacements
//! point away from, the nearer markers weighing more (see there).
//! [`ContactDetector`] picks one per sensor kind.
//!
//! Works on any bytes: mismatched sizes and empty images are errors, never panics.

// `!(a > b)` is deliberate here: a NaN must fail every check, which `a <= b` would not.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use image::RgbImage;

use crate::imaging::{BoxBorder, box_blur_repeated, close_values, flood_fill, luma, luma_f64, max_channel_difference};

/// Why no contact was found.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DetectError {
    #[error("frame is {frame:?} px but the reference is {reference:?} px")]
    SizeMismatch { frame: [u32; 2], reference: [u32; 2] },
    #[error("empty image")]
    Empty,
    #[error("no contact: strongest change {peak:.2} levels is within {contrast:.2} of the noise floor {floor:.2}")]
    NoContact { peak: f64, floor: f64, contrast: f64 },
    #[error("only {found} markers found in the reference (need {needed})")]
    TooFewMarkers { found: usize, needed: usize },
    #[error("no contact: {moved} markers moved more than {min_shift_px} px (need {needed})")]
    MarkersStill { moved: usize, min_shift_px: f64, needed: usize },
    #[error("the marker displacements do not point away from one centre")]
    NoCentre,
}

/// How contacts are located: by the changed pixels (see-through skins, where the object
/// itself shows) or by the markers' displacement field (marker skins, where the pins move
/// but the object is invisible and a changed-pixel centroid jumps between pins).
#[derive(Debug, Clone, PartialEq)]
pub enum ContactDetector {
    Difference(DetectOptions),
    Markers(MarkerOptions),
    /// The blend towards the object's white on a see-through skin ([`detect_imprint`]).
    Imprint(ImprintOptions),
}

impl ContactDetector {
    /// The detector suited to a sensor kind at an image width: markers for TacTip (white
    /// pins), the imprint's outline for ViTac and ViTacTip (with its dark markers filled).
    pub fn for_sensor(kind: crate::sensor::SensorKind, width: u32) -> Self {
        use crate::sensor::SensorKind;
        match kind {
            SensorKind::TacTip => Self::Markers(MarkerOptions::default()),
            SensorKind::ViTac => Self::Imprint(ImprintOptions::for_width(width)),
            SensorKind::ViTacTip => Self::Imprint(ImprintOptions::with_markers(width)),
        }
    }

    /// Locates the contact in `frame` against the no-contact `reference`.
    pub fn detect(&self, frame: &RgbImage, reference: &RgbImage) -> Result<Contact, DetectError> {
        match self {
            Self::Difference(o) => detect_contact(frame, reference, o),
            Self::Markers(o) => detect_marker_contact(frame, reference, o),
            Self::Imprint(o) => detect_imprint(frame, reference, o),
        }
    }
}

/// Settings of [`detect_contact`].
#[derive(Debug, Clone, PartialEq)]
pub struct DetectOptions {
    /// Box-blur radius, px (applied three times).
    pub blur_px: u32,
    /// Region threshold between the floor (0) and the peak (1).
    pub fraction: f64,
    /// Least rise of the peak above the floor counted as a contact, grey levels.
    pub min_contrast: f64,
    /// Floor = median + this many MADs of the smoothed change.
    pub floor_mads: f64,
}

impl Default for DetectOptions {
    fn default() -> Self {
        Self { blur_px: 6, fraction: 0.3, min_contrast: 3.0, floor_mads: 4.0 }
    }
}

impl DetectOptions {
    /// Defaults with the blur scaled to the image width (6 px at 512 px).
    pub fn for_width(width: u32) -> Self {
        Self { blur_px: ((6 * width) / 512).max(1), ..Self::default() }
    }
}

/// A detected contact.
#[derive(Debug, Clone, PartialEq)]
pub struct Contact {
    /// Weighted centroid (column, row) in pixel coordinates where pixel (i, j) covers
    /// `[i, i+1) x [j, j+1)`, i.e. its centre is at `i + 0.5`.
    pub centroid_px: [f64; 2],
    /// Pixels in the contact region.
    pub area_px: usize,
    /// Strongest smoothed change, grey levels.
    pub peak: f64,
    /// Noise floor, grey levels.
    pub floor: f64,
    /// Marker detection: how many markers moved (then `peak` is the largest shift in px and
    /// `area_px` the same count); `None` for a changed-pixel detection.
    pub moved_markers: Option<usize>,
    /// Imprint detection ([`detect_imprint`]): the radius of the fitted outline, px (then
    /// `peak` is the strongest blend towards white, 0..1); `None` otherwise, or when no
    /// outline was found and the region centroid stands.
    pub outline_radius_px: Option<f64>,
}

impl std::fmt::Display for Contact {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if let Some(r) = self.outline_radius_px {
            return write!(
                f,
                "contact at ({:.2}, {:.2}) px, outline radius {r:.1} px, blend {:.2}",
                self.centroid_px[0], self.centroid_px[1], self.peak
            );
        }
        if let Some(n) = self.moved_markers {
            return write!(
                f,
                "contact at ({:.2}, {:.2}) px, {n} markers moved, up to {:.2} px",
                self.centroid_px[0], self.centroid_px[1], self.peak
            );
        }
        write!(
            f,
            "contact at ({:.2}, {:.2}) px, {} px region, contrast {:.1} levels",
            self.centroid_px[0],
            self.centroid_px[1],
            self.area_px,
            self.peak - self.floor
        )
    }
}

/// Settings of [`detect_marker_contact`].
#[derive(Debug, Clone, PartialEq)]
pub struct MarkerOptions {
    /// Markers are brighter than the skin (TacTip: white pins on black); `false` for dark
    /// markers on a bright skin.
    pub bright: bool,
    /// Smallest and largest marker blob, px.
    pub min_area_px: usize,
    pub max_area_px: usize,
    /// Least displacement counted as moved, px.
    pub min_shift_px: f64,
    /// Fewest moved markers for a detection.
    pub min_moved: usize,
}

impl Default for MarkerOptions {
    fn default() -> Self {
        Self { bright: true, min_area_px: 4, max_area_px: 4000, min_shift_px: 0.25, min_moved: 4 }
    }
}

/// Sub-pixel marker centroids: connected blobs brighter (or darker) than halfway between the
/// image's median and its 99.5th (0.5th) percentile, weighted by how far they pass it.
pub fn find_markers(image: &RgbImage, options: &MarkerOptions) -> Vec<[f64; 2]> {
    let (w, h) = (image.width() as usize, image.height() as usize);
    if w == 0 || h == 0 {
        return Vec::new();
    }
    let sign = if options.bright { 1.0 } else { -1.0 };
    let g: Vec<f32> = image.as_raw().chunks_exact(3).map(|p| sign * luma(&[p[0] as f32, p[1] as f32, p[2] as f32])).collect();
    let mut sorted = g.clone();
    sorted.sort_by(f32::total_cmp);
    let median = sorted[sorted.len() / 2];
    let high = sorted[((sorted.len() - 1) as f64 * 0.995) as usize];
    let threshold = (median + high) / 2.0;
    if !(high - median > 10.0) {
        return Vec::new();
    }
    let mut seen = vec![false; w * h];
    let mut markers = Vec::new();
    for start in 0..w * h {
        if seen[start] || g[start] <= threshold {
            continue;
        }
        let blob = flood_fill(&g, w, h, start, threshold as f64, &mut seen);
        let (mut su, mut sv, mut sw) = (0.0f64, 0.0f64, 0.0f64);
        for &i in &blob {
            let (x, y) = (i % w, i / w);
            let wt = (g[i] - threshold) as f64;
            su += wt * (x as f64 + 0.5);
            sv += wt * (y as f64 + 0.5);
            sw += wt;
        }
        let area = blob.len();
        if (options.min_area_px..=options.max_area_px).contains(&area) && sw > 0.0 {
            markers.push([su / sw, sv / sw]);
        }
    }
    markers
}

/// Locates the contact on a marker skin: markers are matched between the reference and the
/// frame (nearest within half the typical marker spacing), each displacement is refined on the
/// images (`track_marker`), and the contact is the point the displacements point away from
/// (least squares on `d x (p - c) = 0`, see `lines_centre`). Independent of where the lattice's markers happen to lie, unlike
/// a centroid of the changed pixels.
pub fn detect_marker_contact(frame: &RgbImage, reference: &RgbImage, options: &MarkerOptions) -> Result<Contact, DetectError> {
    if frame.dimensions() != reference.dimensions() {
        return Err(DetectError::SizeMismatch {
            frame: [frame.width(), frame.height()],
            reference: [reference.width(), reference.height()],
        });
    }
    let before = find_markers(reference, options);
    let after = find_markers(frame, options);
    if before.len() < options.min_moved || after.is_empty() {
        return Err(DetectError::TooFewMarkers { found: before.len(), needed: options.min_moved });
    }
    let dist2 = |a: &[f64; 2], b: &[f64; 2]| (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2);
    let nearest = |p: &[f64; 2], set: &[[f64; 2]], skip_self: bool| -> Option<(usize, f64)> {
        set.iter().enumerate().map(|(j, q)| (j, dist2(p, q))).filter(|(_, d)| !skip_self || *d > 0.0).min_by(|a, b| a.1.total_cmp(&b.1))
    };
    let mut spacings: Vec<f64> = before.iter().filter_map(|p| nearest(p, &before, true)).map(|(_, d)| d.sqrt()).collect();
    spacings.sort_by(f64::total_cmp);
    let spacing = spacings.get(spacings.len() / 2).copied().unwrap_or(0.0);
    let max_shift = spacing / 2.0;
    // Each moved marker as (rest position, displacement).
    let mut moves: Vec<([f64; 2], [f64; 2])> = Vec::new();
    let mut peak = 0.0f64;
    for p in &before {
        let Some((j, d2)) = nearest(p, &after, false) else { continue };
        if !(d2.sqrt() < max_shift) {
            continue;
        }
        // Only mutual matches: the frame marker's nearest reference marker is this one.
        if nearest(&after[j], &before, false).is_none_or(|(_, back)| back < d2) {
            continue;
        }
        moves.push((*p, [after[j][0] - p[0], after[j][1] - p[1]]));
    }
    // The blob centroids gave each moved marker's displacement to about a pixel; it is refined
    // against the reference image itself (see [`track_marker`]).
    let (lf, lr) = (luma_plane(frame), luma_plane(reference));
    let (w, h) = (frame.width() as usize, frame.height() as usize);
    let half_window = (0.3 * spacing).round().clamp(2.0, 64.0) as usize;
    moves.retain_mut(|(p, d)| match track_marker(&lf, &lr, w, h, *p, *d, half_window) {
        Some(refined) => {
            *d = refined;
            let shift = d[0].hypot(d[1]);
            peak = peak.max(shift);
            shift > options.min_shift_px && shift < max_shift
        }
        None => false,
    });
    let moved = moves.len();
    if moved < options.min_moved {
        return Err(DetectError::MarkersStill { moved, min_shift_px: options.min_shift_px, needed: options.min_moved });
    }
    // The row of a marker is `|d|` times the distance of the centre from its line, and an
    // error in `d` across the line moves that line by its distance `r` from the centre times
    // the error over `|d|`: a far marker that barely moved points only roughly at the centre.
    // So the rows are weighted by `1 / r^2` (r from the previous solution, at least a marker
    // spacing), three times over; the first solution weighs them all alike.
    let mut c = lines_centre(&moves, None)?;
    for _ in 0..3 {
        c = lines_centre(&moves, Some((c, spacing.max(1.0))))?;
    }
    Ok(Contact { centroid_px: c, area_px: moved, peak, floor: 0.0, moved_markers: Some(moved), outline_radius_px: None })
}

/// The image's luma, row-major.
fn luma_plane(image: &RgbImage) -> Vec<f32> {
    image.as_raw().chunks_exact(3).map(|p| luma(&[p[0] as f32, p[1] as f32, p[2] as f32])).collect()
}

/// The displacement of the marker at `p` in the reference `lr` to where it is in the frame `lf`
/// (both `w` x `h` luma), starting from `d`: Lucas-Kanade over the square of `half_window`
/// px around it, with the frame modelled as the shifted reference times a gain that varies
/// linearly across the window, plus an offset. A centroid of the marker's bright pixels is
/// locked to the pixel grid (a shift of a third of a pixel moves it by more or less, depending
/// on where the marker's edge falls) and follows any brightness gradient across the marker
/// (a pressed skin is shaded, brighter on the side facing the light): on the simulated TacTip
/// they put the located contact 1 px off. The image model takes both out. `None` when the
/// window leaves the image or the system is singular (a marker the frame no longer shows).
fn track_marker(lf: &[f32], lr: &[f32], w: usize, h: usize, p: [f64; 2], d: [f64; 2], half_window: usize) -> Option<[f64; 2]> {
    if w < 3 || h < 3 || lf.len() != w * h || lr.len() != w * h {
        return None;
    }
    let (x0, y0) = (p[0].floor(), p[1].floor());
    let hw = half_window as f64;
    if !(x0 - hw >= 1.0 && y0 - hw >= 1.0 && x0 + hw + 1.0 < w as f64 && y0 + hw + 1.0 < h as f64) {
        return None;
    }
    let (x0, y0) = (x0 as usize, y0 as usize);
    let at = |x: f64, y: f64| sample(lr, w, h, x, y).unwrap_or(0.0);
    let mut d = d;
    for _ in 0..8 {
        let mut ata = [[0.0f64; 6]; 6];
        let mut atb = [0.0f64; 6];
        for y in y0 - half_window..=y0 + half_window {
            for x in x0 - half_window..=x0 + half_window {
                let (px, py) = (x as f64 + 0.5, y as f64 + 0.5);
                let (sx, sy) = (px - d[0], py - d[1]);
                let r = at(sx, sy);
                let (gx, gy) = (at(sx + 0.5, sy) - at(sx - 0.5, sy), at(sx, sy + 0.5) - at(sx, sy - 0.5));
                let (u, v) = (px - p[0], py - p[1]);
                // F = a R + bx u R + by v R + c - a grad(R) . delta
                let row = [r, u * r, v * r, 1.0, -gx, -gy];
                let f = lf[y * w + x] as f64;
                for i in 0..6 {
                    for j in 0..6 {
                        ata[i][j] += row[i] * row[j];
                    }
                    atb[i] += row[i] * f;
                }
            }
        }
        let sol = super::fit::solve(ata, atb)?;
        let gain = sol[0];
        if !(gain > 0.2) {
            return None;
        }
        let step = [sol[4] / gain, sol[5] / gain];
        d = [d[0] + step[0], d[1] + step[1]];
        if !(d[0].abs() <= hw && d[1].abs() <= hw) {
            return None;
        }
        if step[0].hypot(step[1]) < 1e-3 {
            break;
        }
    }
    Some(d)
}

/// The point the displacements `moves` (rest position, displacement) point away from: least
/// squares on `d x (p - c) = 0`, each row weighted by `1 / max(|p - c0|, floor)^2` when
/// `around` gives `(c0, floor)`.
fn lines_centre(moves: &[([f64; 2], [f64; 2])], around: Option<([f64; 2], f64)>) -> Result<[f64; 2], DetectError> {
    let (mut a11, mut a12, mut a22, mut b1, mut b2) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for (p, d) in moves {
        let wt = match around {
            Some((c0, floor)) => 1.0 / (p[0] - c0[0]).hypot(p[1] - c0[1]).max(floor).powi(2),
            None => 1.0,
        };
        // Row [d.y, -d.x] . c = d.y p.x - d.x p.y.
        let (r1, r2, rhs) = (d[1], -d[0], d[1] * p[0] - d[0] * p[1]);
        a11 += wt * r1 * r1;
        a12 += wt * r1 * r2;
        a22 += wt * r2 * r2;
        b1 += wt * r1 * rhs;
        b2 += wt * r2 * rhs;
    }
    let det = a11 * a22 - a12 * a12;
    if !(det.abs() > 1e-9 * (a11 * a22).abs().max(f64::MIN_POSITIVE)) {
        return Err(DetectError::NoCentre);
    }
    let c = [(b1 * a22 - b2 * a12) / det, (a11 * b2 - a12 * b1) / det];
    if !c.iter().all(|v| v.is_finite()) {
        return Err(DetectError::NoCentre);
    }
    Ok(c)
}

/// The frame's size as (width, height) when the reference has the same one and it is not empty.
fn checked_size(frame: &RgbImage, reference: &RgbImage) -> Result<(usize, usize), DetectError> {
    let (w, h) = frame.dimensions();
    if reference.dimensions() != (w, h) {
        return Err(DetectError::SizeMismatch { frame: [w, h], reference: [reference.width(), reference.height()] });
    }
    if w == 0 || h == 0 {
        return Err(DetectError::Empty);
    }
    Ok((w as usize, h as usize))
}

/// Locates the contact in `frame` against the no-contact `reference`.
pub fn detect_contact(frame: &RgbImage, reference: &RgbImage, options: &DetectOptions) -> Result<Contact, DetectError> {
    let (w, h) = checked_size(frame, reference)?;
    let mut change = max_channel_difference(frame, reference);
    box_blur_repeated(&mut change, w, h, options.blur_px as usize, 3, BoxBorder::Shrink);
    let mut sorted = change.clone();
    sorted.sort_by(f32::total_cmp);
    let median = sorted[sorted.len() / 2] as f64;
    let mut dev: Vec<f32> = change.iter().map(|v| (*v as f64 - median).abs() as f32).collect();
    dev.sort_by(f32::total_cmp);
    let mad = dev[dev.len() / 2] as f64;
    let floor = median + options.floor_mads * mad;
    let (peak_i, peak) = change.iter().enumerate().fold((0, f32::MIN), |best, (i, &v)| if v > best.1 { (i, v) } else { best });
    let peak = peak as f64;
    if !(peak - floor >= options.min_contrast) {
        return Err(DetectError::NoContact { peak, floor, contrast: options.min_contrast });
    }
    let threshold = floor + options.fraction.clamp(0.0, 1.0) * (peak - floor);
    // Flood fill (4-connected) from the peak over pixels above the threshold; a flat top at
    // the threshold gives the peak's centre.
    let (centroid_px, area) = region_centroid(&change, w, h, peak_i, threshold);
    Ok(Contact { centroid_px, area_px: area, peak, floor, moved_markers: None, outline_radius_px: None })
}

/// Settings of [`detect_imprint`].
#[derive(Debug, Clone, PartialEq)]
pub struct ImprintOptions {
    /// Level the pressed object and its glow push the image towards (8-bit luma).
    pub white_level: f64,
    /// Radius of the closing (dilate, then erode) behind the search for the skin's markers, px
    /// (0: no markers; see `fill_markers`).
    pub close_px: u32,
    /// Box-blur radius, px (applied twice).
    pub blur_px: u32,
    /// Region threshold as a fraction of the peak blend.
    pub fraction: f64,
    /// Least peak blend counted as a contact (0..1).
    pub min_blend: f64,
    /// Rays cast to find the imprint's outline (0: keep the region centroid).
    pub edge_rays: usize,
    /// How far the rays reach, as a fraction of the image's smaller side.
    pub max_radius_frac: f64,
}

impl Default for ImprintOptions {
    fn default() -> Self {
        Self { white_level: 255.0, close_px: 0, blur_px: 4, fraction: 0.5, min_blend: 0.08, edge_rays: 128, max_radius_frac: 0.3 }
    }
}

impl ImprintOptions {
    /// Defaults (a skin without markers, ViTac) with the lengths scaled to the image width
    /// (given at 512 px).
    pub fn for_width(width: u32) -> Self {
        let d = Self::default();
        Self { close_px: scaled(d.close_px, width), blur_px: scaled(d.blur_px, width), ..d }
    }

    /// For a see-through skin with dark markers (ViTacTip, markers about 4.7 px in radius at
    /// 512 px): they are found under a closing of 4 + 2 px and filled from the skin around
    /// them, a wider blur (6 px) evens out what is left. (Before the skin model, with the
    /// markers filled by the closing itself, closing 0 / 2 / 3 / 4 / 5 / 6 / 8 px gave
    /// 1.76-1.92 / 1.57 / 1.18 / 0.33 / 0.36 / 0.75 / 0.73 px RMS on 75 simulated presses.)
    pub fn with_markers(width: u32) -> Self {
        Self { close_px: scaled(4, width), blur_px: scaled(6, width), ..Self::default() }
    }
}

/// A length given at 512 px width, scaled to `width` (at least 1 unless it is 0).
fn scaled(px_at_512: u32, width: u32) -> u32 {
    if px_at_512 == 0 { 0 } else { ((px_at_512 as u64 * width as u64) / 512).max(1) as u32 }
}

/// Locates the contact on a see-through skin by the blend towards white: the per-pixel
/// `(F - R) / (white - R)` (luma), the fraction of the way each pixel moved from the
/// reference towards the object's near-white. Unlike the raw change it does not grow where
/// the skin behind is darker, so the darker rim of the field of view does not pull the
/// centroid outwards. The skin's markers (which hide the object and so leave holes in the
/// blend) are filled by a closing, then the centroid of the region around the peak above
/// `fraction * peak`, weighted by how far each pixel passes it.
pub fn detect_imprint(frame: &RgbImage, reference: &RgbImage, options: &ImprintOptions) -> Result<Contact, DetectError> {
    let (w, h) = checked_size(frame, reference)?;
    // The markers are filled in each image before the two are compared: pins that the press
    // moved would otherwise leave a bright spot where they were and a dark one where they
    // went, a ring of crescents around the contact that the outline search takes for edges.
    let filled = |image: &RgbImage| {
        let mut l: Vec<f32> = image.as_raw().chunks_exact(3).map(|p| luma_f64(p) as f32).collect();
        fill_markers(&mut l, w, h, options.close_px as usize);
        l
    };
    let (lf, lr) = (filled(frame), filled(reference));
    let mut blend: Vec<f32> = lf
        .iter()
        .zip(&lr)
        .map(|(&f, &r)| {
            let (f, r) = (f as f64, r as f64);
            ((f - r) / (options.white_level - r).max(8.0)).clamp(-1.0, 1.5) as f32
        })
        .collect();
    box_blur_repeated(&mut blend, w, h, options.blur_px as usize, 2, BoxBorder::Shrink);
    let (peak_i, peak) = blend.iter().enumerate().fold((0, f32::MIN), |best, (i, &v)| if v > best.1 { (i, v) } else { best });
    let peak = peak as f64;
    if !(peak >= options.min_blend) {
        return Err(DetectError::NoContact { peak, floor: 0.0, contrast: options.min_blend });
    }
    let threshold = options.fraction.clamp(0.0, 1.0) * peak;
    let (mut centroid_px, area) = region_centroid(&blend, w, h, peak_i, threshold);
    let mut outline_radius_px = None;
    if options.edge_rays > 0 {
        let reach = options.max_radius_frac * w.min(h) as f64;
        for _ in 0..2 {
            match imprint_circle(&blend, w, h, centroid_px, reach, options.edge_rays) {
                Some((c, r)) => {
                    centroid_px = c;
                    outline_radius_px = Some(r);
                }
                None => break,
            }
        }
    }
    Ok(Contact { centroid_px, area_px: area, peak, floor: 0.0, moved_markers: None, outline_radius_px })
}

/// Fills the dark markers of a see-through skin in the luma plane `l` from the skin around
/// them. A closing alone (a running maximum, then minimum, over `close_px`) fills a marker with
/// the brightest skin within reach, so on a sloping blend (the outline of an imprint) the
/// filled marker is brighter than its surroundings and bends the outline towards it. Here the
/// closing, two pixels wider so that it covers whole markers, only finds them (pixels at least
/// a quarter darker than it); they are then filled by normalised convolution, the mean of the
/// unmasked pixels around each, which follows the slope of the blend across the marker. The
/// markers' anti-aliased rims are kept: masking them too (a one-pixel dilation) left the
/// simulated ViTacTip's calibration at 0.91 px against 0.40 px without. Radius 0 leaves `l`
/// as it is.
fn fill_markers(l: &mut [f32], w: usize, h: usize, close_px: usize) {
    if close_px == 0 || l.len() != w * h {
        return;
    }
    let reach = close_px + 2;
    let mut closed = l.to_vec();
    close_values(&mut closed, w, h, reach);
    let mask: Vec<bool> = l.iter().zip(&closed).map(|(&v, &c)| v < c - (0.25 * c).max(12.0)).collect();
    let mut sum: Vec<f32> = l.iter().zip(&mask).map(|(&v, &m)| if m { 0.0 } else { v }).collect();
    let mut weight: Vec<f32> = mask.iter().map(|&m| if m { 0.0 } else { 1.0 }).collect();
    box_blur_repeated(&mut sum, w, h, reach, 2, BoxBorder::Shrink);
    box_blur_repeated(&mut weight, w, h, reach, 2, BoxBorder::Shrink);
    for (i, v) in l.iter_mut().enumerate() {
        if mask[i] {
            *v = if weight[i] > 0.05 { sum[i] / weight[i] } else { closed[i] };
        }
    }
}

/// Bilinear sample of a row-major field at pixel coordinates (pixel centres at `i + 0.5`);
/// `None` outside.
fn sample(values: &[f32], w: usize, h: usize, x: f64, y: f64) -> Option<f64> {
    let (fx, fy) = (x - 0.5, y - 0.5);
    if !(fx >= 0.0 && fy >= 0.0 && fx < (w - 1) as f64 && fy < (h - 1) as f64) {
        return None;
    }
    let (i, j) = (fx as usize, fy as usize);
    let (tx, ty) = (fx - i as f64, fy - j as f64);
    let at = |a: usize, b: usize| values[b * w + a] as f64;
    Some((at(i, j) * (1.0 - tx) + at(i + 1, j) * tx) * (1.0 - ty) + (at(i, j + 1) * (1.0 - tx) + at(i + 1, j + 1) * tx) * ty)
}

/// The imprint's outline as a circle (centre, radius): along `rays` rays from `start`, the steepest fall of
/// `values` (sub-pixel, by a parabola through the derivative's three samples around it), then
/// an algebraic circle fit with one round of outlier rejection. The centre of the outline
/// depends on where the edge is, not on how bright the skin behind it is, so a gain that
/// varies across the image barely moves it. `None` when too few rays find an edge.
fn imprint_circle(values: &[f32], w: usize, h: usize, start: [f64; 2], reach: f64, rays: usize) -> Option<([f64; 2], f64)> {
    const STEP: f64 = 0.5;
    let mut edge = Vec::with_capacity(rays);
    for k in 0..rays {
        let a = std::f64::consts::TAU * k as f64 / rays as f64;
        let (dy, dx) = a.sin_cos();
        let samples: Vec<f64> = (0..)
            .map(|n| 2.0 + n as f64 * STEP)
            .take_while(|t| *t <= reach)
            .map_while(|t| sample(values, w, h, start[0] + t * dx, start[1] + t * dy))
            .collect();
        if samples.len() < 5 {
            continue;
        }
        let deriv: Vec<f64> = samples.windows(3).map(|s| (s[2] - s[0]) / (2.0 * STEP)).collect();
        let (m, _) = deriv.iter().enumerate().fold((0, f64::MAX), |b, (i, &d)| if d < b.1 { (i, d) } else { b });
        if m == 0 || m + 1 >= deriv.len() {
            continue;
        }
        let (d0, d1, d2) = (deriv[m - 1], deriv[m], deriv[m + 1]);
        let denom = d0 - 2.0 * d1 + d2;
        let off = if denom.abs() > 1e-12 { (0.5 * (d0 - d2) / denom).clamp(-0.5, 0.5) } else { 0.0 };
        // deriv[m] is centred on sample m + 1.
        let t = 2.0 + (m as f64 + 1.0 + off) * STEP;
        edge.push([start[0] + t * dx, start[1] + t * dy]);
    }
    let fit = |pts: &[[f64; 2]]| -> Option<([f64; 2], f64)> {
        if pts.len() < 8 {
            return None;
        }
        // x^2 + y^2 + D x + E y + F = 0, least squares, around the points' mean.
        let n = pts.len() as f64;
        let mean = [pts.iter().map(|p| p[0]).sum::<f64>() / n, pts.iter().map(|p| p[1]).sum::<f64>() / n];
        let mut ata = [[0.0; 3]; 3];
        let mut atb = [0.0; 3];
        for p in pts {
            let (x, y) = (p[0] - mean[0], p[1] - mean[1]);
            let row = [x, y, 1.0];
            let b = -(x * x + y * y);
            for r in 0..3 {
                for c in 0..3 {
                    ata[r][c] += row[r] * row[c];
                }
                atb[r] += row[r] * b;
            }
        }
        let [d, e, f] = solve3(ata, atb)?;
        let c = [mean[0] - d / 2.0, mean[1] - e / 2.0];
        let r2 = d * d / 4.0 + e * e / 4.0 - f;
        (r2 > 0.0 && c.iter().all(|v| v.is_finite())).then(|| (c, r2.sqrt()))
    };
    let (c, r) = fit(&edge)?;
    let dist: Vec<f64> = edge.iter().map(|p| ((p[0] - c[0]).hypot(p[1] - c[1]) - r).abs()).collect();
    let mut sorted = dist.clone();
    sorted.sort_by(f64::total_cmp);
    let limit = (3.0 * 1.4826 * sorted[sorted.len() / 2]).max(1.0);
    let kept: Vec<[f64; 2]> = edge.iter().zip(&dist).filter(|(_, d)| **d <= limit).map(|(p, _)| *p).collect();
    fit(&kept)
}

/// Solves a 3 x 3 system by Cramer's rule; `None` when (nearly) singular.
fn solve3(a: [[f64; 3]; 3], b: [f64; 3]) -> Option<[f64; 3]> {
    let det = |m: [[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det(a);
    let scale = a.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
    if !(d.abs() > 1e-12 * scale.powi(3)) {
        return None;
    }
    let mut x = [0.0; 3];
    for (k, xk) in x.iter_mut().enumerate() {
        let mut m = a;
        for r in 0..3 {
            m[r][k] = b[r];
        }
        *xk = det(m) / d;
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// Centroid of the 4-connected region above `threshold` around `start`, each pixel weighted
/// by how far it passes the threshold; the start pixel's centre when the region is flat.
fn region_centroid(values: &[f32], w: usize, h: usize, start: usize, threshold: f64) -> ([f64; 2], usize) {
    let mut seen = vec![false; w * h];
    let region = flood_fill(values, w, h, start, threshold, &mut seen);
    let (mut su, mut sv, mut sw) = (0.0f64, 0.0f64, 0.0f64);
    for &i in &region {
        let (x, y) = (i % w, i / w);
        let weight = values[i] as f64 - threshold;
        su += weight * (x as f64 + 0.5);
        sv += weight * (y as f64 + 0.5);
        sw += weight;
    }
    if sw > 0.0 { ([su / sw, sv / sw], region.len()) } else { ([(start % w) as f64 + 0.5, (start / w) as f64 + 0.5], region.len()) }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn disc(w: u32, h: u32, cx: f64, cy: f64, r: f64) -> RgbImage {
        RgbImage::from_fn(w, h, |x, y| {
            // Anti-aliased disc: 4x4 samples per pixel.
            let mut hits = 0;
            for a in 0..4 {
                for b in 0..4 {
                    let (px, py) = (x as f64 + (a as f64 + 0.5) / 4.0, y as f64 + (b as f64 + 0.5) / 4.0);
                    if (px - cx).hypot(py - cy) < r {
                        hits += 1;
                    }
                }
            }
            let v = 20 + (hits * 200 / 16) as u8;
            image::Rgb([v, v, v])
        })
    }

    #[test]
    fn finds_a_disc_to_sub_pixel() {
        let reference = RgbImage::from_pixel(128, 96, image::Rgb([20, 20, 20]));
        for (cx, cy) in [(40.3, 50.7), (80.5, 30.25), (64.0, 48.0)] {
            let c = detect_contact(&disc(128, 96, cx, cy, 7.0), &reference, &DetectOptions::default()).unwrap();
            assert!((c.centroid_px[0] - cx).abs() < 0.1 && (c.centroid_px[1] - cy).abs() < 0.1, "{c} vs ({cx}, {cy})");
        }
    }

    /// Bright discs on a square lattice, pushed away from `centre` by a Gaussian-profile shift.
    fn pins(centre: Option<[f64; 2]>) -> RgbImage {
        let mut pos = Vec::new();
        for j in 0..9 {
            for i in 0..9 {
                let p = [16.0 + 20.0 * i as f64 + 3.0 * (j % 2) as f64, 16.0 + 20.0 * j as f64];
                let q = match centre {
                    Some(c) => {
                        let (dx, dy) = (p[0] - c[0], p[1] - c[1]);
                        let r = dx.hypot(dy).max(1e-9);
                        let shift = 4.0 * (r / 25.0) * (-(r * r) / (2.0 * 25.0 * 25.0)).exp();
                        [p[0] + shift * dx / r, p[1] + shift * dy / r]
                    }
                    None => p,
                };
                pos.push(q);
            }
        }
        RgbImage::from_fn(200, 200, |x, y| {
            let (px, py) = (x as f64 + 0.5, y as f64 + 0.5);
            let d = pos.iter().map(|q| (q[0] - px).hypot(q[1] - py)).fold(f64::MAX, f64::min);
            let v = (10.0 + 200.0 * (3.5 - d).clamp(0.0, 1.0)) as u8;
            image::Rgb([v, v, v])
        })
    }

    #[test]
    fn marker_field_points_at_the_contact() {
        let reference = pins(None);
        for c in [[100.0, 100.0], [83.3, 111.7], [120.4, 90.9]] {
            let got = detect_marker_contact(&pins(Some(c)), &reference, &MarkerOptions::default()).unwrap();
            assert!((got.centroid_px[0] - c[0]).hypot(got.centroid_px[1] - c[1]) < 0.3, "{got} vs {c:?}");
            assert!(got.moved_markers.unwrap() >= 8, "{got}");
        }
        assert!(matches!(
            detect_marker_contact(&reference, &reference, &MarkerOptions::default()),
            Err(DetectError::MarkersStill { moved: 0, .. })
        ));
        let blank = RgbImage::from_pixel(200, 200, image::Rgb([10, 10, 10]));
        assert!(matches!(detect_marker_contact(&blank, &blank, &MarkerOptions::default()), Err(DetectError::TooFewMarkers { .. })));
    }

    /// The pins of [`pins`] pressed at `c`, with the skin shaded as a press shades it: brighter
    /// on the side of the contact facing the light (up-left), by up to `shade` either way.
    fn shaded_pins(c: [f64; 2], shade: f64) -> RgbImage {
        let mut img = pins(Some(c));
        for (x, y, p) in img.enumerate_pixels_mut() {
            let (dx, dy) = (x as f64 + 0.5 - c[0], y as f64 + 0.5 - c[1]);
            let r2 = (dx * dx + dy * dy) / (30.0 * 30.0);
            // The slope of a smooth dent, towards the light at (-1, -1) / sqrt(2).
            let slope = -(dx + dy) / (30.0 * std::f64::consts::SQRT_2) * (-r2).exp();
            let gain = 1.0 + shade * slope;
            for v in p.0.iter_mut() {
                *v = (*v as f64 * gain).round().clamp(0.0, 255.0) as u8;
            }
        }
        img
    }

    /// Sub-pixel contacts under shading: a centroid of each pin's bright pixels follows the
    /// shading and locks to the pixel grid; the tracked displacements do not.
    #[test]
    fn marker_contact_is_not_pulled_by_shading_or_the_pixel_grid() {
        let reference = pins(None);
        let mut worst = 0.0f64;
        for c in [[100.3, 100.6], [83.7, 111.2], [120.45, 90.9], [95.5, 104.25]] {
            let got = detect_marker_contact(&shaded_pins(c, 0.3), &reference, &MarkerOptions::default()).unwrap();
            worst = worst.max((got.centroid_px[0] - c[0]).hypot(got.centroid_px[1] - c[1]));
        }
        assert!(worst < 0.15, "worst error {worst:.3} px");
    }

    /// A see-through skin: a background darker towards the rim under a radial gain, dark
    /// markers on a lattice, and a pressed disc (white, with a broad glow around it) centred
    /// at `c`.
    fn see_through(c: Option<[f64; 2]>, markers: bool) -> RgbImage {
        RgbImage::from_fn(256, 256, |x, y| {
            let (px, py) = (x as f64 + 0.5, y as f64 + 0.5);
            let rho = (px - 128.0).hypot(py - 128.0) / 128.0;
            let gain = 1.0 - 0.3 * rho * rho;
            let mut v = 170.0 - 70.0 * rho;
            if let Some(c) = c {
                let r = (px - c[0]).hypot(py - c[1]);
                let glow = 0.7 * (-(r - 20.0).max(0.0) / 15.0).exp();
                v += (240.0 - v) * glow;
                let inside = ((24.0 - r) / 3.0 + 0.5).clamp(0.0, 1.0);
                v += (252.0 - v) * inside;
            }
            let (mx, my) = ((px / 12.0).round() * 12.0, (py / 12.0).round() * 12.0);
            if markers && (px - mx).hypot(py - my) < 2.5 {
                v = 40.0;
            }
            let g = (v * gain) as u8;
            image::Rgb([g, g, g])
        })
    }

    #[test]
    fn imprint_outline_is_found_despite_the_gain_and_the_markers() {
        for markers in [false, true] {
            let reference = see_through(None, markers);
            let options =
                if markers { ImprintOptions { close_px: 2, ..ImprintOptions::with_markers(256) } } else { ImprintOptions::for_width(256) };
            for c in [[128.0, 128.0], [90.3, 150.6], [170.7, 101.2]] {
                let got = detect_imprint(&see_through(Some(c), markers), &reference, &options).unwrap();
                let err = (got.centroid_px[0] - c[0]).hypot(got.centroid_px[1] - c[1]);
                assert!(err < 0.3, "markers {markers}: {got} vs {c:?}: {err:.3} px");
                // The region centroid alone is pulled towards the brighter centre.
                let plain = detect_imprint(&see_through(Some(c), markers), &reference, &ImprintOptions { edge_rays: 0, ..options.clone() })
                    .unwrap();
                let plain_err = (plain.centroid_px[0] - c[0]).hypot(plain.centroid_px[1] - c[1]);
                if c != [128.0, 128.0] {
                    assert!(plain_err > 0.8, "markers {markers} {c:?}: region centroid {plain_err:.3} px");
                }
            }
            assert!(matches!(detect_imprint(&reference, &reference, &options), Err(DetectError::NoContact { .. })));
        }
    }

    #[test]
    fn no_contact_and_bad_sizes_are_errors() {
        let reference = RgbImage::from_pixel(64, 64, image::Rgb([20, 20, 20]));
        assert!(matches!(detect_contact(&reference, &reference, &DetectOptions::default()), Err(DetectError::NoContact { .. })));
        let other = RgbImage::new(32, 64);
        assert!(matches!(detect_contact(&other, &reference, &DetectOptions::default()), Err(DetectError::SizeMismatch { .. })));
        let empty = RgbImage::new(0, 0);
        assert_eq!(detect_contact(&empty, &empty, &DetectOptions::default()), Err(DetectError::Empty));
    }
}
