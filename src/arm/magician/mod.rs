//! Dobot Magician over serial: its firmware profile and the [`Arm`] implementation.
//!
//! Layers: [`proto`] frames and parses the binary protocol (sans-io), [`transport`] runs
//! request/reply over a serial port, [`MagicianArm`] turns that into the [`Arm`] contract:
//!
//! - `enable`: clear alarms, clear the command queue, set PTP speed ratios, start the queue.
//! - `move_to`: a queued SetPTPCmd (MOVJ for [`MoveKind::Joint`], MOVL for
//!   [`MoveKind::Linear`]), remembering its queue index.
//! - `wait_arrived`: polls GetQueuedCmdCurrentIndex until that index has run and GetPose is
//!   within the profile's tolerance; an alarm raised meanwhile is an [`ArmError::Fault`].
//! - `stop`: force-stop and clear the queue. `disable`: stop the queue (the protocol has no
//!   motor power-off; the steppers keep holding).
//! - `firmware_version`: GetDeviceVersion, `major.minor.revision`.
//!
//! The Magician's `r` (end-effector rotation) is rig's `yaw_deg`. The blocking serial link runs
//! on tokio's blocking pool so the futures stay `Send` and never block the runtime.

pub mod proto;
pub mod transport;

use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use serde::Deserialize;

use crate::arm::{Alarm, Arm, ArmError, Arrival, MoveKind};
use crate::clock::Clock;
use crate::pose::Pose;
use proto::{Command, PtpMode, Reply};
use transport::{MagicianLink, TransportError};

/// The embedded default profile (`firmware-profiles/magician.toml`).
pub const DEFAULT_PROFILE_TOML: &str = include_str!("../../../firmware-profiles/magician.toml");

/// Errors reading a Magician profile.
#[derive(Debug, thiserror::Error)]
pub enum MagicianProfileError {
    #[error("cannot read {path}: {source}")]
    Read {
        path: std::path::PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: {source}")]
    Parse {
        path: std::path::PathBuf,
        #[source]
        source: crate::untrusted::SyntaxError,
    },
    #[error("{path}: {field} {problem}")]
    Invalid { path: std::path::PathBuf, field: &'static str, problem: String },
}

/// Serial settings.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MagicianSerial {
    pub baud: u32,
    pub reply_timeout_ms: u64,
}

/// Cartesian workspace: radius from the base axis, height, end-effector rotation.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MagicianWorkspace {
    pub radius_mm: [f64; 2],
    pub z_mm: [f64; 2],
    pub r_deg: [f64; 2],
}

/// PTP speed ratios.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MagicianSpeed {
    pub velocity_ratio_pct: f64,
    pub acceleration_ratio_pct: f64,
}

/// Arrival detection.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MagicianArrival {
    pub tolerance_mm: f64,
    pub poll_ms: u64,
}

/// `firmware-profiles/magician.toml`.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MagicianProfile {
    pub name: String,
    pub model: String,
    #[serde(default)]
    pub description: String,
    pub serial: MagicianSerial,
    pub workspace: MagicianWorkspace,
    pub speed: MagicianSpeed,
    pub arrival: MagicianArrival,
}

impl MagicianProfile {
    /// The embedded default profile.
    pub fn default_magician() -> Self {
        // The embedded file is checked by the test `embedded_profile_is_valid`.
        Self::parse(DEFAULT_PROFILE_TOML, Path::new("firmware-profiles/magician.toml"))
            .unwrap_or_else(|e| panic!("embedded magician profile: {e}"))
    }

    /// The profile a rig configuration names (`[arm] profile`), as
    /// [`FirmwareProfile::named`](crate::arm::profile::FirmwareProfile::named) finds an MG400
    /// profile; none is the embedded one.
    pub fn named(name: Option<&str>) -> Result<Self, crate::arm::profile::ProfileLookupError> {
        let Some(name) = name else { return Ok(Self::default_magician()) };
        let as_path = Path::new(name);
        let path = if as_path.extension().is_some_and(|e| e == "toml") || as_path.is_file() {
            as_path.to_path_buf()
        } else {
            crate::arm::profile::profile_path(name)
        };
        Self::load(&path).map_err(|e| crate::arm::profile::ProfileLookupError { name: name.to_string(), reason: e.to_string() })
    }

