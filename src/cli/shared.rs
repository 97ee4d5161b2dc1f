//! Argument groups and helpers several subcommands share. It uses no other `cli` module, so
//! the subcommands can share it without importing each other or the dispatcher.

use std::path::PathBuf;

use anyhow::bail;
use clap::Args as ClapArgs;

use crate::config::RigConfig;
use crate::synth::runtime::{ArenaExtend, ConvSearch, CudaOptions};
use crate::synth::{ExecutionProviderKind, ImageRange, RuntimeOptions, SchedulerKind};

/// Sampling settings, the same flags in every synth mode. Each one left out takes the model
/// package's own (`model.toml`), else rig's fallback: 20 steps unguided for a fill, 50 steps
/// at guidance 9 (MultiDiffSense's paper) for `synth one`.
#[derive(Debug, Clone, ClapArgs)]
pub struct SamplingArgs {
    /// Sampling steps [default: the package's `sampling_steps`, else 20 (fill) or 50 (one)].
    #[arg(long)]
    pub steps: Option<usize>,
    /// Classifier-free guidance scale (1: unguided, half the work, as MultiDiffSense's scripts
    /// save) [default: the package's `guidance`, else 1 (fill) or 9 (one)].
    #[arg(long)]
    pub guidance: Option<f32>,
    /// DDIM eta (0: deterministic) [default: the package's `eta`, else 0].
    #[arg(long)]
    pub eta: Option<f32>,
    /// Sampler: ddim or dpm++2m [default: the package's `sampler`, else ddim].
    #[arg(long, alias = "scheduler")]
    pub sampler: Option<SchedulerKind>,
    /// ControlNet conditioning scale: how strongly the depth-map hint steers the image (1: as
    /// the model was trained).
    #[arg(long, default_value_t = 1.0)]
    pub conditioning_scale: f32,
    /// How the model's output becomes 8-bit pixels: `clamp` (x/2 + 0.5 clamped to [0, 1], as
    /// diffusers writes) or `minmax` (each image stretched from its own min to its own max, as
    /// MultiDiffSense's scripts save, for comparing with their outputs).
    #[arg(long, value_enum, default_value_t = ImageRange::Clamp)]
    pub image_range: ImageRange,
}

/// Where ONNX Runtime comes from and where it runs.
#[derive(Debug, Clone, ClapArgs)]
pub struct RuntimeArgs {
    /// ONNX Runtime library (libonnxruntime.so) or its folder. Default: $RIG_ORT_LIB,
    /// $ORT_DYLIB_PATH, then .rig/onnxruntime/ (filled by scripts/setup.sh).
    #[arg(long, value_name = "PATH")]
    pub ort_lib: Option<PathBuf>,
    /// Execution provider: cpu, cuda or tensorrt (the latter two need a GPU build of ONNX Runtime).
    #[arg(long, default_value = "cpu")]
    pub provider: ExecutionProviderKind,
    /// CPU threads per model (default: ONNX Runtime's choice).
    #[arg(long)]
    pub threads: Option<usize>,
    /// GPU index for --provider cuda or tensorrt.
    #[arg(long, default_value_t = 0, value_name = "N")]
    pub device_id: i32,
    /// cuDNN's convolution algorithm search (cuda): exhaustive (ONNX Runtime's default; the
    /// slowest first step), heuristic, or default (no search, least memory).
    #[arg(long, value_enum, value_name = "SEARCH")]
    pub cudnn_conv_search: Option<ConvSearch>,
    /// How the CUDA memory arena grows: next-power-of-two (ONNX Runtime's default) or
    /// same-as-requested.
    #[arg(long, value_enum, value_name = "STRATEGY")]
    pub arena_extend: Option<ArenaExtend>,
    /// Limit of the CUDA memory arena, MiB.
    #[arg(long, value_name = "MIB")]
    pub gpu_mem_limit_mib: Option<usize>,
    /// Folder for TensorRT's engine and timing caches (--provider tensorrt; untested).
    #[arg(long, value_name = "DIR")]
    pub trt_engine_cache: Option<PathBuf>,
    /// Run classifier-free guidance as two passes a step (unconditioned, conditioned) instead
    /// of one batch of two (what a package whose graphs take a fixed batch of 1 gets anyway).
    #[arg(long)]
    pub two_pass_guidance: bool,
    /// Copy every tensor in and out of each model call instead of binding them (I/O binding
    /// keeps the ControlNet's residuals on the device); for comparisons.
    #[arg(long)]
    pub no_io_binding: bool,
}

