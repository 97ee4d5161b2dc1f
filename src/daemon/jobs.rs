//! How the daemon runs a [`JobRequest`] on its opened rig: the library runners of
//! [`crate::jobs`] (the same ones the standalone commands call), with the rig's arm and cameras
//! wrapped in [`LiveArm`] and [`LiveCamera`] so that progress, pose and frames reach the status
//! API as they happen. What is the daemon's own: the rig stays open between jobs, a collection
//! may only use the sensors the daemon opened, and the last model package loaded is kept for
//! the next synth job.

// A job's error is returned once per job, unboxed, as in `crate::jobs`: the exit-code table
// finds the library errors by type in the chain.
#![allow(clippy::result_large_err)]

use std::path::{Path, PathBuf};
use std::sync::Arc;

use tokio::sync::watch;

use super::live::{LiveArm, LiveCamera, png_bytes};
use super::state::DaemonState;
use crate::clock::Clock;
use crate::config::RigConfig;
use crate::geometry::objects::ObjectChoice;
use crate::jobs::adaptive::AdaptiveRun;
use crate::jobs::calibrate::CalibrateOutcome;
use crate::jobs::collect::SensorFeed;
use crate::jobs::{AdaptiveRequest, AuditRequest, CalibrateRequest, CollectRequest, FillRequest};
use crate::jobs::{JobError, JobRequest, Observer};
use crate::plan::PlannedPose;
use crate::rigs::{Rig, RigCamera, RigError};
use crate::sensor::SensorKind;
use crate::synth::{Pipeline, RuntimeOptions};

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
    /// The ONNX Runtime library synth jobs load, fixed when the daemon started (`None`: none
    /// was found, and synth jobs fail saying so).
    pub ort_lib: Option<PathBuf>,
}

impl RigContext<'_> {
    fn observer(&self) -> Observer {
        Observer { progress: self.progress.clone(), cancel: self.cancel.clone() }
    }
}

/// A job's end when it did not fail: the summary line, and whether it was cancelled.
pub struct JobEnd {
    pub message: String,
    pub cancelled: bool,
    /// Progress units done, when the job counts them itself (its progress bar jumps to the
    /// end when finished, also early).
    pub done: Option<u64>,
}

/// Why a daemon job failed: the job itself, or putting its object under the open rig.
#[derive(Debug, thiserror::Error)]
pub enum DaemonJobError {
    #[error("{0}")]
    Job(#[from] JobError),
    #[error("{0}")]
    Rig(#[from] RigError),
}

/// Runs `request` on the opened rig.
pub async fn run_job(request: &JobRequest, ctx: RigContext<'_>) -> Result<JobEnd, DaemonJobError> {
    match request {
        JobRequest::Collect(r) => run_collect(r, ctx).await,
        JobRequest::Synth(r) => run_synth(r, ctx).await,
        JobRequest::Calibrate(r) => run_calibrate(r, ctx).await,
        JobRequest::Audit(r) => run_audit(r, ctx).await,
        JobRequest::Adaptive(r) => run_adaptive(r, ctx).await,
    }
}

fn sensor_names(rig: &Rig) -> String {
    rig.cameras.iter().map(|c| c.sensor_dir()).collect::<Vec<_>>().join(",")
}

/// The open cameras a job uses (`wanted` picks them by sensor), each shown on the live page as
/// it captures.
fn live_feeds<'a>(
    cameras: &'a mut [RigCamera],
    state: &Arc<DaemonState>,
    wanted: impl Fn(SensorKind) -> bool,
) -> Vec<SensorFeed<LiveCamera<'a>>> {
    cameras
        .iter_mut()
        .filter(|c| wanted(c.kind()))
        .map(|camera| SensorFeed {
            sensor: camera.kind(),
            calibration: camera.calibration_name(),
            capture: camera.capture_part(),
            camera: LiveCamera { camera, state: Arc::clone(state) },
        })
        .collect()
}

