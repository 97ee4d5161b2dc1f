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
//! the HTTP server.
//!
//! Listening anywhere but loopback needs a token ([`DaemonError::TokenRequired`]); with a
//! token every API call must carry `Authorization: Bearer <token>`.

pub mod api;
pub mod client;
pub mod jobs;
pub mod live;
pub mod state;
mod worker;

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use tokio::sync::watch;

pub use state::{DaemonState, JobState, JobView, StatusView};

use crate::config::RigConfig;
use crate::geometry::objects::ObjectChoice;
use crate::rigs::{Rig, RigError};
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
}

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
        }
    }
}

/// A running daemon.
pub struct Daemon {
    addr: SocketAddr,
    state: Arc<DaemonState>,
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

        let worker = tokio::spawn(worker::run_worker(Arc::clone(&state), rig, config, clock, options.idle_refresh));
        let (stop_server, mut stop_rx) = watch::channel(false);
        let router = api::router(api::ApiState { state: Arc::clone(&state), token: token.map(Arc::from) });
        let server = tokio::spawn(async move {
            axum::serve(listener, router)
                .with_graceful_shutdown(async move {
                    let _ = stop_rx.wait_for(|stop| *stop).await;
                })
                .await
        });
        Ok(Daemon { addr, state, stop_server, server, worker })
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
        self.state.begin_shutdown();
        let worker = self.worker.await;
        let _ = self.stop_server.send(true);
        let server = self.server.await;
        worker.map_err(|e| DaemonError::Task { task: "worker", reason: e.to_string() })?;
        server.map_err(|e| DaemonError::Task { task: "server", reason: e.to_string() })?.map_err(DaemonError::Serve)
    }
}
