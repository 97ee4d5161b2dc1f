//! Start-up: turning a [`RigConfig`] into the hardware seams the job uses.
//!
//! This is the one place that names backends. With the built-in simulated rig it starts the
//! simulated MG400 in-process on loopback (real TCP, real protocol) and connects the real
//! client to it, and builds simulated sensors that read the simulated arm's true pose. The
//! collection job never knows which it got. Real hardware: the MG400 over TCP or the Magician
//! over serial ([`RigArm`]), V4L2 or nokhwa cameras bound by USB identity ([`RigCamera`]).
//!
//! Modbus peripherals (`[modbus.<name>]`) come out as a [`ModbusBench`], connected before the
//! arm moves; a `transport = "sim"` one is a simulated device ([`SimModbusServer`]) started
//! here on loopback, a force sensor reading the simulated arm's truth.
//!
//! Faults from `[sim.faults]` ([`FaultConfig`]) are injected here too, at the seams: the
//! simulator gets its controller switches, a task closes its sockets periodically, and each
//! camera fails the frame requests it is told to (waiting, then [`CameraError::Timeout`]),
//! so the job and the client see exactly what a flaky bench would show them.

use std::path::PathBuf;
use std::sync::Arc;

use std::time::Duration;

use crate::arm::dobot::client::{Mg400Client, Mg400Config};
use crate::arm::magician::{MagicianArm, MagicianProfile};
use crate::arm::profile::{FirmwareProfile, ProfileLookupError};
use crate::arm::{Alarm, Arm, ArmError, Arrival, MoveKind};
use crate::calibration::Calibration;
use crate::camera::nokhwa_backend::NokhwaCamera;
use crate::camera::usb::DeviceSelector;
use crate::camera::v4l2::{CameraSettings, V4l2Camera};
use crate::camera::{Camera, CameraError, Frame};
use crate::clock::{Clock, MonotonicClock};
use crate::config::{ArmBackend, FaultConfig, RigConfig, SensorBackend};
use crate::dataset::CapturePart;
use crate::geometry::objects::{ObjectChoice, ObjectResolveError};
use crate::io::modbus::{ModbusBench, ModbusError, ModbusTransport, SimPeripheralKind};
use crate::pose::Pose;
use crate::sensor::{SensorKind, SensorKindParseError, SensorSet};
use crate::sim::mg400::{SimFaults, SimMg400, SimMg400Config, SimPort};
use crate::sim::modbus::{ArmContact, SimModbusServer};
use crate::sim::sensor::{Scene, SensorSim, SimCamera};

