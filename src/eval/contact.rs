//! Contact estimation: where an image shows the contact (its centroid and second moments),
//! estimated from the change against the no-contact reference; the contact region the
//! contact metrics are measured over; and the contact the commanded pose gives the mesh.

// `!(a > b)` is deliberate here: a NaN must fail every check, which `a <= b` would not.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use image::RgbImage;
use serde::Serialize;

use crate::calibration::model::Calibration;
use crate::geometry::DepthMap;
use crate::imaging::{BoxBorder, box_blur, box_blur_repeated, dilate_mask, flood_fill, max_channel_difference};
use crate::sensor::SensorKind;

/// A contact region whose second moments have a smaller-to-larger eigenvalue ratio above this
/// is near-isotropic (a disc, a ring, a square): its orientation says nothing about yaw.
pub const ISOTROPY_RATIO: f64 = 0.5;

/// The contact region of a true image: pixels whose change from the reference (3 x 3 box
/// mean) exceeds `threshold` levels, dilated by `dilate_px` (square). Row-major, one entry per
/// pixel; sizes must match (else all false).
pub fn contact_mask(truth: &RgbImage, reference: &RgbImage, threshold: f64, dilate_px: u32) -> Vec<bool> {
    let (w, h) = (truth.width() as usize, truth.height() as usize);
    if truth.dimensions() != reference.dimensions() || w == 0 || h == 0 {
        return vec![false; w * h];
    }
    let mut change = max_channel_difference(truth, reference);
    box_blur(&mut change, w, h, 1, BoxBorder::Shrink);
    let core: Vec<bool> = change.iter().map(|&c| c as f64 > threshold).collect();
    if dilate_px == 0 {
        return core;
    }
    dilate_mask(&core, w, h, dilate_px as usize)
}

/// A contact region's weighted centroid and second central moments, in pixels (pixel (i, j)
/// is the point (i + 0.5, j + 0.5)).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContactEstimate {
    pub centroid_px: [f64; 2],
    /// Second central moments: [uu, uv, vv], px^2.
    pub moments_px2: [f64; 3],
}

impl ContactEstimate {
    fn from_weights(weights: impl Iterator<Item = (usize, f64)>, width: usize) -> Option<Self> {
        let (mut sw, mut su, mut sv, mut suu, mut suv, mut svv) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        for (i, wt) in weights {
            if !(wt > 0.0) || !wt.is_finite() {
                continue;
            }
            let (u, v) = ((i % width) as f64 + 0.5, (i / width) as f64 + 0.5);
            sw += wt;
            su += wt * u;
            sv += wt * v;
            suu += wt * u * u;
            suv += wt * u * v;
            svv += wt * v * v;
        }
        if !(sw > 0.0) {
            return None;
        }
        let (mu, mv) = (su / sw, sv / sw);
        let m = [suu / sw - mu * mu, suv / sw - mu * mv, svv / sw - mv * mv];
        let est = Self { centroid_px: [mu, mv], moments_px2: m };
        (mu.is_finite() && mv.is_finite() && m.iter().all(|v| v.is_finite())).then_some(est)
    }

    /// The centroid in sensor-frame mm through `calib`.
    pub fn centroid_mm(&self, calib: &Calibration) -> [f64; 2] {
        let (x, y) = calib.px_to_mm(self.centroid_px[0], self.centroid_px[1]);
        [x, y]
    }

    /// The second moments in sensor-frame mm^2 (the calibration's linear part applied), as
    /// [xx, xy, yy].
    fn moments_mm2(&self, calib: &Calibration) -> [f64; 3] {
        // px_to_mm is linear: J = diag(1/sx, 1/sy) R(-rotation).
        let (s, c) = calib.rotation_deg.to_radians().sin_cos();
        let j =
            [[c / calib.scale_px_per_mm[0], s / calib.scale_px_per_mm[0]], [-s / calib.scale_px_per_mm[1], c / calib.scale_px_per_mm[1]]];
        let m = [[self.moments_px2[0], self.moments_px2[1]], [self.moments_px2[1], self.moments_px2[2]]];
        let mut jm = [[0.0; 2]; 2];
        for r in 0..2 {
            for k in 0..2 {
                jm[r][k] = j[r][0] * m[0][k] + j[r][1] * m[1][k];
            }
        }
        let mut out = [[0.0; 2]; 2];
        for r in 0..2 {
            for k in 0..2 {
                out[r][k] = jm[r][0] * j[k][0] + jm[r][1] * j[k][1];
            }
        }
        [out[0][0], out[0][1], out[1][1]]
    }

