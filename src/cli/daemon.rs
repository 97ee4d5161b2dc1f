//! `rig daemon`: keep the rig open, run queued jobs, serve the status API and the live page
//! until SIGTERM or Ctrl-C (then: no new jobs, the running one stopped at a safe point, the
//! arm retracted and disabled, exit 0). Behaviour lives in [`crate::daemon`].

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use anyhow::Context;
use clap::Args as ClapArgs;

use crate::config::RigConfig;
use crate::daemon::{Daemon, DaemonOptions};
use crate::rigs::SensorChoice;

/// Arguments of `rig daemon`.
#[derive(Debug, ClapArgs)]
pub struct Args {
    /// Address of the HTTP API and page. Anything but loopback needs --token.
    #[arg(long, default_value = "127.0.0.1:7700")]
    pub listen: SocketAddr,
    /// Bearer token every API call must carry (required when --listen is not loopback).
    #[arg(long, env = "RIG_DAEMON_TOKEN", hide_env_values = true)]
    pub token: Option<String>,
    /// Rig configuration file (default: $RIG_CONFIG, then ./rig.toml, else the simulated rig).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Sensors to open and keep streaming: tactip, vitac, vitactip or all.
    #[arg(long, default_value = "all")]
    pub sensor: String,
    /// Object the simulated sensors show until a job names one.
    #[arg(long, default_value = "sphere")]
    pub object: String,
    /// Seed of the simulated sensors' noise (fixed for the daemon's life).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Between jobs, refresh every sensor's frame and the arm pose this often, ms (0: never).
    #[arg(long, default_value_t = 1000)]
    pub idle_refresh_ms: u64,
}

/// Runs `rig daemon`.
pub fn run(args: Args) -> anyhow::Result<()> {
    let config = RigConfig::discover(args.config.as_deref())?;
    println!("{}", config.describe());
    let runtime = tokio::runtime::Runtime::new().context("starting the async runtime")?;
    runtime.block_on(async move {
        let options = DaemonOptions {
            listen: args.listen,
            token: args.token,
            config,
            sensors: SensorChoice::parse(&args.sensor)?,
            object: args.object,
            seed: args.seed,
            idle_refresh: (args.idle_refresh_ms > 0).then(|| Duration::from_millis(args.idle_refresh_ms)),
        };
        let token_set = options.token.as_deref().is_some_and(|t| !t.is_empty());
        let daemon = Daemon::start(options).await.map_err(|e| match e {
            e @ crate::daemon::DaemonError::TokenRequired { .. } => anyhow::Error::new(crate::cli::usage(&e.to_string())),
            e => anyhow::Error::new(e),
        })?;
        println!(
            "rig daemon listening on http://{} (page: http://{}/{}); SIGTERM or Ctrl-C stops it",
            daemon.addr(),
            daemon.addr(),
            if token_set { "#token=<token>" } else { "" }
        );
        wait_for_stop_signal().await?;
        println!("stopping: no new jobs; finishing the current step, then retracting and disabling the arm");
        daemon.shutdown().await?;
        println!("stopped: arm disabled");
        Ok(())
    })
}

/// Waits for SIGTERM or SIGINT.
async fn wait_for_stop_signal() -> anyhow::Result<()> {
    let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())
        .context("installing the SIGTERM handler")?;
    tokio::select! {
        _ = term.recv() => {}
        r = tokio::signal::ctrl_c() => r.context("waiting for Ctrl-C")?,
    }
    Ok(())
}
