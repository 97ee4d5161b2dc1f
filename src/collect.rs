//! The collection job: plan x arm x cameras x dataset.
//!
//! For every planned pose not yet in every sensor's dataset, the job moves the sensor above the
//! pose at the approach height (MovJ), descends to the contact depth (MovL), waits for arrival
//! (Sync plus the feedback pose), waits the settle time, captures frames exposed after that
//! instant from each sensor that still lacks the pose, writes image and row durably, and
//! retracts. A no-contact reference frame is taken first. A recoverable arm fault (alarm,
//! timeout, dropped socket) is cleared and the pose retried, and so is a camera timeout; a
//! cancel request (Ctrl-C, SIGTERM, a daemon cancel) lets the current pose finish for at most
//! [`CANCEL_GRACE`], abandons it past that (whatever it waits on: an arm that does not arrive,
//! a camera, a Modbus device that never answers), retracts (at most
//! [`CANCEL_RETRACT_TIMEOUT`]), disables the arm (at most [`CANCEL_DISABLE_TIMEOUT`]) and
//! leaves every dataset consistent for `--resume`: the arm is disabled within 5 s of the
//! request. A fault that ends the run (retries spent, a dead camera, a full disk) also
//! lifts the arm off the sensor and disables it before the error is returned.
//!
//! Modbus peripherals ([`Peripherals`]) act around every capture: their `before_capture`
//! writes once the arm has arrived (frames are exposed only after they finished), their reads
//! and `after_capture` writes after the frames, still in contact. The readings go into every
//! sensor's row of that pose (`modbus` column), so rows are appended only once the whole pose
//! succeeded. A required peripheral's fault is retried like a camera timeout; an optional
//! one's only leaves its values empty (see [`crate::io::modbus`]).
//!
//! However a run ends (finished, interrupted, failed), what each camera's stream delivered
//! during it ([`Camera::stream_stats`] after the run less before it) is added to that sensor's
//! part of the capture chain in every dataset's manifest, so a resumed dataset's counts cover
//! all its runs. A run killed outright (SIGKILL, power loss) adds nothing.
//!
//! The job only sees the [`Arm`], [`Camera`] and [`Peripherals`] traits: the same code drives
//! the real and the simulated rig.

use std::sync::Arc;
use std::time::Duration;

use tokio::sync::watch;
use tracing::{info, warn};

use crate::arm::{Arm, ArmError, Arrival, MoveKind, move_and_wait};
use crate::camera::{Camera, CameraError, StreamOrigin, StreamStats, capture_settled};
use crate::clock::Clock;
use crate::config::CollectConfig;
use crate::dataset::{DatasetError, DatasetWriter, PoseRow, Source};
use crate::io::modbus::{ModbusError, NoPeripherals, Peripherals, format_readings};
use crate::plan::PlannedPose;
use crate::pose::{Pose, WorkFrame};