    /// Orientation of the principal axis in the sensor frame, degrees in (-90, 90].
    pub fn axis_deg(&self, calib: &Calibration) -> f64 {
        let [xx, xy, yy] = self.moments_mm2(calib);
        0.5 * (2.0 * xy).atan2(xx - yy).to_degrees()
    }

    /// Standard deviation along the contact's longer axis, image pixels (the larger
    /// eigenvalue of the pixel moments, square-rooted): how far the contact extends.
    pub fn major_std_px(&self) -> f64 {
        let [xx, xy, yy] = self.moments_px2;
        let d = (((xx - yy) / 2.0).powi(2) + xy * xy).sqrt();
        ((xx + yy) / 2.0 + d).max(0.0).sqrt()
    }

    /// Smaller over larger eigenvalue of the moments in mm^2: 1 for a disc, 0 for a line.
    pub fn isotropy(&self, calib: &Calibration) -> f64 {
        let [xx, xy, yy] = self.moments_mm2(calib);
        let mean = (xx + yy) / 2.0;
        let d = (((xx - yy) / 2.0).powi(2) + xy * xy).sqrt();
        let (lo, hi) = (mean - d, mean + d);
        if hi > 0.0 { (lo / hi).clamp(0.0, 1.0) } else { 1.0 }
    }
}

/// Whether a contact's orientation can be read from an image judged by `estimator` at
/// `width_px`: it is elongated (eigenvalue ratio below [`ISOTROPY_RATIO`]) and it extends
/// beyond the estimator's blur (its longer-axis spread at least [`ContactEstimator::blur_std_px`]).
/// A contact of a pixel or two, a cone's tip touched lightly, has a "long axis" by
/// rasterisation alone; no image of it shows one.
pub fn yaw_observable(contact: &ContactEstimate, calib: &Calibration, estimator: &ContactEstimator, width_px: usize) -> bool {
    contact.isotropy(calib) < ISOTROPY_RATIO && contact.major_std_px() >= estimator.blur_std_px(width_px)
}

/// Angle between two axes (mod 180), degrees in [0, 90].
pub fn axis_difference_deg(a_deg: f64, b_deg: f64) -> f64 {
    let d = (a_deg - b_deg).rem_euclid(180.0);
    d.min(180.0 - d)
}

/// How [`estimate_contact_with`] finds the contact in an image: the blur that turns the change
/// from the reference into a smooth field, and how far above the noise floor the region starts.
/// Each sensor kind has its own ([`Self::for_sensor`]), chosen on the true images of the
/// training collection only (never on a model's images, never on a test set); the guide,
/// `docs/src/evaluation.md`, "Choosing the estimator". Every method's image of a sensor is judged by the same one.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ContactEstimator {
    /// Box-blur radius as a divisor of the image width (radius `width / blur_divisor` rounded
    /// down, at least 1 px), applied three times.
    pub blur_divisor: f64,
    /// The region is the connected pixels around the strongest change above
    /// `floor + region_fraction (peak - floor)`; 0: everything above the noise floor.
    pub region_fraction: f64,
}

impl ContactEstimator {
    /// Any image: radius `size / 64`, region above `floor + 0.3 (peak - floor)`. Used for
    /// sensors rig does not know.
    pub const GENERIC: Self = Self { blur_divisor: 64.0, region_fraction: 0.3 };
    /// TacTip: the contact shows only as marker motion, scattered pins with no sharp peak, so
    /// the region is everything above the noise floor.
    pub const TACTIP: Self = Self { blur_divisor: 32.0, region_fraction: 0.0 };
    /// ViTac: the see-through skin shows the object itself, with a sharp edge: the least blur.
    pub const VITAC: Self = Self { blur_divisor: 128.0, region_fraction: 0.4 };
    /// ViTacTip: see-through skin with markers.
    pub const VITACTIP: Self = Self { blur_divisor: 128.0, region_fraction: 0.3 };

