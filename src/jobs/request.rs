//! The job requests: what a job is asked, as the CLI builds it and the daemon's `POST
//! /api/jobs` deserialises it, with the checks that need no file ([`JobRequest::check`]) and the
//! confinement of its paths to the daemon's data roots ([`JobRequest::confine`]).
//!
//! This file stands alone: it uses only [`crate::sensor`], [`crate::roots`],
//! [`crate::synth::settings`] and [`crate::synth::limits`] (std, serde, clap and thiserror
//! beneath them), so the daemon's decoding and validation is fuzzed on its own
//! (`fuzz/fuzz_targets/job_request.rs`). What a job does with a request (plans, datasets,
//! models) is in the job's own module, beside its runner.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::roots::{DataRoots, PathError, check_length};
use crate::sensor::{SensorKind, SensorSet};
use crate::synth::limits::BadSetting;
use crate::synth::settings::{ImageRange, SchedulerKind, Shard, TwinSize, defaults};

/// Why a request was refused before anything was read or loaded.
#[derive(Debug, thiserror::Error)]
pub enum RequestError {
    /// An option the command would reject (exit code 2).
    #[error("{field}: {reason}")]
    BadOption { field: &'static str, reason: String },
    /// A path outside the daemon's data roots, or one that cannot be resolved there.
    #[error("{0}")]
    Path(#[from] PathError),
    /// A sampling or size setting out of its bounds.
    #[error("{0}")]
    Setting(#[from] BadSetting),
}

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
    /// `rig audit`.
    Audit(AuditRequest),
    /// `rig collect --adaptive`.
    Adaptive(AdaptiveRequest),
}

impl JobRequest {
    /// `collect`, `synth`, `calibrate`, `audit` or `adaptive`.
    pub fn kind(&self) -> &'static str {
        match self {
            JobRequest::Collect(_) => "collect",
            JobRequest::Synth(_) => "synth",
            JobRequest::Calibrate(_) => "calibrate",
            JobRequest::Audit(_) => "audit",
            JobRequest::Adaptive(_) => "adaptive",
        }
    }

    /// Checks every setting that needs no file: numbers within their bounds (so nothing is
    /// allocated from an absurd size), names that become file names plain. The preparing
    /// steps of each job call the same check, so the CLI refuses what the daemon refuses.
    pub fn check(&self) -> Result<(), RequestError> {
        match self {
            JobRequest::Collect(r) => r.check(),
            JobRequest::Synth(r) => r.check(),
            JobRequest::Calibrate(r) => r.check(),
            JobRequest::Audit(r) => r.check(),
            JobRequest::Adaptive(r) => r.check(),
        }
    }

    /// The request with every path it names resolved inside `roots` (symlinks followed,
    /// relative paths from the roots' base), paths it writes may not exist yet but must land
    /// there. Paths it reads must exist when the job starts ([`Confine::Starting`]); when it is
    /// submitted ([`Confine::Submitted`]) they may still be missing, as an earlier job in the
    /// queue may write them (a collection, then a fill of its dataset), but must lie inside
    /// the roots all the same. A refused path is named as the request gave it.
    pub fn confine(&mut self, roots: &DataRoots, when: Confine) -> Result<(), RequestError> {
        let read = Reader { roots, when };
        match self {
            JobRequest::Collect(r) => r.confine(&read),
            JobRequest::Synth(r) => r.confine(&read),
            JobRequest::Calibrate(r) => r.confine(roots),
            JobRequest::Audit(r) => r.confine(&read),
            JobRequest::Adaptive(r) => r.confine(&read),
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
    pub fn input(&self, field: &str, given: &std::path::Path) -> Result<PathBuf, PathError> {
        match self.when {
            Confine::Starting => self.roots.input(field, given),
            Confine::Submitted => self.roots.output(field, given),
        }
    }
}

/// `Some(path)` resolved by `resolve`, `None` left alone.
fn confine_opt(
    path: &mut Option<PathBuf>,
    resolve: impl FnOnce(&std::path::Path) -> Result<PathBuf, PathError>,
) -> Result<(), RequestError> {
    if let Some(p) = path.as_mut() {
        *p = resolve(p)?;
    }
    Ok(())
}

/// Each path a request names, as `(field, path)`, checked with [`check_length`].
fn check_paths<'a>(paths: impl IntoIterator<Item = (&'static str, Option<&'a std::path::Path>)>) -> Result<(), RequestError> {
    for (field, path) in paths.into_iter().filter_map(|(field, path)| path.map(|p| (field, p))) {
        check_length(field, path)?;
    }
    Ok(())
}

/// A name that becomes a folder or file name (an object name): not empty, at most 100 bytes,
/// no path separator, no control character, not starting with a dot.
pub fn check_plain_name(field: &'static str, name: &str) -> Result<(), RequestError> {
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
        Some(reason) => Err(RequestError::BadOption { field, reason: format!("{reason}: it must be a plain name (it names a folder)") }),
        None => Ok(()),
    }
}

/// A collection: the options of `rig collect` (see its `--help`), the body of a daemon
/// `collect` job. Fields left out take these defaults.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CollectRequest {
    /// Object name from the object library (`datasets/objects/<name>.stl`).
    pub object: String,
    /// Object STL file instead of a library name (its stem names the object).
    pub stl: Option<PathBuf>,
    /// The sensors to capture.
    pub sensor: SensorSet,
    /// Plan file (TOML); `poses` and `seed` override its fields.
    pub plan: Option<PathBuf>,
    /// Number of poses to sample from the grid.
    pub poses: Option<usize>,
    /// Seed of the sampling (and of the simulated sensors' noise).
    pub seed: Option<u64>,
    /// Output root; datasets go to `<out>/<object>/<sensor>/`.
    pub out: PathBuf,
    /// Continue a killed run (or start one when none exists).
    pub resume: bool,
}

