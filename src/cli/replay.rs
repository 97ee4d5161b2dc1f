//! `rig replay FILE [--out DIR]`: re-runs a recorded collection against its recording, with
//! no hardware, and writes the dataset again. `rig replay FILE --info` says what the
//! recording holds instead.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Context, bail};

use crate::arm::profile::FirmwareProfile;
use crate::camera::Camera;
use crate::config::RigConfig;
use crate::dataset::ObjectInfo;
use crate::geometry::objects::ObjectChoice;
use crate::jobs::JobError;
use crate::plan::{PlanSpec, PlannedPose};
use crate::record::replay::ReplayError;
use crate::record::{RecordedSensor, RecordingFile, RecordingHeader};
use crate::rigs::RigCamera;

/// Arguments of `rig replay`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The recording (`rig collect --record FILE`).
    pub file: PathBuf,
    /// Output root; datasets go to `<out>/<object>/<sensor>/` (must not hold them yet).
    #[arg(long, default_value = "datasets-replay")]
    pub out: PathBuf,
    /// Seconds without progress after which the replay is declared stuck.
    #[arg(long, default_value_t = 10.0)]
    pub stall_s: f64,
    /// Say what the recording holds (header and counted events) instead of replaying it.
    #[arg(long)]
    pub info: bool,
}

/// Runs `rig replay`.
pub fn run(args: Args) -> anyhow::Result<()> {
    // The header, then a scan of every record (checksums, frame sizes, the end record), one
    // record at a time, before anything is replayed or written.
    let opened = RecordingFile::open(&args.file).and_then(|file| file.scan().map(|summary| (file, summary)));
    let (recording, summary) = match opened {
        Ok(r) => r,
        // A file that is not a whole recording is bad input (exit 2).
        Err(e) if e.is_bad_input() => bail!(crate::cli::UsageError(e.to_string())),
        Err(e) => return Err(e.into()),
    };
    let h = &recording.header;
    if args.info {
        println!("{}: recorded by rig {}: {}", args.file.display(), h.rig_version, h.command_line.join(" "));
        println!(
            "object {}, sensors {}, {} planned poses (seed {}), firmware profile {}",
            h.object.name,
            h.sensors.iter().map(|s| s.sensor_dir.name()).collect::<Vec<_>>().join(", "),
            h.plan.len(),
            h.seed,
            h.profile.name
        );
        println!("{summary}");
        return Ok(());
    }
    println!("replaying {} ({} events, rig {}): {}", args.file.display(), summary.events, h.rig_version, h.command_line.join(" "));
    if !(args.stall_s.is_finite() && args.stall_s > 0.0) {
        bail!(crate::cli::usage("--stall-s must be a positive number of seconds"));
    }
    // One thread: the client's feedback reader and the job interleave only where the
    // recording says (see `record::replay`).
    let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build().context("starting the async runtime")?;
    let outcome = runtime.block_on(crate::jobs::replay::run(&recording, &summary, &args.out, Duration::from_secs_f64(args.stall_s)));
    match outcome {
        Ok(o) => {
            println!(
                "replayed {} of {} recorded events: {} poses captured into {}{}",
                o.replayed,
                o.recorded,
                o.summary.captured,
                args.out.join(&h.object.name).display(),
                if o.summary.interrupted {
                    format!(", then stopped where the recorded run was interrupted ({} poses left)", o.summary.remaining)
                } else {
                    String::new()
                }
            );
            Ok(())
        }
        Err(JobError::Replay(e @ (ReplayError::Diverged(_) | ReplayError::PeripheralsDiverged(_)))) => {
            eprintln!("error: {e}");
            bail!(crate::cli::ExitStatus(3))
        }
        Err(e) => Err(e).context("replaying the collection"),
    }
}

/// The header `rig collect --record` writes: what the replay needs to run the same job.
pub(crate) fn recording_header(
    config: &RigConfig,
    object: &ObjectChoice,
    cameras: &[RigCamera],
    spec: &PlanSpec,
    plan: &[PlannedPose],
    profile: &FirmwareProfile,
) -> RecordingHeader {
    RecordingHeader {
        rig_version: crate::version().to_string(),
        command_line: std::env::args().collect(),
        config_source: config.source.as_ref().map(|p| p.display().to_string()),
        object: ObjectInfo {
            name: object.name.clone(),
            stl_path: object.path.as_ref().map(|p| p.display().to_string()),
            stl_sha256: Some(object.sha256.clone()),
        },
        sensors: cameras
            .iter()
            .map(|c| RecordedSensor {
                camera: c.name().to_string(),
                sensor_dir: c.kind(),
                calibration: c.calibration_name(),
                capture: Some(c.capture_part()),
            })
            .collect(),
        seed: spec.seed,
        plan_spec: spec.clone(),
        plan: plan.to_vec(),
        work_frame: config.work_frame,
        collect: config.collect.clone(),
        profile: profile.clone(),
        speed_factor_pct: config.arm.speed_factor,
        capture_arm: Some(crate::jobs::collect::arm_part(config, profile)),
        capture_modbus: crate::jobs::collect::modbus_parts(config),
    }
}
