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
