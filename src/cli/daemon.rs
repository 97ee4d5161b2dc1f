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
use crate::sensor::SensorSet;

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
    /// A folder jobs may read and write (repeatable); every path a job names must resolve
    /// inside one, symlinks included. Default: the daemon's working folder.
    #[arg(long = "root", value_name = "DIR")]
    pub roots: Vec<PathBuf>,
    /// ONNX Runtime library (or its folder) for synth jobs, fixed for the daemon's life
    /// (default: $RIG_ORT_LIB, $ORT_DYLIB_PATH, then the checkout's .rig/onnxruntime/).
    #[arg(long, value_name = "PATH")]
    pub ort_lib: Option<PathBuf>,
    /// A host name the daemon also answers to in the Host header (repeatable), e.g. the
    /// machine's name on the lab network; loopback names and the listen IP always work.
    #[arg(long = "allow-host", value_name = "NAME")]
    pub allowed_hosts: Vec<String>,
}

/// Runs `rig daemon`.
pub fn run(args: Args) -> anyhow::Result<()> {
    if args.idle_refresh_ms != 0
        && let Err(problem) = crate::bounds::DAEMON_IDLE_REFRESH.check(args.idle_refresh_ms)
    {
        anyhow::bail!(crate::cli::usage(&format!("--idle-refresh-ms {problem} (or 0: off)")));
    }
    let config = RigConfig::discover(args.config.as_deref())?;
    println!("{}", config.describe());
    let roots = crate::roots::DataRoots::from_working_folder(&args.roots)?;
    println!("data roots: {roots}");
    let runtime = tokio::runtime::Runtime::new().context("starting the async runtime")?;
    let result = runtime.block_on(async move {
        let options = DaemonOptions {
            listen: args.listen,
            token: args.token,
            config,
            sensors: args.sensor.parse::<SensorSet>()?,
            object: args.object,
            seed: args.seed,
            idle_refresh: (args.idle_refresh_ms > 0).then(|| Duration::from_millis(args.idle_refresh_ms)),
            roots: Some(roots),
            ort_lib: args.ort_lib,
            allowed_hosts: args.allowed_hosts,
        };
        let token_set = options.token.as_deref().is_some_and(|t| !t.is_empty());
        let daemon = Daemon::start(options).await.map_err(|e| match e {
            e @ crate::daemon::DaemonError::TokenRequired { .. } => anyhow::Error::new(crate::cli::usage(&e.to_string())),
            e => anyhow::Error::new(e),
        })?;
        match daemon.ort_lib() {
            Some(lib) => println!("ONNX Runtime for synth jobs: {}", lib.display()),
            None => println!("ONNX Runtime for synth jobs: none found (synth jobs will fail; pass --ort-lib or run scripts/setup.sh)"),
        }
        println!(
            "rig daemon listening on http://{} (page: http://{}/{}); SIGTERM or Ctrl-C stops it",
            daemon.addr(),
            daemon.addr(),
            if token_set { "#token=<token>" } else { "" }
        );
        wait_for_stop_signal().await?;
        println!("stopping: no new jobs; finishing the current step, then retracting and disabling the arm");
        let state = std::sync::Arc::clone(daemon.state());
        daemon.shutdown().await?;
        if state.status().arm.mode == "disabled" {
            println!("stopped: arm disabled");
            Ok(())
        } else {
            let errors: Vec<String> = state.status().errors.into_iter().map(|e| e.message).collect();
            println!("stopped, but the arm may NOT be disabled: {}", errors.join("; "));
            anyhow::bail!(crate::cli::ExitStatus(3))
        }
    });
    // A job abandoned at shutdown may have left a model thread blocked (in a FIFO read, say):
    // the process exits without joining it.
    runtime.shutdown_timeout(Duration::from_millis(200));
    result
}

/// Waits for SIGTERM or SIGINT.
async fn wait_for_stop_signal() -> anyhow::Result<()> {
    let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()).context("installing the SIGTERM handler")?;
    tokio::select! {
        _ = term.recv() => {}
        r = tokio::signal::ctrl_c() => r.context("waiting for Ctrl-C")?,
    }
    Ok(())
}

