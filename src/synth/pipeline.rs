//! The diffusion loop: ControlNet then UNet with its residuals, classifier-free guidance,
//! the scheduler step, and the VAE decode to an 8-bit RGB image.
//!
//! Per step, one ControlNet call and one UNet call serve the whole batch: with guidance
//! (`guidance != 1`) the batch is `[uncond_1..uncond_n, cond_1..cond_n]` and the noise estimate
//! is `uncond + g * (cond - uncond)` (diffusers' formula); at guidance 1 the unconditional half
//! is skipped, halving the work. Several requests with the same step count, scheduler, eta,
//! conditioning scale, size and guided-ness run in one batch ([`Pipeline::generate_batch`]);
//! each keeps its own seed stream, so a batched image equals the unbatched one.
//!
//! Where a package's ControlNet or UNet declares a fixed batch (a number, not a name, in
//! dimension 0 of `sample`), each call takes that many rows: with a fixed batch of 1, guidance
//! runs as two passes a step ([`Pipeline::guidance_passes`] says which; a log line at load).
//!
//! Tensors between calls (I/O binding, unless [`RuntimeOptions::without_io_binding`]): the
//! text embeddings and control image are bound once per batch; the ControlNet's residuals stay
//! where it wrote them (the GPU's memory under CUDA) and are bound straight into the UNet;
//! the UNet's noise estimate comes back to the host. The guidance combination and the
//! scheduler step stay on the CPU, so the latents (64 KB an image at 512 px) make one small
//! round trip a step: a fraction of a millisecond at PCIe speeds against the 27 MB of
//! residuals per image that no longer cross, and one scheduler implementation (the one
//! checked against diffusers) rather than a second one as an ONNX graph. On the CPU provider
//! the output is bit-identical with and without binding (tests/synth/synth_device.rs).
//!
//! Determinism: the initial latents come from ChaCha8 seeded with the request's seed
//! (`seed_from_u64`), turned into standard normals by Box–Muller (53-bit uniforms, both outputs
//! used); DDIM's eta noise continues the same stream. `--init-latents` replaces the first part
//! so a run can be compared with a Python one.
//!
//! Output: the decoder's `sample` (in [-1, 1] nominally) is kept raw, NHWC float32, and mapped
//! to 8 bits as diffusers does: `round(clamp(x / 2 + 0.5, 0, 1) * 255)`. [`raw_to_rgb8`] also
//! maps it the way MultiDiffSense saves images ([`ImageRange::MinMax`]).

#[cfg(feature = "synth")]
use std::ops::Range;
#[cfg(feature = "synth")]
use std::path::{Path, PathBuf};
#[cfg(feature = "synth")]
use std::time::Instant;

use image::RgbImage;
#[cfg(feature = "synth")]
use ort::session::{IoBinding, Session};
use rand_chacha::ChaCha8Rng;
use rand_chacha::rand_core::Rng;
#[cfg(feature = "synth")]
use rand_chacha::rand_core::SeedableRng;

#[cfg(feature = "synth")]
use super::SynthError;
use super::npy::NpyArray;
#[cfg(feature = "synth")]
use super::package::{Accept, ModelIo, ModelPackage, TensorSpec};
#[cfg(feature = "synth")]
use super::runtime::{
    Inputs, Runtime, RuntimeOptions, device_memory, f32_tensor, f32_value, host_memory, init_runtime, number_tensor, number_value, run_f32,
};
#[cfg(feature = "synth")]
use super::scheduler::Scheduler;
use super::scheduler::SchedulerKind;
#[cfg(feature = "synth")]
use super::text::TextEncoder;

/// One image to synthesise.
#[derive(Debug, Clone, Copy)]
pub struct GenerateRequest<'a> {
    /// The control (hint) image, e.g. the viridis depth map; resized (bilinear) to the output
    /// size when it differs.
    pub control: &'a RgbImage,
    pub prompt: &'a str,
    /// Text for the unconditional half of guidance (usually empty).
    pub negative_prompt: &'a str,
    pub steps: usize,
    /// Classifier-free guidance scale; 1 runs the conditional half only.
    pub guidance: f32,
    /// DDIM eta (0: deterministic DDIM).
    pub eta: f32,
    pub seed: u64,
    pub scheduler: SchedulerKind,
    /// Multiplies the ControlNet residuals.
    pub conditioning_scale: f32,
    /// Initial latents `[1, C, H/8, W/8]`, C order; `None` draws them from `seed`.
    pub init_latents: Option<&'a [f32]>,
    /// Output (width, height) in pixels; `None`: the package's resolution.
    pub size: Option<(u32, u32)>,
    /// Return the latents after every step (for comparisons with diffusers).
    pub keep_step_latents: bool,
}

impl<'a> GenerateRequest<'a> {
    /// A request with MultiDiffSense's sampling settings: DDIM, 50 steps, eta 0, guidance 9
    /// (the paper's scale; its scripts save scale-1 samples), conditioning scale 1, seed 0.
    pub fn new(control: &'a RgbImage, prompt: &'a str) -> Self {
        Self {
            control,
            prompt,
            negative_prompt: "",
            steps: 50,
            guidance: 9.0,
            eta: 0.0,
            seed: 0,
            scheduler: SchedulerKind::Ddim,
            conditioning_scale: 1.0,
            init_latents: None,
            size: None,
            keep_step_latents: false,
        }
    }

    #[cfg(feature = "synth")]
    fn guided(&self) -> bool {
        self.guidance != 1.0
    }
}

/// One synthesised image.
#[derive(Debug, Clone)]
pub struct GenerateOutput {
    /// The image as [`ImageRange::Clamp`] maps it.
    pub image: RgbImage,
    /// The decoder's output before clamping, `[1, H, W, 3]` float32.
    pub raw: NpyArray,
    /// Latents after each step, `[1, C, h, w]` each (empty unless asked for).
    pub step_latents: Vec<NpyArray>,
}

impl GenerateOutput {
    /// The image with its 8-bit values mapped by `range` (`Clamp`: [`Self::image`] itself).
    pub fn to_rgb8(&self, range: ImageRange) -> RgbImage {
        match range {
            ImageRange::Clamp => self.image.clone(),
            ImageRange::MinMax => raw_to_rgb8(&self.raw.data, self.image.width(), self.image.height(), range),
        }
    }
}

