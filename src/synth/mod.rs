//! `rig synth`: MultiDiffSense-style image synthesis over ONNX Runtime.
//!
//! Data flow, one image:
//!
//! ```text
//! prompt (prompt::mds_prompt) ─► tokenizer (text) ─► text_encoder ─► embeddings (cached per prompt)
//! control image (depth hint) ─────────────────────────────────────────────┐
//! seed ─► initial latents ─► [ controlnet ─► residuals ─► unet ─► CFG ─► scheduler.step ] × steps
//!                                                                          ─► vae_decoder ─► RGB
//! ```
//!
//! - [`runtime`] finds and loads the ONNX Runtime library (load-dynamic) and picks the
//!   execution provider;
//! - [`package`] opens a model package directory (layout in ARCHITECTURE.md and
//!   the guide, `docs/src/synthesis.md`, "The model package"), reads `model.toml`, and checks every model's tensor names, element types
//!   and ranks against the contract, naming file and tensor on a mismatch;
//! - [`text`] tokenises (CLIP BPE, padded to 77 with the end token) and encodes prompts, with
//!   an embedding cache;
//! - [`prompt`] builds the MultiDiffSense prompt text;
//! - [`hint`] checks a caller's control image against the package's `hint_encoding`;
//! - [`scheduler`] holds DDIM (as diffusers) and DPM-Solver++ 2M;
//! - [`pipeline`] runs the step loop with classifier-free guidance batched as [uncond, cond];
//! - [`npy`] reads and writes float32 `.npy` files for comparing with Python runs;
//! - [`limits`] holds the ranges of sampling settings and sizes, checked before allocating;
//! - [`settings`] holds the setting types a job request names (sampler, image range, shard);
//! - [`onnx_graph`] counts the UNet's downsamples, which fix the sizes a package can make.

pub mod fill;
pub mod hint;
pub mod limits;
pub mod model_toml;
pub mod npy;
pub mod onnx_graph;
pub mod package;
pub mod pipeline;
pub mod prompt;
pub mod runtime;
pub mod scheduler;
pub mod settings;
#[cfg(feature = "synth")]
pub mod text;
#[cfg(feature = "synth")]
pub mod tokenizer_json;
#[cfg(not(feature = "synth"))]
mod without_ort;

use std::path::PathBuf;

#[cfg(feature = "synth")]
pub use pipeline::Pipeline;
pub use pipeline::{GenerateOutput, GenerateRequest, ImageRange, SynthTiming};
pub use runtime::{ExecutionProviderKind, RuntimeOptions};
pub use scheduler::SchedulerKind;
#[cfg(not(feature = "synth"))]
pub use without_ort::Pipeline;

