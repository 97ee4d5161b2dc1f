//! Command-line parsing and wiring. Each subcommand lives in its own file with a clap `Args`
//! struct and a `run` function; behaviour lives in the library modules, not here.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

pub mod calibrate;
pub mod collect;
pub mod fill;
pub mod sim;
pub mod dataset;
pub mod plan;
pub mod sensor;
pub mod synth;
pub mod compare;
pub mod objects;
pub mod render;
pub mod sensor_bridge;

/// rig: drive a tactile-sensing rig (Dobot MG400 + vision-based tactile sensors), collect
/// datasets and synthesise the poses not collected.
#[derive(Debug, Parser)]
#[command(name = "rig", version, about, long_about = None)]
pub struct Cli {
    /// Log filter (tracing EnvFilter syntax), e.g. `info` or `rig=debug`.
    #[arg(long, global = true, env = "RIG_LOG", default_value = "warn")]
    pub log: String,
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Print the version and the configuration rig would use.
    Info,
    /// Drive the arm through a pose plan, capture every sensor, write the datasets.
    Collect(collect::CollectArgs),
    /// Run the simulated MG400 (real protocol on loopback) until Ctrl-C.
    Sim(sim::Args),
    /// Pose plans: show a plan's grid, sampled poses and motion time.
    Plan(plan::Args),
    /// Datasets: verify, export, import, merge.
    Dataset(dataset::Args),
    /// Simulated tactile sensors: render frames for checking their look.
    Sensor(sensor::Args),
    /// Synthesise tactile images with a diffusion model package (ONNX Runtime).
    Synth(synth::Args),
    /// Render one image of an object under a sensor at a pose (depth, control or a sensor).
    Render(render::Args),
    /// The STL object library: regenerate it, or draw a contact sheet.
    Objects(objects::Args),
    /// Calibrate a sensor's pixel-to-mm mapping (automatic presses, wizard, or from a dataset).
    Calibrate(calibrate::Args),
    /// Compare the simulator with the real MultiDiffSense example frames (SSIM, baseline).
    CompareReal(compare::Args),
}

/// Parses the command line, runs the command, maps errors to an exit code.
pub fn main() -> ExitCode {
    let cli = Cli::parse();
    let filter = tracing_subscriber::EnvFilter::try_new(&cli.log)
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn"));
    tracing_subscriber::fmt().with_env_filter(filter).with_writer(std::io::stderr).init();
    let result = match cli.command {
        Command::Info => {
            println!("rig {}", crate::version());
            Ok(())
        }
        Command::Collect(args) => collect::run(args),
        Command::Sim(args) => sim::run(args),
        Command::Plan(args) => plan::run(args),
        Command::Dataset(args) => dataset::run(args),
        Command::Sensor(args) => sensor::run(args),
        Command::Synth(args) => synth::run(args),
        Command::Render(args) => render::run(args),
        Command::Objects(args) => objects::run(args),
        Command::CompareReal(args) => compare::run(args),
        Command::Calibrate(args) => calibrate::run(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // An exit status alone has said what it had to say already.
            if e.downcast_ref::<ExitStatus>().is_none() {
                eprintln!("error: {e:#}");
            }
            ExitCode::from(exit_code(&e))
        }
    }
}

/// Exit codes: 1 general failure, 2 bad input (usage, files, plans), 3 hardware or protocol
/// fault, 4 interrupted.
pub fn exit_code(e: &anyhow::Error) -> u8 {
    if let Some(code) = e.downcast_ref::<ExitStatus>() {
        return code.0;
    }
    if e.downcast_ref::<UsageError>().is_some() {
        return 2;
    }
    for cause in e.chain() {
        if cause.downcast_ref::<crate::arm::ArmError>().is_some() {
            return 3;
        }
        if cause.downcast_ref::<crate::plan::PlanError>().is_some() {
            return 2;
        }
        if let Some(e) = cause.downcast_ref::<crate::dataset::DatasetError>() {
            use crate::dataset::DatasetError as D;
            if matches!(e, D::NotEmpty { .. } | D::NotADataset { .. } | D::ManifestMismatch { .. } | D::MalformedMds { .. }) {
                return 2;
            }
        }
    }
    1
}

/// Bad input on the command line (exit code 2).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct UsageError(pub String);

/// A [`UsageError`] with this message.
pub fn usage(message: &str) -> UsageError {
    UsageError(message.to_string())
}

/// An error that carries its own exit code.
#[derive(Debug, thiserror::Error)]
#[error("exit status {0}")]
pub struct ExitStatus(pub u8);
