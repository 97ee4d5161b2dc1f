//! `SimCamera` behind the `Camera` seam: it renders what the arm truth says, derives the noise
//! key from the pose (not the timing), and hands out stale frames when the scene asks.
//!
//! Time runs on a [`ScriptedClock`]: virtual time that advances a fixed step each time it is
//! read and publishes scripted arm truths when it passes their times, so the tests are
//! deterministic and take no real time.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use rig::camera::{Camera, CameraError};
use rig::clock::Clock;
use rig::geometry::DepthMap;
use rig::pose::{Pose, WorkFrame};
use rig::sensor::SensorKind;
use rig::sim::ArmTruth;
use rig::sim::sensor::{MotionState, Scene, SensorSim, SimCamera, Stage, shapes};
use tokio::sync::watch;

struct ScriptedClock {
    state: Mutex<(f64, Vec<ArmTruth>)>,
    step_s: f64,
    tx: watch::Sender<ArmTruth>,
}

impl ScriptedClock {
    /// Starts at 0 with `first` published; `script` truths are published when the clock
    /// reaches their `t_s`.
    fn new(step_s: f64, first: ArmTruth, mut script: Vec<ArmTruth>) -> (Arc<Self>, watch::Receiver<ArmTruth>) {
        let (tx, rx) = watch::channel(first);
        script.sort_by(|a, b| b.t_s.total_cmp(&a.t_s));
        (Arc::new(Self { state: Mutex::new((0.0, script)), step_s, tx }), rx)
    }
    fn skip_to(&self, t_s: f64) {
        let mut st = self.state.lock().unwrap();
        st.0 = st.0.max(t_s);
    }
}

impl Clock for ScriptedClock {
    fn now_s(&self) -> f64 {
        let mut st = self.state.lock().unwrap();
        st.0 += self.step_s;
        let now = st.0;
        while st.1.last().is_some_and(|e| e.t_s <= now) {
            if let Some(e) = st.1.pop() {
                self.tx.send_replace(e);
            }
        }
        now
    }
    fn real_duration(&self, _sim: Duration) -> Duration {
        Duration::ZERO
    }
}

const W: u32 = 160;
const H: u32 = 120;
const K: f32 = 3.0;

fn depth_of(object: &Pose) -> DepthMap {
    // A sphere whose centre follows the object pose and whose indentation is the pose's z.
    shapes::sphere(W, H, K, -object.x_mm as f32, -object.y_mm as f32, 8.0, object.z_mm as f32)
}

fn camera(scene: Scene, seed: u64, truth: watch::Receiver<ArmTruth>, clock: Arc<dyn Clock>) -> SimCamera {
    let sim = SensorSim::new(SensorKind::ViTacTip, scene, W, H, K, seed);
    SimCamera::new("vitactip".into(), sim, Box::new(depth_of), WorkFrame::default(), truth, clock, 1.0 / 30.0).with_exposure_s(1.0 / 60.0)
}

fn truth_at(plan: Pose, t_s: f64) -> ArmTruth {
    ArmTruth { t_s, pose: WorkFrame::default().contact_pose(&plan), speed_mm_s: 0.0 }
}

#[tokio::test]
async fn renders_the_truth_with_a_pose_derived_key() {
    let plan = Pose::new(1.5, -2.0, 0.3, 10.0);
    let (clock, rx) = ScriptedClock::new(1e-3, truth_at(plan, 0.0), vec![]);
    let mut cam = camera(Scene::preset("full").unwrap(), 42, rx, clock);
    let f0 = cam.frame_after(0.25).await.unwrap();
    let f1 = cam.frame_after(0.25).await.unwrap();
    assert!(f0.t_capture_s >= 0.25 && f1.t_capture_s > f0.t_capture_s);
    assert_eq!((f0.seq, f1.seq), (0, 1));

    let wf = WorkFrame::default();
    let object = cam.object_pose(&wf.contact_pose(&plan));
    assert!((object.z_mm - (0.3 + wf.contact_depth_mm)).abs() < 1e-9, "z is the indentation");
    let reference = SensorSim::new(SensorKind::ViTacTip, Scene::preset("full").unwrap(), W, H, K, 42);
    let depth = depth_of(&object);
    let still = MotionState { exposure_s: 1.0 / 60.0, ..MotionState::STILL };
    assert_eq!(f0.image, reference.render(&depth, &still, SimCamera::frame_key(42, &object, 0)));
    assert_eq!(f1.image, reference.render(&depth, &still, SimCamera::frame_key(42, &object, 1)));
    assert_ne!(f0.image, f1.image, "the second frame at a pose has fresh noise");
}

