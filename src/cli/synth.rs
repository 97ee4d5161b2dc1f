//! `rig synth`: synthesise tactile images with a model package.
//!
//! `rig synth one ...` makes one image (for trying a package, or comparing with a Python run);
//! `rig synth info --model DIR` shows what a package holds. Fill-missing mode (`rig synth
//! --fill-missing`) sits on the same [`Args`] as top-level flags beside the subcommand; the
//! integrator wires it on top of [`rig::synth`](crate::synth), the dataset and geometry modules.

use std::path::PathBuf;

use anyhow::{Context, bail};
use clap::{Args as ClapArgs, Subcommand};

use super::shared::{RuntimeArgs, SamplingArgs};
use crate::features::Feature;
use crate::pose::Pose;
use crate::synth::npy::NpyArray;
use crate::synth::package::Sampling;
use crate::synth::{GenerateRequest, ImageRange, Pipeline};

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
    #[command(after_help = crate::cli::examples::SYNTH_ONE)]
    One(Box<OneArgs>),
    /// Show a model package: config, tensors, hash.
    #[command(after_help = crate::cli::examples::SYNTH_INFO)]
    Info(InfoArgs),
    /// Time a package: load, warm-up (first step) and steady state per image, over N images
    /// made in batches as a fill makes them (scripts/gpu-bench-rig.sh runs it per guidance).
    #[command(after_help = crate::cli::examples::SYNTH_BENCH)]
    Bench(Box<BenchArgs>),
}

/// `rig synth bench`.
#[derive(Debug, ClapArgs)]
pub struct BenchArgs {
    /// Model package directory.
    #[arg(long, value_name = "DIR")]
    pub model: PathBuf,
    /// Control (hint) image.
    #[arg(long, value_name = "PNG")]
    pub control: PathBuf,
    #[arg(long)]
    pub prompt: String,
    #[command(flatten)]
    pub sampling: SamplingArgs,
    /// Initial latents for every image, float32 .npy [1, C, H/8, W/8] (default: seeds 0, 1, ...).
    #[arg(long, value_name = "FILE.npy")]
    pub init_latents: Option<PathBuf>,
    /// Images to make.
    #[arg(long, default_value_t = 8)]
    pub images: usize,
    /// Images per model call, as `--fill-missing --batch`.
    #[arg(long, default_value_t = 4)]
    pub batch: usize,
    /// Also print the timing as one JSON object.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub runtime: RuntimeArgs,
}

/// Most images one `rig synth bench` makes.
const MAX_BENCH_IMAGES: usize = 1024;

/// `rig synth one`.
#[derive(Debug, ClapArgs)]
pub struct OneArgs {
    /// Model package directory (model.toml, tokenizer/, text_encoder/, controlnet/, unet/, vae_decoder/, scheduler/);
    /// default: models/default, found as --fill-missing finds it, else the tiny test package.
    #[arg(long, value_name = "DIR")]
    pub model: Option<PathBuf>,
    /// Control (hint) image, e.g. the colour-mapped depth map of the pose.
    #[arg(long, value_name = "PNG")]
    pub control: PathBuf,
    /// Prompt text. Or give --sensor and --pose to build the MultiDiffSense prompt.
    #[arg(long, required_unless_present = "pose", conflicts_with_all = ["sensor", "pose"])]
    pub prompt: Option<String>,
    /// Sensor of the MultiDiffSense prompt: tactip, vitac or vitactip (any case).
    #[arg(long, requires = "pose")]
    pub sensor: Option<crate::sensor::SensorKind>,
    /// Work-frame pose for the MultiDiffSense prompt: x_mm,y_mm,z_mm,yaw_deg.
    #[arg(long, requires = "sensor", allow_hyphen_values = true)]
    pub pose: Option<Pose>,
    /// Text for the unconditional half of classifier-free guidance.
    #[arg(long, default_value = "")]
    pub negative_prompt: String,
    #[command(flatten)]
    pub sampling: SamplingArgs,
    /// Seed of the initial noise.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Initial latents, float32 .npy of shape [1, C, H/8, W/8] (e.g. saved from a Python run).
    #[arg(long, value_name = "FILE.npy")]
    pub init_latents: Option<PathBuf>,
    /// Output size WxH in pixels (default: the package's resolution).
    #[arg(long, value_name = "WxH", value_parser = parse_size)]
    pub size: Option<(u32, u32)>,
    /// Output PNG (8-bit RGB).
    #[arg(long, value_name = "PNG")]
    pub out: PathBuf,
    /// Also write the decoder output before clamping, float32 .npy, NHWC.
    #[arg(long, value_name = "FILE.npy")]
    pub dump_raw: Option<PathBuf>,
    #[command(flatten)]
    pub runtime: RuntimeArgs,
}