impl Default for CollectRequest {
    fn default() -> Self {
        Self {
            object: "sphere".into(),
            stl: None,
            sensor: SensorSet::all(),
            plan: None,
            poses: None,
            seed: None,
            out: PathBuf::from("datasets"),
            resume: false,
        }
    }
}

impl CollectRequest {
    /// Checks what needs no file: the object name is a plain name (it names the dataset's
    /// folder). The pose count is checked against the plan's grid by [`Self::plan_spec`].
    pub fn check(&self) -> Result<(), RequestError> {
        if self.stl.is_none() {
            check_plain_name("object", &self.object)?;
        }
        check_paths([("stl", self.stl.as_deref()), ("plan", self.plan.as_deref()), ("out", Some(self.out.as_path()))])
    }

    /// Resolves `stl` and `plan` (read) and `out` (written) inside `roots`.
    pub fn confine(&mut self, read: &Reader<'_>) -> Result<(), RequestError> {
        confine_opt(&mut self.stl, |p| read.input("stl", p))?;
        confine_opt(&mut self.plan, |p| read.input("plan", p))?;
        self.out = read.roots.output("out", &self.out)?;
        Ok(())
    }
}

/// A synthesis: the options of `rig synth --fill-missing` and `--poses-of` (see their
/// `--help`), the body of a daemon `synth` job. Fields left out take these defaults; sampling
/// settings left out take the model package's own (`model.toml`), else rig's.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FillRequest {
    /// A dataset (`.../<object>/<sensor>`) or a folder holding several (two levels deep).
    pub dataset: PathBuf,
    /// Twins mode: synthesise exactly the real poses of this dataset (or of every dataset
    /// under this folder) into `out`, mirroring `<object>/<sensor>`.
    pub poses_of: Option<PathBuf>,
    /// Model package directory (default: `models/default`, else the tiny test package).
    pub model: Option<PathBuf>,
    /// Only part i of n of the poses (`"i/n"`), written to `out`.
    pub shard: Option<Shard>,
    /// Where the synthetic rows go (required with `shard` and `poses_of`; default: into the
    /// dataset itself).
    pub out: Option<PathBuf>,
    /// Sampling steps.
    pub steps: Option<usize>,
    /// Classifier-free guidance scale (1: unguided).
    pub guidance: Option<f32>,
    /// DDIM eta (0: deterministic); none: the package's `eta`, else 0.
    pub eta: Option<f32>,
    /// `ddim` or `dpm++2m`.
    pub sampler: Option<SchedulerKind>,
    /// ControlNet conditioning scale (1: as trained).
    pub conditioning_scale: f32,
    /// Poses per model call.
    pub batch: usize,
    /// Supersampling factor of the control image's depth map.
    pub supersample: u32,
    /// How the model's output becomes 8-bit pixels: `clamp` (the default) or `minmax` (each
    /// image stretched from its own min to its own max, as MultiDiffSense saves).
    pub image_range: ImageRange,
    /// At most this many poses per dataset (after sharding).
    pub limit: Option<usize>,
    /// Twins mode: the twins' image size.
    pub twin_size: TwinSize,
}