/// Errors that end a collection.
#[derive(Debug, thiserror::Error)]
pub enum CollectError {
    #[error(transparent)]
    Arm(#[from] ArmError),
    #[error(transparent)]
    Camera(#[from] CameraError),
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    /// `pose_id` is `None` for the no-contact reference pose.
    #[error("{} gave up after {attempts} attempts: {last}", describe_pose(*.pose_id))]
    RetriesExhausted { pose_id: Option<u32>, attempts: u32, last: ArmError },
    #[error("{} gave up after {attempts} attempts: {last}", describe_pose(*.pose_id))]
    CameraRetriesExhausted { pose_id: Option<u32>, attempts: u32, last: CameraError },
    /// A required Modbus peripheral's fault (timeout, lost connection, exception). Boxed:
    /// the error is large and rare, and every `Result` of the job carries its size.
    #[error(transparent)]
    Peripheral(Box<ModbusError>),
    #[error("{} gave up after {attempts} attempts: {last}", describe_pose(*.pose_id))]
    PeripheralRetriesExhausted { pose_id: Option<u32>, attempts: u32, last: Box<ModbusError> },
    #[error("{what} must be the same for every sensor")]
    Mismatch { what: &'static str },
}

impl From<ModbusError> for CollectError {
    fn from(e: ModbusError) -> Self {
        CollectError::Peripheral(Box::new(e))
    }
}

/// One retryable step of the job.
#[derive(Debug, Clone, Copy)]
enum Step<'p> {
    /// The no-contact reference frames above the plan origin.
    Reference,
    Pose(&'p PlannedPose),
}

impl Step<'_> {
    fn pose_id(&self) -> Option<u32> {
        match self {
            Step::Reference => None,
            Step::Pose(p) => Some(p.pose_id),
        }
    }
}

fn describe_pose(pose_id: Option<u32>) -> String {
    match pose_id {
        Some(id) => format!("plan pose {id}"),
        None => "the no-contact reference pose above the plan origin".to_string(),
    }
}

/// One sensor of the job: where its frames come from and where they go.
pub struct SensorStream<C: Camera> {
    pub camera: C,
    pub writer: DatasetWriter,
    /// The source its rows are written with: `real`, or `simulated` for a simulated sensor.
    pub source: Source,
}

/// What a finished (or interrupted) collection did.
#[derive(Debug, Clone, PartialEq)]
pub struct CollectSummary {
    /// Poses captured in this run.
    pub captured: usize,
    /// Poses that were already complete in every dataset (resume).
    pub skipped: usize,
    /// Poses left when the run was interrupted.
    pub remaining: usize,
    /// Arm faults cleared, camera timeouts and required-peripheral faults, each followed by a
    /// retry of the pose.
    pub recovered_faults: usize,
    pub interrupted: bool,
}

/// How long a cancelled collection lets its current pose go on before abandoning it (rows are
/// written whole or not at all, so an abandoned pose is simply not done).
pub const CANCEL_GRACE: Duration = Duration::from_secs(1);
/// Longest the retract after a cancel may take before the arm is disabled where it stands.
pub const CANCEL_RETRACT_TIMEOUT: Duration = Duration::from_secs(2);
/// Longest a cancelled collection waits for the arm to take the disable command.
pub const CANCEL_DISABLE_TIMEOUT: Duration = Duration::from_secs(1);

/// How a step of the job ended without an error.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum StepEnd {
    Done,
    /// Cancelled, and the step did not end within [`CANCEL_GRACE`]: dropped where it was.
    Abandoned,
}

/// Resolves [`CANCEL_GRACE`] after `cancel` turns true (never, when nobody can cancel).
async fn grace_after_cancel(mut cancel: watch::Receiver<bool>) {
    if cancel.wait_for(|c| *c).await.is_err() {
        std::future::pending::<()>().await;
    }
    tokio::time::sleep(CANCEL_GRACE).await;
}

/// The collection job. Borrow the arm; own the sensor streams and the peripherals.
pub struct CollectJob<'a, A: Arm, C: Camera, P: Peripherals = NoPeripherals> {
    pub arm: &'a mut A,
    pub sensors: Vec<SensorStream<C>>,
    pub work_frame: WorkFrame,
    pub options: CollectConfig,
    pub clock: Arc<dyn Clock>,
    /// Set to `true` to ask the job to stop after the current step.
    pub cancel: watch::Receiver<bool>,
    /// Stop as if cancelled once this many poses of this run are captured (the replay of an
    /// interrupted recording stops where the recorded run saw its interrupt). `None`: no limit.
    pub stop_after: Option<usize>,
    /// Progress display (hidden when not attached to a terminal).
    pub progress: indicatif::ProgressBar,
    /// Modbus peripherals around each capture ([`NoPeripherals`] when none are configured).
    pub peripherals: P,
}

impl<'a, A: Arm, C: Camera, P: Peripherals> CollectJob<'a, A, C, P> {
    fn cancelled(&self) -> bool {
        *self.cancel.borrow()
    }

    fn move_timeout(&self) -> Duration {
        Duration::from_secs_f64(self.options.move_timeout_s)
    }

    /// Moves to `target` and waits for arrival.
    async fn go(&mut self, target: Pose, kind: MoveKind) -> Result<Arrival, ArmError> {
        let timeout = self.move_timeout();
        move_and_wait(&mut *self.arm, target, kind, timeout).await
    }