pub use super::settings::ImageRange;

/// One image's decoder output, NHWC `[height, width, 3]` float32 (the data of
/// [`GenerateOutput::raw`]), as an 8-bit RGB image, its values mapped by `range`. Missing
/// values (a short slice) read as NaN, which maps to 0.
pub fn raw_to_rgb8(raw: &[f32], width: u32, height: u32, range: ImageRange) -> RgbImage {
    let at = |i: usize| raw.get(i).copied().unwrap_or(f32::NAN);
    let len = 3 * width as usize * height as usize;
    match range {
        ImageRange::Clamp => RgbImage::from_fn(width, height, |x, y| {
            let i = 3 * (y as usize * width as usize + x as usize);
            image::Rgb([to_u8(at(i)), to_u8(at(i + 1)), to_u8(at(i + 2))])
        }),
        ImageRange::MinMax => {
            let values = &raw[..len.min(raw.len())];
            let lo = values.iter().copied().fold(f32::INFINITY, f32::min);
            let hi = values.iter().copied().fold(f32::NEG_INFINITY, f32::max);
            // float32 throughout, as torch computes it; `as u8` truncates (torch's uint8 cast)
            // and saturates, NaN to 0.
            let span = (hi - lo) + 1e-8_f32;
            let level = |v: f32| (((v - lo) / span) * 255.0 + 0.5).clamp(0.0, 255.0) as u8;
            RgbImage::from_fn(width, height, |x, y| {
                let i = 3 * (y as usize * width as usize + x as usize);
                image::Rgb([level(at(i)), level(at(i + 1)), level(at(i + 2))])
            })
        }
    }
}

/// A session with the file it came from and its checked inputs/outputs.
#[cfg(feature = "synth")]
struct ModelSession {
    session: Session,
    file: PathBuf,
    io: ModelIo,
}

#[cfg(feature = "synth")]
impl ModelSession {
    fn open(runtime: &Runtime, package: &ModelPackage, relative: &str, opts: &RuntimeOptions) -> Result<Self, SynthError> {
        let file = package.file(relative);
        let session = runtime.session(&file, opts)?;
        let io = ModelIo::of(&file, &session)?;
        Ok(Self { session, file, io })
    }
}

/// A loaded model package, ready to generate.
#[cfg(feature = "synth")]
pub struct Pipeline {
    package: ModelPackage,
    runtime: Runtime,
    text: TextEncoder,
    controlnet: ModelSession,
    unet: ModelSession,
    vae: ModelSession,
    down_names: Vec<String>,
    residual_names: Vec<String>,
    controlnet_timestep: TensorSpec,
    unet_timestep: TensorSpec,
    conditioning_scale: TensorSpec,
    latent_channels: usize,
    /// Width and height must be multiples of this many pixels (see [`Pipeline::size_multiple`]).
    size_multiple: u32,
    hash: String,
    /// Asked at the top of every sampling step: true stops the sampling ([`SynthError::Cancelled`]).
    cancel: Option<CancelCheck>,
    /// The batch the ControlNet's and UNet's `sample` inputs declare, where fixed.
    fixed_batch: Option<usize>,
    opts: RuntimeOptions,
    timing: SynthTiming,
}

/// Where the time of a process's synthesis went: loading, the first step's extra cost, and
/// the steady state per image.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SynthTiming {
    /// [`Pipeline::load`]: the library, the four sessions, the checks, the package hash, s.
    pub load_s: f64,
    /// What the process's first denoising step cost beyond the median of the other steps of
    /// its batch (kernel selection, memory arenas, cuDNN's algorithm search), s.
    pub warmup_s: f64,
    /// Images made so far.
    pub images: usize,
    /// Wall time of all generate calls so far (warm-up included), s.
    pub generate_s: f64,
}

impl SynthTiming {
    /// The steady-state time per image: all generating time less the warm-up, per image.
    pub fn steady_per_image_s(&self) -> Option<f64> {
        (self.images > 0).then(|| (self.generate_s - self.warmup_s).max(0.0) / self.images as f64)
    }

    /// `load 1.23 s, warm-up 0.40 s (first step), 0.50 s an image steady state (16 images)`.
    pub fn line(&self) -> String {
        let steady = match self.steady_per_image_s() {
            Some(s) => format!("{s:.3} s an image steady state ({} image{})", self.images, if self.images == 1 { "" } else { "s" }),
            None => "no image yet".to_string(),
        };
        format!("load {:.2} s, warm-up {:.3} s (first step), {steady}", self.load_s, self.warmup_s)
    }
}

/// The inputs one step's session calls share: text embeddings `[batch, seq_len, hidden]` and
/// control images `[batch, 3, h, w]`, and the sizes.
#[cfg(feature = "synth")]
struct StepShape<'a> {
    ehs: &'a [f32],
    hint: &'a [f32],
    seq_len: usize,
    hidden: usize,
    channels: usize,
    latent_hw: (usize, usize),
    image_hw: (usize, usize),
    conditioning_scale: f32,
}

#[cfg(feature = "synth")]
impl StepShape<'_> {
    fn latent_len(&self) -> usize {
        self.channels * self.latent_hw.0 * self.latent_hw.1
    }
    fn latent_shape(&self, rows: usize) -> [usize; 4] {
        [rows, self.channels, self.latent_hw.0, self.latent_hw.1]
    }
    fn ehs_rows(&self, r: &Range<usize>) -> &[f32] {
        let len = self.seq_len * self.hidden;
        &self.ehs[r.start * len..r.end * len]
    }
    fn hint_rows(&self, r: &Range<usize>) -> &[f32] {
        let len = 3 * self.image_hw.0 * self.image_hw.1;
        &self.hint[r.start * len..r.end * len]
    }
}

/// One call's I/O bindings: text embeddings, control image and conditioning scale bound once
/// per batch; the ControlNet's residuals stay where the ControlNet wrote them (the device)
/// and are bound straight into the UNet; the UNet's noise estimate comes back to the host.
#[cfg(feature = "synth")]
struct BoundCall {
    controlnet: IoBinding,
    unet: IoBinding,
}

