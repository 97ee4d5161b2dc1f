//! `rig daemon`: a long-running rig with a job queue, an HTTP status API and a live page.
//!
//! ```text
//!   HTTP (axum)  ──►  DaemonState (jobs, arm, latest frames, synth pair, errors)  ◄──  worker
//!   api::router        state.rs                                                   worker.rs
//!                                                                                   │ owns
//!                                                                                   ▼
//!                                                  Rig (arm connection + camera streams, open
//!                                                  for the daemon's life) ── jobs.rs runners
//! ```
//!
//! [`Daemon::start`] opens the rig once (the configured one, or the built-in simulated rig),
//! binds the listener and spawns the worker, which runs queued [`JobRequest`](crate::jobs::JobRequest)s one at a time
//! through the same library jobs the standalone commands use. A job's failure is recorded
//! with its error and exit code and the queue goes on. [`Daemon::shutdown`] (SIGTERM/SIGINT
//! in `rig daemon`) stops accepting jobs, cancels the queued ones, asks the running one to
//! stop at its next safe point, retracts and disables the arm, closes the rig, then stops
//! the HTTP server, all within [`SHUTDOWN_DEADLINE`]: a job that does not reach its safe point
//! in time is abandoned (the worker's stop grace), and the retract and the disable are bounded.
//!
//! Listening anywhere but loopback needs a token ([`DaemonError::TokenRequired`]); with a
//! token every API call must carry `Authorization: Bearer <token>`. The `Host`, CSRF, body and
//! timeout rules are in [`api`] and [`serve`]; the security chapter of the docs
//! (`docs/src/security.md`) says what they protect.
//!
//! Trust fixed at start, never taken from a request: the data roots ([`DataRoots`], from
//! `--root`; every path a job names must resolve inside one) and the ONNX Runtime library
//! (`--ort-lib`, else the search of [`crate::synth::runtime`]). The worker hands both to the
//! jobs in a [`WorkerContext`]. A job that fails or panics fails alone: the worker records it
//! with its exit code and runs the next one.

pub mod api;
pub mod client;
pub mod jobs;
pub mod live;
pub mod serve;
pub mod state;
mod worker;

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use tokio::sync::watch;

pub use state::{DaemonState, JobState, JobView, StatusView};
pub use worker::WorkerContext;

use crate::config::RigConfig;
use crate::geometry::objects::ObjectChoice;
use crate::rigs::{Rig, RigError};
use crate::roots::{DataRoots, RootsError};
use crate::sensor::SensorSet;

