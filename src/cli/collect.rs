//! `rig collect`: wires the configuration, the plan, the arm, the cameras and the datasets to
//! the collection job.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{Context, bail};
use clap::Args;

use super::shared::absolute;
use crate::config::RigConfig;
use crate::jobs::CollectRequest;
use crate::jobs::collect::SensorFeed;
use crate::jobs::{JobRequest, Observer};
use crate::rigs::Rig;
use crate::sensor::SensorSet;

/// Arguments of `rig collect`.
#[derive(Debug, Args)]
pub struct CollectArgs {
    /// Object name from the object library (`datasets/objects/<name>.stl`).
    #[arg(long, default_value = "sphere")]
    pub object: String,
    /// Object STL file instead of a library name.
    #[arg(long)]
    pub stl: Option<PathBuf>,
    /// Sensor(s) to capture: tactip, vitac, vitactip, a comma-separated list, or all.
    #[arg(long, default_value = "all")]
    pub sensor: SensorSet,
    /// Plan file (TOML); flags below override its fields.
    #[arg(long)]
    pub plan: Option<PathBuf>,
    /// Number of poses to sample from the grid.
    #[arg(long)]
    pub poses: Option<usize>,
    /// Seed of the sampling (and of the simulated sensors' noise).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Output root; datasets go to `<out>/<object>/<sensor>/`.
    #[arg(long, default_value = "datasets")]
    pub out: PathBuf,
    /// Continue a killed run (or start one when none exists).
    #[arg(long)]
    pub resume: bool,
    /// Record every byte exchanged with the arm and every captured frame into FILE, for
    /// `rig replay FILE`.
    #[arg(long, value_name = "FILE")]
    pub record: Option<PathBuf>,
    /// Adaptive collection: press --budget poses of the plan in --rounds rounds, each round
    /// where the model's fill is least trustworthy, then fill the rest with the model
    /// (see the guide, "Adaptive collection").
    #[arg(long, requires = "budget")]
    pub adaptive: bool,
    /// Real presses of an adaptive collection (at most the plan's poses).
    #[arg(long, requires = "adaptive")]
    pub budget: Option<usize>,
    /// Model package of an adaptive collection (default: models/default, else the tiny test package).
    #[arg(long, requires = "adaptive", value_name = "DIR")]
    pub model: Option<PathBuf>,
    /// Rounds an adaptive collection splits its presses over.
    #[arg(long, requires = "adaptive", default_value_t = 4)]
    pub rounds: usize,
    /// Model images per scored pose (the spread over seeds) in an adaptive collection.
    #[arg(long, requires = "adaptive", default_value_t = 4)]
    pub seeds_per_pose: usize,
    /// Sampling steps of the model's images in an adaptive collection (default: the package's).
    #[arg(long, requires = "adaptive")]
    pub steps: Option<usize>,
    #[command(flatten)]
    pub rig: crate::cli::shared::RigTarget,
}

impl CollectArgs {
    /// The collection these arguments ask for.
    pub fn request(&self) -> CollectRequest {
        CollectRequest {
            object: self.object.clone(),
            stl: self.stl.clone(),
            sensor: self.sensor.clone(),
            plan: self.plan.clone(),
            poses: self.poses,
            seed: self.seed,
            out: self.out.clone(),
            resume: self.resume,
        }
    }

    /// The adaptive collection these options ask for, of `collect`.
    pub fn adaptive_request(&self, collect: CollectRequest) -> crate::jobs::AdaptiveRequest {
        crate::jobs::AdaptiveRequest {
            collect,
            budget: self.budget.unwrap_or(0),
            rounds: self.rounds,
            seeds_per_pose: self.seeds_per_pose,
            model: self.model.clone(),
            steps: self.steps,
        }
    }
}

