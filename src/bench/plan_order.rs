//! Plan order: the same sampled poses in random order and in rig's optimised order, total
//! motion time from the firmware profile's joint-space model
//! ([`FirmwareProfile::motion_time_s`](crate::arm::profile::FirmwareProfile::motion_time_s))
//! between consecutive approach poses, as `rig collect` orders them
//! ([`FirmwareProfile::pose_cost_s`](crate::arm::profile::FirmwareProfile::pose_cost_s)). Accuracy does not change: the poses are the same.

use std::time::Instant;

use super::error::BenchError;
use super::knob::{BenchConfig, Knob};
use super::plot::{Plot, Series};
use super::table::{Column, KnobReport, Row};
use crate::arm::profile::FirmwareProfile;
use crate::plan::{Order, PlanSpec, Sampling};
use crate::pose::{Pose, WorkFrame};

/// Total motion time of `config.plan_poses` poses (the default plan's grid, LHS sampling)
/// per seed, random against optimised.
pub fn measure(config: &BenchConfig) -> Result<KnobReport, BenchError> {
    let profile = FirmwareProfile::default_mg400();
    let work_frame = WorkFrame::default();
    let cost = |a: &Pose, b: &Pose| profile.pose_cost_s(&work_frame, a, b);
    let mut rows = Vec::new();
    let (mut random_pts, mut rig_pts) =
        (Series { name: "random order".into(), ..Default::default() }, Series { name: "rig's order".into(), ..Default::default() });
    for &seed in &config.plan_seeds {
        let base = PlanSpec { sampling: Sampling::Lhs, n_poses: Some(config.plan_poses), seed, ..PlanSpec::default() };
        let t = Instant::now();
        let random = PlanSpec { order: Order::Random, ..base.clone() }.build(&cost)?;
        let random_ms = t.elapsed().as_secs_f64() * 1e3;
        let t = Instant::now();
        let rig = PlanSpec { order: Order::Optimised, ..base }.build(&cost)?;
        let rig_ms = t.elapsed().as_secs_f64() * 1e3;
        let n = rig.poses.len() as f64;
        let (tr, to) = (random.motion_time_after_s, rig.motion_time_after_s);
        rows.push(Row { label: format!("random, seed {seed}"), values: vec![n, tr, tr / n, 1.0, random_ms] });
        rows.push(Row { label: format!("rig's order, seed {seed}"), values: vec![n, to, to / n, to / tr, rig_ms] });
        random_pts.points.push([seed as f64, tr]);
        random_pts.labels.push(String::new());
        rig_pts.points.push([seed as f64, to]);
        rig_pts.labels.push(format!("{:.2}x", to / tr));
    }
    if rows.is_empty() {
        return Err(BenchError::Empty { knob: Knob::PlanOrder, reason: "no plan seeds" });
    }
    Ok(KnobReport {
        knob: Knob::PlanOrder,
        title: "Plan order: random against rig's order".into(),
        label_column: "order".into(),
        columns: vec![
            Column::new("poses", 0),
            Column::new("total motion [s, modelled]", 1),
            Column::new("per pose [s]", 3),
            Column::new("vs random", 3),
            Column::new("ordering [ms]", 1),
        ],
        rows,
        notes: vec![
            format!(
                "{} poses sampled by Latin hypercube from the default plan's grid (x, y ±5 mm, z ±1 mm, yaw ±90°), \
                 per seed, once in random order and once in rig's optimised order (nearest neighbour plus 2-opt).",
                config.plan_poses
            ),
            format!(
                "Total motion time = sum over consecutive poses of `FirmwareProfile::motion_time_s` between the approach \
                 poses (profile `{}`, 100 % speed: every joint a trapezoid under its speed and acceleration limits, the \
                 slowest joint sets the time). Descent and retract are the same for every order and left out. \
                 *ordering* is the wall time to build the plan.",
                profile.name
            ),
        ],
        plot: Plot {
            title: "Plan order: total motion time".into(),
            x_label: "plan seed".into(),
            y_label: "total motion time [s, modelled]".into(),
            series: vec![random_pts, rig_pts],
            lines: false,
        },
    })
}
