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
}

/// Runs `rig collect`.
pub fn run(args: CollectArgs) -> anyhow::Result<()> {
    if let Some(daemon) = args.rig.daemon("the job", &[("--record", args.record.is_some())])? {
        let mut request = args.request();
        request.stl = request.stl.as_deref().map(absolute);
        request.plan = request.plan.as_deref().map(absolute);
        request.out = absolute(&request.out);
        return crate::cli::daemon::submit_and_follow(daemon, JobRequest::Collect(request));
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
    let mut rig =
        Rig::open_with(&config, &prepared.object, &prepared.sensors, setup.plan_spec.seed, clock.clone(), recorder.clone()).await?;
    if let Some(recorder) = &recorder {
        recorder.begin(&crate::cli::replay::recording_header(
            &config,
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

    let cancel = super::shared::cancel_on_interrupt(
        "finishing the current pose (waiting at most 1 s for it), then retracting and disabling the arm",
    )?;
    let progress = super::shared::progress()?;
    progress.bar().set_prefix(crate::progress::collection_name(&setup.object.name, &prepared.sensors));
    let peripherals = crate::record::RecordingPeripherals::new(std::mem::take(&mut rig.peripherals), recorder.clone());
    let observer = Observer { progress: progress.bar().clone(), cancel };
    let outcome = crate::jobs::collect::run(setup, &mut rig.arm, feeds, peripherals, Arc::clone(&clock), observer, None).await;
    progress.finish();
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
