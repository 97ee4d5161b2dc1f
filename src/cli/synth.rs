//! `rig synth`: synthesise tactile images with a model package.
//!
//! `rig synth one ...` makes one image (for trying a package, or comparing with a Python run);
//! `rig synth info --model DIR` shows what a package holds. Fill-missing mode (`rig synth
//! --fill-missing`) sits on the same [`Args`] as top-level flags beside the subcommand; the
//! integrator wires it on top of [`rig::synth`](crate::synth), the dataset and geometry modules.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, bail};
use clap::{Args as ClapArgs, Subcommand};

use crate::pose::Pose;
use crate::synth::npy::NpyArray;
use crate::synth::package::Sampling;
use crate::synth::{ExecutionProviderKind, GenerateRequest, ImageRange, Pipeline, RuntimeOptions, SchedulerKind};

/// `rig synth` arguments.
#[derive(Debug, ClapArgs)]
#[command(args_conflicts_with_subcommands = true)]
pub struct Args {
    #[command(subcommand)]
    pub command: Option<SynthCommand>,
    #[command(flatten)]
    pub fill: super::fill::FillArgs,
}

/// The `rig synth` modes.
#[derive(Debug, Subcommand)]
pub enum SynthCommand {
    /// Synthesise one image from a control image and a prompt.
    One(Box<OneArgs>),
    /// Show a model package: config, tensors, hash.
    Info(InfoArgs),
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

/// `rig synth one`.
#[derive(Debug, ClapArgs)]
pub struct OneArgs {
    /// Model package directory (model.toml, tokenizer/, text_encoder/, controlnet/, unet/, vae_decoder/, scheduler/).
    #[arg(long, value_name = "DIR")]
    pub model: PathBuf,
    /// Control (hint) image, e.g. the colour-mapped depth map of the pose.
    #[arg(long, value_name = "PNG")]
    pub control: PathBuf,
    /// Prompt text. Or give --sensor and --pose to build the MultiDiffSense prompt.
    #[arg(long, required_unless_present = "pose", conflicts_with_all = ["sensor", "pose"])]
    pub prompt: Option<String>,
    /// Sensor label for the MultiDiffSense prompt (TacTip, ViTac, ViTacTip).
    #[arg(long, requires = "pose")]
    pub sensor: Option<String>,
    /// Work-frame pose for the MultiDiffSense prompt: x_mm,y_mm,z_mm,yaw_deg.
    #[arg(long, requires = "sensor", allow_hyphen_values = true)]
    pub pose: Option<Pose>,
    /// Text for the unconditional half of classifier-free guidance.
    #[arg(long, default_value = "")]
    pub negative_prompt: String,
    /// Sampling steps [default: the package's `sampling_steps`, else 50].
    #[arg(long)]
    pub steps: Option<usize>,
    /// Classifier-free guidance scale (1: no guidance, half the work) [default: the package's
    /// `guidance`, else 9 as in MultiDiffSense's paper].
    #[arg(long)]
    pub guidance: Option<f32>,
    /// DDIM eta (0: deterministic) [default: the package's `eta`, else 0].
    #[arg(long)]
    pub eta: Option<f32>,
    /// Seed of the initial noise.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Sampler: ddim or dpm++2m [default: the package's `sampler`, else ddim].
    #[arg(long)]
    pub scheduler: Option<SchedulerKind>,
    /// ControlNet conditioning scale.
    #[arg(long, default_value_t = 1.0)]
    pub conditioning_scale: f32,
    /// Initial latents, float32 .npy of shape [1, C, H/8, W/8] (e.g. saved from a Python run).
    #[arg(long, value_name = "FILE.npy")]
    pub init_latents: Option<PathBuf>,
    /// Output size WxH in pixels (default: the package's resolution).
    #[arg(long, value_name = "WxH", value_parser = parse_size)]
    pub size: Option<(u32, u32)>,
    /// Output PNG (8-bit RGB).
    #[arg(long, value_name = "PNG")]
    pub out: PathBuf,
    /// How the output becomes 8-bit pixels: `clamp` (x/2 + 0.5 clamped to [0, 1], as diffusers
    /// writes) or `minmax` (stretched from the image's own min to its own max, as
    /// MultiDiffSense's scripts save, for comparing with their outputs). --dump-raw is unaffected.
    #[arg(long, value_enum, default_value_t = ImageRange::Clamp)]
    pub image_range: ImageRange,
    /// Also write the decoder output before clamping, float32 .npy, NHWC.
    #[arg(long, value_name = "FILE.npy")]
    pub dump_raw: Option<PathBuf>,
    #[command(flatten)]
    pub runtime: RuntimeArgs,
}

/// `rig synth info`.
#[derive(Debug, ClapArgs)]
pub struct InfoArgs {
    /// Model package directory.
    #[arg(long, value_name = "DIR")]
    pub model: PathBuf,
    #[command(flatten)]
    pub runtime: RuntimeArgs,
}

fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(|| format!("expected WxH, e.g. 512x512; got {s:?}"))?;
    let w = w.trim().parse::<u32>().map_err(|_| format!("width {w:?} is not a whole number"))?;
    let h = h.trim().parse::<u32>().map_err(|_| format!("height {h:?} is not a whole number"))?;
    Ok((w, h))
}

