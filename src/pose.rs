//! Poses and frames.
//!
//! A [`Pose`] is the 4-DoF pose rig works with everywhere: position in mm and yaw in degrees.
//! Which frame a pose lives in is said by the name of the variable or field holding it
//! (`base_pose`: the robot base frame; `plan_pose`/`object_pose`: the work frame, relative to
//! the object's contact point). [`WorkFrame`] converts between the two.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

/// A 4-DoF pose: position in mm, yaw (rotation about z) in degrees.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Pose {
    pub x_mm: f64,
    pub y_mm: f64,
    pub z_mm: f64,
    pub yaw_deg: f64,
}

impl Pose {
    pub const fn new(x_mm: f64, y_mm: f64, z_mm: f64, yaw_deg: f64) -> Self {
        Self { x_mm, y_mm, z_mm, yaw_deg }
    }

    /// Euclidean distance between the positions, mm.
    pub fn distance_mm(&self, other: &Pose) -> f64 {
        ((self.x_mm - other.x_mm).powi(2) + (self.y_mm - other.y_mm).powi(2) + (self.z_mm - other.z_mm).powi(2)).sqrt()
    }

    /// Smallest absolute yaw difference, degrees in [0, 180].
    pub fn yaw_error_deg(&self, other: &Pose) -> f64 {
        wrap_deg(self.yaw_deg - other.yaw_deg).abs()
    }

    /// True when every component is finite.
    pub fn is_finite(&self) -> bool {
        self.x_mm.is_finite() && self.y_mm.is_finite() && self.z_mm.is_finite() && self.yaw_deg.is_finite()
    }
}

/// Wraps an angle in degrees into (-180, 180].
pub fn wrap_deg(a_deg: f64) -> f64 {
    if !a_deg.is_finite() {
        return a_deg;
    }
    let mut a = a_deg.rem_euclid(360.0);
    if a > 180.0 {
        a -= 360.0;
    }
    a
}

impl fmt::Display for Pose {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "(x {:.3} mm, y {:.3} mm, z {:.3} mm, yaw {:.3} deg)", self.x_mm, self.y_mm, self.z_mm, self.yaw_deg)
    }
}

/// Error parsing a pose written as `x,y,z,yaw`.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum PoseParseError {
    #[error("a pose is written x,y,z,yaw (mm, mm, mm, deg); got {count} values in {text:?}")]
    WrongCount { text: String, count: usize },
    #[error("pose component {index} of {text:?} is not a finite number")]
    NotANumber { text: String, index: usize },
}

impl FromStr for Pose {
    type Err = PoseParseError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let parts: Vec<&str> = s.split(',').map(str::trim).collect();
        if parts.len() != 4 {
            return Err(PoseParseError::WrongCount { text: s.to_string(), count: parts.len() });
        }
        let mut v = [0.0f64; 4];
        for (i, p) in parts.iter().enumerate() {
            v[i] = p
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| PoseParseError::NotANumber { text: s.to_string(), index: i })?;
        }
        Ok(Pose::new(v[0], v[1], v[2], v[3]))
    }
}

/// Where the object sits in the robot base frame, and how the sensor approaches it.
///
/// Plan poses are relative to this frame: `x_mm`, `y_mm` are offsets of the sensor centre from
/// the object's contact point (rotated by `origin.yaw_deg`), `z_mm` is extra indentation
/// beyond `contact_depth_mm` (positive presses deeper), `yaw_deg` adds to `origin.yaw_deg`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WorkFrame {
    /// Base-frame pose of the tool when the sensor tip just touches the object's top at the
    /// plan origin.
    pub origin: Pose,
    /// Indentation in mm at plan z = 0 (MultiDiffSense uses about 1.5 mm).
    #[serde(default = "default_contact_depth")]
    pub contact_depth_mm: f64,
    /// Height above the touching point from which the sensor descends, mm.
    #[serde(default = "default_approach")]
    pub approach_mm: f64,
    /// Tool length from the flange to the sensor tip along -z, mm (added to every base z).
    #[serde(default)]
    pub tool_offset_mm: f64,
}

fn default_contact_depth() -> f64 {
    1.5
}
fn default_approach() -> f64 {
    10.0
}

impl Default for WorkFrame {
    fn default() -> Self {
        Self {
            origin: Pose::new(300.0, 0.0, -20.0, 0.0),
            contact_depth_mm: default_contact_depth(),
            approach_mm: default_approach(),
            tool_offset_mm: 0.0,
        }
    }
}

