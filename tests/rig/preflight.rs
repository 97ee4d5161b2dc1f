//! The pre-flight of `rig collect|calibrate|audit --dry-run`: every device the run would open
//! is opened without moving anything (the arm connected and read, never enabled; one frame per
//! camera; one read per Modbus peripheral); a missing camera, a silent Modbus device and an
//! unreachable arm each exit 3, named, with nothing moved and nothing written. A simulated
//! MG400 started by the test (real protocol on loopback) shows what the pre-flight sent it.
//! Also `rig info --config` and `rig devices --config`.

use std::path::Path;
use std::sync::Arc;

use rig::clock::MonotonicClock;
use rig::config::RigConfig;
use rig::sim::mg400::{SimMg400, SimMg400Config};

use crate::run::{expect_code, rig, rig_cmd};

/// A loopback port nothing listens on (bound, then let go).
fn closed_port() -> u16 {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
    listener.local_addr().expect("addr").port()
}

/// `[arm]` naming the simulated MG400 `sim` as a real MG400 at its loopback ports.
fn arm_at(sim: &SimMg400) -> String {
    format!(
        "[arm]\nbackend = \"mg400\"\nhost = \"127.0.0.1\"\ndashboard_port = {}\nmotion_port = {}\nfeedback_port = {}\n",
        sim.dashboard_addr().port(),
        sim.motion_addr().port(),
        sim.feedback_addr().port()
    )
}

#[test]
fn a_dry_run_on_the_built_in_simulated_rig_opens_every_device_and_moves_nothing() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path();
    let t = expect_code(&rig(dir, &["collect", "--dry-run", "--poses", "5", "--sensor", "tactip,vitac", "--out", "out"]), 0);
    for line in [
        "pre-flight of the built-in simulated rig (nothing is enabled, nothing moves):",
        "  ok      arm: simulated MG400 on loopback (profile mg400-v1.6): mode 4 (Disabled), no alarms, at (x ",
        "  ok      camera tactip: simulated: one 512x512 frame",
        "  ok      camera vitac: simulated: one 512x512 frame",
        "  ok      simulated MG400 controller: received no enable and no motion command",
        "arm envelope (base frame): x ",
        "deepest press: ",
        "output: out/sphere/tactip, out/sphere/vitac",
        "nothing moved",
    ] {
        assert!(t.contains(line), "missing {line:?} in:\n{t}");
    }
    assert!(!dir.join("out").exists(), "a dry run writes no dataset");
    // The calibration's and the audit's dry runs pre-flight too.
    let t = expect_code(&rig(dir, &["calibrate", "--sensor", "vitac", "--dry-run"]), 0);
    assert!(t.contains("  ok      camera vitac: simulated: one 512x512 frame") && t.contains("output: calibration/vitac.toml"), "{t}");
    assert!(!dir.join("calibration").exists());
}

