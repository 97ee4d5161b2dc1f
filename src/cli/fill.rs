//! `rig synth --fill-missing`: synthesise every planned pose a dataset lacks; `rig synth
//! --poses-of DATASET --out DIR`: synthesise exactly the real poses of a dataset (its
//! synthetic twin, for `rig eval`).

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use clap::Args;

use crate::synth::fill::{FillOptions, Shard, TwinSize, fill_missing, missing_poses, synthesise_poses_of};
use crate::synth::{ImageRange, Pipeline, RuntimeOptions, SchedulerKind};

/// Fill-missing mode of `rig synth`.
#[derive(Debug, Clone, Args)]
pub struct FillArgs {
    /// Synthesise every pose of the dataset's plan that has no image yet.
    #[arg(long)]
    pub fill_missing: bool,
    /// Synthesise exactly the poses of the real rows of this dataset (or of every dataset under
    /// this folder, two levels deep) into --out, mirroring `<object>/<sensor>`: the synthetic
    /// twin of a test set for `rig eval`. Resumable.
    #[arg(long, value_name = "DATASET", conflicts_with = "fill_missing")]
    pub poses_of: Option<PathBuf>,
    /// A dataset (`.../<object>/<sensor>`) or a folder holding several (searched two levels
    /// deep for manifest.toml).
    #[arg(long, value_name = "DIR", default_value = "datasets")]
    pub dataset: PathBuf,
    /// Model package directory (default: models/default, else the tiny test package).
    #[arg(long, value_name = "DIR")]
    pub model: Option<PathBuf>,
    /// Do only part i of n of the missing poses (pose_id % n == i - 1), written to --out.
    #[arg(long, value_name = "i/n")]
    pub shard: Option<Shard>,
    /// Where the synthetic rows go (required with --shard; default: into the dataset itself).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Sampling steps [default: the package's `sampling_steps`, else 20].
    #[arg(long)]
    pub steps: Option<usize>,
    /// Classifier-free guidance scale (1: unguided, half the work, as MultiDiffSense's scripts
    /// save) [default: the package's `guidance`, else 1].
    #[arg(long)]
    pub guidance: Option<f32>,
    /// DDIM eta (0: deterministic) [default: the package's `eta`, else 0].
    #[arg(long)]
    pub eta: Option<f32>,
    /// Sampler: ddim or dpm++2m [default: the package's `sampler`, else ddim].
    #[arg(long)]
    pub sampler: Option<SchedulerKind>,
    /// ControlNet conditioning scale: how strongly the depth-map hint steers the image (1: as
    /// the model was trained).
    #[arg(long, default_value_t = 1.0)]
    pub conditioning_scale: f32,
    /// Poses per model call.
    #[arg(long, default_value_t = 4)]
    pub batch: usize,
    /// How the model's output becomes 8-bit pixels: `clamp` (x/2 + 0.5 clamped to [0, 1], as
    /// diffusers writes) or `minmax` (each image stretched from its own min to its own max, as
    /// MultiDiffSense's scripts save, for comparing with their outputs).
    #[arg(long, value_enum, default_value_t = ImageRange::Clamp)]
    pub image_range: ImageRange,
    /// Supersampling factor of the control image's depth map.
    #[arg(long, default_value_t = 2)]
    pub supersample: u32,
    /// At most this many poses per dataset (after sharding).
    #[arg(long)]
    pub limit: Option<usize>,
    /// List what would be synthesised; load no model.
    #[arg(long)]
    pub dry_run: bool,
    /// With --poses-of: the twins' image size. `model`: the model's own resolution, untouched
    /// (what `rig eval` should judge: no resampling of the model's output). `source`: resized
    /// to the real frames' size, as `--fill-missing` writes into a dataset.
    #[arg(long, value_enum, default_value_t = TwinSize::Model, requires = "poses_of")]
    pub twin_size: TwinSize,
    /// ONNX Runtime library (libonnxruntime.so) or its folder (default: $RIG_ORT_LIB,
    /// $ORT_DYLIB_PATH, then .rig/onnxruntime/).
    #[arg(long = "fill-ort-lib", value_name = "PATH")]
    pub ort_lib: Option<PathBuf>,
    #[command(flatten)]
    pub daemon: crate::cli::daemon::DaemonTarget,
}