/// Runs `rig collect`.
pub fn run(args: CollectArgs) -> anyhow::Result<()> {
    if let Some(daemon) = args.rig.daemon("the job", &[("--record", args.record.is_some())])? {
        let mut request = args.request();
        request.stl = request.stl.as_deref().map(absolute);
        request.plan = request.plan.as_deref().map(absolute);
        request.out = absolute(&request.out);
        let job = if args.adaptive {
            let mut adaptive = args.adaptive_request(request);
            adaptive.model = adaptive.model.as_deref().map(absolute);
            JobRequest::Adaptive(adaptive)
        } else {
            JobRequest::Collect(request)
        };
        return crate::cli::daemon::submit_and_follow(daemon, job);
    }
    let config = args.rig.rig_config()?;
    println!("{}", config.describe());
    let runtime = tokio::runtime::Runtime::new().context("starting the async runtime")?;
    runtime.block_on(run_async(args, config))
}

async fn run_async(args: CollectArgs, config: RigConfig) -> anyhow::Result<()> {
    if args.record.is_some() && args.resume {
        bail!(crate::cli::usage("--record starts a new dataset; it cannot be combined with --resume"));
    }
    if args.adaptive {
        return run_adaptive(args, config).await;
    }
    let prepared = args.request().prepare(&config)?;
    println!("{}", prepared.plan_line());
    if args.rig.dry_run {
        let setup = &prepared.setup;
        let outputs: Vec<String> = prepared.sensors.0.iter().map(|&k| setup.dataset_dir(k).display().to_string()).collect();
        return super::shared::dry_run(&config, &prepared.object, &prepared.sensors, setup.plan_spec.seed, &prepared.envelope, &outputs)
            .await;
    }

    let clock = crate::rigs::clock_for(&config);
    let recorder = match &args.record {
        Some(path) => {
            Some(crate::record::Recorder::create(path, clock.clone()).with_context(|| format!("creating recording {}", path.display()))?)
        }
        None => None,
    };
    let setup = &prepared.setup;
    let cancel = super::shared::cancel_on_interrupt(
        "finishing the current pose (waiting at most 1 s for it), then retracting and disabling the arm",
    )?;
    let (rig, outcome) = open_and_collect(&config, &prepared, setup, clock, recorder.clone(), cancel).await?;
    // Close the recording even when the run failed: its replay reproduces the failure. An
    // interrupt is recorded as where the job stopped, for the replay to stop there too.
    if let (Some(recorder), Ok(o)) = (&recorder, &outcome)
        && o.summary.interrupted
    {
        recorder.log_interrupt(o.summary.captured as u64);
    }
    if let (Some(recorder), Some(path)) = (&recorder, &args.record) {
        let records = recorder.finish()?;
        println!("recorded {records} events into {}", path.display());
    }
    let outcome = outcome?;
    rig.shutdown().await;
    println!("{}", outcome.line("--resume"));
    if outcome.summary.interrupted {
        bail!(crate::cli::ExitStatus(4));
    }
    Ok(())
}

/// Opens the rig of `config` and runs the collection `setup` on it (the recording header
/// first, when recording); the rig is returned open, for the caller to close after the
/// recording.
async fn open_and_collect(
    config: &RigConfig,
    prepared: &crate::jobs::collect::PreparedCollect,
    setup: &crate::jobs::collect::CollectSetup,
    clock: Arc<dyn crate::clock::Clock>,
    recorder: Option<crate::record::Recorder>,
    cancel: tokio::sync::watch::Receiver<bool>,
) -> anyhow::Result<(Rig, Result<crate::jobs::collect::CollectOutcome, crate::jobs::JobError>)> {
    let mut rig =
        Rig::open_with(config, &prepared.object, &prepared.sensors, setup.plan_spec.seed, clock.clone(), recorder.clone()).await?;
    if let Some(recorder) = &recorder {
        recorder.begin(&crate::cli::replay::recording_header(
            config,
            &prepared.object,
            &rig.cameras,
            &setup.plan_spec,
            &setup.poses,
            &prepared.profile,
        ))?;
    }
    let mut feeds = Vec::new();
    for (index, camera) in rig.cameras.drain(..).enumerate() {
        let index = u8::try_from(index).context("more than 256 sensors")?;
        let (sensor, calibration, capture) = (camera.kind(), camera.calibration_name(), camera.capture_part());
        feeds.push(SensorFeed {
            camera: crate::record::RecordingCamera::new(camera, index, recorder.clone()),
            sensor,
            calibration,
            capture,
        });
    }

    let progress = super::shared::progress()?;
    progress.bar().set_prefix(crate::progress::collection_name(&setup.object.name, &prepared.sensors));
    let peripherals = crate::record::RecordingPeripherals::new(std::mem::take(&mut rig.peripherals), recorder.clone());
    let observer = Observer { progress: progress.bar().clone(), cancel };
    let outcome = crate::jobs::collect::run(setup, &mut rig.arm, feeds, peripherals, Arc::clone(&clock), observer, None).await;
    progress.finish();
    Ok((rig, outcome))
}

