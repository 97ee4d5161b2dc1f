//! `rig eval`: how close synthetic tactile images are to real ones, beside two baselines.
//!
//! Data flow: [`evaluate`] finds the datasets under the real, synthetic and collected roots
//! (a dataset, or a folder of `<object>/<sensor>` datasets), pairs real and synthetic datasets
//! by object and sensor, then their rows by commanded pose (x, y, z, yaw equal within
//! [`POSE_TOLERANCE`]). Real side: rows `source=real`; synthetic side: rows `source=synthetic`.
//! A pose the collected (training) set also has for that object and sensor is dropped and
//! counted, so what is left is unseen. Every image is resized to `size_px` square (bilinear)
//! before anything is measured.
//!
//! For each pair four images are judged against the true (real) one:
//!
//! - **model**: the synthetic image;
//! - **pose-blind**: the mean of the sensor's collected images (any object, any pose);
//! - **nearest-neighbour**: the collected image of the closest pose ([`pose_distance`]: mm of
//!   x, y, z plus |yaw difference| / 15 deg; the same object when the collected set has it,
//!   else any object of that sensor), its change from its own no-contact reference moved
//!   rigidly by the pose difference ([`warp_to_pose`]) and added back onto that reference;
//! - **true image**: the real image itself, only for pose recoverability (the estimator's own
//!   error, the floor).
//!
//! Metrics ([`crate::metrics`]): SSIM, PSNR and MSE over the whole frame, and over the contact
//! region ([`contact_mask`]: pixels where the true image differs from its dataset's
//! `reference.png`). Pose recoverability ([`estimate_contact_with`] and the sensor's
//! [`ContactEstimator`], the same for every method's image): the contact's centroid and
//! principal axis, estimated from an image's change against the reference, compared with the
//! contact the commanded pose gives the object's mesh through the calibration
//! ([`geometric_contact`]), in mm and degrees, and with the estimate from the true image of the
//! same pose. [`EvalReport::to_markdown`] prints the table; the report is also `Serialize`.
//!
//! Means over different poses can mislead: a baseline that finds no contact on the hardest
//! poses is averaged over easier ones. [`paired_comparisons`] therefore also sets the model
//! against each baseline pose by pose, over the poses where both have the figure, with a 95%
//! bootstrap interval of the mean difference and a verdict only where it excludes 0. Each
//! comparison also carries its [`Ceiling`]: the same comparison with the true image in the
//! model's place, which says whether any model could beat that baseline on that test set (a
//! baseline at the estimator's floor cannot be beaten, only matched).
//! [`EvalReport::pairs`] keeps every per-pose figure (`rig eval --pairs`).
//!
//! Nothing here panics on odd images: a blank image has no contact estimate (counted), an
//! empty mask skips the contact metrics for that pose (counted), and the table says `n/a`
//! where a figure has no data.

// `!(a > b)` is deliberate here: a NaN must fail every check, which `a <= b` would not.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use glam::DVec2;
use image::RgbImage;
use serde::Serialize;

use crate::calibration::model::Calibration;
use crate::dataset::{DatasetError, Manifest, PoseRow, REFERENCE_FILE, Source, read_rows};
use crate::geometry::DepthMap;
use crate::geometry::stl::Mesh;
use crate::imaging::{BoxBorder, MeanImage, box_blur, box_blur_repeated, dilate_mask, flood_fill, max_channel_difference};
use crate::metrics;
use crate::pose::Pose;
use crate::sensor::SensorKind;

/// Two poses are the same pose when x, y, z (mm) and yaw (deg) each differ by at most this.
pub const POSE_TOLERANCE: f64 = 1e-6;
/// Yaw difference that counts as much as 1 mm in [`pose_distance`], degrees.
pub const NN_YAW_DEG_PER_MM: f64 = 15.0;
/// Smallest `size_px`: the SSIM window.
pub const MIN_SIZE_PX: u32 = 11;
/// A contact region whose second moments have a smaller-to-larger eigenvalue ratio above this
/// is near-isotropic (a disc, a ring, a square): its orientation says nothing about yaw.
pub const ISOTROPY_RATIO: f64 = 0.5;

/// Errors of `rig eval`: all are bad input (missing or inconsistent datasets).
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    #[error("--size {size_px}: images must be at least {min} px (the SSIM window)")]
    BadSize { size_px: u32, min: u32 },
    #[error("--object {object}: no real dataset of that object under {dir}")]
    UnknownObject { object: String, dir: PathBuf },
    #[error("no dataset under {dir} (--{side}: a dataset has a manifest.toml)")]
    NoDatasets { side: &'static str, dir: PathBuf },
    #[error("{side}: two datasets for object {object:?} and sensor {sensor:?}: {first} and {second}")]
    DuplicateDataset { side: &'static str, object: String, sensor: String, first: PathBuf, second: PathBuf },
    #[error("dataset {dir}: {source}")]
    Dataset {
        dir: PathBuf,
        #[source]
        source: DatasetError,
    },
    #[error("cannot read image {path}: {source}")]
    Image {
        path: PathBuf,
        #[source]
        source: image::ImageError,
    },
    #[error("dataset {dir} has no {REFERENCE_FILE} (the no-contact frame the contact region is measured against)")]
    NoReference { dir: PathBuf },
    #[error(
        "no pose pairs: {real_datasets} real and {synthetic_datasets} synthetic datasets, {matched_datasets} matched by object and sensor, {unpaired_real} real and {unpaired_synthetic} synthetic poses without a twin, {dropped_seen} dropped as seen in the collected set"
    )]
    NoPairs {
        real_datasets: usize,
        synthetic_datasets: usize,
        matched_datasets: usize,
        unpaired_real: usize,
        unpaired_synthetic: usize,
        dropped_seen: usize,
    },
    #[error(
        "pose_id {pose_id} of {object}/{sensor}: the real image is {real_width}x{real_height} px, the synthetic one {synthetic_width}x{synthetic_height} px: not the same shape, so not a twin of it (`rig synth --poses-of` writes twins of the same shape)"
    )]
    SizeMismatch {
        object: String,
        sensor: String,
        pose_id: u32,
        real_width: u32,
        real_height: u32,
        synthetic_width: u32,
        synthetic_height: u32,
    },
}

/// Settings of an evaluation.
#[derive(Debug, Clone, PartialEq)]
pub struct EvalOptions {
    /// Every image is resized to `size_px` x `size_px` before it is measured.
    pub size_px: u32,
    /// What the test set is (e.g. "unseen poses"); the table's heading.
    pub label: String,
    /// A pixel belongs to the contact region when the true image's change from the reference
    /// (largest channel difference, 3 x 3 box mean) exceeds this, grey levels.
    pub mask_threshold: f64,
    /// The region is then dilated by this many pixels (square).
    pub mask_dilate_px: u32,
    /// Only these objects of the real and synthetic sides (empty: all). The collected set is
    /// not filtered: baselines may use any object of the sensor.
    pub objects: Vec<String>,
    /// The contact estimator for every sensor (None: each sensor's own,
    /// [`ContactEstimator::for_sensor`]).
    pub estimator: Option<ContactEstimator>,
}

