//! The real MG400 client against the simulated MG400 on 127.0.0.1, ephemeral ports.
//!
//! The simulator runs on a clock 20x faster than real time, so moves take milliseconds;
//! nothing here asserts on elapsed time (timeouts only bound a hang).

use std::sync::Arc;
use std::time::Duration;

use rig::arm::dobot::client::{Mg400Client, Mg400Config};
use rig::arm::dobot::proto::RobotMode;
use rig::arm::kinematics::Joints;
use rig::arm::profile::FirmwareProfile;
use rig::arm::{Arm, ArmError, MoveKind};
use rig::clock::{Clock, MockClock, MonotonicClock};
use rig::pose::Pose;
use rig::sim::mg400::{SimFaults, SimMg400, SimMg400Config, SimPort};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

const WAIT: Duration = Duration::from_secs(20);
const TOL_MM: f64 = 0.05;

async fn start_sim(faults: SimFaults) -> (SimMg400, Arc<dyn Clock>) {
    let clock: Arc<dyn Clock> = Arc::new(MonotonicClock::scaled(20.0));
    let cfg = SimMg400Config { faults, ..Default::default() };
    let sim = SimMg400::start(cfg, clock.clone()).await.expect("simulator starts on loopback");
    (sim, clock)
}

/// What the simulator's addresses and profile make of the client settings.
fn sim_client_config(sim: &SimMg400) -> Mg400Config {
    Mg400Config::at_addresses(sim.dashboard_addr(), sim.motion_addr(), sim.feedback_addr(), sim.profile())
}

fn client_config(sim: &SimMg400) -> Mg400Config {
    let mut cfg = sim_client_config(sim);
    assert_eq!(cfg.profile, FirmwareProfile::default_mg400());
    assert_eq!(cfg.motion_port, sim.motion_addr().port());
    cfg.arrival_tolerance_mm = TOL_MM;
    cfg.arrival_tolerance_deg = 0.05;
    cfg.speed_factor_pct = 100;
    cfg
}

async fn connect(sim: &SimMg400, clock: &Arc<dyn Clock>) -> Mg400Client {
    Mg400Client::connect(client_config(sim), clock.clone()).await.expect("client connects to the simulator")
}

/// Twenty poses on a grid around a contact point, yaw varying too.
fn grid_poses() -> Vec<Pose> {
    (0..20)
        .map(|i| {
            let f = i as f64;
            Pose::new(280.0 + (i % 5) as f64 * 10.0, -30.0 + (i / 5) as f64 * 20.0, -40.0 + (f * 7.0) % 40.0, -30.0 + f * 3.0)
        })
        .collect()
}

async fn move_and_wait(client: &mut Mg400Client, target: Pose, kind: MoveKind) -> rig::arm::Arrival {
    client.move_to(target, kind).await.expect("move accepted");
    client.wait_arrived(target, WAIT).await.expect("arrives")
}

#[tokio::test]
async fn enables_and_moves_through_twenty_poses() {
    let (sim, clock) = start_sim(SimFaults::default()).await;
    assert_eq!(sim.mode(), RobotMode::Disabled, "the simulator starts disabled");
    let mut client = connect(&sim, &clock).await;
    client.enable().await.unwrap();
    assert_eq!(client.robot_mode().await.unwrap(), RobotMode::Enabled);
    let mut last_t = f64::NEG_INFINITY;
    for (i, target) in grid_poses().into_iter().enumerate() {
        let kind = if i % 2 == 0 { MoveKind::Joint } else { MoveKind::Linear };
        let arrival = move_and_wait(&mut client, target, kind).await;
        assert!(arrival.error_mm <= TOL_MM, "pose {i}: {} mm off", arrival.error_mm);
        assert!(arrival.measured.distance_mm(&target) <= TOL_MM);
        assert!(arrival.measured.yaw_error_deg(&target) <= 0.05);
        assert!(arrival.t_s > last_t, "arrival times follow the clock");
        last_t = arrival.t_s;
        assert!(sim.pose().distance_mm(&target) <= TOL_MM);
    }
    assert_eq!(sim.stats().moves_started, 20);
    assert_eq!(sim.truth().borrow().pose, grid_poses()[19]);
    client.disable().await.unwrap();
    assert_eq!(sim.mode(), RobotMode::Disabled);
}

