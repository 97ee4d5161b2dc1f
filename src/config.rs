//! The rig configuration file (`rig.toml`), in two stages.
//!
//! [`RawConfig`] is what serde reads from TOML, every field optional; [`RigConfig::resolve`]
//! validates it once and fills defaults into the types the program uses. With no file at all,
//! rig runs on the built-in simulated rig ([`ArmBackend::Simulated`], simulated sensors).
//!
//! Lookup order: `--config FILE`, then `$RIG_CONFIG`, then `./rig.toml`.
//!
//! `[sim.faults]` (simulated rig only) injects faults into a run, for the fault matrix
//! (`tests/rig/fault_matrix.rs`) and for trying recovery by hand: controller reply delays and
//! split replies, feedback garbage, alarms at chosen moves, dropped sockets, camera timeouts
//! and a full disk (a byte budget the dataset writer honours). See [`FaultConfig`].
//! A real bench (see `examples/bench-rig.toml`) names the arm (`mg400` by address, `magician`
//! by serial port), binds each sensor to a camera by USB identity (`port:1-2.3`,
//! `serial:...`; see `camera::usb::DeviceSelector`), locks its exposure, gain and white
//! balance, and lists Modbus peripherals under `[modbus.<name>]`. Every sensor has a press
//! limit, the deepest the arm may press its skin ([`RigConfig::press_limit`]: `[sensors.<name>]
//! max_indentation_mm`, else the sensor's conservative default), which [`crate::fence`] holds
//! every pose to.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::pose::WorkFrame;

/// Errors reading or validating the rig configuration.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read rig config {path}")]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("rig config {path} is not valid")]
    Parse {
        path: PathBuf,
        #[source]
        source: crate::untrusted::SyntaxError,
    },
    #[error("rig config {path}: {field} {problem}")]
    Invalid { path: PathBuf, field: &'static str, problem: String },
}

/// `[arm]` as written in the file.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawArm {
    /// `sim` (default), `mg400` or `magician`.
    pub backend: Option<String>,
    /// Magician only: its serial port (`/dev/ttyUSB0`).
    pub serial_port: Option<PathBuf>,
    pub host: Option<String>,
    pub dashboard_port: Option<u16>,
    pub motion_port: Option<u16>,
    pub feedback_port: Option<u16>,
    /// Firmware profile name (`firmware-profiles/<name>.toml`) or path.
    pub profile: Option<String>,
    /// Global speed factor, percent.
    pub speed_factor: Option<u8>,
    /// Simulated rig only: how much faster than real time the simulation runs.
    pub sim_time_scale: Option<f64>,
}

/// `[collect]` as written in the file.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawCollect {
    pub settle_s: Option<f64>,
    pub frames_per_pose: Option<u32>,
    pub average_frames: Option<bool>,
    pub move_timeout_s: Option<f64>,
    pub retries_per_pose: Option<u32>,
}

/// `[sensors.<name>]` as written in the file.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawSensor {
    /// `sim` (default), `v4l2` or `nokhwa`.
    pub backend: Option<String>,
    /// `/dev/videoN`, a USB port path or a serial number (hardware backends).
    pub device: Option<String>,
    /// Calibration file (robot mm to image pixels).
    pub calibration: Option<PathBuf>,
    /// Simulated sensors: scene preset name (see `sim::sensor::Scene`).
    pub scene: Option<String>,
    pub width: Option<u32>,
    pub height: Option<u32>,
    /// Hardware backends: frame rate to run the camera at.
    pub fps: Option<u32>,
    /// Hardware backends: `yuyv` or `mjpeg` instead of the automatic choice.
    pub pixel_format: Option<String>,
    /// Hardware backends: manual exposure, units of 100 us (V4L2 `exposure_time_absolute`).
    pub exposure_100us: Option<i64>,
    /// Hardware backends: manual gain (camera units).
    pub gain: Option<i64>,
    /// Hardware backends: manual white balance, K.
    pub white_balance_k: Option<i64>,
    /// Hardware backends: frames dropped after the stream starts.
    pub warmup_frames: Option<u32>,
    /// Hardware backends: mmap buffers.
    pub buffers: Option<u32>,
    /// The deepest the arm may press this sensor's skin, mm of indentation (default: the
    /// sensor's own, [`crate::sensor::SensorKind::default_max_indentation_mm`]).
    pub max_indentation_mm: Option<f64>,
}

/// `[sim]` as written in the file.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawSim {
    #[serde(default)]
    pub faults: RawFaults,
    /// Simulated sensors: the physical unit (static specks and dust); default: the run's seed.
    pub sensor_unit_seed: Option<u64>,
    /// Simulated sensors: frames queued in each camera's driver buffer before a request,
    /// exposed earlier (what the fresh-frame rule discards); default 0.
    pub stale_buffer_frames: Option<u32>,
}

/// `[sim.faults]` as written in the file.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawFaults {
    /// Real time the simulated controller waits before each dashboard/motion reply, ms.
    pub reply_delay_ms: Option<u64>,
    /// Send every controller reply in two writes.
    pub split_replies: Option<bool>,
    /// Garbage bytes before every n-th feedback frame.
    pub feedback_garbage_every: Option<u32>,
    /// Each feedback connection starts with the tail of a frame.
    pub feedback_start_mid_frame: Option<bool>,
    /// Moves (1-based, counted from the start of the run) that end in a collision alarm.
    pub collision_at_moves: Option<Vec<u64>>,
    /// The dashboard connection is closed, unanswered, at its command n + 1.
    pub drop_dashboard_after: Option<u64>,
    /// Close every open controller socket (dashboard, motion, feedback) this often, rig-clock s.
    pub drop_sockets_every_s: Option<f64>,
    /// Camera frame requests (1-based, per camera, counted from the start) that time out.
    pub camera_timeout_at_frames: Option<Vec<u64>>,
    /// How long a timing-out frame request waits before failing, real ms.
    pub camera_timeout_ms: Option<u64>,
    /// Bytes each dataset writer may write in this run before the disk is "full" (ENOSPC).
    pub disk_budget_bytes: Option<u64>,
}

