//! Firmware profiles: what one robot/firmware dialect allows.
//!
//! A profile is a TOML file in `firmware-profiles/` (ports, feedback layout, joint limits, the
//! J3−J2 parallelogram rule, the Cartesian workspace, speed limits, kinematic constants). The
//! default, `mg400-v1.6`, is embedded in the binary so rig works from any directory.
//!
//! Loading is two-stage: the file is deserialised as written (unknown keys refused), then
//! [`FirmwareProfile::validate`] checks that every range is ordered and every speed positive.
//!
//! [`FirmwareProfile::check_reachable`] is the fence in front of the arm: every target passes
//! through it before a byte is sent, and a refusal names the pose and the limit.
//! [`FirmwareProfile::motion_time_s`] is the motion-time model the plan optimiser uses.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::arm::ArmError;
use crate::arm::kinematics::{Joints, KinematicsError, Mg400Geometry};
use crate::pose::Pose;

/// The embedded default profile text.
const MG400_V1_6: &str = include_str!("../../firmware-profiles/mg400-v1.6.toml");

/// Transport settings of the three-socket TCP dialect.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TransportProfile {
    pub dashboard_port: u16,
    pub motion_port: u16,
    pub feedback_port: u16,
    pub feedback_frame_len: usize,
    pub feedback_period_ms: u64,
    /// Most motion commands rig keeps queued on the controller at once.
    pub max_queued_commands: usize,
}

/// Joint limits, degrees, as `[min, max]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JointLimits {
    pub j1_deg: [f64; 2],
    pub j2_deg: [f64; 2],
    pub j3_deg: [f64; 2],
    pub j4_deg: [f64; 2],
    /// Allowed J3 − J2 (the parallelogram rule).
    pub j3_minus_j2_deg: [f64; 2],
    /// Minimum J2 whenever J3 ≤ 0.
    pub j2_min_when_j3_nonpositive_deg: f64,
}

/// Cartesian fence: flange radius from the base axis and height, mm.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Workspace {
    pub radius_mm: [f64; 2],
    pub z_mm: [f64; 2],
}

/// Speed and acceleration limits at 100 % speed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpeedLimits {
    pub joint_speed_deg_s: [f64; 4],
    pub joint_acc_deg_s2: [f64; 4],
    pub linear_speed_mm_s: f64,
    pub linear_acc_mm_s2: f64,
    pub yaw_speed_deg_s: f64,
    pub yaw_acc_deg_s2: f64,
}

/// One robot/firmware dialect.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FirmwareProfile {
    pub name: String,
    pub model: String,
    pub firmware: String,
    pub description: String,
    pub transport: TransportProfile,
    pub kinematics: Mg400Geometry,
    pub joint_limits: JointLimits,
    pub workspace: Workspace,
    pub speed: SpeedLimits,
}