/// `rig collect --adaptive`: every round chosen (or replayed from the manifests), recorded and
/// collected on a freshly opened rig, then the rest of the plan's grid filled with the model.
async fn run_adaptive(args: CollectArgs, config: RigConfig) -> anyhow::Result<()> {
    if args.record.is_some() {
        bail!(crate::cli::usage("--record keeps one collection's bytes; an adaptive collection runs several: leave out --record"));
    }
    let request = args.adaptive_request(args.request());
    // The numbers against the plan first: a refusal needs no model.
    let prepared = request.collect.prepare(&config)?;
    println!("{}", prepared.plan_line());
    request.check_plan(prepared.plan.poses.len())?;
    if args.rig.dry_run {
        let setup = &prepared.setup;
        let outputs: Vec<String> = prepared.sensors.0.iter().map(|&k| setup.dataset_dir(k).display().to_string()).collect();
        return super::shared::dry_run(&config, &prepared.object, &prepared.sensors, setup.plan_spec.seed, &prepared.envelope, &outputs)
            .await;
    }
    crate::features::Feature::Synth.require("`rig collect --adaptive` runs the model here")?;
    let model = request.model_dir();
    crate::synth::fill::check_model_dir(&model)?;
    println!("model: {}", model.display());
    let mut pipeline = crate::synth::Pipeline::load(&model, &crate::synth::RuntimeOptions::default())
        .with_context(|| format!("loading model package {}", model.display()))?;
    let mut run = request.prepare(&config, &pipeline)?;
    let clock = crate::rigs::clock_for(&config);
    // One listener for the whole run: an interrupt while the model chooses stops after its
    // current call (the round is chosen again on resume), one while pressing stops as a plain
    // collection does.
    let cancel = super::shared::cancel_on_interrupt(
        "finishing the current pose (waiting at most 1 s for it), then retracting and disabling the arm; an adaptive collection choosing a round stops after the model's current call",
    )?;
    let interrupted = || {
        println!("interrupted: continue with --resume (the rounds recorded are pressed as recorded)");
        crate::cli::ExitStatus(4)
    };
    while let Some(round) = run.next_round(&mut pipeline, &|| *cancel.borrow())? {
        println!("{}", round.line(run.record.settings.rounds));
        if *cancel.borrow() {
            bail!(interrupted());
        }
        let (rig, outcome) = open_and_collect(&config, &run.prepared, &round.setup, clock.clone(), None, cancel.clone()).await?;
        let outcome = outcome?;
        rig.shutdown().await;
        if outcome.summary.interrupted || *cancel.borrow() {
            bail!(interrupted());
        }
    }
    if *cancel.borrow() {
        // Stopped while the model chose a round: nothing of it was recorded.
        bail!(interrupted());
    }
    let progress = super::shared::progress()?;
    let observer = Observer { progress: progress.bar().clone(), cancel };
    for fill in run.fill_requests() {
        let targets = fill.targets()?;
        let mut print = |report: &crate::jobs::fill::FillReport| progress.suspend(|| println!("{}", report.line()));
        if crate::jobs::fill::run(&fill, &targets, &mut pipeline, &observer, &mut |_| {}, &mut print)?.cancelled {
            progress.finish();
            bail!(interrupted());
        }
    }
    progress.finish();
    println!(
        "adaptive collection: {} poses pressed in {} rounds into {}, the rest filled with {}",
        run.record.choices.len(),
        run.record.settings.rounds,
        run.prepared.setup.out.join(&run.prepared.setup.object.name).display(),
        run.record.settings.model
    );
    Ok(())
}
