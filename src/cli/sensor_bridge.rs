//! The one place the geometry commands (`render`, `objects contact-sheet`, `compare-real`)
//! reach the tactile-sensor simulator.
//!
//! [`render_tactile`] renders one still frame through `sim::sensor::SensorSim`.

use image::RgbImage;

use crate::calibration::Calibration;
use crate::geometry::DepthMap;
use crate::sensor::SensorKind;
use crate::sim::sensor::{MotionState, Scene, SensorSim, SkinModel};

/// The tactile-sensor simulator could not render.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("cannot render {}: {reason}", sensor.label())]
pub struct SensorUnavailable {
    pub sensor: SensorKind,
    pub reason: String,
}

/// Renders what `sensor` would show for `depth` (calibration `calib`, noise seed `seed`) with
/// the simulator's `full` scene, the arm at rest.
pub fn render_tactile(sensor: SensorKind, depth: &DepthMap, calib: &Calibration, seed: u64) -> Result<RgbImage, SensorUnavailable> {
    let scene = Scene::preset("full").map_err(|e| SensorUnavailable { sensor, reason: e.to_string() })?;
    render_tactile_with(sensor, depth, calib, seed, &scene, None, None)
}

/// As [`render_tactile`], with the stages of `scene` and, when `reference` is given, the
/// sensor's static look taken from it: a measured no-contact frame of the real sensor (same
/// size as `depth`), to which the simulator adds only the contact (see
/// `SensorSim::with_reference`); `skin`, when given, replaces the kind's fitted skin (a fit
/// tries candidates this way).
pub fn render_tactile_with(
    sensor: SensorKind,
    depth: &DepthMap,
    calib: &Calibration,
    seed: u64,
    scene: &Scene,
    reference: Option<&RgbImage>,
    skin: Option<&SkinModel>,
) -> Result<RgbImage, SensorUnavailable> {
    let px_per_mm = ((calib.scale_px_per_mm[0].abs() + calib.scale_px_per_mm[1].abs()) / 2.0) as f32;
    let mut sim = SensorSim::new(sensor, scene.clone(), depth.width, depth.height, px_per_mm, seed);
    if let Some(skin) = skin {
        sim = sim.with_skin(*skin);
    }
    if let Some(r) = reference {
        sim = sim.with_reference(r).map_err(|e| SensorUnavailable { sensor, reason: e.to_string() })?;
    }
    Ok(sim.render(depth, &MotionState::STILL, seed))
}

/// Whether [`render_tactile`] can render in this build (it can since the simulator landed;
/// kept for the commands that still ask).
pub fn simulator_available() -> bool {
    true
}