/// A cancel flag the sampling loop reads between steps (e.g. a job's cancel request).
pub type CancelCheck = std::sync::Arc<dyn Fn() -> bool + Send + Sync>;

#[cfg(feature = "synth")]
impl std::fmt::Debug for Pipeline {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Pipeline")
            .field("package", &self.package.dir)
            .field("library", &self.runtime.library)
            .field("hash", &self.hash)
            .finish_non_exhaustive()
    }
}

#[cfg(feature = "synth")]
const STEP_INPUTS: [&str; 3] = ["sample", "timestep", "encoder_hidden_states"];

#[cfg(feature = "synth")]
impl Pipeline {
    /// Opens the package at `model_dir`, loads ONNX Runtime and the four models, and checks
    /// every model against the package contract.
    pub fn load(model_dir: &Path, opts: &RuntimeOptions) -> Result<Pipeline, SynthError> {
        let started = Instant::now();
        let package = ModelPackage::open(model_dir)?;
        let runtime = init_runtime(opts)?;

        let te_file = package.file("text_encoder/model.onnx");
        let te_session = runtime.session(&te_file, opts)?;
        let text = TextEncoder::new(te_session, &te_file, &package.file("tokenizer/tokenizer.json"), &package.config.end_token)?;

        let controlnet = ModelSession::open(&runtime, &package, "controlnet/model.onnx", opts)?;
        let io = &controlnet.io;
        let sample = io.expect("input", "sample", Accept::Float32, &[4])?;
        let controlnet_batch = sample.shape[0];
        let latent_channels = if sample.shape[1] > 0 { sample.shape[1] as usize } else { 4 };
        let controlnet_timestep = io.expect("input", "timestep", Accept::Number, &[0, 1])?.clone();
        io.expect("input", "encoder_hidden_states", Accept::Float32, &[3])?;
        io.expect("input", "controlnet_cond", Accept::Float32, &[4])?;
        let conditioning_scale = io.expect("input", "conditioning_scale", Accept::Float32, &[0, 1])?.clone();
        let mut allowed: Vec<String> = STEP_INPUTS.iter().map(|s| s.to_string()).collect();
        allowed.extend(["controlnet_cond".to_string(), "conditioning_scale".to_string()]);
        io.only_inputs(&allowed)?;
        let n_down = io.count_numbered("output", "down_block_res_samples_");
        // With none found, checking `_0` gives the error naming the first missing output.
        let mut down_names: Vec<String> = (0..n_down.max(1)).map(|i| format!("down_block_res_samples_{i}")).collect();
        for name in &down_names {
            io.expect("output", name, Accept::Float32, &[4])?;
        }
        io.expect("output", "mid_block_res_sample", Accept::Float32, &[4])?;
        down_names.push("mid_block_res_sample".to_string());

        let unet = ModelSession::open(&runtime, &package, "unet/model.onnx", opts)?;
        let io = &unet.io;
        let unet_batch = io.expect("input", "sample", Accept::Float32, &[4])?.shape[0];
        let unet_timestep = io.expect("input", "timestep", Accept::Number, &[0, 1])?.clone();
        io.expect("input", "encoder_hidden_states", Accept::Float32, &[3])?;
        let n_unet = io.count_numbered("input", "down_block_additional_residual_");
        if n_unet != n_down && n_unet > 0 {
            return Err(SynthError::ResidualCountMismatch {
                controlnet_file: controlnet.file.clone(),
                controlnet: n_down,
                unet_file: unet.file.clone(),
                unet: n_unet,
            });
        }
        let mut residual_names: Vec<String> = (0..n_down).map(|i| format!("down_block_additional_residual_{i}")).collect();
        residual_names.push("mid_block_additional_residual".to_string());
        for name in &residual_names {
            io.expect("input", name, Accept::Float32, &[4])?;
        }
        let mut allowed: Vec<String> = STEP_INPUTS.iter().map(|s| s.to_string()).collect();
        allowed.extend(residual_names.iter().cloned());
        io.only_inputs(&allowed)?;
        io.expect("output", "out_sample", Accept::Float32, &[4])?;

        let vae = ModelSession::open(&runtime, &package, "vae_decoder/model.onnx", opts)?;
        vae.io.expect("input", "latent_sample", Accept::Float32, &[4])?;
        vae.io.only_inputs(&["latent_sample".to_string()])?;
        vae.io.expect("output", "sample", Accept::Float32, &[4])?;

        // The UNet halves the latent once per downsample: sizes must divide by 2^downsamples.
        let f = package.config.vae_scale_factor;
        let size_multiple = match super::onnx_graph::count_stride2_convs(&unet.file) {
            Ok(n) => f.saturating_mul(1u32.checked_shl(n.min(16) as u32).unwrap_or(1)),
            Err(e) => {
                tracing::warn!(file = %unet.file.display(), error = %e, "cannot count the UNet's downsamples; sizes are checked against the VAE factor only");
                f
            }
        };
        let resolution = (package.config.width_px, package.config.height_px);
        if super::limits::check_size("resolution", resolution, size_multiple).is_err() {
            return Err(SynthError::BadModelConfig {
                path: package.file("model.toml"),
                field: "resolution",
                value: format!("[{}, {}]", resolution.0, resolution.1),
                reason: "must be a multiple of the UNet's size multiple (VAE factor times 2 per downsample)",
            });
        }

        // A graph exported with a fixed batch (dimension 0 a number, not a name) takes only
        // that many rows a call: guidance then runs as two passes.
        let fixed_batch = [controlnet_batch, unet_batch].into_iter().filter(|&b| b > 0).min().map(|b| b as usize);
        if let Some(b) = fixed_batch {
            tracing::info!(
                controlnet = %controlnet.file.display(),
                unet = %unet.file.display(),
                batch = b,
                "the ControlNet and UNet take a fixed batch: classifier-free guidance runs as two passes a step"
            );
        }

        let hash = package.content_hash()?;
        let timing = SynthTiming { load_s: started.elapsed().as_secs_f64(), ..SynthTiming::default() };
        Ok(Pipeline {
            package,
            runtime,
            text,
            controlnet,
            unet,
            vae,
            down_names,
            residual_names,
            controlnet_timestep,
            unet_timestep,
            conditioning_scale,
            latent_channels,
            size_multiple,
            hash,
            fixed_batch,
            opts: opts.clone(),
            timing,
            cancel: None,
        })
    }