impl Default for FillRequest {
    fn default() -> Self {
        Self {
            dataset: PathBuf::from("datasets"),
            poses_of: None,
            model: None,
            shard: None,
            out: None,
            steps: None,
            guidance: None,
            eta: None,
            sampler: None,
            conditioning_scale: defaults::CONDITIONING_SCALE,
            batch: defaults::BATCH,
            supersample: defaults::SUPERSAMPLE,
            image_range: ImageRange::default(),
            limit: None,
            twin_size: TwinSize::default(),
        }
    }
}

impl FillRequest {
    /// Checks the sampling settings against [`crate::synth::limits`] before any model loads
    /// (settings left to the package are checked when it is read).
    pub fn check(&self) -> Result<(), RequestError> {
        crate::synth::limits::check_fill_settings(
            self.steps,
            self.guidance,
            self.eta,
            self.conditioning_scale,
            self.batch,
            self.supersample,
        )?;
        check_paths([
            ("dataset", Some(self.dataset.as_path())),
            ("poses_of", self.poses_of.as_deref()),
            ("model", self.model.as_deref()),
            ("out", self.out.as_deref()),
        ])
    }

    /// Resolves `dataset`, `poses_of` and `model` (read) and `out` (written) inside `roots`.
    /// The default model (`model` left out) is rig's own package, not a path of the request.
    pub fn confine(&mut self, read: &Reader<'_>) -> Result<(), RequestError> {
        if self.poses_of.is_none() {
            self.dataset = read.input("dataset", &self.dataset)?;
        }
        confine_opt(&mut self.poses_of, |p| read.input("poses_of", p))?;
        confine_opt(&mut self.model, |p| read.input("model", p))?;
        confine_opt(&mut self.out, |p| read.roots.output("out", p))?;
        Ok(())
    }
}

/// An automatic calibration: the options of `rig calibrate` (see its `--help`), the body of a
/// daemon `calibrate` job. Fields left out take these defaults.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CalibrateRequest {
    /// The sensor to calibrate.
    pub sensor: SensorKind,
    /// Where to save the calibration (default `calibration/<sensor>.toml`).
    pub out: Option<PathBuf>,
    /// Presses per axis of the grid.
    pub grid: usize,
    /// Half the grid's side, mm.
    pub span_mm: f64,
    /// Extra indentations (mm) pressed at a 3 x 3 layer each, for the depth-dependent scale.
    pub depths_mm: Vec<f64>,
}

impl Default for CalibrateRequest {
    fn default() -> Self {
        Self { sensor: SensorKind::TacTip, out: None, grid: 5, span_mm: 4.0, depths_mm: vec![-0.5, 0.5] }
    }
}

/// Most presses per axis of a calibration grid (a 21 x 21 grid is 441 presses).
pub const MAX_GRID: usize = 21;
/// Most extra depth layers.
pub const MAX_DEPTH_LAYERS: usize = 8;
/// Largest half span of the grid, mm (larger than any sensor's skin).
pub const MAX_SPAN_MM: f64 = 30.0;
/// Largest extra indentation either way, mm.
pub const MAX_EXTRA_DEPTH_MM: f64 = 5.0;

