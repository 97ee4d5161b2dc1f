//! The one place the geometry commands (`render`, `objects contact-sheet`, `compare-real`)
//! reach the tactile-sensor simulator.
//!
//! The simulator (`sim::sensor`) is built on another branch; until it is merged,
//! [`render_tactile`] answers [`SensorUnavailable`] and the commands say so. At merge time only
//! the body of [`render_tactile`] (and [`simulator_available`]) changes; with the sensor
//! branch's API as of this writing that is:
//!
//! ```text
//! let kind = match sensor { TacTip => SensorKind::TacTip, ViTac => SensorKind::ViTac, ViTacTip => SensorKind::ViTacTip };
//! let scene = Scene::preset("full")?;   // map SceneError into the error type
//! let px_per_mm = ((calib.scale_px_per_mm[0].abs() + calib.scale_px_per_mm[1].abs()) / 2.0) as f32;
//! let sim = SensorSim::new(kind, scene, depth.width, depth.height, px_per_mm, seed);
//! Ok(sim.render(depth, &MotionState::STILL, seed))
//! ```
//!
//! [`TactileSensor`] mirrors `sim::sensor::SensorKind` (same names and parsing) and can be
//! replaced by it then.

use std::fmt;
use std::str::FromStr;

use image::RgbImage;

use crate::calibration::Calibration;
use crate::geometry::DepthMap;

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

/// The tactile-sensor simulator is not part of this build.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("sensor simulator not available in this build (cannot render {sensor}); depth and control work")]
pub struct SensorUnavailable {
    pub sensor: TactileSensor,
}

/// Renders what `sensor` would show for `depth` (calibration `calib`, noise seed `seed`).
pub fn render_tactile(
    sensor: TactileSensor,
    depth: &DepthMap,
    calib: &Calibration,
    seed: u64,
) -> Result<RgbImage, SensorUnavailable> {
    // Wired to `sim::sensor::SensorSim` at merge time; the arguments are what it takes.
    let _ = (depth, calib, seed);
    Err(SensorUnavailable { sensor })
}

/// Whether [`render_tactile`] can render in this build.
pub fn simulator_available() -> bool {
    false
}