    /// How classifier-free guidance runs: one batch of two per step, or two passes (where the
    /// graphs take a fixed batch of 1, or `--two-pass-guidance` asks); `rig synth info` prints it.
    pub fn guidance_passes(&self) -> String {
        match (self.fixed_batch, self.opts.force_two_pass) {
            (Some(1), _) => "two passes a step (the ControlNet and UNet graphs take a fixed batch of 1)".to_string(),
            (Some(b), _) => format!("calls of {b} rows (the ControlNet and UNet graphs take a fixed batch of {b})"),
            (None, true) => "two passes a step (--two-pass-guidance)".to_string(),
            (None, false) => "one batch of two a step, [unconditioned, conditioned] (the graphs' batch is dynamic)".to_string(),
        }
    }

    /// Whether the step loop binds its tensors (I/O binding) rather than copying them in and
    /// out of every session call.
    pub fn io_binding(&self) -> bool {
        !self.opts.without_io_binding
    }

    /// Load, warm-up and steady-state time of this process's synthesis so far.
    pub fn timing(&self) -> SynthTiming {
        self.timing
    }

    /// Rows per ControlNet/UNet call for a step batch of `batch` rows (`2n` with guidance).
    fn rows_per_call(&self, batch: usize, guided: bool) -> Result<usize, SynthError> {
        rows_per_call(self.fixed_batch, self.opts.force_two_pass, batch, guided)
    }

    /// Sets (or with `None` clears) the check the sampling loop makes before every step; once
    /// it answers true, generating returns [`SynthError::Cancelled`] at the next step.
    pub fn set_cancel(&mut self, cancel: Option<CancelCheck>) {
        self.cancel = cancel;
    }

    /// Width and height of a synthesised image must be multiples of this many pixels: the VAE
    /// factor times 2 per downsample of the UNet (16 for the tiny test package and for
    /// `models/default`, 64 for Stable Diffusion 1.5).
    pub fn size_multiple(&self) -> u32 {
        self.size_multiple
    }

    /// Checks a request's settings against [`super::limits`] and this package: size, guidance,
    /// eta, conditioning scale, steps for its sampler, initial latents. Nothing is allocated
    /// before it passes.
    pub fn check_request(&self, r: &GenerateRequest) -> Result<(), SynthError> {
        self.validate(r, r.size.unwrap_or(self.resolution()))
    }

    /// SHA-256 (hex) over the package's files; see [`ModelPackage::content_hash`].
    pub fn package_hash(&self) -> &str {
        &self.hash
    }

    /// The package's native output size (width, height) in pixels.
    pub fn resolution(&self) -> (u32, u32) {
        (self.package.config.width_px, self.package.config.height_px)
    }

    /// The shape `[1, channels, h, w]` of the initial latents of an image at the package's
    /// resolution (what [`GenerateRequest::init_latents`] must hold).
    pub fn latent_shape(&self) -> [usize; 4] {
        let (w, h) = self.resolution();
        let f = self.package.config.vae_scale_factor.max(1);
        [1, self.latent_channels, (h / f) as usize, (w / f) as usize]
    }

    /// The package (config, schedule, directory).
    pub fn package(&self) -> &ModelPackage {
        &self.package
    }

    /// The ONNX Runtime library in use.
    pub fn library(&self) -> &Path {
        &self.runtime.library
    }