impl EvalOptions {
    /// Defaults at a size: threshold 10 levels, dilation `size / 64` px (2 px at 128).
    pub fn at_size(size_px: u32, label: &str) -> Self {
        Self {
            size_px,
            label: label.to_string(),
            mask_threshold: 10.0,
            mask_dilate_px: (size_px / 64).max(1),
            objects: Vec::new(),
            estimator: None,
        }
    }
}

impl Default for EvalOptions {
    fn default() -> Self {
        Self::at_size(128, "test set")
    }
}

/// Whose image is judged.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    Model,
    PoseBlind,
    NearestNeighbour,
    TrueImage,
}

impl Method {
    pub const ALL: [Method; 4] = [Method::Model, Method::PoseBlind, Method::NearestNeighbour, Method::TrueImage];

    /// The name in the table.
    pub fn label(&self) -> &'static str {
        match self {
            Method::Model => "model",
            Method::PoseBlind => "pose-blind",
            Method::NearestNeighbour => "nearest-neighbour",
            Method::TrueImage => "true image",
        }
    }
}

/// One row of the table: a method on one sensor's pairs. `None`: no data (shown `n/a`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MethodRow {
    pub sensor: String,
    pub method: Method,
    /// Pairs judged.
    pub n: usize,
    pub ssim: Option<f64>,
    /// Mean of the per-image PSNR, dB; infinite when some image is identical to its truth
    /// (written `null` in JSON, `inf` in the table).
    pub psnr_db: Option<f64>,
    pub mse: Option<f64>,
    /// Pairs whose true image has contact pixels (the contact columns average over these).
    pub n_contact: usize,
    pub contact_ssim: Option<f64>,
    pub contact_psnr_db: Option<f64>,
    pub contact_mse: Option<f64>,
    /// Mean distance between the contact centroid estimated from this method's image and the
    /// centroid of the contact the commanded pose gives the mesh, mm.
    pub position_err_mm: Option<f64>,
    /// Poses with a geometric contact, and of those, poses where this image gave an estimate.
    pub position_attempts: usize,
    pub position_found: usize,
    /// Mean angle between the estimated principal axis and the mesh contact's, degrees
    /// (mod 180, so at most 90), over poses whose mesh contact is not near-isotropic.
    pub yaw_err_deg: Option<f64>,
    pub yaw_attempts: usize,
    pub yaw_found: usize,
    /// The same two errors against the estimate from the true image of the same pose.
    pub position_vs_true_mm: Option<f64>,
    pub yaw_vs_true_deg: Option<f64>,
}

/// What was counted rather than measured.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct EvalCounts {
    pub real_datasets: usize,
    pub synthetic_datasets: usize,
    pub collected_images: usize,
    /// Pairs judged.
    pub pairs: usize,
    /// Test poses the collected set also has (same object and sensor): dropped.
    pub dropped_seen: usize,
    /// Real poses without a synthetic twin, and synthetic poses without a real one.
    pub unpaired_real: usize,
    pub unpaired_synthetic: usize,
    /// A few of the unpaired poses, for the message (`object/sensor pose_id (x, y, z, yaw)`).
    pub unpaired_examples: Vec<String>,
    /// Datasets on one side with no dataset of the same object and sensor on the other.
    pub unmatched_datasets: Vec<String>,
    /// True images without contact pixels (skipped for the contact metrics).
    pub no_contact_pixels: usize,
    /// Poses whose mesh contact is near-isotropic (skipped for yaw).
    pub yaw_unobservable: usize,
    /// Poses without a mesh contact (no mesh, or the object does not touch): skipped for
    /// pose recoverability against the pose.
    pub no_geometric_contact: usize,
    /// Sensors with no collected image: their baseline rows are `n/a`.
    pub sensors_without_baseline: Vec<String>,
    /// Real datasets whose manifest names a calibration file that cannot be loaded here: the
    /// default calibration for the image size stands in (pose errors in mm are then approximate).
    pub default_calibration_for: Vec<String>,
}

/// One method on one pair: what the table averages, per pose (`rig eval --pairs`).
/// `None`: not measured (no contact pixels, no estimate, yaw not observable, ...).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PairRecord {
    /// Which pair (0, 1, ...: the order judged); the methods of one pair share it.
    pub pair: usize,
    pub object: String,
    pub sensor: String,
    pub pose_id: u32,
    pub x_mm: f64,
    pub y_mm: f64,
    pub z_mm: f64,
    pub yaw_deg: f64,
    pub method: &'static str,
    pub ssim: Option<f64>,
    pub contact_ssim: Option<f64>,
    pub position_err_mm: Option<f64>,
    pub yaw_err_deg: Option<f64>,
    pub position_vs_true_mm: Option<f64>,
    pub yaw_vs_true_deg: Option<f64>,
    /// PSNR is infinite for an image identical to its truth (written `inf`).
    pub psnr_db: Option<f64>,
    pub mse: Option<f64>,
    pub contact_psnr_db: Option<f64>,
    pub contact_mse: Option<f64>,
    /// The commanded pose gives the mesh a contact: the pose errors were attempted.
    pub mesh_contact: bool,
    /// ... and that contact has an observable yaw: the yaw error was attempted.
    pub yaw_observable: bool,
}

/// The result of [`evaluate`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EvalReport {
    pub label: String,
    pub size_px: u32,
    pub mask_threshold: f64,
    pub mask_dilate_px: u32,
    pub counts: EvalCounts,
    pub rows: Vec<MethodRow>,
    /// The contact estimator each sensor's images were judged by.
    pub estimators: BTreeMap<String, ContactEstimator>,
    /// The model against each baseline, pair by pair ([`paired_comparisons`]).
    pub comparisons: Vec<PairedComparison>,
    /// Every method on every pair, in the order judged (not in the JSON: see [`Self::write_pairs_csv`]).
    #[serde(skip)]
    pub pairs: Vec<PairRecord>,
}

/// One dataset read from disk.
#[derive(Clone)]
struct DatasetInfo {
    dir: PathBuf,
    manifest: Manifest,
    rows: Vec<PoseRow>,
}

impl DatasetInfo {
    fn load(dir: &Path) -> Result<Self, EvalError> {
        let wrap = |source| EvalError::Dataset { dir: dir.to_path_buf(), source };
        let manifest = Manifest::load(dir).map_err(wrap)?;
        let rows = read_rows(dir).map_err(wrap)?;
        Ok(Self { dir: dir.to_path_buf(), manifest, rows })
    }

    fn key(&self) -> (String, String) {
        (self.manifest.object.name.clone(), self.manifest.sensor.to_string())
    }

    fn rows_of(&self, source: Source) -> impl Iterator<Item = &PoseRow> {
        self.rows.iter().filter(move |r| r.source == source)
    }
}