impl RuntimeArgs {
    pub fn options(&self) -> RuntimeOptions {
        RuntimeOptions {
            ort_lib: self.ort_lib.clone(),
            provider: self.provider,
            intra_threads: self.threads,
            cuda: CudaOptions {
                device_id: self.device_id,
                conv_search: self.cudnn_conv_search,
                arena_extend: self.arena_extend,
                mem_limit_bytes: self.gpu_mem_limit_mib.map(|m| m.saturating_mul(1 << 20)),
            },
            trt_engine_cache: self.trt_engine_cache.clone(),
            force_two_pass: self.two_pass_guidance,
            without_io_binding: self.no_io_binding,
        }
    }
}

/// Refuses (usage error, exit 2) an output file whose folder does not exist, checked before a
/// long run, so an hour of work is not lost to a mistyped `--out` at the end. `flag` names it.
pub fn output_folder_exists(flag: &str, path: &std::path::Path) -> anyhow::Result<()> {
    let folder = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => std::path::Path::new("."),
    };
    if !folder.is_dir() {
        bail!(crate::report::usage(&format!(
            "{flag} {}: the folder {} does not exist (rig writes the file there when the run ends; make the folder first)",
            path.display(),
            folder.display()
        )));
    }
    Ok(())
}

/// `path` from this directory, for a daemon that may run in another.
pub fn absolute(path: &std::path::Path) -> PathBuf {
    std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf())
}

/// A cancel flag for a job that stops at its next safe point: it turns true at the first Ctrl-C
/// (SIGINT) or SIGTERM, which is then announced on stderr with `what` (e.g. "finishing the
/// current pose, then retracting and disabling the arm"). The listeners are in place when this
/// returns, so no signal after it is missed; from then on neither kills rig (a SIGTERM that
/// killed it mid-move would leave the arm enabled). Needs a Tokio runtime.
pub(crate) fn cancel_on_interrupt(what: &'static str) -> anyhow::Result<tokio::sync::watch::Receiver<bool>> {
    use anyhow::Context;
    use tokio::signal::unix::{SignalKind, signal};
    let mut sigint = signal(SignalKind::interrupt()).context("listening for Ctrl-C")?;
    let mut sigterm = signal(SignalKind::terminate()).context("listening for SIGTERM")?;
    let (tx, rx) = tokio::sync::watch::channel(false);
    tokio::spawn(async move {
        let name = tokio::select! {
            s = sigint.recv() => s.map(|()| "interrupt"),
            s = sigterm.recv() => s.map(|()| "SIGTERM"),
        };
        if let Some(name) = name {
            eprintln!("{name}: {what}");
            let _ = tx.send(true);
        }
    });
    Ok(rx)
}

/// The progress display of a job run here: a bar in a terminal, plain lines elsewhere
/// ([`crate::progress`]); a bad `$RIG_PROGRESS_INTERVAL_S` is bad input.
pub(crate) fn progress() -> anyhow::Result<crate::progress::Progress> {
    crate::progress::Progress::for_stderr().map_err(|e| anyhow::Error::new(crate::cli::usage(&e.to_string())))
}

/// `--daemon URL` on the job commands: submit to a running daemon instead of running here.
#[derive(Debug, Clone, ClapArgs)]
pub struct DaemonTarget {
    /// Submit the job to the rig daemon at URL (e.g. http://127.0.0.1:7700) and follow it,
    /// instead of opening the rig here.
    #[arg(long, value_name = "URL")]
    pub daemon: Option<String>,
    /// With --daemon: print the job id and return at once instead of following it.
    #[arg(long, requires = "daemon")]
    pub detach: bool,
    /// With --daemon: the daemon's token (default: $RIG_DAEMON_TOKEN).
    #[arg(long, value_name = "TOKEN", requires = "daemon")]
    pub daemon_token: Option<String>,
}

/// Where a job that moves the arm runs (`rig collect`, `rig calibrate`, `rig audit`): on the
/// rig configured here (`--config`, `--dry-run`) or on a daemon's rig (`--daemon`).
#[derive(Debug, Clone, ClapArgs)]
pub struct RigTarget {
    /// Rig configuration file (default: $RIG_CONFIG, then ./rig.toml, else the simulated rig).
    #[arg(long)]
    pub config: Option<std::path::PathBuf>,
    /// Print what would run (the plan, the press pattern, the audit's draw), check every pose
    /// against the workspace and the press limit, and open every device without moving
    /// anything (pre-flight); exit 3 naming each device that failed.
    #[arg(long)]
    pub dry_run: bool,
    #[command(flatten)]
    pub daemon: DaemonTarget,
}