    pub fn load(path: &Path) -> Result<Self, MagicianProfileError> {
        let text = crate::untrusted::read_text(path, crate::untrusted::MAX_CONFIG_BYTES)
            .map_err(|source| MagicianProfileError::Read { path: path.to_path_buf(), source })?;
        Self::parse(&text, path)
    }

    pub fn parse(text: &str, path: &Path) -> Result<Self, MagicianProfileError> {
        let p: Self = toml::from_str(text).map_err(|e| MagicianProfileError::Parse {
            path: path.to_path_buf(),
            source: crate::untrusted::SyntaxError::from_toml(&e, text),
        })?;
        let invalid = |field, problem: String| MagicianProfileError::Invalid { path: path.to_path_buf(), field, problem };
        let range_ok = |r: [f64; 2]| r[0].is_finite() && r[1].is_finite() && r[0] < r[1];
        if !range_ok(p.workspace.radius_mm) || p.workspace.radius_mm[0] < 0.0 {
            return Err(invalid("workspace.radius_mm", format!("must be [min, max] with 0 <= min < max, got {:?}", p.workspace.radius_mm)));
        }
        if !range_ok(p.workspace.z_mm) {
            return Err(invalid("workspace.z_mm", format!("must be [min, max], got {:?}", p.workspace.z_mm)));
        }
        if !range_ok(p.workspace.r_deg) {
            return Err(invalid("workspace.r_deg", format!("must be [min, max], got {:?}", p.workspace.r_deg)));
        }
        for (field, v) in
            [("speed.velocity_ratio_pct", p.speed.velocity_ratio_pct), ("speed.acceleration_ratio_pct", p.speed.acceleration_ratio_pct)]
        {
            if !(v > 0.0 && v <= 100.0) {
                return Err(invalid(field, format!("must be in (0, 100], got {v}")));
            }
        }
        if !(p.arrival.tolerance_mm > 0.0 && p.arrival.tolerance_mm.is_finite()) {
            return Err(invalid("arrival.tolerance_mm", format!("must be above 0, got {}", p.arrival.tolerance_mm)));
        }
        // Every number within its documented range ([`crate::bounds`]).
        use crate::bounds;
        let within = |bound: &bounds::Bound, field: &'static str, value: f64| bound.check(value).map(|_| ()).map_err(|e| invalid(field, e));
        within(&bounds::MAGICIAN_BAUD, "serial.baud", f64::from(p.serial.baud))?;
        within(&bounds::MAGICIAN_REPLY_TIMEOUT, "serial.reply_timeout_ms", p.serial.reply_timeout_ms as f64)?;
        within(&bounds::MAGICIAN_POLL, "arrival.poll_ms", p.arrival.poll_ms as f64)?;
        within(&bounds::MAGICIAN_TOLERANCE, "arrival.tolerance_mm", p.arrival.tolerance_mm)?;
        for (field, r) in [("workspace.radius_mm", p.workspace.radius_mm), ("workspace.z_mm", p.workspace.z_mm)] {
            for v in r {
                within(&bounds::PROFILE_REACH, field, v)?;
            }
        }
        for v in p.workspace.r_deg {
            within(&bounds::MAGICIAN_ROTATION, "workspace.r_deg", v)?;
        }
        Ok(p)
    }

    /// Refuses targets outside the workspace before anything is sent.
    pub fn check_reachable(&self, pose: &Pose) -> Result<(), ArmError> {
        let w = &self.workspace;
        let radius = pose.x_mm.hypot(pose.y_mm);
        let unreachable = |limit: String| Err(ArmError::Unreachable { pose: *pose, limit });
        if !pose.is_finite() {
            return unreachable("non-finite coordinate".into());
        }
        if radius < w.radius_mm[0] || radius > w.radius_mm[1] {
            return unreachable(format!("radius {radius:.1} mm outside {:?} mm", w.radius_mm));
        }
        if pose.z_mm < w.z_mm[0] || pose.z_mm > w.z_mm[1] {
            return unreachable(format!("z {:.1} mm outside {:?} mm", pose.z_mm, w.z_mm));
        }
        if pose.yaw_deg < w.r_deg[0] || pose.yaw_deg > w.r_deg[1] {
            return unreachable(format!("r {:.1} deg outside {:?} deg", pose.yaw_deg, w.r_deg));
        }
        Ok(())
    }
}

