//! The baselines a model is judged beside: the pose-blind mean of the sensor's collected
//! images, and the nearest collected pose's image moved to the test pose.

use std::collections::BTreeMap;
use std::path::PathBuf;

use glam::DVec2;
use image::RgbImage;

use super::error::EvalError;
use super::pairing::{DatasetInfo, load_at, same_pose};
use crate::calibration::model::Calibration;
use crate::dataset::REFERENCE_FILE;
use crate::imaging::MeanImage;
use crate::pose::Pose;

/// Yaw difference that counts as much as 1 mm in [`pose_distance`], degrees.
pub const NN_YAW_DEG_PER_MM: f64 = 15.0;

/// The nearest-neighbour distance: Euclidean mm over x, y, z plus the smallest yaw difference
/// over [`NN_YAW_DEG_PER_MM`] (15 degrees weigh as 1 mm).
pub fn pose_distance(a: &Pose, b: &Pose) -> f64 {
    a.distance_mm(b) + a.yaw_error_deg(b) / NN_YAW_DEG_PER_MM
}

/// Moves the contact of `image` (taken at pose `from`) to where pose `to` would put it: the
/// change of `image` from its no-contact `reference` is resampled (bilinear) through the
/// rigid motion that takes the object from `from` to `to` under `calib` (translation by the
/// x/y difference in mm, rotation by the yaw difference, as [`object_to_pixel`] maps them),
/// and added back onto `reference`; where the motion reaches outside the image the change is
/// zero, so the reference shows. The sensor's static background is not moved, and the z
/// difference is ignored.
///
/// [`object_to_pixel`]: crate::geometry::raster::object_to_pixel
pub fn warp_to_pose(image: &RgbImage, reference: &RgbImage, from: &Pose, to: &Pose, calib: &Calibration) -> RgbImage {
    if image.dimensions() != reference.dimensions() {
        return reference.clone();
    }
    let (w, h) = image.dimensions();
    let a_from = crate::geometry::raster::object_to_pixel(from, calib);
    let a_to = crate::geometry::raster::object_to_pixel(to, calib);
    let to_source = a_from * a_to.inverse();
    let diff: Vec<f32> = image.as_raw().iter().zip(reference.as_raw()).map(|(&a, &b)| a as f32 - b as f32).collect();
    let at = |x: i64, y: i64, k: usize| -> f32 {
        if x < 0 || y < 0 || x >= w as i64 || y >= h as i64 { 0.0 } else { diff[(y as usize * w as usize + x as usize) * 3 + k] }
    };
    let mut out = reference.clone();
    for (x, y, px) in out.enumerate_pixels_mut() {
        let q = to_source.transform_point2(DVec2::new(x as f64 + 0.5, y as f64 + 0.5)) - DVec2::splat(0.5);
        if !q.is_finite() {
            continue;
        }
        let (x0, y0) = (q.x.floor(), q.y.floor());
        let (fx, fy) = ((q.x - x0) as f32, (q.y - y0) as f32);
        let (x0, y0) = (x0 as i64, y0 as i64);
        for k in 0..3 {
            let d = at(x0, y0, k) * (1.0 - fx) * (1.0 - fy)
                + at(x0 + 1, y0, k) * fx * (1.0 - fy)
                + at(x0, y0 + 1, k) * (1.0 - fx) * fy
                + at(x0 + 1, y0 + 1, k) * fx * fy;
            px.0[k] = (px.0[k] as f32 + d).round().clamp(0.0, 255.0) as u8;
        }
    }
    out
}

/// A collected (training) image's pose and where to find it.
pub(super) struct CollectedPose {
    object: String,
    pose: Pose,
    /// The dataset folder and the image's path below it.
    dir: PathBuf,
    image: String,
    /// Index into the collected datasets (for their reference frames).
    dataset: usize,
}

/// The collected set of one sensor: poses, the mean image, and loaded images on demand.
pub(super) struct CollectedSensor {
    pub poses: Vec<CollectedPose>,
    /// The pose-blind baseline: the mean of the sensor's collected images.
    pub mean: Option<RgbImage>,
}

/// The collected (training) set at the measuring size.
pub(super) struct Collected {
    /// Per sensor: poses and the pose-blind mean image.
    pub by_sensor: BTreeMap<String, CollectedSensor>,
    /// Each collected dataset's `reference.png`, when it has one.
    pub references: Vec<Option<RgbImage>>,
    /// Collected images (real rows).
    pub images: usize,
}