impl FillArgs {
    /// The same fill as a daemon job.
    pub fn job_spec(&self) -> crate::daemon::SynthSpec {
        use crate::cli::collect::absolute;
        crate::daemon::SynthSpec {
            dataset: absolute(&self.dataset),
            model: self.model.as_deref().map(absolute),
            shard: self.shard.map(|s| format!("{}/{}", s.index, s.count)),
            out: self.out.as_deref().map(absolute),
            steps: self.steps,
            guidance: self.guidance,
            eta: self.eta,
            sampler: self.sampler.map(|s| s.to_string()),
            image_range: self.image_range,
            conditioning_scale: self.conditioning_scale,
            batch: self.batch,
            supersample: self.supersample,
            limit: self.limit,
            ort_lib: self.ort_lib.as_deref().map(absolute),
        }
    }
}

pub use crate::synth::fill::{default_model, find_datasets};

/// Runs `rig synth --fill-missing`.
pub fn run(args: FillArgs) -> anyhow::Result<()> {
    if let Some(source) = args.poses_of.clone() {
        if args.daemon.daemon.is_some() {
            bail!(crate::cli::usage("--daemon runs only --fill-missing jobs: run --poses-of without --daemon"));
        }
        return run_poses_of(&source, args);
    }
    if !args.fill_missing {
        bail!(crate::cli::usage(
            "rig synth needs a mode: `rig synth --fill-missing ...`, `rig synth --poses-of DATASET --out DIR`, `rig synth one ...` or `rig synth info ...`"
        ));
    }
    if args.daemon.daemon.is_some() {
        if args.dry_run {
            bail!(crate::cli::usage("--daemon runs the fill on the daemon: drop --dry-run, or run it standalone"));
        }
        return crate::cli::daemon::submit_and_follow(&args.daemon, crate::daemon::JobSpec::Synth(args.job_spec()));
    }
    let shard = args.shard.unwrap_or(Shard::ALL);
    if args.shard.is_some() && args.out.is_none() {
        bail!(crate::cli::usage("--shard needs --out DIR: each shard writes its own dataset, joined by `rig dataset merge`"));
    }
    let datasets = find_datasets(&args.dataset);
    if datasets.is_empty() {
        bail!(crate::cli::usage(&format!(
            "no dataset under {} (a dataset has a manifest.toml; collect one with `rig collect`)",
            args.dataset.display()
        )));
    }
    if args.out.is_some() && datasets.len() > 1 {
        bail!(crate::cli::usage("--out takes one dataset: name it with --dataset .../<object>/<sensor>"));
    }
    if args.dry_run {
        for d in &datasets {
            let work = missing_poses(d, args.out.as_deref(), shard)?;
            println!(
                "{}: {} of {} grid poses present, {} to synthesise in shard {}/{}",
                d.display(),
                work.present,
                work.grid,
                work.todo.len(),
                shard.index,
                shard.count
            );
        }
        return Ok(());
    }
    let mut pipeline = load_pipeline(&args)?;
    let options = fill_options(&args, shard, &pipeline);
    for d in &datasets {
        let progress = progress_bar();
        let t0 = std::time::Instant::now();
        let summary =
            fill_missing(d, args.out.as_deref(), &mut pipeline, &options, &progress).with_context(|| format!("filling {}", d.display()))?;
        progress.finish_and_clear();
        println!(
            "{}: synthesised {} poses in {:.1} s ({} of {} grid poses were present{})",
            args.out.as_deref().unwrap_or(d).display(),
            summary.synthesised,
            t0.elapsed().as_secs_f64(),
            summary.present,
            summary.grid,
            if summary.left > 0 { format!(", {} left to other shards or --limit", summary.left) } else { String::new() }
        );
    }
    Ok(())
}

/// Loads `--model` (or the default), saying which package it is.
fn load_pipeline(args: &FillArgs) -> anyhow::Result<Pipeline> {
    let model = args.model.clone().unwrap_or_else(default_model);
    if model.ends_with("tests/data/tiny-package") {
        println!("model: {} (the tiny test package with random weights: no trained default model is installed)", model.display());
    } else {
        println!("model: {}", model.display());
    }
    let runtime = RuntimeOptions { ort_lib: args.ort_lib.clone(), ..RuntimeOptions::default() };
    Pipeline::load(&model, &runtime).with_context(|| format!("loading model package {}", model.display()))
}

