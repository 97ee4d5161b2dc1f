//! [`SimCamera`]: a simulated sensor behind the [`Camera`] seam.
//!
//! A frame is exposed over `[t0, t0 + exposure]` with `t0 = max(not_before_s, now)`. The
//! camera reads the arm truth at both ends (the direction of motion comes from the change
//! of pose, the speed from the truth's `speed_mm_s`), converts the base-frame pose to the
//! work frame, asks the depth source for the object's depth map at
//! `(x, y, indentation, yaw)` and renders. Waiting goes through the [`Clock`], so a scaled
//! or mock clock runs the camera faster than real time.
//!
//! The noise key of a frame depends only on the seed, the rendered pose quantised to
//! 1 um / 1 mdeg and how many frames were already taken at that pose, so a seeded
//! collection gives the same bytes whatever the timing.
//!
//! With the scene's `stale_frame` stage the camera hands out what it saw one frame period
//! before the end of the exposure (a buffer that was not flushed), stamped as the new frame.
//!
//! With a stale buffer ([`SimCamera::with_stale_buffer`], `[sim] stale_buffer_frames`) the
//! camera models a driver queue: up to N frames, one frame period apart, exposed before the
//! request and since the previous frame, wait in front of the fresh ones. [`Camera::frame_after`]
//! hands them through the same [`StaleFrameFilter`] a hardware backend uses, so frames exposed
//! before the instant asked for are discarded and counted (`stale_discarded`).
//!
//! It renders a frame only when one is asked for, so it has no stream to measure:
//! [`Camera::stream_stats`] counts the frames it rendered, none dropped, and gives its frame
//! rate as nominal ([`StreamOrigin::Simulated`]), never as measured.

use std::collections::HashMap;
use std::sync::Arc;
use std::time::Duration;

use tokio::sync::watch;

use super::stages::mix64;
use super::{MotionState, SensorSim, Stage};
use crate::camera::{Camera, CameraError, Frame, StaleFrameFilter, StreamOrigin, StreamStats};
use crate::clock::Clock;
use crate::geometry::DepthMap;
use crate::pose::{Pose, WorkFrame};
use crate::sim::ArmTruth;

/// Gives the object's depth map for an object pose (work frame x, y in mm, indentation in
/// mm as z, yaw in degrees).
pub type DepthSource = Box<dyn Fn(&Pose) -> DepthMap + Send + Sync>;

/// Longest real time a frame may take before the camera reports a timeout.
const DEFAULT_TIMEOUT: Duration = Duration::from_secs(30);
/// Longest single real-time sleep while waiting on the clock (a mock clock may jump).
const POLL: Duration = Duration::from_millis(2);
/// Real waits shorter than this are not worth a timer (tokio's resolution is 1 ms).
const MIN_SLEEP: Duration = Duration::from_micros(50);

/// A simulated tactile camera.
pub struct SimCamera {
    name: String,
    sim: SensorSim,
    depth_source: DepthSource,
    work_frame: WorkFrame,
    truth: watch::Receiver<ArmTruth>,
    clock: Arc<dyn Clock>,
    frame_period_s: f64,
    exposure_s: f64,
    timeout: Duration,
    seq: u64,
    taken_at_pose: HashMap<[i64; 4], u64>,
    /// Frames the modelled driver queue holds at most (0: no queue).
    stale_buffer_frames: u32,
    /// End of the last frame's exposure, rig clock: the queue fills from there.
    last_frame_end_s: Option<f64>,
    stale: StaleFrameFilter,
}

impl std::fmt::Debug for SimCamera {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SimCamera")
            .field("name", &self.name)
            .field("kind", &self.sim.kind())
            .field("frame_period_s", &self.frame_period_s)
            .field("exposure_s", &self.exposure_s)
            .field("seq", &self.seq)
            .finish_non_exhaustive()
    }
}

