//! `rig arm send`: sends one dashboard command to an MG400 and prints the reply
//! ([`crate::arm::dobot::send`]).

use anyhow::Context;
use clap::{Args as ClapArgs, Subcommand};

use crate::arm::dobot::client::{Mg400Config, dashboard_once};
use crate::arm::dobot::proto::ErrorId;
use crate::arm::dobot::send::parse_dashboard_command;
use crate::arm::profile::FirmwareProfile;

/// Arguments of `rig arm`.
#[derive(Debug, ClapArgs)]
pub struct Args {
    #[command(subcommand)]
    pub command: ArmCommand,
}

#[derive(Debug, Subcommand)]
pub enum ArmCommand {
    /// Send one dashboard command (port 29999) and print the controller's reply, e.g.
    /// `RobotMode()`, `GetPose()`, `GetErrorID()`, `ClearError()`. Motion commands are refused.
    #[command(after_help = super::examples::ARM)]
    Send(SendArgs),
}

/// Arguments of `rig arm send`.
#[derive(Debug, ClapArgs)]
pub struct SendArgs {
    /// The controller's address (LAN1 defaults to 192.168.1.6).
    #[arg(long, value_name = "HOST")]
    pub addr: String,
    /// The dashboard port (the simulator's is printed by `rig sim`).
    #[arg(long, default_value_t = 29999)]
    pub port: u16,
    /// The command as the controller takes it, e.g. "RobotMode()".
    pub command: String,
}

/// Checks the command (bad input, exit 2, before connecting), sends it once, prints the reply
/// as it came (`ErrorID,{values},Command();`). A reply with a non-zero ErrorID is printed, then
/// exits 3 with its meaning, as any refused command does.
pub fn run(args: Args) -> anyhow::Result<()> {
    let ArmCommand::Send(args) = args.command;
    let request = parse_dashboard_command(&args.command).map_err(|e| anyhow::Error::new(crate::cli::usage(&e.to_string())))?;
    let cfg = Mg400Config::new(args.addr.clone(), FirmwareProfile::default_mg400()).with_ports(args.port, 30003, 30004);
    let runtime = tokio::runtime::Runtime::new().context("starting the async runtime")?;
    let reply = runtime
        .block_on(dashboard_once(&cfg, &request))
        .with_context(|| format!("sending {} to the MG400 dashboard at {}:{}", request.encode(), args.addr, args.port))?;
    println!("{}", reply.encode());
    if reply.error_id != ErrorId::Accepted {
        return Err(crate::arm::ArmError::Refused {
            command: request.encode(),
            error_id: reply.error_id.code(),
            meaning: reply.error_id.meaning(),
        }
        .into());
    }
    Ok(())
}