/// Runs `rig synth`.
pub fn run(args: Args) -> anyhow::Result<()> {
    match args.command {
        Some(SynthCommand::One(one)) => run_one(*one),
        Some(SynthCommand::Info(info)) => run_info(info),
        None => super::fill::run(args.fill),
    }
}

fn load(model: &std::path::Path, runtime: &RuntimeArgs) -> anyhow::Result<Pipeline> {
    Pipeline::load(model, &runtime.options()).with_context(|| format!("loading model package {}", model.display()))
}

fn run_one(args: OneArgs) -> anyhow::Result<()> {
    let prompt = match (&args.prompt, &args.sensor, &args.pose) {
        (Some(p), _, _) => p.clone(),
        (None, Some(sensor), Some(pose)) => crate::synth::prompt::mds_prompt(sensor, pose),
        _ => bail!("give --prompt, or --sensor with --pose"),
    };
    let control = image::open(&args.control).with_context(|| format!("reading control image {}", args.control.display()))?.to_rgb8();
    let init = match &args.init_latents {
        Some(path) => Some(NpyArray::read(path).with_context(|| format!("reading initial latents {}", path.display()))?),
        None => None,
    };
    let t0 = Instant::now();
    let mut pipeline = load(&args.model, &args.runtime)?;
    let load_s = t0.elapsed().as_secs_f64();
    // Without the package's say: 50 steps at guidance 9, as in MultiDiffSense's paper.
    let Sampling { steps, guidance, sampler: scheduler, eta } =
        pipeline.package().config.sampling(args.steps, args.guidance, args.scheduler, args.eta, ONE_FALLBACK);
    let request = GenerateRequest {
        control: &control,
        prompt: &prompt,
        negative_prompt: &args.negative_prompt,
        steps,
        guidance,
        eta,
        seed: args.seed,
        scheduler,
        conditioning_scale: args.conditioning_scale,
        init_latents: init.as_ref().map(|a| a.data.as_slice()),
        size: args.size,
        keep_step_latents: false,
    };
    let t1 = Instant::now();
    let out = pipeline.generate(&request).context("synthesising the image")?;
    let gen_s = t1.elapsed().as_secs_f64();
    out.to_rgb8(args.image_range).save(&args.out).with_context(|| format!("writing {}", args.out.display()))?;
    if let Some(path) = &args.dump_raw {
        out.raw.write(path).with_context(|| format!("writing {}", path.display()))?;
    }
    let (w, h) = out.image.dimensions();
    println!("prompt: {prompt}");
    println!(
        "wrote {} ({w}x{h}) in {gen_s:.2} s (+{load_s:.2} s loading): {} steps {}, guidance {}, eta {}, seed {}{}",
        args.out.display(),
        steps,
        scheduler,
        guidance,
        eta,
        args.seed,
        if args.image_range == ImageRange::Clamp { String::new() } else { format!(", image range {}", args.image_range) }
    );
    if let Some(path) = &args.dump_raw {
        println!("raw decoder output (NHWC float32): {}", path.display());
    }
    println!(
        "package {} sha256 {}; ONNX Runtime {} ({})",
        pipeline.package().config.name,
        pipeline.package_hash(),
        pipeline.library().display(),
        args.runtime.provider
    );
    Ok(())
}

