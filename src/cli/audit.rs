//! `rig audit`: collect a seeded share of a dataset's synthesised poses again on the rig and
//! judge the synthesised images against the captured ones (see [`crate::jobs::audit`]).

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{Context, bail};
use clap::Args as ClapArgs;

use super::shared::absolute;
use crate::config::RigConfig;
use crate::jobs::collect::SensorFeed;
use crate::jobs::{AuditRequest, JobRequest, Observer};
use crate::rigs::Rig;
use crate::sensor::SensorSet;

/// `rig audit` arguments.
#[derive(Debug, ClapArgs)]
pub struct Args {
    /// The dataset (`<out>/<object>/<sensor>`) whose synthesised rows are audited; the audit
    /// goes to `DIR/audit/`.
    #[arg(long, value_name = "DIR")]
    pub dataset: PathBuf,
    /// Share of the synthesised poses to collect again (above 0, at most 1; at least one pose).
    #[arg(long, default_value_t = 0.1)]
    pub fraction: f64,
    /// Seed of the draw.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Exit 1 when the mean contact-region SSIM (RGB) is below this bound.
    #[arg(long, value_name = "X", allow_negative_numbers = true)]
    pub min_ssim: Option<f64>,
    /// The object's STL file, when the dataset's object is not in the object library.
    #[arg(long)]
    pub stl: Option<PathBuf>,
    /// Every image is resized to N x N px before it is measured (128: the default model's).
    #[arg(long, value_name = "N", default_value_t = 128)]
    pub size: u32,
    #[command(flatten)]
    pub rig: crate::cli::shared::RigTarget,
}

impl Args {
    /// The audit these arguments ask for.
    pub fn request(&self) -> AuditRequest {
        AuditRequest {
            dataset: self.dataset.clone(),
            fraction: self.fraction,
            seed: self.seed,
            min_ssim: self.min_ssim,
            stl: self.stl.clone(),
            size_px: self.size,
        }
    }
}

/// Runs `rig audit`.
pub fn run(args: Args) -> anyhow::Result<()> {
    if let Some(daemon) = args.rig.daemon("the job", &[])? {
        let mut request = args.request();
        request.dataset = absolute(&request.dataset);
        request.stl = request.stl.as_deref().map(absolute);
        return crate::cli::daemon::submit_and_follow(daemon, JobRequest::Audit(request));
    }
    if !args.dataset.is_dir() {
        bail!(crate::cli::usage(&format!("--dataset {}: no such directory", args.dataset.display())));
    }
    let config = args.rig.rig_config()?;
    println!("{}", config.describe());
    let runtime = tokio::runtime::Runtime::new().context("starting the async runtime")?;
    runtime.block_on(run_async(args, config))
}

async fn run_async(args: Args, config: RigConfig) -> anyhow::Result<()> {
    let prepared = args.request().prepare(&config)?;
    println!("{}", prepared.plan_line());
    if args.rig.dry_run {
        let outputs = [
            prepared.audit_dataset().display().to_string(),
            prepared.audit_root().join(crate::jobs::audit::REPORT_FILE).display().to_string(),
        ];
        let sensors = SensorSet::one(prepared.sensor);
        let seed = prepared.setup.plan_spec.seed;
        return super::shared::dry_run(&config, &prepared.object, &sensors, seed, &prepared.envelope, &outputs).await;
    }
    let clock = crate::rigs::clock_for(&config);
    let sensors = SensorSet::one(prepared.sensor);
    let mut rig = Rig::open_with(&config, &prepared.object, &sensors, prepared.setup.plan_spec.seed, clock.clone(), None).await?;
    let feeds: Vec<SensorFeed<_>> = rig
        .cameras
        .drain(..)
        .map(|camera| {
            let (sensor, calibration, capture) = (camera.kind(), camera.calibration_name(), camera.capture_part());
            SensorFeed { camera, sensor, calibration, capture }
        })
        .collect();
    let cancel = super::shared::cancel_on_interrupt(
        "finishing the current pose (waiting at most 1 s for it), then retracting and disabling the arm",
    )?;
    let progress = super::shared::progress()?;
    progress.bar().set_prefix(format!("{} audit", crate::progress::dataset_name(&prepared.request.dataset)));
    let peripherals = std::mem::take(&mut rig.peripherals);
    let observer = Observer { progress: progress.bar().clone(), cancel };
    let outcome = crate::jobs::audit::run(&prepared, &mut rig.arm, feeds, peripherals, Arc::clone(&clock), observer).await;
    progress.finish();
    rig.shutdown().await;
    let outcome = outcome?;
    println!("{}", outcome.collected.line("the same rig audit command"));
    let Some(scored) = outcome.scored else { bail!(crate::cli::ExitStatus(4)) };
    println!("\n{}", scored.scores.totals_markdown());
    for line in scored.summary.lines() {
        println!("{line}");
    }
    println!("report: {}", scored.report.display());
    if let Some(panel) = &scored.panel {
        println!("worst poses: {}", panel.display());
    }
    println!("{}", scored.verdict);
    if scored.passed == Some(false) {
        eprintln!(
            "error: mean contact SSIM {} is below --min-ssim {}",
            scored.summary.contact_ssim.map_or("n/a".to_string(), |f| format!("{:.3}", f.mean)),
            args.min_ssim.unwrap_or_default()
        );
        bail!(crate::cli::ExitStatus(1));
    }
    Ok(())
}
