//! Command-line parsing and wiring. Each subcommand lives in its own file with a clap `Args`
//! struct and a `run` function; behaviour lives in the library modules, not here.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

pub mod bench;
pub mod calibrate;
pub mod collect;
pub mod daemon;
pub mod fill;
pub mod sim;
pub mod dataset;
pub mod devices;
pub mod eval;
pub mod plan;
pub mod replay;
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
    /// Keep the rig open and run queued jobs; HTTP status API and live page (until SIGTERM).
    Daemon(daemon::Args),
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
    /// Judge synthetic images against real ones (SSIM, PSNR, MSE, pose recoverability) beside
    /// pose-blind and nearest-neighbour baselines.
    Eval(eval::Args),
    /// Re-run a recorded collection (`rig collect --record`) without hardware.
    Replay(replay::Args),
    /// List cameras (formats, USB identities), serial ports and USB devices on this machine.
    Devices(devices::Args),
    /// Measure what accuracy costs in time, knob by knob; write a Markdown report with SVG plots.
    Bench(bench::Args),
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
            crate::config::RigConfig::discover(None).map(|c| println!("{}", c.describe())).map_err(anyhow::Error::from)
        }
        Command::Collect(args) => collect::run(args),
        Command::Daemon(args) => daemon::run(args),
        Command::Sim(args) => sim::run(args),
        Command::Plan(args) => plan::run(args),
        Command::Dataset(args) => dataset::run(args),
        Command::Sensor(args) => sensor::run(args),
        Command::Synth(args) => synth::run(args),
        Command::Render(args) => render::run(args),
        Command::Objects(args) => objects::run(args),
        Command::CompareReal(args) => compare::run(args),
        Command::Eval(args) => eval::run(args),
        Command::Replay(args) => replay::run(args),
        Command::Devices(args) => devices::run(args),
        Command::Calibrate(args) => calibrate::run(args),
        Command::Bench(args) => bench::run(args),
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

/// Exit codes: 1 general failure (including a full disk), 2 bad input (usage, config, plan,
/// object, calibration, profile, model package and dataset files; a plan outside the
/// workspace), 3 hardware or protocol fault (arm alarms and lost connections once retries are
/// spent, camera failures), 4 interrupted. the README's "Bad input" table lists each bad input.
pub fn exit_code(e: &anyhow::Error) -> u8 {
    if let Some(code) = e.downcast_ref::<ExitStatus>() {
        return code.0;
    }
    if e.downcast_ref::<UsageError>().is_some()
        || matches!(e.downcast_ref::<crate::collect::CollectError>(), Some(crate::collect::CollectError::Unreachable { .. }))
    {
        return 2;
    }
    for cause in e.chain() {
        if cause.downcast_ref::<crate::arm::ArmError>().is_some()
            || cause.downcast_ref::<crate::camera::CameraError>().is_some()
        {
            return 3;
        }
        if let Some(e) = cause.downcast_ref::<crate::collect::CollectError>() {
            use crate::collect::CollectError as C;
            match e {
                C::RetriesExhausted { .. }
                | C::CameraRetriesExhausted { .. }
                | C::PeripheralRetriesExhausted { .. }
                | C::Arm(_)
                | C::Camera(_) => return 3,
                C::Peripheral(e) if e.is_recoverable() => return 3,
                C::Peripheral(_) => return 2,
                C::Unreachable { .. } | C::Mismatch { .. } => return 2,
                C::Dataset(_) => {}
            }
        }
        if cause.downcast_ref::<crate::config::ConfigError>().is_some() {
            return 2;
        }
        if let Some(e) = cause.downcast_ref::<crate::synth::SynthError>() {
            use crate::synth::SynthError as S;
            if matches!(e, S::MissingFiles { .. } | S::ModelToml { .. } | S::BadModelConfig { .. } | S::BadRequest { .. }) {
                return 2;
            }
        }
        if let Some(e) = cause.downcast_ref::<crate::rigs::RigError>() {
            use crate::rigs::RigError as R;
            if matches!(e, R::UnknownSensor { .. } | R::Object { .. } | R::Profile { .. } | R::Calibration { .. }) {
                return 2;
            }
            if let R::Modbus(m) = e {
                return if m.is_recoverable() { 3 } else { 2 };
            }
        }
        if cause.downcast_ref::<crate::plan::PlanError>().is_some() {
            return 2;
        }
        if let Some(e) = cause.downcast_ref::<crate::dataset::DatasetError>() {
            use crate::dataset::DatasetError as D;
            if matches!(
                e,
                D::NotEmpty { .. }
                    | D::NotADataset { .. }
                    | D::ManifestMismatch { .. }
                    | D::MalformedMds { .. }
                    | D::BadHeader { .. }
                    | D::ManifestParse { .. }
            ) {
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