/// Errors loading a profile.
#[derive(Debug, thiserror::Error)]
pub enum ProfileError {
    #[error("cannot read firmware profile {path}: {source}")]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("firmware profile {path} is not valid TOML for a profile: {source}")]
    Parse {
        path: PathBuf,
        #[source]
        source: crate::untrusted::SyntaxError,
    },
    #[error("firmware profile {name}: {field} is invalid: {problem}")]
    Invalid { name: String, field: &'static str, problem: String },
}

/// Why a pose or joint set is outside the profile. Its text is the `limit` of
/// [`ArmError::Unreachable`].
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ReachError {
    #[error("the pose has a non-finite component")]
    NonFinite,
    #[error("z = {z_mm:.3} mm is outside the workspace height [{min_mm}, {max_mm}] mm")]
    Height { z_mm: f64, min_mm: f64, max_mm: f64 },
    #[error("radius {radius_mm:.3} mm from the base axis is outside the workspace [{min_mm}, {max_mm}] mm")]
    Radius { radius_mm: f64, min_mm: f64, max_mm: f64 },
    #[error("no joint solution: {0}")]
    Kinematics(KinematicsError),
    #[error("J{joint} = {value_deg:.3} deg is outside its limit [{min_deg}, {max_deg}] deg")]
    Joint { joint: u8, value_deg: f64, min_deg: f64, max_deg: f64 },
    #[error("J3 - J2 = {diff_deg:.3} deg is outside the parallelogram limit [{min_deg}, {max_deg}] deg")]
    Parallelogram { diff_deg: f64, min_deg: f64, max_deg: f64 },
    #[error("J2 = {j2_deg:.3} deg is below {min_deg} deg while J3 <= 0 (self-collision zone)")]
    LowElbow { j2_deg: f64, min_deg: f64 },
}

/// A profile named in a rig configuration that could not be found or read.
#[derive(Debug, thiserror::Error)]
#[error("firmware profile {name}: {reason}")]
pub struct ProfileLookupError {
    pub name: String,
    pub reason: String,
}

/// `firmware-profiles/<name>.toml` in the working folder when it is there, else in rig's own
/// folder of profiles.
pub fn profile_path(name: &str) -> PathBuf {
    let file = format!("{name}.toml");
    let local = Path::new("firmware-profiles").join(&file);
    if local.is_file() { local } else { Path::new(env!("CARGO_MANIFEST_DIR")).join("firmware-profiles").join(file) }
}

impl FirmwareProfile {
    /// The embedded `mg400-v1.6` profile (the default).
    pub fn default_mg400() -> FirmwareProfile {
        // The embedded text is part of the binary and covered by a test; failing here is a
        // build defect, not bad input.
        Self::parse(MG400_V1_6, Path::new("<embedded mg400-v1.6>")).expect("the embedded mg400-v1.6 profile is valid")
    }

    /// Loads and validates a profile file.
    pub fn load(path: impl AsRef<Path>) -> Result<FirmwareProfile, ProfileError> {
        let path = path.as_ref();
        let text = crate::untrusted::read_text(path, crate::untrusted::MAX_CONFIG_BYTES)
            .map_err(|source| ProfileError::Read { path: path.to_path_buf(), source })?;
        Self::parse(&text, path)
    }

    /// The profile a rig configuration names (`[arm] profile`): none is the embedded MG400
    /// V1.6 profile; a name ending in `.toml` or naming an existing file is that file; any
    /// other name is `firmware-profiles/<name>.toml` in the working folder, else in rig's own.
    pub fn named(name: Option<&str>) -> Result<FirmwareProfile, ProfileLookupError> {
        let Some(name) = name else { return Ok(Self::default_mg400()) };
        let as_path = Path::new(name);
        let found = if as_path.extension().is_some_and(|e| e == "toml") || as_path.is_file() {
            FirmwareProfile::load(as_path)
        } else {
            let dir = profile_path(name).parent().map(Path::to_path_buf).unwrap_or_default();
            FirmwareProfile::by_name(dir, name)
        };
        found.map_err(|e| ProfileLookupError { name: name.to_string(), reason: e.to_string() })
    }

    /// Motion time between two consecutive plan poses, s: the travel at the approach height
    /// of `work_frame` (retract and descent are the same for every pair, so they do not change
    /// the order of a plan).
    pub fn pose_cost_s(&self, work_frame: &crate::pose::WorkFrame, a: &Pose, b: &Pose) -> f64 {
        self.motion_time_s(&work_frame.approach_pose(a), &work_frame.approach_pose(b))
    }

    /// Loads `firmware-profiles/<name>.toml` under `dir`, or the embedded default when `name`
    /// is `mg400-v1.6` and no such file exists.
    pub fn by_name(dir: impl AsRef<Path>, name: &str) -> Result<FirmwareProfile, ProfileError> {
        let path = dir.as_ref().join(format!("{name}.toml"));
        if name == "mg400-v1.6" && !path.exists() {
            return Ok(Self::default_mg400());
        }
        Self::load(path)
    }

