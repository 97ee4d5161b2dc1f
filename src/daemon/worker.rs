//! The worker: the one task that owns the opened rig. It runs the queued jobs one at a time,
//! records each end (a failure is recorded and the queue goes on), refreshes the live view
//! while idle, and on shutdown leaves the arm retracted and disabled before closing the rig.
//!
//! Isolation: each job runs behind [`CatchPanic`], so a job that panics fails alone (its
//! error says so, exit code 1) and the worker goes on to the next; the state's mutex is
//! never held across a job, and its lock recovers from poisoning, so the status keeps being
//! served. (What no code can catch, an allocation the machine cannot satisfy, is kept out by
//! the bounds checked before allocating: [`crate::synth::limits`], [`crate::plan`]'s grid cap,
//! the dataset's file-size caps.)

use std::future::Future;
use std::panic::AssertUnwindSafe;
use std::path::PathBuf;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};
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
use crate::report::Exit;
use crate::rigs::{Rig, RigArm};
use crate::roots::DataRoots;
use crate::synth::{Pipeline, RuntimeOptions};

/// What the daemon fixed at start and every job runs under: the data roots every path a
/// request names must resolve inside ([`DataRoots::input`], [`DataRoots::output`]), and the
/// ONNX Runtime library synth jobs load (never one a request names).
#[derive(Debug, Clone)]
pub struct WorkerContext {
    pub roots: DataRoots,
    /// Resolved at start; `None` when no library was found (synth jobs then fail).
    pub ort_lib: Option<PathBuf>,
}

/// A future that turns a panic while it is polled into an error carrying the panic message.
/// The inner future is dropped at the panic (never polled again).
pub(crate) struct CatchPanic<'a, T> {
    inner: Option<Pin<Box<dyn Future<Output = T> + Send + 'a>>>,
}

impl<'a, T> CatchPanic<'a, T> {
    pub(crate) fn new(inner: impl Future<Output = T> + Send + 'a) -> Self {
        Self { inner: Some(Box::pin(inner)) }
    }
}

impl<T> Future for CatchPanic<'_, T> {
    type Output = Result<T, String>;
    fn poll(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Self::Output> {
        let Some(inner) = self.inner.as_mut() else { return Poll::Ready(Err("polled after a panic".into())) };
        match std::panic::catch_unwind(AssertUnwindSafe(|| inner.as_mut().poll(cx))) {
            Ok(Poll::Pending) => Poll::Pending,
            Ok(Poll::Ready(v)) => Poll::Ready(Ok(v)),
            Err(payload) => {
                self.inner = None;
                let message = payload
                    .downcast_ref::<&str>()
                    .map(|s| s.to_string())
                    .or_else(|| payload.downcast_ref::<String>().cloned())
                    .unwrap_or_else(|| "a panic without a message".into());
                Poll::Ready(Err(message))
            }
        }
    }
}

/// A panic injected into every job of this kind (`collect`, `synth`, `calibrate`), read from
/// `RIG_DEBUG_PANIC_JOB_KIND`: only in debug builds, for the test that a panicking job fails
/// alone. Release builds have no such hook.
fn injected_panic(kind: &str) -> bool {
    cfg!(debug_assertions) && std::env::var("RIG_DEBUG_PANIC_JOB_KIND").is_ok_and(|k| k == kind)
}

/// Longest wait for one idle frame or pose reading (a stalled camera must not stall the queue).
const IDLE_READ_TIMEOUT: Duration = Duration::from_secs(2);

/// How long a running job has, after a cancel request, to stop at its next safe point (a
/// pose, a sampling step). Past it the worker stops waiting: the job is recorded as cancelled
/// and abandoned (a model thread blocked in a read is left behind, never joined), so a job
/// that cannot stop (a FIFO read, a step that never returns) cannot hold the queue.
pub const JOB_STOP_GRACE: Duration = Duration::from_secs(10);
/// The same grace once the daemon is stopping: short, so that the arm is retracted and
/// disabled within 5 s of SIGTERM (this, plus [`SHUTDOWN_RETRACT_TIMEOUT`] and
/// [`SHUTDOWN_DISABLE_TIMEOUT`], plus half a second of asking and closing).
pub const SHUTDOWN_STOP_GRACE: Duration = Duration::from_secs(1);
/// Longest the shutdown's retract may take before the arm is disabled where it stands.
pub const SHUTDOWN_RETRACT_TIMEOUT: Duration = Duration::from_secs(2);
/// Longest the shutdown waits for the arm to take the disable command.
pub const SHUTDOWN_DISABLE_TIMEOUT: Duration = Duration::from_secs(1);