/// Everything that can go wrong loading a package or generating an image.
#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    #[error(
        "ONNX Runtime library not found; looked at: {}. Run scripts/setup.sh (fills .rig/onnxruntime/ \
         from the PyPI onnxruntime wheel), or pass --ort-lib / set RIG_ORT_LIB to libonnxruntime.so",
        searched.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
    )]
    OrtLibraryNotFound { searched: Vec<PathBuf> },
    #[error("{path} does not exist (given by {origin}); point it at libonnxruntime.so or its folder")]
    OrtLibraryMissing { path: PathBuf, origin: &'static str },
    #[error(
        "refusing to load the ONNX Runtime library {path}: {reason}. Loading a library runs its code: make it and its folder \
         yours and not writable by others (chmod go-w), or name a library you trust with --ort-lib / RIG_ORT_LIB"
    )]
    OrtLibraryUntrusted { path: PathBuf, reason: String },
    #[cfg(feature = "synth")]
    #[error("could not load the ONNX Runtime library {path}: {source}")]
    OrtLoad { path: PathBuf, source: ort::LoadDynamicError },
    #[error(
        "execution provider {provider} is not available in the ONNX Runtime library {library}; \
         it needs a build with {provider} support (e.g. the onnxruntime-gpu wheel), or use --provider cpu"
    )]
    ProviderUnavailable { provider: ExecutionProviderKind, library: PathBuf },
    #[cfg(feature = "synth")]
    #[error("ONNX Runtime: {context}: {source}")]
    Ort { context: String, source: ort::Error },
    /// ONNX Runtime could not load a model file of the package: corrupt, truncated, or not a
    /// model (bad input, unlike an [`Ort`](Self::Ort) failure while running one).
    #[error("{file}: not a model ONNX Runtime can load: {reason}")]
    BadModelFile { file: PathBuf, reason: String },
    #[error("not a complete model package: missing {}", missing.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", "))]
    MissingFiles { dir: PathBuf, missing: Vec<PathBuf> },
    /// A file of the package broke the opener's rules ([`crate::confine`]): a symlink on the
    /// way, a FIFO or device, too large.
    #[error("model package: {0}")]
    Confined(#[from] crate::confine::ConfineError),
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: {source}")]
    ModelToml { path: PathBuf, source: crate::untrusted::SyntaxError },
    #[error("{path}: {field} = {value:?} is not valid: {reason}")]
    BadModelConfig { path: PathBuf, field: &'static str, value: String, reason: &'static str },
    #[error("{path}: {source}")]
    Scheduler { path: PathBuf, source: scheduler::SchedulerError },
    #[error("{path}: cannot load the tokenizer: {reason}")]
    Tokenizer { path: PathBuf, reason: String },
    #[error("{path}: the tokenizer has no end token ({token:?}) to pad with")]
    NoEndToken { path: PathBuf, token: String },
    #[error("{file}: the model has no {direction} named `{tensor}`; its {direction}s are: {}", available.join(", "))]
    MissingTensor { file: PathBuf, direction: &'static str, tensor: String, available: Vec<String> },
    #[error("{file}: {direction} `{tensor}` has element type {found}; expected {expected}")]
    WrongElementType { file: PathBuf, direction: &'static str, tensor: String, found: String, expected: &'static str },
    #[error("{file}: {direction} `{tensor}` has shape {found:?} (-1: dynamic); expected {expected}")]
    WrongShape { file: PathBuf, direction: &'static str, tensor: String, found: Vec<i64>, expected: String },
    #[error("{file}: input `{tensor}` is not part of the model-package contract, so rig cannot feed it")]
    UnexpectedInput { file: PathBuf, tensor: String },
    #[error(
        "{controlnet_file} returns {controlnet} down-block residuals but {unet_file} takes {unet}; \
         they must come from the same base model"
    )]
    ResidualCountMismatch { controlnet_file: PathBuf, controlnet: usize, unet_file: PathBuf, unet: usize },
    #[error("{file}: output `{tensor}` came back with shape {found:?}; expected {expected:?}")]
    UnexpectedOutputShape { file: PathBuf, tensor: String, found: Vec<i64>, expected: Vec<i64> },
    #[error("{field} = {value} is not valid: {reason}")]
    BadRequest { field: &'static str, value: String, reason: String },
    #[error("{0}")]
    Npy(#[from] npy::NpyError),
    #[error("{path}: {source}")]
    Image { path: PathBuf, source: image::ImageError },
    /// This build has no ONNX Runtime (made without the `synth` feature).
    #[error(transparent)]
    FeatureMissing(#[from] crate::features::FeatureMissing),
    /// A cancel request ([`Pipeline::set_cancel`]) stopped the sampling between two steps.
    #[error("cancelled between two sampling steps")]
    Cancelled,
}

/// The per-pose seed of a synthesis plan: SplitMix64 of `plan_seed + golden * (pose_id + 1)`.
///
/// Stable across versions and platforms (pure integer arithmetic), distinct for distinct
/// pose ids under one plan seed, and uncorrelated between neighbouring ids, so a pose's image
/// does not depend on which other poses are synthesised or in which order.
pub fn pose_seed(plan_seed: u64, pose_id: u32) -> u64 {
    const GOLDEN: u64 = 0x9E37_79B9_7F4A_7C15;
    splitmix64(plan_seed.wrapping_add(GOLDEN.wrapping_mul(pose_id as u64 + 1)))
}

/// SplitMix64's output function (Steele, Lea, Flood 2014).
fn splitmix64(x: u64) -> u64 {
    let mut z = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

impl From<limits::BadSetting> for SynthError {
    fn from(e: limits::BadSetting) -> Self {
        SynthError::BadRequest { field: e.field, value: e.value, reason: e.reason }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pose_seed_is_stable_and_distinct() {
        // SplitMix64 reference: the first output of a generator seeded with 0 is
        // 0xE220A8397B1DCDAF (Vigna's splitmix64.c).
        assert_eq!(splitmix64(0), 0xE220_A839_7B1D_CDAF);
        let seeds: std::collections::HashSet<u64> = (0..10_000).map(|i| pose_seed(42, i)).collect();
        assert_eq!(seeds.len(), 10_000);
        assert_ne!(pose_seed(1, 0), pose_seed(2, 0));
        assert_eq!(pose_seed(42, 7), pose_seed(42, 7));
    }
}
