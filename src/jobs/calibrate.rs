//! The automatic calibration job: [`CalibrateRequest`] (what `rig calibrate` and a daemon
//! `calibrate` job are asked) and its runner: [`press_and_fit`] presses the indenter at every
//! offset of a pattern and fits the pixel-to-mm map; [`run`] does that for a request and saves
//! the result. `rig bench` calls [`press_and_fit`] with its own patterns and saves nothing.

use std::ops::ControlFlow;
use std::path::PathBuf;

use super::{CalibrateRequest, JobError, Observer};
use crate::arm::Arm;
use crate::arm::profile::FirmwareProfile;
use crate::calibration::detect::ContactDetector;
use crate::calibration::fit::{FitOptions, PointFit};
use crate::calibration::press::{ArmStation, Press, PressError, PressPattern, run_pattern};
use crate::camera::Camera;
use crate::config::RigConfig;
use crate::fence::{Envelope, Fence, PoseSource};
use crate::sensor::SensorKind;

impl CalibrateRequest {
    /// The press pattern, checked against the fence of `config`'s arm and the sensor's press
    /// limit (nothing moves for a press outside the workspace or past the limit), and what it
    /// visits.
    pub fn prepare(&self, config: &RigConfig) -> Result<(PressPattern, Envelope), JobError> {
        self.check()?;
        let pattern = PressPattern::grid(self.grid, self.span_mm, &self.depths_mm);
        let envelope = fence(config, self.sensor)?.check_offsets(&config.work_frame, &pattern.offsets)?;
        Ok((pattern, envelope))
    }

    /// `pattern: N presses, ...`, as `rig calibrate` prints it.
    pub fn pattern_line(&self, pattern: &PressPattern) -> String {
        format!(
            "pattern: {} presses, {}x{} grid over ±{} mm, extra depths {:?} mm",
            pattern.offsets.len(),
            self.grid.max(2),
            self.grid.max(2),
            self.span_mm,
            self.depths_mm
        )
    }
}

/// The fence of a calibration of `sensor` on `config`'s arm: its workspace and the sensor's
/// press limit.
pub fn fence(config: &RigConfig, sensor: SensorKind) -> Result<Fence, JobError> {
    let profile = FirmwareProfile::named(config.arm.profile.as_deref())?;
    Ok(Fence::for_run(profile, config, &[sensor], PoseSource::Presses))
}

/// How a press run ended when it did not fail.
#[derive(Debug, Clone)]
pub enum PressOutcome {
    /// Every press done and fitted; the calibration's image size is the reference frame's.
    Fitted { presses: Vec<Press>, fit: Box<PointFit> },
    /// Stopped by the observer after `done` of `total` presses; the arm is retracted.
    Cancelled { done: usize, total: usize },
}

/// Presses the indenter at every offset of `pattern` with `sensor`'s `camera`, then fits; the
/// pattern passes the fence of `sensor` first ([`fence`]), so nothing moves for a press outside
/// the workspace or past the press limit. The arm is left disabled (retracted above the origin
/// when the run got that far). `on_press` sees every press; the observer counts them and its
/// cancel stops between presses.
#[allow(clippy::too_many_arguments, reason = "the hardware, the job and its observers, each needed")]
pub async fn press_and_fit<A: Arm, C: Camera>(
    arm: &mut A,
    camera: C,
    sensor: SensorKind,
    config: &RigConfig,
    pattern: &PressPattern,
    observer: &Observer,
    on_press: &mut (dyn FnMut(usize, &Press) + Send),
) -> Result<PressOutcome, JobError> {
    let size = config.sensors.iter().find(|s| s.name == sensor.name()).map_or([512, 512], |s| [s.width, s.height]);
    let fence = fence(config, sensor)?;
    let detector = ContactDetector::for_sensor(sensor, size[0]);
    let mut station = ArmStation::new(arm, camera, config.work_frame, config.collect.clone(), detector, fence);
    let fit_options = FitOptions { image_size: size, ..FitOptions::default() };
    observer.progress.set_length(pattern.offsets.len() as u64);
    let run = run_pattern(&mut station, pattern, &fit_options, |k, press| {
        on_press(k, press);
        observer.progress.inc(1);
        if observer.cancelled() { ControlFlow::Break(()) } else { ControlFlow::Continue(()) }
    })
    .await;
    // The pattern ends in contact-free air; a failed run may not: leave the arm disabled.
    let disabled = station.arm.disable().await.map_err(PressError::from);
    let run = match run {
        Err(PressError::Cancelled { done, total }) => {
            disabled?;
            return Ok(PressOutcome::Cancelled { done, total });
        }
        run => run?,
    };
    disabled?;
    let mut fit = run.fit;
    if let Some(reference) = &station.reference {
        fit.calibration.image_size = [reference.width(), reference.height()];
    }
    Ok(PressOutcome::Fitted { presses: run.presses, fit: Box::new(fit) })
}

/// How a calibration job ended when it did not fail.
#[derive(Debug, Clone)]
pub enum CalibrateOutcome {
    Saved { path: PathBuf, fit: Box<PointFit> },
    Cancelled { path: PathBuf, done: usize, total: usize },
}

impl CalibrateOutcome {
    /// A daemon job's message.
    pub fn line(&self) -> String {
        match self {
            CalibrateOutcome::Saved { path, fit } => format!("saved {}; {}", path.display(), fit.residual_line()),
            CalibrateOutcome::Cancelled { path, done, total } => {
                format!("cancelled after {done} of {total} presses; no calibration saved ({} untouched)", path.display())
            }
        }
    }
}

/// Runs `request` (its `pattern` from [`CalibrateRequest::prepare`]) on `arm` and `camera` and
/// saves the calibration; a cancelled run saves nothing.
pub async fn run<A: Arm, C: Camera>(
    request: &CalibrateRequest,
    pattern: &PressPattern,
    arm: &mut A,
    camera: C,
    config: &RigConfig,
    observer: &Observer,
    on_press: &mut (dyn FnMut(usize, &Press) + Send),
) -> Result<CalibrateOutcome, JobError> {
    let path = request.out_path();
    match press_and_fit(arm, camera, request.sensor, config, pattern, observer, on_press).await? {
        PressOutcome::Cancelled { done, total } => Ok(CalibrateOutcome::Cancelled { path, done, total }),
        PressOutcome::Fitted { fit, .. } => {
            save(&fit, &path)?;
            Ok(CalibrateOutcome::Saved { path, fit })
        }
    }
}

/// Saves a fitted calibration to `path`, creating its folder.
pub fn save(fit: &PointFit, path: &std::path::Path) -> Result<(), JobError> {
    let failed = |reason: String| JobError::SaveCalibration { path: path.to_path_buf(), reason };
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| failed(e.to_string()))?;
    }
    fit.calibration.save(path).map_err(|e| failed(e.to_string()))
}
