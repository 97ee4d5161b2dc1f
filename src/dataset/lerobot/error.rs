//! The LeRobot export's errors, apart so that the export and its rolling files share them.

use std::path::{Path, PathBuf};

use crate::dataset::DatasetError;

/// Errors of the LeRobot export.
#[derive(Debug, thiserror::Error)]
pub enum LerobotError {
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    #[error("{root} holds no rig dataset (no manifest.toml in it, nor in <object>/<sensor>/ below it)")]
    NoDatasets { root: PathBuf },
    /// The datasets cannot form one LeRobot dataset as they are.
    #[error("cannot export these datasets as one LeRobot dataset: {reason}")]
    Layout { reason: String },
    #[error("{out} exists and is not an empty folder; refusing to overwrite it (give a new --out)")]
    OutNotEmpty { out: PathBuf },
    #[error("{0}")]
    BadOption(String),
    /// One row (a frame with its images, or an episode's record) does not fit a file.
    #[error(
        "a row of {kind} takes about {row_bytes} bytes with the file's overhead, more than a file may hold ({bound_bytes} bytes): raise --max-file-mb"
    )]
    RowTooLarge { kind: &'static str, row_bytes: u64, bound_bytes: u64 },
    #[error("writing {path}: {reason}")]
    Write { path: PathBuf, reason: String },
}

/// An I/O error as the dataset module reports it (a full disk says what to do).
pub(super) fn io_err(op: &'static str, path: &Path) -> impl FnOnce(std::io::Error) -> LerobotError {
    let to_dataset = DatasetError::io(op, path);
    move |source| LerobotError::Dataset(to_dataset(source))
}

pub(super) fn write_err(path: &Path, e: impl std::fmt::Display) -> LerobotError {
    LerobotError::Write { path: path.to_path_buf(), reason: e.to_string() }
}