    /// Runs the plan. Poses already present in every sensor's dataset are skipped. However the
    /// run ends, the cameras' stream counts of the run go into the manifests
    /// (`record_streams`); a finished run then stamps its end time.
    pub async fn run(mut self, plan: &[PlannedPose]) -> Result<CollectSummary, CollectError> {
        let at_start: Vec<Option<StreamStats>> = self.sensors.iter().map(|s| s.camera.stream_stats()).collect();
        let result = self.run_plan(plan).await;
        let recorded = self.record_streams(&at_start);
        let (summary, end) = match result {
            Ok(ended) => ended,
            Err(e) => {
                if let Err(not_recorded) = recorded {
                    warn!(error = %not_recorded, "could not add the stream counts to the manifests");
                }
                return Err(e);
            }
        };
        recorded?;
        // Rows are already durable; finishing stamps the end time, which an interrupted run
        // has not reached.
        if !summary.interrupted {
            for s in std::mem::take(&mut self.sensors) {
                s.writer.finish()?;
            }
        }
        self.progress.finish_and_clear();
        end?;
        info!(?summary, "collection finished");
        Ok(summary)
    }

    /// Adds what each camera's stream delivered since `at_start` to its sensor's part of the
    /// capture chain, in every dataset's manifest (each lists every sensor of the run). A
    /// camera that cannot count adds nothing; a measured stream also adds its timing.
    fn record_streams(&mut self, at_start: &[Option<StreamStats>]) -> Result<(), DatasetError> {
        let runs: Vec<(String, StreamStats)> = self
            .sensors
            .iter()
            .zip(at_start)
            .filter_map(|(s, start)| {
                let now = s.camera.stream_stats()?;
                let run = start.as_ref().map_or(now, |start| now.since(start));
                Some((s.writer.manifest().sensor.to_string(), run))
            })
            .collect();
        if runs.is_empty() {
            return Ok(());
        }
        for s in &mut self.sensors {
            s.writer.update_manifest(|manifest| {
                let Some(chain) = manifest.capture.as_mut() else { return };
                for (name, run) in &runs {
                    if let Some(part) = chain.sensors.iter_mut().find(|p| &p.name == name) {
                        let timed = (run.origin == StreamOrigin::Measured).then_some((run.timed_frames, run.timed_s));
                        part.add_stream_run(run.frames_received, run.frames_dropped, timed);
                        part.add_stale_frames(crate::camera::fresh_frame_rule(self.options.settle_s), run.stale_discarded);
                    }
                }
            })?;
        }
        Ok(())
    }

    /// The plan's steps, up to the arm disabled at the end; returns the summary and how the
    /// final retract went.
    async fn run_plan(&mut self, plan: &[PlannedPose]) -> Result<(CollectSummary, Result<Arrival, ArmError>), CollectError> {
        let mut summary = CollectSummary { captured: 0, skipped: 0, remaining: 0, recovered_faults: 0, interrupted: false };
        let todo: Vec<&PlannedPose> =
            plan.iter().filter(|p| self.sensors.iter().any(|s| !s.writer.done_ids().contains(&p.pose_id))).collect();
        summary.skipped = plan.len() - todo.len();
        self.progress.set_length(plan.len() as u64);
        self.progress.set_position(summary.skipped as u64);
        // Poses a resumed run finds done are not this run's rate.
        self.progress.reset_eta();
        info!(total = plan.len(), todo = todo.len(), "collection starting");

        self.arm.enable().await?;
        let origin = Pose::default();
        let above_origin = self.work_frame.approach_pose(&origin);

        // The no-contact reference frame, for every sensor that has none yet.
        if self.sensors.iter().any(|s| !has_reference(&s.writer)) {
            match self.with_retries(Step::Reference, above_origin, &mut summary).await {
                Ok(StepEnd::Done) => {}
                Ok(StepEnd::Abandoned) => {
                    summary.remaining = todo.len();
                    summary.interrupted = true;
                }
                Err(e) => return Err(self.stop_after(above_origin, e).await),
            }
        }

        for (k, planned) in todo.iter().enumerate() {
            if summary.interrupted || self.cancelled() || self.stop_after.is_some_and(|n| k >= n) {
                summary.remaining = todo.len() - k;
                summary.interrupted = true;
                break;
            }
            match self.with_retries(Step::Pose(planned), above_origin, &mut summary).await {
                Ok(StepEnd::Done) => {}
                Ok(StepEnd::Abandoned) => {
                    summary.remaining = todo.len() - k;
                    summary.interrupted = true;
                    break;
                }
                Err(e) => return Err(self.stop_after(above_origin, e).await),
            }
            summary.captured += 1;
            self.progress.inc(1);
        }

        // Leave the arm above the object, disabled; close the datasets. After a cancel both are
        // bounded, so the arm is disabled within 5 s of it.
        let end = if self.cancelled() {
            match tokio::time::timeout(CANCEL_RETRACT_TIMEOUT, self.go(above_origin, MoveKind::Linear)).await {
                Ok(end) => end,
                Err(_) => Err(ArmError::Timeout { what: "retracting after the cancel".into(), after: CANCEL_RETRACT_TIMEOUT }),
            }
        } else {
            self.go(above_origin, MoveKind::Linear).await
        };
        if let Err(e) = &end {
            warn!(error = %e, "could not retract at the end; disabling the arm where it stands");
        }
        if self.cancelled() {
            tokio::time::timeout(CANCEL_DISABLE_TIMEOUT, self.arm.disable())
                .await
                .map_err(|_| ArmError::Timeout { what: "disabling the arm after the cancel".into(), after: CANCEL_DISABLE_TIMEOUT })??;
        } else {
            self.arm.disable().await?;
        }
        Ok((summary, end))
    }