/// The whole file.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawConfig {
    #[serde(default)]
    pub sim: RawSim,
    #[serde(default)]
    pub arm: RawArm,
    pub work_frame: Option<WorkFrame>,
    #[serde(default)]
    pub collect: RawCollect,
    #[serde(default)]
    pub sensors: std::collections::BTreeMap<String, RawSensor>,
    /// Modbus peripherals read or written around each capture.
    #[serde(default)]
    pub modbus: std::collections::BTreeMap<String, crate::io::modbus::RawModbusPeripheral>,
}

/// Which arm to drive.
#[derive(Debug, Clone, PartialEq)]
pub enum ArmBackend {
    /// Start the simulated MG400 in-process on loopback and drive it over TCP.
    Simulated { time_scale: f64 },
    /// A real MG400 at `host`.
    Mg400 { host: String, dashboard_port: u16, motion_port: u16, feedback_port: u16 },
    /// A Dobot Magician on a serial port.
    Magician { serial_port: PathBuf },
}

/// The validated `[arm]` section.
#[derive(Debug, Clone, PartialEq)]
pub struct ArmConfig {
    pub backend: ArmBackend,
    pub profile: Option<String>,
    pub speed_factor: u8,
}

/// The validated `[collect]` section (also stored as is in recordings).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CollectConfig {
    pub settle_s: f64,
    pub frames_per_pose: u32,
    pub average_frames: bool,
    pub move_timeout_s: f64,
    pub retries_per_pose: u32,
}

impl Default for CollectConfig {
    fn default() -> Self {
        Self { settle_s: 0.2, frames_per_pose: 1, average_frames: false, move_timeout_s: 30.0, retries_per_pose: 3 }
    }
}

impl CollectConfig {
    /// How each pose's image is captured: `frames_per_pose` frames, averaged or the last.
    pub fn capture_settings(&self) -> crate::camera::CaptureSettings {
        crate::camera::CaptureSettings { frames: self.frames_per_pose, average: self.average_frames }
    }
}

/// The validated `[sensors.<name>]` section.
#[derive(Debug, Clone, PartialEq)]
pub struct SensorConfig {
    pub name: String,
    pub backend: SensorBackend,
    pub calibration: Option<PathBuf>,
    pub scene: String,
    pub width: u32,
    pub height: u32,
    /// Rate, format and locked controls for hardware backends (size = `width` x `height`).
    pub camera: crate::camera::v4l2::CameraSettings,
    /// `max_indentation_mm` as configured; `None`: the sensor's default.
    pub max_indentation_mm: Option<f64>,
}

/// Largest press limit a configuration may set, mm: the standard TacTip's tip is a hemisphere
/// 40 mm across, 20 mm deep, so a limit past that guards no skin and is taken for a typo.
pub const MAX_PRESS_LIMIT_MM: f64 = 20.0;

/// The deepest the arm may press one sensor's skin: mm of indentation into the object's top,
/// counted from first touch (the work frame's contact depth plus a plan pose's `z_mm`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PressLimit {
    pub sensor: crate::sensor::SensorKind,
    pub max_indentation_mm: f64,
    /// Set by `[sensors.<name>] max_indentation_mm`, not the sensor's default.
    pub configured: bool,
}

impl std::fmt::Display for PressLimit {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (mm, name) = (self.max_indentation_mm, self.sensor.name());
        if self.configured {
            write!(f, "{name}'s press limit of {mm} mm (set by [sensors.{name}] max_indentation_mm)")
        } else {
            write!(
                f,
                "{name}'s press limit of {mm} mm ({}'s default; [sensors.{name}] max_indentation_mm sets another)",
                self.sensor.label()
            )
        }
    }
}

/// Where a sensor's frames come from.
#[derive(Debug, Clone, PartialEq)]
pub enum SensorBackend {
    Simulated,
    V4l2 { device: String },
    Nokhwa { device: String },
}

/// The validated `[sim.faults]` section: faults injected into a simulated run. The default
/// injects nothing.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FaultConfig {
    /// The simulated controller's own switches (the fields of `sim::mg400::SimFaults`,
    /// which `rigs` hands it; kept here so the config reader needs nothing of the simulator).
    pub controller: ControllerFaults,
    /// Close every controller socket this often, rig-clock seconds.
    pub drop_sockets_every_s: Option<f64>,
    /// Per-camera frame requests (1-based) that fail with a timeout.
    pub camera_timeout_at_frames: Vec<u64>,
    /// Real time a failing frame request waits before it reports the timeout.
    pub camera_timeout: std::time::Duration,
    /// Byte budget of each dataset writer (a full disk once spent).
    pub disk_budget_bytes: Option<u64>,
}

/// Faults the simulated MG400 controller injects itself.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ControllerFaults {
    pub reply_delay: std::time::Duration,
    pub split_replies: bool,
    pub feedback_garbage_every: Option<u32>,
    pub feedback_start_mid_frame: bool,
    pub collision_at_moves: Vec<u64>,
    pub drop_dashboard_after: Option<u64>,
}