/// Errors starting or stopping the daemon.
#[derive(Debug, thiserror::Error)]
pub enum DaemonError {
    #[error("listening on {addr}, which is not loopback, needs a token (--token or RIG_DAEMON_TOKEN)")]
    TokenRequired { addr: SocketAddr },
    #[error("binding {addr}: {source}")]
    Bind {
        addr: SocketAddr,
        #[source]
        source: std::io::Error,
    },
    #[error("opening the rig: {0}")]
    Rig(#[from] RigError),
    #[error("serving HTTP: {0}")]
    Serve(#[source] std::io::Error),
    #[error("the {task} task ended abnormally: {reason}")]
    Task { task: &'static str, reason: String },
    #[error("data roots: {0}")]
    Roots(#[source] RootsError),
    #[error("ONNX Runtime for synth jobs: {0}")]
    OrtLib(#[source] crate::synth::SynthError),
}

/// Longest [`Daemon::shutdown`] waits for the worker to stop the job and make the arm safe.
pub const SHUTDOWN_DEADLINE: Duration = Duration::from_secs(5);

/// How to run a daemon.
#[derive(Debug, Clone)]
pub struct DaemonOptions {
    /// Port 0 picks a free port ([`Daemon::addr`] tells which).
    pub listen: SocketAddr,
    /// Required when `listen` is not loopback; empty counts as none.
    pub token: Option<String>,
    pub config: RigConfig,
    /// The sensors to open (jobs may use any subset).
    pub sensors: SensorSet,
    /// The object the simulated sensors show until a job names one.
    pub object: String,
    /// Seed of the simulated sensors' noise, fixed for the daemon's life.
    pub seed: u64,
    /// How often to refresh the frames and the arm pose between jobs; `None`: never.
    pub idle_refresh: Option<Duration>,
    /// The folders jobs may read and write (`--root`); `None`: the working folder.
    pub roots: Option<DataRoots>,
    /// The ONNX Runtime library (or its folder) synth jobs use (`--ort-lib`); `None`: the
    /// search of [`crate::synth::runtime`], done once at start.
    pub ort_lib: Option<PathBuf>,
    /// Host names, besides loopback ones and the listen IP, the daemon answers to
    /// (`--allow-host`).
    pub allowed_hosts: Vec<String>,
}

impl DaemonOptions {
    /// Loopback, an OS-chosen port, no token, all three sensors, frames refreshed every second
    /// between jobs.
    pub fn local(config: RigConfig) -> Self {
        Self {
            listen: SocketAddr::from(([127, 0, 0, 1], 0)),
            token: None,
            config,
            sensors: SensorSet::all(),
            object: "sphere".into(),
            seed: 0,
            idle_refresh: Some(Duration::from_secs(1)),
            roots: None,
            ort_lib: None,
            allowed_hosts: Vec::new(),
        }
    }
}

/// A running daemon.
pub struct Daemon {
    addr: SocketAddr,
    state: Arc<DaemonState>,
    context: WorkerContext,
    stop_server: watch::Sender<bool>,
    server: tokio::task::JoinHandle<std::io::Result<()>>,
    worker: tokio::task::JoinHandle<()>,
}

impl Daemon {
    /// Checks the token rule, opens the rig, binds, and starts serving and working.
    pub async fn start(options: DaemonOptions) -> Result<Daemon, DaemonError> {
        let token = options.token.clone().filter(|t| !t.is_empty());
        if token.is_none() && !options.listen.ip().is_loopback() {
            return Err(DaemonError::TokenRequired { addr: options.listen });
        }
        let roots = match options.roots.clone() {
            Some(roots) => roots,
            None => DataRoots::from_working_folder(&[]).map_err(DaemonError::Roots)?,
        };
        // Resolved once: a library named at start must exist; one found by the search is kept,
        // so no later change of the environment or the working folder changes what jobs load.
        let ort_lib = match crate::synth::runtime::locate_ort_library(options.ort_lib.as_deref()) {
            Ok((path, origin)) => {
                tracing::info!(library = %path.display(), origin, "ONNX Runtime for synth jobs");
                Some(path)
            }
            Err(e) if options.ort_lib.is_some() => return Err(DaemonError::OrtLib(e)),
            Err(e) => {
                tracing::warn!(error = %e, "no ONNX Runtime library: synth jobs will fail");
                None
            }
        };
        let context = WorkerContext { roots, ort_lib };
        let listener =
            tokio::net::TcpListener::bind(options.listen).await.map_err(|source| DaemonError::Bind { addr: options.listen, source })?;
        let addr = listener.local_addr().map_err(|source| DaemonError::Bind { addr: options.listen, source })?;

        let config = options.config;
        let object = ObjectChoice::resolve(&options.object, None).map_err(RigError::from)?;
        let clock = crate::rigs::clock_for(&config);
        let rig = Rig::open(&config, &object, &options.sensors, options.seed, Arc::clone(&clock)).await?;
        let describe = format!(
            "{}; sensors {}",
            config.describe().lines().next().unwrap_or_default(),
            rig.cameras.iter().map(|c| c.sensor_dir()).collect::<Vec<_>>().join(",")
        );
        let state = Arc::new(DaemonState::new(describe));

        let worker = tokio::spawn(worker::run_worker(Arc::clone(&state), rig, config, clock, options.idle_refresh, context.clone()));
        let (stop_server, stop_rx) = watch::channel(false);
        let hosts = Arc::new(api::HostRule::new(addr, &options.allowed_hosts));
        let roots = Arc::new(context.roots.clone());
        let router = api::router(api::ApiState { state: Arc::clone(&state), token: token.map(Arc::from), hosts, roots });
        let server = tokio::spawn(serve::serve(listener, router, stop_rx));
        Ok(Daemon { addr, state, context, stop_server, server, worker })
    }

    /// The data roots jobs are confined to.
    pub fn roots(&self) -> &DataRoots {
        &self.context.roots
    }

    /// The ONNX Runtime library synth jobs load (`None`: none was found at start).
    pub fn ort_lib(&self) -> Option<&std::path::Path> {
        self.context.ort_lib.as_deref()
    }

    /// Where it listens.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// Its state (what the API serves).
    pub fn state(&self) -> &Arc<DaemonState> {
        &self.state
    }

    /// Stops cleanly: no new jobs, queued ones cancelled, the running one stopped at a safe
    /// point, the arm retracted and disabled, the rig closed, then the HTTP server stopped.
    pub async fn shutdown(self) -> Result<(), DaemonError> {
        for line in self.state.begin_shutdown() {
            tracing::warn!("{line}");
        }
        // The worker bounds each stage itself (the job's grace, the retract, the disable);
        // this is the net under those bounds.
        let worker = match tokio::time::timeout(SHUTDOWN_DEADLINE, self.worker).await {
            Ok(joined) => joined.map_err(|e| DaemonError::Task { task: "worker", reason: e.to_string() }),
            Err(_) => Err(DaemonError::Task { task: "worker", reason: format!("it did not stop within {SHUTDOWN_DEADLINE:?}") }),
        };
        let _ = self.stop_server.send(true);
        let server = self.server.await;
        worker?;
        server.map_err(|e| DaemonError::Task { task: "server", reason: e.to_string() })?.map_err(DaemonError::Serve)
    }
}