    /// Runs one step, clearing and retrying it after a recoverable arm fault (alarm, timeout,
    /// dropped socket) or a camera timeout, up to `retries_per_pose` times.
    /// A cancel lets the step go on for [`CANCEL_GRACE`], then abandons it
    /// ([`StepEnd::Abandoned`]), and a cancelled step is not retried.
    async fn with_retries(&mut self, step: Step<'_>, above_origin: Pose, summary: &mut CollectSummary) -> Result<StepEnd, CollectError> {
        let pose_id = step.pose_id();
        let label = describe_pose(pose_id);
        let mut attempt = 0u32;
        loop {
            if attempt > 0 && self.cancelled() {
                return Ok(StepEnd::Abandoned);
            }
            attempt += 1;
            let abandon = grace_after_cancel(self.cancel.clone());
            let result = {
                let run = async {
                    match step {
                        Step::Reference => self.reference_frames(above_origin).await,
                        Step::Pose(planned) => self.one_pose(planned).await,
                    }
                };
                tokio::select! {
                    biased;
                    result = run => result,
                    () = abandon => {
                        warn!(?pose_id, "cancelled: abandoning the step after {CANCEL_GRACE:?}");
                        return Ok(StepEnd::Abandoned);
                    }
                }
            };
            match result {
                Ok(()) => return Ok(StepEnd::Done),
                Err(CollectError::Arm(e)) if e.is_recoverable() && attempt <= self.options.retries_per_pose => {
                    warn!(?pose_id, attempt, error = %e, "arm fault; clearing and retrying");
                    self.progress.println(format!("{label}: {e}; clearing and retrying"));
                    match self.arm.clear_error().await {
                        Ok(alarms) if !alarms.is_empty() => info!(?alarms, "cleared alarms"),
                        Ok(_) => {}
                        Err(e) => return Err(e.into()),
                    }
                    summary.recovered_faults += 1;
                }
                // A frame that did not come is retried like an arm fault: a camera that
                // stalls once (USB hiccup) must not end a long collection.
                Err(CollectError::Camera(e @ CameraError::Timeout { .. })) if attempt <= self.options.retries_per_pose => {
                    warn!(?pose_id, attempt, error = %e, "camera timeout; retrying");
                    self.progress.println(format!("{label}: {e}; retrying"));
                    summary.recovered_faults += 1;
                }
                // A peripheral that did not answer (or refused) once is retried with the pose:
                // its rows are not written yet, so the retry captures the pose afresh.
                Err(CollectError::Peripheral(e)) if e.is_recoverable() && attempt <= self.options.retries_per_pose => {
                    warn!(?pose_id, attempt, error = %e, "peripheral fault; retrying");
                    self.progress.println(format!("{label}: {e}; retrying"));
                    summary.recovered_faults += 1;
                }
                Err(CollectError::Arm(e)) if e.is_recoverable() => {
                    return Err(CollectError::RetriesExhausted { pose_id, attempts: attempt, last: e });
                }
                Err(CollectError::Peripheral(e)) if e.is_recoverable() => {
                    return Err(CollectError::PeripheralRetriesExhausted { pose_id, attempts: attempt, last: e });
                }
                Err(CollectError::Camera(e @ CameraError::Timeout { .. })) => {
                    return Err(CollectError::CameraRetriesExhausted { pose_id, attempts: attempt, last: e });
                }
                Err(e) => return Err(e),
            }
        }
    }