/// What a Magician alarm code means, by the code ranges of the protocol's alarm table
/// (section 4.2: 0x00-0x0F common, 0x10-0x1F planning, 0x20-0x2F kinematics, 0x30-0x3F
/// overspeed, 0x40-0x4F joint limit, 0x50-0x5F lost step, 0x60-0x6F sensor/servo).
pub fn alarm_description(code: u16) -> String {
    let class = match code {
        0x00 => return "reset occurred".into(),
        0x01..=0x0F => "common alarm",
        0x10..=0x1F => "planning alarm (target not reachable by the planner)",
        0x20..=0x2F => "kinematics alarm",
        0x30..=0x3F => "overspeed alarm",
        0x40..=0x4F => "joint limit alarm",
        0x50..=0x5F => "lost-step alarm",
        _ => "other alarm",
    };
    format!("{class} {code:#04x}")
}

fn arm_error(context: &str, e: TransportError) -> ArmError {
    match e {
        TransportError::Timeout { after, .. } => ArmError::Timeout { what: context.to_string(), after },
        TransportError::Io(source) => ArmError::Io { context: context.to_string(), source },
        TransportError::Closed => ArmError::Io {
            context: context.to_string(),
            source: std::io::Error::new(std::io::ErrorKind::UnexpectedEof, "serial port closed"),
        },
        TransportError::Open { path, source } => {
            ArmError::Io { context: format!("opening {}", path.display()), source: std::io::Error::other(source) }
        }
        TransportError::Proto(p) => ArmError::Protocol(format!("{context}: {p}")),
    }
}

/// A Dobot Magician behind the [`Arm`] trait.
pub struct MagicianArm {
    link: Arc<Mutex<MagicianLink>>,
    profile: MagicianProfile,
    clock: Arc<dyn Clock>,
    /// Queue index of the last move sent; `None` before any or after a stop.
    last_queued: Option<u64>,
}

impl MagicianArm {
    /// Opens the serial port at `path` with the profile's settings.
    pub fn open(path: &Path, profile: MagicianProfile, clock: Arc<dyn Clock>) -> Result<Self, ArmError> {
        let link = MagicianLink::open(path, profile.serial.baud, Duration::from_millis(profile.serial.reply_timeout_ms))
            .map_err(|e| arm_error("opening the Magician's serial port", e))?;
        Ok(Self::with_link(link, profile, clock))
    }

    /// Drives a Magician over an already open link (tests: a pseudo-terminal).
    pub fn with_link(link: MagicianLink, profile: MagicianProfile, clock: Arc<dyn Clock>) -> Self {
        Self { link: Arc::new(Mutex::new(link)), profile, clock, last_queued: None }
    }

    pub fn profile(&self) -> &MagicianProfile {
        &self.profile
    }

    /// One request on the blocking pool.
    async fn request(&self, command: Command, context: &'static str) -> Result<Reply, ArmError> {
        let link = Arc::clone(&self.link);
        let result = tokio::task::spawn_blocking(move || {
            // A panic while holding the lock leaves at worst unread bytes, which the framer
            // skips as stale; the link stays usable.
            let mut link = link.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
            link.request(&command)
        })
        .await
        .map_err(|e| ArmError::Io { context: context.to_string(), source: std::io::Error::other(e) })?;
        result.map_err(|e| arm_error(context, e))
    }

    /// The active alarms, named (read only: nothing is cleared).
    pub async fn alarms(&self) -> Result<Vec<Alarm>, ArmError> {
        match self.request(Command::GetAlarmsState, "reading alarms").await? {
            Reply::Alarms(codes) => {
                Ok(codes.into_iter().map(|c| Alarm { source: 0, id: i64::from(c), description: alarm_description(c) }).collect())
            }
            other => Err(ArmError::Protocol(format!("GetAlarmsState answered {other:?}"))),
        }
    }

    async fn current_index(&self) -> Result<u64, ArmError> {
        match self.request(Command::GetQueuedCurrentIndex, "reading the queue index").await? {
            Reply::CurrentIndex(i) => Ok(i),
            other => Err(ArmError::Protocol(format!("GetQueuedCmdCurrentIndex answered {other:?}"))),
        }
    }
}