#[tokio::test]
async fn a_seeded_sequence_is_the_same_whatever_the_timing() {
    let poses = [Pose::new(0.0, 0.0, 0.0, 0.0), Pose::new(2.0, 1.0, 0.5, -5.0), Pose::new(0.0, 0.0, 0.0, 0.0)];
    let mut runs = Vec::new();
    for (step_s, gap_s) in [(1e-3, 0.05), (7e-3, 1.7)] {
        let script: Vec<ArmTruth> = poses.iter().enumerate().map(|(i, p)| truth_at(*p, i as f64 * gap_s)).collect();
        let (clock, rx) = ScriptedClock::new(step_s, script[0], script.clone());
        let mut cam = camera(Scene::preset("full").unwrap(), 9, rx, clock.clone());
        let mut frames = Vec::new();
        for i in 0..poses.len() {
            // Ask a little after each arrival (the arm settles, the job asks for a frame).
            let t = i as f64 * gap_s + 0.2 * gap_s;
            frames.push(cam.frame_after(t).await.unwrap().image);
            clock.skip_to((i + 1) as f64 * gap_s - step_s);
        }
        runs.push(frames);
    }
    assert_eq!(runs[0], runs[1]);
    assert_ne!(runs[0][0], runs[0][2], "a revisited pose gets the next noise key");
}

#[tokio::test]
async fn stale_frames_show_the_truth_one_period_earlier() {
    let before = Pose::new(0.0, 0.0, -3.0, 0.0); // above the object: no contact
    let after = Pose::new(0.0, 0.0, 1.0, 0.0); // pressed
    for stale in [false, true] {
        let mut stages = vec![Stage::SeeThrough];
        if stale {
            stages.push(Stage::StaleFrame);
        }
        // The arm arrives at t = 1.0 s; the job asks for a frame exposed after that.
        let (clock, rx) = ScriptedClock::new(1e-3, truth_at(before, 0.0), vec![truth_at(after, 1.0)]);
        let mut cam = camera(Scene::with_stages("t", &stages), 1, rx, clock);
        let frame = cam.frame_after(1.0).await.unwrap();
        let no_contact = cam.sim().reference();
        assert!(frame.t_capture_s >= 1.0);
        if stale {
            assert_eq!(frame.image, no_contact, "the stale frame predates the arrival");
            assert_eq!(cam.sim().stage_counts().get(Stage::StaleFrame), 1);
            // A later request is one period behind that request, after the arrival.
            let next = cam.frame_after(1.2).await.unwrap();
            assert_ne!(next.image, no_contact);
        } else {
            assert_ne!(frame.image, no_contact, "a fresh frame shows the contact");
            assert_eq!(cam.sim().stage_counts().get(Stage::StaleFrame), 0);
        }
    }
}

#[tokio::test]
async fn motion_during_the_exposure_blurs() {
    let plan = Pose::new(0.0, 0.0, 0.5, 0.0);
    let mut images = Vec::new();
    for speed_mm_s in [0.0, 60.0] {
        let t = ArmTruth { speed_mm_s, ..truth_at(plan, 0.0) };
        let (clock, rx) = ScriptedClock::new(1e-3, t, vec![]);
        let mut cam = camera(Scene::with_stages("blur", &[Stage::SeeThrough, Stage::MotionBlur]), 1, rx, clock);
        images.push(cam.frame_after(0.0).await.unwrap().image);
        assert_eq!(cam.sim().stage_counts().get(Stage::MotionBlur), 1);
    }
    assert_ne!(images[0], images[1]);
}

#[tokio::test]
async fn a_clock_that_never_reaches_the_exposure_times_out() {
    struct Frozen;
    impl Clock for Frozen {
        fn now_s(&self) -> f64 {
            0.0
        }
    }
    let (_tx, rx) = watch::channel(ArmTruth::default());
    let sim = SensorSim::new(SensorKind::TacTip, Scene::preset("none").unwrap(), 32, 32, 1.0, 0);
    let source = Box::new(|_: &Pose| DepthMap::empty(32, 32));
    let mut cam =
        SimCamera::new("t".into(), sim, source, WorkFrame::default(), rx, Arc::new(Frozen), 0.1).with_timeout(Duration::from_millis(100));
    let err = cam.frame_after(5.0).await.unwrap_err();
    assert!(matches!(err, CameraError::Timeout { timeout_ms: 100, .. }), "{err}");
}
