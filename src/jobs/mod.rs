//! Jobs: one typed request per job, validated once, and one runner each.
//!
//! | job | request | runner | front ends |
//! |---|---|---|---|
//! | collect | [`CollectRequest`] | [`collect::run`] | `rig collect`, daemon `collect`, `rig replay`, `rig bench` |
//! | fill | [`FillRequest`] | [`fill::run`] | `rig synth --fill-missing` / `--poses-of`, daemon `synth` |
//! | replay | a recording's header ([`replay::setup_of`]) | [`replay::run`] (over [`collect::run`]) | `rig replay` |
//! | calibrate | [`CalibrateRequest`] | [`calibrate::run`] | `rig calibrate`, daemon `calibrate`, `rig bench` |
//! | audit | [`AuditRequest`] | [`audit::run`] (over [`collect::run`]), then [`audit::score`] | `rig audit` |
//!
//! A request is a serde type ([`request`]): the CLI turns its clap arguments into one, the
//! daemon deserialises the same type from a job's JSON ([`JobRequest`]), and replay and bench
//! build one in code. Each request checks itself ([`JobRequest::check`]), then resolves itself
//! against the rig's configuration and files before anything moves or loads (`prepare`,
//! `targets`, beside each runner), so every front end refuses the same inputs with the same
//! errors.
//! The runners take the request, the hardware the front end opened (an [`crate::arm::Arm`],
//! [`crate::camera::Camera`]s; never a backend by name: opening a rig is `rigs`' job, above
//! this module), and an [`Observer`] for progress and cancellation.

// A job's error is returned once per job, not in a hot loop; its variants keep the library
// errors whole (unboxed) so that the exit-code table can find them by type in the chain.
#![allow(clippy::result_large_err)]

pub mod adaptive;
pub mod audit;
pub mod calibrate;
pub mod collect;
pub mod fill;
pub mod replay;
pub mod request;

use std::path::PathBuf;

use tokio::sync::watch;

pub use request::{
    AdaptiveRequest, AuditRequest, CalibrateRequest, CollectRequest, Confine, FillRequest, JobRequest, Reader, RequestError,
    check_plain_name,
};

impl JobError {
    /// An option the command would reject (exit code 2), refused after the request's own
    /// checks (by what it names, or by where it runs).
    pub fn bad_option(field: &'static str, reason: impl Into<String>) -> JobError {
        RequestError::BadOption { field, reason: reason.into() }.into()
    }

    /// A [`JobError::Fill`] for `dir`, for `map_err`.
    pub fn fill(action: &'static str, dir: &std::path::Path) -> impl FnOnce(crate::synth::fill::FillError) -> JobError {
        let dir = dir.to_path_buf();
        move |source| JobError::Fill { action, dir, source }
    }
}

/// What a runner reports to, and is stopped by: a progress bar (hidden, or drawn by the CLI,
/// or read by the daemon's status) and a cancel flag (Ctrl-C, or a daemon cancel request)
/// checked at the job's safe points.
#[derive(Debug, Clone)]
pub struct Observer {
    pub progress: indicatif::ProgressBar,
    pub cancel: watch::Receiver<bool>,
}

impl Observer {
    /// A hidden progress bar and no way to cancel (tests, replay, bench).
    pub fn hidden() -> Self {
        let (_, cancel) = watch::channel(false);
        Self { progress: indicatif::ProgressBar::hidden(), cancel }
    }

    /// True once a stop was asked for.
    pub fn cancelled(&self) -> bool {
        *self.cancel.borrow()
    }
}

/// Why a job failed. Each variant keeps the library error as its source, so the exit-code
/// table ([`crate::report::exit_code`]) finds it in the chain.
#[derive(Debug, thiserror::Error)]
pub enum JobError {
    #[error("{0}")]
    Plan(#[from] crate::plan::PlanError),
    #[error("{0}")]
    Object(#[from] crate::geometry::objects::ObjectResolveError),
    #[error("{0}")]
    Profile(#[from] crate::arm::profile::ProfileLookupError),
    #[error("{0}")]
    Collect(#[from] crate::collect::CollectError),
    #[error("opening dataset {dir}: {source}")]
    Dataset {
        dir: PathBuf,
        #[source]
        source: crate::dataset::DatasetError,
    },
    #[error("{action} {dir}: {source}")]
    Fill {
        action: &'static str,
        dir: PathBuf,
        #[source]
        source: crate::synth::fill::FillError,
    },
    #[error("loading model package {model}: {source}")]
    Model {
        model: PathBuf,
        #[source]
        source: crate::synth::SynthError,
    },
    #[error("{0}")]
    Press(#[from] crate::calibration::press::PressError),
    /// A pose outside the workspace or past the press limit, refused before anything moved.
    #[error("{0}")]
    Fence(#[from] crate::fence::FenceError),
    #[error("saving the calibration {path}: {reason}")]
    SaveCalibration { path: PathBuf, reason: String },
    /// A request refused before anything was read or loaded: an option out of its bounds, a
    /// path outside the data roots.
    #[error("{0}")]
    Request(#[from] RequestError),
    /// A sampling or size setting out of its bounds.
    #[error("{0}")]
    Settings(#[from] crate::synth::SynthError),
    #[error("sensor {sensor} is not open here (open: {opened})")]
    SensorNotOpen { sensor: crate::sensor::SensorKind, opened: String },
    #[error("{0}")]
    Replay(#[from] crate::record::replay::ReplayError),
    /// Scoring an audit: the datasets could not be paired or read.
    #[error("scoring the audit of {dataset}: {source}")]
    Audit {
        dataset: PathBuf,
        #[source]
        source: crate::eval::EvalError,
    },
    #[error("writing {path}: {reason}")]
    AuditWrite { path: PathBuf, reason: String },
    #[error("the synth worker thread stopped: {reason}")]
    Worker { reason: String },
}