impl SimCamera {
    /// A camera streaming every `frame_period_s` (rig clock); the exposure defaults to half
    /// the period. Non-finite or non-positive periods fall back to 1/30 s.
    pub fn new(
        name: String,
        sim: SensorSim,
        depth_source: DepthSource,
        work_frame: WorkFrame,
        truth: watch::Receiver<ArmTruth>,
        clock: Arc<dyn Clock>,
        frame_period_s: f64,
    ) -> Self {
        let frame_period_s = if frame_period_s.is_finite() && frame_period_s > 0.0 { frame_period_s } else { 1.0 / 30.0 };
        Self {
            name,
            sim,
            depth_source,
            work_frame,
            truth,
            clock,
            frame_period_s,
            exposure_s: frame_period_s / 2.0,
            timeout: DEFAULT_TIMEOUT,
            seq: 0,
            taken_at_pose: HashMap::new(),
            stale_buffer_frames: 0,
            last_frame_end_s: None,
            stale: StaleFrameFilter::default(),
        }
    }

    /// Sets the exposure time (clamped to `0..=frame period`).
    pub fn with_exposure_s(mut self, exposure_s: f64) -> Self {
        self.exposure_s = if exposure_s.is_finite() { exposure_s.clamp(0.0, self.frame_period_s) } else { self.exposure_s };
        self
    }

    /// Models a driver queue of up to `frames` frames exposed before each request (see the
    /// module docs).
    pub fn with_stale_buffer(mut self, frames: u32) -> Self {
        self.stale_buffer_frames = frames;
        self
    }

    /// Sets how long (real time) a frame may take before [`CameraError::Timeout`].
    pub fn with_timeout(mut self, timeout: Duration) -> Self {
        self.timeout = timeout;
        self
    }

    /// Replaces the object under the sensor (a long-running rig presses several objects in
    /// turn without reopening its cameras).
    pub fn set_depth_source(&mut self, depth_source: DepthSource) {
        self.depth_source = depth_source;
    }

    /// The simulator (for its stage counts and reference frame).
    pub fn sim(&self) -> &SensorSim {
        &self.sim
    }

    /// Object pose (x, y, indentation as z, yaw) for a base-frame tool pose.
    pub fn object_pose(&self, base: &Pose) -> Pose {
        let plan = self.work_frame.plan_pose(base);
        Pose::new(plan.x_mm, plan.y_mm, plan.z_mm + self.work_frame.contact_depth_mm, plan.yaw_deg)
    }

    /// Noise key of the `count`-th frame (0-based) taken at `object_pose`.
    pub fn frame_key(seed: u64, object_pose: &Pose, count: u64) -> u64 {
        let q = quantise(object_pose);
        let mut k = mix64(seed);
        for v in q {
            k = mix64(k ^ v as u64);
        }
        mix64(k ^ count)
    }

    /// Sleeps until the clock reaches `t_s`, failing after the timeout (real time).
    async fn wait_until(&self, t_s: f64, started: tokio::time::Instant) -> Result<(), CameraError> {
        loop {
            let now = self.clock.now_s();
            if now >= t_s {
                return Ok(());
            }
            if started.elapsed() > self.timeout {
                return Err(CameraError::Timeout { camera: self.name.clone(), timeout_ms: self.timeout.as_millis() as u64 });
            }
            let real = self.clock.real_duration(Duration::from_secs_f64(t_s - now));
            if real < MIN_SLEEP {
                // A virtual clock (no real time behind it) moves when polled: just yield.
                tokio::task::yield_now().await;
            } else {
                tokio::time::sleep(real.min(POLL)).await;
            }
        }
    }

    fn read_truth(&self) -> ArmTruth {
        // Copy out at once: the borrow guard must not live across an await.
        *self.truth.borrow()
    }
}

/// The pose quantised to 1 um and 1 mdeg (non-finite components become 0).
fn quantise(p: &Pose) -> [i64; 4] {
    let q = |v: f64, per_unit: f64| if v.is_finite() { (v * per_unit).round() as i64 } else { 0 };
    [q(p.x_mm, 1e3), q(p.y_mm, 1e3), q(p.z_mm, 1e3), q(p.yaw_deg, 1e3)]
}