    /// How that library was chosen (`--ort-lib`, `RIG_ORT_LIB`, the checkout's `.rig/onnxruntime/`...).
    pub fn library_origin(&self) -> &'static str {
        self.runtime.origin
    }

    /// Token ids the tokenizer gives `prompt` (padded to the sequence length).
    pub fn token_ids(&self, prompt: &str) -> Result<Vec<u32>, SynthError> {
        self.text.tokenizer.ids(prompt)
    }

    /// Text embeddings `[L * D]` of `prompt` (cached).
    pub fn embed(&mut self, prompt: &str) -> Result<Vec<f32>, SynthError> {
        Ok(self.text.encode(&[prompt])?.into_iter().next().map(|e| e.to_vec()).unwrap_or_default())
    }

    /// How many distinct prompts have cached embeddings.
    pub fn cached_prompts(&self) -> usize {
        self.text.cached()
    }

    /// Synthesises one image.
    pub fn generate(&mut self, request: &GenerateRequest) -> Result<GenerateOutput, SynthError> {
        let out = self.run_group(&[request])?;
        out.into_iter().next().ok_or(SynthError::BadRequest {
            field: "request",
            value: "1".to_string(),
            reason: "no image came back".to_string(),
        })
    }

    /// Synthesises several images, batching compatible requests (same steps, scheduler, eta,
    /// conditioning scale, size and guided-ness) into shared session calls. The results come
    /// back in request order and equal the unbatched ones per seed.
    pub fn generate_batch(&mut self, requests: &[GenerateRequest]) -> Result<Vec<GenerateOutput>, SynthError> {
        let mut results: Vec<Option<GenerateOutput>> = (0..requests.len()).map(|_| None).collect();
        let mut groups: Vec<(BatchKey, Vec<usize>)> = Vec::new();
        for (i, r) in requests.iter().enumerate() {
            let key = BatchKey::of(r, self.resolution());
            match groups.iter_mut().find(|(k, _)| *k == key) {
                Some((_, members)) => members.push(i),
                None => groups.push((key, vec![i])),
            }
        }
        for (_, members) in groups {
            let batch: Vec<&GenerateRequest> = members.iter().map(|&i| &requests[i]).collect();
            for (i, out) in members.into_iter().zip(self.run_group(&batch)?) {
                results[i] = Some(out);
            }
        }
        Ok(results.into_iter().flatten().collect())
    }

    fn validate(&self, r: &GenerateRequest, size: (u32, u32)) -> Result<(), SynthError> {
        let bad = |field, value: String, reason: String| Err(SynthError::BadRequest { field, value, reason });
        let f = self.package.config.vae_scale_factor;
        super::limits::check_size("size", size, self.size_multiple)?;
        if r.control.width() == 0 || r.control.height() == 0 {
            return bad("control", "0 pixels".to_string(), "the control image is empty".into());
        }
        super::limits::check_guidance(r.guidance)?;
        super::limits::check_eta(r.eta)?;
        super::limits::check_conditioning_scale(r.conditioning_scale)?;
        // A step count the schedule cannot take is the request's (`--steps`), not the package's.
        self.package.schedule.check_steps(r.scheduler, r.steps).map_err(|source| match source {
            super::scheduler::SchedulerError::BadStepCount { .. } => {
                SynthError::BadRequest { field: "steps", value: r.steps.to_string(), reason: source.to_string() }
            }
            source => SynthError::Scheduler { path: self.package.file("scheduler/scheduler_config.json"), source },
        })?;
        if let Some(init) = r.init_latents {
            let want = self.latent_channels * (size.0 / f) as usize * (size.1 / f) as usize;
            if init.len() != want {
                return bad(
                    "init_latents",
                    format!("{} values", init.len()),
                    format!("expected [1, {}, {}, {}] = {want} values", self.latent_channels, size.1 / f, size.0 / f),
                );
            }
        }
        Ok(())
    }

    fn timestep_value(&self, spec: &TensorSpec, t: i64, batch: usize) -> Result<ort::session::SessionInputValue<'static>, SynthError> {
        match spec.shape.as_slice() {
            [] => number_value(spec.ty, &[], &[t as f64]),
            [1] => number_value(spec.ty, &[1], &[t as f64]),
            _ => number_value(spec.ty, &[batch], &vec![t as f64; batch]),
        }
    }

    fn scale_tensor(&self, scale: f32) -> Result<ort::value::Tensor<f32>, SynthError> {
        if self.conditioning_scale.shape.is_empty() { f32_tensor(&[], &[scale]) } else { f32_tensor(&[1], &[scale]) }
    }

    fn timestep_tensor(&self, spec: &TensorSpec, t: i64, batch: usize) -> Result<ort::value::DynValue, SynthError> {
        match spec.shape.as_slice() {
            [] => number_tensor(spec.ty, &[], &[t as f64]),
            [1] => number_tensor(spec.ty, &[1], &[t as f64]),
            _ => number_tensor(spec.ty, &[batch], &vec![t as f64; batch]),
        }
    }

    /// The UNet's noise estimate for `rows` rows, checked against their latent shape.
    fn check_noise(&self, rows: usize, shape: &StepShape, found: Vec<i64>, noise: Vec<f32>) -> Result<Vec<f32>, SynthError> {
        if noise.len() != rows * shape.latent_len() {
            return Err(SynthError::UnexpectedOutputShape {
                file: self.unet.file.clone(),
                tensor: "out_sample".to_string(),
                found,
                expected: shape.latent_shape(rows).iter().map(|&d| d as i64).collect(),
            });
        }
        Ok(noise)
    }

    /// One step for rows `r` of the batch, every input copied in and every output copied out.
    fn step_plain(&mut self, shape: &StepShape, r: &Range<usize>, sample: &[f32], t: i64) -> Result<Vec<f32>, SynthError> {
        let n = r.len();
        let latent_shape = shape.latent_shape(n);
        let ehs_shape = [n, shape.seq_len, shape.hidden];
        let inputs: Inputs = vec![
            ("sample".into(), f32_value(&latent_shape, sample.to_vec())?),
            ("timestep".into(), self.timestep_value(&self.controlnet_timestep, t, n)?),
            ("encoder_hidden_states".into(), f32_value(&ehs_shape, shape.ehs_rows(r).to_vec())?),
            ("controlnet_cond".into(), f32_value(&[n, 3, shape.image_hw.0, shape.image_hw.1], shape.hint_rows(r).to_vec())?),
            ("conditioning_scale".into(), self.scale_tensor(shape.conditioning_scale)?.into()),
        ];
        let residuals = run_f32(&mut self.controlnet.session, &self.controlnet.file, inputs, &self.down_names)?;

        let mut inputs: Inputs = vec![
            ("sample".into(), f32_value(&latent_shape, sample.to_vec())?),
            ("timestep".into(), self.timestep_value(&self.unet_timestep, t, n)?),
            ("encoder_hidden_states".into(), f32_value(&ehs_shape, shape.ehs_rows(r).to_vec())?),
        ];
        for (name, (shape, data)) in self.residual_names.iter().zip(residuals) {
            let shape: Vec<usize> = shape.iter().map(|&d| d.max(0) as usize).collect();
            inputs.push((name.clone(), f32_value(&shape, data)?));
        }
        let mut out = run_f32(&mut self.unet.session, &self.unet.file, inputs, &["out_sample".to_string()])?;
        let (found, noise) = out.pop().unwrap_or_default();
        self.check_noise(n, shape, found, noise)
    }

    /// Binds what stays the same for every step of a batch (rows `r`): the text embeddings and
    /// the control image are copied to the device here, once; the ControlNet's outputs are
    /// left on the device, the UNet's comes back to the host.
    fn bind_constants(&self, shape: &StepShape, r: &Range<usize>) -> Result<BoundCall, SynthError> {
        let n = r.len();
        let on = |file: &Path| {
            let context = format!("binding the inputs and outputs of {}", file.display());
            move |source| SynthError::Ort { context, source }
        };
        let ehs = f32_tensor(&[n, shape.seq_len, shape.hidden], shape.ehs_rows(r))?;
        let hint = f32_tensor(&[n, 3, shape.image_hw.0, shape.image_hw.1], shape.hint_rows(r))?;
        let device = device_memory(&self.opts)?;

        let file = &self.controlnet.file;
        let mut controlnet = self.controlnet.session.create_binding().map_err(on(file))?;
        controlnet.bind_input("encoder_hidden_states", &ehs).map_err(on(file))?;
        controlnet.bind_input("controlnet_cond", &hint).map_err(on(file))?;
        controlnet.bind_input("conditioning_scale", &self.scale_tensor(shape.conditioning_scale)?).map_err(on(file))?;
        for name in &self.down_names {
            controlnet.bind_output_to_device(name.as_str(), &device).map_err(on(file))?;
        }

        let file = &self.unet.file;
        let mut unet = self.unet.session.create_binding().map_err(on(file))?;
        unet.bind_input("encoder_hidden_states", &ehs).map_err(on(file))?;
        unet.bind_output_to_device("out_sample", &host_memory()?).map_err(on(file))?;
        Ok(BoundCall { controlnet, unet })
    }

    /// One step for `n` rows through their bindings: the latents go in (the one per-step copy
    /// to the device), the residuals pass from ControlNet to UNet where they are, the noise
    /// estimate comes back.
    fn step_bound(&mut self, b: &mut BoundCall, shape: &StepShape, n: usize, sample: &[f32], t: i64) -> Result<Vec<f32>, SynthError> {
        let on = |file: &Path| {
            let context = format!("running {} with bound inputs", file.display());
            move |source| SynthError::Ort { context, source }
        };
        let sample = f32_tensor(&shape.latent_shape(n), sample)?;
        let controlnet_t = self.timestep_tensor(&self.controlnet_timestep, t, n)?;
        let unet_t = self.timestep_tensor(&self.unet_timestep, t, n)?;
        let (cn_file, unet_file) = (&self.controlnet.file, &self.unet.file);
        b.controlnet.bind_input("sample", &sample).map_err(on(cn_file))?;
        b.controlnet.bind_input("timestep", &controlnet_t).map_err(on(cn_file))?;
        {
            let mut outputs = self.controlnet.session.run_binding(&b.controlnet).map_err(on(cn_file))?;
            for (down, residual) in self.down_names.iter().zip(&self.residual_names) {
                let available: Vec<String> = outputs.keys().map(|k| k.to_string()).collect();
                let value = outputs.remove(down.as_str()).ok_or_else(|| SynthError::MissingTensor {
                    file: cn_file.clone(),
                    direction: "output",
                    tensor: down.clone(),
                    available,
                })?;
                b.unet.bind_input(residual.as_str(), &value).map_err(on(unet_file))?;
            }
        }
        b.unet.bind_input("sample", &sample).map_err(on(unet_file))?;
        b.unet.bind_input("timestep", &unet_t).map_err(on(unet_file))?;
        let outputs = self.unet.session.run_binding(&b.unet).map_err(on(unet_file))?;
        let value = outputs.get("out_sample").ok_or_else(|| SynthError::MissingTensor {
            file: unet_file.clone(),
            direction: "output",
            tensor: "out_sample".to_string(),
            available: outputs.keys().map(|k| k.to_string()).collect(),
        })?;
        let (found, noise) = value
            .try_extract_tensor::<f32>()
            .map_err(|source| SynthError::Ort { context: format!("reading output `out_sample` of {}", unet_file.display()), source })?;
        let (found, noise) = (found.to_vec(), noise.to_vec());
        drop(outputs);
        self.check_noise(n, shape, found, noise)
    }

    /// Runs requests that share a [`BatchKey`] as one batch.
    fn run_group(&mut self, reqs: &[&GenerateRequest]) -> Result<Vec<GenerateOutput>, SynthError> {
        let started = Instant::now();
        let out = self.run_group_untimed(reqs)?;
        self.timing.generate_s += started.elapsed().as_secs_f64();
        self.timing.images += out.len();
        Ok(out)
    }

    fn run_group_untimed(&mut self, reqs: &[&GenerateRequest]) -> Result<Vec<GenerateOutput>, SynthError> {
        let first = reqs[0];
        let size = first.size.unwrap_or(self.resolution());
        for r in reqs {
            self.validate(r, size)?;
        }
        let n = reqs.len();
        let f = self.package.config.vae_scale_factor;
        let (w, h) = (size.0 as usize, size.1 as usize);
        let (lw, lh) = (w / f as usize, h / f as usize);
        let c = self.latent_channels;
        let latent_len = c * lh * lw;
        let guided = first.guided();
        let batch = if guided { 2 * n } else { n };

        // Text: [uncond..., cond...] or [cond...].
        let conds = self.text.encode(&reqs.iter().map(|r| r.prompt).collect::<Vec<_>>())?;
        let mut ehs: Vec<f32> = Vec::new();
        if guided {
            let unconds = self.text.encode(&reqs.iter().map(|r| r.negative_prompt).collect::<Vec<_>>())?;
            unconds.iter().for_each(|e| ehs.extend_from_slice(e));
        }
        conds.iter().for_each(|e| ehs.extend_from_slice(e));
        let seq_len = self.text.tokenizer.sequence_len;
        let hidden = ehs.len() / (batch * seq_len);

        // Control images, NCHW, duplicated for the two halves of guidance.
        let mut hint: Vec<f32> = Vec::with_capacity(n * 3 * w * h);
        for r in reqs {
            hint.extend(encode_hint(r.control, size, self.package.config.hint_encoding));
        }
        if guided {
            hint.extend_from_within(..);
        }

        // Latents and per-request noise streams and schedulers.
        let mut rngs: Vec<ChaCha8Rng> = reqs.iter().map(|r| ChaCha8Rng::seed_from_u64(r.seed)).collect();
        let mut latents: Vec<Vec<f32>> = reqs
            .iter()
            .zip(rngs.iter_mut())
            .map(|(r, rng)| match r.init_latents {
                Some(init) => init.to_vec(),
                None => gaussian(rng, latent_len),
            })
            .collect();
        let schedule = &self.package.schedule;
        let sched_path = self.package.file("scheduler/scheduler_config.json");
        let mut schedulers: Vec<Scheduler> = reqs
            .iter()
            .map(|r| Scheduler::new(schedule, r.scheduler, r.steps, r.eta))
            .collect::<Result<_, _>>()
            .map_err(|source| SynthError::Scheduler { path: sched_path.clone(), source })?;
        let timesteps = schedulers[0].timesteps().to_vec();
        let mut step_latents: Vec<Vec<NpyArray>> = vec![Vec::new(); n];

        let shape = StepShape {
            ehs: &ehs,
            hint: &hint,
            seq_len,
            hidden,
            channels: c,
            latent_hw: (lh, lw),
            image_hw: (h, w),
            conditioning_scale: first.conditioning_scale,
        };
        let rows = self.rows_per_call(batch, guided)?;
        let calls: Vec<Range<usize>> = (0..batch).step_by(rows.max(1)).map(|r| r..(r + rows).min(batch)).collect();
        let mut bound: Vec<BoundCall> =
            if self.io_binding() { calls.iter().map(|r| self.bind_constants(&shape, r)).collect::<Result<_, _>>()? } else { Vec::new() };
        let first_batch = self.timing.images == 0 && self.timing.warmup_s == 0.0;
        let mut step_s: Vec<f64> = Vec::with_capacity(timesteps.len());

        for &t in &timesteps {
            if self.cancel.as_ref().is_some_and(|cancelled| cancelled()) {
                return Err(SynthError::Cancelled);
            }
            let step_started = Instant::now();
            let mut sample: Vec<f32> = latents.concat();
            if guided {
                sample.extend_from_within(..);
            }
            let mut noise_pred: Vec<f32> = Vec::with_capacity(batch * latent_len);
            for (i, r) in calls.iter().enumerate() {
                let rows = &sample[r.start * latent_len..r.end * latent_len];
                let out = match bound.get_mut(i) {
                    Some(b) => self.step_bound(b, &shape, r.len(), rows, t)?,
                    None => self.step_plain(&shape, r, rows, t)?,
                };
                noise_pred.extend_from_slice(&out);
            }

            for k in 0..n {
                let eps: Vec<f32> = if guided {
                    let g = reqs[k].guidance;
                    let uncond = &noise_pred[k * latent_len..(k + 1) * latent_len];
                    let cond = &noise_pred[(n + k) * latent_len..(n + k + 1) * latent_len];
                    uncond.iter().zip(cond).map(|(&u, &c)| u + g * (c - u)).collect()
                } else {
                    noise_pred[k * latent_len..(k + 1) * latent_len].to_vec()
                };
                let noise = schedulers[k].needs_noise().then(|| gaussian(&mut rngs[k], latent_len));
                latents[k] = schedulers[k].step(&self.package.schedule, &eps, &latents[k], noise.as_deref());
                if reqs[k].keep_step_latents {
                    step_latents[k].push(NpyArray { shape: vec![1, c, lh, lw], data: latents[k].clone() });
                }
            }
            step_s.push(step_started.elapsed().as_secs_f64());
        }
        if first_batch && step_s.len() > 1 {
            let mut rest = step_s[1..].to_vec();
            rest.sort_by(f64::total_cmp);
            self.timing.warmup_s = (step_s[0] - rest[rest.len() / 2]).max(0.0);
        }

        // Decode all at once.
        let scale = self.package.config.latent_scale;
        let scaled: Vec<f32> = latents.concat().iter().map(|v| v / scale).collect();
        let inputs: Inputs = vec![("latent_sample".into(), f32_value(&[n, c, lh, lw], scaled)?)];
        let mut out = run_f32(&mut self.vae.session, &self.vae.file, inputs, &["sample".to_string()])?;
        let (shape, decoded) = out.pop().unwrap_or_default();
        if shape != [n as i64, 3, h as i64, w as i64] {
            return Err(SynthError::UnexpectedOutputShape {
                file: self.vae.file.clone(),
                tensor: "sample".to_string(),
                found: shape,
                expected: vec![n as i64, 3, h as i64, w as i64],
            });
        }
        let plane = w * h;
        Ok((0..n)
            .map(|k| {
                let img = &decoded[k * 3 * plane..(k + 1) * 3 * plane];
                let mut raw = Vec::with_capacity(3 * plane);
                for p in 0..plane {
                    raw.extend([img[p], img[plane + p], img[2 * plane + p]]);
                }
                let image = raw_to_rgb8(&raw, size.0, size.1, ImageRange::Clamp);
                GenerateOutput {
                    image,
                    raw: NpyArray { shape: vec![1, h, w, 3], data: raw },
                    step_latents: std::mem::take(&mut step_latents[k]),
                }
            })
            .collect())
    }
}