    /// The estimator of a sensor, by its dataset name (`TacTip`, `vitac`, ...); `GENERIC` for
    /// a name rig does not know.
    pub fn for_sensor(sensor: &str) -> Self {
        match sensor.parse::<SensorKind>() {
            Ok(SensorKind::TacTip) => Self::TACTIP,
            Ok(SensorKind::ViTac) => Self::VITAC,
            Ok(SensorKind::ViTacTip) => Self::VITACTIP,
            Err(_) => Self::GENERIC,
        }
    }

    /// Box-blur radius at an image width, px: `width / blur_divisor` rounded down, at least 1.
    pub fn blur_radius_px(&self, width_px: usize) -> usize {
        ((width_px as f64 / self.blur_divisor) as usize).max(1)
    }

    /// Standard deviation of the estimator's blur at an image width, px: three box blurs of
    /// radius r spread a point by sqrt(r (r + 1)) (each box has variance r (r + 1) / 3).
    pub fn blur_std_px(&self, width_px: usize) -> f64 {
        let r = self.blur_radius_px(width_px) as f64;
        (r * (r + 1.0)).sqrt()
    }

    /// Parses `DIVISOR,FRACTION` (`rig eval --estimator 64,0.3`).
    pub fn parse(text: &str) -> Result<Self, EstimatorParseError> {
        let bad = || EstimatorParseError { text: text.to_string() };
        let (d, f) = text.split_once(',').ok_or_else(bad)?;
        let (blur_divisor, region_fraction): (f64, f64) = (d.trim().parse().map_err(|_| bad())?, f.trim().parse().map_err(|_| bad())?);
        if !(blur_divisor >= 1.0 && blur_divisor.is_finite() && (0.0..1.0).contains(&region_fraction)) {
            return Err(bad());
        }
        Ok(Self { blur_divisor, region_fraction })
    }
}

/// A contact estimator that does not parse ([`ContactEstimator::parse`]).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{text:?}: expected BLUR_DIVISOR,REGION_FRACTION, e.g. 64,0.3 (divisor >= 1, fraction in [0, 1))")]
pub struct EstimatorParseError {
    pub text: String,
}

/// The change map blurred three times by a box of `radius` px.
fn smoothed_change(change: &[f32], w: usize, h: usize, radius: usize) -> Vec<f32> {
    let mut out = change.to_vec();
    box_blur_repeated(&mut out, w, h, radius, 3, BoxBorder::Shrink);
    out
}

/// The noise floor of a change map: median + 4 median absolute deviations (the upper median,
/// element `len / 2` in order, found by selection rather than a full sort: the estimator
/// computes it for every image judged, once or twice).
fn noise_floor(change: &[f32]) -> f64 {
    let mut values = change.to_vec();
    let mid = values.len() / 2;
    let median = *values.select_nth_unstable_by(mid, f32::total_cmp).1 as f64;
    let mut dev: Vec<f64> = change.iter().map(|&v| (v as f64 - median).abs()).collect();
    median + 4.0 * *dev.select_nth_unstable_by(mid, f64::total_cmp).1
}

/// [`estimate_contact_with`] the generic estimator.
pub fn estimate_contact(image: &RgbImage, reference: &RgbImage) -> Option<ContactEstimate> {
    estimate_contact_with(image, reference, &ContactEstimator::GENERIC)
}