/// `rig synth info`.
#[derive(Debug, ClapArgs)]
pub struct InfoArgs {
    /// Model package directory (default: models/default, found as --fill-missing finds it).
    #[arg(long, value_name = "DIR")]
    pub model: Option<PathBuf>,
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
        Some(SynthCommand::One(one)) => {
            Feature::Synth.require("`rig synth one`")?;
            run_one(*one)
        }
        Some(SynthCommand::Info(info)) => {
            Feature::Synth.require("`rig synth info`")?;
            run_info(info)
        }
        Some(SynthCommand::Bench(bench)) => {
            Feature::Synth.require("`rig synth bench`")?;
            run_bench(*bench)
        }
        None => super::fill::run(args.fill),
    }
}

/// The package `--model` names, else the default package as `--fill-missing` finds it; a
/// named folder that does not exist is refused saying so (exit 2).
fn model_dir(given: Option<&std::path::Path>) -> anyhow::Result<PathBuf> {
    let dir = given.map(std::path::Path::to_path_buf).unwrap_or_else(crate::synth::fill::default_model);
    crate::synth::fill::check_model_dir(&dir)?;
    Ok(dir)
}

fn load(model: &std::path::Path, runtime: &RuntimeArgs) -> anyhow::Result<Pipeline> {
    Pipeline::load(model, &runtime.options()).with_context(|| format!("loading model package {}", model.display()))
}

fn run_one(args: OneArgs) -> anyhow::Result<()> {
    let prompt = match (&args.prompt, &args.sensor, &args.pose) {
        (Some(p), _, _) => p.clone(),
        (None, Some(sensor), Some(pose)) => crate::synth::prompt::mds_prompt(*sensor, pose),
        _ => bail!("give --prompt, or --sensor with --pose"),
    };
    // Bounds first: nothing is read, loaded or allocated for settings that mean nothing.
    if let Some(g) = args.sampling.guidance {
        crate::synth::limits::check_guidance(g)?;
    }
    if let Some(eta) = args.sampling.eta {
        crate::synth::limits::check_eta(eta)?;
    }
    crate::synth::limits::check_conditioning_scale(args.sampling.conditioning_scale)?;
    if let Some(size) = args.size {
        crate::synth::limits::check_size("size", size, 1)?;
    }
    super::shared::output_folder_exists("--out", &args.out)?;
    if let Some(path) = &args.dump_raw {
        super::shared::output_folder_exists("--dump-raw", path)?;
    }
    let control = crate::dataset::durable::decode_image(
        &crate::untrusted::read_bytes(&args.control, crate::dataset::durable::MAX_IMAGE_BYTES)
            .with_context(|| format!("reading control image {}", args.control.display()))?,
    )
    .map_err(|reason| crate::synth::SynthError::BadRequest { field: "control", value: args.control.display().to_string(), reason })?;
    let init = match &args.init_latents {
        Some(path) => Some(
            NpyArray::read(path)
                .map_err(crate::synth::SynthError::from)
                .with_context(|| format!("reading initial latents {}", path.display()))?,
        ),
        None => None,
    };
    // The control image must be what the package was conditioned on (its hint_encoding),
    // checked against model.toml before the ONNX models are loaded.
    let model = model_dir(args.model.as_deref())?;
    let config =
        crate::synth::package::ModelPackage::open(&model).with_context(|| format!("loading model package {}", model.display()))?.config;
    let control = crate::synth::hint::control_for(&control, config.hint_encoding, config.control_colour_map, &args.control)?;
    let mut pipeline = load(&model, &args.runtime)?;
    // Without the package's say: 50 steps at guidance 9, as in MultiDiffSense's paper.
    let s = &args.sampling;
    let Sampling { steps, guidance, sampler: scheduler, eta } =
        pipeline.package().config.sampling(s.steps, s.guidance, s.sampler, s.eta, ONE_FALLBACK);
    let request = GenerateRequest {
        control: &control,
        prompt: &prompt,
        negative_prompt: &args.negative_prompt,
        steps,
        guidance,
        eta,
        seed: args.seed,
        scheduler,
        conditioning_scale: s.conditioning_scale,
        init_latents: init.as_ref().map(|a| a.data.as_slice()),
        size: args.size,
        keep_step_latents: false,
    };
    let out = pipeline.generate(&request).context("synthesising the image")?;
    let timing = pipeline.timing();
    out.to_rgb8(s.image_range).save(&args.out).with_context(|| format!("writing {}", args.out.display()))?;
    if let Some(path) = &args.dump_raw {
        out.raw.write(path).with_context(|| format!("writing {}", path.display()))?;
    }
    let (w, h) = out.image.dimensions();
    println!("prompt: {prompt}");
    println!(
        "wrote {} ({w}x{h}) in {:.2} s (+{:.2} s loading): {} steps {}, guidance {}, eta {}, seed {}{}",
        args.out.display(),
        timing.generate_s,
        timing.load_s,
        steps,
        scheduler,
        guidance,
        eta,
        args.seed,
        if s.image_range == ImageRange::Clamp { String::new() } else { format!(", image range {}", s.image_range) }
    );
    if let Some(path) = &args.dump_raw {
        println!("raw decoder output (NHWC float32): {}", path.display());
    }
    println!("timing: {}", timing.line());
    println!(
        "package {} sha256 {}; ONNX Runtime {} ({})",
        pipeline.package().config.name,
        pipeline.package_hash(),
        pipeline.library().display(),
        args.runtime.provider
    );
    Ok(())
}

