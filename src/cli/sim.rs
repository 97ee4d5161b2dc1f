//! `rig sim`: run the simulated MG400 standalone until Ctrl-C.
//!
//! Listens on the real ports (29999 dashboard, 30003 motion, 30004 feedback) by default, so
//! Dobot's own SDKs and netcat can drive it; `--port-base N` moves them to N, N+3, N+4.

use std::net::IpAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use anyhow::Context;

use crate::arm::profile::FirmwareProfile;
use crate::clock::{Clock, MonotonicClock};
use crate::pose::Pose;
use crate::sim::mg400::{SimFaults, SimMg400, SimMg400Config};

/// Options of `rig sim`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Address to listen on.
    #[arg(long, default_value = "127.0.0.1")]
    pub bind: IpAddr,
    /// Port base: dashboard on N, motion on N+3, feedback on N+4. Without it (and without the
    /// per-port flags) the profile's ports are used (29999, 30003, 30004). 0 = any free ports.
    #[arg(long)]
    pub port_base: Option<u16>,
    /// Dashboard port (overrides --port-base).
    #[arg(long)]
    pub dashboard_port: Option<u16>,
    /// Motion port (overrides --port-base).
    #[arg(long)]
    pub motion_port: Option<u16>,
    /// Feedback port (overrides --port-base).
    #[arg(long)]
    pub feedback_port: Option<u16>,
    /// Simulated seconds per real second (10 = ten times faster than real time).
    #[arg(long, default_value_t = 1.0)]
    pub time_scale: f64,
    /// Firmware profile TOML (default: the embedded mg400-v1.6).
    #[arg(long)]
    pub profile: Option<PathBuf>,
    /// Start pose x,y,z,yaw (mm, mm, mm, deg).
    #[arg(long, default_value = "300,0,0,0", allow_hyphen_values = true)]
    pub start_pose: Pose,
    /// Fault: delay every reply by this many milliseconds.
    #[arg(long, default_value_t = 0)]
    pub reply_delay_ms: u64,
    /// Fault: send each reply in two writes.
    #[arg(long)]
    pub split_replies: bool,
    /// Fault: put garbage bytes before every N-th feedback frame.
    #[arg(long)]
    pub feedback_garbage_every: Option<u32>,
    /// Fault: start each feedback connection in the middle of a frame.
    #[arg(long)]
    pub feedback_start_mid_frame: bool,
    /// Fault: the K-th move executed ends halfway in a collision alarm (112).
    #[arg(long)]
    pub collision_at_move: Option<u64>,
    /// Fault: close each dashboard connection, unanswered, at its (N+1)-th command.
    #[arg(long)]
    pub drop_dashboard_after: Option<u64>,
}

/// Runs the simulator until Ctrl-C.
pub fn run(args: Args) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.time_scale.is_finite() && args.time_scale > 0.0,
        "--time-scale must be a positive number, got {}",
        args.time_scale
    );
    let cfg = sim_config(&args)?;
    let runtime = tokio::runtime::Builder::new_multi_thread().enable_all().build()?;
    runtime.block_on(async move {
        let clock: Arc<dyn Clock> = Arc::new(MonotonicClock::scaled(args.time_scale));
        let ports = (cfg.dashboard_port, cfg.motion_port, cfg.feedback_port);
        let profile_name = cfg.profile.name.clone();
        let sim = SimMg400::start(cfg, clock).await.with_context(|| {
            format!("starting the simulated MG400 on {} ports {}/{}/{} (dashboard/motion/feedback)", args.bind, ports.0, ports.1, ports.2)
        })?;
        println!("simulated MG400 (profile {}, time x{}), disabled until EnableRobot()", profile_name, args.time_scale);
        println!("  dashboard {}", sim.dashboard_addr());
        println!("  motion    {}", sim.motion_addr());
        println!("  feedback  {}", sim.feedback_addr());
        println!(
            "try: rig arm send --addr {} --port {} 'RobotMode()'    (Ctrl-C stops the simulator)",
            sim.dashboard_addr().ip(),
            sim.dashboard_addr().port()
        );
        tokio::signal::ctrl_c().await.context("waiting for Ctrl-C")?;
        let stats = sim.stats();
        println!(
            "stopping: {} moves executed, {} motion commands, deepest queue {}",
            stats.moves_started, stats.motion_commands, stats.max_queue_depth
        );
        sim.shutdown().await;
        Ok(())
    })
}

/// Resolves the options into the simulator's configuration.
pub fn sim_config(args: &Args) -> anyhow::Result<SimMg400Config> {
    let profile = match &args.profile {
        Some(path) => FirmwareProfile::load(path)?,
        None => FirmwareProfile::default_mg400(),
    };
    let mut cfg = SimMg400Config {
        bind: args.bind,
        dashboard_port: profile.transport.dashboard_port,
        motion_port: profile.transport.motion_port,
        feedback_port: profile.transport.feedback_port,
        start_pose: args.start_pose,
        faults: SimFaults {
            reply_delay: Duration::from_millis(args.reply_delay_ms),
            split_replies: args.split_replies,
            feedback_garbage_every: args.feedback_garbage_every,
            feedback_start_mid_frame: args.feedback_start_mid_frame,
            collision_at_move: args.collision_at_move,
            collision_at_moves: Vec::new(),
            drop_dashboard_after: args.drop_dashboard_after,
        },
        profile,
        ..Default::default()
    };
    if let Some(base) = args.port_base {
        cfg = cfg.with_port_base(base)?;
    }
    cfg.dashboard_port = args.dashboard_port.unwrap_or(cfg.dashboard_port);
    cfg.motion_port = args.motion_port.unwrap_or(cfg.motion_port);
    cfg.feedback_port = args.feedback_port.unwrap_or(cfg.feedback_port);
    Ok(cfg)
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    fn parse(argv: &[&str]) -> Args {
        match crate::cli::Cli::try_parse_from(argv).map(|c| c.command) {
            Ok(crate::cli::Command::Sim(args)) => args,
            other => panic!("expected sim args, got {other:?}"),
        }
    }

    #[test]
    fn ports_from_base_flags_and_defaults() {
        let cfg = sim_config(&parse(&["rig", "sim"])).unwrap();
        assert_eq!((cfg.dashboard_port, cfg.motion_port, cfg.feedback_port), (29999, 30003, 30004));
        let cfg = sim_config(&parse(&["rig", "sim", "--port-base", "41000"])).unwrap();
        assert_eq!((cfg.dashboard_port, cfg.motion_port, cfg.feedback_port), (41000, 41003, 41004));
        let cfg = sim_config(&parse(&["rig", "sim", "--port-base", "41000", "--feedback-port", "0"])).unwrap();
        assert_eq!((cfg.dashboard_port, cfg.motion_port, cfg.feedback_port), (41000, 41003, 0));
        assert!(sim_config(&parse(&["rig", "sim", "--port-base", "65534"])).is_err());
    }

    #[test]
    fn faults_and_start_pose() {
        let args =
            parse(&["rig", "sim", "--collision-at-move", "3", "--split-replies", "--reply-delay-ms", "5", "--start-pose", "310,-20,-5,10"]);
        let cfg = sim_config(&args).unwrap();
        assert_eq!(cfg.faults.collision_at_move, Some(3));
        assert!(cfg.faults.split_replies);
        assert_eq!(cfg.faults.reply_delay, Duration::from_millis(5));
        assert_eq!(cfg.start_pose, Pose::new(310.0, -20.0, -5.0, 10.0));
        assert!(parse(&["rig", "sim", "--time-scale", "10"]).time_scale == 10.0);
    }
}
