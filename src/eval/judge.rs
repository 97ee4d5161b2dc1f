//! Judging one pair: each method's image against the true one (SSIM, PSNR, MSE over the whole
//! frame and the contact region) and the pose errors of the contact estimated from it, with
//! what one real dataset's pairs share (`DatasetJudge`).

use image::RgbImage;

use super::baselines::{Collected, CollectedSensor};
use super::contact::{
    ContactEstimate, ContactEstimator, axis_difference_deg, contact_mask, estimate_contact_with, geometric_contact, yaw_observable,
};
use super::error::EvalError;
use super::pairing::{DatasetInfo, calibration_at, load_image, mesh_of, resized};
use super::records::{EvalCounts, Method, PairRecord};
use crate::calibration::model::Calibration;
use crate::dataset::{PoseRow, REFERENCE_FILE};
use crate::geometry::stl::Mesh;
use crate::metrics;
use crate::pose::Pose;

/// What every pair of one real dataset (and its synthetic twin) is judged with: the no-contact
/// reference, calibration and mesh at the measuring size, the sensor's contact estimator and
/// collected set.
pub(super) struct DatasetJudge<'a> {
    object: &'a str,
    sensor: &'a str,
    real: &'a DatasetInfo,
    synthetic: &'a DatasetInfo,
    settings: JudgeSettings,
    reference: RgbImage,
    calib: Calibration,
    mesh: Option<Mesh>,
    contact_depth_mm: f64,
    collected: Option<&'a CollectedSensor>,
    collected_references: &'a [Option<RgbImage>],
}

/// How the pairs of a dataset are judged.
#[derive(Debug, Clone, Copy)]
pub(super) struct JudgeSettings {
    /// Images are resized to this square size.
    pub size_px: u32,
    /// The contact region of a true image ([`contact_mask`]).
    pub mask_threshold: f64,
    pub mask_dilate_px: u32,
    /// The contact estimator every image of the sensor is judged by.
    pub estimator: ContactEstimator,
}

impl<'a> DatasetJudge<'a> {
    /// Reads what the pairs of `real` (object and sensor `key`) share. A calibration file the
    /// manifest names but that cannot be loaded is replaced by the default for the image size
    /// and counted.
    pub fn new(
        key: &'a (String, String),
        real: &'a DatasetInfo,
        synthetic: &'a DatasetInfo,
        collected: &'a Collected,
        settings: JudgeSettings,
        counts: &mut EvalCounts,
    ) -> Result<Self, EvalError> {
        let (object, sensor) = key;
        let size = settings.size_px;
        // Through the dataset rules: a symlinked or missing reference is not "no reference".
        let reference = match load_image(&real.dir, REFERENCE_FILE) {
            Err(EvalError::Dataset {
                source: crate::dataset::DatasetError::Confined(crate::confine::ConfineError::Missing { .. }),
                ..
            }) => {
                return Err(EvalError::NoReference { dir: real.dir.clone() });
            }
            other => other?,
        };
        let native = reference.dimensions();
        let reference = resized(reference, size);
        let calib = calibration_at(real, native, size).unwrap_or_else(|| {
            counts.default_calibration_for.push(format!("{object}/{sensor}"));
            Calibration::default_for(size, size)
        });
        Ok(Self {
            object,
            sensor,
            real,
            synthetic,
            settings,
            reference,
            calib,
            mesh: mesh_of(&real.dir, &real.manifest)?,
            contact_depth_mm: real.manifest.work_frame.map(|w| w.contact_depth_mm).unwrap_or(1.5),
            collected: collected.by_sensor.get(sensor),
            collected_references: &collected.references,
        })
    }

    /// Whether the collected (training) set has `pose` of this object: a seen pose, dropped.
    pub fn seen(&self, pose: &Pose) -> bool {
        self.collected.is_some_and(|c| c.has_pose(self.object, pose))
    }