fn run_bench(args: BenchArgs) -> anyhow::Result<()> {
    if args.images == 0 || args.images > MAX_BENCH_IMAGES {
        bail!(crate::cli::usage(&format!("--images must be 1 to {MAX_BENCH_IMAGES}; got {}", args.images)));
    }
    crate::synth::limits::check_batch(args.batch)?;
    if let Some(g) = args.sampling.guidance {
        crate::synth::limits::check_guidance(g)?;
    }
    if let Some(eta) = args.sampling.eta {
        crate::synth::limits::check_eta(eta)?;
    }
    crate::synth::limits::check_conditioning_scale(args.sampling.conditioning_scale)?;
    let control = crate::dataset::durable::decode_image(
        &crate::untrusted::read_bytes(&args.control, crate::dataset::durable::MAX_IMAGE_BYTES)
            .with_context(|| format!("reading control image {}", args.control.display()))?,
    )
    .map_err(|reason| crate::synth::SynthError::BadRequest { field: "control", value: args.control.display().to_string(), reason })?
    .to_rgb8();
    let init = match &args.init_latents {
        Some(path) => Some(
            NpyArray::read(path)
                .map_err(crate::synth::SynthError::from)
                .with_context(|| format!("reading initial latents {}", path.display()))?,
        ),
        None => None,
    };
    let mut pipeline = load(&model_dir(Some(&args.model))?, &args.runtime)?;
    let s = &args.sampling;
    let Sampling { steps, guidance, sampler, eta } =
        pipeline.package().config.sampling(s.steps, s.guidance, s.sampler, s.eta, ONE_FALLBACK);
    let requests: Vec<GenerateRequest> = (0..args.images)
        .map(|i| GenerateRequest {
            control: &control,
            prompt: &args.prompt,
            negative_prompt: "",
            steps,
            guidance,
            eta,
            seed: i as u64,
            scheduler: sampler,
            conditioning_scale: s.conditioning_scale,
            init_latents: init.as_ref().map(|a| a.data.as_slice()),
            size: None,
            keep_step_latents: false,
        })
        .collect();
    for chunk in requests.chunks(args.batch) {
        pipeline.generate_batch(chunk).context("synthesising")?;
    }
    let t = pipeline.timing();
    let (w, h) = pipeline.resolution();
    println!(
        "{} images {w}x{h} in batches of {}, {steps} steps {sampler}, guidance {guidance}, provider {}: {}",
        args.images,
        args.batch,
        args.runtime.provider,
        t.line()
    );
    println!("guidance     {}", pipeline.guidance_passes());
    if args.json {
        let json = serde_json::json!({
            "model": pipeline.package().dir.display().to_string(),
            "provider": args.runtime.provider.to_string(),
            "size_px": [w, h],
            "steps": steps,
            "guidance": guidance,
            "images": t.images,
            "batch": args.batch,
            "io_binding": pipeline.io_binding(),
            "load_s": t.load_s,
            "warmup_s": t.warmup_s,
            "generate_s": t.generate_s,
            "steady_s_per_image": t.steady_per_image_s(),
        });
        println!("{json}");
    }
    Ok(())
}