#[tokio::test]
async fn move_to_the_current_pose_returns() {
    let (sim, clock) = start_sim(SimFaults::default()).await;
    let mut client = connect(&sim, &clock).await;
    client.enable().await.unwrap();
    let here = client.pose().await.unwrap();
    assert_eq!(here, sim.pose());
    // The mode never becomes 7 for a zero-length move; arrival must not wait for it.
    let arrival = move_and_wait(&mut client, here, MoveKind::Linear).await;
    assert_eq!(arrival.error_mm, 0.0);
    let arrival = move_and_wait(&mut client, here, MoveKind::Joint).await;
    assert_eq!(arrival.measured, here);
}

#[tokio::test]
async fn collision_alarm_is_recovered_and_the_move_retried() {
    let faults = SimFaults { collision_at_move: Some(2), ..Default::default() };
    let (sim, clock) = start_sim(faults).await;
    let mut client = connect(&sim, &clock).await;
    client.enable().await.unwrap();
    let first = Pose::new(300.0, 20.0, -20.0, 0.0);
    let second = Pose::new(260.0, -60.0, -30.0, 20.0);
    move_and_wait(&mut client, first, MoveKind::Joint).await;

    client.move_to(second, MoveKind::Joint).await.unwrap();
    let err = client.wait_arrived(second, WAIT).await.expect_err("the second move collides");
    let ArmError::Fault { alarms } = &err else { panic!("expected a robot fault, got {err:?}") };
    assert_eq!(alarms.len(), 1);
    assert_eq!((alarms[0].source, alarms[0].id), (0, 112));
    assert_eq!(alarms[0].description, "collision detection");
    assert!(err.is_recoverable());
    assert_eq!(sim.mode(), RobotMode::Error);
    // Stopped halfway, not at the target.
    assert!(sim.pose().distance_mm(&second) > 1.0);

    // While in alarm, further moves report the fault instead of being sent blindly.
    let err = client.move_to(second, MoveKind::Joint).await.expect_err("still in alarm");
    assert!(matches!(err, ArmError::Fault { .. }), "{err:?}");

    let cleared = client.clear_error().await.unwrap();
    assert_eq!(cleared.iter().map(|a| a.id).collect::<Vec<_>>(), vec![112]);
    assert_eq!(sim.mode(), RobotMode::Enabled, "re-enabled after the collision disabled the arm");
    let arrival = move_and_wait(&mut client, second, MoveKind::Joint).await;
    assert!(arrival.error_mm <= TOL_MM);
}

#[tokio::test]
async fn dropped_dashboard_socket_is_reconnected() {
    let (sim, clock) = start_sim(SimFaults::default()).await;
    let mut client = connect(&sim, &clock).await;
    client.enable().await.unwrap();
    assert_eq!(sim.stats().dashboard_connections, 1);
    sim.drop_connections(SimPort::Dashboard);
    while sim.open_connections(SimPort::Dashboard) > 0 {
        tokio::time::sleep(Duration::from_millis(2)).await;
    }
    assert_eq!(client.robot_mode().await.unwrap(), RobotMode::Enabled);
    assert_eq!(sim.stats().dashboard_connections, 2);
    move_and_wait(&mut client, Pose::new(310.0, 10.0, -10.0, 5.0), MoveKind::Linear).await;

    // Connections that close mid-command: the unanswered command is sent again.
    sim.set_faults(SimFaults { drop_dashboard_after: Some(2), ..Default::default() });
    for _ in 0..6 {
        assert_eq!(client.robot_mode().await.unwrap(), RobotMode::Enabled);
    }
    assert!(sim.stats().dashboard_connections >= 4, "{:?}", sim.stats());
}

