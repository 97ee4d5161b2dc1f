//! Jobs: one typed request per job, validated once, and one runner each.
//!
//! | job | request | runner | front ends |
//! |---|---|---|---|
//! | collect | [`collect::CollectRequest`] | [`collect::run`] | `rig collect`, daemon `collect`, `rig replay`, `rig bench` |
//! | fill | [`fill::FillRequest`] | [`fill::run`] | `rig synth --fill-missing` / `--poses-of`, daemon `synth` |
//! | replay | a recording's header ([`replay::setup_of`]) | [`replay::run`] (over [`collect::run`]) | `rig replay` |
//! | calibrate | [`calibrate::CalibrateRequest`] | [`calibrate::run`] | `rig calibrate`, daemon `calibrate`, `rig bench` |
//!
//! A request is a serde type: the CLI turns its clap arguments into one, the daemon
//! deserialises the same type from a job's JSON ([`JobRequest`]), and replay and bench build
//! one in code. Each request resolves and checks itself before anything moves or loads
//! (`prepare`/`validate`), so every front end refuses the same inputs with the same errors.
//! The runners take the request, the hardware the front end opened (an [`crate::arm::Arm`],
//! [`crate::camera::Camera`]s; never a backend by name: opening a rig is `rigs`' job, above
//! this module), and an [`Observer`] for progress and cancellation.

// A job's error is returned once per job, not in a hot loop; its variants keep the library
// errors whole (unboxed) so that the exit-code table can find them by type in the chain.
#![allow(clippy::result_large_err)]

pub mod calibrate;
pub mod collect;
pub mod fill;
pub mod replay;

use std::path::PathBuf;

use crate::roots::DataRoots;

use serde::{Deserialize, Serialize};
use tokio::sync::watch;

pub use calibrate::CalibrateRequest;
pub use collect::CollectRequest;
pub use fill::FillRequest;

/// A job, as `POST /api/jobs` takes it: a `kind` and the options of the standalone command of
/// that name (`{"kind": "collect", "object": "edge", "poses": 6}`); fields left out take the
/// command's defaults.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum JobRequest {
    /// `rig collect`.
    Collect(CollectRequest),
    /// `rig synth --fill-missing` (or `--poses-of`).
    Synth(FillRequest),
    /// `rig calibrate` (automatic presses).
    Calibrate(CalibrateRequest),
}

impl JobRequest {
    /// `collect`, `synth` or `calibrate`.
    pub fn kind(&self) -> &'static str {
        match self {
            JobRequest::Collect(_) => "collect",
            JobRequest::Synth(_) => "synth",
            JobRequest::Calibrate(_) => "calibrate",
        }
    }

    /// Checks every setting that needs no file: numbers within their bounds (so nothing is
    /// allocated from an absurd size), names that become file names plain. The preparing
    /// steps of each job call the same check, so the CLI refuses what the daemon refuses.
    pub fn check(&self) -> Result<(), JobError> {
        match self {
            JobRequest::Collect(r) => r.check(),
            JobRequest::Synth(r) => r.check(),
            JobRequest::Calibrate(r) => r.check(),
        }
    }

    /// The request with every path it names resolved inside `roots` (symlinks followed,
    /// relative paths from the roots' base), paths it writes may not exist yet but must land
    /// there. Paths it reads must exist when the job starts ([`Confine::Starting`]); when it is
    /// submitted ([`Confine::Submitted`]) they may still be missing, as an earlier job in the
    /// queue may write them (a collection, then a fill of its dataset), but must lie inside
    /// the roots all the same. A refused path is named as the request gave it.
    pub fn confine(&mut self, roots: &DataRoots, when: Confine) -> Result<(), JobError> {
        let read = Reader { roots, when };
        match self {
            JobRequest::Collect(r) => r.confine(&read),
            JobRequest::Synth(r) => r.confine(&read),
            JobRequest::Calibrate(r) => r.confine(roots),
        }
    }
}

/// When a daemon confines a job's paths.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Confine {
    /// At `POST /api/jobs`: paths read may not exist yet.
    Submitted,
    /// When the job starts: paths read must exist.
    Starting,
}

/// Resolves the paths a job reads, as [`Confine`] says.
pub struct Reader<'a> {
    pub roots: &'a DataRoots,
    pub when: Confine,
}

impl Reader<'_> {
    /// `given` resolved inside the roots; it must exist unless the job is only being submitted.
    pub fn input(&self, field: &str, given: &std::path::Path) -> Result<PathBuf, crate::roots::PathError> {
        match self.when {
            Confine::Starting => self.roots.input(field, given),
            Confine::Submitted => self.roots.output(field, given),
        }
    }
}

/// `Some(path)` resolved by `resolve`, `None` left alone.
fn confine_opt(
    path: &mut Option<PathBuf>,
    resolve: impl FnOnce(&std::path::Path) -> Result<PathBuf, crate::roots::PathError>,
) -> Result<(), JobError> {
    if let Some(p) = path.as_mut() {
        *p = resolve(p)?;
    }
    Ok(())
}

/// A name that becomes a folder or file name (an object name): not empty, at most 100 bytes,
/// no path separator, no control character, not starting with a dot.
pub fn check_plain_name(field: &'static str, name: &str) -> Result<(), JobError> {
    let reason = if name.is_empty() {
        Some("is empty")
    } else if name.len() > 100 {
        Some("is longer than 100 bytes")
    } else if name.starts_with('.') {
        Some("starts with a dot")
    } else if name.chars().any(|c| c == '/' || c == '\\' || c.is_control()) {
        Some("contains a path separator or a control character")
    } else {
        None
    };
    match reason {
        Some(reason) => Err(JobError::BadOption { field, reason: format!("{reason}: it must be a plain name (it names a folder)") }),
        None => Ok(()),
    }
}

impl JobError {
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
    #[error("saving the calibration {path}: {reason}")]
    SaveCalibration { path: PathBuf, reason: String },
    /// A path outside the daemon's data roots, or one that cannot be resolved there.
    #[error("{0}")]
    Path(#[from] crate::roots::PathError),
    /// A sampling or size setting out of its bounds.
    #[error("{0}")]
    Settings(#[from] crate::synth::SynthError),
    /// An option the command would reject (exit code 2).
    #[error("{field}: {reason}")]
    BadOption { field: &'static str, reason: String },
    #[error("sensor {sensor} is not open here (open: {opened})")]
    SensorNotOpen { sensor: crate::sensor::SensorKind, opened: String },
    #[error("{0}")]
    Replay(#[from] crate::record::replay::ReplayError),
    #[error("the synth worker thread stopped: {reason}")]
    Worker { reason: String },
}