/// Datasets under `root` keyed by (object, sensor); a key twice is an error.
fn load_side(root: &Path, side: &'static str) -> Result<BTreeMap<(String, String), DatasetInfo>, EvalError> {
    let dirs = crate::dataset::find_datasets(root);
    if dirs.is_empty() {
        return Err(EvalError::NoDatasets { side, dir: root.to_path_buf() });
    }
    let mut out = BTreeMap::new();
    for d in dirs {
        let info = DatasetInfo::load(&d)?;
        let key = info.key();
        if let Some(first) = out.get(&key) {
            let first: &DatasetInfo = first;
            return Err(EvalError::DuplicateDataset { side, object: key.0, sensor: key.1, first: first.dir.clone(), second: d });
        }
        out.insert(key, info);
    }
    Ok(out)
}

/// Whether two poses are the same within [`POSE_TOLERANCE`].
pub fn same_pose(a: &Pose, b: &Pose) -> bool {
    (a.x_mm - b.x_mm).abs() <= POSE_TOLERANCE
        && (a.y_mm - b.y_mm).abs() <= POSE_TOLERANCE
        && (a.z_mm - b.z_mm).abs() <= POSE_TOLERANCE
        && (a.yaw_deg - b.yaw_deg).abs() <= POSE_TOLERANCE
}

/// The nearest-neighbour distance: Euclidean mm over x, y, z plus the smallest yaw difference
/// over [`NN_YAW_DEG_PER_MM`] (15 degrees weigh as 1 mm).
pub fn pose_distance(a: &Pose, b: &Pose) -> f64 {
    a.distance_mm(b) + a.yaw_error_deg(b) / NN_YAW_DEG_PER_MM
}

/// Reads a PNG and resizes it to `size` x `size` (bilinear) when it is not already.
fn load_at(path: &Path, size: u32) -> Result<RgbImage, EvalError> {
    let img = image::open(path).map_err(|source| EvalError::Image { path: path.to_path_buf(), source })?.to_rgb8();
    Ok(resize_square(img, size))
}

fn resize_square(img: RgbImage, size: u32) -> RgbImage {
    if img.dimensions() == (size, size) { img } else { image::imageops::resize(&img, size, size, image::imageops::FilterType::Triangle) }
}

/// The dataset's calibration at `size` x `size`: the file its manifest names, else (none or
/// `default`) the default for its image size, which is what `rig collect` renders with then.
fn calibration_at(info: &DatasetInfo, native: (u32, u32), size: u32) -> Option<Calibration> {
    let calib = match info.manifest.calibration.as_deref() {
        None | Some("default") | Some("none") => Calibration::default_for(native.0, native.1),
        Some(path) => Calibration::load(Path::new(path)).ok()?,
    };
    Some(calib.scaled_to(size, size))
}

/// The object's mesh: its STL when the file is there, else the library object of that name.
fn mesh_of(manifest: &Manifest) -> Option<Mesh> {
    if let Some(path) = manifest.object.stl_path.as_deref().map(PathBuf::from).filter(|p| p.is_file())
        && let Ok(mesh) = Mesh::load(&path)
    {
        return Some(mesh);
    }
    crate::geometry::objects::load_object(&manifest.object.name).ok()
}

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
/// training collection only (never on a model's images, never on a test set); README, "Choosing
/// the estimator". Every method's image of a sensor is judged by the same one.
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
struct CollectedPose {
    object: String,
    pose: Pose,
    path: PathBuf,
    /// Index into the collected datasets (for their reference frames).
    dataset: usize,
}

/// The collected set of one sensor: poses, the mean image, and loaded images on demand.
struct CollectedSensor {
    poses: Vec<CollectedPose>,
    mean: Option<RgbImage>,
}

/// The collected (training) set at the measuring size.
struct Collected {
    /// Per sensor: poses and the pose-blind mean image.
    by_sensor: BTreeMap<String, CollectedSensor>,
    /// Each collected dataset's `reference.png`, when it has one.
    references: Vec<Option<RgbImage>>,
    /// Collected images (real rows).
    images: usize,
}

impl Collected {
    /// Lists the real rows of `sets` per sensor and averages their images (each read once).
    fn load(sets: &[DatasetInfo], size: u32) -> Result<Self, EvalError> {
        let mut by_sensor: BTreeMap<String, CollectedSensor> = BTreeMap::new();
        let mut references = Vec::new();
        for (index, d) in sets.iter().enumerate() {
            references.push(load_at(&d.dir.join(REFERENCE_FILE), size).ok());
            let (object, sensor) = d.key();
            let entry = by_sensor.entry(sensor).or_insert_with(|| CollectedSensor { poses: Vec::new(), mean: None });
            for r in d.rows_of(Source::Real) {
                entry.poses.push(CollectedPose { object: object.clone(), pose: r.commanded(), path: d.dir.join(&r.image), dataset: index });
            }
        }
        let mut images = 0;
        for sensor in by_sensor.values_mut() {
            let mut mean = MeanImage::new(size, size);
            for p in &sensor.poses {
                mean.add(&load_at(&p.path, size)?);
            }
            images += sensor.poses.len();
            sensor.mean = mean.image();
        }
        Ok(Self { by_sensor, references, images })
    }
}

fn mean(v: impl Iterator<Item = f64>) -> Option<f64> {
    let (sum, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x, n + 1));
    mean_of(sum, n)
}