/// Rows per ControlNet/UNet call: the graphs' fixed batch where they declare one (it must
/// divide the `batch` rows of a step), half the batch for forced two-pass guidance, else all.
#[cfg(feature = "synth")]
fn rows_per_call(fixed_batch: Option<usize>, force_two_pass: bool, batch: usize, guided: bool) -> Result<usize, SynthError> {
    match fixed_batch {
        Some(b) if b > 0 && batch.is_multiple_of(b) => Ok(b),
        Some(b) => Err(SynthError::BadRequest {
            field: "batch",
            value: batch.to_string(),
            reason: format!("the package's ControlNet and UNet take a fixed batch of {b}, which does not divide {batch} rows"),
        }),
        None if force_two_pass && guided && batch >= 2 => Ok(batch / 2),
        None => Ok(batch),
    }
}

/// Requests that can share session calls.
#[cfg(feature = "synth")]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct BatchKey {
    steps: usize,
    scheduler: SchedulerKind,
    eta_bits: u32,
    scale_bits: u32,
    guided: bool,
    size: (u32, u32),
}

#[cfg(feature = "synth")]
impl BatchKey {
    fn of(r: &GenerateRequest, native: (u32, u32)) -> Self {
        Self {
            steps: r.steps,
            scheduler: r.scheduler,
            eta_bits: r.eta.to_bits(),
            scale_bits: r.conditioning_scale.to_bits(),
            guided: r.guided(),
            size: r.size.unwrap_or(native),
        }
    }
}

