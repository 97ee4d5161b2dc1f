//! Command-line parsing and wiring. Each subcommand lives in its own file with a clap `Args`
//! struct and a `run` function; behaviour lives in the library modules, not here.

use std::process::ExitCode;

use clap::{CommandFactory, Parser, Subcommand};

pub mod arm;
pub mod audit;
pub mod bench;
pub mod calibrate;
pub mod collect;
pub mod compare;
pub mod daemon;
pub mod dataset;
pub mod devices;
pub mod eval;
pub mod examples;
pub mod fill;
pub mod generate;
pub mod info;
pub mod objects;
pub mod plan;
pub mod render;
pub mod replay;
pub mod sensor;
pub mod sensor_bridge;
pub mod shared;
pub mod sim;
pub mod synth;

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
    /// Print the version and what the rig configuration names (arm, work frame, cameras, press
    /// limits, Modbus peripherals).
    #[command(after_help = examples::INFO)]
    Info(info::Args),
    /// Drive the arm through a pose plan, capture every sensor, write the datasets.
    #[command(after_help = examples::COLLECT)]
    Collect(collect::CollectArgs),
    /// Keep the rig open and run queued jobs; HTTP status API and live page (until SIGTERM).
    #[command(after_help = examples::DAEMON)]
    Daemon(daemon::Args),
    /// Run the simulated MG400 (real protocol on loopback) until Ctrl-C.
    #[command(after_help = examples::SIM)]
    Sim(sim::Args),
    /// The MG400 by hand: send one dashboard command and print its reply (no motion).
    #[command(after_help = examples::ARM)]
    Arm(arm::Args),
    /// Pose plans: show a plan's grid, sampled poses and motion time.
    #[command(after_help = examples::PLAN)]
    Plan(plan::Args),
    /// Datasets: verify, export, import, merge.
    #[command(after_help = examples::DATASET)]
    Dataset(dataset::Args),
    /// Simulated tactile sensors: render frames for checking their look.
    #[command(after_help = examples::SENSOR)]
    Sensor(sensor::Args),
    /// Synthesise tactile images with a diffusion model package (ONNX Runtime).
    #[command(after_help = examples::SYNTH)]
    Synth(synth::Args),
    /// Render one image of an object under a sensor at a pose (depth, control or a sensor).
    #[command(after_help = examples::RENDER)]
    Render(render::Args),
    /// The STL object library: regenerate it, or draw a contact sheet.
    #[command(after_help = examples::OBJECTS)]
    Objects(objects::Args),
    /// Calibrate a sensor's pixel-to-mm mapping (automatic presses, wizard, or from a dataset).
    #[command(after_help = examples::CALIBRATE)]
    Calibrate(calibrate::Args),
    /// Compare the simulator with the real MultiDiffSense example frames (SSIM, baseline).
    #[command(after_help = examples::COMPARE_REAL)]
    CompareReal(compare::Args),
    /// Judge synthetic images against real ones (SSIM, PSNR, MSE, pose recoverability) beside
    /// pose-blind and nearest-neighbour baselines; or, with --downstream, train pose regressors
    /// on real, mixed and synthetic rows and score them on held-out real rows.
    #[command(after_help = examples::EVAL)]
    Eval(eval::Args),
    /// Collect a seeded share of a dataset's synthesised poses again and judge the synthesised
    /// images against the captured ones (SSIM, PSNR, pose recoverability, intervals).
    #[command(after_help = examples::AUDIT)]
    Audit(audit::Args),
    /// Re-run a recorded collection (`rig collect --record`) without hardware.
    #[command(after_help = examples::REPLAY)]
    Replay(replay::Args),
    /// List cameras (formats, USB identities), serial ports and USB devices on this machine, and
    /// which devices the rig configuration names were found.
    #[command(after_help = examples::DEVICES)]
    Devices(devices::Args),
    /// Measure what accuracy costs in time, knob by knob; write a Markdown report with SVG plots.
    #[command(after_help = examples::BENCH)]
    Bench(bench::Args),
    /// Write the man pages or shell completions (made from these command-line definitions).
    #[command(after_help = examples::GENERATE)]
    Generate(generate::Args),
}

/// Parses the command line, runs the command, maps errors to an exit code.
pub fn main() -> ExitCode {
    let cli = Cli::parse();
    end_quietly_when_stdout_closes();
    let filter = tracing_subscriber::EnvFilter::try_new(&cli.log).unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn"));
    tracing_subscriber::fmt().with_env_filter(filter).with_writer(std::io::stderr).init();
    let result = match cli.command {
        Command::Info(args) => info::run(args),
        Command::Collect(args) => collect::run(args),
        Command::Daemon(args) => daemon::run(args),
        Command::Sim(args) => sim::run(args),
        Command::Arm(args) => arm::run(args),
        Command::Plan(args) => plan::run(args),
        Command::Dataset(args) => dataset::run(args),
        Command::Sensor(args) => sensor::run(args),
        Command::Synth(args) => synth::run(args),
        Command::Render(args) => render::run(args),
        Command::Objects(args) => objects::run(args),
        Command::CompareReal(args) => compare::run(args),
        Command::Eval(args) => eval::run(args),
        Command::Audit(args) => audit::run(args),
        Command::Replay(args) => replay::run(args),
        Command::Devices(args) => devices::run(args),
        Command::Calibrate(args) => calibrate::run(args),
        Command::Bench(args) => bench::run(args),
        Command::Generate(args) => generate::run(args, Cli::command()),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // An exit status alone has said what it had to say already.
            if e.downcast_ref::<ExitStatus>().is_none() {
                eprintln!("error: {}", error_report(&e));
            }
            ExitCode::from(exit_code(&e))
        }
    }
}

/// `rig plan show | head`: once the reader has gone, end as Unix tools do (killed by SIGPIPE)
/// rather than panic in `println!`. Rust ignores SIGPIPE by default; its sockets send with
/// MSG_NOSIGNAL, so a dropped TCP peer still comes back as an error, not as this signal.
fn end_quietly_when_stdout_closes() {
    #[cfg(unix)]
    // SAFETY: called once at start-up, before any other thread exists; resets one signal's
    // disposition to the default.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

pub use crate::report::{ExitStatus, UsageError, error_report, exit_code, usage};
