//! Fresh frames, proven: a collection whose simulated cameras hold a buffer of stale frames
//! (queued while the arm moved, exposed before it arrived) saves no frame captured before
//! arrival + settle, and the manifest's sensor part names the rule and counts what it threw
//! away. First through the library, with every arrival and every delivered frame watched,
//! then through `rig collect` with `[sim] stale_buffer_frames` in the rig config.

use std::path::Path;
use std::process::Command;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use rig::arm::{Alarm, Arm, ArmError, Arrival, MoveKind};
use rig::camera::{Camera, CameraError, Frame, StreamStats, fresh_frame_rule};
use rig::clock::Clock;
use rig::collect::{CollectJob, SensorStream};
use rig::config::CollectConfig;
use rig::dataset::{CaptureChain, CapturePart, DatasetWriter, Manifest, ObjectInfo, Source, read_rows};
use rig::io::modbus::NoPeripherals;
use rig::plan::PlannedPose;
use rig::pose::{Pose, WorkFrame};
use rig::sensor::SensorKind;
use rig::sim::ArmTruth;
use rig::sim::sensor::{Scene, SensorSim, SimCamera, shapes};
use tokio::sync::watch;

const SETTLE_S: f64 = 0.2;
const FRAME_PERIOD_S: f64 = 1.0 / 30.0;
const STALE_FRAMES: u32 = 4;
/// How long each move takes on the clock: far longer than the buffer, so it is full at arrival.
const MOVE_S: f64 = 0.5;

/// Virtual time: a small step at every read, and a jump for each move.
struct SteppingClock {
    now_s: Mutex<f64>,
}

impl SteppingClock {
    fn skip(&self, by_s: f64) {
        *self.now_s.lock().unwrap() += by_s;
    }
}

impl Clock for SteppingClock {
    fn now_s(&self) -> f64 {
        let mut t = self.now_s.lock().unwrap();
        *t += 1e-3;
        *t
    }
    fn real_duration(&self, _sim: Duration) -> Duration {
        Duration::ZERO
    }
}

/// An arm that takes `MOVE_S` to get anywhere and notes each arrival time.
struct TimedArm {
    at: Pose,
    clock: Arc<SteppingClock>,
    arrivals: Arc<Mutex<Vec<f64>>>,
}

impl Arm for TimedArm {
    async fn enable(&mut self) -> Result<(), ArmError> {
        Ok(())
    }
    async fn move_to(&mut self, target: Pose, _kind: MoveKind) -> Result<(), ArmError> {
        self.at = target;
        Ok(())
    }
    async fn wait_arrived(&mut self, target: Pose, _timeout: Duration) -> Result<Arrival, ArmError> {
        self.clock.skip(MOVE_S);
        let t_s = self.clock.now_s();
        self.arrivals.lock().unwrap().push(t_s);
        Ok(Arrival { measured: target, error_mm: 0.0, t_s })
    }
    async fn pose(&mut self) -> Result<Pose, ArmError> {
        Ok(self.at)
    }
    async fn stop(&mut self) -> Result<(), ArmError> {
        Ok(())
    }
    async fn clear_error(&mut self) -> Result<Vec<Alarm>, ArmError> {
        Ok(Vec::new())
    }
    async fn disable(&mut self) -> Result<(), ArmError> {
        Ok(())
    }
}

/// The simulated camera, watched: for each frame it delivers, the latest arrival before the
/// request and the frame's capture time.
struct WatchedCamera {
    inner: SimCamera,
    arrivals: Arc<Mutex<Vec<f64>>>,
    delivered: Vec<(f64, f64)>,
}

impl Camera for &mut WatchedCamera {
    fn name(&self) -> &str {
        self.inner.name()
    }
    async fn frame_after(&mut self, not_before_s: f64) -> Result<Frame, CameraError> {
        let arrival = self.arrivals.lock().unwrap().last().copied().unwrap_or(f64::NEG_INFINITY);
        let frame = self.inner.frame_after(not_before_s).await?;
        self.delivered.push((arrival, frame.t_capture_s));
        Ok(frame)
    }
    fn stream_stats(&self) -> Option<StreamStats> {
        self.inner.stream_stats()
    }
}