impl CalibrateRequest {
    /// Checks the pattern's numbers before a pattern is built: grid 2 to [`MAX_GRID`] presses
    /// a side, half span above 0 and at most [`MAX_SPAN_MM`], at most [`MAX_DEPTH_LAYERS`]
    /// finite extra depths within ±[`MAX_EXTRA_DEPTH_MM`].
    pub fn check(&self) -> Result<(), RequestError> {
        let bad = |field, reason: String| Err(RequestError::BadOption { field, reason });
        if !(2..=MAX_GRID).contains(&self.grid) {
            return bad("grid", format!("{} presses a side: must be 2 to {MAX_GRID}", self.grid));
        }
        if !(self.span_mm.is_finite() && self.span_mm > 0.0 && self.span_mm <= MAX_SPAN_MM) {
            return bad("span_mm", format!("{}: must be above 0 and at most {MAX_SPAN_MM} mm", self.span_mm));
        }
        if self.depths_mm.len() > MAX_DEPTH_LAYERS {
            return bad("depths_mm", format!("{} layers: at most {MAX_DEPTH_LAYERS}", self.depths_mm.len()));
        }
        if let Some(d) = self.depths_mm.iter().find(|d| !(d.is_finite() && d.abs() <= MAX_EXTRA_DEPTH_MM)) {
            return bad("depths_mm", format!("{d}: each must be within ±{MAX_EXTRA_DEPTH_MM} mm"));
        }
        check_paths([("out", self.out.as_deref())])
    }

    /// Resolves `out` (written) inside `roots`; the default, `calibration/<sensor>.toml`, is
    /// resolved from the roots' base.
    pub fn confine(&mut self, roots: &DataRoots) -> Result<(), RequestError> {
        self.out = Some(roots.output("out", &self.out_path())?);
        Ok(())
    }

    /// Where the calibration is saved.
    pub fn out_path(&self) -> PathBuf {
        self.out.clone().unwrap_or_else(|| self.sensor.calibration_path())
    }
}

/// An audit of a dataset's synthesised poses: the options of `rig audit` (see its `--help`).
/// Fields left out take these defaults.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AuditRequest {
    /// The dataset (`.../<object>/<sensor>`) whose synthetic rows are audited.
    pub dataset: PathBuf,
    /// Share of its synthetic poses to collect again, above 0 and at most 1 (at least one pose).
    pub fraction: f64,
    /// Seed of the draw.
    pub seed: u64,
    /// Fail (exit 1) when the mean contact-region SSIM is below this bound.
    pub min_ssim: Option<f64>,
    /// The object's STL file, when the dataset's object is not in the object library.
    pub stl: Option<PathBuf>,
    /// Every image is resized to this many pixels square before it is measured.
    pub size_px: u32,
}

impl Default for AuditRequest {
    fn default() -> Self {
        Self { dataset: PathBuf::from("datasets"), fraction: 0.1, seed: 0, min_ssim: None, stl: None, size_px: 128 }
    }
}

/// Largest measuring size of an audit, px.
pub const MAX_AUDIT_SIZE_PX: u32 = 1024;

impl AuditRequest {
    /// Checks the numbers: fraction in (0, 1], `min_ssim` in [-1, 1], size 11 to
    /// [`MAX_AUDIT_SIZE_PX`].
    pub fn check(&self) -> Result<(), RequestError> {
        let bad = |field, reason: String| Err(RequestError::BadOption { field, reason });
        if !(self.fraction.is_finite() && self.fraction > 0.0 && self.fraction <= 1.0) {
            return bad("fraction", format!("{}: must be above 0 and at most 1", self.fraction));
        }
        if let Some(m) = self.min_ssim
            && !(m.is_finite() && (-1.0..=1.0).contains(&m))
        {
            return bad("min_ssim", format!("{m}: SSIM lies in [-1, 1]"));
        }
        if !(11..=MAX_AUDIT_SIZE_PX).contains(&self.size_px) {
            return bad("size_px", format!("{}: must be 11 (the SSIM window) to {MAX_AUDIT_SIZE_PX}", self.size_px));
        }
        check_paths([("dataset", Some(self.dataset.as_path())), ("stl", self.stl.as_deref())])
    }