impl WorkFrame {
    /// Base-frame pose that presses the sensor at `plan` (work frame).
    pub fn contact_pose(&self, plan: &Pose) -> Pose {
        let (s, c) = self.origin.yaw_deg.to_radians().sin_cos();
        Pose {
            x_mm: self.origin.x_mm + c * plan.x_mm - s * plan.y_mm,
            y_mm: self.origin.y_mm + s * plan.x_mm + c * plan.y_mm,
            z_mm: self.origin.z_mm + self.tool_offset_mm - (self.contact_depth_mm + plan.z_mm),
            yaw_deg: self.origin.yaw_deg + plan.yaw_deg,
        }
    }

    /// Base-frame pose above `plan` at the approach height.
    pub fn approach_pose(&self, plan: &Pose) -> Pose {
        let mut p = self.contact_pose(plan);
        p.z_mm = self.origin.z_mm + self.tool_offset_mm + self.approach_mm;
        p
    }

    /// Inverse of [`contact_pose`](Self::contact_pose): the work-frame pose of a base-frame
    /// tool pose. Its `z_mm` is the indentation beyond `contact_depth_mm`.
    pub fn plan_pose(&self, base: &Pose) -> Pose {
        let (s, c) = self.origin.yaw_deg.to_radians().sin_cos();
        let dx = base.x_mm - self.origin.x_mm;
        let dy = base.y_mm - self.origin.y_mm;
        Pose {
            x_mm: c * dx + s * dy,
            y_mm: -s * dx + c * dy,
            z_mm: self.origin.z_mm + self.tool_offset_mm - base.z_mm - self.contact_depth_mm,
            yaw_deg: base.yaw_deg - self.origin.yaw_deg,
        }
    }

    /// How deep a work-frame pose presses the skin into the object's top, mm: the contact
    /// depth plus the pose's extra indentation (negative: above the surface). What a sensor's
    /// press limit bounds.
    pub fn press_depth_mm(&self, plan: &Pose) -> f64 {
        self.contact_depth_mm + plan.z_mm
    }

    /// Indentation of the sensor into the object's top in mm at a base-frame pose
    /// (negative: above the surface).
    pub fn indentation_mm(&self, base: &Pose) -> f64 {
        self.plan_pose(base).z_mm + self.contact_depth_mm
    }
}

/// Rounding allowed above a press limit, mm: plan values such as `-1 + 4 x 0.5` land a few
/// ulps off the number a user wrote as the limit.
const PRESS_ROUNDING_MM: f64 = 1e-9;

/// Whether a press `depth_mm` deep keeps to `limit_mm` (up to float rounding); a depth that is
/// not a number never does.
pub fn within_press_limit(depth_mm: f64, limit_mm: f64) -> bool {
    depth_mm <= limit_mm + PRESS_ROUNDING_MM
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parse_and_reject() {
        assert_eq!("1,2,3,4".parse::<Pose>().unwrap(), Pose::new(1.0, 2.0, 3.0, 4.0));
        assert!(matches!("1,2,3".parse::<Pose>(), Err(PoseParseError::WrongCount { count: 3, .. })));
        assert!(matches!("1,x,3,4".parse::<Pose>(), Err(PoseParseError::NotANumber { index: 1, .. })));
        assert!(matches!("1,2,NaN,4".parse::<Pose>(), Err(PoseParseError::NotANumber { index: 2, .. })));
    }

    #[test]
    fn wrap() {
        assert_eq!(wrap_deg(190.0), -170.0);
        assert_eq!(wrap_deg(-180.0), 180.0);
        assert_eq!(wrap_deg(540.0), 180.0);
        assert!((Pose::new(0., 0., 0., 179.0).yaw_error_deg(&Pose::new(0., 0., 0., -179.0)) - 2.0).abs() < 1e-9);
    }

    #[test]
    fn work_frame_round_trip() {
        let wf = WorkFrame { origin: Pose::new(300.0, 20.0, -40.0, 30.0), ..Default::default() };
        let plan = Pose::new(3.0, -4.0, 0.5, 12.0);
        let base = wf.contact_pose(&plan);
        let back = wf.plan_pose(&base);
        assert!(back.distance_mm(&plan) < 1e-9 && (back.yaw_deg - plan.yaw_deg).abs() < 1e-9);
        assert!((wf.indentation_mm(&base) - 2.0).abs() < 1e-9);
        assert_eq!(wf.press_depth_mm(&plan), 2.0);
        assert!(within_press_limit(-1.0 + 4.0 * 0.5 + 1.5, 2.5) && !within_press_limit(2.5001, 2.5) && !within_press_limit(f64::NAN, 2.5));
        assert!(wf.approach_pose(&plan).z_mm > base.z_mm);
    }
}