    /// Judges one pair (`row` of the real dataset, `twin` of the synthetic one): counts it and
    /// what it lacks, and appends one record per method to `pairs`.
    pub fn judge(&self, row: &PoseRow, twin: &PoseRow, counts: &mut EvalCounts, pairs: &mut Vec<PairRecord>) -> Result<(), EvalError> {
        let (size, pose, estimator) = (self.settings.size_px, row.commanded(), &self.settings.estimator);
        let truth = load_image(&self.real.dir, &row.image)?;
        let model = load_image(&self.synthetic.dir, &twin.image)?;
        let (rd, sd) = (truth.dimensions(), model.dimensions());
        // Both sides are resized to `size` square; only the shape must agree (twins come at
        // the model's resolution by default).
        if u64::from(rd.0) * u64::from(sd.1) != u64::from(sd.0) * u64::from(rd.1) {
            return Err(EvalError::SizeMismatch {
                object: self.object.to_string(),
                sensor: self.sensor.to_string(),
                pose_id: row.pose_id,
                real_width: rd.0,
                real_height: rd.1,
                synthetic_width: sd.0,
                synthetic_height: sd.1,
            });
        }
        let (truth, model) = (resized(truth, size), resized(model, size));
        counts.pairs += 1;

        let mask = contact_mask(&truth, &self.reference, self.settings.mask_threshold, self.settings.mask_dilate_px);
        let mask = if mask.iter().any(|&m| m) { Some(mask) } else { None };
        if mask.is_none() {
            counts.no_contact_pixels += 1;
        }
        let geometric = self.mesh.as_ref().and_then(|m| {
            let object_pose = Pose { z_mm: pose.z_mm + self.contact_depth_mm, ..pose };
            geometric_contact(&crate::geometry::raster::render_depth(m, &object_pose, &self.calib, size, size, 2))
        });
        if geometric.is_none() {
            counts.no_geometric_contact += 1;
        }
        let truth_estimate = estimate_contact_with(&truth, &self.reference, estimator);
        let observable_from = geometric.or(truth_estimate);
        let yaw_observable = observable_from.is_some_and(|g| yaw_observable(&g, &self.calib, estimator, size as usize));
        if observable_from.is_some() && !yaw_observable {
            counts.yaw_unobservable += 1;
        }
        let pose_truth = PoseTruth { geometric, yaw_observable, truth_estimate, calib: self.calib.clone() };

        let pair_index = counts.pairs - 1;
        let mesh_contact = geometric.is_some();
        let record = |method: Method, i: ImageFigures, e: PoseErrors| PairRecord {
            pair: pair_index,
            object: self.object.to_string(),
            sensor: self.sensor.to_string(),
            pose_id: row.pose_id,
            x_mm: pose.x_mm,
            y_mm: pose.y_mm,
            z_mm: pose.z_mm,
            yaw_deg: pose.yaw_deg,
            method: method.label(),
            ssim: i.ssim,
            contact_ssim: i.contact_ssim,
            position_err_mm: e.position_mm,
            yaw_err_deg: e.yaw_deg,
            position_vs_true_mm: e.position_vs_true_mm,
            yaw_vs_true_deg: e.yaw_vs_true_deg,
            psnr_db: i.psnr_db,
            mse: i.mse,
            contact_psnr_db: i.contact_psnr_db,
            contact_mse: i.contact_mse,
            mesh_contact,
            yaw_observable,
        };
        let mut judge = |method: Method, image: &RgbImage| {
            let figures = image_figures(&truth, image, mask.as_deref());
            let errors = pose_errors(estimate_contact_with(image, &self.reference, estimator), &pose_truth, true);
            pairs.push(record(method, figures, errors));
        };
        judge(Method::Model, &model);
        if let Some(c) = self.collected
            && let Some(mean_image) = &c.mean
        {
            judge(Method::PoseBlind, mean_image);
            if let Some(nn) = c.nearest_image(self.object, &pose, &self.calib, size, self.collected_references)? {
                judge(Method::NearestNeighbour, &nn);
            }
        }
        pairs.push(record(Method::TrueImage, ImageFigures::default(), pose_errors(truth_estimate, &pose_truth, false)));
        Ok(())
    }
}

/// One image's similarity to its truth; `None` where not measured.
#[derive(Default)]
struct ImageFigures {
    ssim: Option<f64>,
    psnr_db: Option<f64>,
    mse: Option<f64>,
    contact_ssim: Option<f64>,
    contact_psnr_db: Option<f64>,
    contact_mse: Option<f64>,
}

/// One estimate's errors (see [`MethodRow`]); `None`: not measured.
#[derive(Default)]
struct PoseErrors {
    position_mm: Option<f64>,
    yaw_deg: Option<f64>,
    position_vs_true_mm: Option<f64>,
    yaw_vs_true_deg: Option<f64>,
}

/// What one pair gives the recoverability figures.
struct PoseTruth {
    geometric: Option<ContactEstimate>,
    yaw_observable: bool,
    truth_estimate: Option<ContactEstimate>,
    calib: Calibration,
}

/// SSIM, PSNR and MSE of `image` against `truth`, whole frame and (with a mask) contact region.
fn image_figures(truth: &RgbImage, image: &RgbImage, mask: Option<&[bool]>) -> ImageFigures {
    let (Ok(s), Ok(m)) = (metrics::ssim(truth, image), metrics::mse(truth, image)) else { return ImageFigures::default() };
    let mut out = ImageFigures {
        ssim: Some(s),
        psnr_db: Some(metrics::psnr(truth, image).unwrap_or(f64::INFINITY)),
        mse: Some(m),
        ..ImageFigures::default()
    };
    if let Some(mask) = mask
        && let (Ok(cs), Ok(cm)) = (metrics::ssim_masked(truth, image, mask), metrics::mse_masked(truth, image, mask))
    {
        out.contact_ssim = Some(cs);
        out.contact_psnr_db = Some(metrics::psnr_masked(truth, image, mask).unwrap_or(f64::INFINITY));
        out.contact_mse = Some(cm);
    }
    out
}

/// The pose errors of `estimate`: against the mesh contact, and (with `vs_true`) against the
/// true image's estimate.
fn pose_errors(estimate: Option<ContactEstimate>, truth: &PoseTruth, vs_true: bool) -> PoseErrors {
    let calib = &truth.calib;
    let distance = |e: &ContactEstimate, g: &ContactEstimate| {
        let (a, b) = (e.centroid_mm(calib), g.centroid_mm(calib));
        (a[0] - b[0]).hypot(a[1] - b[1])
    };
    let axis = |e: &ContactEstimate, g: &ContactEstimate| axis_difference_deg(e.axis_deg(calib), g.axis_deg(calib));
    let yaw_observable = truth.yaw_observable;
    let mut out = PoseErrors::default();
    if let (Some(g), Some(e)) = (&truth.geometric, &estimate) {
        out.position_mm = Some(distance(e, g));
        out.yaw_deg = yaw_observable.then(|| axis(e, g));
    }
    if vs_true && let (Some(e), Some(t)) = (&estimate, &truth.truth_estimate) {
        out.position_vs_true_mm = Some(distance(e, t));
        out.yaw_vs_true_deg = yaw_observable.then(|| axis(e, t));
    }
    out
}
