//! Command-line parsing and wiring. Each subcommand lives in its own file with a clap `Args`
//! struct and a `run` function; behaviour lives in the library modules, not here.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

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
    /// Render one image of an object under a sensor at a pose (depth, control or a sensor).
    Render(render::Args),
    /// The STL object library: regenerate it, or draw a contact sheet.
    Objects(objects::Args),
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
        Command::Render(args) => render::run(args),
        Command::Objects(args) => objects::run(args),
        Command::CompareReal(args) => compare::run(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
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
    for cause in e.chain() {
        if cause.downcast_ref::<crate::arm::ArmError>().is_some() {
            return 3;
        }
    }
    1
}

/// An error that carries its own exit code.
#[derive(Debug, thiserror::Error)]
#[error("exit status {0}")]
pub struct ExitStatus(pub u8);