    /// Parses and validates profile text; `path` is only used in errors.
    pub fn parse(text: &str, path: &Path) -> Result<FirmwareProfile, ProfileError> {
        let profile: FirmwareProfile = toml::from_str(text)
            .map_err(|e| ProfileError::Parse { path: path.to_path_buf(), source: crate::untrusted::SyntaxError::from_toml(&e, text) })?;
        profile.validate()?;
        Ok(profile)
    }

    /// Checks ranges are ordered and finite, speeds positive.
    pub fn validate(&self) -> Result<(), ProfileError> {
        let invalid = |field, problem: String| ProfileError::Invalid { name: self.name.clone(), field, problem };
        let range = |field, r: [f64; 2]| {
            if r[0].is_finite() && r[1].is_finite() && r[0] <= r[1] {
                Ok(())
            } else {
                Err(invalid(field, format!("[{}, {}] is not an ordered finite range", r[0], r[1])))
            }
        };
        let l = &self.joint_limits;
        range("joint_limits.j1_deg", l.j1_deg)?;
        range("joint_limits.j2_deg", l.j2_deg)?;
        range("joint_limits.j3_deg", l.j3_deg)?;
        range("joint_limits.j4_deg", l.j4_deg)?;
        range("joint_limits.j3_minus_j2_deg", l.j3_minus_j2_deg)?;
        range("workspace.radius_mm", self.workspace.radius_mm)?;
        range("workspace.z_mm", self.workspace.z_mm)?;
        let s = &self.speed;
        let positives = s.joint_speed_deg_s.iter().chain(&s.joint_acc_deg_s2).chain([
            &s.linear_speed_mm_s,
            &s.linear_acc_mm_s2,
            &s.yaw_speed_deg_s,
            &s.yaw_acc_deg_s2,
        ]);
        for v in positives {
            if !(v.is_finite() && *v > 0.0) {
                return Err(invalid("speed", format!("{v} is not a positive speed or acceleration")));
            }
        }
        let k = &self.kinematics;
        if !(k.link2_mm > 0.0 && k.link3_mm > 0.0 && k.r_offset_mm.is_finite() && k.z_offset_mm.is_finite()) {
            return Err(invalid("kinematics", "link lengths must be positive and offsets finite".into()));
        }
        // Every number within its documented range ([`crate::bounds`]).
        use crate::bounds;
        let within = |bound: &bounds::Bound, field: &'static str, value: f64| bound.check(value).map(|_| ()).map_err(|p| invalid(field, p));
        let t = &self.transport;
        for (field, port) in [
            ("transport.dashboard_port", t.dashboard_port),
            ("transport.motion_port", t.motion_port),
            ("transport.feedback_port", t.feedback_port),
        ] {
            within(&bounds::PROFILE_PORT, field, f64::from(port))?;
        }
        within(&bounds::PROFILE_FRAME_LEN, "transport.feedback_frame_len", t.feedback_frame_len as f64)?;
        within(&bounds::PROFILE_FEEDBACK_PERIOD, "transport.feedback_period_ms", t.feedback_period_ms as f64)?;
        within(&bounds::PROFILE_QUEUE, "transport.max_queued_commands", t.max_queued_commands as f64)?;
        for (field, r) in [
            ("joint_limits.j1_deg", l.j1_deg),
            ("joint_limits.j2_deg", l.j2_deg),
            ("joint_limits.j3_deg", l.j3_deg),
            ("joint_limits.j4_deg", l.j4_deg),
            ("joint_limits.j3_minus_j2_deg", l.j3_minus_j2_deg),
        ] {
            for v in r {
                within(&bounds::PROFILE_JOINT, field, v)?;
            }
        }
        within(&bounds::PROFILE_JOINT, "joint_limits.j2_min_when_j3_nonpositive_deg", l.j2_min_when_j3_nonpositive_deg)?;
        for (field, v) in [
            ("workspace.radius_mm", self.workspace.radius_mm[0]),
            ("workspace.radius_mm", self.workspace.radius_mm[1]),
            ("workspace.z_mm", self.workspace.z_mm[0]),
            ("workspace.z_mm", self.workspace.z_mm[1]),
            ("kinematics.link2_mm", k.link2_mm),
            ("kinematics.link3_mm", k.link3_mm),
            ("kinematics.r_offset_mm", k.r_offset_mm),
            ("kinematics.z_offset_mm", k.z_offset_mm),
        ] {
            within(&bounds::PROFILE_REACH, field, v)?;
        }
        if self.workspace.radius_mm[0] < 0.0 {
            return Err(invalid("workspace.radius_mm", format!("a radius is at least 0 mm, got {}", self.workspace.radius_mm[0])));
        }
        for v in s.joint_speed_deg_s.iter().chain(&s.joint_acc_deg_s2).chain([
            &s.linear_speed_mm_s,
            &s.linear_acc_mm_s2,
            &s.yaw_speed_deg_s,
            &s.yaw_acc_deg_s2,
        ]) {
            within(&bounds::PROFILE_SPEED, "speed", *v)?;
        }
        Ok(())
    }

