//! Argument groups and helpers several subcommands share. It uses no other `cli` module, so
//! the subcommands can share it without importing each other or the dispatcher.

use std::path::PathBuf;

use clap::Args as ClapArgs;

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
