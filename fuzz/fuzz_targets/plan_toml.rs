//! Fuzzes the plan TOML reader and validation; a plan that validates and is small enough to
//! build in a fuzz iteration is built too.
#![no_main]
#![allow(dead_code)]

#[path = "../../src/pose.rs"]
mod pose;
#[path = "../../src/plan/mod.rs"]
mod plan;
#[path = "../../src/untrusted.rs"]
mod untrusted;
#[path = "../../src/confine.rs"]
mod confine;

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    let Ok(spec) = plan::PlanSpec::from_toml_str(text) else { return };
    if spec.validate().is_err() {
        return;
    }
    let _ = (spec.axis_counts(), spec.grid_len(), spec.planned_len());
    if spec.planned_len() <= 200 && spec.grid_len() <= 100_000 {
        let built = spec.build(&|a: &pose::Pose, b: &pose::Pose| (a.x_mm - b.x_mm).abs() + (a.y_mm - b.y_mm).abs());
        if let Ok(p) = built {
            assert!(p.poses.len() as u64 <= spec.grid_len());
        }
    }
});