#[tokio::test]
async fn dropped_motion_and_feedback_sockets_are_reconnected() {
    let (sim, clock) = start_sim(SimFaults::default()).await;
    let mut client = connect(&sim, &clock).await;
    client.enable().await.unwrap();
    sim.drop_connections(SimPort::Motion);
    sim.drop_connections(SimPort::Feedback);
    while sim.open_connections(SimPort::Motion) > 0 {
        tokio::time::sleep(Duration::from_millis(2)).await;
    }
    let target = Pose::new(290.0, -15.0, -25.0, -10.0);
    let arrival = move_and_wait(&mut client, target, MoveKind::Joint).await;
    assert!(arrival.error_mm <= TOL_MM);
    assert_eq!(sim.open_connections(SimPort::Feedback), 1);
}

#[tokio::test]
async fn unreachable_target_is_refused_before_sending() {
    let (sim, clock) = start_sim(SimFaults::default()).await;
    let mut client = connect(&sim, &clock).await;
    client.enable().await.unwrap();
    for target in [Pose::new(600.0, 0.0, 0.0, 0.0), Pose::new(300.0, 0.0, 300.0, 0.0), Pose::new(-300.0, 5.0, 0.0, 0.0)] {
        let err = client.move_to(target, MoveKind::Linear).await.expect_err("refused");
        let ArmError::Unreachable { pose, limit } = &err else { panic!("expected Unreachable, got {err:?}") };
        assert_eq!(*pose, target);
        assert!(limit.contains("mg400-v1.6"), "{limit}");
        assert!(err.to_string().contains(&format!("{target}")));
    }
    assert_eq!(sim.stats().motion_commands, 0, "nothing reached the controller");
    assert_eq!(sim.mode(), RobotMode::Enabled);
}

#[tokio::test]
async fn controller_alarm_for_a_target_it_cannot_reach() {
    // A profile wider than the controller's: rig lets the target through, the controller
    // alarms (mode 9, alarm 34), and the client reports a typed fault.
    let (sim, clock) = start_sim(SimFaults::default()).await;
    let mut cfg = client_config(&sim);
    cfg.profile.workspace.radius_mm[1] = 1000.0;
    cfg.profile.workspace.z_mm[1] = 1000.0;
    cfg.profile.kinematics.link2_mm = 500.0;
    let wide = [-1000.0, 1000.0];
    let limits = &mut cfg.profile.joint_limits;
    (limits.j1_deg, limits.j2_deg, limits.j3_deg, limits.j4_deg, limits.j3_minus_j2_deg) = (wide, wide, wide, wide, wide);
    limits.j2_min_when_j3_nonpositive_deg = -1000.0;
    let mut client = Mg400Client::connect(cfg, clock.clone()).await.unwrap();
    client.enable().await.unwrap();
    let target = Pose::new(600.0, 0.0, 0.0, 0.0);
    client.move_to(target, MoveKind::Joint).await.unwrap();
    let err = client.wait_arrived(target, WAIT).await.expect_err("alarm");
    let ArmError::Fault { alarms } = err else { panic!("expected a fault, got {err:?}") };
    assert_eq!(alarms[0].id, 34);
    assert_eq!(client.clear_error().await.unwrap()[0].id, 34);
    assert!(client.read_alarms().await.unwrap().is_empty());
    assert_eq!(sim.mode(), RobotMode::Enabled);
}

#[tokio::test]
async fn never_more_than_the_bound_queued() {
    let (sim, clock) = start_sim(SimFaults::default()).await;
    let mut cfg = client_config(&sim);
    cfg.max_queued_commands = 4;
    let mut client = Mg400Client::connect(cfg, clock.clone()).await.unwrap();
    client.enable().await.unwrap();
    let poses = grid_poses();
    for p in &poses {
        client.move_to(*p, MoveKind::Joint).await.unwrap();
        assert!(client.queued_moves() <= 4);
    }
    let last = *poses.last().unwrap();
    client.wait_arrived(last, WAIT).await.unwrap();
    let stats = sim.stats();
    assert_eq!(stats.motion_commands, 20);
    assert!(stats.max_queue_depth <= 4, "{stats:?}");
    assert!(!stats.frozen);
}

#[tokio::test]
async fn survives_split_delayed_replies_and_feedback_garbage() {
    let faults = SimFaults {
        reply_delay: Duration::from_millis(3),
        split_replies: true,
        feedback_garbage_every: Some(3),
        feedback_start_mid_frame: true,
        ..Default::default()
    };
    let (sim, clock) = start_sim(faults).await;
    let mut client = connect(&sim, &clock).await;
    client.enable().await.unwrap();
    for target in grid_poses().into_iter().take(5) {
        let arrival = move_and_wait(&mut client, target, MoveKind::Linear).await;
        assert!(arrival.error_mm <= TOL_MM);
    }
}