    /// Refuses a base-frame target outside the profile, naming the pose and the limit.
    pub fn check_reachable(&self, base_pose: &Pose) -> Result<(), ArmError> {
        self.reach(base_pose)
            .map(|_| ())
            .map_err(|e| ArmError::Unreachable { pose: *base_pose, limit: format!("{e} (profile {})", self.name) })
    }

    /// The joint angles for `pose` when it is inside the profile, else the violated limit.
    pub fn reach(&self, pose: &Pose) -> Result<Joints, ReachError> {
        if !pose.is_finite() {
            return Err(ReachError::NonFinite);
        }
        let [z_min, z_max] = self.workspace.z_mm;
        if pose.z_mm < z_min || pose.z_mm > z_max {
            return Err(ReachError::Height { z_mm: pose.z_mm, min_mm: z_min, max_mm: z_max });
        }
        let radius = pose.x_mm.hypot(pose.y_mm);
        let [r_min, r_max] = self.workspace.radius_mm;
        if radius < r_min || radius > r_max {
            return Err(ReachError::Radius { radius_mm: radius, min_mm: r_min, max_mm: r_max });
        }
        let joints = self.kinematics.inverse(pose).map_err(ReachError::Kinematics)?;
        self.check_joints(&joints)?;
        Ok(joints)
    }

    /// Checks joint angles against the joint limits and the parallelogram rules.
    pub fn check_joints(&self, j: &Joints) -> Result<(), ReachError> {
        let l = &self.joint_limits;
        for (joint, value, [min, max]) in
            [(1u8, j.j1_deg, l.j1_deg), (2, j.j2_deg, l.j2_deg), (3, j.j3_deg, l.j3_deg), (4, j.j4_deg, l.j4_deg)]
        {
            if !(value >= min && value <= max) {
                return Err(ReachError::Joint { joint, value_deg: value, min_deg: min, max_deg: max });
            }
        }
        let diff = j.j3_deg - j.j2_deg;
        let [min, max] = l.j3_minus_j2_deg;
        if diff < min || diff > max {
            return Err(ReachError::Parallelogram { diff_deg: diff, min_deg: min, max_deg: max });
        }
        if j.j3_deg <= 0.0 && j.j2_deg < l.j2_min_when_j3_nonpositive_deg {
            return Err(ReachError::LowElbow { j2_deg: j.j2_deg, min_deg: l.j2_min_when_j3_nonpositive_deg });
        }
        Ok(())
    }