/// The pre-flight against an MG400 it does not own: it connects and reads the mode, the alarms
/// and the pose, and the controller receives no enable and no motion command; the controller's
/// counters do see an enable when one is sent.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_pre_flight_never_enables_the_arm_nor_sends_a_motion_command() {
    let clock: Arc<dyn rig::clock::Clock> = Arc::new(MonotonicClock::new());
    let sim = SimMg400::start(SimMg400Config::default(), Arc::clone(&clock)).await.expect("simulated MG400");
    let start_pose = sim.pose();
    let config = RigConfig::parse(&arm_at(&sim), Path::new("bench.toml")).expect("config");
    let object = rig::geometry::objects::ObjectChoice::resolve("sphere", None).expect("sphere");
    let no_camera = rig::sensor::SensorSet(Vec::new());
    let preflight = rig::rigs::preflight(&config, &object, &no_camera, 0, Arc::clone(&clock)).await;
    let lines = preflight.lines();
    assert!(lines[0].starts_with("  ok      arm: MG400 at 127.0.0.1:") && lines[0].contains("mode 4 (Disabled), no alarms"), "{lines:?}");
    preflight.result().expect("every device answered");
    let stats = sim.stats();
    assert!(stats.dashboard_connections >= 1, "the pre-flight talked to the controller: {stats:?}");
    assert_eq!((stats.enable_requests, stats.motion_requests, stats.motion_commands), (0, 0, 0), "{stats:?}");
    assert_eq!(sim.mode(), rig::arm::dobot::proto::RobotMode::Disabled);
    assert_eq!(sim.pose(), start_pose);

    // The same through the binary, with a camera that is not there: exit 3 for the camera,
    // and still nothing but reads reached the controller.
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().to_path_buf();
    let camera = dir.join("video0");
    let toml = format!("{}[sensors.tactip]\nbackend = \"v4l2\"\ndevice = \"{}\"\n", arm_at(&sim), camera.display());
    std::fs::write(dir.join("bench.toml"), toml).expect("config");
    let out = tokio::task::spawn_blocking(move || {
        rig(&dir, &["collect", "--dry-run", "--config", "bench.toml", "--sensor", "tactip", "--poses", "3", "--out", "out"])
    })
    .await
    .expect("rig ran");
    let t = expect_code(&out, 3);
    assert!(t.contains("  ok      arm: MG400 at 127.0.0.1:") && t.contains("  FAILED  camera tactip: v4l2 "), "{t}");
    assert!(t.contains("error: pre-flight: 1 device failed: camera tactip"), "{t}");
    let stats = sim.stats();
    assert!(stats.dashboard_connections >= 2, "{stats:?}");
    assert_eq!((stats.enable_requests, stats.motion_requests), (0, 0), "{stats:?}");
    assert!(!tmp.path().join("out").exists());

    // The counters are live: an enable is counted (so the zeros above are not a constant).
    let mut client = rig::arm::dobot::client::Mg400Client::connect(
        rig::arm::dobot::client::Mg400Config::new("127.0.0.1", rig::arm::profile::FirmwareProfile::default_mg400()).with_ports(
            sim.dashboard_addr().port(),
            sim.motion_addr().port(),
            sim.feedback_addr().port(),
        ),
        Arc::clone(&clock),
    )
    .await
    .expect("client");
    rig::arm::Arm::enable(&mut client).await.expect("enable");
    assert_eq!(sim.stats().enable_requests, 1);
    drop(client);
    sim.shutdown().await;
}

#[test]
fn a_missing_camera_and_a_silent_modbus_device_are_both_named_with_exit_3() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path();
    let config = format!(
        "[sensors.vitac]\nbackend = \"v4l2\"\ndevice = \"{}\"\n\
         [modbus.force]\ntransport = \"sim\"\nsim = \"force\"\nsim_stop_answering_after = 0\ntimeout_ms = 200\n\
         read = [{{ name = \"force_mN\", kind = \"input\", register = 0, words = 2, signed = true }}]\n",
        dir.join("video7").display()
    );
    std::fs::write(dir.join("rig.toml"), config).expect("config");
    for args in [&["collect", "--dry-run", "--out", "out"][..], &["calibrate", "--sensor", "vitac", "--dry-run", "--out", "cal.toml"][..]] {
        let t = expect_code(&rig(dir, args), 3);
        assert!(t.contains("  ok      arm: simulated MG400"), "{t}");
        assert!(t.contains("  FAILED  camera vitac: v4l2 ") && t.contains("video7"), "{t}");
        assert!(
            t.contains("  FAILED  modbus force (sim force sensor unit 1, required): ") && t.contains("got no answer within 200ms"),
            "{t}"
        );
        assert!(t.contains("error: pre-flight: 2 devices failed: camera vitac") && t.contains("; modbus force"), "{t}");
        assert!(t.contains("received no enable and no motion command") && t.contains("dry run: nothing moved"), "{t}");
        if args[0] == "collect" {
            // Every device is tried: the other cameras answered.
            assert!(t.contains("  ok      camera tactip: simulated: one 512x512 frame"), "{t}");
            assert!(t.contains("  ok      camera vitactip: simulated: one 512x512 frame"), "{t}");
        }
    }
    assert!(!dir.join("out").exists() && !dir.join("cal.toml").exists());
    // An optional device that is silent is a warning, not a failure.
    let optional =
        std::fs::read_to_string(dir.join("rig.toml")).expect("config").replace("timeout_ms = 200", "timeout_ms = 200\nrequired = false");
    std::fs::write(
        dir.join("optional.toml"),
        optional.replace(&format!("[sensors.vitac]\nbackend = \"v4l2\"\ndevice = \"{}\"\n", dir.join("video7").display()), ""),
    )
    .expect("config");
    let t = expect_code(&rig(dir, &["collect", "--dry-run", "--config", "optional.toml", "--sensor", "tactip"]), 0);
    assert!(t.contains("  warning modbus force (sim force sensor unit 1, optional): "), "{t}");
}

