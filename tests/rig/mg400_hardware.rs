//! Opt-in checks against a real MG400 (run with
//! `RIG_ARM_ADDR=192.168.1.6 cargo test --test rig mg400_hardware:: -- --ignored`). The robot must be
//! in "TCP/IP secondary development" remote-control mode. The only move is to the pose the arm
//! already holds, so nothing travels.

use std::sync::Arc;
use std::time::Duration;

use rig::arm::dobot::client::{Mg400Client, Mg400Config};
use rig::arm::profile::FirmwareProfile;
use rig::arm::{Arm, MoveKind};
use rig::clock::{Clock, MonotonicClock};

fn arm_addr() -> String {
    std::env::var("RIG_ARM_ADDR").unwrap_or_else(|_| panic!("set RIG_ARM_ADDR to the MG400's address"))
}

#[tokio::test]
#[ignore = "needs an MG400 at RIG_ARM_ADDR"]
async fn real_arm_enables_and_holds_its_pose() {
    let clock: Arc<dyn Clock> = Arc::new(MonotonicClock::new());
    let cfg = Mg400Config::new(arm_addr(), FirmwareProfile::default_mg400());
    let mut arm = Mg400Client::connect(cfg, clock).await.expect("connects to the MG400");
    let here = arm.pose().await.unwrap();
    arm.enable().await.unwrap();
    arm.move_to(here, MoveKind::Linear).await.unwrap();
    let arrival = arm.wait_arrived(here, Duration::from_secs(10)).await.unwrap();
    assert!(arrival.error_mm < 0.1, "{arrival:?}");
    arm.disable().await.unwrap();
}
