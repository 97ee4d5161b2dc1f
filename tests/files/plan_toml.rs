//! Plan files and the stability of pose ids.

use std::collections::BTreeSet;
use std::path::Path;

use rig::plan::{Order, PlanError, PlanSpec, Sampling, TrapezoidMotionModel};
use rig::pose::Pose;

fn cost() -> impl Fn(&Pose, &Pose) -> f64 {
    let m = TrapezoidMotionModel::default();
    move |a: &Pose, b: &Pose| m.time_s(a, b)
}

#[test]
fn default_plan_file_is_the_default_spec() {
    let spec =
        PlanSpec::load(Path::new(env!("CARGO_MANIFEST_DIR")).join("plans/default.toml").as_path()).expect("plans/default.toml loads");
    assert_eq!(spec, PlanSpec::default());
}

#[test]
fn unknown_keys_and_bad_values_are_refused() {
    let good = toml::to_string(&PlanSpec::default()).expect("serialise");
    assert_eq!(PlanSpec::from_toml_str(&good).expect("round trip"), PlanSpec::default());
    assert!(PlanSpec::from_toml_str(&format!("{good}\nspeed = 3\n")).is_err());
    assert!(PlanSpec::from_toml_str(&good.replace("\"lhs\"", "\"sobol\"")).is_err());
    let tmp = tempfile::tempdir().expect("tempdir");
    let path = tmp.path().join("p.toml");
    std::fs::write(&path, good.replace("step = 15.0", "step = -15.0")).expect("write");
    assert!(matches!(PlanSpec::load(&path), Err(PlanError::BadStep { axis: "yaw_deg", .. })));
    std::fs::write(&path, "sampling = \"lhs\"").expect("write");
    assert!(matches!(PlanSpec::load(&path), Err(PlanError::Parse { .. })));
}

#[test]
fn pose_ids_do_not_depend_on_sampling_seed_or_order() {
    let c = cost();
    let grid = PlanSpec::default().grid();
    for (sampling, order, seed) in
        [(Sampling::Random, Order::Optimised, 1), (Sampling::Lhs, Order::Random, 2), (Sampling::Lhs, Order::AsSampled, 3)]
    {
        let spec = PlanSpec { sampling, order, seed, n_poses: Some(300), ..PlanSpec::default() };
        let plan = spec.build(&c).expect("build");
        assert_eq!(plan.poses.len(), 300);
        for p in &plan.poses {
            assert_eq!(grid[p.pose_id as usize].pose, p.pose);
        }
        let unique: BTreeSet<u32> = plan.poses.iter().map(|p| p.pose_id).collect();
        assert_eq!(unique.len(), 300);
    }
    // Full sampling returns the grid itself.
    let full = PlanSpec { sampling: Sampling::Full, n_poses: None, order: Order::AsSampled, ..PlanSpec::default() };
    assert_eq!(full.build(&c).expect("build").poses, grid);
}

#[test]
fn lhs_can_take_the_whole_grid() {
    let spec = PlanSpec {
        x_mm: rig::plan::AxisRange::new(0.0, 2.0, 1.0),
        y_mm: rig::plan::AxisRange::new(0.0, 1.0, 1.0),
        z_mm: rig::plan::AxisRange::new(0.0, 0.0, 1.0),
        yaw_deg: rig::plan::AxisRange::new(-45.0, 45.0, 45.0),
        sampling: Sampling::Lhs,
        n_poses: Some(18),
        seed: 4,
        order: Order::Optimised,
    };
    let plan = spec.build(&cost()).expect("build");
    let ids: BTreeSet<u32> = plan.poses.iter().map(|p| p.pose_id).collect();
    assert_eq!(ids, (0..18).collect());
}

#[test]
fn optimised_500_pose_plan_meets_the_ratio_goal() {
    // Same measurement as benches/plan_order.rs, one seed: random order against rig's order.
    let c = cost();
    let base = PlanSpec { seed: 11, ..PlanSpec::default() };
    let random = PlanSpec { order: Order::Random, ..base.clone() }.build(&c).expect("build");
    let rig = base.build(&c).expect("build");
    let ratio = rig.motion_time_after_s / random.motion_time_after_s;
    assert!(ratio <= 0.6, "ratio {ratio}");
}

#[test]
fn plan_show_cli_prints_the_poses_and_refuses_bad_plans() {
    let rig = env!("CARGO_BIN_EXE_rig");
    let out = std::process::Command::new(rig).args(["plan", "show", "--n", "5", "--seed", "3", "--x", "-2:2:1"]).output().expect("run rig");
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("grid: 5 x 11 x 5 x 13 = 3575 poses"), "{text}");
    assert!(text.contains("motion time:"), "{text}");
    // Header line plus five pose lines after it.
    let after_header = text.lines().skip_while(|l| !l.contains("pose_id")).count();
    assert_eq!(after_header, 6, "{text}");

    let bad = std::process::Command::new(rig).args(["plan", "show", "--yaw", "10:0:5"]).output().expect("run rig");
    assert_eq!(bad.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&bad.stderr).contains("yaw_deg"));
}

mod prop {
    use super::*;
    use proptest::prelude::*;
    use rig::plan::AxisRange;

    fn axis() -> impl Strategy<Value = AxisRange> {
        (-10i32..10, 0i32..6, 1i32..4)
            .prop_map(|(min, span, step)| AxisRange::new(min as f64 * 0.5, (min + span) as f64 * 0.5, step as f64 * 0.5))
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

        /// Any valid plan yields distinct grid ids whose poses are the grid's, in any order.
        #[test]
        fn any_valid_plan_is_a_set_of_grid_points(
            x in axis(), y in axis(), z in axis(), yaw in axis(),
            lhs in any::<bool>(), frac in 0.0f64..1.0, seed in any::<u64>(), order in 0usize..3,
        ) {
            let mut spec = PlanSpec {
                x_mm: x, y_mm: y, z_mm: z, yaw_deg: yaw,
                sampling: if lhs { Sampling::Lhs } else { Sampling::Random },
                n_poses: None,
                seed,
                order: [Order::AsSampled, Order::Random, Order::Optimised][order],
            };
            let grid_len = spec.grid_len() as usize;
            spec.n_poses = Some(((grid_len as f64 * frac) as usize).clamp(1, grid_len));
            let plan = spec.build(&cost()).expect("valid plan");
            let ids: BTreeSet<u32> = plan.poses.iter().map(|p| p.pose_id).collect();
            prop_assert_eq!(ids.len(), spec.n_poses.unwrap_or(0));
            for p in &plan.poses {
                prop_assert_eq!(spec.pose_of(p.pose_id), Some(p.pose));
            }
            prop_assert!(plan.motion_time_after_s <= plan.motion_time_before_s + 1e-9 || order == 1);
        }
    }
}