fn mean_of(sum: f64, n: usize) -> Option<f64> {
    (n > 0 && !sum.is_nan()).then(|| sum / n as f64)
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

impl MethodRow {
    /// The table row of `method` on `sensor`: the means over its per-pair `records`.
    pub fn from_records(sensor: &str, method: Method, records: &[&PairRecord]) -> Self {
        let over = |f: fn(&PairRecord) -> Option<f64>| mean(records.iter().filter_map(|r| f(r)));
        let count = |f: fn(&PairRecord) -> bool| records.iter().filter(|r| f(r)).count();
        MethodRow {
            sensor: sensor.to_string(),
            method,
            n: count(|r| r.ssim.is_some()),
            ssim: over(|r| r.ssim),
            psnr_db: over(|r| r.psnr_db),
            mse: over(|r| r.mse),
            n_contact: count(|r| r.contact_ssim.is_some()),
            contact_ssim: over(|r| r.contact_ssim),
            contact_psnr_db: over(|r| r.contact_psnr_db),
            contact_mse: over(|r| r.contact_mse),
            position_err_mm: over(|r| r.position_err_mm),
            position_attempts: count(|r| r.mesh_contact),
            position_found: count(|r| r.position_err_mm.is_some()),
            yaw_err_deg: over(|r| r.yaw_err_deg),
            yaw_attempts: count(|r| r.mesh_contact && r.yaw_observable),
            yaw_found: count(|r| r.yaw_err_deg.is_some()),
            position_vs_true_mm: over(|r| r.position_vs_true_mm),
            yaw_vs_true_deg: over(|r| r.yaw_vs_true_deg),
        }
    }
}

/// Runs the evaluation (see the module docs). `collected` empty: the real rows of the
/// synthetic datasets are the collected set.
pub fn evaluate(real_root: &Path, synthetic_root: &Path, collected: &[PathBuf], options: &EvalOptions) -> Result<EvalReport, EvalError> {
    let size = options.size_px;
    if size < MIN_SIZE_PX {
        return Err(EvalError::BadSize { size_px: size, min: MIN_SIZE_PX });
    }
    let mut real = load_side(real_root, "real")?;
    let mut synthetic = load_side(synthetic_root, "synthetic")?;
    // Before the object filter: baselines may use any object of the sensor.
    let collected_sets: Vec<DatasetInfo> = if collected.is_empty() {
        synthetic.values().cloned().collect()
    } else {
        let mut v = Vec::new();
        for root in collected {
            let dirs = crate::dataset::find_datasets(root);
            if dirs.is_empty() {
                return Err(EvalError::NoDatasets { side: "collected", dir: root.clone() });
            }
            for d in dirs {
                v.push(DatasetInfo::load(&d)?);
            }
        }
        v
    };
    if !options.objects.is_empty() {
        if let Some(object) = options.objects.iter().find(|o| !real.keys().any(|(name, _)| name == *o)) {
            return Err(EvalError::UnknownObject { object: object.clone(), dir: real_root.to_path_buf() });
        }
        real.retain(|(name, _), _| options.objects.contains(name));
        synthetic.retain(|(name, _), _| options.objects.contains(name));
    }
    let Collected { by_sensor, references: collected_refs, images } = Collected::load(&collected_sets, size)?;
    let mut counts =
        EvalCounts { real_datasets: real.len(), synthetic_datasets: synthetic.len(), collected_images: images, ..EvalCounts::default() };

    let mut pairs: Vec<PairRecord> = Vec::new();
    let mut estimators = BTreeMap::new();
    let mut matched = 0usize;
    for (key, s) in &synthetic {
        if !real.contains_key(key) {
            counts.unmatched_datasets.push(format!("synthetic {} ({}/{})", s.dir.display(), key.0, key.1));
            counts.unpaired_synthetic += s.rows_of(Source::Synthetic).count();
        }
    }
    for (key, r) in &real {
        let (object, sensor) = key;
        let Some(s) = synthetic.get(key) else {
            counts.unmatched_datasets.push(format!("real {} ({object}/{sensor})", r.dir.display()));
            counts.unpaired_real += r.rows_of(Source::Real).count();
            continue;
        };
        matched += 1;
        let reference_path = r.dir.join(REFERENCE_FILE);
        if !reference_path.is_file() {
            return Err(EvalError::NoReference { dir: r.dir.clone() });
        }
        let native =
            image::image_dimensions(&reference_path).map_err(|source| EvalError::Image { path: reference_path.clone(), source })?;
        let reference = load_at(&reference_path, size)?;
        let calib = calibration_at(r, native, size).unwrap_or_else(|| {
            counts.default_calibration_for.push(format!("{object}/{sensor}"));
            Calibration::default_for(size, size)
        });
        let mesh = mesh_of(&r.manifest);
        let contact_depth_mm = r.manifest.work_frame.map(|w| w.contact_depth_mm).unwrap_or(1.5);
        let collected_here = by_sensor.get(sensor);
        let estimator = options.estimator.unwrap_or_else(|| ContactEstimator::for_sensor(sensor));
        estimators.insert(sensor.clone(), estimator);
        let synthetic_rows: Vec<&PoseRow> = s.rows_of(Source::Synthetic).collect();
        let mut used = vec![false; synthetic_rows.len()];
        for row in r.rows_of(Source::Real) {
            let pose = row.commanded();
            let twin = synthetic_rows.iter().enumerate().find(|(i, t)| !used[*i] && same_pose(&t.commanded(), &pose));
            let Some((ti, twin)) = twin else {
                counts.unpaired_real += 1;
                if counts.unpaired_examples.len() < 5 {
                    counts.unpaired_examples.push(describe(object, sensor, "real", row));
                }
                continue;
            };
            used[ti] = true;
            if collected_here.is_some_and(|c| c.poses.iter().any(|p| &p.object == object && same_pose(&p.pose, &pose))) {
                counts.dropped_seen += 1;
                continue;
            }
            let real_path = r.dir.join(&row.image);
            let synth_path = s.dir.join(&twin.image);
            let rd = image::image_dimensions(&real_path).map_err(|source| EvalError::Image { path: real_path.clone(), source })?;
            let sd = image::image_dimensions(&synth_path).map_err(|source| EvalError::Image { path: synth_path.clone(), source })?;
            // Both sides are resized to `size` square; only the shape must agree (twins come at
            // the model's resolution by default).
            if u64::from(rd.0) * u64::from(sd.1) != u64::from(sd.0) * u64::from(rd.1) {
                return Err(EvalError::SizeMismatch {
                    object: object.clone(),
                    sensor: sensor.clone(),
                    pose_id: row.pose_id,
                    real_width: rd.0,
                    real_height: rd.1,
                    synthetic_width: sd.0,
                    synthetic_height: sd.1,
                });
            }
            let truth = load_at(&real_path, size)?;
            let model = load_at(&synth_path, size)?;
            counts.pairs += 1;

            let mask = contact_mask(&truth, &reference, options.mask_threshold, options.mask_dilate_px);
            let mask = if mask.iter().any(|&m| m) { Some(mask) } else { None };
            if mask.is_none() {
                counts.no_contact_pixels += 1;
            }
            let geometric = mesh.as_ref().and_then(|m| {
                let object_pose = Pose { z_mm: pose.z_mm + contact_depth_mm, ..pose };
                geometric_contact(&crate::geometry::raster::render_depth(m, &object_pose, &calib, size, size, 2))
            });
            if geometric.is_none() {
                counts.no_geometric_contact += 1;
            }
            let truth_estimate = estimate_contact_with(&truth, &reference, &estimator);
            let observable_from = geometric.or(truth_estimate);
            let yaw_observable = observable_from.is_some_and(|g| yaw_observable(&g, &calib, &estimator, size as usize));
            if observable_from.is_some() && !yaw_observable {
                counts.yaw_unobservable += 1;
            }
            let pose_truth = PoseTruth { geometric, yaw_observable, truth_estimate, calib: calib.clone() };

            let pair_index = counts.pairs - 1;
            let mesh_contact = geometric.is_some();
            let record = |method: Method, i: ImageFigures, e: PoseErrors| PairRecord {
                pair: pair_index,
                object: object.clone(),
                sensor: sensor.clone(),
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
                let errors = pose_errors(estimate_contact_with(image, &reference, &estimator), &pose_truth, true);
                pairs.push(record(method, figures, errors));
            };
            judge(Method::Model, &model);
            if let Some(c) = collected_here
                && let Some(mean_image) = &c.mean
            {
                judge(Method::PoseBlind, mean_image);
                if let Some(nn) = nearest(c, object, &pose) {
                    let img = load_at(&nn.path, size)?;
                    let nn_reference = collected_refs.get(nn.dataset).cloned().flatten().unwrap_or_else(|| mean_image.clone());
                    judge(Method::NearestNeighbour, &warp_to_pose(&img, &nn_reference, &nn.pose, &pose, &calib));
                }
            }
            pairs.push(record(Method::TrueImage, ImageFigures::default(), pose_errors(truth_estimate, &pose_truth, false)));
        }
        for (i, t) in synthetic_rows.iter().enumerate() {
            if !used[i] {
                counts.unpaired_synthetic += 1;
                if counts.unpaired_examples.len() < 5 {
                    counts.unpaired_examples.push(describe(object, sensor, "synthetic", t));
                }
            }
        }
    }
    if counts.pairs == 0 {
        return Err(EvalError::NoPairs {
            real_datasets: real.len(),
            synthetic_datasets: synthetic.len(),
            matched_datasets: matched,
            unpaired_real: counts.unpaired_real,
            unpaired_synthetic: counts.unpaired_synthetic,
            dropped_seen: counts.dropped_seen,
        });
    }
    let sensors: std::collections::BTreeSet<&str> = pairs.iter().map(|p| p.sensor.as_str()).collect();
    let mut rows = Vec::new();
    for sensor in sensors {
        if by_sensor.get(sensor).is_none_or(|c| c.mean.is_none()) {
            counts.sensors_without_baseline.push(sensor.to_string());
        }
        for method in Method::ALL {
            let records: Vec<&PairRecord> = pairs.iter().filter(|p| p.sensor == sensor && p.method == method.label()).collect();
            rows.push(MethodRow::from_records(sensor, method, &records));
        }
    }
    Ok(EvalReport {
        label: options.label.clone(),
        size_px: size,
        mask_threshold: options.mask_threshold,
        mask_dilate_px: options.mask_dilate_px,
        counts,
        rows,
        estimators,
        comparisons: paired_comparisons(&pairs),
        pairs,
    })
}

/// A figure the model is compared on, pair by pair.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Figure {
    ContactSsim,
    PositionErr,
    YawErr,
}

