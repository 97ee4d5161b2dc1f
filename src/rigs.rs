//! Start-up: turning a [`RigConfig`] into the hardware seams the job uses.
//!
//! This is the one place that names backends. With the built-in simulated rig it starts the
//! simulated MG400 in-process on loopback (real TCP, real protocol) and connects the real
//! client to it, and builds simulated sensors that read the simulated arm's true pose. The
//! collection job never knows which it got.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use sha2::{Digest, Sha256};

use crate::arm::dobot::client::{Mg400Client, Mg400Config};
use crate::arm::profile::FirmwareProfile;
use crate::calibration::Calibration;
use crate::camera::{Camera, CameraError, Frame};
use crate::clock::{Clock, MonotonicClock};
use crate::config::{ArmBackend, RigConfig, SensorBackend};
use crate::geometry::objects::{load_object, object_path};
use crate::geometry::stl::Mesh;
use crate::pose::{Pose, WorkFrame};
use crate::sim::mg400::{SimMg400, SimMg400Config};
use crate::sim::sensor::{Scene, SensorKind, SensorSim, SimCamera};

/// Errors assembling the rig.
#[derive(Debug, thiserror::Error)]
pub enum RigError {
    #[error("unknown sensor {given:?}: expected tactip, vitac, vitactip or all")]
    UnknownSensor { given: String },
    #[error("object {name:?}: {reason}")]
    Object { name: String, reason: String },
    #[error("firmware profile {name}: {reason}")]
    Profile { name: String, reason: String },
    #[error("calibration {path}: {reason}")]
    Calibration { path: PathBuf, reason: String },
    #[error("starting the simulated MG400: {0}")]
    Sim(#[source] std::io::Error),
    #[error(transparent)]
    Arm(#[from] crate::arm::ArmError),
    #[error("sensor {name}: backend {backend} is not available in this build of rig")]
    BackendUnavailable { name: String, backend: String },
}

/// Which sensors a command asked for.
#[derive(Debug, Clone, PartialEq)]
pub struct SensorChoice(pub Vec<SensorKind>);

impl SensorChoice {
    /// `tactip|vitac|vitactip|all`, or a comma-separated list.
    pub fn parse(text: &str) -> Result<Self, RigError> {
        if text.eq_ignore_ascii_case("all") {
            return Ok(Self(vec![SensorKind::TacTip, SensorKind::ViTac, SensorKind::ViTacTip]));
        }
        let mut kinds = Vec::new();
        for part in text.split(',').map(str::trim) {
            let kind = part.parse::<SensorKind>().map_err(|_| RigError::UnknownSensor { given: part.to_string() })?;
            if !kinds.contains(&kind) {
                kinds.push(kind);
            }
        }
        Ok(Self(kinds))
    }
}

/// The object being pressed: its mesh and provenance.
#[derive(Debug, Clone)]
pub struct ObjectChoice {
    pub name: String,
    /// The STL file; `None` for a built-in procedural mesh.
    pub path: Option<PathBuf>,
    /// sha256 of the STL bytes (of the generated binary STL for a built-in mesh).
    pub sha256: String,
    pub mesh: Arc<Mesh>,
}

impl ObjectChoice {
    /// A library object by name, or an STL file (whose stem becomes the name).
    pub fn resolve(name: &str, stl: Option<&Path>) -> Result<Self, RigError> {
        let err = |reason: String| RigError::Object { name: name.to_string(), reason };
        let (name, path) = match stl {
            Some(p) => (
                p.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| name.to_string()),
                Some(p.to_path_buf()),
            ),
            None => {
                let found = [PathBuf::from("."), PathBuf::from(env!("CARGO_MANIFEST_DIR"))]
                    .into_iter()
                    .map(|root| object_path(root, name))
                    .find(|p| p.is_file());
                (name.to_string(), found)
            }
        };
        match path {
            Some(path) => {
                let bytes = std::fs::read(&path).map_err(|e| err(format!("cannot read {}: {e}", path.display())))?;
                let mesh = Mesh::from_bytes(&bytes).map_err(|e| err(format!("{}: {e}", path.display())))?;
                let sha256 = hex::encode(Sha256::digest(&bytes));
                Ok(Self { name, path: Some(path), sha256, mesh: Arc::new(mesh) })
            }
            None => {
                // No file: the library's procedural mesh (or a clear "unknown object" error).
                let mesh = load_object(&name).map_err(|e| err(e.to_string()))?;
                let sha256 = hex::encode(Sha256::digest(mesh.to_binary_bytes(&name)));
                Ok(Self { name, path: None, sha256, mesh: Arc::new(mesh) })
            }
        }
    }
}

/// The firmware profile the configuration names (the embedded MG400 V1.6 profile by default).
pub fn profile_for(config: &RigConfig) -> Result<FirmwareProfile, RigError> {
    match &config.arm.profile {
        None => Ok(FirmwareProfile::default_mg400()),
        Some(name) => {
            let as_path = Path::new(name);
            let found = if as_path.extension().is_some_and(|e| e == "toml") || as_path.is_file() {
                FirmwareProfile::load(as_path)
            } else {
                let local = Path::new("firmware-profiles");
                let dir = if local.join(format!("{name}.toml")).is_file() {
                    local.to_path_buf()
                } else {
                    Path::new(env!("CARGO_MANIFEST_DIR")).join("firmware-profiles")
                };
                FirmwareProfile::by_name(dir, name)
            };
            found.map_err(|e| RigError::Profile { name: name.clone(), reason: e.to_string() })
        }
    }
}

/// The rig clock: real time on real hardware, sped up on the simulated rig.
pub fn clock_for(config: &RigConfig) -> Arc<dyn Clock> {
    match config.arm.backend {
        ArmBackend::Simulated { time_scale } => Arc::new(MonotonicClock::scaled(time_scale)),
        ArmBackend::Mg400 { .. } => Arc::new(MonotonicClock::new()),
    }
}

/// Motion time between two consecutive plan poses, s: the travel at the approach height
/// (retract and descent are the same for every pair, so they do not change the order).
pub fn pose_cost_s(profile: &FirmwareProfile, work_frame: &WorkFrame, a: &Pose, b: &Pose) -> f64 {
    profile.motion_time_s(&work_frame.approach_pose(a), &work_frame.approach_pose(b))
}

/// A camera of any backend this build supports.
pub enum RigCamera {
    Simulated { kind: SensorKind, camera: SimCamera, calibration: String },
}

impl RigCamera {
    /// Directory name of its dataset (`tactip`, `vitac`, `vitactip`).
    pub fn sensor_dir(&self) -> String {
        match self {
            RigCamera::Simulated { kind, .. } => kind.to_string(),
        }
    }
    /// The calibration it renders or was fitted with, for the manifest.
    pub fn calibration_name(&self) -> String {
        match self {
            RigCamera::Simulated { calibration, .. } => calibration.clone(),
        }
    }
}

impl Camera for RigCamera {
    fn name(&self) -> &str {
        match self {
            RigCamera::Simulated { camera, .. } => camera.name(),
        }
    }
    async fn frame_after(&mut self, not_before_s: f64) -> Result<Frame, CameraError> {
        match self {
            RigCamera::Simulated { camera, .. } => camera.frame_after(not_before_s).await,
        }
    }
}

/// An opened rig: the arm client, the cameras, and the simulator when one runs in-process.
pub struct Rig {
    pub arm: Mg400Client,
    pub cameras: Vec<RigCamera>,
    sim: Option<SimMg400>,
}

impl Rig {
    /// Starts (simulated) hardware and connects to it.
    pub async fn open(
        config: &RigConfig,
        object: &ObjectChoice,
        sensors: &SensorChoice,
        seed: u64,
        clock: Arc<dyn Clock>,
    ) -> Result<Self, RigError> {
        let profile = profile_for(config)?;
        let (arm_cfg, sim) = match &config.arm.backend {
            ArmBackend::Simulated { .. } => {
                let sim_cfg = SimMg400Config { profile: profile.clone(), ..SimMg400Config::default() };
                let sim = SimMg400::start(sim_cfg, Arc::clone(&clock)).await.map_err(RigError::Sim)?;
                let cfg = Mg400Config::new(sim.dashboard_addr().ip().to_string(), profile.clone()).with_ports(
                    sim.dashboard_addr().port(),
                    sim.motion_addr().port(),
                    sim.feedback_addr().port(),
                );
                (cfg, Some(sim))
            }
            ArmBackend::Mg400 { host, dashboard_port, motion_port, feedback_port } => {
                (Mg400Config::new(host.clone(), profile.clone()).with_ports(*dashboard_port, *motion_port, *feedback_port), None)
            }
        };
        let mut arm_cfg = arm_cfg;
        arm_cfg.speed_factor_pct = config.arm.speed_factor;
        let arm = Mg400Client::connect(arm_cfg, Arc::clone(&clock)).await?;

        let mut cameras = Vec::new();
        for kind in &sensors.0 {
            let sensor_cfg = config.sensors.iter().find(|s| s.name == kind.to_string());
            let backend = sensor_cfg.map(|s| s.backend.clone()).unwrap_or(SensorBackend::Simulated);
            match backend {
                SensorBackend::Simulated => {
                    let Some(sim) = &sim else {
                        return Err(RigError::BackendUnavailable {
                            name: kind.to_string(),
                            backend: "sim (a simulated sensor needs the simulated arm)".into(),
                        });
                    };
                    let (width, height) = sensor_cfg.map(|s| (s.width, s.height)).unwrap_or((512, 512));
                    let scene_name = sensor_cfg.map(|s| s.scene.clone()).unwrap_or_else(|| "full".into());
                    // The configured file, else the one `rig calibrate` saved, else the default.
                    let saved = crate::calibration::saved_path(&kind.to_string());
                    let configured = sensor_cfg.and_then(|s| s.calibration.clone());
                    let (calib, calib_name) = match configured.or_else(|| saved.is_file().then_some(saved)) {
                        Some(p) => (
                            Calibration::load(&p).map_err(|e| RigError::Calibration { path: p.clone(), reason: e.to_string() })?,
                            p.display().to_string(),
                        ),
                        None => (Calibration::default_for(width, height), "default".to_string()),
                    };
                    let scene = Scene::preset(&scene_name).map_err(|e| RigError::BackendUnavailable {
                        name: kind.to_string(),
                        backend: format!("sim scene {scene_name:?}: {e}"),
                    })?;
                    let px_per_mm = calib.scale_px_per_mm[0] as f32;
                    let renderer = SensorSim::new(*kind, scene, width, height, px_per_mm, seed ^ sensor_salt(*kind));
                    let mesh = Arc::clone(&object.mesh);
                    let depth_calib = calib.clone();
                    let depth_source = Box::new(move |object_pose: &Pose| {
                        crate::geometry::raster::render_depth(&mesh, object_pose, &depth_calib, width, height, 1)
                    });
                    let camera = SimCamera::new(
                        kind.to_string(),
                        renderer,
                        depth_source,
                        config.work_frame,
                        sim.truth(),
                        Arc::clone(&clock),
                        1.0 / 30.0,
                    );
                    cameras.push(RigCamera::Simulated { kind: *kind, camera, calibration: calib_name });
                }
                SensorBackend::V4l2 { .. } => {
                    return Err(RigError::BackendUnavailable { name: kind.to_string(), backend: "v4l2".into() });
                }
                SensorBackend::Nokhwa { .. } => {
                    return Err(RigError::BackendUnavailable { name: kind.to_string(), backend: "nokhwa".into() });
                }
            }
        }
        Ok(Self { arm, cameras, sim })
    }

    /// Stops the in-process simulator, if any.
    pub async fn shutdown(self) {
        let Rig { arm, cameras, sim } = self;
        // Close the client first, so it does not try to reconnect to a simulator going away.
        drop(arm);
        drop(cameras);
        if let Some(sim) = sim {
            sim.shutdown().await;
        }
    }
}

/// Decorrelates the noise of the three simulated sensors sharing one seed.
fn sensor_salt(kind: SensorKind) -> u64 {
    match kind {
        SensorKind::TacTip => 0x7AC7_1900,
        SensorKind::ViTac => 0x5EE7_4400,
        SensorKind::ViTacTip => 0xB07B_0000,
    }
}
