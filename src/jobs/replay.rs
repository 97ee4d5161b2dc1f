//! The replay job: a recorded collection re-run with no hardware. The recording's header is
//! the request it was made from, already resolved ([`setup_of`]); [`run`] opens the replayed
//! hardware ([`ReplayRig`]) and runs the same collection runner as a live run
//! ([`super::collect::run`]), then judges the run against the recording.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use super::collect::{CollectSetup, SensorFeed};
use super::{JobError, Observer};
use crate::collect::CollectSummary;
use crate::dataset::CapturePart;
use crate::record::replay::{ReplayError, ReplayRig};
use crate::record::{RecordingFile, RecordingHeader, Summary};

/// What a replay did.
#[derive(Debug, Clone, PartialEq)]
pub struct ReplayOutcome {
    pub summary: CollectSummary,
    /// Events served and in all.
    pub replayed: usize,
    pub recorded: usize,
    /// The datasets written, one per sensor.
    pub datasets: Vec<PathBuf>,
}

/// The collection a recording was made of, writing new datasets under `out`.
pub fn setup_of(header: &RecordingHeader, out: &Path) -> CollectSetup {
    CollectSetup {
        object: header.object.clone(),
        plan_spec: header.plan_spec.clone(),
        poses: header.plan.clone(),
        profile_name: header.profile.name.clone(),
        work_frame: header.work_frame,
        options: header.collect.clone(),
        out: out.to_path_buf(),
        resume: false,
        disk_budget_bytes: None,
        // A recording from before the capture chain was recorded names no arm.
        arm: header.capture_arm.clone().unwrap_or_else(|| CapturePart::new("arm", "unrecorded", false, None)),
        modbus: header.capture_modbus.clone(),
        fence: crate::fence::Fence::replayed(header.profile.clone()),
        adaptive: None,
    }
}

/// Re-runs the recorded collection into `out` (`<out>/<object>/<sensor>/`) with the real client
/// and job over the recording, read from its file as the events are served (`summary`: the
/// scan that checked the whole file first, [`RecordingFile::scan`]). `stall_after` is the
/// watchdog's patience. Run it on a current-thread runtime (see [`crate::record::replay`]).
pub async fn run(recording: &RecordingFile, summary: &Summary, out: &Path, stall_after: Duration) -> Result<ReplayOutcome, JobError> {
    let h = &recording.header;
    let mut rig = ReplayRig::open(recording, summary, stall_after).await?;
    let setup = setup_of(h, out);
    let feeds: Vec<_> = std::mem::take(&mut rig.cameras)
        .into_iter()
        .zip(&h.sensors)
        .map(|(camera, s)| SensorFeed {
            camera,
            sensor: s.sensor_dir,
            calibration: s.calibration.clone(),
            capture: s.capture.clone().unwrap_or_else(|| CapturePart::new(s.sensor_dir.to_string(), "unrecorded", false, None)),
        })
        .collect();
    let result = super::collect::run(
        &setup,
        &mut rig.arm,
        feeds,
        rig.peripherals.clone(),
        Arc::clone(&rig.clock),
        Observer::hidden(),
        rig.stop_after,
    )
    .await;
    rig.verdict()?;
    let outcome = result.map_err(|e| match e {
        // The replayed job failed the way the recorded one did.
        JobError::Collect(e) => JobError::Replay(ReplayError::Collect(e)),
        e => e,
    })?;
    let (replayed, recorded) = rig.finished()?;
    Ok(ReplayOutcome { summary: outcome.summary, replayed, recorded, datasets: outcome.datasets })
}