async fn run_collect(request: &CollectRequest, ctx: RigContext<'_>) -> Result<JobEnd, DaemonJobError> {
    let observer = ctx.observer();
    let RigContext { rig, config, clock, state, .. } = ctx;
    let prepared = request.prepare(config)?;
    let opened = sensor_names(rig);
    if let Some(sensor) = prepared.sensors.iter().find(|&k| !rig.cameras.iter().any(|c| c.kind() == k)) {
        return Err(JobError::SensorNotOpen { sensor, opened }.into());
    }
    rig.set_object(config, &prepared.object)?;

    let Rig { arm, cameras, peripherals, .. } = rig;
    let feeds = live_feeds(cameras, &state, |kind| prepared.sensors.contains(kind));
    let setup = &prepared.setup;
    let mut live_arm = LiveArm::new(arm, Arc::clone(&state), &setup.poses, &setup.work_frame);
    let outcome = crate::jobs::collect::run(setup, &mut live_arm, feeds, peripherals, clock, observer, None).await?;
    let s = &outcome.summary;
    Ok(JobEnd { message: outcome.line("resume"), cancelled: s.interrupted, done: Some((s.skipped + s.captured) as u64) })
}

/// An audit on the open rig: its dataset's sensor must be open; the drawn poses are collected
/// like a collection job's, then scored on a blocking thread.
async fn run_audit(request: &AuditRequest, ctx: RigContext<'_>) -> Result<JobEnd, DaemonJobError> {
    let observer = ctx.observer();
    let RigContext { rig, config, clock, state, .. } = ctx;
    let prepared = request.prepare(config)?;
    let opened = sensor_names(rig);
    if !rig.cameras.iter().any(|c| c.kind() == prepared.sensor) {
        return Err(JobError::SensorNotOpen { sensor: prepared.sensor, opened }.into());
    }
    rig.set_object(config, &prepared.object)?;
    let Rig { arm, cameras, peripherals, .. } = rig;
    let feeds = live_feeds(cameras, &state, |kind| kind == prepared.sensor);
    let setup = &prepared.setup;
    let mut live_arm = LiveArm::new(arm, Arc::clone(&state), &setup.poses, &setup.work_frame);
    let collected = crate::jobs::collect::run(setup, &mut live_arm, feeds, peripherals, clock, observer, None).await?;
    let s = &collected.summary;
    let done = Some((s.skipped + s.captured) as u64);
    if s.interrupted {
        return Ok(JobEnd { message: collected.line("the same audit job"), cancelled: true, done });
    }
    let for_scoring = prepared.clone();
    // Boxed across the thread: the job error is large.
    let scored = tokio::task::spawn_blocking(move || crate::jobs::audit::score(&for_scoring).map_err(Box::new))
        .await
        .map_err(|e| JobError::Worker { reason: e.to_string() })?
        .map_err(|e| *e)?;
    let mut message = scored.summary.lines().join("; ");
    if scored.passed == Some(false) {
        message += "; below --min-ssim";
    }
    message += &format!("; {}", scored.verdict);
    Ok(JobEnd { message, cancelled: false, done })
}

/// The ONNX Runtime of the daemon's synth and adaptive jobs, or why there is none.
fn runtime_options(ort_lib: Option<PathBuf>, job: &'static str) -> Result<RuntimeOptions, JobError> {
    crate::features::Feature::Synth.require(job).map_err(|e| JobError::Settings(e.into()))?;
    let Some(ort_lib) = ort_lib else {
        return Err(JobError::bad_option(
            "synth",
            "the daemon found no ONNX Runtime library when it started: restart it with --ort-lib PATH",
        ));
    };
    Ok(RuntimeOptions { ort_lib: Some(ort_lib), ..RuntimeOptions::default() })
}

/// Runs `work` with the model on a blocking thread and gives the model back with its result
/// (`None`: the thread panicked and the model is dropped; the next job loads it again).
async fn with_model<T: Send + 'static>(
    model: Pipeline,
    work: impl FnOnce(&mut Pipeline) -> T + Send + 'static,
) -> (Option<Pipeline>, Result<T, JobError>) {
    let task = tokio::task::spawn_blocking(move || {
        let mut model = model;
        let out = work(&mut model);
        (model, out)
    });
    match task.await {
        Ok((model, out)) => (Some(model), Ok(out)),
        Err(e) => (None, Err(JobError::Worker { reason: e.to_string() })),
    }
}

/// The package `model` run by `runtime`: the daemon's loaded one when it is that (taken out of
/// `cached`), else loaded on a blocking thread (the one cached is dropped).
async fn cached_or_load(
    cached: &mut Option<(PathBuf, RuntimeOptions, Pipeline)>,
    model: &Path,
    runtime: &RuntimeOptions,
) -> Result<Pipeline, JobError> {
    if let Some((_, _, p)) = cached.take().filter(|(m, r, _)| m == model && r.ort_lib == runtime.ort_lib) {
        return Ok(p);
    }
    let (m, r) = (model.to_path_buf(), runtime.clone());
    tokio::task::spawn_blocking(move || Pipeline::load(&m, &r))
        .await
        .map_err(|e| JobError::Worker { reason: e.to_string() })?
        .map_err(|source| JobError::Model { model: model.to_path_buf(), source })
}