fn run_info(args: InfoArgs) -> anyhow::Result<()> {
    let pipeline = load(&model_dir(args.model.as_deref())?, &args.runtime)?;
    let p = pipeline.package();
    let c = &p.config;
    println!("package      {}", p.dir.display());
    println!("name         {}", c.name);
    println!("resolution   {}x{} px (latents /{})", c.width_px, c.height_px, c.vae_scale_factor);
    println!("modalities   {}", c.modalities.join(", "));
    println!(
        "prompt       {} (e.g. {})",
        c.prompt_template,
        crate::synth::prompt::mds_prompt(crate::sensor::SensorKind::ViTac, &Pose::new(0.12, -0.34, 1.5, 15.0))
    );
    println!("latent scale {}", c.latent_scale);
    println!("hint         {:?}", c.hint_encoding);
    println!(
        "control      {}",
        match c.control_colour_map {
            Some(crate::synth::package::ControlColourMap::Viridis) =>
                "the depth map colour-mapped with viridis (a grey control image is refused)",
            None => "any 8-bit RGB or grey image (no control_colour_map declared)",
        }
    );
    let s = &p.schedule.config;
    println!(
        "scheduler    {} betas {}..{} over {} steps, {} spacing, steps_offset {}, set_alpha_to_one {}",
        s.beta_schedule, s.beta_start, s.beta_end, s.num_train_timesteps, s.timestep_spacing, s.steps_offset, s.set_alpha_to_one
    );
    println!("sampling     {}", sampling_line(c));
    println!("sha256       {}", pipeline.package_hash());
    println!("runtime      {} (from {}; provider {})", pipeline.library().display(), pipeline.library_origin(), args.runtime.provider);
    println!("sizes        multiples of {} px, at most {} px a side", pipeline.size_multiple(), crate::synth::limits::MAX_SIDE_PX);
    println!("guidance     {}", pipeline.guidance_passes());
    println!(
        "step tensors {}",
        if pipeline.io_binding() {
            "I/O binding: embeddings and control image bound once a batch, the ControlNet's residuals passed to the UNet on the device, latents copied each step"
        } else {
            "copied in and out of every model call (--no-io-binding)"
        }
    );
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
        let s = &one.sampling;
        assert_eq!(
            (s.steps, s.guidance, s.sampler, one.size),
            (Some(4), None, Some(crate::synth::SchedulerKind::DpmSolverPp2m), Some((64, 64)))
        );
        let one = parse_one(&["--sensor", "ViTac", "--pose", "-1,2,0.5,-30"]).unwrap();
        assert_eq!(one.pose, Some(Pose::new(-1.0, 2.0, 0.5, -30.0)));
        // One vocabulary: any case names the same sensor, so builds the same prompt.
        let lower = parse_one(&["--sensor", "vitac", "--pose", "-1,2,0.5,-30"]).unwrap();
        assert_eq!(lower.sensor, Some(crate::sensor::SensorKind::ViTac));
        assert_eq!(lower.sensor, one.sensor);
        let err = parse_one(&["--sensor", "gelsight", "--pose", "0,0,1,0"]).expect_err("not a sensor");
        assert!(err.to_string().contains("tactip, vitac or vitactip"), "{err}");
        assert!(parse_one(&[]).is_err(), "a prompt or a pose is required");
    }
}