    /// Captures the no-contact reference frame of every sensor that has none yet.
    async fn reference_frames(&mut self, above_origin: Pose) -> Result<(), CollectError> {
        let arrival = self.go(above_origin, MoveKind::Joint).await?;
        // The reference is lit like every pose; its readings have no row to go into.
        let not_before = self.prepare_capture(arrival.t_s).await?;
        let mut images = Vec::new();
        for (k, s) in self.sensors.iter_mut().enumerate().filter(|(_, s)| !has_reference(&s.writer)) {
            images.push((k, capture_settled(&mut s.camera, not_before, self.options.capture_settings()).await?.0));
        }
        let readings = self.peripherals.after_capture().await?;
        if !readings.is_empty() {
            info!(readings = %format_readings(&readings), "peripherals at the reference frame");
        }
        for (k, image) in images {
            self.sensors[k].writer.write_reference(&image)?;
        }
        Ok(())
    }

    /// The peripherals' `before_capture` writes after an arrival at `arrival_t_s`; returns the
    /// instant frames must be exposed after: the settle time after arrival, and not before the
    /// writes finished. Without peripherals this is exactly the settle time after arrival.
    async fn prepare_capture(&mut self, arrival_t_s: f64) -> Result<f64, CollectError> {
        let settled_s = arrival_t_s + self.options.settle_s;
        if self.peripherals.is_empty() {
            return Ok(settled_s);
        }
        self.peripherals.before_capture().await?;
        Ok(settled_s.max(self.clock.now_s()))
    }

    /// Leaves the arm safe after a fault that ends the run: lifts it off the sensor (the
    /// pose may have stopped in contact) and disables it. Best effort, since the arm may be
    /// what failed; returns `error` for the caller to report. Every row written is already
    /// durable, so the datasets resume as they are.
    async fn stop_after(&mut self, above_origin: Pose, error: CollectError) -> CollectError {
        warn!(error = %error, "stopping the collection: retracting and disabling the arm");
        if let Err(e) = self.arm.clear_error().await {
            warn!(error = %e, "could not clear the arm's error state");
        }
        if let Err(e) = self.go(above_origin, MoveKind::Linear).await {
            warn!(error = %e, "could not retract after the fault");
        }
        if let Err(e) = self.arm.disable().await {
            warn!(error = %e, "could not disable the arm after the fault");
        }
        self.progress.finish_and_clear();
        error
    }

    /// Approach, descend, settle, capture, write, retract: one pose.
    async fn one_pose(&mut self, planned: &PlannedPose) -> Result<(), CollectError> {
        let above = self.work_frame.approach_pose(&planned.pose);
        let contact = self.work_frame.contact_pose(&planned.pose);
        self.go(above, MoveKind::Joint).await?;
        let arrival = self.go(contact, MoveKind::Linear).await?;
        let not_before = self.prepare_capture(arrival.t_s).await?;
        let measured = self.work_frame.plan_pose(&arrival.measured);
        let mut captured = Vec::new();
        for (k, s) in self.sensors.iter_mut().enumerate().filter(|(_, s)| !s.writer.done_ids().contains(&planned.pose_id)) {
            let (image, t_capture_s) = capture_settled(&mut s.camera, not_before, self.options.capture_settings()).await?;
            captured.push((k, image, t_capture_s));
        }
        // Read while still pressed; only then are rows written, so a peripheral fault leaves
        // the pose undone in every dataset and the retry captures it again.
        let modbus = format_readings(&self.peripherals.after_capture().await?);
        for (k, image, t_capture_s) in captured {
            let source = self.sensors[k].source;
            let row = PoseRow::captured(planned.pose_id, planned.pose, measured, t_capture_s, source).with_modbus(modbus.clone());
            self.sensors[k].writer.append(row, &image)?;
        }
        self.go(above, MoveKind::Linear).await?;
        Ok(())
    }
}

/// The move-and-wait step, [`crate::arm::move_and_wait`] (here for the callers that still
/// name it so).
pub use crate::arm::move_and_wait as go;

