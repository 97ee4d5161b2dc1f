//! Total motion time of a 500-pose plan in random order and in rig's optimised order, under
//! the firmware profile's joint-space motion model between approach poses
//! (`FirmwareProfile::motion_time_s` through `rigs::pose_cost_s`, what `rig collect` orders
//! by). Prints a table; the goal is rig's order at most 0.6x the random order. `rig bench`
//! reports the same comparison beside the other knobs.
//!
//! Run: `cargo bench --bench plan_order` (`cargo test` runs it too, as a one-row smoke run).

use std::time::Instant;

use rig::arm::profile::FirmwareProfile;
use rig::plan::{Order, PlanSpec, Sampling};
use rig::pose::{Pose, WorkFrame};

fn main() {
    // `cargo bench` passes --bench; under `cargo test --all-targets` run one row only.
    let full = std::env::args().any(|a| a == "--bench");
    let seeds: &[u64] = if full { &[0, 1, 2] } else { &[0] };
    let profile = FirmwareProfile::default_mg400();
    let work_frame = WorkFrame::default();
    let cost = move |a: &Pose, b: &Pose| profile.pose_cost_s(&work_frame, a, b);
    println!("{:<8} {:>5} {:>6} {:>14} {:>14} {:>7} {:>10}", "sampling", "n", "seed", "random [s]", "rig [s]", "ratio", "order [ms]");
    let mut worst: f64 = 0.0;
    for sampling in [Sampling::Random, Sampling::Lhs] {
        for &seed in seeds {
            let base = PlanSpec { sampling, n_poses: Some(500), seed, ..PlanSpec::default() };
            let random = PlanSpec { order: Order::Random, ..base.clone() }.build(&cost).expect("valid plan");
            let t0 = Instant::now();
            let rig = PlanSpec { order: Order::Optimised, ..base }.build(&cost).expect("valid plan");
            let ms = t0.elapsed().as_secs_f64() * 1e3;
            let ratio = rig.motion_time_after_s / random.motion_time_after_s;
            worst = worst.max(ratio);
            println!(
                "{:<8} {:>5} {:>6} {:>14.1} {:>14.1} {:>7.3} {:>10.1}",
                sampling.to_string(),
                500,
                seed,
                random.motion_time_after_s,
                rig.motion_time_after_s,
                ratio,
                ms
            );
        }
    }
    println!("worst ratio {worst:.3} (goal <= 0.6)");
}