impl Figure {
    pub const ALL: [Figure; 3] = [Figure::ContactSsim, Figure::PositionErr, Figure::YawErr];

    /// The name in the table.
    pub fn label(&self) -> &'static str {
        match self {
            Figure::ContactSsim => "contact SSIM",
            Figure::PositionErr => "pos err mm",
            Figure::YawErr => "yaw err deg",
        }
    }

    fn of(&self, p: &PairRecord) -> Option<f64> {
        match self {
            Figure::ContactSsim => p.contact_ssim,
            Figure::PositionErr => p.position_err_mm,
            Figure::YawErr => p.yaw_err_deg,
        }
        .filter(|v| v.is_finite())
    }

    /// Whether a larger value is better (SSIM) or worse (errors).
    fn higher_is_better(&self) -> bool {
        matches!(self, Figure::ContactSsim)
    }

    fn decimals(&self) -> usize {
        match self {
            Figure::ContactSsim => 4,
            Figure::PositionErr => 3,
            Figure::YawErr => 2,
        }
    }
}

/// What a paired comparison shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Verdict {
    /// The 95% interval of the mean difference lies wholly on the model's better side.
    ModelBetter,
    /// ... wholly on its worse side.
    ModelWorse,
    /// The interval holds 0: no difference shown.
    NoDifferenceShown,
    /// Fewer than [`MIN_PAIRS_FOR_VERDICT`] pairs with the figure on both sides.
    TooFewPairs,
}

impl Verdict {
    pub fn label(&self) -> &'static str {
        match self {
            Verdict::ModelBetter => "model better",
            Verdict::ModelWorse => "model worse",
            Verdict::NoDifferenceShown => "no difference shown",
            Verdict::TooFewPairs => "too few pairs",
        }
    }
}

/// Bootstrap resamples behind each interval.
pub const BOOTSTRAP_RESAMPLES: usize = 4000;
/// Fewer pairs than this get no verdict.
pub const MIN_PAIRS_FOR_VERDICT: usize = 10;

/// The model against one baseline on one figure of one sensor, over the pairs where both have
/// that figure (so a method that finds no contact on a hard pose is not averaged over easier
/// poses than the other).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PairedComparison {
    pub sensor: String,
    pub baseline: Method,
    pub figure: Figure,
    /// Pairs where both have the figure.
    pub n: usize,
    pub model_mean: f64,
    pub baseline_mean: f64,
    /// Mean of (model - baseline) over the n pairs.
    pub difference: f64,
    /// 95% percentile-bootstrap interval of that mean ([`BOOTSTRAP_RESAMPLES`] resamples of the
    /// pairs, a fixed seed: the same data gives the same interval).
    pub interval95: [f64; 2],
    pub verdict: Verdict,
    /// What a perfect model would show against the same baseline: the true image in the
    /// model's place ([`Ceiling`]). `None` where no pair has the figure on both sides.
    pub true_image: Option<Ceiling>,
}

/// The true image against a baseline on one figure, as if it were the model: the best any model
/// can show on this test set. Its pose errors are measured like any method's; its contact SSIM
/// is 1 (the image against itself) wherever the baseline has one. Where even this comparison
/// shows no difference, the baseline sits at the estimator's floor and no model can beat it
/// here: "no difference shown" is then the best verdict there is.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Ceiling {
    /// Pairs where the true image and the baseline both have the figure.
    pub n: usize,
    pub true_mean: f64,
    pub baseline_mean: f64,
    /// Mean of (true image - baseline), and its 95% bootstrap interval.
    pub difference: f64,
    pub interval95: [f64; 2],
    /// [`Verdict::ModelBetter`]: the true image beats the baseline, so a model can too.
    pub verdict: Verdict,
}

impl Ceiling {
    /// Whether a model can show that it beats the baseline on this figure here.
    pub fn winnable(&self) -> bool {
        self.verdict == Verdict::ModelBetter
    }
}

/// Mean of `d` and its 95% percentile-bootstrap interval (resampling the entries, fixed seed).
pub fn bootstrap_mean_interval(d: &[f64]) -> Option<(f64, [f64; 2])> {
    use rand::{RngExt, SeedableRng};
    if d.is_empty() || d.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let n = d.len();
    let mean = d.iter().sum::<f64>() / n as f64;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x9a1_4ed);
    let mut means: Vec<f64> = (0..BOOTSTRAP_RESAMPLES).map(|_| (0..n).map(|_| d[rng.random_range(0..n)]).sum::<f64>() / n as f64).collect();
    means.sort_by(f64::total_cmp);
    let lo = means[(BOOTSTRAP_RESAMPLES as f64 * 0.025) as usize];
    let hi = means[((BOOTSTRAP_RESAMPLES as f64 * 0.975).ceil() as usize - 1).min(BOOTSTRAP_RESAMPLES - 1)];
    Some((mean, [lo, hi]))
}

