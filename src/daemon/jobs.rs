//! The jobs a daemon runs, and how each runs on the opened rig.
//!
//! A [`JobSpec`] is what `POST /api/jobs` takes: a `kind` (`collect`, `synth`, `calibrate`)
//! and the options of the standalone command of that name, in JSON (`{"kind": "collect",
//! "object": "edge", "poses": 6}`); fields left out take the command's defaults. Relative
//! paths are relative to the daemon's working directory.
//!
//! The runners reuse the library jobs ([`CollectJob`], [`fill_missing_observed`],
//! [`run_pattern`]) with the daemon's arm and cameras wrapped in [`LiveArm`] and
//! [`LiveCamera`], so progress, pose and frames reach the status API as they happen.

use std::ops::ControlFlow;
use std::path::PathBuf;
use std::sync::Arc;

use serde::{Deserialize, Serialize};
use tokio::sync::watch;

use super::live::{LiveArm, LiveCamera, png_bytes};
use super::state::DaemonState;
use crate::arm::Arm;
use crate::calibration::detect::ContactDetector;
use crate::calibration::fit::FitOptions;
use crate::calibration::press::{ArmStation, PressError, PressPattern, indenter_mesh, run_pattern};
use crate::clock::Clock;
use crate::collect::{CollectError, CollectJob, SensorStream, check_plan};
use crate::config::RigConfig;
use crate::dataset::{DatasetError, DatasetWriter, Manifest, ObjectInfo};
use crate::plan::{PlanError, PlanSpec};
use crate::rigs::{ObjectChoice, Rig, RigError, SensorChoice};
use crate::sim::sensor::SensorKind;
use crate::synth::fill::{FillError, FillOptions, Shard, fill_missing_observed};
use crate::synth::{Pipeline, RuntimeOptions, SchedulerKind, SynthError};

/// A job to run: the kind and the options of its standalone command.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum JobSpec {
    /// `rig collect`.
    Collect(CollectSpec),
    /// `rig synth --fill-missing`.
    Synth(SynthSpec),
    /// `rig calibrate` (automatic presses).
    Calibrate(CalibrateSpec),
}

impl JobSpec {
    /// `collect`, `synth` or `calibrate`.
    pub fn kind(&self) -> &'static str {
        match self {
            JobSpec::Collect(_) => "collect",
            JobSpec::Synth(_) => "synth",
            JobSpec::Calibrate(_) => "calibrate",
        }
    }
}

/// The options of `rig collect` (see its `--help`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CollectSpec {
    pub object: String,
    pub stl: Option<PathBuf>,
    pub sensor: String,
    pub plan: Option<PathBuf>,
    pub poses: Option<usize>,
    pub seed: Option<u64>,
    pub out: PathBuf,
    pub resume: bool,
}

impl Default for CollectSpec {
    fn default() -> Self {
        Self {
            object: "sphere".into(),
            stl: None,
            sensor: "all".into(),
            plan: None,
            poses: None,
            seed: None,
            out: PathBuf::from("datasets"),
            resume: false,
        }
    }
}

/// The options of `rig synth --fill-missing` (see its `--help`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SynthSpec {
    pub dataset: PathBuf,
    pub model: Option<PathBuf>,
    /// `i/n`.
    pub shard: Option<String>,
    pub out: Option<PathBuf>,
    /// None: the package's `sampling_steps`, else [`FillOptions`]' default.
    pub steps: Option<usize>,
    /// None: the package's `guidance`, else [`FillOptions`]' default.
    pub guidance: Option<f32>,
    /// None: the package's `eta`, else 0.
    pub eta: Option<f32>,
    /// `ddim` or `dpm++2m`; none: the package's `sampler`, else ddim.
    pub sampler: Option<String>,
    /// How the model's output becomes 8-bit pixels (`clamp` or `minmax`).
    pub image_range: crate::synth::ImageRange,
    /// ControlNet conditioning scale (1: as trained).
    pub conditioning_scale: f32,
    pub batch: usize,
    pub supersample: u32,
    pub limit: Option<usize>,
    /// ONNX Runtime library or its folder.
    pub ort_lib: Option<PathBuf>,
}

impl Default for SynthSpec {
    fn default() -> Self {
        let d = FillOptions::default();
        Self {
            dataset: PathBuf::from("datasets"),
            model: None,
            shard: None,
            out: None,
            steps: None,
            guidance: None,
            eta: None,
            sampler: None,
            image_range: d.image_range,
            conditioning_scale: d.conditioning_scale,
            batch: d.batch,
            supersample: d.supersample,
            limit: None,
            ort_lib: None,
        }
    }
}

