//! The error of a bench run or of writing its report.

use std::path::{Path, PathBuf};

use super::knob::Knob;

/// Errors of a bench run or of writing its report.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("plot {path}: {reason}")]
    Plot { path: PathBuf, reason: String },
    #[error("{0}")]
    Rig(#[from] crate::rigs::RigError),
    #[error("{0}")]
    Collect(#[from] crate::collect::CollectError),
    #[error("{0}")]
    Job(#[from] crate::jobs::JobError),
    #[error("{0}")]
    Dataset(#[from] crate::dataset::DatasetError),
    #[error("{0}")]
    Press(#[from] crate::calibration::press::PressError),
    #[error("{0}")]
    Synth(#[from] crate::synth::SynthError),
    #[error("{0}")]
    Plan(#[from] crate::plan::PlanError),
    #[error("{0}")]
    Metrics(#[from] crate::metrics::MetricsError),
    #[error("{0}")]
    Object(#[from] crate::geometry::objects::ObjectError),
    /// A stage's `rig` command (a child process) failed.
    #[error("`{command}` failed ({status}):\n{output}")]
    Child { command: String, status: String, output: String },
    #[error("{knob}: nothing to measure ({reason})")]
    Empty { knob: Knob, reason: &'static str },
}

impl BenchError {
    pub(crate) fn io(path: &Path, source: std::io::Error) -> Self {
        Self::Io { path: path.to_path_buf(), source }
    }
}