fn run_info(args: InfoArgs) -> anyhow::Result<()> {
    let pipeline = load(&args.model, &args.runtime)?;
    let p = pipeline.package();
    let c = &p.config;
    println!("package      {}", p.dir.display());
    println!("name         {}", c.name);
    println!("resolution   {}x{} px (latents /{})", c.width_px, c.height_px, c.vae_scale_factor);
    println!("modalities   {}", c.modalities.join(", "));
    println!("prompt       {} (e.g. {})", c.prompt_template, crate::synth::prompt::mds_prompt("ViTac", &Pose::new(0.12, -0.34, 1.5, 15.0)));
    println!("latent scale {}", c.latent_scale);
    println!("hint         {:?}", c.hint_encoding);
    let s = &p.schedule.config;
    println!(
        "scheduler    {} betas {}..{} over {} steps, {} spacing, steps_offset {}, set_alpha_to_one {}",
        s.beta_schedule, s.beta_start, s.beta_end, s.num_train_timesteps, s.timestep_spacing, s.steps_offset, s.set_alpha_to_one
    );
    println!("sampling     {}", sampling_line(c));
    println!("sha256       {}", pipeline.package_hash());
    println!("runtime      {} ({})", pipeline.library().display(), args.runtime.provider);
    Ok(())
}

/// `rig synth one`'s steps and guidance when neither the flags nor the package name them (50
/// steps, guidance 9: MultiDiffSense's paper).
const ONE_FALLBACK: (usize, f32) = (50, 9.0);

/// The package's sampling defaults as `rig synth info` prints them: each `model.toml` key, and
/// what rig uses where the package names none.
fn sampling_line(c: &crate::synth::package::ModelConfig) -> String {
    fn key<T: std::fmt::Display>(v: Option<T>) -> String {
        v.map(|v| v.to_string()).unwrap_or_else(|| "unset".to_string())
    }
    let mut line = format!(
        "sampler {}, steps {}, eta {}, guidance {} (model.toml; flags override)",
        key(c.sampler),
        key(c.sampling_steps),
        key(c.eta),
        key(c.guidance)
    );
    if c.sampler.is_none() || c.sampling_steps.is_none() || c.eta.is_none() || c.guidance.is_none() {
        let fill = crate::synth::fill::FillOptions::default();
        line.push_str(&format!(
            "; where unset: ddim, eta 0, and {} steps, guidance {} for rig synth one, {} steps, guidance {} for \
             --fill-missing and --poses-of",
            ONE_FALLBACK.0, ONE_FALLBACK.1, fill.steps, fill.guidance
        ));
    }
    line
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[test]
    fn size_parses() {
        assert_eq!(parse_size("512x256").unwrap(), (512, 256));
        assert!(parse_size("512").is_err());
        assert!(parse_size("ax2").is_err());
    }

    /// `rig synth one --model m --control c.png --out o.png` plus `extra`, parsed.
    fn parse_one(extra: &[&str]) -> Result<OneArgs, clap::Error> {
        let base = ["rig", "synth", "one", "--model", "m", "--control", "c.png", "--out", "o.png"];
        let cli = crate::cli::Cli::try_parse_from(base.iter().chain(extra))?;
        let crate::cli::Command::Synth(Args { command: Some(SynthCommand::One(one)), .. }) = cli.command else { panic!("not synth one") };
        Ok(*one)
    }

    #[test]
    fn one_parses_with_prompt_or_pose() {
        let one = parse_one(&["--prompt", "p", "--steps", "4", "--scheduler", "dpm++2m", "--size", "64x64"]).unwrap();
        assert_eq!((one.steps, one.guidance, one.scheduler, one.size), (Some(4), None, Some(SchedulerKind::DpmSolverPp2m), Some((64, 64))));
        assert_eq!((one.eta, one.image_range), (None, ImageRange::Clamp));
        let one = parse_one(&["--sensor", "ViTac", "--pose", "-1,2,0.5,-30", "--eta", "0.5", "--image-range", "minmax"]).unwrap();
        assert_eq!(one.pose, Some(Pose::new(-1.0, 2.0, 0.5, -30.0)));
        assert_eq!((one.eta, one.image_range), (Some(0.5), ImageRange::MinMax));
        assert!(parse_one(&["--prompt", "p", "--image-range", "stretch"]).is_err());
        assert!(parse_one(&[]).is_err(), "a prompt or a pose is required");
    }
}