/// Resolves once the running job has had its grace: [`JOB_STOP_GRACE`] after `cancel` turns
/// true, or [`SHUTDOWN_STOP_GRACE`] after the daemon began stopping, whichever ends first
/// (never, if the cancel's sender is gone first).
async fn grace_after_cancel(mut cancel: tokio::sync::watch::Receiver<bool>, state: Arc<DaemonState>) {
    let sender_gone = cancel.wait_for(|c| *c).await.is_err();
    if sender_gone {
        std::future::pending::<()>().await;
    }
    let cancelled_at = tokio::time::Instant::now();
    let mut stopping_since: Option<tokio::time::Instant> = None;
    loop {
        let now = tokio::time::Instant::now();
        if stopping_since.is_none() && !state.accepting() {
            stopping_since = Some(now);
        }
        if now.duration_since(cancelled_at) >= JOB_STOP_GRACE
            || stopping_since.is_some_and(|t| now.duration_since(t) >= SHUTDOWN_STOP_GRACE)
        {
            return;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// Runs jobs until the state stops accepting them, then makes the arm safe and closes the rig.
pub(crate) async fn run_worker(
    state: Arc<DaemonState>,
    mut rig: Rig,
    config: RigConfig,
    clock: Arc<dyn Clock>,
    idle_period: Option<Duration>,
    context: WorkerContext,
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
            let mut spec = job.spec.clone();
            // Confined again now: what it reads must exist by now, and a folder may have been
            // swapped for a symlink since submission.
            let confined = spec.confine(&context.roots, crate::jobs::Confine::Starting);
            let panic_here = injected_panic(spec.kind());
            let stop_wait = grace_after_cancel(job.cancel.clone(), Arc::clone(&state));
            let ctx = RigContext {
                rig: &mut rig,
                config: &config,
                clock: Arc::clone(&clock),
                state: Arc::clone(&state),
                job_id: job.id,
                cancel: job.cancel,
                progress: job.progress,
                pipeline: &mut pipeline,
                ort_lib: context.ort_lib.clone(),
            };
            let run = CatchPanic::new(async {
                if panic_here {
                    panic!("RIG_DEBUG_PANIC_JOB_KIND: a panic injected into this job");
                }
                confined.map_err(crate::jobs::JobError::from)?;
                run_job(&spec, ctx).await
            });
            let ended = tokio::select! {
                ended = run => Some(ended),
                () = stop_wait => None,
            };
            let (outcome, done) = match ended {
                None => {
                    let message =
                        "cancelled: the job did not stop at a safe point in time and was abandoned (what it wrote stays)".to_string();
                    warn!(id = job.id, "job abandoned after the stop grace");
                    (JobOutcome::Cancelled { message }, None)
                }
                Some(Ok(Ok(end))) if end.cancelled => (JobOutcome::Cancelled { message: end.message }, end.done),
                Some(Ok(Ok(end))) => (JobOutcome::Done { message: end.message }, end.done),
                Some(Ok(Err(e))) => {
                    let (error, exit_code) = describe_failure(e);
                    warn!(id = job.id, %error, "job failed");
                    (JobOutcome::Failed { error, exit_code }, None)
                }
                Some(Err(panic)) => {
                    let error = format!("the job stopped on an internal error (a panic: {panic}); the daemon goes on");
                    warn!(id = job.id, %error, "job panicked");
                    (JobOutcome::Failed { error, exit_code: Exit::Failure.code() }, None)
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
    // Closing the streams is courtesy; it must not hold the shutdown past its deadline.
    if tokio::time::timeout(Duration::from_millis(300), rig.shutdown()).await.is_err() {
        warn!("closing the rig took too long; leaving it to the process exit");
    }
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
        RigArm::Mg400(client) => match tokio::time::timeout(Duration::from_millis(300), client.robot_mode()).await {
            Ok(Ok(mode)) => format!("{mode:?}").to_lowercase(),
            _ => state.status().arm.mode,
        },
        RigArm::Magician(_) => state.status().arm.mode,
    };
    if matches!(mode.as_str(), "enabled" | "running") {
        let above = config.work_frame.approach_pose(&Pose::default());
        // Bounded: the whole shutdown must leave the arm disabled within 5 s of SIGTERM.
        let timeout = Duration::from_secs_f64(config.collect.move_timeout_s).min(SHUTDOWN_RETRACT_TIMEOUT);
        match tokio::time::timeout(timeout, crate::collect::go(&mut rig.arm, above, MoveKind::Linear, timeout)).await {
            Ok(Ok(_)) => {}
            Ok(Err(e)) => {
                warn!(error = %e, "shutdown: could not retract the arm");
                state.record_error(None, format!("shutdown: could not retract the arm: {e}"));
            }
            Err(_) => {
                warn!("shutdown: the retract did not end in time; disabling the arm where it is");
                state.record_error(None, format!("shutdown: the retract did not end within {timeout:?}; disabled where it stood"));
            }
        }
    }
    match tokio::time::timeout(SHUTDOWN_DISABLE_TIMEOUT, rig.arm.disable()).await {
        Ok(Ok(())) => state.set_arm(Some("disabled".into()), None),
        Ok(Err(e)) => {
            warn!(error = %e, "shutdown: could not disable the arm");
            state.record_error(None, format!("shutdown: could not disable the arm: {e}"));
        }
        Err(_) => {
            warn!("shutdown: the arm did not take the disable command in time");
            state.record_error(None, format!("shutdown: the arm did not take the disable command within {SHUTDOWN_DISABLE_TIMEOUT:?}"));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn a_panicking_job_becomes_an_error_and_a_good_one_its_value() {
        let panicked = CatchPanic::new(async {
            tokio::task::yield_now().await;
            if std::hint::black_box(true) {
                panic!("boom at pose 7");
            }
            1
        })
        .await;
        assert_eq!(panicked, Err("boom at pose 7".to_string()));
        let owned = CatchPanic::new(async {
            if std::hint::black_box(true) {
                panic!("{}", String::from("formatted"));
            }
        })
        .await;
        assert_eq!(owned, Err("formatted".to_string()));
        assert_eq!(CatchPanic::new(async { 5 }).await, Ok(5));
    }

    #[test]
    fn the_panic_hook_is_off_unless_asked_for() {
        // The variable is never set by the test harness; a release build ignores it anyway.
        assert!(!injected_panic("no-such-kind"));
    }
}