    /// Seconds a joint move from `from` to `to` takes at 100 % speed: each joint follows a
    /// trapezoidal (or, for short moves, triangular) velocity profile under the profile's speed
    /// and acceleration limits, and the move lasts as long as its slowest joint. Yaw enters
    /// through J4. A pose without a joint solution falls back to a straight-line estimate at
    /// the linear limits, so the optimiser still gets a finite cost.
    pub fn motion_time_s(&self, from: &Pose, to: &Pose) -> f64 {
        let s = &self.speed;
        match (self.kinematics.inverse(from), self.kinematics.inverse(to)) {
            (Ok(a), Ok(b)) => {
                let (a, b) = (a.to_array(), b.to_array());
                (0..4).map(|i| trapezoid_time_s((b[i] - a[i]).abs(), s.joint_speed_deg_s[i], s.joint_acc_deg_s2[i])).fold(0.0, f64::max)
            }
            _ => {
                let linear = trapezoid_time_s(from.distance_mm(to), s.linear_speed_mm_s, s.linear_acc_mm_s2);
                let yaw = trapezoid_time_s(from.yaw_error_deg(to), s.yaw_speed_deg_s, s.yaw_acc_deg_s2);
                let t = linear.max(yaw);
                if t.is_finite() { t } else { f64::MAX }
            }
        }
    }
}

/// Time to travel `distance` from rest to rest with speed limit `v_max` and acceleration
/// limit `a_max`: triangular when the distance is too short to reach `v_max`.
pub fn trapezoid_time_s(distance: f64, v_max: f64, a_max: f64) -> f64 {
    // Also catches NaN: no distance, no time.
    if distance.is_nan() || distance <= 0.0 {
        return 0.0;
    }
    if distance <= v_max * v_max / a_max { 2.0 * (distance / a_max).sqrt() } else { distance / v_max + v_max / a_max }
}

/// Position fraction in [0, 1] at time fraction `tau` in [0, 1] of a rest-to-rest trapezoidal
/// profile whose acceleration phase takes `accel_fraction` (≤ 0.5) of the move.
pub fn trapezoid_fraction(tau: f64, accel_fraction: f64) -> f64 {
    let tau = tau.clamp(0.0, 1.0);
    let fa = accel_fraction.clamp(1e-9, 0.5);
    // Peak speed (in units of distance per move time) so that the area is 1.
    let v = 1.0 / (1.0 - fa);
    if tau < fa {
        0.5 * v / fa * tau * tau
    } else if tau <= 1.0 - fa {
        0.5 * v * fa + v * (tau - fa)
    } else {
        let rest = 1.0 - tau;
        1.0 - 0.5 * v / fa * rest * rest
    }
}

/// The acceleration fraction of a trapezoid move over `distance` (for [`trapezoid_fraction`]).
pub fn trapezoid_accel_fraction(distance: f64, v_max: f64, a_max: f64) -> f64 {
    let total = trapezoid_time_s(distance, v_max, a_max);
    if total <= 0.0 {
        return 0.5;
    }
    let t_acc = (v_max / a_max).min(total / 2.0);
    (t_acc / total).min(0.5)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn embedded_default_loads_and_matches_file() {
        let p = FirmwareProfile::default_mg400();
        assert_eq!(p.name, "mg400-v1.6");
        assert_eq!(p.transport.dashboard_port, 29999);
        assert_eq!(p.transport.feedback_frame_len, 1440);
        let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/firmware-profiles");
        assert_eq!(FirmwareProfile::load(format!("{dir}/mg400-v1.6.toml")).unwrap(), p);
        assert_eq!(FirmwareProfile::by_name("/nonexistent", "mg400-v1.6").unwrap(), p);
    }

    #[test]
    fn bad_profiles_are_refused() {
        let text = MG400_V1_6.replace("j2_deg = [-25.0, 85.0]", "j2_deg = [85.0, -25.0]");
        assert!(matches!(FirmwareProfile::parse(&text, Path::new("x")), Err(ProfileError::Invalid { field: "joint_limits.j2_deg", .. })));
        let text = format!("{MG400_V1_6}\nsurprise = 1\n");
        assert!(matches!(FirmwareProfile::parse(&text, Path::new("x")), Err(ProfileError::Parse { .. })));
        assert!(matches!(FirmwareProfile::load("/nonexistent/p.toml"), Err(ProfileError::Read { .. })));
    }

    #[test]
    fn reachability_names_the_limit() {
        let p = FirmwareProfile::default_mg400();
        p.check_reachable(&Pose::new(300.0, 0.0, -20.0, 0.0)).unwrap();
        p.check_reachable(&Pose::new(20.0, 280.0, -60.0, 200.0)).unwrap();
        let refuse = |pose: Pose| match p.check_reachable(&pose) {
            Err(ArmError::Unreachable { pose: got, limit }) => {
                assert_eq!(format!("{got}"), format!("{pose}"));
                limit
            }
            other => panic!("expected Unreachable for {pose}, got {other:?}"),
        };
        assert!(refuse(Pose::new(300.0, 0.0, 250.0, 0.0)).contains("height"));
        assert!(refuse(Pose::new(600.0, 0.0, 0.0, 0.0)).contains("radius"));
        assert!(refuse(Pose::new(-300.0, 10.0, 0.0, 0.0)).contains("J1"));
        assert!(refuse(Pose::new(300.0, 0.0, 0.0, 400.0)).contains("J4"));
        assert!(refuse(Pose::new(f64::NAN, 0.0, 0.0, 0.0)).contains("non-finite"));
        // Close in and high: J3 - J2 leaves the parallelogram range or J2 its limit.
        let limit = refuse(Pose::new(190.0, 0.0, 190.0, 0.0));
        assert!(limit.contains("J") && limit.contains("mg400-v1.6"), "{limit}");
    }

    #[test]
    fn motion_time_model() {
        let p = FirmwareProfile::default_mg400();
        let a = Pose::new(300.0, 0.0, -20.0, 0.0);
        assert_eq!(p.motion_time_s(&a, &a), 0.0);
        let near = p.motion_time_s(&a, &Pose::new(301.0, 0.0, -20.0, 0.0));
        let far = p.motion_time_s(&a, &Pose::new(250.0, 100.0, -20.0, 0.0));
        assert!(near > 0.0 && far > near);
        // Pure yaw moves J4 only: 90 deg at 600 deg/s^2 never reaches 300 deg/s (triangular);
        // 170 deg does (trapezoid).
        let yaw = p.motion_time_s(&a, &Pose::new(300.0, 0.0, -20.0, 90.0));
        assert!((yaw - 2.0 * (90.0f64 / 600.0).sqrt()).abs() < 1e-9, "{yaw}");
        let yaw = p.motion_time_s(&Pose::new(300.0, 0.0, -20.0, -85.0), &Pose::new(300.0, 0.0, -20.0, 85.0));
        assert!((yaw - (170.0 / 300.0 + 300.0 / 600.0)).abs() < 1e-9, "{yaw}");
        // Symmetric.
        assert!((far - p.motion_time_s(&Pose::new(250.0, 100.0, -20.0, 0.0), &a)).abs() < 1e-9);
    }

    #[test]
    fn trapezoid_shape() {
        assert_eq!(trapezoid_time_s(0.0, 1.0, 1.0), 0.0);
        assert!((trapezoid_time_s(0.25, 1.0, 1.0) - 1.0).abs() < 1e-12); // triangular
        assert!((trapezoid_time_s(3.0, 1.0, 1.0) - 4.0).abs() < 1e-12);
        for fa in [0.1, 0.25, 0.5] {
            assert_eq!(trapezoid_fraction(0.0, fa), 0.0);
            assert!((trapezoid_fraction(1.0, fa) - 1.0).abs() < 1e-12);
            assert!((trapezoid_fraction(0.5, fa) - 0.5).abs() < 1e-12);
            let mut last = 0.0;
            for i in 0..=100 {
                let s = trapezoid_fraction(i as f64 / 100.0, fa);
                assert!(s >= last - 1e-12);
                last = s;
            }
        }
    }
}
