//! `rig synth --fill-missing`: synthesise every planned pose a dataset lacks; `rig synth
//! --poses-of DATASET --out DIR`: synthesise exactly the captured poses of a dataset (its
//! synthetic twin, for `rig eval`).

use std::path::PathBuf;

use anyhow::{Context, bail};
use clap::Args;

use super::shared::{RuntimeArgs, SamplingArgs};
use crate::jobs::FillRequest;
use crate::jobs::fill::FillReport;
use crate::jobs::{JobError, JobRequest, Observer};
use crate::synth::Pipeline;
use crate::synth::fill::{Shard, TwinSize};

/// Fill-missing and twins modes of `rig synth`.
#[derive(Debug, Clone, Args)]
pub struct FillArgs {
    /// Synthesise every pose of the dataset's plan that has no image yet.
    #[arg(long)]
    pub fill_missing: bool,
    /// Synthesise exactly the poses of the captured rows (real or simulated; never synthetic
    /// ones) of this dataset (or of every dataset under
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
    #[command(flatten)]
    pub sampling: SamplingArgs,
    /// Poses per model call.
    #[arg(long, default_value_t = 4)]
    pub batch: usize,
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
    #[command(flatten)]
    pub runtime: RuntimeArgs,
    #[command(flatten)]
    pub daemon: crate::cli::daemon::DaemonTarget,
}

impl FillArgs {
    /// The synthesis these arguments ask for.
    pub fn request(&self) -> FillRequest {
        let s = &self.sampling;
        FillRequest {
            dataset: self.dataset.clone(),
            poses_of: self.poses_of.clone(),
            model: self.model.clone(),
            shard: self.shard,
            out: self.out.clone(),
            steps: s.steps,
            guidance: s.guidance,
            eta: s.eta,
            sampler: s.sampler,
            conditioning_scale: s.conditioning_scale,
            image_range: s.image_range,
            batch: self.batch,
            supersample: self.supersample,
            limit: self.limit,
            twin_size: self.twin_size,
        }
    }
}

pub use crate::synth::fill::{default_model, find_datasets};

/// Runs `rig synth --fill-missing` or `rig synth --poses-of`.
pub fn run(args: FillArgs) -> anyhow::Result<()> {
    if args.poses_of.is_none() && !args.fill_missing {
        bail!(crate::cli::usage(
            "rig synth needs a mode: `rig synth --fill-missing ...`, `rig synth --poses-of DATASET --out DIR`, `rig synth one ...` or `rig synth info ...`"
        ));
    }
    let request = args.request();
    if args.daemon.daemon.is_some() && request.twins() {
        bail!(crate::cli::usage("--daemon runs only --fill-missing jobs: run --poses-of without --daemon"));
    }
    if args.daemon.daemon.is_some() {
        if args.dry_run || args.runtime.ort_lib.is_some() {
            bail!(crate::cli::usage(
                "--daemon runs the job on the daemon with its own ONNX Runtime: drop --dry-run and --ort-lib, or run it standalone"
            ));
        }
        use super::shared::absolute;
        let request = FillRequest {
            dataset: absolute(&request.dataset),
            poses_of: request.poses_of.as_deref().map(absolute),
            model: request.model.as_deref().map(absolute),
            out: request.out.as_deref().map(absolute),
            ..request
        };
        return crate::cli::daemon::submit_and_follow(&args.daemon, JobRequest::Synth(request));
    }
    // The daemon and the dry run need no ONNX Runtime here; a local run does.
    if !args.dry_run {
        crate::features::Feature::Synth
            .require("`rig synth --fill-missing` and `--poses-of` run here (`--daemon URL` runs them on a daemon)")?;
    }
    let targets = request.targets().map_err(usage_of)?;
    if args.dry_run {
        for line in request.dry_run()? {
            println!("{line}");
        }
        return Ok(());
    }
    let model = request.model_dir();
    // Said only when rig fell back to it, not when the user named it.
    if request.model.is_none() && model.ends_with("tests/data/tiny-package") {
        println!("model: {} (the tiny test package with random weights: no trained default model is installed)", model.display());
    } else {
        println!("model: {}", model.display());
    }
    crate::synth::fill::check_model_dir(&model)?;
    let mut pipeline =
        Pipeline::load(&model, &args.runtime.options()).with_context(|| format!("loading model package {}", model.display()))?;
    for warning in request.upscale_warnings(&targets, &pipeline) {
        eprintln!("{warning}");
    }
    let progress = super::shared::progress()?;
    let (_, cancel) = tokio::sync::watch::channel(false);
    let observer = Observer { progress: progress.bar().clone(), cancel };
    let mut print = |report: &FillReport| {
        progress.suspend(|| println!("{}", report.line()));
    };
    crate::jobs::fill::run(&request, &targets, &mut pipeline, &observer, &mut |_| {}, &mut print)?;
    progress.finish();
    println!("timing: {}", pipeline.timing().line());
    Ok(())
}

/// An option the request refused is bad input on the command line (exit 2).
fn usage_of(e: JobError) -> anyhow::Error {
    match e {
        JobError::Request(crate::jobs::RequestError::BadOption { reason, .. }) => anyhow::Error::new(crate::cli::usage(&reason)),
        e => anyhow::Error::new(e),
    }
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
    fn eta_and_image_range_reach_the_request_the_daemon_gets() {
        let request = parse(&[]).request();
        assert_eq!((request.eta, request.image_range), (None, ImageRange::Clamp), "left to the package");
        let request = parse(&["--eta", "0.3", "--image-range", "minmax"]).request();
        assert_eq!((request.eta, request.image_range), (Some(0.3), ImageRange::MinMax));
        let json: crate::jobs::JobRequest =
            serde_json::from_str(r#"{"kind": "synth", "eta": 0.3, "image_range": "minmax"}"#).expect("a daemon job");
        let crate::jobs::JobRequest::Synth(job) = json else { panic!("not a synth job") };
        assert_eq!((job.eta, job.image_range), (request.eta, request.image_range));
        assert!(crate::cli::Cli::try_parse_from(["rig", "synth", "--fill-missing", "--image-range", "stretch"]).is_err());
    }
}
