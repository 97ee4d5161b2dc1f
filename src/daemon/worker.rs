//! The worker: the one task that owns the opened rig. It runs the queued jobs one at a time,
//! records each end (a failure is recorded and the queue goes on), refreshes the live view
//! while idle, and on shutdown leaves the arm retracted and disabled before closing the rig.

use std::sync::Arc;
use std::time::Duration;

use tracing::{info, warn};

use super::jobs::{DaemonJobError, RigContext, run_job};
use super::live::{publish_frame, reported_mode};
use super::state::{DaemonState, JobOutcome};
use crate::arm::{Arm, MoveKind};
use crate::camera::Camera;
use crate::clock::Clock;
use crate::config::RigConfig;
use crate::pose::Pose;
use crate::rigs::{Rig, RigArm};
use crate::synth::{Pipeline, RuntimeOptions};

/// Longest wait for one idle frame or pose reading (a stalled camera must not stall the queue).
const IDLE_READ_TIMEOUT: Duration = Duration::from_secs(2);

/// Runs jobs until the state stops accepting them, then makes the arm safe and closes the rig.
pub(crate) async fn run_worker(
    state: Arc<DaemonState>,
    mut rig: Rig,
    config: RigConfig,
    clock: Arc<dyn Clock>,
    idle_period: Option<Duration>,
) {
    let mut pipeline: Option<(std::path::PathBuf, RuntimeOptions, Pipeline)> = None;
    let mut last_idle_error: Option<String> = None;
    // A first look at the rig before any job.
    if idle_period.is_some() {
        idle_tick(&mut rig, &state, &clock, &mut last_idle_error).await;
    }
    while state.accepting() {
        if let Some(job) = state.start_next() {
            info!(id = job.id, kind = job.spec.kind(), "job starting");
            let ctx = RigContext {
                rig: &mut rig,
                config: &config,
                clock: Arc::clone(&clock),
                state: Arc::clone(&state),
                job_id: job.id,
                cancel: job.cancel,
                progress: job.progress,
                pipeline: &mut pipeline,
            };
            let (outcome, done) = match run_job(&job.spec, ctx).await {
                Ok(end) if end.cancelled => (JobOutcome::Cancelled { message: end.message }, end.done),
                Ok(end) => (JobOutcome::Done { message: end.message }, end.done),
                Err(e) => {
                    let (error, exit_code) = describe_failure(e);
                    warn!(id = job.id, %error, "job failed");
                    (JobOutcome::Failed { error, exit_code }, None)
                }
            };
            info!(id = job.id, ?outcome, "job ended");
            state.finish(job.id, outcome, done);
            continue;
        }
        match idle_period {
            Some(period) => {
                tokio::select! {
                    _ = state.wake.notified() => {}
                    _ = tokio::time::sleep(period) => idle_tick(&mut rig, &state, &clock, &mut last_idle_error).await,
                }
            }
            None => state.wake.notified().await,
        }
    }
    make_safe(&mut rig, &config, &state).await;
    rig.shutdown().await;
    info!("worker stopped: arm disabled, rig closed");
}

/// The failure's message (with its causes) and the exit code the standalone command gives it.
fn describe_failure(e: DaemonJobError) -> (String, u8) {
    let err = anyhow::Error::new(e);
    (crate::report::error_report(&err), crate::report::exit_code(&err))
}

/// Between jobs: one fresh frame of every sensor and the arm's pose and mode, so the page
/// shows the rig as it is now. Errors are recorded once each, not every tick.
async fn idle_tick(rig: &mut Rig, state: &DaemonState, clock: &Arc<dyn Clock>, last_error: &mut Option<String>) {
    let mut errors = Vec::new();
    let now_s = clock.now_s();
    for camera in &mut rig.cameras {
        match tokio::time::timeout(IDLE_READ_TIMEOUT, camera.frame_after(now_s)).await {
            Ok(Ok(frame)) => publish_frame(state, &camera.sensor_dir(), &frame),
            Ok(Err(e)) => errors.push(format!("idle frame of {}: {e}", camera.sensor_dir())),
            Err(_) => errors.push(format!("idle frame of {}: no frame within {IDLE_READ_TIMEOUT:?}", camera.sensor_dir())),
        }
    }
    match tokio::time::timeout(IDLE_READ_TIMEOUT, rig.arm.pose()).await {
        Ok(Ok(pose)) => state.set_arm(reported_mode(&rig.arm), Some(pose)),
        Ok(Err(e)) => errors.push(format!("reading the arm's pose: {e}")),
        Err(_) => errors.push(format!("reading the arm's pose: no answer within {IDLE_READ_TIMEOUT:?}")),
    }
    let joined = (!errors.is_empty()).then(|| errors.join("; "));
    if joined != *last_error {
        if let Some(message) = &joined {
            warn!(%message, "idle refresh");
            state.record_error(None, message.clone());
        }
        *last_error = joined;
    }
}

/// Shutdown: lift the arm above the plan origin when it is enabled (it may have stopped in
/// contact), then disable it. Best effort: each failure is logged and recorded.
async fn make_safe(rig: &mut Rig, config: &RigConfig, state: &DaemonState) {
    // Asked now, not read from feedback, which may lag the job's last command.
    let mode = match &mut rig.arm {
        RigArm::Mg400(client) => match client.robot_mode().await {
            Ok(mode) => format!("{mode:?}").to_lowercase(),
            Err(_) => state.status().arm.mode,
        },
        RigArm::Magician(_) => state.status().arm.mode,
    };
    if matches!(mode.as_str(), "enabled" | "running") {
        let above = config.work_frame.approach_pose(&Pose::default());
        let timeout = Duration::from_secs_f64(config.collect.move_timeout_s);
        if let Err(e) = crate::collect::go(&mut rig.arm, above, MoveKind::Linear, timeout).await {
            warn!(error = %e, "shutdown: could not retract the arm");
            state.record_error(None, format!("shutdown: could not retract the arm: {e}"));
        }
    }
    match rig.arm.disable().await {
        Ok(()) => state.set_arm(Some("disabled".into()), None),
        Err(e) => {
            warn!(error = %e, "shutdown: could not disable the arm");
            state.record_error(None, format!("shutdown: could not disable the arm: {e}"));
        }
    }
}