impl Camera for SimCamera {
    fn name(&self) -> &str {
        &self.name
    }

    async fn frame_after(&mut self, not_before_s: f64) -> Result<Frame, CameraError> {
        let started = tokio::time::Instant::now();
        let now = self.clock.now_s();
        // The queue: frames exposed one period apart, the newest ending now, none before the
        // previous frame's end. They come first and are kept only if the rule admits them.
        let queued = match self.last_frame_end_s {
            Some(last_end) => (((now - last_end) / self.frame_period_s).floor().max(0.0) as u64).min(u64::from(self.stale_buffer_frames)),
            None => u64::from(self.stale_buffer_frames),
        };
        for k in (0..queued).rev() {
            let queued_end = now - k as f64 * self.frame_period_s;
            if self.stale.admit(queued_end - self.exposure_s, not_before_s) {
                // Fresh enough: deliver it (seen as the arm is now; it stood still since).
                let seen = self.read_truth();
                return Ok(self.render(seen, seen, queued_end));
            }
        }
        let t0 = if not_before_s.is_finite() { not_before_s.max(now) } else { now };
        let mut t_end = t0 + self.exposure_s;

        let (start, seen) = if self.sim.runs(Stage::StaleFrame) {
            self.sim.count(Stage::StaleFrame);
            let t_stale = t_end - self.frame_period_s;
            if t_stale >= now {
                self.wait_until(t_stale - self.exposure_s, started).await?;
                let a = self.read_truth();
                self.wait_until(t_stale, started).await?;
                (a, self.read_truth())
            } else {
                // Too late to look back: keep what is seen now and deliver it one period later.
                let a = self.read_truth();
                t_end = self.clock.now_s().max(now) + self.frame_period_s;
                (a, a)
            }
        } else {
            self.wait_until(t0, started).await?;
            let a = self.read_truth();
            (a, a)
        };
        self.wait_until(t_end, started).await?;
        let (start, seen) = if self.sim.runs(Stage::StaleFrame) { (start, seen) } else { (start, self.read_truth()) };
        Ok(self.render(start, seen, t_end))
    }

    fn stream_stats(&self) -> Option<StreamStats> {
        Some(StreamStats {
            frames_received: self.seq,
            frames_dropped: 0,
            timed_frames: 0,
            timed_s: 0.0,
            stale_discarded: self.stale.discarded(),
            origin: StreamOrigin::Simulated { nominal_fps: 1.0 / self.frame_period_s },
        })
    }
}

impl SimCamera {
    /// Renders the frame whose exposure ends at `t_end`, from the truths at its start and
    /// end.
    fn render(&mut self, start: ArmTruth, seen: ArmTruth, t_end: f64) -> Frame {
        let object_pose = self.object_pose(&seen.pose);
        let start_pose = self.object_pose(&start.pose);
        let (dx, dy) = (object_pose.x_mm - start_pose.x_mm, object_pose.y_mm - start_pose.y_mm);
        let motion = MotionState {
            speed_px_per_s: (seen.speed_mm_s.abs() * self.sim.px_per_mm() as f64) as f32,
            direction_rad: if dx == 0.0 && dy == 0.0 { 0.0 } else { dy.atan2(dx) as f32 },
            exposure_s: self.exposure_s as f32,
        };
        let q = quantise(&object_pose);
        let count = self.taken_at_pose.entry(q).or_insert(0);
        let key = Self::frame_key(self.sim.seed(), &object_pose, *count);
        *count += 1;
        let depth = (self.depth_source)(&object_pose);
        let image = self.sim.render(&depth, &motion, key);
        let seq = self.seq;
        self.seq += 1;
        self.last_frame_end_s = Some(t_end);
        Frame { image, t_capture_s: t_end - self.exposure_s / 2.0, seq }
    }
}