impl FaultConfig {
    /// The faults switched on, as `name=value` pairs named like the config keys.
    pub fn describe(&self) -> String {
        let c = &self.controller;
        let mut parts = Vec::new();
        if !c.reply_delay.is_zero() {
            parts.push(format!("reply_delay_ms={}", c.reply_delay.as_millis()));
        }
        if c.split_replies {
            parts.push("split_replies".to_string());
        }
        if let Some(n) = c.feedback_garbage_every {
            parts.push(format!("feedback_garbage_every={n}"));
        }
        if c.feedback_start_mid_frame {
            parts.push("feedback_start_mid_frame".to_string());
        }
        if !c.collision_at_moves.is_empty() {
            parts.push(format!("collision_at_moves={:?}", c.collision_at_moves));
        }
        if let Some(n) = c.drop_dashboard_after {
            parts.push(format!("drop_dashboard_after={n}"));
        }
        if let Some(s) = self.drop_sockets_every_s {
            parts.push(format!("drop_sockets_every_s={s}"));
        }
        if !self.camera_timeout_at_frames.is_empty() {
            parts.push(format!(
                "camera_timeout_at_frames={:?} ({} ms each)",
                self.camera_timeout_at_frames,
                self.camera_timeout.as_millis()
            ));
        }
        if let Some(b) = self.disk_budget_bytes {
            parts.push(format!("disk_budget_bytes={b}"));
        }
        parts.join(", ")
    }

    /// True when no fault is switched on.
    pub fn is_empty(&self) -> bool {
        *self == Self::default()
    }
}

/// The resolved configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct RigConfig {
    /// The file it came from; `None` for the built-in simulated rig.
    pub source: Option<PathBuf>,
    pub arm: ArmConfig,
    pub work_frame: WorkFrame,
    pub collect: CollectConfig,
    /// Configured sensors by name; empty means "the three simulated sensors".
    pub sensors: Vec<SensorConfig>,
    /// Injected faults (simulated rig only).
    pub faults: FaultConfig,
    /// Modbus peripherals by name.
    pub modbus: std::collections::BTreeMap<String, crate::io::modbus::ModbusPeripheralConfig>,
    /// Simulated sensors: the seed of the physical unit's static look (`[sim]
    /// sensor_unit_seed`); `None`: derived from the run's seed, so each plan seed simulates
    /// another unit.
    pub sensor_unit_seed: Option<u64>,
    /// Simulated sensors: frames queued in each camera's buffer before a request (`[sim]
    /// stale_buffer_frames`, at most 64).
    pub sim_stale_buffer_frames: u32,
}

/// Default time scale of the built-in simulated rig.
pub const DEFAULT_SIM_TIME_SCALE: f64 = 20.0;

impl RigConfig {
    /// The built-in simulated rig used when no configuration file exists.
    pub fn builtin_sim() -> Self {
        Self {
            source: None,
            arm: ArmConfig { backend: ArmBackend::Simulated { time_scale: DEFAULT_SIM_TIME_SCALE }, profile: None, speed_factor: 100 },
            work_frame: WorkFrame::default(),
            collect: CollectConfig::default(),
            sensors: Vec::new(),
            faults: FaultConfig::default(),
            modbus: std::collections::BTreeMap::new(),
            sensor_unit_seed: None,
            sim_stale_buffer_frames: 0,
        }
    }

    /// Finds and reads the configuration: `explicit`, then `$RIG_CONFIG`, then `./rig.toml`;
    /// the built-in simulated rig when none exists.
    pub fn discover(explicit: Option<&Path>) -> Result<Self, ConfigError> {
        if let Some(p) = explicit {
            return Self::load(p);
        }
        if let Some(p) = std::env::var_os("RIG_CONFIG") {
            return Self::load(Path::new(&p));
        }
        let local = Path::new("rig.toml");
        if local.is_file() {
            return Self::load(local);
        }
        Ok(Self::builtin_sim())
    }