    /// Resolves `dataset` and `stl` (read) inside `roots`; the audit folder is written inside
    /// the dataset.
    pub fn confine(&mut self, read: &Reader<'_>) -> Result<(), RequestError> {
        self.dataset = read.input("dataset", &self.dataset)?;
        confine_opt(&mut self.stl, |p| read.input("stl", p))?;
        Ok(())
    }
}

/// Most presses an adaptive collection may ask for: the most poses a plan can have
/// (`crate::plan::MAX_GRID_POINTS`, held equal where both are compiled: `jobs::adaptive`); its
/// choices are one line each of the dataset's `adaptive.csv`, read up to that many. A number
/// here, as the fuzz target that compiles this file has no plan module.
pub const MAX_BUDGET: usize = 1_000_000;
/// Most rounds an adaptive collection may ask for.
pub const MAX_ROUNDS: usize = 100;
/// Most seeds per scored pose.
pub const MAX_SEEDS_PER_POSE: usize = 16;

/// An adaptive collection: the options of `rig collect --adaptive` (see its `--help`), the body
/// of a daemon `adaptive` job. `collect` is the collection itself, as a `collect` job's body
/// (`{"kind": "adaptive", "collect": {"object": "edge"}, "budget": 30}`); fields left out take
/// these defaults, and `budget` must be given.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AdaptiveRequest {
    pub collect: CollectRequest,
    /// Real presses in all (1 to the plan's poses, at most [`MAX_BUDGET`]).
    pub budget: usize,
    /// Rounds the presses are split over.
    pub rounds: usize,
    /// Model images per scored pose, each with its own seed (the spread over seeds).
    pub seeds_per_pose: usize,
    /// Model package directory (default: `models/default`, else the tiny test package).
    pub model: Option<PathBuf>,
    /// Sampling steps of the model's images (default: the package's, else rig's).
    pub steps: Option<usize>,
}

impl Default for AdaptiveRequest {
    fn default() -> Self {
        Self { collect: CollectRequest::default(), budget: 0, rounds: 4, seeds_per_pose: 4, model: None, steps: None }
    }
}

impl AdaptiveRequest {
    /// Checks what needs no plan: the collection's own check, a budget of 1 to [`MAX_BUDGET`]
    /// presses, 1 to [`MAX_ROUNDS`] rounds and at most one per press, 2 to
    /// [`MAX_SEEDS_PER_POSE`] seeds, the sampling steps within their bounds. The budget against
    /// the plan's poses is checked when the plan is read (`AdaptiveRequest::check_plan`).
    pub fn check(&self) -> Result<(), RequestError> {
        let bad = |field, reason: String| Err(RequestError::BadOption { field, reason });
        self.collect.check()?;
        if self.budget == 0 {
            return bad("budget", "0 presses: give the real presses in all (1 to the plan's poses)".to_string());
        }
        if self.budget > MAX_BUDGET {
            return bad("budget", format!("{} presses: at most {MAX_BUDGET}, the most poses a plan can have", self.budget));
        }
        if self.rounds == 0 || self.rounds > MAX_ROUNDS.min(self.budget) {
            return bad(
                "rounds",
                format!("{}: must be from 1 to {} (at most one round per press)", self.rounds, MAX_ROUNDS.min(self.budget)),
            );
        }
        if !(2..=MAX_SEEDS_PER_POSE).contains(&self.seeds_per_pose) {
            return bad(
                "seeds_per_pose",
                format!("{}: must be from 2 to {MAX_SEEDS_PER_POSE} (a spread needs two images)", self.seeds_per_pose),
            );
        }
        crate::synth::limits::check_steps(self.steps)?;
        check_paths([("model", self.model.as_deref())])
    }

    /// Resolves the collection's paths as a `collect` job's and `model` (read) inside `roots`.
    /// The default model (`model` left out) is rig's own package, not a path of the request.
    pub fn confine(&mut self, read: &Reader<'_>) -> Result<(), RequestError> {
        self.collect.confine(read)?;
        confine_opt(&mut self.model, |p| read.input("model", p))
    }
}
