//! What stops an evaluation: missing or inconsistent datasets, all bad input.

use std::path::PathBuf;

use crate::dataset::{DatasetError, REFERENCE_FILE};

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