/// One side against another over the pairs where both have a value: (n, means, mean
/// difference, its interval, verdict from the first side's point of view).
struct Paired {
    n: usize,
    means: [f64; 2],
    difference: f64,
    interval95: [f64; 2],
    verdict: Verdict,
}

fn paired(values: &[(f64, f64)], figure: Figure) -> Option<Paired> {
    let d: Vec<f64> = values.iter().map(|(x, y)| x - y).collect();
    let (difference, interval95) = bootstrap_mean_interval(&d)?;
    let n = d.len();
    let verdict = if n < MIN_PAIRS_FOR_VERDICT {
        Verdict::TooFewPairs
    } else if interval95[0] > 0.0 || interval95[1] < 0.0 {
        let first_higher = interval95[0] > 0.0;
        if first_higher == figure.higher_is_better() { Verdict::ModelBetter } else { Verdict::ModelWorse }
    } else {
        Verdict::NoDifferenceShown
    };
    let mean = |f: fn(&(f64, f64)) -> f64| values.iter().map(f).sum::<f64>() / n as f64;
    Some(Paired { n, means: [mean(|v| v.0), mean(|v| v.1)], difference, interval95, verdict })
}

/// The model against pose-blind and nearest-neighbour on every [`Figure`], per sensor, each
/// with its [`Ceiling`].
pub fn paired_comparisons(pairs: &[PairRecord]) -> Vec<PairedComparison> {
    // (sensor, pair) -> method -> record
    let mut by_pair: BTreeMap<(&str, usize), BTreeMap<&str, &PairRecord>> = BTreeMap::new();
    for p in pairs {
        by_pair.entry((p.sensor.as_str(), p.pair)).or_default().insert(p.method, p);
    }
    let sensors: Vec<&str> = {
        let mut v: Vec<&str> = by_pair.keys().map(|(s, _)| *s).collect();
        v.dedup();
        v
    };
    let mut out = Vec::new();
    for sensor in sensors {
        for baseline in [Method::PoseBlind, Method::NearestNeighbour] {
            for figure in Figure::ALL {
                let (mut model, mut truth) = (Vec::new(), Vec::new());
                for methods in by_pair.range((sensor, 0)..=(sensor, usize::MAX)).map(|(_, v)| v) {
                    let get = |method: Method| methods.get(method.label()).and_then(|p| figure.of(p));
                    let Some(b) = get(baseline) else { continue };
                    if let Some(m) = get(Method::Model) {
                        model.push((m, b));
                    }
                    let t = match figure {
                        // The true image against itself; pairs without contact pixels have no
                        // contact SSIM for the baseline either.
                        Figure::ContactSsim => Some(1.0),
                        Figure::PositionErr | Figure::YawErr => get(Method::TrueImage),
                    };
                    if let Some(t) = t {
                        truth.push((t, b));
                    }
                }
                let Some(m) = paired(&model, figure) else { continue };
                let true_image = paired(&truth, figure).map(|t| Ceiling {
                    n: t.n,
                    true_mean: t.means[0],
                    baseline_mean: t.means[1],
                    difference: t.difference,
                    interval95: t.interval95,
                    verdict: t.verdict,
                });
                out.push(PairedComparison {
                    sensor: sensor.to_string(),
                    baseline,
                    figure,
                    n: m.n,
                    model_mean: m.means[0],
                    baseline_mean: m.means[1],
                    difference: m.difference,
                    interval95: m.interval95,
                    verdict: m.verdict,
                    true_image,
                });
            }
        }
    }
    out
}

/// One line per baseline: how many comparisons the model wins, loses and ties, and of the
/// ties, which no model could win (see [`Ceiling`]).
pub fn comparison_summary(comparisons: &[PairedComparison]) -> String {
    let mut s = String::new();
    for baseline in [Method::PoseBlind, Method::NearestNeighbour] {
        let mine: Vec<&PairedComparison> = comparisons.iter().filter(|c| c.baseline == baseline).collect();
        if mine.is_empty() {
            continue;
        }
        let name = |c: &&PairedComparison| format!("{} {}", c.sensor, c.figure.label());
        let with = |v: Verdict| -> Vec<&PairedComparison> { mine.iter().copied().filter(|c| c.verdict == v).collect() };
        let list = |v: &[&PairedComparison]| v.iter().map(name).collect::<Vec<_>>().join(", ");
        let (better, worse, ties, few) =
            (with(Verdict::ModelBetter), with(Verdict::ModelWorse), with(Verdict::NoDifferenceShown), with(Verdict::TooFewPairs));
        let (winnable, floor): (Vec<_>, Vec<_>) = ties.iter().copied().partition(|c| c.true_image.as_ref().is_some_and(Ceiling::winnable));
        s += &format!("\nAgainst {}: model better on {} of {}", baseline.label(), better.len(), mine.len());
        if !worse.is_empty() {
            s += &format!("; worse on {} ({})", worse.len(), list(&worse));
        }
        if !ties.is_empty() {
            s += &format!("; no difference shown on {}", ties.len());
            let mut parts = Vec::new();
            if !floor.is_empty() {
                parts.push(format!("not winnable here, even the true image shows none: {}", list(&floor)));
            }
            if !winnable.is_empty() {
                parts.push(format!("winnable, the true image beats the baseline: {}", list(&winnable)));
            }
            s += &format!(" ({})", parts.join("; "));
        }
        if !few.is_empty() {
            s += &format!("; too few pairs on {}", few.len());
        }
        s += ".\n";
    }
    s
}

fn describe(object: &str, sensor: &str, side: &str, row: &PoseRow) -> String {
    format!("{side} {object}/{sensor} pose_id {} ({}, {}, {}, {})", row.pose_id, row.x_mm, row.y_mm, row.z_mm, row.yaw_deg)
}

/// The collected pose nearest to `pose` by [`pose_distance`]: among `object`'s when there are
/// any, else among all of the sensor's.
fn nearest<'a>(c: &'a CollectedSensor, object: &str, pose: &Pose) -> Option<&'a CollectedPose> {
    let same: Vec<&CollectedPose> = c.poses.iter().filter(|p| p.object == object).collect();
    let pool: Vec<&CollectedPose> = if same.is_empty() { c.poses.iter().collect() } else { same };
    pool.into_iter().min_by(|a, b| pose_distance(&a.pose, pose).total_cmp(&pose_distance(&b.pose, pose)))
}

fn cell(v: Option<f64>, decimals: usize) -> String {
    match v {
        Some(x) if x.is_infinite() => "inf".to_string(),
        Some(x) if x.is_finite() => format!("{x:.decimals$}"),
        _ => "n/a".to_string(),
    }
}