pub use super::shared::DaemonTarget;

/// How often a followed job is polled.
const FOLLOW_PERIOD: Duration = Duration::from_millis(500);

/// Submits `spec` to the daemon at `url`, prints the job id, and (unless `detach`) follows its
/// progress to the end; the exit status is the one the standalone command would give. Ctrl-C
/// while following cancels the job on the daemon (it stops at its next safe point).
pub fn submit_and_follow(target: &DaemonTarget, spec: crate::jobs::JobRequest) -> anyhow::Result<()> {
    let url = target.daemon.as_deref().context("--daemon URL is required here")?;
    // Read here, not through clap's `env`: `rig synth` rejects flags beside its subcommands,
    // and an environment value would count as one.
    let token = target.daemon_token.clone().or_else(|| std::env::var("RIG_DAEMON_TOKEN").ok());
    // A URL rig cannot use (https://, another scheme, no host) is the command line's: exit 2.
    let client = crate::daemon::client::DaemonClient::new(url, token).map_err(|e| crate::cli::usage(&e.to_string()))?;
    let runtime = tokio::runtime::Runtime::new().context("starting the async runtime")?;
    runtime.block_on(follow(client, url, spec, target.detach))
}

async fn follow(client: crate::daemon::client::DaemonClient, url: &str, spec: crate::jobs::JobRequest, detach: bool) -> anyhow::Result<()> {
    use crate::daemon::{JobState, JobView};
    let body = serde_json::to_value(&spec).context("encoding the job")?;
    let job: JobView = match client.post_json("/api/jobs", &body).await {
        Ok(job) => job,
        // 400: the daemon refused the job itself (a bound, a path outside its data roots): bad
        // input, exit 2, as the standalone command would give.
        Err(crate::daemon::client::ClientError::Status { status: 400, message }) => {
            return Err(crate::report::usage(&format!("the daemon at {url} refused the job: {message}")).into());
        }
        Err(e) => return Err(anyhow::Error::new(e).context(format!("submitting the job to {url}"))),
    };
    println!("submitted {} job {} to {url}", spec.kind(), job.id);
    if detach {
        println!("follow it with: curl {url}/api/jobs/{}", job.id);
        return Ok(());
    }
    let progress = indicatif::ProgressBar::new(0);
    progress.set_style(
        indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len}  {msg}").unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let path = format!("/api/jobs/{}", job.id);
    let mut interrupt = std::pin::pin!(tokio::signal::ctrl_c());
    let mut cancel_sent = false;
    let last = loop {
        let j: JobView = client.get_json(&path).await.with_context(|| format!("following job {} on {url}", job.id))?;
        progress.set_length(j.progress.total);
        progress.set_position(j.progress.done);
        progress.set_message(match (j.state, j.progress.eta_s) {
            (JobState::Queued, _) => "queued".to_string(),
            (_, Some(eta_s)) => format!("eta {eta_s:.0} s"),
            _ => String::new(),
        });
        if j.state.is_final() {
            break j;
        }
        tokio::select! {
            _ = tokio::time::sleep(FOLLOW_PERIOD) => {}
            r = &mut interrupt, if !cancel_sent => {
                r.context("waiting for Ctrl-C")?;
                cancel_sent = true;
                progress.println("interrupt: asking the daemon to cancel the job (it stops at its next safe point)");
                let r = client.request("POST", &format!("{path}/cancel"), None).await?;
                if r.status != 200 {
                    progress.println(format!("cancel answered {}: {}", r.status, String::from_utf8_lossy(&r.body)));
                }
            }
        }
    };
    progress.finish_and_clear();
    match last.state {
        JobState::Done => {
            println!("{}", last.message.unwrap_or_default());
            Ok(())
        }
        JobState::Cancelled => {
            println!("{}", last.message.unwrap_or_else(|| "cancelled".into()));
            anyhow::bail!(crate::cli::ExitStatus(4))
        }
        _ => {
            eprintln!("error: job {} failed on the daemon: {}", last.id, last.error.unwrap_or_default());
            anyhow::bail!(crate::cli::ExitStatus(last.exit_code.unwrap_or(1)))
        }
    }
}
