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
//! [`preflight`] opens the same devices the same way for a dry run, each whatever the others
//! did, and moves nothing: the arm connected and read (mode, alarms, pose; never an enable or
//! a motion command), one frame from each camera, one read of each Modbus peripheral. It
//! reports every device ([`Preflight`]), so a dry run names all that fail.
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
use crate::io::modbus::{ModbusBench, ModbusError, ModbusPeripheral, ModbusPeripheralConfig, ModbusTransport, SimPeripheralKind};
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
    /// A sensor with no camera configured is simulated, and a simulated sensor reads the
    /// simulated arm's pose: on a real arm it has nothing to show.
    #[error(
        "sensor {name} is simulated (no camera backend in [sensors.{name}]), and a simulated sensor needs the simulated arm: \
         configure its camera, or leave the sensor out with --sensor"
    )]
    SimulatedSensorOnRealArm { name: String },
    #[error("sensor {name}: {source}")]
    Camera {
        name: String,
        #[source]
        source: CameraError,
    },
    /// A required Modbus peripheral could not be reached (or a simulated one started).
    #[error(transparent)]
    Modbus(#[from] ModbusError),
    /// A pre-flight that should have moved nothing sent the simulated MG400 an enable or a
    /// motion command (a fault of rig itself).
    #[error("the simulated MG400 received {enable_requests} enable and {motion_requests} motion commands during the pre-flight")]
    Moved { enable_requests: u64, motion_requests: u64 },
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
        let sim = start_sim(config, &clock).await?;
        let arm = connect_arm(config, sim.as_ref(), &clock, recorder).await?;
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
            cameras.push(open_camera(config, *kind, object, seed, sim.as_ref(), &clock)?);
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

/// The MG400 firmware profile of `config`. The Magician has its own profile format; the MG400
/// profile then only feeds the motion-time model of plan ordering, so the embedded one stands
/// in.
fn mg400_profile(config: &RigConfig) -> Result<FirmwareProfile, RigError> {
    match config.arm.backend {
        ArmBackend::Magician { .. } => Ok(FirmwareProfile::default_mg400()),
        _ => profile_for(config),
    }
}

/// Starts the simulated MG400 in-process on loopback when `config` names the simulated arm.
async fn start_sim(config: &RigConfig, clock: &Arc<dyn Clock>) -> Result<Option<SimMg400>, RigError> {
    if !matches!(config.arm.backend, ArmBackend::Simulated { .. }) {
        return Ok(None);
    }
    let profile = mg400_profile(config)?;
    let sim_cfg = SimMg400Config { profile, faults: sim_faults(&config.faults), ..SimMg400Config::default() };
    Ok(Some(SimMg400::start(sim_cfg, Arc::clone(clock)).await.map_err(RigError::Sim)?))
}

/// Connects to the arm `config` names (`sim`: the simulator [`start_sim`] started). Connecting
/// neither enables the arm nor moves it.
async fn connect_arm(
    config: &RigConfig,
    sim: Option<&SimMg400>,
    clock: &Arc<dyn Clock>,
    recorder: Option<crate::record::Recorder>,
) -> Result<RigArm, RigError> {
    let profile = mg400_profile(config)?;
    let arm_cfg = match (&config.arm.backend, sim) {
        (ArmBackend::Simulated { .. }, Some(sim)) => Mg400Config::new(sim.dashboard_addr().ip().to_string(), profile).with_ports(
            sim.dashboard_addr().port(),
            sim.motion_addr().port(),
            sim.feedback_addr().port(),
        ),
        (ArmBackend::Simulated { .. }, None) => {
            return Err(RigError::Sim(std::io::Error::other("the simulated MG400 is not running")));
        }
        (ArmBackend::Mg400 { host, dashboard_port, motion_port, feedback_port }, _) => {
            Mg400Config::new(host.clone(), profile).with_ports(*dashboard_port, *motion_port, *feedback_port)
        }
        (ArmBackend::Magician { serial_port }, _) => {
            let magician_profile = MagicianProfile::named(config.arm.profile.as_deref())?;
            // Its kind is looked at before it is opened: a file or FIFO is no port (and a
            // FIFO would block the open), /dev/null answers nothing.
            crate::io::serial::check_serial_device(serial_port).map_err(RigError::SerialPort)?;
            let arm = MagicianArm::open(serial_port, magician_profile, Arc::clone(clock)).map_err(|e| not_a_tty(serial_port, e))?;
            return Ok(RigArm::Magician(arm));
        }
    };
    let mut arm_cfg = arm_cfg;
    arm_cfg.speed_factor_pct = config.arm.speed_factor;
    Ok(RigArm::Mg400(match recorder {
        Some(recorder) => crate::record::connect_recorded(arm_cfg, Arc::clone(clock), recorder).await?,
        None => Mg400Client::connect(arm_cfg, Arc::clone(clock)).await?,
    }))
}

/// Opens the camera of sensor `kind` as `config` says (simulated, V4L2 or nokhwa); a simulated
/// one renders `object` as the simulated arm `sim` presses it.
fn open_camera(
    config: &RigConfig,
    kind: SensorKind,
    object: &ObjectChoice,
    seed: u64,
    sim: Option<&SimMg400>,
    clock: &Arc<dyn Clock>,
) -> Result<RigCamera, RigError> {
    let sensor_cfg = config.sensors.iter().find(|s| s.name == kind.to_string());
    let backend = sensor_cfg.map(|s| s.backend.clone()).unwrap_or(SensorBackend::Simulated);
    match backend {
        SensorBackend::Simulated => {
            let Some(sim) = sim else {
                return Err(RigError::SimulatedSensorOnRealArm { name: kind.to_string() });
            };
            let (width, height) = sim_size(sensor_cfg);
            let scene_name = sensor_cfg.map(|s| s.scene.clone()).unwrap_or_else(|| "full".into());
            let (calib, calib_name) = sim_calibration(kind, sensor_cfg, width, height)?;
            let scene = Scene::preset(&scene_name)
                .map_err(|e| RigError::BackendUnavailable { name: kind.to_string(), backend: format!("sim scene {scene_name:?}: {e}") })?;
            let px_per_mm = calib.scale_px_per_mm[0] as f32;
            let mut renderer = SensorSim::new(kind, scene, width, height, px_per_mm, seed ^ sensor_salt(kind));
            if let Some(unit) = config.sensor_unit_seed {
                renderer = renderer.with_unit_seed(unit ^ sensor_salt(kind));
            }
            let depth_source = sim_depth_source(object, calib.clone(), width, height);
            let camera = SimCamera::new(
                kind.to_string(),
                renderer,
                depth_source,
                config.work_frame,
                sim.truth(),
                Arc::clone(clock),
                1.0 / f64::from(SIM_FPS),
            )
            .with_stale_buffer(config.sim_stale_buffer_frames);
            Ok(RigCamera::Simulated {
                kind,
                camera,
                calibration: calib_name,
                timeouts: InjectedTimeouts::from_faults(&config.faults),
                resolution_px: [width, height],
            })
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
            let settings = sensor_cfg.camera.clone();
            if is_v4l2 {
                let camera = V4l2Camera::open(&name, &selector, &sensor_cfg.camera, Arc::clone(clock)).map_err(camera_err)?;
                Ok(RigCamera::V4l2 { kind, camera, calibration, device: device.clone(), settings })
            } else {
                let camera = NokhwaCamera::open(&name, &selector, &sensor_cfg.camera, Arc::clone(clock)).map_err(camera_err)?;
                Ok(RigCamera::Nokhwa { kind, camera, calibration, device: device.clone(), settings })
            }
        }
    }
}

/// The configured Modbus peripherals, connected, with the simulated ones started first (on
/// loopback; the client then speaks Modbus TCP to them like to a real device).
async fn open_peripherals(config: &RigConfig, sim: Option<&SimMg400>) -> Result<(ModbusBench, Vec<SimModbusServer>), RigError> {
    let (configs, servers) = start_sim_peripherals(config, sim).await?;
    Ok((ModbusBench::connect(&configs).await?, servers))
}

/// Starts the simulated Modbus devices (`transport = "sim"`) and returns every peripheral's
/// configuration, the simulated ones pointed at their servers.
async fn start_sim_peripherals(
    config: &RigConfig,
    sim: Option<&SimMg400>,
) -> Result<(std::collections::BTreeMap<String, ModbusPeripheralConfig>, Vec<SimModbusServer>), RigError> {
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
    Ok((configs, servers))
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

/// What a pre-flight found on one device.
#[derive(Debug)]
pub enum DeviceOutcome {
    /// It answered; what it said.
    Ready(String),
    /// An optional Modbus peripheral that did not answer: the run goes on without its values.
    Optional(ModbusError),
    /// It could not be opened or did not answer.
    Failed(RigError),
}

/// One device a pre-flight opened.
#[derive(Debug)]
pub struct DeviceCheck {
    /// The device as the configuration names it (`arm: MG400 at 192.168.1.6:29999 (profile
    /// mg400-v1.6)`, `camera tactip: v4l2 port:1-2.1`, `modbus force (tcp ... required)`).
    pub device: String,
    pub outcome: DeviceOutcome,
}

/// What [`preflight`] found, device by device, in the order it opened them.
#[derive(Debug)]
pub struct Preflight {
    pub checks: Vec<DeviceCheck>,
}

/// Devices a pre-flight could not open or that did not answer (each named), with the exit
/// code of the worst: 3 when any is a hardware fault.
#[derive(Debug, thiserror::Error)]
#[error("pre-flight: {} failed: {}", failed_count(.failed.len()), .failed.iter().map(|(d, e)| format!("{d}: {e}")).collect::<Vec<_>>().join("; "))]
pub struct PreflightError {
    pub failed: Vec<(String, RigError)>,
}

fn failed_count(n: usize) -> String {
    if n == 1 { "1 device".to_string() } else { format!("{n} devices") }
}

impl Preflight {
    /// One line per device: `  ok      arm: ...: mode 4 (Disabled), ...`, `  FAILED  camera
    /// tactip: ...: <why>`, `  warning modbus light (...): <why>`.
    pub fn lines(&self) -> Vec<String> {
        self.checks
            .iter()
            .map(|c| match &c.outcome {
                DeviceOutcome::Ready(what) => format!("  ok      {}: {what}", c.device),
                DeviceOutcome::Optional(e) => format!("  warning {}: {e} (optional: the run goes on without its values)", c.device),
                DeviceOutcome::Failed(e) => format!("  FAILED  {}: {e}", c.device),
            })
            .collect()
    }

    /// `Err` naming every device that failed.
    pub fn result(self) -> Result<(), PreflightError> {
        let failed: Vec<(String, RigError)> = self
            .checks
            .into_iter()
            .filter_map(|c| match c.outcome {
                DeviceOutcome::Failed(e) => Some((c.device, e)),
                DeviceOutcome::Ready(_) | DeviceOutcome::Optional(_) => None,
            })
            .collect();
        if failed.is_empty() { Ok(()) } else { Err(PreflightError { failed }) }
    }
}

impl RigArm {
    /// What a pre-flight reads from the arm: robot mode (MG400), active alarms and pose. Sends
    /// no enable, no clear and no motion: nothing moves.
    pub async fn status(&mut self) -> Result<String, ArmError> {
        let (mode, alarms) = match self {
            RigArm::Mg400(a) => {
                let mode = a.robot_mode().await?;
                (Some(mode), a.read_alarms().await?)
            }
            RigArm::Magician(a) => (None, a.alarms().await?),
        };
        let pose = self.pose().await?;
        let alarms = if alarms.is_empty() {
            "no alarms".to_string()
        } else {
            let list: Vec<String> = alarms.iter().map(|a| format!("{} ({})", a.id, a.description)).collect();
            format!("active alarms {} (a run clears them when it enables the arm)", list.join(", "))
        };
        Ok(match mode {
            Some(mode) => format!("mode {} ({mode:?}), {alarms}, at {pose}", mode.code()),
            None => format!("{alarms}, at {pose}"),
        })
    }
}

/// The arm as a pre-flight names it.
fn arm_label(config: &RigConfig) -> String {
    let profile = config.arm.profile.as_deref().map_or_else(|| FirmwareProfile::default_mg400().name, str::to_string);
    match &config.arm.backend {
        ArmBackend::Simulated { .. } => format!("arm: simulated MG400 on loopback (profile {profile})"),
        ArmBackend::Mg400 { host, dashboard_port, .. } => format!("arm: MG400 at {host}:{dashboard_port} (profile {profile})"),
        ArmBackend::Magician { serial_port } => format!("arm: Magician on {}", serial_port.display()),
    }
}

/// The camera of `kind` as a pre-flight names it.
fn camera_label(config: &RigConfig, kind: SensorKind) -> String {
    match config.sensors.iter().find(|s| s.name == kind.name()).map(|s| &s.backend) {
        None | Some(SensorBackend::Simulated) => format!("camera {kind}: simulated"),
        Some(SensorBackend::V4l2 { device }) => format!("camera {kind}: v4l2 {device}"),
        Some(SensorBackend::Nokhwa { device }) => format!("camera {kind}: nokhwa {device}"),
    }
}

/// Opens every device a run of `sensors` would open, without moving anything: connects to the
/// arm and reads its mode, alarms and pose (never enables it); opens each sensor's camera at
/// its configured format and takes one frame; connects each Modbus peripheral and makes one
/// read (never a write). Every device is tried, whatever the others did, so the report names
/// all that fail. On the simulated rig the simulated MG400 is started for it and its counters
/// are read at the end: a pre-flight that had sent it an enable or a motion command fails.
pub async fn preflight(config: &RigConfig, object: &ObjectChoice, sensors: &SensorSet, seed: u64, clock: Arc<dyn Clock>) -> Preflight {
    let mut checks = Vec::new();
    let (sim, arm) = match start_sim(config, &clock).await {
        Ok(sim) => {
            let arm = connect_arm(config, sim.as_ref(), &clock, None).await;
            (sim, arm)
        }
        Err(e) => (None, Err(e)),
    };
    let mut arm = match arm {
        Ok(mut arm) => {
            let outcome = match arm.status().await {
                Ok(status) => DeviceOutcome::Ready(status),
                Err(e) => DeviceOutcome::Failed(e.into()),
            };
            checks.push(DeviceCheck { device: arm_label(config), outcome });
            Some(arm)
        }
        Err(e) => {
            checks.push(DeviceCheck { device: arm_label(config), outcome: DeviceOutcome::Failed(e) });
            None
        }
    };
    for &kind in &sensors.0 {
        let outcome = match open_camera(config, kind, object, seed, sim.as_ref(), &clock) {
            Ok(mut camera) => match camera.frame_after(clock.now_s()).await {
                Ok(frame) => DeviceOutcome::Ready(frame_line(&camera, &frame)),
                Err(e) => DeviceOutcome::Failed(RigError::Camera { name: kind.to_string(), source: e }),
            },
            Err(e) => DeviceOutcome::Failed(e),
        };
        checks.push(DeviceCheck { device: camera_label(config, kind), outcome });
    }
    let mut servers = Vec::new();
    match start_sim_peripherals(config, sim.as_ref()).await {
        Ok((configs, started)) => {
            servers = started;
            for (name, peripheral) in configs {
                let device = format!("modbus {}", config.modbus.get(&name).map_or_else(|| peripheral.describe(), |p| p.describe()));
                let required = peripheral.required;
                let probed = match ModbusPeripheral::connect(peripheral).await {
                    Ok(mut p) => p.probe().await,
                    Err(e) => Err(e),
                };
                let outcome = match probed {
                    Ok(read) => DeviceOutcome::Ready(read),
                    Err(e) if !required => DeviceOutcome::Optional(e),
                    Err(e) => DeviceOutcome::Failed(e.into()),
                };
                checks.push(DeviceCheck { device, outcome });
            }
        }
        Err(e) => checks.push(DeviceCheck { device: "modbus".to_string(), outcome: DeviceOutcome::Failed(e) }),
    }
    // Close the client before the simulator goes away, then read what the simulator received.
    drop(arm.take());
    for server in servers {
        server.shutdown();
    }
    if let Some(sim) = sim {
        let stats = sim.stats();
        let outcome = if stats.enable_requests == 0 && stats.motion_requests == 0 {
            DeviceOutcome::Ready("received no enable and no motion command".to_string())
        } else {
            DeviceOutcome::Failed(RigError::Moved { enable_requests: stats.enable_requests, motion_requests: stats.motion_requests })
        };
        checks.push(DeviceCheck { device: "simulated MG400 controller".to_string(), outcome });
        sim.shutdown().await;
    }
    Preflight { checks }
}

/// `one 512x512 frame` and, for a hardware camera, the format it streams.
fn frame_line(camera: &RigCamera, frame: &Frame) -> String {
    let size = format!("one {}x{} frame", frame.image.width(), frame.image.height());
    match camera {
        RigCamera::Simulated { .. } => size,
        RigCamera::V4l2 { camera, .. } => {
            let f = camera.format();
            let fourcc = String::from_utf8_lossy(&f.format.fourcc()).into_owned();
            format!("{size}, streaming {fourcc} {}x{} at {} fps from {}", f.width, f.height, f.fps, camera.path().display())
        }
        RigCamera::Nokhwa { settings, .. } => format!("{size}, asked {}x{} at {} fps", settings.width, settings.height, settings.fps),
    }
}
