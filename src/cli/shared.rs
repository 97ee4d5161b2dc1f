//! Argument groups and helpers several subcommands share. It uses no other `cli` module, so
//! the subcommands can share it without importing each other or the dispatcher.

use std::path::PathBuf;

use clap::Args as ClapArgs;

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
}

impl RuntimeArgs {
    pub fn options(&self) -> RuntimeOptions {
        RuntimeOptions { ort_lib: self.ort_lib.clone(), provider: self.provider, intra_threads: self.threads }
    }
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