fn fill_options(args: &FillArgs, shard: Shard, pipeline: &Pipeline) -> FillOptions {
    let defaults = FillOptions::default();
    let sampling =
        pipeline.package().config.sampling(args.steps, args.guidance, args.sampler, args.eta, (defaults.steps, defaults.guidance));
    FillOptions {
        steps: sampling.steps,
        guidance: sampling.guidance,
        eta: sampling.eta,
        scheduler: sampling.sampler,
        conditioning_scale: args.conditioning_scale,
        shard,
        batch: args.batch,
        supersample: args.supersample,
        limit: args.limit,
        image_range: args.image_range,
    }
}

fn progress_bar() -> indicatif::ProgressBar {
    let progress = indicatif::ProgressBar::new(0);
    progress.set_style(
        indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} poses  {per_sec}  eta {eta}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    progress
}

/// `rig synth --poses-of SOURCE --out DIR`: every dataset under SOURCE gets its twin at the
/// same relative path under DIR (DIR itself when SOURCE is one dataset).
fn run_poses_of(source: &Path, args: FillArgs) -> anyhow::Result<()> {
    let Some(out) = args.out.clone() else {
        bail!(crate::cli::usage("--poses-of needs --out DIR: where the synthetic twin datasets go"));
    };
    let datasets = find_datasets(source);
    if datasets.is_empty() {
        bail!(crate::cli::usage(&format!(
            "no dataset under {} (a dataset has a manifest.toml; collect one with `rig collect`)",
            source.display()
        )));
    }
    let shard = args.shard.unwrap_or(Shard::ALL);
    let pairs: Vec<(PathBuf, PathBuf)> = datasets
        .iter()
        .map(|d| {
            let rel = d.strip_prefix(source).map(Path::to_path_buf).unwrap_or_default();
            let twin = if rel.as_os_str().is_empty() { out.clone() } else { out.join(rel) };
            (d.clone(), twin)
        })
        .collect();
    if args.dry_run {
        for (d, o) in &pairs {
            let real = crate::dataset::read_rows(d)?.iter().filter(|r| r.source == crate::dataset::Source::Real).count();
            println!("{}: {real} real poses to synthesise into {}", d.display(), o.display());
        }
        return Ok(());
    }
    let mut pipeline = load_pipeline(&args)?;
    let options = fill_options(&args, shard, &pipeline);
    for (d, o) in &pairs {
        let progress = progress_bar();
        let t0 = std::time::Instant::now();
        let summary = synthesise_poses_of(d, o, &mut pipeline, &options, args.twin_size, &progress)
            .with_context(|| format!("synthesising the poses of {}", d.display()))?;
        progress.finish_and_clear();
        println!(
            "{}: synthesised {} poses in {:.1} s ({} real poses in {}, {} were present{})",
            o.display(),
            summary.synthesised,
            t0.elapsed().as_secs_f64(),
            summary.real,
            d.display(),
            summary.present,
            if summary.left > 0 { format!(", {} left to other shards or --limit", summary.left) } else { String::new() }
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use clap::Parser;

    use crate::synth::ImageRange;

    fn parse(extra: &[&str]) -> super::FillArgs {
        let cli = crate::cli::Cli::try_parse_from(["rig", "synth", "--fill-missing"].iter().chain(extra)).expect("parses");
        let crate::cli::Command::Synth(args) = cli.command else { panic!("not rig synth") };
        args.fill
    }

    #[test]
    fn eta_and_image_range_reach_the_daemon_job() {
        let args = parse(&[]);
        assert_eq!((args.eta, args.image_range), (None, ImageRange::Clamp));
        let args = parse(&["--eta", "0.3", "--image-range", "minmax"]);
        assert_eq!((args.eta, args.image_range), (Some(0.3), ImageRange::MinMax));
        let spec = args.job_spec();
        assert_eq!((spec.eta, spec.image_range), (Some(0.3), ImageRange::MinMax));
    }
}
