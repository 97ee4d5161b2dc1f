//! Opt-in checks against a real Dobot Magician. Run with
//! `RIG_MAGICIAN_PORT=/dev/ttyUSB0 cargo test --test rig hw_magician:: -- --ignored`.
//! The only move is to the pose the arm already holds, so nothing travels.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use rig::arm::magician::{MagicianArm, MagicianProfile};
use rig::arm::{Arm, MoveKind};
use rig::clock::MonotonicClock;

fn port() -> PathBuf {
    std::env::var_os("RIG_MAGICIAN_PORT")
        .map(PathBuf::from)
        .unwrap_or_else(|| panic!("set RIG_MAGICIAN_PORT to the Magician's serial port"))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "needs a Dobot Magician at RIG_MAGICIAN_PORT"]
async fn real_magician_enables_and_holds_its_pose() {
    let mut arm =
        MagicianArm::open(&port(), MagicianProfile::default_magician(), Arc::new(MonotonicClock::new())).expect("opens the serial port");
    let here = arm.pose().await.expect("GetPose answers");
    println!("Magician at {here}");
    let firmware = arm.firmware_version().await.expect("GetDeviceVersion answers");
    println!("firmware {firmware}");
    arm.enable().await.unwrap();
    arm.move_to(here, MoveKind::Linear).await.unwrap();
    let arrival = arm.wait_arrived(here, Duration::from_secs(10)).await.unwrap();
    assert!(arrival.error_mm < 0.5, "{arrival:?}");
    println!("alarms: {:?}", arm.clear_error().await.unwrap());
    arm.disable().await.unwrap();
}