impl RigTarget {
    /// The daemon to submit to, when `--daemon` was given; a usage error when a flag of a
    /// standalone run was given with it. `standalone`: this command's own such flags, by name,
    /// and whether each was given (`--config` and `--dry-run` are added here).
    pub fn daemon(&self, job: &str, standalone: &[(&str, bool)]) -> anyhow::Result<Option<&DaemonTarget>> {
        if self.daemon.daemon.is_none() {
            return Ok(None);
        }
        let flags: Vec<(&str, bool)> =
            standalone.iter().copied().chain([("--config", self.config.is_some()), ("--dry-run", self.dry_run)]).collect();
        if flags.iter().any(|&(_, given)| given) {
            let names: Vec<&str> = flags.iter().map(|&(name, _)| name).collect();
            let list = match names.split_last() {
                Some((last, rest)) if !rest.is_empty() => format!("{} and {last}", rest.join(", ")),
                _ => names.join(""),
            };
            bail!(crate::report::usage(&format!("--daemon runs {job} on the daemon's rig: {list} apply to a standalone run only")));
        }
        Ok(Some(&self.daemon))
    }

    /// The rig configuration of a standalone run ([`RigConfig::discover`]).
    pub fn rig_config(&self) -> anyhow::Result<RigConfig> {
        Ok(RigConfig::discover(self.config.as_deref())?)
    }
}

/// What a dry run prints after its job's own line: the pre-flight of every device the job
/// would open ([`crate::rigs::preflight`]: the arm connected and read, never enabled; one
/// frame per camera; one read per Modbus peripheral), the envelope the poses visit, and the
/// `outputs`. Fails (exit 3 when a device is missing or silent) naming every device that
/// failed; nothing moves either way.
pub(crate) async fn dry_run(
    config: &RigConfig,
    object: &crate::geometry::objects::ObjectChoice,
    sensors: &crate::sensor::SensorSet,
    seed: u64,
    envelope: &crate::fence::Envelope,
    outputs: &[String],
) -> anyhow::Result<()> {
    let which = match &config.source {
        None => "the built-in simulated rig".to_string(),
        Some(path) => format!("rig config {}", path.display()),
    };
    println!("pre-flight of {which} (nothing is enabled, nothing moves):");
    let preflight = crate::rigs::preflight(config, object, sensors, seed, crate::rigs::clock_for(config)).await;
    for line in preflight.lines() {
        println!("{line}");
    }
    for line in envelope.lines() {
        println!("{line}");
    }
    println!("output: {}", outputs.join(", "));
    let result = preflight.result();
    match &result {
        Ok(()) => println!("dry run: poses checked against the workspace and the press limit, every device answered; nothing moved"),
        Err(_) => println!("dry run: nothing moved"),
    }
    Ok(result?)
}

#[cfg(test)]
mod tests {
    use clap::Parser;

    use super::*;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        rig: RigTarget,
        #[arg(long)]
        record: bool,
    }

    fn target(args: &[&str]) -> Cli {
        Cli::try_parse_from(std::iter::once("rig").chain(args.iter().copied())).expect("parses")
    }

    #[test]
    fn a_daemon_run_refuses_the_flags_of_a_standalone_run_and_names_them_all() {
        let standalone = target(&["--config", "rig.toml", "--dry-run"]);
        assert!(standalone.rig.daemon("the job", &[]).expect("no daemon").is_none());
        let daemon = target(&["--daemon", "http://127.0.0.1:9"]);
        let to = daemon.rig.daemon("the job", &[("--record", daemon.record)]).expect("no standalone flag");
        assert_eq!(to.and_then(|t| t.daemon.as_deref()), Some("http://127.0.0.1:9"));
        for (args, record) in [
            (&["--daemon", "u", "--dry-run"][..], false),
            (&["--daemon", "u", "--config", "c.toml"][..], false),
            (&["--daemon", "u"][..], true),
        ] {
            let e = target(args).rig.daemon("the job", &[("--record", record)]).expect_err("refused");
            assert_eq!(crate::report::exit_code(&e), 2, "{e}");
            assert_eq!(
                e.to_string(),
                "--daemon runs the job on the daemon's rig: --record, --config and --dry-run apply to a standalone run only"
            );
        }
    }
}