#[test]
fn an_unreachable_arm_exits_3_naming_it() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path();
    let port = closed_port();
    std::fs::write(dir.join("far.toml"), format!("[arm]\nbackend = \"mg400\"\nhost = \"127.0.0.1\"\ndashboard_port = {port}\n"))
        .expect("config");
    let t = expect_code(&rig(dir, &["collect", "--dry-run", "--config", "far.toml", "--sensor", "tactip", "--out", "out"]), 3);
    assert!(t.contains(&format!("  FAILED  arm: MG400 at 127.0.0.1:{port} (profile mg400-v1.6): ")), "{t}");
    assert!(t.contains("Connection refused"), "{t}");
    // A simulated sensor has nothing to show on a real arm: said so, and --sensor named.
    assert!(t.contains("sensor tactip is simulated") && t.contains("--sensor"), "{t}");
    assert!(t.contains(&format!("error: pre-flight: 2 devices failed: arm: MG400 at 127.0.0.1:{port}")), "{t}");
    assert!(!dir.join("out").exists());
}

const BENCH: &str = "[arm]\nbackend = \"mg400\"\nhost = \"192.0.2.7\"\nprofile = \"mg400-v1.6\"\nspeed_factor = 30\n\
    [work_frame]\norigin = { x_mm = 250.0, y_mm = 10.0, z_mm = -30.0, yaw_deg = 5.0 }\ncontact_depth_mm = 1.2\n\
    [sensors.tactip]\nbackend = \"v4l2\"\ndevice = \"port:1-2.1\"\nwidth = 640\nheight = 480\nfps = 30\npixel_format = \"mjpeg\"\n\
    exposure_100us = 156\nmax_indentation_mm = 4.0\n\
    [modbus.light]\ntransport = \"tcp\"\naddress = \"192.0.2.50:502\"\nrequired = false\n\
    read = [{ name = \"level_permille\", register = 0 }]\n";

#[test]
fn info_lists_what_the_configuration_names_from_config_or_rig_config() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path();
    std::fs::write(dir.join("bench.toml"), BENCH).expect("config");
    let by_flag = expect_code(&rig(dir, &["info", "--config", "bench.toml"]), 0);
    let by_env = {
        let o = rig_cmd(dir, &["info"]).env("RIG_CONFIG", dir.join("bench.toml")).output().expect("rig info");
        expect_code(&o, 0)
    };
    for t in [&by_flag, &by_env] {
        for line in [
            "  arm: MG400 at 192.0.2.7 (dashboard 29999, motion 30003, feedback 30004), profile mg400-v1.6, speed factor 30%",
            "  work frame: origin (x 250.000 mm, y 10.000 mm, z -30.000 mm, yaw 5.000 deg), contact depth 1.2 mm, approach 10 mm, tool offset 0 mm",
            "  sensor tactip: v4l2 camera port:1-2.1, 640x480 at 30 fps, format MJPG, exposure 156 x 100 us, gain auto, white balance auto, calibration none set; press limit 4 mm (configured)",
            "  sensor vitac: simulated (no [sensors.vitac] table), 512x512; press limit 2.5 mm (ViTac's default)",
            "  modbus light (tcp 192.0.2.50:502 unit 1, optional): reads level_permille, timeout 500 ms",
        ] {
            assert!(t.contains(line), "missing {line:?} in:\n{t}");
        }
    }
    let t = expect_code(&rig(dir, &["info"]), 0);
    assert!(t.contains("using the built-in simulated rig") && t.contains("  arm: simulated MG400"), "{t}");
    // A configuration that cannot be read is bad input, for info and for devices (refused
    // before anything is scanned).
    for args in [&["info", "--config", "nope.toml"][..], &["devices", "--config", "nope.toml"][..]] {
        let t = expect_code(&rig(dir, args), 2);
        assert!(t.contains("cannot read rig config nope.toml"), "{t}");
    }
    std::fs::write(dir.join("typo.toml"), "[sensors.tactip]\nmax_indentation_mm = 0.0\n").expect("config");
    let t = expect_code(&rig(dir, &["devices", "--config", "typo.toml"]), 2);
    assert!(t.contains("sensors.*.max_indentation_mm") && t.contains("must be above 0"), "{t}");
}