impl Arm for MagicianArm {
    async fn enable(&mut self) -> Result<(), ArmError> {
        self.request(Command::ClearAllAlarmsState, "clearing alarms").await?;
        self.request(Command::QueuedClear, "clearing the command queue").await?;
        let speed = Command::SetPtpCommonParams {
            velocity_ratio_pct: self.profile.speed.velocity_ratio_pct as f32,
            acceleration_ratio_pct: self.profile.speed.acceleration_ratio_pct as f32,
        };
        self.request(speed, "setting PTP speed").await?;
        self.request(Command::QueuedStartExec, "starting the command queue").await?;
        self.last_queued = None;
        Ok(())
    }

    async fn move_to(&mut self, target: Pose, kind: MoveKind) -> Result<(), ArmError> {
        self.profile.check_reachable(&target)?;
        let mode = match kind {
            MoveKind::Joint => PtpMode::MovjXyz,
            MoveKind::Linear => PtpMode::MovlXyz,
        };
        let command = Command::SetPtp {
            mode,
            x_mm: target.x_mm as f32,
            y_mm: target.y_mm as f32,
            z_mm: target.z_mm as f32,
            r_deg: target.yaw_deg as f32,
        };
        match self.request(command, "queueing a PTP move").await? {
            Reply::QueuedIndex(i) => {
                self.last_queued = Some(i);
                Ok(())
            }
            other => Err(ArmError::Protocol(format!("SetPTPCmd answered {other:?}"))),
        }
    }

    async fn wait_arrived(&mut self, target: Pose, timeout: Duration) -> Result<Arrival, ArmError> {
        let start_s = self.clock.now_s();
        let poll = Duration::from_millis(self.profile.arrival.poll_ms.max(1));
        loop {
            let alarms = self.alarms().await?;
            if !alarms.is_empty() {
                return Err(ArmError::Fault { alarms });
            }
            let done = match self.last_queued {
                Some(i) => self.current_index().await? >= i,
                None => true,
            };
            if done {
                let measured = self.pose().await?;
                let error_mm = measured.distance_mm(&target);
                if error_mm <= self.profile.arrival.tolerance_mm {
                    return Ok(Arrival { measured, error_mm, t_s: self.clock.now_s() });
                }
            }
            if self.clock.now_s() - start_s > timeout.as_secs_f64() {
                return Err(ArmError::Timeout { what: format!("waiting for the Magician to reach {target}"), after: timeout });
            }
            tokio::time::sleep(self.clock.real_duration(poll)).await;
        }
    }

    async fn pose(&mut self) -> Result<Pose, ArmError> {
        match self.request(Command::GetPose, "reading the pose").await? {
            Reply::Pose(p) => Ok(Pose::new(f64::from(p.x_mm), f64::from(p.y_mm), f64::from(p.z_mm), f64::from(p.r_deg))),
            other => Err(ArmError::Protocol(format!("GetPose answered {other:?}"))),
        }
    }

    async fn stop(&mut self) -> Result<(), ArmError> {
        self.request(Command::QueuedForceStopExec, "stopping the queue").await?;
        self.request(Command::QueuedClear, "clearing the command queue").await?;
        self.last_queued = None;
        Ok(())
    }

    async fn clear_error(&mut self) -> Result<Vec<Alarm>, ArmError> {
        let alarms = self.alarms().await?;
        self.request(Command::ClearAllAlarmsState, "clearing alarms").await?;
        self.request(Command::QueuedClear, "clearing the command queue").await?;
        self.request(Command::QueuedStartExec, "starting the command queue").await?;
        self.last_queued = None;
        Ok(alarms)
    }

    async fn disable(&mut self) -> Result<(), ArmError> {
        self.request(Command::QueuedStopExec, "stopping the queue").await?;
        Ok(())
    }

    async fn firmware_version(&mut self) -> Option<String> {
        match self.request(Command::GetDeviceVersion, "reading the firmware version").await {
            Ok(Reply::DeviceVersion(version)) => Some(version.to_string()),
            Ok(other) => {
                tracing::warn!("GetDeviceVersion answered {other:?}; recording no firmware version");
                None
            }
            Err(e) => {
                tracing::warn!(error = %e, "the Magician did not report its firmware version");
                None
            }
        }
    }
}

#[cfg(all(test, unix))]
mod tests {
    use super::*;
    use crate::clock::MonotonicClock;
    use crate::io::serial::PtyPair;
    use crate::sim::magician::SimMagician;
    use proto::MagicianPose;