/// diffusers' `numpy_to_pil`: `round(clamp(x / 2 + 0.5, 0, 1) * 255)`.
pub fn to_u8(x: f32) -> u8 {
    let v = (x / 2.0 + 0.5).clamp(0.0, 1.0) * 255.0;
    // numpy's `.round()` rounds half to even.
    if v.is_nan() { 0 } else { v.round_ties_even() as u8 }
}

/// The control image as NCHW floats for `controlnet_cond`.
pub fn encode_hint(control: &RgbImage, size: (u32, u32), encoding: super::package::HintEncoding) -> Vec<f32> {
    let resized;
    let img = if control.dimensions() == size {
        control
    } else {
        resized = image::imageops::resize(control, size.0, size.1, image::imageops::FilterType::Triangle);
        &resized
    };
    let (w, h) = (size.0 as usize, size.1 as usize);
    let mut out = vec![0.0f32; 3 * w * h];
    for (x, y, p) in img.enumerate_pixels() {
        let i = y as usize * w + x as usize;
        for ch in 0..3 {
            let v = p.0[ch] as f32 / 255.0;
            out[ch * w * h + i] = match encoding {
                super::package::HintEncoding::Rgb01 => v,
                super::package::HintEncoding::Rgb11 => v * 2.0 - 1.0,
            };
        }
    }
    out
}

