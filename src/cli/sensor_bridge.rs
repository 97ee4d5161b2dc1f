//! The one place the geometry commands (`render`, `objects contact-sheet`, `compare-real`)
//! reach the tactile-sensor simulator.
//!
//! [`render_tactile`] renders one still frame through `sim::sensor::SensorSim`.
//! [`TactileSensor`] mirrors `sim::sensor::SensorKind` (same names and parsing; it converts
//! into it) with the file-name spellings these commands use.

use std::fmt;
use std::str::FromStr;

use image::RgbImage;

use crate::calibration::Calibration;
use crate::geometry::DepthMap;
use crate::sim::sensor::{MotionState, Scene, SensorKind, SensorSim};

/// The vision-based tactile sensors rig simulates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum TactileSensor {
    TacTip,
    ViTac,
    ViTacTip,
}

impl TactileSensor {
    pub const ALL: [TactileSensor; 3] = [TactileSensor::TacTip, TactileSensor::ViTac, TactileSensor::ViTacTip];

    /// Lower-case name used on the command line and in file names (`tactip`).
    pub fn slug(self) -> &'static str {
        match self {
            TactileSensor::TacTip => "tactip",
            TactileSensor::ViTac => "vitac",
            TactileSensor::ViTacTip => "vitactip",
        }
    }

    /// Name as the MultiDiffSense data spells it (`TacTip`).
    pub fn dataset_name(self) -> &'static str {
        match self {
            TactileSensor::TacTip => "TacTip",
            TactileSensor::ViTac => "ViTac",
            TactileSensor::ViTacTip => "ViTacTip",
        }
    }
}

impl fmt::Display for TactileSensor {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.dataset_name())
    }
}

/// A sensor name that is not one of `tactip|vitac|vitactip`.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("unknown tactile sensor {name:?}; expected tactip, vitac or vitactip")]
pub struct UnknownSensor {
    pub name: String,
}

impl FromStr for TactileSensor {
    type Err = UnknownSensor;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "tactip" => Ok(TactileSensor::TacTip),
            "vitac" => Ok(TactileSensor::ViTac),
            "vitactip" => Ok(TactileSensor::ViTacTip),
            _ => Err(UnknownSensor { name: s.to_string() }),
        }
    }
}

/// The tactile-sensor simulator could not render.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("cannot render {sensor}: {reason}")]
pub struct SensorUnavailable {
    pub sensor: TactileSensor,
    pub reason: String,
}

impl From<TactileSensor> for SensorKind {
    fn from(sensor: TactileSensor) -> Self {
        match sensor {
            TactileSensor::TacTip => SensorKind::TacTip,
            TactileSensor::ViTac => SensorKind::ViTac,
            TactileSensor::ViTacTip => SensorKind::ViTacTip,
        }
    }
}

/// Renders what `sensor` would show for `depth` (calibration `calib`, noise seed `seed`) with
/// the simulator's `full` scene, the arm at rest.
pub fn render_tactile(sensor: TactileSensor, depth: &DepthMap, calib: &Calibration, seed: u64) -> Result<RgbImage, SensorUnavailable> {
    let scene = Scene::preset("full").map_err(|e| SensorUnavailable { sensor, reason: e.to_string() })?;
    render_tactile_with(sensor, depth, calib, seed, &scene, None)
}

/// As [`render_tactile`], with the stages of `scene` and, when `reference` is given, the
/// sensor's static look taken from it: a measured no-contact frame of the real sensor (same
/// size as `depth`), to which the simulator adds only the contact (see
/// `SensorSim::with_reference`).
pub fn render_tactile_with(
    sensor: TactileSensor,
    depth: &DepthMap,
    calib: &Calibration,
    seed: u64,
    scene: &Scene,
    reference: Option<&RgbImage>,
) -> Result<RgbImage, SensorUnavailable> {
    let px_per_mm = ((calib.scale_px_per_mm[0].abs() + calib.scale_px_per_mm[1].abs()) / 2.0) as f32;
    let mut sim = SensorSim::new(sensor.into(), scene.clone(), depth.width, depth.height, px_per_mm, seed);
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