/// A recoverability cell: the mean, with `(found/attempts)` when some images gave no estimate.
fn found_cell(v: Option<f64>, found: usize, attempts: usize) -> String {
    let base = cell(v, 2);
    if attempts > 0 && found < attempts { format!("{base} ({found}/{attempts})") } else { base }
}

impl EvalReport {
    /// The Markdown table with its heading and counts.
    pub fn to_markdown(&self) -> String {
        let c = &self.counts;
        let mut s = format!("### rig eval: {} ({} px)\n\n", self.label, self.size_px);
        s += &format!(
            "{} pairs from {} real and {} synthetic datasets; {} collected images for the baselines. \
             Dropped as seen in the collected set: {}. Without a twin: {} real, {} synthetic poses. \
             No contact pixels (left out of the contact columns): {}. Yaw not observable (contact near-isotropic or within the estimator's blur, left out of the yaw columns): {}. \
             No mesh contact (left out of the pose-error columns): {}.\n",
            c.pairs,
            c.real_datasets,
            c.synthetic_datasets,
            c.collected_images,
            c.dropped_seen,
            c.unpaired_real,
            c.unpaired_synthetic,
            c.no_contact_pixels,
            c.yaw_unobservable,
            c.no_geometric_contact
        );
        if !self.estimators.is_empty() {
            let each: Vec<String> = self
                .estimators
                .iter()
                .map(|(sensor, e)| format!("{sensor} blur size/{}, region {}", e.blur_divisor, e.region_fraction))
                .collect();
            s += &format!("Contact estimator: {}.\n", each.join("; "));
        }
        if !c.unpaired_examples.is_empty() {
            s += &format!("Unpaired, e.g.: {}.\n", c.unpaired_examples.join("; "));
        }
        if !c.unmatched_datasets.is_empty() {
            s += &format!("Datasets without a counterpart: {}.\n", c.unmatched_datasets.join("; "));
        }
        if !c.default_calibration_for.is_empty() {
            s += &format!(
                "Calibration file not found, default calibration used (pose errors approximate) for: {}.\n",
                c.default_calibration_for.join(", ")
            );
        }
        if !c.sensors_without_baseline.is_empty() {
            s += &format!("No collected images (baselines n/a) for: {}.\n", c.sensors_without_baseline.join(", "));
        }
        s += "\n| sensor | method | n | SSIM | PSNR dB | MSE | contact SSIM | contact PSNR dB | contact MSE | pos err mm | yaw err deg | pos vs true mm | yaw vs true deg |\n";
        s += "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n";
        for r in &self.rows {
            let image_cols = if r.method == Method::TrueImage {
                ["n/a".to_string(), "n/a".to_string(), "n/a".to_string(), "n/a".to_string(), "n/a".to_string(), "n/a".to_string()]
            } else {
                [
                    cell(r.ssim, 3),
                    cell(r.psnr_db, 2),
                    cell(r.mse, 1),
                    cell(r.contact_ssim, 3),
                    cell(r.contact_psnr_db, 2),
                    cell(r.contact_mse, 1),
                ]
            };
            let n = if r.method == Method::TrueImage { r.position_attempts } else { r.n };
            s += &format!(
                "| {} | {} | {} | {} | {} | {} | {} | {} |\n",
                r.sensor,
                r.method.label(),
                n,
                image_cols.join(" | "),
                found_cell(r.position_err_mm, r.position_found, r.position_attempts),
                found_cell(r.yaw_err_deg, r.yaw_found, r.yaw_attempts),
                cell(r.position_vs_true_mm, 2),
                cell(r.yaw_vs_true_deg, 2),
            );
        }
        if !self.comparisons.is_empty() {
            s += &format!(
                "\nThe model against each baseline, pose by pose: only poses where both have the figure; difference = model - baseline, \
                 its mean with a 95% bootstrap interval; a verdict where the interval excludes 0 (and n >= {MIN_PAIRS_FOR_VERDICT}). \
                 The last two columns put the true image in the model's place (its contact SSIM is 1), over the poses where it and the baseline \
                 have the figure: the best any model can show. \"no\": not even the true image beats the baseline here (the baseline is at the \
                 estimator's floor), so \"no difference shown\" is the best verdict a model can get.\n\n"
            );
            s += "| sensor | baseline | figure | n | model | baseline | difference | 95% interval | verdict | true image - baseline | can a model win |\n";
            s += "|---|---|---|---:|---:|---:|---:|---|---|---|---|\n";
            for c in &self.comparisons {
                let k = c.figure.decimals();
                let (ceiling, winnable) = match &c.true_image {
                    Some(t) => (
                        format!("{:+.k$} [{:+.k$}, {:+.k$}]", t.difference, t.interval95[0], t.interval95[1]),
                        match t.verdict {
                            Verdict::TooFewPairs => "too few pairs",
                            _ if t.winnable() => "yes",
                            _ => "no",
                        },
                    ),
                    None => ("n/a".to_string(), "n/a"),
                };
                s += &format!(
                    "| {} | {} | {} | {} | {:.k$} | {:.k$} | {:+.k$} | [{:+.k$}, {:+.k$}] | {} | {ceiling} | {winnable} |\n",
                    c.sensor,
                    c.baseline.label(),
                    c.figure.label(),
                    c.n,
                    c.model_mean,
                    c.baseline_mean,
                    c.difference,
                    c.interval95[0],
                    c.interval95[1],
                    c.verdict.label(),
                );
            }
            s += &comparison_summary(&self.comparisons);
        }
        s
    }