#[tokio::test]
async fn stale_buffered_frames_are_never_saved_and_the_manifest_counts_them() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("sphere").join("tactip");
    let clock = Arc::new(SteppingClock { now_s: Mutex::new(10.0) });
    let arrivals = Arc::new(Mutex::new(Vec::new()));
    let (_truth_tx, truth) =
        watch::channel(ArmTruth { t_s: 0.0, pose: WorkFrame::default().contact_pose(&Pose::default()), speed_mm_s: 0.0 });
    let sim = SensorSim::new(SensorKind::TacTip, Scene::preset("full").unwrap(), 64, 64, 3.0, 7);
    let depth = Box::new(|p: &Pose| shapes::sphere(64, 64, 3.0, -p.x_mm as f32, -p.y_mm as f32, 8.0, p.z_mm as f32));
    let inner = SimCamera::new("tactip".into(), sim, depth, WorkFrame::default(), truth, clock.clone(), FRAME_PERIOD_S)
        .with_stale_buffer(STALE_FRAMES);
    let mut camera = WatchedCamera { inner, arrivals: arrivals.clone(), delivered: Vec::new() };

    let mut manifest = Manifest::new(SensorKind::TacTip, ObjectInfo::named("sphere"), None);
    manifest.capture = Some(CaptureChain {
        arm: CapturePart::new("arm", "sim-mg400", true, None),
        sensors: vec![CapturePart::new("tactip", "sim", true, None)],
        modbus: Vec::new(),
    });
    let writer = DatasetWriter::start(&dir, manifest, false).unwrap();
    let plan: Vec<PlannedPose> =
        (0..3).map(|pose_id| PlannedPose { pose_id, pose: Pose::new(f64::from(pose_id), 0.0, 0.5, 0.0) }).collect();
    let (_stop, cancel) = watch::channel(false);
    let mut arm = TimedArm { at: Pose::default(), clock: clock.clone(), arrivals: arrivals.clone() };
    let job = CollectJob {
        arm: &mut arm,
        sensors: vec![SensorStream { camera: &mut camera, writer, source: Source::Real }],
        work_frame: WorkFrame::default(),
        options: CollectConfig { settle_s: SETTLE_S, ..CollectConfig::default() },
        clock: clock.clone(),
        cancel,
        stop_after: None,
        progress: indicatif::ProgressBar::hidden(),
        peripherals: NoPeripherals,
    };
    let summary = job.run(&plan).await.unwrap();
    assert_eq!(summary.captured, 3);

    // The reference frame and one frame per pose, each exposed after its arrival + settle.
    assert_eq!(camera.delivered.len(), 4, "{:?}", camera.delivered);
    for &(arrival_s, t_capture_s) in &camera.delivered {
        assert!(t_capture_s > arrival_s + SETTLE_S, "a frame captured at {t_capture_s} s, arrival {arrival_s} s + {SETTLE_S} s settle");
    }
    // What was saved is what was delivered.
    let rows = read_rows(&dir).unwrap();
    assert_eq!(rows.len(), 3);
    for row in &rows {
        let t = row.t_capture_s.expect("a captured row has its capture time");
        assert!(camera.delivered.iter().any(|&(_, d)| d == t), "row {} at {t} s was not a delivered frame", row.pose_id);
    }
    // Every request found a full buffer of stale frames, and threw it away.
    let part = Manifest::load(&dir).unwrap().capture.unwrap().sensors.remove(0);
    assert_eq!(part.stale_frames_discarded, Some(u64::from(STALE_FRAMES) * 4), "{part:?}");
    assert_eq!(part.fresh_frame_rule.as_deref(), Some(fresh_frame_rule(SETTLE_S).as_str()));
    assert!(part.fresh_frame_rule.as_deref().is_some_and(|r| r.contains("arrival + settle_s (0.2 s)")), "{part:?}");
}

#[test]
fn rig_collect_with_stale_buffer_cameras_records_the_rule_and_the_discards() {
    let tmp = tempfile::tempdir().unwrap();
    let config = tmp.path().join("rig.toml");
    std::fs::write(&config, "[collect]\nsettle_s = 0.25\n[sim]\nstale_buffer_frames = 3\n").unwrap();
    let out = tmp.path().join("out");
    let status = Command::new(env!("CARGO_BIN_EXE_rig"))
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .env_remove("RIG_CONFIG")
        .args(["collect", "--object", "sphere", "--sensor", "tactip", "--seed", "2", "--poses", "3", "--config"])
        .arg(&config)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(status.status.success(), "{}", String::from_utf8_lossy(&status.stderr));
    let dir = out.join("sphere").join("tactip");
    let part = Manifest::load(&dir).unwrap().capture.unwrap().sensors.into_iter().find(|p| p.name == "tactip").unwrap();
    assert_eq!(part.fresh_frame_rule.as_deref(), Some(fresh_frame_rule(0.25).as_str()));
    // Three poses and the reference frame: every request met a buffer of 3 frames exposed
    // during the move (the simulated moves take far longer than 3 frame periods).
    assert_eq!(part.stale_frames_discarded, Some(12), "{part:?}");
    assert_eq!(read_rows(&dir).unwrap().len(), 3);
    assert!(Path::new(&dir).join("reference.png").is_file());
}