#[tokio::test]
async fn attach_runs_over_given_streams() {
    let (sim, clock) = start_sim(SimFaults::default()).await;
    let d = TcpStream::connect(sim.dashboard_addr()).await.unwrap();
    let m = TcpStream::connect(sim.motion_addr()).await.unwrap();
    let f = TcpStream::connect(sim.feedback_addr()).await.unwrap();
    let mut client = Mg400Client::attach(client_config(&sim), clock.clone(), d, m, f);
    client.enable().await.unwrap();
    let target = Pose::new(320.0, 30.0, -30.0, 12.5);
    let arrival = move_and_wait(&mut client, target, MoveKind::Joint).await;
    assert!(arrival.error_mm <= TOL_MM);
}

#[tokio::test]
async fn starts_where_configured_or_refuses_to_start() {
    let clock: Arc<dyn Clock> = Arc::new(MonotonicClock::scaled(20.0));
    let joints = Joints::new(10.0, 30.0, 40.0, -5.0);
    let cfg = SimMg400Config { start_joints: Some(joints), ..Default::default() };
    let sim = SimMg400::start(cfg, clock.clone()).await.unwrap();
    let expected = FirmwareProfile::default_mg400().kinematics.forward(&joints);
    assert_eq!(sim.pose(), expected);
    let mut client = Mg400Client::connect(sim_client_config(&sim), clock.clone()).await.unwrap();
    assert!(client.pose().await.unwrap().distance_mm(&expected) < 1e-9);
    let bad = SimMg400Config { start_pose: Pose::new(900.0, 0.0, 0.0, 0.0), ..Default::default() };
    let err = SimMg400::start(bad, clock).await.err().expect("unreachable start refused");
    assert_eq!(err.kind(), std::io::ErrorKind::InvalidInput);
}

/// What `printf 'EnableRobot()' | nc 127.0.0.1 29999` sees: the real reply format.
#[tokio::test]
async fn raw_protocol_as_netcat_sees_it() {
    let (sim, _clock) = start_sim(SimFaults::default()).await;
    let mut d = TcpStream::connect(sim.dashboard_addr()).await.unwrap();
    let mut m = TcpStream::connect(sim.motion_addr()).await.unwrap();
    async fn ask(s: &mut TcpStream, text: &str) -> String {
        s.write_all(text.as_bytes()).await.unwrap();
        let mut out = Vec::new();
        let mut b = [0u8; 256];
        while !out.ends_with(b";") {
            let n = s.read(&mut b).await.unwrap();
            assert!(n > 0, "connection closed");
            out.extend_from_slice(&b[..n]);
        }
        String::from_utf8(out).unwrap()
    }
    assert_eq!(ask(&mut d, "RobotMode()").await, "0,{4},RobotMode();");
    assert_eq!(ask(&mut m, "MovJ(300,10,0,0)").await, "-1,{},MovJ(300,10,0,0);");
    assert_eq!(ask(&mut d, "EnableRobot()").await, "0,{},EnableRobot();");
    assert_eq!(ask(&mut d, "enablerobot(1,2)").await, "-20000,{},enablerobot(1,2);");
    assert_eq!(ask(&mut d, "Jump()").await, "-10000,{},Jump();");
    assert_eq!(ask(&mut m, "MovJ(300,10,0,0)").await, "0,{},MovJ(300,10,0,0);");
    assert_eq!(ask(&mut m, "Sync()").await, "0,{},Sync();");
    // Dobot's Python SDK formats numbers with %f.
    assert_eq!(ask(&mut m, "MovL(300.000000,10.000000,0.000000,0.000000)").await, "0,{},MovL(300.000000,10.000000,0.000000,0.000000);");
    assert_eq!(ask(&mut m, "Sync()").await, "0,{},Sync();");
    // Sync answered only after the move: the arm is at the target now.
    assert_eq!(sim.pose(), Pose::new(300.0, 10.0, 0.0, 0.0));
    assert_eq!(ask(&mut d, "GetPose()").await, "0,{300.000000,10.000000,0.000000,0.000000},GetPose();");
    let errors = ask(&mut d, "GetErrorID()").await;
    assert!(errors.starts_with("0,{[\n\t[],"), "{errors:?}");
}