/// An adaptive collection on the open rig (`rig collect --adaptive`'s job): every round chosen
/// with the model on a blocking thread (a cancel stops it after the model's current call),
/// recorded, then pressed like a collection job, then the rest filled with the same model,
/// which stays loaded for the next job.
async fn run_adaptive(request: &AdaptiveRequest, ctx: RigContext<'_>) -> Result<JobEnd, DaemonJobError> {
    let observer = ctx.observer();
    let RigContext { rig, config, clock, state, job_id, pipeline, ort_lib, cancel, .. } = ctx;
    let runtime = runtime_options(ort_lib, "the daemon's adaptive jobs")?;
    // The numbers against the plan, and the sensors against the open rig, before any model loads.
    let prepared = request.collect.prepare(config)?;
    request.check_plan(prepared.plan.poses.len())?;
    let opened = sensor_names(rig);
    if let Some(sensor) = prepared.sensors.iter().find(|&k| !rig.cameras.iter().any(|c| c.kind() == k)) {
        return Err(JobError::SensorNotOpen { sensor, opened }.into());
    }
    let model = request.model_dir();
    crate::synth::fill::check_model_dir(&model).map_err(JobError::Settings)?;
    let mut slot = Some(cached_or_load(pipeline, &model, &runtime).await?);
    let end = adaptive_rounds(request, &mut slot, rig, config, clock, state, job_id, observer, cancel).await;
    *pipeline = slot.map(|p| (model, runtime, p));
    end
}

/// The rounds and the fill of [`run_adaptive`]; the model lives in `slot` between its calls.
#[allow(clippy::too_many_arguments)]
async fn adaptive_rounds(
    request: &AdaptiveRequest,
    slot: &mut Option<Pipeline>,
    rig: &mut Rig,
    config: &RigConfig,
    clock: Arc<dyn Clock>,
    state: Arc<DaemonState>,
    job_id: u64,
    observer: Observer,
    cancel: watch::Receiver<bool>,
) -> Result<JobEnd, DaemonJobError> {
    let lost = || JobError::Worker { reason: "the model was lost with a panicked thread".to_string() };
    let model = slot.take().ok_or_else(lost)?;
    let (model, run) = {
        let (request, config) = (request.clone(), config.clone());
        with_model(model, move |p| request.prepare(&config, p)).await
    };
    *slot = model;
    let mut run: AdaptiveRun = run??;
    rig.set_object(config, &run.prepared.object)?;
    let cancelled = |stage: &str, done: usize| JobEnd {
        message: format!("cancelled {stage} ({done} poses pressed; the rounds recorded are pressed as recorded on resume)"),
        cancelled: true,
        done: Some(done as u64),
    };
    let (mut calls, mut choose_s) = (0, 0.0);
    loop {
        let model = slot.take().ok_or_else(lost)?;
        let flag = cancel.clone();
        let (model, chosen) = with_model(model, move |p| {
            let round = run.next_round(p, &|| *flag.borrow());
            (run, round)
        })
        .await;
        *slot = model;
        let (back, round) = chosen?;
        run = back;
        let pressed = run.record.choices.len();
        let Some(round) = round? else {
            if *cancel.borrow() {
                return Ok(cancelled("while choosing a round", pressed));
            }
            break;
        };
        tracing::info!(job = job_id, "{}", round.line(run.record.settings.rounds));
        calls += round.model_calls;
        choose_s += round.choose_s;
        let Rig { arm, cameras, peripherals, .. } = &mut *rig;
        let feeds = live_feeds(cameras, &state, |kind| run.prepared.sensors.contains(kind));
        let setup = &round.setup;
        let mut live_arm = LiveArm::new(arm, Arc::clone(&state), &setup.poses, &setup.work_frame);
        let outcome =
            crate::jobs::collect::run(setup, &mut live_arm, feeds, peripherals, Arc::clone(&clock), observer.clone(), None).await?;
        if outcome.summary.interrupted || *cancel.borrow() {
            return Ok(cancelled("while pressing", pressed));
        }
    }
    let fills = run.fill_requests();
    let mut lines = vec![format!(
        "{} poses pressed in {} rounds (choosing them took {calls} model calls in {choose_s:.1} s), the rest filled with {}",
        run.record.choices.len(),
        run.record.settings.rounds,
        run.record.settings.model
    )];
    for fill in fills {
        let targets = fill.targets()?;
        let model = slot.take().ok_or_else(lost)?;
        let (observer, state) = (observer.clone(), Arc::clone(&state));
        let (model, filled) = with_model(model, move |p| {
            let mut on_pose = |filled: &crate::synth::fill::FilledPose<'_>| {
                state.set_synth(job_id, filled.pose_id, png_bytes(filled.control), png_bytes(filled.image));
            };
            crate::jobs::fill::run(&fill, &targets, p, &observer, &mut on_pose, &mut |_| {})
        })
        .await;
        *slot = model;
        let outcome = filled??;
        lines.extend(outcome.reports.iter().flat_map(|r| std::iter::once(r.line()).chain(r.warning())));
        if outcome.cancelled {
            let pressed = run.record.choices.len();
            return Ok(JobEnd {
                message: format!("cancelled while filling; {}", lines.join("; ")),
                cancelled: true,
                done: Some(pressed as u64),
            });
        }
    }
    Ok(JobEnd { message: lines.join("; "), cancelled: false, done: None })
}

