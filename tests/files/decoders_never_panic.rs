//! Every decoder of outside data, fed arbitrary bytes and mutated valid inputs, returns a value
//! or an error and never panics: STL, MDS CSV import, calibration TOML, rig config TOML, plan
//! TOML, firmware profile TOML and a dataset's kept order (`order.csv`).
//!
//! This is the proptest side of the fuzzing (`scripts/fuzz-smoke.sh` runs the cargo-fuzz
//! targets). The firmware profile and the MDS CSV import have no cargo-fuzz target (they pull
//! in too much of rig to compile alone), so this is their only fuzzing; for the others it is
//! the fallback that runs with plain `cargo test`.

use std::path::{Path, PathBuf};

use proptest::prelude::*;

use crate::mutate;
use rig::arm::profile::FirmwareProfile;
use rig::calibration::Calibration;
use rig::config::RigConfig;
use rig::dataset::export::parse_mds;
use rig::geometry::stl::Mesh;
use rig::plan::PlanSpec;

/// A valid MDS CSV: the real sample when the shared data is there, else a small literal one.
fn mds_seed() -> Vec<u8> {
    let shared = std::env::var("RIG_SHARED").unwrap_or_else(|_| "../shared".to_string());
    let real = PathBuf::from(shared).join("real-sample/multidiffsense-example/csv/1.csv");
    std::fs::read(real).unwrap_or_else(|_| {
        b"image_name,data_name,obj_id,pose_id,pose_1,pose_2,pose_3,pose_4,pose_5,pose_6,move_1,move_2,move_3,move_4,move_5,move_6\n\
frame_0_0.png,d,1,1,-3.06,0.5,1.5,0,0,-89.7,0,0,0,0,0,0\n"
            .to_vec()
    })
}

fn profile_seed() -> Vec<u8> {
    std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("firmware-profiles/mg400-v1.6.toml")).expect("the shipped firmware profile")
}

fn stl_seed() -> Vec<u8> {
    let tri = |z: f32| [glam::Vec3::new(0.0, 0.0, z), glam::Vec3::new(1.0, 0.0, z), glam::Vec3::new(0.0, 1.0, z)];
    Mesh::new(vec![tri(0.0), tri(1.0)]).to_binary_bytes("seed")
}

fn calibration_seed() -> Vec<u8> {
    Calibration::default_for(512, 512).to_toml().expect("default calibration encodes").into_bytes()
}

const CONFIG_SEED: &str = "[arm]\nbackend = \"sim\"\nsim_time_scale = 20.0\n[collect]\nframes_per_pose = 2\n\
[work_frame]\norigin = { x_mm = 300.0, y_mm = 0.0, z_mm = -20.0, yaw_deg = 90.0 }\n\
[sensors.tactip]\nscene = \"full\"\n[sim.faults]\ncollision_at_moves = [3]\ndisk_budget_bytes = 1000\n";

const PLAN_SEED: &str = "sampling = \"lhs\"\nn_poses = 4\nseed = 1\norder = \"optimised\"\n\
x_mm = { min = -5.0, max = 5.0, step = 1.0 }\ny_mm = { min = -5.0, max = 5.0, step = 1.0 }\n\
z_mm = { min = 0.0, max = 1.0, step = 0.5 }\nyaw_deg = { min = -180.0, max = 180.0, step = 90.0 }\n";

const ORDER_SEED: &[u8] = b"pose_id\n4711\n12\n0\n999999\n";

/// Runs every decoder on `bytes`; each either decodes or errs.
fn decode_all(bytes: &[u8]) {
    let _ = Mesh::from_bytes(bytes);
    let _ = rig::dataset::order::parse_order(bytes, Path::new("order.csv"));
    let _ = parse_mds(bytes, Path::new("fuzz.csv"));
    if let Ok(text) = std::str::from_utf8(bytes) {
        let _ = Calibration::from_toml(text, "fuzz.toml");
        if let Ok(c) = RigConfig::parse(text, Path::new("fuzz.toml")) {
            let _ = c.describe();
        }
        if let Ok(spec) = PlanSpec::from_toml_str(text)
            && spec.validate().is_ok()
        {
            let _ = (spec.grid_len(), spec.planned_len());
        }
        if let Ok(p) = FirmwareProfile::parse(text, Path::new("fuzz.toml")) {
            let _ = p.check_reachable(&rig::pose::Pose::new(300.0, 0.0, 0.0, 0.0));
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    #[test]
    fn arbitrary_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..600)) {
        decode_all(&bytes);
    }

    #[test]
    fn mutated_valid_inputs_never_panic(
        which in 0usize..7,
        edits in prop::collection::vec((any::<usize>(), any::<u8>(), any::<u8>()), 1..8),
    ) {
        let seed = match which {
            0 => stl_seed(),
            1 => mds_seed(),
            2 => calibration_seed(),
            3 => CONFIG_SEED.as_bytes().to_vec(),
            4 => PLAN_SEED.as_bytes().to_vec(),
            5 => ORDER_SEED.to_vec(),
            _ => profile_seed(),
        };
        decode_all(&mutate(&seed, &edits));
    }
}

/// The seeds themselves decode, so the mutations start from valid input.
#[test]
fn seeds_are_valid() {
    assert!(Mesh::from_bytes(&stl_seed()).is_ok());
    assert!(parse_mds(&mds_seed(), Path::new("seed.csv")).is_ok());
    assert!(Calibration::from_toml(std::str::from_utf8(&calibration_seed()).unwrap_or_default(), "seed").is_ok());
    assert!(RigConfig::parse(CONFIG_SEED, Path::new("seed.toml")).is_ok());
    let plan = PlanSpec::from_toml_str(PLAN_SEED).expect("plan seed parses");
    assert!(plan.validate().is_ok());
    assert_eq!(rig::dataset::order::parse_order(ORDER_SEED, Path::new("seed")).ok(), Some(vec![4711, 12, 0, 999999]));
    assert!(FirmwareProfile::parse(std::str::from_utf8(&profile_seed()).unwrap_or_default(), Path::new("p")).is_ok());
}