/// Errors assembling the rig.
#[derive(Debug, thiserror::Error)]
pub enum RigError {
    #[error(transparent)]
    UnknownSensor(#[from] SensorKindParseError),
    #[error(transparent)]
    Object(#[from] ObjectResolveError),
    #[error(transparent)]
    Profile(#[from] ProfileLookupError),
    #[error("calibration {path}: {reason}")]
    Calibration { path: PathBuf, reason: String },
    #[error("starting the simulated MG400: {0}")]
    Sim(#[source] std::io::Error),
    #[error(transparent)]
    Arm(#[from] crate::arm::ArmError),
    #[error("sensor {name}: backend {backend} is not available in this build of rig")]
    BackendUnavailable { name: String, backend: String },
    #[error("sensor {name}: {source}")]
    Camera {
        name: String,
        #[source]
        source: CameraError,
    },
    /// A required Modbus peripheral could not be reached (or a simulated one started).
    #[error(transparent)]
    Modbus(#[from] ModbusError),
    /// The arm's `serial_port` is not a serial device (a file, a FIFO, `/dev/null`, a device
    /// that is not a terminal): the configuration's mistake.
    #[error("arm.serial_port: {0}")]
    SerialPort(#[source] crate::io::serial::SerialError),
}

/// A Magician that would not open because its port is not a terminal (`ENOTTY`): bad input,
/// not a hardware fault; any other failure as it is.
fn not_a_tty(path: &std::path::Path, e: crate::arm::ArmError) -> RigError {
    let serial = match &e {
        crate::arm::ArmError::Io { source, .. } => source.get_ref().and_then(|s| s.downcast_ref::<serialport::Error>()),
        _ => None,
    };
    match serial {
        Some(s) if crate::io::serial::is_not_a_tty(s) => RigError::SerialPort(crate::io::serial::SerialError::NotSerial {
            path: path.to_path_buf(),
            found: "a device that is not a terminal",
        }),
        _ => RigError::Arm(e),
    }
}

/// The firmware profile the configuration names (the embedded MG400 V1.6 profile by default).
pub fn profile_for(config: &RigConfig) -> Result<FirmwareProfile, RigError> {
    Ok(FirmwareProfile::named(config.arm.profile.as_deref())?)
}

/// The rig clock: real time on real hardware, sped up on the simulated rig.
pub fn clock_for(config: &RigConfig) -> Arc<dyn Clock> {
    match config.arm.backend {
        ArmBackend::Simulated { time_scale } => Arc::new(MonotonicClock::scaled(time_scale)),
        ArmBackend::Mg400 { .. } | ArmBackend::Magician { .. } => Arc::new(MonotonicClock::new()),
    }
}

/// Frame rate of the simulated sensors, Hz.
const SIM_FPS: u32 = 30;

/// A camera of any backend this build supports.
#[allow(clippy::large_enum_variant, reason = "a rig holds three cameras; boxing buys nothing")]
pub enum RigCamera {
    /// `resolution_px` is the rendered size, for the manifest.
    Simulated {
        kind: SensorKind,
        camera: SimCamera,
        calibration: String,
        timeouts: InjectedTimeouts,
        resolution_px: [u32; 2],
    },
    /// `device` is the configured selector (`/dev/video0`, `usb:1-2.3`) and `settings` the
    /// configured stream, for the manifest.
    V4l2 {
        kind: SensorKind,
        camera: V4l2Camera,
        calibration: String,
        device: String,
        settings: CameraSettings,
    },
    Nokhwa {
        kind: SensorKind,
        camera: NokhwaCamera,
        calibration: String,
        device: String,
        settings: CameraSettings,
    },
}

/// Frame requests a simulated camera fails on purpose (`[sim.faults] camera_timeout_at_frames`).
#[derive(Debug, Clone, Default)]
pub struct InjectedTimeouts {
    /// 1-based frame requests that time out.
    pub at_requests: Vec<u64>,
    /// Real time a failing request waits before it reports the timeout, as a stalled
    /// camera would.
    pub wait: std::time::Duration,
    /// Frame requests so far.
    pub requests: u64,
}

impl InjectedTimeouts {
    fn from_faults(faults: &FaultConfig) -> Self {
        Self { at_requests: faults.camera_timeout_at_frames.clone(), wait: faults.camera_timeout, requests: 0 }
    }

    /// Counts a request; true when this one must time out.
    fn next_fails(&mut self) -> bool {
        self.requests += 1;
        self.at_requests.contains(&self.requests)
    }
}

impl RigCamera {
    /// The sensor it captures.
    pub fn kind(&self) -> SensorKind {
        match self {
            RigCamera::Simulated { kind, .. } | RigCamera::V4l2 { kind, .. } | RigCamera::Nokhwa { kind, .. } => *kind,
        }
    }
    /// Directory name of its dataset (`tactip`, `vitac`, `vitactip`).
    pub fn sensor_dir(&self) -> String {
        self.kind().to_string()
    }
    /// The calibration it renders or was fitted with, for the manifest.
    pub fn calibration_name(&self) -> String {
        match self {
            RigCamera::Simulated { calibration, .. } | RigCamera::V4l2 { calibration, .. } | RigCamera::Nokhwa { calibration, .. } => {
                calibration.clone()
            }
        }
    }
    /// The camera as a dataset manifest's capture chain names it: backend `sim` (simulated,
    /// its rendered size and frame rate), `v4l2` (the configured device, the node opened and
    /// its USB identity, the negotiated format and size, the configured rate, the locked
    /// controls as read back) or `nokhwa` (the configured device, format when forced, size and
    /// rate). The stream counts are added when a collection ends.
    pub fn capture_part(&self) -> CapturePart {
        let name = self.kind().to_string();
        let fourcc = |f: crate::camera::convert::PixelFormat| String::from_utf8_lossy(&f.fourcc()).into_owned();
        match self {
            RigCamera::Simulated { resolution_px, .. } => {
                CapturePart::new(name, "sim", true, None).with_stream(None, None, *resolution_px, SIM_FPS)
            }
            RigCamera::V4l2 { device, camera, settings, .. } => {
                let choice = camera.format();
                let part = CapturePart::new(name, "v4l2", false, Some(device.clone()))
                    .with_stream(
                        Some(camera.path().display().to_string()),
                        Some(fourcc(choice.format)),
                        [choice.width, choice.height],
                        settings.fps,
                    )
                    .with_controls(camera.controls().iter().copied());
                match camera.usb() {
                    Some(usb) => part.with_usb(&usb.port_path, usb.vendor_id, usb.product_id, usb.serial.as_deref()),
                    None => part,
                }
            }
            RigCamera::Nokhwa { device, settings, .. } => CapturePart::new(name, "nokhwa", false, Some(device.clone())).with_stream(
                None,
                settings.pixel_format.map(fourcc),
                [settings.width, settings.height],
                settings.fps,
            ),
        }
    }
}

impl Camera for RigCamera {
    fn name(&self) -> &str {
        match self {
            RigCamera::Simulated { camera, .. } => camera.name(),
            RigCamera::V4l2 { camera, .. } => camera.name(),
            RigCamera::Nokhwa { camera, .. } => camera.name(),
        }
    }
    async fn frame_after(&mut self, not_before_s: f64) -> Result<Frame, CameraError> {
        match self {
            RigCamera::Simulated { camera, timeouts, .. } => {
                if timeouts.next_fails() {
                    tokio::time::sleep(timeouts.wait).await;
                    return Err(CameraError::Timeout { camera: camera.name().to_string(), timeout_ms: timeouts.wait.as_millis() as u64 });
                }
                camera.frame_after(not_before_s).await
            }
            RigCamera::V4l2 { camera, .. } => camera.frame_after(not_before_s).await,
            RigCamera::Nokhwa { camera, .. } => camera.frame_after(not_before_s).await,
        }
    }
    fn stream_stats(&self) -> Option<crate::camera::StreamStats> {
        match self {
            RigCamera::Simulated { camera, .. } => camera.stream_stats(),
            RigCamera::V4l2 { camera, .. } => camera.stream_stats(),
            RigCamera::Nokhwa { camera, .. } => camera.stream_stats(),
        }
    }
}

/// The arm of any backend this build supports; [`Arm`] by delegation.
#[allow(clippy::large_enum_variant, reason = "one arm per rig; boxing buys nothing")]
pub enum RigArm {
    Mg400(Mg400Client),
    Magician(MagicianArm),
}

impl Arm for RigArm {
    async fn enable(&mut self) -> Result<(), ArmError> {
        match self {
            RigArm::Mg400(a) => a.enable().await,
            RigArm::Magician(a) => a.enable().await,
        }
    }
    async fn move_to(&mut self, target: Pose, kind: MoveKind) -> Result<(), ArmError> {
        match self {
            RigArm::Mg400(a) => a.move_to(target, kind).await,
            RigArm::Magician(a) => a.move_to(target, kind).await,
        }
    }
    async fn wait_arrived(&mut self, target: Pose, timeout: Duration) -> Result<Arrival, ArmError> {
        match self {
            RigArm::Mg400(a) => a.wait_arrived(target, timeout).await,
            RigArm::Magician(a) => a.wait_arrived(target, timeout).await,
        }
    }
    async fn pose(&mut self) -> Result<Pose, ArmError> {
        match self {
            RigArm::Mg400(a) => a.pose().await,
            RigArm::Magician(a) => a.pose().await,
        }
    }
    async fn stop(&mut self) -> Result<(), ArmError> {
        match self {
            RigArm::Mg400(a) => a.stop().await,
            RigArm::Magician(a) => a.stop().await,
        }
    }
    async fn clear_error(&mut self) -> Result<Vec<Alarm>, ArmError> {
        match self {
            RigArm::Mg400(a) => a.clear_error().await,
            RigArm::Magician(a) => a.clear_error().await,
        }
    }
    async fn disable(&mut self) -> Result<(), ArmError> {
        match self {
            RigArm::Mg400(a) => a.disable().await,
            RigArm::Magician(a) => a.disable().await,
        }
    }
    async fn firmware_version(&mut self) -> Option<String> {
        match self {
            RigArm::Mg400(a) => a.firmware_version().await,
            RigArm::Magician(a) => a.firmware_version().await,
        }
    }
}

/// An opened rig: the arm client, the cameras, and the simulator when one runs in-process.
pub struct Rig {
    pub arm: RigArm,
    pub cameras: Vec<RigCamera>,
    /// The Modbus peripherals of `[modbus.*]` (empty when none), for the job.
    pub peripherals: ModbusBench,
    sim: Option<SimMg400>,
    /// Simulated Modbus devices (`transport = "sim"`), running until shutdown.
    modbus_sims: Vec<SimModbusServer>,
    /// The task closing the simulator's sockets (`[sim.faults] drop_sockets_every_s`).
    socket_dropper: Option<tokio::task::JoinHandle<()>>,
}

impl Rig {
    /// Starts (simulated) hardware and connects to it.
    pub async fn open(
        config: &RigConfig,
        object: &ObjectChoice,
        sensors: &SensorSet,
        seed: u64,
        clock: Arc<dyn Clock>,
    ) -> Result<Self, RigError> {
        Self::open_with(config, object, sensors, seed, clock, None).await
    }

    /// [`open`](Self::open), with every byte on the arm's sockets logged to `recorder` when
    /// one is given (`rig collect --record`).
    pub async fn open_with(
        config: &RigConfig,
        object: &ObjectChoice,
        sensors: &SensorSet,
        seed: u64,
        clock: Arc<dyn Clock>,
        recorder: Option<crate::record::Recorder>,
    ) -> Result<Self, RigError> {
        // The Magician has its own profile format; the MG400 profile then only feeds the
        // motion-time model of plan ordering, so the embedded one stands in.
        let profile = match config.arm.backend {
            ArmBackend::Magician { .. } => FirmwareProfile::default_mg400(),
            _ => profile_for(config)?,
        };
        let (arm_cfg, sim) = match &config.arm.backend {
            ArmBackend::Simulated { .. } => {
                let sim_cfg = SimMg400Config { profile: profile.clone(), faults: sim_faults(&config.faults), ..SimMg400Config::default() };
                let sim = SimMg400::start(sim_cfg, Arc::clone(&clock)).await.map_err(RigError::Sim)?;
                let cfg = Mg400Config::new(sim.dashboard_addr().ip().to_string(), profile.clone()).with_ports(
                    sim.dashboard_addr().port(),
                    sim.motion_addr().port(),
                    sim.feedback_addr().port(),
                );
                (Some(cfg), Some(sim))
            }
            ArmBackend::Mg400 { host, dashboard_port, motion_port, feedback_port } => {
                (Some(Mg400Config::new(host.clone(), profile.clone()).with_ports(*dashboard_port, *motion_port, *feedback_port)), None)
            }
            ArmBackend::Magician { .. } => (None, None),
        };
        let arm = match arm_cfg {
            Some(mut arm_cfg) => {
                arm_cfg.speed_factor_pct = config.arm.speed_factor;
                RigArm::Mg400(match recorder {
                    Some(recorder) => crate::record::connect_recorded(arm_cfg, Arc::clone(&clock), recorder).await?,
                    None => Mg400Client::connect(arm_cfg, Arc::clone(&clock)).await?,
                })
            }
            None => {
                // Only the Magician backend builds no MG400 config.
                let serial_port = match &config.arm.backend {
                    ArmBackend::Magician { serial_port } => serial_port.clone(),
                    _ => PathBuf::new(),
                };
                let magician_profile = MagicianProfile::named(config.arm.profile.as_deref())?;
                // Its kind is looked at before it is opened: a file or FIFO is no port (and a
                // FIFO would block the open), /dev/null answers nothing.
                crate::io::serial::check_serial_device(&serial_port).map_err(RigError::SerialPort)?;
                let arm = MagicianArm::open(&serial_port, magician_profile, Arc::clone(&clock)).map_err(|e| not_a_tty(&serial_port, e))?;
                RigArm::Magician(arm)
            }
        };
        let socket_dropper = match (&sim, config.faults.drop_sockets_every_s) {
            (Some(sim), Some(every_s)) => {
                let dropper = sim.connection_dropper();
                let period = clock.real_duration(std::time::Duration::from_secs_f64(every_s));
                Some(tokio::spawn(async move {
                    loop {
                        tokio::time::sleep(period).await;
                        tracing::info!("fault injection: closing the simulated MG400's sockets");
                        for port in [SimPort::Dashboard, SimPort::Motion, SimPort::Feedback] {
                            dropper.drop_connections(port);
                        }
                    }
                }))
            }
            _ => None,
        };

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
                    let (width, height) = sim_size(sensor_cfg);
                    let scene_name = sensor_cfg.map(|s| s.scene.clone()).unwrap_or_else(|| "full".into());
                    let (calib, calib_name) = sim_calibration(*kind, sensor_cfg, width, height)?;
                    let scene = Scene::preset(&scene_name).map_err(|e| RigError::BackendUnavailable {
                        name: kind.to_string(),
                        backend: format!("sim scene {scene_name:?}: {e}"),
                    })?;
                    let px_per_mm = calib.scale_px_per_mm[0] as f32;
                    let mut renderer = SensorSim::new(*kind, scene, width, height, px_per_mm, seed ^ sensor_salt(*kind));
                    if let Some(unit) = config.sensor_unit_seed {
                        renderer = renderer.with_unit_seed(unit ^ sensor_salt(*kind));
                    }
                    let depth_source = sim_depth_source(object, calib.clone(), width, height);
                    let camera = SimCamera::new(
                        kind.to_string(),
                        renderer,
                        depth_source,
                        config.work_frame,
                        sim.truth(),
                        Arc::clone(&clock),
                        1.0 / f64::from(SIM_FPS),
                    )
                    .with_stale_buffer(config.sim_stale_buffer_frames);
                    cameras.push(RigCamera::Simulated {
                        kind: *kind,
                        camera,
                        calibration: calib_name,
                        timeouts: InjectedTimeouts::from_faults(&config.faults),
                        resolution_px: [width, height],
                    });
                }
                SensorBackend::V4l2 { ref device } | SensorBackend::Nokhwa { ref device } => {
                    let is_v4l2 = matches!(backend, SensorBackend::V4l2 { .. });
                    let Some(sensor_cfg) = sensor_cfg else {
                        return Err(RigError::BackendUnavailable {
                            name: kind.to_string(),
                            backend: "hardware camera without a [sensors] entry".into(),
                        });
                    };
                    let camera_err = |e: CameraError| RigError::Camera { name: kind.to_string(), source: e };
                    let selector = DeviceSelector::parse(device)
                        .map_err(|e| RigError::BackendUnavailable { name: kind.to_string(), backend: e.to_string() })?;
                    let calibration = sensor_cfg.calibration.as_ref().map_or_else(|| "none".to_string(), |p| p.display().to_string());
                    let name = kind.to_string();
                    if is_v4l2 {
                        let camera = V4l2Camera::open(&name, &selector, &sensor_cfg.camera, Arc::clone(&clock)).map_err(camera_err)?;
                        let settings = sensor_cfg.camera.clone();
                        cameras.push(RigCamera::V4l2 { kind: *kind, camera, calibration, device: device.clone(), settings });
                    } else {
                        let camera = NokhwaCamera::open(&name, &selector, &sensor_cfg.camera, Arc::clone(&clock)).map_err(camera_err)?;
                        let settings = sensor_cfg.camera.clone();
                        cameras.push(RigCamera::Nokhwa { kind: *kind, camera, calibration, device: device.clone(), settings });
                    }
                }
            }
        }
        let (peripherals, modbus_sims) = open_peripherals(config, sim.as_ref()).await?;
        Ok(Self { arm, cameras, peripherals, sim, modbus_sims, socket_dropper })
    }

    /// Puts `object` under the simulated sensors (their depth maps now come from its mesh),
    /// keeping every camera and the arm connection open. Hardware cameras are left alone:
    /// what they see is whatever lies on the bench.
    pub fn set_object(&mut self, config: &RigConfig, object: &ObjectChoice) -> Result<(), RigError> {
        for camera in &mut self.cameras {
            if let RigCamera::Simulated { kind, camera, .. } = camera {
                let sensor_cfg = config.sensors.iter().find(|s| s.name == kind.to_string());
                let (width, height) = sim_size(sensor_cfg);
                let (calib, _) = sim_calibration(*kind, sensor_cfg, width, height)?;
                camera.set_depth_source(sim_depth_source(object, calib, width, height));
            }
        }
        Ok(())
    }

    /// Stops the in-process simulator, if any.
    pub async fn shutdown(self) {
        let Rig { arm, cameras, peripherals, sim, modbus_sims, socket_dropper } = self;
        if let Some(task) = socket_dropper {
            task.abort();
        }
        drop(peripherals);
        for server in modbus_sims {
            server.shutdown();
        }
        // Close the client first, so it does not try to reconnect to a simulator going away.
        drop(arm);
        drop(cameras);
        if let Some(sim) = sim {
            sim.shutdown().await;
        }
    }
}

/// The configured Modbus peripherals, connected, with the simulated ones started first (on
/// loopback; the client then speaks Modbus TCP to them like to a real device).
async fn open_peripherals(config: &RigConfig, sim: Option<&SimMg400>) -> Result<(ModbusBench, Vec<SimModbusServer>), RigError> {
    let mut configs = std::collections::BTreeMap::new();
    let mut servers = Vec::new();
    for (name, peripheral) in &config.modbus {
        let mut peripheral = peripheral.clone();
        if let ModbusTransport::Sim { device, stop_answering_after } = peripheral.transport {
            let contact = match (device, sim) {
                (SimPeripheralKind::ForceSensor { .. }, Some(sim)) => {
                    Some(ArmContact { truth: sim.truth(), work_frame: config.work_frame })
                }
                (SimPeripheralKind::ForceSensor { .. }, None) => {
                    return Err(RigError::BackendUnavailable {
                        name: format!("modbus.{name}"),
                        backend: "sim force sensor (it presses with the simulated arm; use arm backend sim)".into(),
                    });
                }
                (SimPeripheralKind::Illumination, _) => None,
            };
            let server = SimModbusServer::start(device, contact, stop_answering_after).await.map_err(RigError::Sim)?;
            tracing::info!(peripheral = %name, addr = %server.addr(), "simulated Modbus device started");
            peripheral.transport = ModbusTransport::Tcp { address: server.addr().to_string() };
            servers.push(server);
        }
        configs.insert(name.clone(), peripheral);
    }
    Ok((ModbusBench::connect(&configs).await?, servers))
}

/// Image size of a simulated sensor (512 x 512 unless configured).
fn sim_size(sensor_cfg: Option<&crate::config::SensorConfig>) -> (u32, u32) {
    sensor_cfg.map(|s| (s.width, s.height)).unwrap_or((512, 512))
}

/// A simulated sensor's calibration and its name for the manifest: the configured file, else
/// the one `rig calibrate` saved, else the default for the image size.
fn sim_calibration(
    kind: SensorKind,
    sensor_cfg: Option<&crate::config::SensorConfig>,
    width: u32,
    height: u32,
) -> Result<(Calibration, String), RigError> {
    let saved = kind.calibration_path();
    let configured = sensor_cfg.and_then(|s| s.calibration.clone());
    match configured.or_else(|| saved.is_file().then_some(saved)) {
        Some(p) => Ok((
            Calibration::load(&p).map_err(|e| RigError::Calibration { path: p.clone(), reason: e.to_string() })?,
            p.display().to_string(),
        )),
        None => Ok((Calibration::default_for(width, height), "default".to_string())),
    }
}

/// The depth maps of `object` a simulated sensor renders.
fn sim_depth_source(object: &ObjectChoice, calib: Calibration, width: u32, height: u32) -> crate::sim::sensor::DepthSource {
    use crate::geometry::raster::{PreparedMesh, RasterScratch, render_depth_into};
    let mesh = PreparedMesh::for_many_renders(&object.mesh);
    Box::new(move |object_pose: &Pose| {
        let mut depth = crate::geometry::DepthMap::empty(0, 0);
        render_depth_into(&mesh, object_pose, &calib, width, height, 1, &mut RasterScratch::default(), &mut depth);
        depth
    })
}

/// The simulator's switches for the configured faults.
fn sim_faults(faults: &FaultConfig) -> SimFaults {
    let c = &faults.controller;
    SimFaults {
        reply_delay: c.reply_delay,
        split_replies: c.split_replies,
        feedback_garbage_every: c.feedback_garbage_every,
        feedback_start_mid_frame: c.feedback_start_mid_frame,
        collision_at_move: None,
        collision_at_moves: c.collision_at_moves.clone(),
        drop_dashboard_after: c.drop_dashboard_after,
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
