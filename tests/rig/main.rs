//! End-to-end tests of the rig binary, the MG400 client, the daemon and the opt-in hardware checks.
//!
//! One test binary per area; run one module with
//! `cargo test --test rig <module>::`.

// Its cases load the tiny model package: the `synth` feature.
#[cfg(feature = "synth")]
mod adaptive;
mod bad_input;
mod bench_report;
mod calibration_cli;
mod calibration_wizard;
mod collect_e2e;
mod collect_modbus;
mod daemon_api;
mod daemon_browser;
mod dataset_kill;
mod fault_matrix;
mod fresh_frames;
// Its cases load model packages and export LeRobot datasets: the default features.
#[cfg(all(feature = "synth", feature = "lerobot"))]
mod hostile;
mod hw_camera;
mod hw_magician;
mod hw_modbus;
mod mg400_client;
mod mg400_hardware;
mod preflight;
mod press_limits;
mod provenance;
mod record_replay;
mod run;

/// The tiny model package of the tests (random weights).
#[cfg(feature = "synth")]
fn tiny_package() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/tiny-package")
}

/// A copy of the tiny model package under `dir`: for breaking, and for the daemon page's fill,
/// whose model must lie inside the daemon's data roots.
#[cfg(feature = "synth")]
fn copy_package(dir: &std::path::Path) -> std::path::PathBuf {
    for f in rig::synth::package::PACKAGE_FILES {
        let to = dir.join(f);
        std::fs::create_dir_all(to.parent().expect("parent")).expect("mkdir");
        std::fs::copy(tiny_package().join(f), to).expect("copy");
    }
    dir.to_path_buf()
}