/// The options of automatic `rig calibrate` (see its `--help`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CalibrateSpec {
    pub sensor: String,
    /// Default `calibration/<sensor>.toml`.
    pub out: Option<PathBuf>,
    pub grid: usize,
    pub span_mm: f64,
    pub depths_mm: Vec<f64>,
}

impl Default for CalibrateSpec {
    fn default() -> Self {
        Self { sensor: "tactip".into(), out: None, grid: 5, span_mm: 4.0, depths_mm: vec![-0.5, 0.5] }
    }
}

/// Why a job failed.
#[derive(Debug, thiserror::Error)]
pub enum JobError {
    #[error(transparent)]
    Rig(#[from] RigError),
    #[error(transparent)]
    Plan(#[from] PlanError),
    #[error(transparent)]
    Collect(#[from] CollectError),
    #[error("opening dataset {dir}: {source}")]
    Dataset {
        dir: PathBuf,
        #[source]
        source: DatasetError,
    },
    #[error(transparent)]
    Fill(#[from] FillError),
    #[error("loading model package {model}: {source}")]
    Model {
        model: PathBuf,
        #[source]
        source: SynthError,
    },
    #[error(transparent)]
    Press(#[from] PressError),
    #[error("saving the calibration {path}: {reason}")]
    SaveCalibration { path: PathBuf, reason: String },
    /// An option the command would reject (exit code 2).
    #[error("{field}: {reason}")]
    BadOption { field: &'static str, reason: String },
    #[error("sensor {sensor} is not open in this daemon (it was started with --sensor {opened})")]
    SensorNotOpen { sensor: String, opened: String },
    #[error("the synth worker thread stopped: {reason}")]
    Worker { reason: String },
}

/// What the worker gives a job: the opened rig and what it was opened with.
pub struct RigContext<'r> {
    pub rig: &'r mut Rig,
    pub config: &'r RigConfig,
    pub clock: Arc<dyn Clock>,
    pub state: Arc<DaemonState>,
    /// The running job's id.
    pub job_id: u64,
    pub cancel: watch::Receiver<bool>,
    pub progress: indicatif::ProgressBar,
    /// The last model package loaded, kept for the next synth job.
    pub pipeline: &'r mut Option<(PathBuf, RuntimeOptions, Pipeline)>,
}

/// A job's end when it did not fail: the summary line, and whether it was cancelled.
pub struct JobEnd {
    pub message: String,
    pub cancelled: bool,
    /// Progress units done, when the job counts them itself (its progress bar jumps to the
    /// end when finished, also early).
    pub done: Option<u64>,
}

/// Runs `spec` on the opened rig.
pub async fn run_job(spec: &JobSpec, ctx: RigContext<'_>) -> Result<JobEnd, JobError> {
    match spec {
        JobSpec::Collect(s) => run_collect(s, ctx).await,
        JobSpec::Synth(s) => run_synth(s, ctx).await,
        JobSpec::Calibrate(s) => run_calibrate(s, ctx).await,
    }
}

fn sensor_names(rig: &Rig) -> String {
    rig.cameras.iter().map(|c| c.sensor_dir()).collect::<Vec<_>>().join(",")
}

async fn run_collect(spec: &CollectSpec, ctx: RigContext<'_>) -> Result<JobEnd, JobError> {
    let RigContext { rig, config, clock, state, cancel, progress, .. } = ctx;
    let mut plan_spec = match &spec.plan {
        Some(p) => PlanSpec::load(p)?,
        None => PlanSpec::default(),
    };
    if let Some(n) = spec.poses {
        plan_spec.n_poses = Some(n);
    }
    if let Some(s) = spec.seed {
        plan_spec.seed = s;
    }
    plan_spec.validate()?;
    let sensors = SensorChoice::parse(&spec.sensor)?;
    let object = ObjectChoice::resolve(&spec.object, spec.stl.as_deref())?;
    let profile = crate::rigs::profile_for(config)?;
    let plan = plan_spec.build(&|a, b| crate::rigs::pose_cost_s(&profile, &config.work_frame, a, b))?;
    check_plan(&plan.poses, &config.work_frame, |p| profile.check_reachable(p))?;
    let opened = sensor_names(rig);
    for kind in &sensors.0 {
        if !rig.cameras.iter().any(|c| c.sensor_dir() == kind.to_string()) {
            return Err(JobError::SensorNotOpen { sensor: kind.to_string(), opened });
        }
    }
    rig.set_object(config, &object)?;

    let Rig { arm, cameras, peripherals, .. } = rig;
    let mut streams = Vec::new();
    for camera in cameras.iter_mut().filter(|c| sensors.0.iter().any(|k| k.to_string() == c.sensor_dir())) {
        let dir = spec.out.join(&object.name).join(camera.sensor_dir());
        let object_info = ObjectInfo {
            name: object.name.clone(),
            stl_path: object.path.as_ref().map(|p| p.display().to_string()),
            stl_sha256: Some(object.sha256.clone()),
        };
        let mut manifest = Manifest::new(&camera.sensor_dir(), object_info, Some(plan_spec.clone()));
        manifest.calibration = Some(camera.calibration_name());
        manifest.firmware_profile = Some(profile.name.clone());
        manifest.work_frame = Some(config.work_frame);
        let writer = if spec.resume { DatasetWriter::resume(&dir, manifest) } else { DatasetWriter::create(&dir, manifest) }
            .map_err(|source| JobError::Dataset { dir: dir.clone(), source })?
            .with_byte_budget(config.faults.disk_budget_bytes);
        streams.push(SensorStream { camera: LiveCamera { camera, state: Arc::clone(&state) }, writer });
    }
    let mut live_arm = LiveArm::new(arm, Arc::clone(&state), &plan.poses, &config.work_frame);
    let job = CollectJob {
        arm: &mut live_arm,
        sensors: streams,
        work_frame: config.work_frame,
        options: config.collect.clone(),
        clock,
        cancel,
        stop_after: None,
        progress,
        peripherals,
    };
    let summary = job.run(&plan.poses).await?;
    let where_ = spec.out.join(&object.name);
    if summary.interrupted {
        return Ok(JobEnd {
            message: format!("interrupted: {} poses captured, {} left; continue with resume", summary.captured, summary.remaining),
            cancelled: true,
            done: Some((summary.skipped + summary.captured) as u64),
        });
    }
    Ok(JobEnd {
        message: format!(
            "collected {} poses ({} already present, {} arm or camera faults recovered) into {}",
            summary.captured,
            summary.skipped,
            summary.recovered_faults,
            where_.display()
        ),
        cancelled: false,
        done: Some((summary.skipped + summary.captured) as u64),
    })
}

async fn run_synth(spec: &SynthSpec, ctx: RigContext<'_>) -> Result<JobEnd, JobError> {
    let RigContext { state, job_id, cancel, progress, pipeline, .. } = ctx;
    let shard = match &spec.shard {
        Some(text) => text.parse::<Shard>()?,
        None => Shard::ALL,
    };
    if spec.shard.is_some() && spec.out.is_none() {
        return Err(JobError::BadOption { field: "shard", reason: "needs out: each shard writes its own dataset".into() });
    }
    let scheduler: Option<SchedulerKind> = match &spec.sampler {
        None => None,
        Some(text) => Some(
            text.parse().map_err(|_| JobError::BadOption { field: "sampler", reason: format!("{text:?}: expected ddim or dpm++2m") })?,
        ),
    };
    let datasets = crate::synth::fill::find_datasets(&spec.dataset);
    if datasets.is_empty() {
        return Err(JobError::BadOption {
            field: "dataset",
            reason: format!("no dataset under {} (a dataset has a manifest.toml)", spec.dataset.display()),
        });
    }
    if spec.out.is_some() && datasets.len() > 1 {
        return Err(JobError::BadOption { field: "out", reason: "takes one dataset: name it with dataset .../<object>/<sensor>".into() });
    }
    let model = spec.model.clone().unwrap_or_else(crate::synth::fill::default_model);
    let runtime = RuntimeOptions { ort_lib: spec.ort_lib.clone(), ..RuntimeOptions::default() };
    let defaults = FillOptions::default();
    // Steps, guidance and sampler are settled once the package is loaded (its model.toml).
    let mut options = FillOptions {
        steps: defaults.steps,
        guidance: defaults.guidance,
        eta: defaults.eta,
        scheduler: SchedulerKind::default(),
        conditioning_scale: spec.conditioning_scale,
        shard,
        batch: spec.batch,
        supersample: spec.supersample,
        limit: spec.limit,
        image_range: spec.image_range,
    };
    // The model runs on a blocking thread; the loaded package comes back for the next job.
    let cached = pipeline.take().filter(|(m, r, _)| *m == model && r.ort_lib == runtime.ort_lib);
    let out = spec.out.clone();
    let (spec_steps, spec_guidance, spec_eta) = (spec.steps, spec.guidance, spec.eta);
    let fallback = (defaults.steps, defaults.guidance);
    let task = tokio::task::spawn_blocking(move || {
        let mut loaded = match cached {
            Some((_, _, p)) => p,
            None => match Pipeline::load(&model, &runtime) {
                Ok(p) => p,
                Err(source) => return (None, Err(JobError::Model { model, source })),
            },
        };
        // The package's own sampling settings where the job names none.
        let sampling = loaded.package().config.sampling(spec_steps, spec_guidance, scheduler, spec_eta, fallback);
        (options.steps, options.guidance, options.scheduler, options.eta) =
            (sampling.steps, sampling.guidance, sampling.sampler, sampling.eta);
        let mut lines = Vec::new();
        let mut cancelled = false;
        for d in &datasets {
            let mut observe = |filled: &crate::synth::fill::FilledPose<'_>| {
                state.set_synth(job_id, filled.pose_id, png_bytes(filled.control), png_bytes(filled.image));
                if *cancel.borrow() { ControlFlow::Break(()) } else { ControlFlow::Continue(()) }
            };
            match fill_missing_observed(d, out.as_deref(), &mut loaded, &options, &progress, &mut observe) {
                Ok(summary) => lines.push(format!(
                    "{}: synthesised {} poses ({} of {} grid poses were present{})",
                    out.as_deref().unwrap_or(d).display(),
                    summary.synthesised,
                    summary.present,
                    summary.grid,
                    if summary.left > 0 { format!(", {} left", summary.left) } else { String::new() }
                )),
                Err(e) => return (Some((model, runtime, loaded)), Err(e.into())),
            }
            if *cancel.borrow() {
                cancelled = true;
                break;
            }
        }
        let message = if cancelled { format!("cancelled; {}", lines.join("; ")) } else { lines.join("; ") };
        (Some((model, runtime, loaded)), Ok(JobEnd { message, cancelled, done: None }))
    });
    match task.await {
        Ok((loaded, result)) => {
            *pipeline = loaded;
            result
        }
        Err(e) => Err(JobError::Worker { reason: e.to_string() }),
    }
}

async fn run_calibrate(spec: &CalibrateSpec, ctx: RigContext<'_>) -> Result<JobEnd, JobError> {
    let RigContext { rig, config, state, progress, cancel, .. } = ctx;
    let kind: SensorKind = spec
        .sensor
        .parse()
        .map_err(|_| JobError::BadOption { field: "sensor", reason: format!("{:?}: expected tactip, vitac or vitactip", spec.sensor) })?;
    let out = spec.out.clone().unwrap_or_else(|| crate::calibration::saved_path(&kind.to_string()));
    let pattern = PressPattern::grid(spec.grid, spec.span_mm, &spec.depths_mm);
    let profile = crate::rigs::profile_for(config)?;
    let plan: Vec<_> = pattern.offsets.iter().enumerate().map(|(k, p)| crate::plan::PlannedPose { pose_id: k as u32, pose: *p }).collect();
    check_plan(&plan, &config.work_frame, |p| profile.check_reachable(p))?;
    let opened = sensor_names(rig);
    let mesh = indenter_mesh();
    let indenter = ObjectChoice { name: "indenter".into(), path: None, sha256: String::new(), mesh: Arc::new(mesh) };
    rig.set_object(config, &indenter)?;
    let Rig { arm, cameras, .. } = rig;
    let Some(camera) = cameras.iter_mut().find(|c| c.sensor_dir() == kind.to_string()) else {
        return Err(JobError::SensorNotOpen { sensor: kind.to_string(), opened });
    };
    let width = config.sensors.iter().find(|s| s.name == kind.to_string()).map_or(512, |s| s.width);
    let mut live_arm = LiveArm::new(arm, Arc::clone(&state), &plan, &config.work_frame);
    let mut station = ArmStation {
        arm: &mut live_arm,
        camera: LiveCamera { camera, state: Arc::clone(&state) },
        work_frame: config.work_frame,
        options: config.collect.clone(),
        detector: ContactDetector::for_sensor(kind, width),
        reference: None,
    };
    progress.set_length(pattern.offsets.len() as u64);
    // A cancel is honoured between presses: the arm retracts and nothing is saved.
    let run = run_pattern(&mut station, &pattern, &FitOptions::default(), |_, _| {
        progress.inc(1);
        if *cancel.borrow() { ControlFlow::Break(()) } else { ControlFlow::Continue(()) }
    })
    .await;
    // The press pattern ends in contact-free air; leave the arm disabled like a collection.
    let disabled = station.arm.disable().await;
    if let Err(PressError::Cancelled { done, total }) = &run {
        disabled.map_err(PressError::from)?;
        return Ok(JobEnd {
            message: format!("cancelled after {done} of {total} presses; no calibration saved ({} untouched)", out.display()),
            cancelled: true,
            done: Some(*done as u64),
        });
    }
    let run = run?;
    disabled.map_err(PressError::from)?;
    let mut fit = run.fit;
    if let Some(reference) = &station.reference {
        fit.calibration.image_size = [reference.width(), reference.height()];
    }
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| JobError::SaveCalibration { path: out.clone(), reason: e.to_string() })?;
    }
    fit.calibration.save(&out).map_err(|e| JobError::SaveCalibration { path: out.clone(), reason: e.to_string() })?;
    Ok(JobEnd { message: format!("saved {}; {}", out.display(), fit.residual_line()), cancelled: false, done: None })
}