/// Estimates the contact in `image` against the no-contact `reference` (same size). Whether
/// there is a contact is decided one way for every estimator: the change (largest channel
/// difference) box-blurred three times at radius `size / 64` (at least 1 px) must peak at
/// least 3 levels above its noise floor (median + 4 MADs). Where it is, the change is blurred
/// at `estimator`'s radius, and the connected region around its strongest change above
/// `floor + region_fraction (peak - floor)` is weighted by how far it rises above that.
/// `None` when there is no contact, or on a size mismatch or an empty image.
pub fn estimate_contact_with(image: &RgbImage, reference: &RgbImage, estimator: &ContactEstimator) -> Option<ContactEstimate> {
    let (w, h) = (image.width() as usize, image.height() as usize);
    if image.dimensions() != reference.dimensions() || w == 0 || h == 0 {
        return None;
    }
    let raw = max_channel_difference(image, reference);
    let gate_radius = (w / 64).max(1);
    let gate = smoothed_change(&raw, w, h, gate_radius);
    let gate_peak = gate.iter().fold(f32::MIN, |b, &v| b.max(v)) as f64;
    if !(gate_peak - noise_floor(&gate) >= 3.0) {
        return None;
    }
    let radius = estimator.blur_radius_px(w);
    let change = if radius == gate_radius { gate } else { smoothed_change(&raw, w, h, radius) };
    let floor = noise_floor(&change);
    let (peak_i, peak) = change.iter().enumerate().fold((0, f32::MIN), |b, (i, &v)| if v > b.1 { (i, v) } else { b });
    let peak = peak as f64;
    let threshold = floor + estimator.region_fraction * (peak - floor);
    let region = flood_fill(&change, w, h, peak_i, threshold, &mut vec![false; w * h]);
    let est = ContactEstimate::from_weights(region.iter().map(|&i| (i, change[i] as f64 - threshold)), w);
    // A flat top exactly at the threshold: the peak pixel alone.
    est.or_else(|| ContactEstimate::from_weights(std::iter::once((peak_i, 1.0)), w))
}

