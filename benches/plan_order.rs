//! Total motion time of a 500-pose plan in random order and in rig's optimised order, under
//! the firmware profile's joint-space motion model between approach poses
//! (`FirmwareProfile::motion_time_s` through `rigs::pose_cost_s`, what `rig collect` orders
//! by). Prints a table; the goal is rig's order at most 0.6x the random order. `rig bench`
//! reports the same comparison beside the other knobs.
//!
//! A second table compares rig's route with the one of the quadratic algorithm it replaced
//! (`rig::plan::reference_order`: nearest neighbour by a full scan, 2-opt over exact 16-nearest
//! lists) at 1,000 and 5,000 poses, Latin hypercube on the default grid and on the 100 x 100 x
//! 10 x 10 grid of `plans/lab-scale.toml`; the goal is at most 1.02x the reference's motion time.
//!
//! Run: `cargo bench --bench plan_order` (`cargo test` runs it too, as a smoke run: one row of
//! each table, the second at 200 poses).

use std::time::Instant;

use rig::arm::profile::FirmwareProfile;
use rig::bench::scale::lab_scale_plan;
use rig::plan::{Order, PlanSpec, Sampling, path_cost, reference_order};
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

    println!();
    println!(
        "{:<8} {:>5} {:>14} {:>14} {:>7} {:>10} {:>14}",
        "grid", "n", "reference [s]", "rig [s]", "ratio", "rig [ms]", "reference [ms]"
    );
    let sizes: &[usize] = if full { &[1_000, 5_000] } else { &[200] };
    let mut worst: f64 = 0.0;
    for &n in sizes {
        let grids = [
            ("default", PlanSpec { n_poses: Some(n), order: Order::AsSampled, ..PlanSpec::default() }),
            ("lab", PlanSpec { order: Order::AsSampled, ..lab_scale_plan(n) }),
        ];
        for (name, spec) in grids {
            let poses = spec.build(&cost).expect("valid plan").poses;
            let t0 = Instant::now();
            let rig = PlanSpec { order: Order::Optimised, ..spec }.build(&cost).expect("valid plan");
            let rig_ms = t0.elapsed().as_secs_f64() * 1e3;
            let t0 = Instant::now();
            let reference = path_cost(&reference_order(&poses, &cost), &cost);
            let reference_ms = t0.elapsed().as_secs_f64() * 1e3;
            let ratio = rig.motion_time_after_s / reference;
            worst = worst.max(ratio);
            println!(
                "{:<8} {:>5} {:>14.1} {:>14.1} {:>7.3} {:>10.1} {:>14.1}",
                name, n, reference, rig.motion_time_after_s, ratio, rig_ms, reference_ms
            );
        }
    }
    println!("worst ratio to the reference {worst:.3} (goal <= 1.02)");
}