/// `len` standard normal floats from `rng` (Box–Muller on 53-bit uniforms).
pub fn gaussian(rng: &mut ChaCha8Rng, len: usize) -> Vec<f32> {
    let mut out = Vec::with_capacity(len + 1);
    while out.len() < len {
        // u1 in (0, 1] so the log is finite; u2 in [0, 1).
        let u1 = 1.0 - (rng.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64);
        let u2 = (rng.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64);
        let r = (-2.0 * u1.ln()).sqrt();
        let (s, c) = (2.0 * std::f64::consts::PI * u2).sin_cos();
        out.push((r * c) as f32);
        out.push((r * s) as f32);
    }
    out.truncate(len);
    out
}

#[cfg(test)]
mod tests {
    use rand_chacha::rand_core::SeedableRng;

    use super::*;

    #[test]
    fn gaussian_is_seeded_and_standard() {
        let a = gaussian(&mut ChaCha8Rng::seed_from_u64(7), 20_001);
        let b = gaussian(&mut ChaCha8Rng::seed_from_u64(7), 20_001);
        assert_eq!(a, b);
        assert_ne!(a, gaussian(&mut ChaCha8Rng::seed_from_u64(8), 20_001));
        let mean = a.iter().map(|&v| v as f64).sum::<f64>() / a.len() as f64;
        let var = a.iter().map(|&v| (v as f64 - mean).powi(2)).sum::<f64>() / a.len() as f64;
        assert!(mean.abs() < 0.03, "mean {mean}");
        assert!((var - 1.0).abs() < 0.05, "variance {var}");
    }

    #[test]
    fn eight_bit_mapping_matches_diffusers() {
        assert_eq!(to_u8(-1.0), 0);
        assert_eq!(to_u8(1.0), 255);
        assert_eq!(to_u8(0.0), 128); // 127.5: half to even
        assert_eq!(to_u8(-3.0), 0);
        assert_eq!(to_u8(f32::NAN), 0);
    }

    #[test]
    fn min_max_range_stretches_each_image_as_multidiffsense_saves() {
        // One pixel row: min -1, max 3, span 4 (+1e-8, lost in float32).
        let raw = [-1.0, 0.0, 3.0, 1.0, 2.0, 0.5];
        let img = raw_to_rgb8(&raw, 2, 1, ImageRange::MinMax);
        // (x + 1) / 4 * 255 + 0.5, truncated: 0.5 -> 0, 64.25 -> 64, 255.5 -> 255, 128 -> 128
        // (127.5 + 0.5: exact), 191.75 -> 191, 96.125 -> 96.
        assert_eq!(img.as_raw(), &vec![0, 64, 255, 128, 191, 96]);
        // The clamp maps the same values without looking at the others.
        let clamped = raw_to_rgb8(&raw, 2, 1, ImageRange::Clamp);
        assert_eq!(clamped.as_raw(), &vec![0, 128, 255, 255, 255, 191]);
        // A flat image: 0 / 1e-8 = 0 everywhere, as torch gives.
        assert_eq!(raw_to_rgb8(&[0.3; 3], 1, 1, ImageRange::MinMax).as_raw(), &vec![0, 0, 0]);
        // A short slice reads as NaN, which maps to 0 rather than panicking.
        assert_eq!(raw_to_rgb8(&[0.0], 1, 1, ImageRange::Clamp).as_raw(), &vec![128, 0, 0]);
    }

    #[test]
    #[cfg(feature = "synth")]
    fn a_fixed_batch_of_one_runs_guidance_as_one_row_a_call() {
        // Dynamic graphs: [uncond, cond] of 2 images in one call; forced: two calls of 2.
        assert_eq!(rows_per_call(None, false, 4, true).unwrap(), 4);
        assert_eq!(rows_per_call(None, true, 4, true).unwrap(), 2);
        assert_eq!(rows_per_call(None, true, 3, false).unwrap(), 3, "nothing to split without guidance");
        // Graphs fixed at batch 1: every row its own call, guided or not.
        assert_eq!(rows_per_call(Some(1), false, 4, true).unwrap(), 1);
        assert_eq!(rows_per_call(Some(1), false, 1, false).unwrap(), 1);
        assert_eq!(rows_per_call(Some(2), false, 4, true).unwrap(), 2);
        let e = rows_per_call(Some(2), false, 3, false).unwrap_err();
        assert!(e.to_string().contains("fixed batch of 2"), "{e}");
    }

    #[test]
    fn steady_state_is_the_time_past_warm_up_per_image() {
        let t = SynthTiming { load_s: 3.0, warmup_s: 2.0, images: 4, generate_s: 10.0 };
        assert_eq!(t.steady_per_image_s(), Some(2.0));
        assert_eq!(t.line(), "load 3.00 s, warm-up 2.000 s (first step), 2.000 s an image steady state (4 images)");
        assert_eq!(SynthTiming::default().steady_per_image_s(), None);
    }

    #[test]
    fn hint_is_nchw_in_unit_range() {
        let mut img = RgbImage::new(2, 1);
        img.put_pixel(1, 0, image::Rgb([255, 0, 51]));
        let v = encode_hint(&img, (2, 1), super::super::package::HintEncoding::Rgb01);
        assert_eq!(v, vec![0.0, 1.0, 0.0, 0.0, 0.0, 0.2]);
        let v = encode_hint(&img, (2, 1), super::super::package::HintEncoding::Rgb11);
        assert_eq!(v[1], 1.0);
        assert_eq!(v[0], -1.0);
    }
}
