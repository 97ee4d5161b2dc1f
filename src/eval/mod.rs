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
//!
//! One file per concern, each using only those listed before it:
//!
//! - [`error`] holds [`EvalError`].
//! - [`pairing`] reads the datasets of each side, keys them by object and sensor, pairs their
//!   rows by commanded pose ([`same_pose`]) and loads images at the measuring size.
//! - [`contact`] estimates contacts ([`ContactEstimator`], [`estimate_contact_with`]), finds
//!   the contact region ([`contact_mask`]) and the mesh contact ([`geometric_contact`]).
//! - [`baselines`] builds the pose-blind mean and the nearest neighbour ([`pose_distance`],
//!   [`warp_to_pose`]).
//! - [`records`] holds what is recorded per pair ([`PairRecord`], [`EvalCounts`]).
//! - [`statistics`] takes the table's means ([`MethodRow`]) and the paired comparisons.
//! - [`judge`] judges one pair: every method's figures and pose errors.
//! - [`report`] writes [`EvalReport`] as Markdown, JSON and CSV.
//! - [`run`] is the run, [`evaluate()`] with its [`EvalOptions`].
//! - [`audit`] scores a dataset's synthesised poses against the same poses collected again
//!   (`rig audit`), with MultiDiffSense's grey min-max SSIM and PSNR beside rig's.
//! - [`regressor`] is the pose regressor (ResNet18's layout, candle) and its training;
//!   [`downstream`] is MultiDiffSense's downstream protocol on it (`rig eval --downstream`):
//!   trained on captured, mixed and synthetic rows, scored on held-out captured rows;
//!   [`downstream_notes`] the warnings its table ends with (small test sets, components the
//!   images cannot show).
//! - [`compare_real`] scores rendered frames against real frames of logged poses, beside the
//!   pose-blind baseline (`rig compare-real`).

pub mod audit;
pub mod baselines;
pub mod compare_real;
pub mod contact;
pub mod downstream;
pub mod downstream_notes;
pub mod error;
pub mod judge;
pub mod pairing;
pub mod records;
pub mod regressor;
pub mod report;
pub mod run;
pub mod statistics;

pub use baselines::{NN_YAW_DEG_PER_MM, pose_distance, warp_to_pose};
pub use contact::{
    ContactEstimate, ContactEstimator, EstimatorParseError, ISOTROPY_RATIO, axis_difference_deg, contact_mask, estimate_contact,
    estimate_contact_with, geometric_contact, yaw_observable,
};
pub use error::EvalError;
pub use pairing::{POSE_TOLERANCE, same_pose};
pub use records::{EvalCounts, Method, PairRecord};
pub use report::EvalReport;
pub use run::{EvalOptions, MIN_SIZE_PX, evaluate};
pub use statistics::{
    BOOTSTRAP_RESAMPLES, Ceiling, Figure, MIN_PAIRS_FOR_VERDICT, MethodRow, PairedComparison, Verdict, bootstrap_mean_interval,
    comparison_summary, paired_comparisons,
};

/// Test images shared by the unit tests of the files above.
#[cfg(test)]
pub(crate) mod test_images {
    use image::{Rgb, RgbImage};

    /// A bright ellipse (half-axes `rx`, `ry`, centre (`cx`, `cy`)) on a dark `size` square.
    pub fn disc(size: u32, cx: f64, cy: f64, rx: f64, ry: f64) -> RgbImage {
        RgbImage::from_fn(size, size, |x, y| {
            let (u, v) = ((x as f64 + 0.5 - cx) / rx, (y as f64 + 0.5 - cy) / ry);
            let v = if u * u + v * v < 1.0 { 200 } else { 20 };
            Rgb([v, v, v])
        })
    }
}