/// The contact the commanded pose gives the mesh: the pixels where the object rises above the
/// undeformed skin (depth map through the calibration), weighted by the indentation.
pub fn geometric_contact(depth: &DepthMap) -> Option<ContactEstimate> {
    let w = depth.width as usize;
    if w == 0 {
        return None;
    }
    ContactEstimate::from_weights(depth.height_mm.iter().enumerate().map(|(i, &h)| (i, h as f64)), w)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::test_images::disc;
    use image::Rgb;

    #[test]
    fn estimate_finds_a_disc_and_an_ellipse_axis() {
        let reference = RgbImage::from_pixel(96, 96, Rgb([20, 20, 20]));
        let calib = Calibration::default_for(96, 96);
        let e = estimate_contact(&disc(96, 40.0, 55.0, 8.0, 8.0), &reference).unwrap();
        assert!((e.centroid_px[0] - 40.0).abs() < 0.3 && (e.centroid_px[1] - 55.0).abs() < 0.3, "{e:?}");
        assert!(e.isotropy(&calib) > 0.9);
        let wide = estimate_contact(&disc(96, 48.0, 48.0, 20.0, 5.0), &reference).unwrap();
        assert!(axis_difference_deg(wide.axis_deg(&calib), 0.0) < 1.0, "{}", wide.axis_deg(&calib));
        assert!(wide.isotropy(&calib) < ISOTROPY_RATIO);
        // Blank and mismatched images give no estimate, never a panic or a NaN.
        assert!(estimate_contact(&reference, &reference).is_none());
        assert!(estimate_contact(&RgbImage::new(10, 96), &reference).is_none());
        assert!(estimate_contact(&RgbImage::new(0, 0), &RgbImage::new(0, 0)).is_none());
    }

    #[test]
    fn the_blur_spread_is_what_three_box_blurs_give() {
        // A point, blurred as the estimator blurs: its spread along x is sqrt(r (r + 1)).
        let (w, h) = (64, 64);
        for (divisor, r) in [(32.0, 2usize), (16.0, 4), (128.0, 1)] {
            let estimator = ContactEstimator { blur_divisor: divisor, region_fraction: 0.0 };
            assert_eq!(estimator.blur_radius_px(w), r);
            let mut point = vec![0.0f32; w * h];
            point[32 * w + 32] = 1.0;
            let blurred = smoothed_change(&point, w, h, r);
            let (mut sum, mut sxx) = (0.0f64, 0.0f64);
            for (i, &v) in blurred.iter().enumerate() {
                let dx = (i % w) as f64 - 32.0;
                sum += v as f64;
                sxx += v as f64 * dx * dx;
            }
            let std = (sxx / sum).sqrt();
            assert!((std - estimator.blur_std_px(w)).abs() < 1e-3, "r {r}: {std} vs {}", estimator.blur_std_px(w));
        }
    }

    #[test]
    fn a_contact_of_a_pixel_or_two_has_no_observable_yaw() {
        let calib = Calibration::default_for(128, 128);
        let line = |len: usize| ContactEstimate::from_weights((0..len).map(|k| (64 * 128 + 40 + k, 1.0)), 128).unwrap();
        // Two lit pixels side by side (a cone's tip touched lightly): a "line" by rasterisation.
        let tip = line(2);
        assert!(tip.isotropy(&calib) < ISOTROPY_RATIO);
        assert!((tip.major_std_px() - 0.5).abs() < 1e-9, "{}", tip.major_std_px());
        for estimator in [ContactEstimator::TACTIP, ContactEstimator::VITAC, ContactEstimator::VITACTIP, ContactEstimator::GENERIC] {
            assert!(!yaw_observable(&tip, &calib, &estimator, 128), "{estimator:?}");
        }
        // Nine pixels (spread 2.58 px) outlast ViTac's blur (1.41) but not TacTip's (4.47).
        let short = line(9);
        assert!(yaw_observable(&short, &calib, &ContactEstimator::VITAC, 128));
        assert!(!yaw_observable(&short, &calib, &ContactEstimator::TACTIP, 128));
        // A long edge is observable through every estimator; a disc through none.
        let edge = line(40);
        for estimator in [ContactEstimator::TACTIP, ContactEstimator::VITAC, ContactEstimator::VITACTIP, ContactEstimator::GENERIC] {
            assert!(yaw_observable(&edge, &calib, &estimator, 128), "{estimator:?}");
        }
        let reference = RgbImage::from_pixel(128, 128, Rgb([20, 20, 20]));
        let round = estimate_contact(&disc(128, 64.0, 64.0, 20.0, 20.0), &reference).unwrap();
        assert!(!yaw_observable(&round, &calib, &ContactEstimator::VITAC, 128));
    }

    #[test]
    fn each_sensor_has_its_estimator_and_the_flag_parses() {
        assert_eq!(ContactEstimator::for_sensor("TacTip"), ContactEstimator::TACTIP);
        assert_eq!(ContactEstimator::for_sensor("vitac"), ContactEstimator::VITAC);
        assert_eq!(ContactEstimator::for_sensor("ViTacTip"), ContactEstimator::VITACTIP);
        assert_eq!(ContactEstimator::for_sensor("gelsight"), ContactEstimator::GENERIC);
        assert_eq!(ContactEstimator::parse(" 64, 0.3"), Ok(ContactEstimator::GENERIC));
        assert_eq!(ContactEstimator::parse("128,0"), Ok(ContactEstimator { blur_divisor: 128.0, region_fraction: 0.0 }));
        for bad in ["64", "0,0.3", "64,1", "64,-0.1", "x,0.3", "inf,0.3", "64,NaN", ""] {
            assert!(ContactEstimator::parse(bad).is_err(), "{bad}");
        }
    }

    /// TacTip-like: 2 x 2 px white pins every 6 px on black (pin (63, 63) centred on (64, 64));
    /// inside an ellipse around that pin (half-axes 24 x 7 px, turned by `turn_deg`) each pin
    /// has moved 2 px in x.
    fn pins(size: u32, turn_deg: f64, pressed: bool) -> RgbImage {
        let (s, c) = turn_deg.to_radians().sin_cos();
        let centre = 63.0;
        let mut img = RgbImage::from_pixel(size, size, Rgb([10, 10, 10]));
        for gy in (3..size).step_by(6) {
            for gx in (3..size).step_by(6) {
                let (dx, dy) = (gx as f64 - centre, gy as f64 - centre);
                let (u, v) = ((c * dx + s * dy) / 24.0, (-s * dx + c * dy) / 7.0);
                let shift = if pressed && u * u + v * v < 1.0 { 2 } else { 0 };
                for (px, py) in [(gx + shift, gy), (gx + shift + 1, gy), (gx + shift, gy + 1), (gx + shift + 1, gy + 1)] {
                    if px < size && py < size {
                        img.put_pixel(px, py, Rgb([230, 230, 230]));
                    }
                }
            }
        }
        img
    }

    #[test]
    fn marker_estimator_finds_the_axis_of_scattered_pin_motion() {
        let size = 128;
        let calib = Calibration::default_for(size, size);
        let reference = pins(size, 0.0, false);
        for turn in [0.0, 30.0, -60.0] {
            let e = estimate_contact_with(&pins(size, turn, true), &reference, &ContactEstimator::TACTIP).unwrap();
            // Image y points down, so the image-frame turn shows as -turn in the x-up sensor frame
            // of the default calibration, or +turn: either way 1 deg of the axis, mod 180.
            let axis = e.axis_deg(&calib);
            let off = axis_difference_deg(axis, turn).min(axis_difference_deg(axis, -turn));
            assert!(off < 4.0, "turn {turn}: axis {axis}");
            assert!(e.isotropy(&calib) < ISOTROPY_RATIO, "turn {turn}: {}", e.isotropy(&calib));
            // Half-way between where the pins were and where they went: (65, 64).
            assert!((e.centroid_px[0] - 65.0).abs() < 1.5 && (e.centroid_px[1] - 64.0).abs() < 1.5, "turn {turn}: {e:?}");
        }
    }

    #[test]
    fn region_fraction_sets_how_much_of_a_soft_contact_counts() {
        let size = 96;
        let reference = RgbImage::from_pixel(size, size, Rgb([20, 20, 20]));
        // A Gaussian bump: the lower the threshold, the wider the region and its moments.
        let bump = RgbImage::from_fn(size, size, |x, y| {
            let r2 = (x as f64 - 48.0).powi(2) + (y as f64 - 40.0).powi(2);
            let v = 20.0 + 150.0 * (-r2 / (2.0 * 8.0f64.powi(2))).exp();
            Rgb([v as u8; 3])
        });
        let spread = |fraction: f64| {
            let e = estimate_contact_with(&bump, &reference, &ContactEstimator { blur_divisor: 64.0, region_fraction: fraction }).unwrap();
            assert!((e.centroid_px[0] - 48.0).abs() < 0.5 && (e.centroid_px[1] - 40.0).abs() < 0.5, "{fraction}: {e:?}");
            e.moments_px2[0] + e.moments_px2[2]
        };
        let (wide, mid, narrow) = (spread(0.0), spread(0.3), spread(0.7));
        assert!(wide > mid && mid > narrow, "{wide} {mid} {narrow}");
    }

    #[test]
    fn whether_there_is_a_contact_is_decided_alike_for_every_estimator() {
        let size = 128;
        let reference = RgbImage::from_pixel(size, size, Rgb([40, 40, 40]));
        // One hot pixel, 60 levels up: no contact. Blurred at radius 1 it still stands 4 levels
        // above the floor; at the shared gate's radius 2 only about 1.4.
        let mut noisy = reference.clone();
        noisy.put_pixel(70, 30, Rgb([100, 100, 100]));
        for estimator in [ContactEstimator::GENERIC, ContactEstimator::TACTIP, ContactEstimator::VITAC, ContactEstimator::VITACTIP] {
            assert!(estimate_contact_with(&noisy, &reference, &estimator).is_none(), "{estimator:?}");
            assert!(estimate_contact_with(&reference, &reference, &estimator).is_none(), "{estimator:?}");
            assert!(
                estimate_contact_with(&disc(size, 50.0, 70.0, 9.0, 9.0), &RgbImage::from_pixel(size, size, Rgb([20, 20, 20])), &estimator)
                    .is_some()
            );
        }
    }

    #[test]
    fn axis_difference_wraps_mod_180() {
        assert!((axis_difference_deg(89.0, -89.0) - 2.0).abs() < 1e-12);
        assert!((axis_difference_deg(10.0, 40.0) - 30.0).abs() < 1e-12);
        assert!((axis_difference_deg(0.0, 180.0)).abs() < 1e-12);
    }

    #[test]
    fn mask_dilates_and_ignores_mismatched_sizes() {
        let reference = RgbImage::from_pixel(32, 32, Rgb([20, 20, 20]));
        let mut truth = reference.clone();
        for y in 14..18 {
            for x in 14..18 {
                truth.put_pixel(x, y, Rgb([120, 120, 120]));
            }
        }
        let core = contact_mask(&truth, &reference, 10.0, 0).iter().filter(|&&m| m).count();
        let dilated = contact_mask(&truth, &reference, 10.0, 2).iter().filter(|&&m| m).count();
        assert!(core >= 16 && dilated > core, "{core} {dilated}");
        assert!(contact_mask(&reference, &reference, 10.0, 2).iter().all(|&m| !m));
        assert!(contact_mask(&RgbImage::new(8, 8), &reference, 10.0, 2).iter().all(|&m| !m));
    }
}