fn has_reference(writer: &DatasetWriter) -> bool {
    writer.has_reference()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Frame;
    use crate::camera::meter::StreamMeter;
    use crate::clock::MockClock;
    use crate::dataset::{CaptureChain, CapturePart, Manifest, ObjectInfo};
    use crate::sensor::SensorKind;

    /// A measured camera: each frame asked for is one driver buffer, its sequence number
    /// `step` after the previous one (`step - 1` dropped), stamped `step` frame intervals of
    /// 1/30 s later.
    struct MeteredCamera {
        meter: StreamMeter,
        sequence: u32,
        t_s: f64,
        step: u32,
    }

    impl MeteredCamera {
        fn deliver(&mut self) {
            self.sequence += self.step;
            self.t_s += f64::from(self.step) / 30.0;
            self.meter.record(self.sequence, self.t_s);
        }
    }

    impl Camera for &mut MeteredCamera {
        fn name(&self) -> &str {
            "tactip"
        }
        async fn frame_after(&mut self, not_before_s: f64) -> Result<Frame, CameraError> {
            self.deliver();
            Ok(Frame { image: image::RgbImage::new(2, 2), t_capture_s: not_before_s, seq: u64::from(self.sequence) })
        }
        fn stream_stats(&self) -> Option<crate::camera::StreamStats> {
            Some(self.meter.stats())
        }
    }

    fn planned(n: u32) -> Vec<PlannedPose> {
        (0..n).map(|pose_id| PlannedPose { pose_id, pose: Pose::new(f64::from(pose_id), 0.0, 0.5, 0.0) }).collect()
    }

    async fn collect(camera: &mut MeteredCamera, dir: &std::path::Path, plan: &[PlannedPose], resume: bool, stop_after: Option<usize>) {
        let part = CapturePart::new("tactip", "v4l2", false, Some("port:1-2".into()));
        let mut manifest = Manifest::new(SensorKind::TacTip, ObjectInfo::named("edge"), None);
        manifest.capture =
            Some(CaptureChain { arm: CapturePart::new("arm", "mg400", false, None), sensors: vec![part], modbus: Vec::new() });
        let writer = DatasetWriter::start(dir, manifest, resume).unwrap();
        let (_stop, cancel) = watch::channel(false);
        let mut arm = crate::arm::fake::CountingArm::default();
        let job = CollectJob {
            arm: &mut arm,
            sensors: vec![SensorStream { camera, writer, source: Source::Real }],
            work_frame: WorkFrame::default(),
            options: CollectConfig { settle_s: 0.0, ..CollectConfig::default() },
            clock: Arc::new(MockClock::new()),
            cancel,
            stop_after,
            progress: indicatif::ProgressBar::hidden(),
            peripherals: NoPeripherals,
        };
        job.run(plan).await.unwrap();
    }

    #[tokio::test]
    async fn a_measured_stream_of_each_run_is_added_to_the_manifest() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("edge").join("tactip");
        // The camera has streamed before the run (a daemon keeps its cameras open): those
        // frames are not the run's.
        let mut camera = MeteredCamera { meter: StreamMeter::new(), sequence: 0, t_s: 100.0, step: 2 };
        for _ in 0..5 {
            camera.deliver();
        }
        // Run 1: the reference frame and 3 poses, every other frame dropped by the driver.
        collect(&mut camera, &dir, &planned(3), false, None).await;
        let part = |dir: &std::path::Path| Manifest::load(dir).unwrap().capture.unwrap().sensors.remove(0);
        let first = part(&dir);
        assert_eq!((first.frames_received, first.frames_dropped), (Some(4), Some(4)));
        assert!((first.stream_s.unwrap() - 8.0 / 30.0).abs() < 1e-9, "{first:?}");
        assert!((first.measured_fps.unwrap() - 15.0).abs() < 1e-9, "{first:?}");

        // Run 2 resumes a longer plan, now without drops, and is interrupted after one pose:
        // its frame is added, and the rate covers both runs' timed frames and time.
        camera.step = 1;
        collect(&mut camera, &dir, &planned(6), true, Some(1)).await;
        let second = part(&dir);
        assert_eq!((second.frames_received, second.frames_dropped), (Some(5), Some(4)));
        assert!((second.stream_s.unwrap() - 9.0 / 30.0).abs() < 1e-9, "{second:?}");
        assert!((second.measured_fps.unwrap() - 5.0 / (9.0 / 30.0)).abs() < 1e-9, "{second:?}");
        assert_eq!(Manifest::load(&dir).unwrap().resumed_utc.len(), 1);
    }
}