    #[test]
    fn embedded_profile_is_valid() {
        let p = MagicianProfile::default_magician();
        assert_eq!(p.serial.baud, 115_200);
        assert!(p.check_reachable(&Pose::new(200.0, 0.0, 0.0, 0.0)).is_ok());
        assert!(matches!(p.check_reachable(&Pose::new(400.0, 0.0, 0.0, 0.0)), Err(ArmError::Unreachable { .. })));
        assert!(matches!(p.check_reachable(&Pose::new(200.0, 0.0, 0.0, 170.0)), Err(ArmError::Unreachable { .. })));
        let broken = DEFAULT_PROFILE_TOML.replace("velocity_ratio_pct = 50.0", "velocity_ratio_pct = 0.0");
        assert!(MagicianProfile::parse(&broken, Path::new("x")).is_err());
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn arm_contract_over_a_pseudo_terminal() {
        let pty = PtyPair::open().unwrap();
        let start = MagicianPose { x_mm: 200.0, y_mm: 0.0, z_mm: 50.0, r_deg: 0.0, joints_deg: [0.0; 4] };
        let mut sim = SimMagician::new(start);
        sim.alarms = vec![0x00];
        let server = sim.serve_in_thread(pty.master_file().unwrap());
        let profile = MagicianProfile::default_magician();
        let mut arm = MagicianArm::open(&pty.slave_path, profile, Arc::new(MonotonicClock::new())).unwrap();

        // The simulator's firmware version, as the controller reports it.
        assert_eq!(arm.firmware_version().await.as_deref(), Some("3.7.0"));
        // A reset alarm is pending: enable clears it.
        arm.enable().await.unwrap();
        let target = Pose::new(220.0, 10.0, 20.0, 15.0);
        arm.move_to(target, MoveKind::Linear).await.unwrap();
        let arrival = arm.wait_arrived(target, Duration::from_secs(5)).await.unwrap();
        assert!(arrival.error_mm < 1e-3, "{arrival:?}");
        assert_eq!(arm.pose().await.unwrap(), target);
        // Out of the workspace: refused before sending.
        let far = Pose::new(500.0, 0.0, 0.0, 0.0);
        assert!(matches!(arm.move_to(far, MoveKind::Joint).await, Err(ArmError::Unreachable { .. })));
        arm.stop().await.unwrap();
        assert!(arm.clear_error().await.unwrap().is_empty());
        arm.disable().await.unwrap();
        drop(arm);
        server.stop();
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_move_the_queue_never_runs_times_out() {
        let pty = PtyPair::open().unwrap();
        let start = MagicianPose { x_mm: 200.0, y_mm: 0.0, z_mm: 50.0, r_deg: 0.0, joints_deg: [0.0; 4] };
        let server = SimMagician::new(start).serve_in_thread(pty.master_file().unwrap());
        let mut arm = MagicianArm::open(&pty.slave_path, MagicianProfile::default_magician(), Arc::new(MonotonicClock::new())).unwrap();
        // No enable: the queue never runs, so the move can only time out.
        let target = Pose::new(210.0, 0.0, 50.0, 0.0);
        arm.move_to(target, MoveKind::Joint).await.unwrap();
        let e = arm.wait_arrived(target, Duration::from_millis(200)).await.unwrap_err();
        assert!(matches!(e, ArmError::Timeout { .. }), "{e}");
        drop(arm);
        server.stop();
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_controller_that_does_not_answer_the_version_query_reports_none() {
        let pty = PtyPair::open().unwrap();
        // A device that reads requests and never answers.
        let mut master = pty.master_file().unwrap();
        let silent = std::thread::spawn(move || {
            let mut buf = [0u8; 64];
            while matches!(std::io::Read::read(&mut master, &mut buf), Ok(n) if n > 0) {}
        });
        let mut profile = MagicianProfile::default_magician();
        profile.serial.reply_timeout_ms = 50;
        let mut arm = MagicianArm::open(&pty.slave_path, profile, Arc::new(MonotonicClock::new())).unwrap();
        assert_eq!(arm.firmware_version().await, None);
        drop(arm);
        // Closing the terminal ends the silent device's read.
        drop(pty);
        drop(silent);
    }
}