/// The simulator's motion runs on the clock it is given: on a mock clock nothing moves until
/// the clock does, and arrival times are stamped in mock seconds.
#[tokio::test]
async fn simulated_motion_follows_a_mock_clock() {
    let mock = MockClock::new();
    let clock: Arc<dyn Clock> = Arc::new(mock.clone());
    let sim = SimMg400::start(SimMg400Config::default(), clock.clone()).await.unwrap();
    let mut client = Mg400Client::connect(sim_client_config(&sim), clock.clone()).await.unwrap();
    client.enable().await.unwrap();
    let target = Pose::new(320.0, 40.0, -10.0, 0.0);
    client.move_to(target, MoveKind::Joint).await.unwrap();
    // The move starts, real time passes, mock time does not: the arm stays at its start pose.
    while sim.stats().moves_started == 0 {
        tokio::time::sleep(Duration::from_millis(1)).await;
    }
    tokio::time::sleep(Duration::from_millis(30)).await;
    assert!(sim.pose().distance_mm(&Pose::new(300.0, 0.0, 0.0, 0.0)) < 1e-9, "{}", sim.pose());
    assert_eq!(sim.mode(), RobotMode::Running);
    let ticker = {
        let mock = mock.clone();
        tokio::spawn(async move {
            loop {
                mock.advance(Duration::from_millis(8));
                tokio::time::sleep(Duration::from_millis(1)).await;
            }
        })
    };
    let arrival = client.wait_arrived(target, WAIT).await.unwrap();
    ticker.abort();
    assert!(arrival.error_mm <= 0.1);
    assert!(arrival.t_s > 0.0 && arrival.t_s <= mock.now_s());
}

/// `rig arm send`: one dashboard command through the real client, the reply as the controller
/// sent it; motion and unknown commands refused (exit 2) before anything connects.
#[tokio::test(flavor = "multi_thread")]
async fn rig_arm_send_prints_the_reply_and_refuses_motion() {
    let (sim, _clock) = start_sim(SimFaults::default()).await;
    let port = sim.dashboard_addr().port().to_string();
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().to_path_buf();
    let send = move |command: &'static str, port: String| {
        let path = path.clone();
        tokio::task::spawn_blocking(move || crate::run::rig(&path, &["arm", "send", "--addr", "127.0.0.1", "--port", &port, command]))
    };
    let o = send("RobotMode()", port.clone()).await.expect("rig");
    assert_eq!(crate::run::expect_code(&o, 0).trim(), "0,{4},RobotMode();");
    let o = send("getpose()", port.clone()).await.expect("rig");
    assert!(crate::run::expect_code(&o, 0).starts_with("0,{"), "{}", crate::run::text(&o));
    // A motion command is refused before anything is sent: the arm stays where it was.
    let before = sim.pose();
    let o = send("MovJ(300,10,0,0)", port.clone()).await.expect("rig");
    let t = crate::run::expect_code(&o, 2);
    assert!(t.contains("MovJ is a motion command"), "{t}");
    assert_eq!(sim.pose(), before);
    let t = crate::run::expect_code(&send("Jump()", port.clone()).await.expect("rig"), 2);
    assert!(t.contains("Jump()") && t.contains("RobotMode"), "{t}");
    // Refused before connecting: a port nothing listens on still gives the bad-input exit.
    let closed = std::net::TcpListener::bind("127.0.0.1:0").expect("bind").local_addr().expect("addr").port().to_string();
    crate::run::expect_code(&send("MovL(300,10,0,0)", closed.clone()).await.expect("rig"), 2);
    // A link that is down is a hardware fault (exit 3), naming where it tried.
    let t = crate::run::expect_code(&send("RobotMode()", closed.clone()).await.expect("rig"), 3);
    assert!(t.contains(&format!("127.0.0.1:{closed}")), "{t}");
}
