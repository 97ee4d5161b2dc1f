//! Synthesis with the committed tiny package (ONNX Runtime) and the evaluation of synthetic images.
//!
//! One test binary per area; run one module with
//! `cargo test --test synth <module>::`.

mod audit;
mod cli;
#[cfg(feature = "downstream")]
mod downstream;
mod eval;
mod mds_parity;
mod synth_device;
mod synth_errors;
mod synth_fill;
mod synth_parity;
mod synth_prompt_real;
