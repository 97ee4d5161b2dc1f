//! `rig collect`: wires the configuration, the plan, the arm, the cameras and the datasets to
//! the collection job.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{Context, bail};
use clap::Args;

use crate::collect::{CollectJob, SensorStream, check_plan};
use crate::config::RigConfig;
use crate::dataset::{DatasetWriter, Manifest, ObjectInfo};
use crate::plan::PlanSpec;
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
    /// Sensor(s) to capture: tactip, vitac, vitactip or all.
    #[arg(long, default_value = "all")]
    pub sensor: String,
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
    /// Rig configuration file (default: $RIG_CONFIG, then ./rig.toml, else the simulated rig).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Print the plan and check it against the workspace, move nothing.
    #[arg(long)]
    pub dry_run: bool,
    /// Record every byte exchanged with the arm and every captured frame into FILE, for
    /// `rig replay FILE`.
    #[arg(long, value_name = "FILE")]
    pub record: Option<PathBuf>,
    #[command(flatten)]
    pub daemon: crate::cli::daemon::DaemonTarget,
}

impl CollectArgs {
    /// The same collection as a daemon job.
    pub fn job_spec(&self) -> crate::daemon::CollectSpec {
        crate::daemon::CollectSpec {
            object: self.object.clone(),
            stl: self.stl.as_deref().map(absolute),
            sensor: self.sensor.clone(),
            plan: self.plan.as_deref().map(absolute),
            poses: self.poses,
            seed: self.seed,
            out: absolute(&self.out),
            resume: self.resume,
        }
    }
}

/// `path` from this directory, for a daemon that may run in another.
pub fn absolute(path: &std::path::Path) -> PathBuf {
    std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf())
}

/// Runs `rig collect`.
pub fn run(args: CollectArgs) -> anyhow::Result<()> {
    if args.daemon.daemon.is_some() {
        if args.dry_run || args.record.is_some() || args.config.is_some() {
            bail!(crate::cli::usage(
                "--daemon runs the job on the daemon's rig: --dry-run, --record and --config apply to a standalone run only"
            ));
        }
        return crate::cli::daemon::submit_and_follow(&args.daemon, crate::daemon::JobSpec::Collect(args.job_spec()));
    }
    let config = RigConfig::discover(args.config.as_deref())?;
    println!("{}", config.describe());
    let runtime = tokio::runtime::Runtime::new().context("starting the async runtime")?;
    runtime.block_on(run_async(args, config))
}

async fn run_async(args: CollectArgs, config: RigConfig) -> anyhow::Result<()> {
    let mut spec = match &args.plan {
        Some(p) => PlanSpec::load(p).with_context(|| format!("reading plan {}", p.display()))?,
        None => PlanSpec::default(),
    };
    if let Some(n) = args.poses {
        spec.n_poses = Some(n);
    }
    if let Some(s) = args.seed {
        spec.seed = s;
    }
    spec.validate().context("checking the plan")?;
    let sensors: SensorSet = args.sensor.parse()?;
    let object = crate::geometry::objects::ObjectChoice::resolve(&args.object, args.stl.as_deref())?;

    let profile = crate::rigs::profile_for(&config)?;
    let plan = spec.build(&|a, b| profile.pose_cost_s(&config.work_frame, a, b)).context("building the plan")?;
    println!(
        "plan: {} poses of a {}-point grid; motion time {:.1} s as sampled, {:.1} s in rig's order",
        plan.poses.len(),
        spec.grid_len(),
        plan.motion_time_before_s,
        plan.motion_time_after_s
    );
    check_plan(&plan.poses, &config.work_frame, |p| profile.check_reachable(p))?;
    if args.dry_run {
        println!("dry run: plan checked against the workspace, nothing moved");
        return Ok(());
    }

    let clock = crate::rigs::clock_for(&config);
    let recorder = match &args.record {
        Some(_) if args.resume => {
            bail!(crate::cli::usage("--record starts a new dataset; it cannot be combined with --resume"))
        }
        Some(path) => {
            Some(crate::record::Recorder::create(path, clock.clone()).with_context(|| format!("creating recording {}", path.display()))?)
        }
        None => None,
    };
    let mut rig = Rig::open_with(&config, &object, &sensors, spec.seed, clock.clone(), recorder.clone()).await?;
    if let Some(recorder) = &recorder {
        recorder.begin(&crate::cli::replay::recording_header(&config, &object, &rig.cameras, &spec, &plan.poses, &profile))?;
    }
    let mut streams = Vec::new();
    for (index, camera) in rig.cameras.drain(..).enumerate() {
        let dir = args.out.join(&object.name).join(camera.sensor_dir());
        let object_info = ObjectInfo {
            name: object.name.clone(),
            stl_path: object.path.as_ref().map(|p| p.display().to_string()),
            stl_sha256: Some(object.sha256.clone()),
        };
        let mut manifest = Manifest::new(camera.kind(), object_info, Some(spec.clone()));
        manifest.calibration = Some(camera.calibration_name());
        manifest.firmware_profile = Some(profile.name.clone());
        manifest.work_frame = Some(config.work_frame);
        let writer = if args.resume { DatasetWriter::resume(&dir, manifest) } else { DatasetWriter::create(&dir, manifest) }
            .with_context(|| format!("opening dataset {}", dir.display()))?
            .with_byte_budget(config.faults.disk_budget_bytes);
        let index = u8::try_from(index).context("more than 256 sensors")?;
        streams.push(SensorStream { camera: crate::record::RecordingCamera::new(camera, index, recorder.clone()), writer });
    }

    let cancel_rx = super::cancel_on_interrupt("finishing the current pose, then retracting and disabling the arm")?;
    let progress = indicatif::ProgressBar::new(plan.poses.len() as u64);
    progress.set_style(
        indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} poses  {per_sec}  eta {eta}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let job = CollectJob {
        arm: &mut rig.arm,
        sensors: streams,
        work_frame: config.work_frame,
        options: config.collect.clone(),
        clock: Arc::clone(&clock),
        cancel: cancel_rx,
        stop_after: None,
        progress,
        peripherals: crate::record::RecordingPeripherals::new(std::mem::take(&mut rig.peripherals), recorder.clone()),
    };
    let summary = job.run(&plan.poses).await;
    // Close the recording even when the run failed: its replay reproduces the failure. An
    // interrupt is recorded as where the job stopped, for the replay to stop there too.
    if let (Some(recorder), Ok(s)) = (&recorder, &summary)
        && s.interrupted
    {
        recorder.log_interrupt(s.captured as u64);
    }
    if let (Some(recorder), Some(path)) = (&recorder, &args.record) {
        let records = recorder.finish()?;
        println!("recorded {records} events into {}", path.display());
    }
    let summary = summary?;
    rig.shutdown().await;
    if summary.interrupted {
        println!("interrupted: {} poses captured, {} left; continue with --resume", summary.captured, summary.remaining);
        bail!(crate::cli::ExitStatus(4));
    }
    println!(
        "collected {} poses ({} already present, {} arm or camera faults recovered) into {}",
        summary.captured,
        summary.skipped,
        summary.recovered_faults,
        args.out.join(&object.name).display()
    );
    Ok(())
}