    /// Reads and validates one file.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = crate::untrusted::read_text(path, crate::untrusted::MAX_CONFIG_BYTES)
            .map_err(|source| ConfigError::Read { path: path.to_path_buf(), source })?;
        Self::parse(&text, path)
    }

    /// Parses and validates TOML text; `path` is only used in messages.
    pub fn parse(text: &str, path: &Path) -> Result<Self, ConfigError> {
        let raw: RawConfig = toml::from_str(text)
            .map_err(|e| ConfigError::Parse { path: path.to_path_buf(), source: crate::untrusted::SyntaxError::from_toml(&e, text) })?;
        Self::resolve(raw, path)
    }

    /// Validates a raw configuration and fills in defaults.
    pub fn resolve(raw: RawConfig, path: &Path) -> Result<Self, ConfigError> {
        use crate::bounds;
        let invalid = |field: &'static str, problem: String| ConfigError::Invalid { path: path.to_path_buf(), field, problem };
        // Every number within its documented range ([`crate::bounds`]).
        let within = |bound: &bounds::Bound, field: &'static str, value: f64| bound.check(value).map(|_| ()).map_err(|p| invalid(field, p));
        let backend = match raw.arm.backend.as_deref().unwrap_or("sim") {
            "sim" | "simulated" => {
                let time_scale = raw.arm.sim_time_scale.unwrap_or(DEFAULT_SIM_TIME_SCALE);
                within(&bounds::ARM_SIM_TIME_SCALE, "arm.sim_time_scale", time_scale)?;
                ArmBackend::Simulated { time_scale }
            }
            "mg400" => {
                let host =
                    raw.arm.host.clone().ok_or_else(|| invalid("arm.host", "is required for backend mg400 (e.g. 192.168.1.6)".into()))?;
                if host.is_empty() || host.len() > 253 {
                    return Err(invalid("arm.host", format!("must be a host name or address of 1 to 253 bytes, got {} bytes", host.len())));
                }
                let (dashboard_port, motion_port, feedback_port) =
                    (raw.arm.dashboard_port.unwrap_or(29999), raw.arm.motion_port.unwrap_or(30003), raw.arm.feedback_port.unwrap_or(30004));
                for (field, port) in
                    [("arm.dashboard_port", dashboard_port), ("arm.motion_port", motion_port), ("arm.feedback_port", feedback_port)]
                {
                    within(&bounds::ARM_PORT, field, f64::from(port))?;
                }
                ArmBackend::Mg400 { host, dashboard_port, motion_port, feedback_port }
            }
            "magician" => ArmBackend::Magician {
                serial_port: raw
                    .arm
                    .serial_port
                    .clone()
                    .ok_or_else(|| invalid("arm.serial_port", "is required for backend magician (e.g. /dev/ttyUSB0)".into()))?,
            },
            other => return Err(invalid("arm.backend", format!("must be sim, mg400 or magician, got {other:?}"))),
        };
        let speed_factor = raw.arm.speed_factor.unwrap_or(100);
        within(&bounds::ARM_SPEED_FACTOR, "arm.speed_factor", f64::from(speed_factor))?;
        let work_frame = raw.work_frame.unwrap_or_default();
        let origin = work_frame.origin;
        for (field, value) in
            [("work_frame.origin.x_mm", origin.x_mm), ("work_frame.origin.y_mm", origin.y_mm), ("work_frame.origin.z_mm", origin.z_mm)]
        {
            within(&bounds::WORK_FRAME_ORIGIN_MM, field, value)?;
        }
        within(&bounds::WORK_FRAME_ORIGIN_YAW, "work_frame.origin.yaw_deg", origin.yaw_deg)?;
        within(&bounds::WORK_FRAME_CONTACT_DEPTH, "work_frame.contact_depth_mm", work_frame.contact_depth_mm)?;
        within(&bounds::WORK_FRAME_APPROACH, "work_frame.approach_mm", work_frame.approach_mm)?;
        within(&bounds::WORK_FRAME_TOOL_OFFSET, "work_frame.tool_offset_mm", work_frame.tool_offset_mm)?;
        let d = CollectConfig::default();
        let collect = CollectConfig {
            settle_s: raw.collect.settle_s.unwrap_or(d.settle_s),
            frames_per_pose: raw.collect.frames_per_pose.unwrap_or(d.frames_per_pose),
            average_frames: raw.collect.average_frames.unwrap_or(d.average_frames),
            move_timeout_s: raw.collect.move_timeout_s.unwrap_or(d.move_timeout_s),
            retries_per_pose: raw.collect.retries_per_pose.unwrap_or(d.retries_per_pose),
        };
        within(&bounds::COLLECT_SETTLE, "collect.settle_s", collect.settle_s)?;
        within(&bounds::COLLECT_FRAMES, "collect.frames_per_pose", f64::from(collect.frames_per_pose))?;
        within(&bounds::COLLECT_MOVE_TIMEOUT, "collect.move_timeout_s", collect.move_timeout_s)?;
        within(&bounds::COLLECT_RETRIES, "collect.retries_per_pose", f64::from(collect.retries_per_pose))?;
        let mut sensors = Vec::new();
        for (key, s) in raw.sensors {
            // `[sensors.TacTip]` and `[sensors.tactip]` are one sensor: the one parser, the
            // canonical name kept (the rig matches sensors by it).
            let name = key
                .parse::<crate::sensor::SensorKind>()
                .map_err(|e| invalid("sensors.<name>", format!("[sensors.{key}]: {e}")))?
                .name()
                .to_string();
            if sensors.iter().any(|c: &SensorConfig| c.name == name) {
                return Err(invalid("sensors.<name>", format!("[sensors.{key}]: sensor {name} is configured twice")));
            }
            let backend = match s.backend.as_deref().unwrap_or("sim") {
                "sim" | "simulated" => SensorBackend::Simulated,
                "v4l2" => SensorBackend::V4l2 {
                    device: s.device.clone().ok_or_else(|| invalid("sensors.*.device", format!("is required for v4l2 sensor {name}")))?,
                },
                "nokhwa" => SensorBackend::Nokhwa {
                    device: s.device.clone().ok_or_else(|| invalid("sensors.*.device", format!("is required for nokhwa sensor {name}")))?,
                },
                other => return Err(invalid("sensors.*.backend", format!("sensor {name}: must be sim, v4l2 or nokhwa, got {other:?}"))),
            };
            if let SensorBackend::V4l2 { device } | SensorBackend::Nokhwa { device } = &backend {
                crate::camera::usb::DeviceSelector::parse(device)
                    .map_err(|e| invalid("sensors.*.device", format!("sensor {name}: {e}")))?;
            }
            let width = s.width.unwrap_or(512);
            let height = s.height.unwrap_or(512);
            let sensor_bound = |bound: &bounds::Bound, field: &'static str, value: f64| {
                bound.check(value).map(|_| ()).map_err(|p| invalid(field, format!("sensor {name}: {p}")))
            };
            sensor_bound(&bounds::SENSOR_SIDE, "sensors.*.width", f64::from(width))?;
            sensor_bound(&bounds::SENSOR_SIDE, "sensors.*.height", f64::from(height))?;
            if u64::from(width) * u64::from(height) > bounds::MAX_IMAGE_PIXELS {
                return Err(invalid(
                    "sensors.*.width",
                    format!(
                        "sensor {name}: {width} x {height} px is more than the {} px in all the dataset readers decode",
                        bounds::MAX_IMAGE_PIXELS
                    ),
                ));
            }
            let defaults = crate::camera::v4l2::CameraSettings::default();
            let pixel_format = match s.pixel_format.as_deref() {
                None => None,
                Some("yuyv") => Some(crate::camera::convert::PixelFormat::Yuyv),
                Some("mjpeg") => Some(crate::camera::convert::PixelFormat::Mjpeg),
                Some(other) => {
                    return Err(invalid("sensors.*.pixel_format", format!("sensor {name}: must be yuyv or mjpeg, got {other:?}")));
                }
            };
            let camera = crate::camera::v4l2::CameraSettings {
                width,
                height,
                fps: s.fps.unwrap_or(defaults.fps),
                pixel_format,
                exposure_100us: s.exposure_100us,
                gain: s.gain,
                white_balance_k: s.white_balance_k,
                buffers: s.buffers.unwrap_or(defaults.buffers),
                warmup_frames: s.warmup_frames.unwrap_or(defaults.warmup_frames),
            };
            sensor_bound(&bounds::SENSOR_FPS, "sensors.*.fps", f64::from(camera.fps))?;
            sensor_bound(&bounds::SENSOR_BUFFERS, "sensors.*.buffers", f64::from(camera.buffers))?;
            sensor_bound(&bounds::SENSOR_WARMUP, "sensors.*.warmup_frames", f64::from(camera.warmup_frames))?;
            for (bound, field, value) in [
                (&bounds::SENSOR_EXPOSURE, "sensors.*.exposure_100us", camera.exposure_100us),
                (&bounds::SENSOR_GAIN, "sensors.*.gain", camera.gain),
                (&bounds::SENSOR_WHITE_BALANCE, "sensors.*.white_balance_k", camera.white_balance_k),
            ] {
                if let Some(v) = value {
                    bound.check(v).map_err(|p| invalid(field, format!("sensor {name}: {p}")))?;
                }
            }
            if let Some(mm) = s.max_indentation_mm
                && !(mm.is_finite() && mm > 0.0 && mm <= MAX_PRESS_LIMIT_MM)
            {
                return Err(invalid(
                    "sensors.*.max_indentation_mm",
                    format!("sensor {name}: must be above 0 and at most {MAX_PRESS_LIMIT_MM} mm, got {mm}"),
                ));
            }
            sensors.push(SensorConfig {
                name,
                backend,
                calibration: s.calibration,
                scene: s.scene.unwrap_or_else(|| "full".into()),
                width,
                height,
                camera,
                max_indentation_mm: s.max_indentation_mm,
            });
        }
        let faults = resolve_faults(&raw.sim.faults, path)?;
        let sim_stale_buffer_frames = raw.sim.stale_buffer_frames.unwrap_or(0);
        within(&bounds::SIM_STALE_FRAMES, "sim.stale_buffer_frames", f64::from(sim_stale_buffer_frames))?;
        if !faults.is_empty() && !matches!(backend, ArmBackend::Simulated { .. }) {
            return Err(invalid("sim.faults", "only applies to the simulated arm (arm.backend = \"sim\")".into()));
        }
        let mut modbus = std::collections::BTreeMap::new();
        for (name, raw_peripheral) in raw.modbus {
            let resolved =
                crate::io::modbus::ModbusPeripheralConfig::resolve(&name, raw_peripheral).map_err(|e| invalid("modbus", e.to_string()))?;
            modbus.insert(name, resolved);
        }
        Ok(Self {
            source: Some(path.to_path_buf()),
            arm: ArmConfig { backend, profile: raw.arm.profile, speed_factor },
            work_frame,
            collect,
            sensors,
            faults,
            modbus,
            sensor_unit_seed: raw.sim.sensor_unit_seed,
            sim_stale_buffer_frames,
        })
    }

    /// The press limit of `sensor`: `[sensors.<name>] max_indentation_mm`, else the sensor's
    /// default.
    pub fn press_limit(&self, sensor: crate::sensor::SensorKind) -> PressLimit {
        let configured = self.sensors.iter().find(|s| s.name == sensor.name()).and_then(|s| s.max_indentation_mm);
        PressLimit {
            sensor,
            max_indentation_mm: configured.unwrap_or_else(|| sensor.default_max_indentation_mm()),
            configured: configured.is_some(),
        }
    }

    /// What the configuration names, one line each, as `rig info` and `rig devices` list it:
    /// the arm (address, profile, speed), the work frame, the capture settings, each sensor
    /// (camera device, size, rate, format, locked controls, calibration, press limit; a sensor
    /// with no `[sensors.<name>]` table is simulated), each Modbus peripheral. Nothing is
    /// opened.
    pub fn listing(&self) -> Vec<String> {
        let profile = self.arm.profile.as_deref().unwrap_or("mg400-v1.6 (built in)");
        let speed = self.arm.speed_factor;
        let arm = match &self.arm.backend {
            ArmBackend::Simulated { time_scale } => {
                format!("arm: simulated MG400 ({time_scale}x real time), profile {profile}, speed factor {speed}%")
            }
            ArmBackend::Mg400 { host, dashboard_port, motion_port, feedback_port } => format!(
                "arm: MG400 at {host} (dashboard {dashboard_port}, motion {motion_port}, feedback {feedback_port}), profile {profile}, speed factor {speed}%"
            ),
            ArmBackend::Magician { serial_port } => {
                format!(
                    "arm: Magician on {}, profile {}, speed factor {speed}%",
                    serial_port.display(),
                    self.arm.profile.as_deref().unwrap_or("magician (built in)")
                )
            }
        };
        let wf = &self.work_frame;
        let c = &self.collect;
        let mut lines = vec![
            arm,
            format!(
                "work frame: origin {}, contact depth {} mm, approach {} mm, tool offset {} mm",
                wf.origin, wf.contact_depth_mm, wf.approach_mm, wf.tool_offset_mm
            ),
            format!(
                "collect: settle {} s, {} frame(s) per pose{}, move timeout {} s, {} retries per pose",
                c.settle_s,
                c.frames_per_pose,
                if c.average_frames { " averaged" } else { "" },
                c.move_timeout_s,
                c.retries_per_pose
            ),
        ];
        for kind in crate::sensor::SensorKind::ALL {
            let limit = self.press_limit(kind);
            let press = if limit.configured {
                format!("press limit {} mm (configured)", limit.max_indentation_mm)
            } else {
                format!("press limit {} mm ({}'s default)", limit.max_indentation_mm, kind.label())
            };
            let line = match self.sensors.iter().find(|s| s.name == kind.name()) {
                None => format!("sensor {kind}: simulated (no [sensors.{kind}] table), 512x512; {press}"),
                Some(s) => {
                    let calibration = s.calibration.as_ref().map_or_else(|| "none set".to_string(), |p| p.display().to_string());
                    let source = match &s.backend {
                        SensorBackend::Simulated => format!("simulated, scene {}, {}x{}", s.scene, s.width, s.height),
                        SensorBackend::V4l2 { device } | SensorBackend::Nokhwa { device } => {
                            let backend = if matches!(s.backend, SensorBackend::V4l2 { .. }) { "v4l2" } else { "nokhwa" };
                            let cam = &s.camera;
                            let format = cam.pixel_format.map_or("auto (YUYV when it reaches the rate, else MJPEG)".to_string(), |f| {
                                String::from_utf8_lossy(&f.fourcc()).into_owned()
                            });
                            let locked = |v: Option<i64>, unit: &str| v.map_or("auto".to_string(), |v| format!("{v}{unit}"));
                            format!(
                                "{backend} camera {device}, {}x{} at {} fps, format {format}, exposure {}, gain {}, white balance {}",
                                s.width,
                                s.height,
                                cam.fps,
                                locked(cam.exposure_100us, " x 100 us"),
                                locked(cam.gain, ""),
                                locked(cam.white_balance_k, " K")
                            )
                        }
                    };
                    format!("sensor {kind}: {source}, calibration {calibration}; {press}")
                }
            };
            lines.push(line);
        }
        for p in self.modbus.values() {
            let reads: Vec<&str> = p.read.iter().map(|r| r.name.as_str()).collect();
            let reads = if reads.is_empty() { "nothing".to_string() } else { reads.join(", ") };
            lines.push(format!("modbus {}: reads {reads}, timeout {} ms", p.describe(), p.timeout.as_millis()));
        }
        if !self.faults.is_empty() {
            lines.push(format!("injected faults: {}", self.faults.describe()));
        }
        lines
    }

    /// One line saying what rig will drive, printed first by commands that move hardware.
    pub fn describe(&self) -> String {
        let mut rig = self.describe_rig();
        if !self.modbus.is_empty() {
            let list: Vec<String> = self.modbus.values().map(|m| m.describe()).collect();
            rig.push_str(&format!("; Modbus peripherals: {}", list.join(", ")));
        }
        if self.faults.is_empty() { rig } else { format!("{rig}; injecting faults: {}", self.faults.describe()) }
    }

    fn describe_rig(&self) -> String {
        match (&self.source, &self.arm.backend) {
            (None, _) => "no rig config found (--config, $RIG_CONFIG, ./rig.toml): using the built-in simulated rig (simulated MG400 over TCP on loopback, simulated sensors)".to_string(),
            (Some(p), ArmBackend::Simulated { time_scale }) => {
                format!("rig config {}: simulated MG400 ({time_scale}x real time)", p.display())
            }
            (Some(p), ArmBackend::Mg400 { host, dashboard_port, .. }) => {
                format!("rig config {}: MG400 at {host}:{dashboard_port}", p.display())
            }
            (Some(p), ArmBackend::Magician { serial_port }) => {
                format!("rig config {}: Dobot Magician on {}", p.display(), serial_port.display())
            }
        }
    }
}