impl Collected {
    /// Lists the real rows of `sets` per sensor and averages their images (each read once).
    pub fn load(sets: &[DatasetInfo], size: u32) -> Result<Self, EvalError> {
        let mut by_sensor: BTreeMap<String, CollectedSensor> = BTreeMap::new();
        let mut references = Vec::new();
        for (index, d) in sets.iter().enumerate() {
            references.push(load_at(&d.dir, REFERENCE_FILE, size).ok());
            let (object, sensor) = d.key();
            let entry = by_sensor.entry(sensor).or_insert_with(|| CollectedSensor { poses: Vec::new(), mean: None });
            for r in d.captured_rows() {
                entry.poses.push(CollectedPose {
                    object: object.clone(),
                    pose: r.commanded(),
                    dir: d.dir.clone(),
                    image: r.image.clone(),
                    dataset: index,
                });
            }
        }
        let mut images = 0;
        for sensor in by_sensor.values_mut() {
            let mut mean = MeanImage::new(size, size);
            for p in &sensor.poses {
                mean.add(&load_at(&p.dir, &p.image, size)?);
            }
            images += sensor.poses.len();
            sensor.mean = mean.image();
        }
        Ok(Self { by_sensor, references, images })
    }
}

impl CollectedSensor {
    /// Whether the set has `pose` of `object` ([`same_pose`]).
    pub fn has_pose(&self, object: &str, pose: &Pose) -> bool {
        self.poses.iter().any(|p| p.object == object && same_pose(&p.pose, pose))
    }

    /// The collected pose nearest to `pose` by [`pose_distance`]: among `object`'s when there
    /// are any, else among all of the sensor's.
    fn nearest(&self, object: &str, pose: &Pose) -> Option<&CollectedPose> {
        let same: Vec<&CollectedPose> = self.poses.iter().filter(|p| p.object == object).collect();
        let pool: Vec<&CollectedPose> = if same.is_empty() { self.poses.iter().collect() } else { same };
        pool.into_iter().min_by(|a, b| pose_distance(&a.pose, pose).total_cmp(&pose_distance(&b.pose, pose)))
    }

    /// The nearest-neighbour baseline at `pose`: the nearest collected image at `size`, its
    /// contact moved to `pose` ([`warp_to_pose`]) over its dataset's reference (`references`,
    /// by dataset; the pose-blind mean where that dataset has none). `None` for an empty set.
    pub fn nearest_image(
        &self,
        object: &str,
        pose: &Pose,
        calib: &Calibration,
        size: u32,
        references: &[Option<RgbImage>],
    ) -> Result<Option<RgbImage>, EvalError> {
        let (Some(nn), Some(mean)) = (self.nearest(object, pose), &self.mean) else { return Ok(None) };
        let img = load_at(&nn.dir, &nn.image, size)?;
        let nn_reference = references.get(nn.dataset).cloned().flatten().unwrap_or_else(|| mean.clone());
        Ok(Some(warp_to_pose(&img, &nn_reference, &nn.pose, pose, calib)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::contact::{axis_difference_deg, estimate_contact};
    use crate::eval::test_images::disc;
    use image::Rgb;

    #[test]
    fn warp_moves_the_contact_by_the_pose_difference() {
        let size = 96;
        let calib = Calibration::default_for(size, size);
        let reference = RgbImage::from_pixel(size, size, Rgb([20, 20, 20]));
        // An object point at the reference point appears at -t (sensor at t, yaw 0).
        let from = Pose::new(0.0, 0.0, 0.0, 0.0);
        let to = Pose::new(-4.0, 2.0, 0.0, 0.0);
        let (u, v) = calib.mm_to_px(0.0, 0.0);
        let src = disc(size, u, v, 5.0, 5.0);
        let warped = warp_to_pose(&src, &reference, &from, &to, &calib);
        let (u2, v2) = calib.mm_to_px(4.0, -2.0);
        let e = estimate_contact(&warped, &reference).unwrap();
        assert!((e.centroid_px[0] - u2).abs() < 0.5 && (e.centroid_px[1] - v2).abs() < 0.5, "{e:?} vs ({u2}, {v2})");
        // No pose difference: the image itself.
        assert_eq!(warp_to_pose(&src, &reference, &from, &from, &calib), src);
        // A yaw difference turns an elongated contact about the sensor centre.
        let bar = disc(size, size as f64 / 2.0, size as f64 / 2.0, 20.0, 4.0);
        let turned = warp_to_pose(&bar, &reference, &from, &Pose::new(0.0, 0.0, 0.0, 30.0), &calib);
        let e = estimate_contact(&turned, &reference).unwrap();
        assert!(axis_difference_deg(e.axis_deg(&calib), -30.0) < 2.0, "{}", e.axis_deg(&calib));
    }
}
