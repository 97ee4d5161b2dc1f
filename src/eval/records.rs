//! What is recorded per pair: whose image was judged ([`Method`]), its figures
//! ([`PairRecord`]), and what was counted rather than measured ([`EvalCounts`]).

use serde::Serialize;

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
