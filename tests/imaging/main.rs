//! Geometry, calibration fits, the simulated sensors and numerical stability.
//!
//! One test binary per area; run one module with
//! `cargo test --test imaging <module>::`.

mod calibration_fit;
mod geometry_cli;
mod geometry_fit_metrics;
mod geometry_raster;
mod sensor_camera;
mod sensor_fuzz;
mod sensor_golden;
mod sensor_look;
mod sensor_stages;
mod sensor_support;
mod stability;