/// Validates `[sim.faults]`.
fn resolve_faults(raw: &RawFaults, path: &Path) -> Result<FaultConfig, ConfigError> {
    use crate::bounds;
    let invalid = |field: &'static str, problem: String| ConfigError::Invalid { path: path.to_path_buf(), field, problem };
    let within = |bound: &bounds::Bound, field: &'static str, value: f64| bound.check(value).map(|_| ()).map_err(|p| invalid(field, p));
    if let Some(every) = raw.feedback_garbage_every {
        within(&bounds::FAULT_EVERY, "sim.faults.feedback_garbage_every", f64::from(every))?;
    }
    let moves = raw.collision_at_moves.clone().unwrap_or_default();
    let frames = raw.camera_timeout_at_frames.clone().unwrap_or_default();
    for (field, list) in [("sim.faults.collision_at_moves", &moves), ("sim.faults.camera_timeout_at_frames", &frames)] {
        within(&bounds::FAULT_COUNTS, field, list.len().max(1) as f64)?;
        if let Some(&bad) = list.iter().find(|&&n| !bounds::FAULT_COUNTS.contains(n as f64)) {
            return Err(invalid(field, format!("counts from 1: each {}, got {bad}", bounds::FAULT_COUNTS.range())));
        }
    }
    if let Some(every_s) = raw.drop_sockets_every_s {
        within(&bounds::FAULT_DROP_SOCKETS, "sim.faults.drop_sockets_every_s", every_s)?;
    }
    // A delay past the client's reply timeout would turn every command into a timeout.
    let reply_delay_ms = raw.reply_delay_ms.unwrap_or(0);
    bounds::FAULT_REPLY_DELAY.check(reply_delay_ms).map_err(|p| invalid("sim.faults.reply_delay_ms", p))?;
    let camera_timeout_ms = raw.camera_timeout_ms.unwrap_or(100);
    bounds::FAULT_CAMERA_TIMEOUT.check(camera_timeout_ms).map_err(|p| invalid("sim.faults.camera_timeout_ms", p))?;
    let mut faults = FaultConfig {
        controller: ControllerFaults {
            reply_delay: std::time::Duration::from_millis(reply_delay_ms),
            split_replies: raw.split_replies.unwrap_or(false),
            feedback_garbage_every: raw.feedback_garbage_every,
            feedback_start_mid_frame: raw.feedback_start_mid_frame.unwrap_or(false),
            collision_at_moves: moves,
            drop_dashboard_after: raw.drop_dashboard_after,
        },
        drop_sockets_every_s: raw.drop_sockets_every_s,
        camera_timeout_at_frames: frames,
        camera_timeout: std::time::Duration::from_millis(camera_timeout_ms),
        disk_budget_bytes: raw.disk_budget_bytes,
    };
    // The timeout length alone injects nothing; keep `is_empty` about real faults.
    if faults.camera_timeout_at_frames.is_empty() {
        faults.camera_timeout = FaultConfig::default().camera_timeout;
    }
    Ok(faults)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pose::Pose;

    #[test]
    fn sensor_unit_seed_is_read_and_defaults_to_none() {
        let c = RigConfig::parse("[sim]\nsensor_unit_seed = 11\n", Path::new("x")).unwrap();
        assert_eq!(c.sensor_unit_seed, Some(11));
        assert_eq!(RigConfig::parse("", Path::new("x")).unwrap().sensor_unit_seed, None);
        assert!(RigConfig::parse("[sim]\nsensor_unit_seed = -1\n", Path::new("x")).is_err());
    }

    #[test]
    fn empty_file_is_the_simulated_rig() {
        let c = RigConfig::parse("", Path::new("rig.toml")).unwrap();
        assert_eq!(c.arm.backend, ArmBackend::Simulated { time_scale: DEFAULT_SIM_TIME_SCALE });
        assert_eq!(c.collect, CollectConfig::default());
    }

    #[test]
    fn real_arm_needs_a_host() {
        let e = RigConfig::parse("[arm]\nbackend = \"mg400\"\n", Path::new("x.toml")).unwrap_err();
        assert!(e.to_string().contains("arm.host"), "{e}");
        let c = RigConfig::parse("[arm]\nbackend = \"mg400\"\nhost = \"192.168.1.6\"\n", Path::new("x.toml")).unwrap();
        assert!(matches!(c.arm.backend, ArmBackend::Mg400 { dashboard_port: 29999, .. }));
    }

    #[test]
    fn unknown_fields_and_bad_values_are_refused() {
        assert!(matches!(RigConfig::parse("[arm]\nspeed = 3\n", Path::new("x")), Err(ConfigError::Parse { .. })));
        let e = RigConfig::parse("[collect]\nframes_per_pose = 0\n", Path::new("x")).unwrap_err();
        assert!(e.to_string().contains("frames_per_pose"));
        let e = RigConfig::parse("[arm]\nspeed_factor = 0\n", Path::new("x")).unwrap_err();
        assert!(e.to_string().contains("speed_factor"));
    }

    /// Every number a configuration holds has a range ([`crate::bounds`]): a Modbus timeout of
    /// 2^64 - 1 ms, a move timeout of 10^9 s, a camera of 10^5 px a side are refused, naming
    /// the key and its range.
    #[test]
    fn numbers_out_of_their_range_are_refused() {
        for (text, key, range) in [
            (
                "[modbus.f]\ntransport = \"tcp\"\naddress = \"127.0.0.1:1\"\ntimeout_ms = 18446744073709551615\n",
                "timeout_ms",
                "1 to 60000 ms",
            ),
            ("[collect]\nmove_timeout_s = 1e9\n", "collect.move_timeout_s", "above 0 and at most 600 s"),
            ("[collect]\nretries_per_pose = 4000000000\n", "collect.retries_per_pose", "0 to 100"),
            ("[sensors.tactip]\nwidth = 100000\n", "sensors.*.width", "16 to 8192 px"),
            ("[sensors.tactip]\nwidth = 8192\nheight = 8192\n", "sensors.*.width", "16777216 px"),
            ("[sensors.tactip]\nexposure_100us = -5\n", "sensors.*.exposure_100us", "1 to 100000"),
            (
                "[work_frame]\norigin = { x_mm = 1e300, y_mm = 0.0, z_mm = 0.0, yaw_deg = 0.0 }\n",
                "work_frame.origin.x_mm",
                "-2000 to 2000 mm",
            ),
            ("[arm]\nbackend = \"mg400\"\nhost = \"h\"\ndashboard_port = 0\n", "arm.dashboard_port", "1 to 65535"),
            ("[sim.faults]\ndrop_sockets_every_s = 1e12\n", "sim.faults.drop_sockets_every_s", "at most 3600 s"),
        ] {
            let e = RigConfig::parse(text, Path::new("x")).expect_err(text).to_string();
            assert!(e.contains(key) && e.contains(range), "{text}: {e}");
        }
        let c =
            RigConfig::parse("[modbus.f]\ntransport = \"tcp\"\naddress = \"127.0.0.1:1\"\ntimeout_ms = 60000\n", Path::new("x")).unwrap();
        assert_eq!(c.modbus["f"].timeout, std::time::Duration::from_secs(60));
    }

    #[test]
    fn sim_faults_are_read_and_checked() {
        let c = RigConfig::parse(
            "[sim.faults]\nsplit_replies = true\ncollision_at_moves = [3, 8]\ncamera_timeout_at_frames = [2]\ndisk_budget_bytes = 4096\n",
            Path::new("x"),
        )
        .unwrap();
        assert!(c.faults.controller.split_replies);
        assert_eq!(c.faults.controller.collision_at_moves, vec![3, 8]);
        assert_eq!(c.faults.camera_timeout_at_frames, vec![2]);
        assert_eq!(c.faults.disk_budget_bytes, Some(4096));
        assert!(RigConfig::parse("", Path::new("x")).unwrap().faults.is_empty());
        let e = RigConfig::parse("[sim.faults]\ncollision_at_moves = [0]\n", Path::new("x")).unwrap_err();
        assert!(e.to_string().contains("collision_at_moves"), "{e}");
        let e =
            RigConfig::parse("[arm]\nbackend = \"mg400\"\nhost = \"h\"\n[sim.faults]\nsplit_replies = true\n", Path::new("x")).unwrap_err();
        assert!(e.to_string().contains("simulated arm"), "{e}");
    }

    #[test]
    fn the_bench_example_resolves() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/bench-rig.toml");
        let c = RigConfig::load(&path).unwrap();
        assert!(matches!(c.arm.backend, ArmBackend::Mg400 { .. }));
        let tactip = c.sensors.iter().find(|s| s.name == "tactip").unwrap();
        assert_eq!(tactip.backend, SensorBackend::V4l2 { device: "port:1-2.1".into() });
        assert_eq!(tactip.camera.exposure_100us, Some(156));
        assert_eq!(c.modbus.len(), 2);
        let e = RigConfig::parse("[sensors.tactip]\nbackend = \"v4l2\"\ndevice = \"video0\"\n", Path::new("x")).unwrap_err();
        assert!(e.to_string().contains("port:"), "{e}");
        let c = RigConfig::parse("[arm]\nbackend = \"magician\"\nserial_port = \"/dev/ttyUSB0\"\n", Path::new("x")).unwrap();
        assert_eq!(c.arm.backend, ArmBackend::Magician { serial_port: "/dev/ttyUSB0".into() });
        assert!(RigConfig::parse("[arm]\nbackend = \"magician\"\n", Path::new("x")).is_err());
    }

    /// Sensor sections go through the one sensor parser: any case names the sensor, a name
    /// that is none of the three is refused listing the valid ones.
    #[test]
    fn sensor_sections_take_any_case() {
        let c = RigConfig::parse("[sensors.ViTac]\nscene = \"full\"\n", Path::new("x")).unwrap();
        assert_eq!(c.sensors.iter().map(|s| s.name.as_str()).collect::<Vec<_>>(), vec!["vitac"]);
        let e = RigConfig::parse("[sensors.gelsight]\n", Path::new("x")).unwrap_err();
        assert!(e.to_string().contains("gelsight") && e.to_string().contains("tactip, vitac or vitactip"), "{e}");
        let e = RigConfig::parse("[sensors.tactip]\n[sensors.TacTip]\n", Path::new("x")).unwrap_err();
        assert!(e.to_string().contains("twice"), "{e}");
    }

    /// A sensor's press limit is its configured `max_indentation_mm`, else its default; a limit
    /// that is not above 0 and at most 20 mm is refused.
    #[test]
    fn press_limits_are_read_checked_and_defaulted() {
        use crate::sensor::SensorKind;
        let c = RigConfig::parse("[sensors.vitac]\nmax_indentation_mm = 3.25\n", Path::new("x")).unwrap();
        assert_eq!(c.press_limit(SensorKind::ViTac), PressLimit { sensor: SensorKind::ViTac, max_indentation_mm: 3.25, configured: true });
        assert_eq!(
            c.press_limit(SensorKind::TacTip),
            PressLimit { sensor: SensorKind::TacTip, max_indentation_mm: 5.0, configured: false }
        );
        assert_eq!(RigConfig::builtin_sim().press_limit(SensorKind::ViTacTip).max_indentation_mm, 2.5);
        for bad in ["0.0", "-1.0", "20.5", "nan", "inf"] {
            let e = RigConfig::parse(&format!("[sensors.tactip]\nmax_indentation_mm = {bad}\n"), Path::new("x")).unwrap_err();
            assert!(e.to_string().contains("max_indentation_mm") && e.to_string().contains("at most 20 mm"), "{bad}: {e}");
        }
        assert!(RigConfig::parse("[sensors.tactip]\nmax_indentation_mm = 20.0\n", Path::new("x")).is_ok());
    }

    #[test]
    fn work_frame_is_read() {
        let c = RigConfig::parse(
            "[work_frame]\norigin = { x_mm = 250.0, y_mm = 10.0, z_mm = -30.0, yaw_deg = 5.0 }\napproach_mm = 8.0\n",
            Path::new("x"),
        )
        .unwrap();
        assert_eq!(c.work_frame.origin, Pose::new(250.0, 10.0, -30.0, 5.0));
        assert_eq!(c.work_frame.approach_mm, 8.0);
        assert_eq!(c.work_frame.contact_depth_mm, 1.5);
    }
}