    /// The report as pretty JSON (non-finite numbers become `null`).
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).unwrap_or_else(|e| format!("{{\"error\": \"{e}\"}}"))
    }

    /// Writes [`Self::pairs`] as CSV (a header, then one line per method and pair; an empty
    /// field is a figure not measured for that pair).
    pub fn write_pairs_csv(&self, out: impl std::io::Write) -> Result<(), csv::Error> {
        let mut w = csv::Writer::from_writer(out);
        for p in &self.pairs {
            w.serialize(p)?;
        }
        w.flush()?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::Rgb;

    fn disc(size: u32, cx: f64, cy: f64, rx: f64, ry: f64) -> RgbImage {
        RgbImage::from_fn(size, size, |x, y| {
            let (u, v) = ((x as f64 + 0.5 - cx) / rx, (y as f64 + 0.5 - cy) / ry);
            let v = if u * u + v * v < 1.0 { 200 } else { 20 };
            Rgb([v, v, v])
        })
    }

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

    #[test]
    fn table_says_na_not_nan() {
        let row = MethodRow::from_records("vitac", Method::Model, &[]);
        let report = EvalReport {
            label: "t".into(),
            size_px: 64,
            mask_threshold: 10.0,
            mask_dilate_px: 1,
            counts: EvalCounts::default(),
            rows: vec![row],
            estimators: BTreeMap::new(),
            comparisons: Vec::new(),
            pairs: Vec::new(),
        };
        let md = report.to_markdown();
        assert!(md.contains("n/a") && !md.contains("NaN"), "{md}");
        assert!(report.to_json().contains("\"ssim\": null"));
    }

    fn record(pair: usize, method: Method, contact_ssim: Option<f64>, position: Option<f64>, yaw: Option<f64>) -> PairRecord {
        PairRecord {
            pair,
            object: "edge".into(),
            sensor: "vitac".into(),
            pose_id: pair as u32,
            x_mm: 0.0,
            y_mm: 0.0,
            z_mm: 0.0,
            yaw_deg: 0.0,
            method: method.label(),
            ssim: contact_ssim,
            contact_ssim,
            position_err_mm: position,
            yaw_err_deg: yaw,
            position_vs_true_mm: None,
            yaw_vs_true_deg: None,
            psnr_db: None,
            mse: None,
            contact_psnr_db: None,
            contact_mse: None,
            mesh_contact: position.is_some(),
            yaw_observable: yaw.is_some(),
        }
    }

    #[test]
    fn bootstrap_interval_is_tight_on_constants_and_covers_the_mean() {
        let (m, ci) = bootstrap_mean_interval(&[0.25; 30]).expect("interval");
        assert_eq!((m, ci), (0.25, [0.25, 0.25]));
        // -1, +1 alternating: mean 0, an interval around it, narrower than the data's range.
        let d: Vec<f64> = (0..40).map(|i| if i % 2 == 0 { -1.0 } else { 1.0 }).collect();
        let (m, [lo, hi]) = bootstrap_mean_interval(&d).expect("interval");
        assert_eq!(m, 0.0);
        assert!(lo < 0.0 && hi > 0.0 && lo > -0.6 && hi < 0.6, "[{lo}, {hi}]");
        // The standard error of that mean is 1/sqrt(40) = 0.158: the 95% interval is about +-0.31.
        assert!((hi - lo - 2.0 * 1.96 / 40f64.sqrt()).abs() < 0.1, "[{lo}, {hi}]");
        assert_eq!(bootstrap_mean_interval(&d), bootstrap_mean_interval(&d), "same data, same interval");
        assert!(bootstrap_mean_interval(&[]).is_none());
        assert!(bootstrap_mean_interval(&[1.0, f64::NAN]).is_none());
    }

    #[test]
    fn paired_comparisons_give_verdicts_on_common_pairs_only() {
        let mut pairs = Vec::new();
        for i in 0..20 {
            let wobble = if i % 2 == 0 { 0.01 } else { -0.01 };
            // Model: contact SSIM 0.1 higher (better); position 0.5 mm lower (better); yaw
            // 1 deg higher (worse) except where the baseline found none.
            pairs.push(record(i, Method::Model, Some(0.9 + wobble), Some(0.5 + wobble), Some(2.0 + wobble)));
            pairs.push(record(i, Method::NearestNeighbour, Some(0.8), Some(1.0), (i < 15).then_some(1.0)));
            // Pose-blind: the same as the model up to noise of both signs.
            pairs.push(record(i, Method::PoseBlind, Some(0.9 - wobble), Some(0.5 - wobble), Some(2.0 - wobble)));
            pairs.push(record(i, Method::TrueImage, None, Some(0.4), Some(1.0)));
        }
        let c = paired_comparisons(&pairs);
        let find = |b: Method, f: Figure| c.iter().find(|x| x.baseline == b && x.figure == f).expect("comparison");
        let nn_ssim = find(Method::NearestNeighbour, Figure::ContactSsim);
        assert_eq!((nn_ssim.n, nn_ssim.verdict), (20, Verdict::ModelBetter), "{nn_ssim:?}");
        assert!((nn_ssim.difference - 0.1).abs() < 1e-12);
        assert_eq!(find(Method::NearestNeighbour, Figure::PositionErr).verdict, Verdict::ModelBetter);
        let nn_yaw = find(Method::NearestNeighbour, Figure::YawErr);
        assert_eq!((nn_yaw.n, nn_yaw.verdict), (15, Verdict::ModelWorse), "only the 15 pairs where both found a yaw: {nn_yaw:?}");
        // The ceilings: the true image in the model's place.
        let ceiling = |b: Method, f: Figure| find(b, f).true_image.clone().expect("ceiling");
        let ssim = ceiling(Method::NearestNeighbour, Figure::ContactSsim);
        assert_eq!((ssim.n, ssim.true_mean), (20, 1.0), "the true image's contact SSIM is 1: {ssim:?}");
        assert!((ssim.difference - 0.2).abs() < 1e-12 && ssim.winnable(), "{ssim:?}");
        let pos = ceiling(Method::NearestNeighbour, Figure::PositionErr);
        assert!((pos.difference + 0.6).abs() < 1e-12 && pos.winnable(), "true 0.4 mm against 1.0: {pos:?}");
        // The baseline's yaw is as good as the true image's: nobody can beat it, only match it.
        let yaw = ceiling(Method::NearestNeighbour, Figure::YawErr);
        assert_eq!((yaw.n, yaw.difference, yaw.verdict), (15, 0.0, Verdict::NoDifferenceShown), "{yaw:?}");
        assert!(!yaw.winnable());
        // Pose-blind's yaw (2.0) is beaten by the true image (1.0) but not by the model.
        let pb_yaw = find(Method::PoseBlind, Figure::YawErr);
        assert_eq!(pb_yaw.verdict, Verdict::NoDifferenceShown);
        assert!(pb_yaw.true_image.as_ref().is_some_and(Ceiling::winnable), "{pb_yaw:?}");
        for f in Figure::ALL {
            let pb = find(Method::PoseBlind, f);
            assert_eq!(pb.verdict, Verdict::NoDifferenceShown, "{pb:?}");
            assert!(pb.interval95[0] < 0.0 && pb.interval95[1] > 0.0, "{pb:?}");
        }
        let summary = comparison_summary(&c);
        assert!(summary.contains("Against nearest-neighbour: model better on 2 of 3; worse on 1 (vitac yaw err deg)."), "{summary}");
        assert!(
            summary.contains(
                "Against pose-blind: model better on 0 of 3; no difference shown on 3 (winnable, the true image beats the baseline: \
                 vitac contact SSIM, vitac pos err mm, vitac yaw err deg)."
            ),
            "{summary}"
        );
        // A tie the true image cannot break either is listed as not winnable.
        let mut floor = find(Method::NearestNeighbour, Figure::YawErr).clone();
        floor.verdict = Verdict::NoDifferenceShown;
        let summary = comparison_summary(&[floor]);
        assert!(
            summary.contains("no difference shown on 1 (not winnable here, even the true image shows none: vitac yaw err deg)"),
            "{summary}"
        );
        // Too few pairs: no verdict, whatever the difference.
        let few: Vec<PairRecord> = pairs.iter().filter(|p| p.pair < MIN_PAIRS_FOR_VERDICT - 1).cloned().collect();
        assert!(paired_comparisons(&few).iter().all(|x| x.verdict == Verdict::TooFewPairs));
        assert!(paired_comparisons(&[]).is_empty());
    }
}