async fn run_synth(request: &FillRequest, ctx: RigContext<'_>) -> Result<JobEnd, DaemonJobError> {
    let observer = ctx.observer();
    let RigContext { state, job_id, pipeline, ort_lib, .. } = ctx;
    if request.twins() {
        // Twins are for evaluating a model offline; the daemon's synth jobs fill datasets.
        return Err(JobError::bad_option("poses_of", "the daemon runs fills only: run `rig synth --poses-of` locally").into());
    }
    crate::features::Feature::Synth.require("the daemon's synth jobs").map_err(|e| JobError::Settings(e.into()))?;
    let targets = request.targets()?;
    let model = request.model_dir();
    let runtime = runtime_options(ort_lib, "the daemon's synth jobs")?;
    // The model runs on a blocking thread; the loaded package comes back for the next job.
    let loaded = cached_or_load(pipeline, &model, &runtime).await?;
    let request = request.clone();
    let (back, end) = with_model(loaded, move |p| {
        let mut on_pose = |filled: &crate::synth::fill::FilledPose<'_>| {
            state.set_synth(job_id, filled.pose_id, png_bytes(filled.control), png_bytes(filled.image));
        };
        let result = crate::jobs::fill::run(&request, &targets, p, &observer, &mut on_pose, &mut |_| {});
        result.map(|o| {
            let lines: Vec<String> = o.reports.iter().flat_map(|r| std::iter::once(r.line()).chain(r.warning())).collect();
            let message = match (o.cancelled, lines.is_empty()) {
                (true, true) => "cancelled (what was written stays and resumes)".to_string(),
                (true, false) => format!("cancelled; {}", lines.join("; ")),
                (false, _) => lines.join("; "),
            };
            JobEnd { message, cancelled: o.cancelled, done: None }
        })
    })
    .await;
    *pipeline = back.map(|p| (model, runtime, p));
    Ok(end??)
}

async fn run_calibrate(request: &CalibrateRequest, ctx: RigContext<'_>) -> Result<JobEnd, DaemonJobError> {
    let observer = ctx.observer();
    let RigContext { rig, config, state, .. } = ctx;
    let (pattern, _) = request.prepare(config)?;
    let opened = sensor_names(rig);
    rig.set_object(config, &ObjectChoice::built_in("indenter", crate::calibration::press::indenter_mesh()))?;
    let Rig { arm, cameras, .. } = rig;
    let Some(camera) = cameras.iter_mut().find(|c| c.kind() == request.sensor) else {
        return Err(JobError::SensorNotOpen { sensor: request.sensor, opened }.into());
    };
    let plan: Vec<PlannedPose> = pattern.offsets.iter().zip(0u32..).map(|(p, pose_id)| PlannedPose { pose_id, pose: *p }).collect();
    let mut live_arm = LiveArm::new(arm, Arc::clone(&state), &plan, &config.work_frame);
    let camera = LiveCamera { camera, state: Arc::clone(&state) };
    let outcome = crate::jobs::calibrate::run(request, &pattern, &mut live_arm, camera, config, &observer, &mut |_, _| {}).await?;
    let (cancelled, done) = match &outcome {
        CalibrateOutcome::Cancelled { done, .. } => (true, Some(*done as u64)),
        CalibrateOutcome::Saved { .. } => (false, None),
    };
    Ok(JobEnd { message: outcome.line(), cancelled, done })
}
