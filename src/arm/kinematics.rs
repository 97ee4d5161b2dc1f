//! MG400 forward and inverse kinematics (fact sheet section 5).
//!
//! The MG400 is a 4-axis arm with a parallelogram: J3 is an absolute angle, not relative to
//! J2. With link lengths L2 = L3 = 175 mm and the offsets of \[HX\] (MG400_ROS2):
//!
//! ```text
//! r = r_offset + L2·sin J2 + L3·cos J3        (r_offset = 43.5 + 66 mm)
//! z = z_offset + L2·cos J2 − L3·sin J3        (z_offset = −53.8 mm)
//! x = r·cos J1,  y = r·sin J1,  yaw = J1 + J4
//! ```
//!
//! Inverse: J1 = atan2(y, x); the planar two-link problem in (r − r_offset, z − z_offset) has
//! the elbow-up solution the controller uses (J2 ≈ 32°, J3 ≈ 32.6° at (350, 0, 0)); J4 is the
//! yaw minus J1.

use serde::{Deserialize, Serialize};

use crate::pose::Pose;

/// Joint angles in degrees.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Joints {
    pub j1_deg: f64,
    pub j2_deg: f64,
    pub j3_deg: f64,
    pub j4_deg: f64,
}

impl Joints {
    pub const fn new(j1_deg: f64, j2_deg: f64, j3_deg: f64, j4_deg: f64) -> Self {
        Self { j1_deg, j2_deg, j3_deg, j4_deg }
    }

    /// The angles as an array, J1 first.
    pub fn to_array(&self) -> [f64; 4] {
        [self.j1_deg, self.j2_deg, self.j3_deg, self.j4_deg]
    }

    pub fn from_array(a: [f64; 4]) -> Self {
        Self::new(a[0], a[1], a[2], a[3])
    }
}

/// The arm's geometry, mm (from the firmware profile).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Mg400Geometry {
    /// Upper arm (J2 link) length.
    pub link2_mm: f64,
    /// Forearm (J3 link) length.
    pub link3_mm: f64,
    /// Radial offset: base axis to J2 plus J3 to the flange.
    pub r_offset_mm: f64,
    /// Vertical offset of the flange at J2 = J3 = 0 minus the link length.
    pub z_offset_mm: f64,
}

impl Default for Mg400Geometry {
    fn default() -> Self {
        Self { link2_mm: 175.0, link3_mm: 175.0, r_offset_mm: 43.5 + 66.0, z_offset_mm: -53.8 }
    }
}

/// Why a pose has no joint solution.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum KinematicsError {
    #[error("pose has a non-finite component")]
    NonFinite,
    #[error("wrist point is {distance_mm:.1} mm from J2, beyond the arm's reach of {reach_mm:.1} mm")]
    OutOfReach { distance_mm: f64, reach_mm: f64 },
    /// The wrist point sits on J2 itself (the two equal links folded onto each other): every
    /// J2 reaches it, so the pose names no joint angles.
    #[error("wrist point is {distance_mm:.2e} mm from J2: the folded, singular configuration has no unique solution")]
    Singular { distance_mm: f64 },
}

/// Wrist-to-J2 distances below this are the folded singularity (the law of cosines divides by
/// the distance, giving 0/0 = NaN at exactly zero).
const SINGULAR_DISTANCE_MM: f64 = 1e-6;

impl Mg400Geometry {
    /// Tool pose of the given joint angles.
    pub fn forward(&self, j: &Joints) -> Pose {
        let (s2, c2) = j.j2_deg.to_radians().sin_cos();
        let (s3, c3) = j.j3_deg.to_radians().sin_cos();
        let r = self.r_offset_mm + self.link2_mm * s2 + self.link3_mm * c3;
        let z = self.z_offset_mm + self.link2_mm * c2 - self.link3_mm * s3;
        let (s1, c1) = j.j1_deg.to_radians().sin_cos();
        Pose::new(r * c1, r * s1, z, j.j1_deg + j.j4_deg)
    }

    /// Joint angles reaching `pose` (elbow up). Joint limits are not checked here.
    pub fn inverse(&self, pose: &Pose) -> Result<Joints, KinematicsError> {
        if !pose.is_finite() {
            return Err(KinematicsError::NonFinite);
        }
        let j1 = pose.y_mm.atan2(pose.x_mm);
        let r = pose.x_mm.hypot(pose.y_mm) - self.r_offset_mm;
        let z = pose.z_mm - self.z_offset_mm;
        let d = r.hypot(z);
        let (l2, l3) = (self.link2_mm, self.link3_mm);
        if d > l2 + l3 || d < (l2 - l3).abs() {
            return Err(KinematicsError::OutOfReach { distance_mm: d, reach_mm: l2 + l3 });
        }
        if d < SINGULAR_DISTANCE_MM {
            return Err(KinematicsError::Singular { distance_mm: d });
        }
        // Angle of the wrist point from the horizontal, and the angles the two links make with
        // that line (law of cosines).
        let phi = z.atan2(r);
        let cos_a2 = ((d * d + l2 * l2 - l3 * l3) / (2.0 * d * l2)).clamp(-1.0, 1.0);
        let cos_a3 = ((d * d + l3 * l3 - l2 * l2) / (2.0 * d * l3)).clamp(-1.0, 1.0);
        // Link 2 points at elevation phi + a2 (J2 measured from vertical), link 3 at
        // elevation phi − a3 (J3 measured downward from horizontal).
        let link2_elev = phi + cos_a2.acos();
        let link3_elev = phi - cos_a3.acos();
        let j2 = std::f64::consts::FRAC_PI_2 - link2_elev;
        let j3 = -link3_elev;
        let j1_deg = j1.to_degrees();
        // J4 is not wrapped: the controller checks J4 = yaw − J1 against its ±180° limit as is.
        Ok(Joints::new(j1_deg, j2.to_degrees(), j3.to_degrees(), pose.yaw_deg - j1_deg))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn known_poses() {
        let g = Mg400Geometry::default();
        let home = g.forward(&Joints::default());
        assert!((home.x_mm - 284.5).abs() < 1e-9 && (home.z_mm - 121.2).abs() < 1e-9);
        let j = g.inverse(&Pose::new(350.0, 0.0, 0.0, 0.0)).unwrap();
        assert!((j.j2_deg - 32.15).abs() < 0.05, "{j:?}");
        assert!((j.j3_deg - 32.63).abs() < 0.05, "{j:?}");
        assert!(matches!(g.inverse(&Pose::new(800.0, 0.0, 0.0, 0.0)), Err(KinematicsError::OutOfReach { .. })));
        assert_eq!(g.inverse(&Pose::new(f64::NAN, 0.0, 0.0, 0.0)), Err(KinematicsError::NonFinite));
        // The folded arm: wrist point exactly on J2 (gave NaN joints before the check).
        let folded = Pose::new(g.r_offset_mm, 0.0, g.z_offset_mm, 0.0);
        assert!(matches!(g.inverse(&folded), Err(KinematicsError::Singular { .. })));
    }

    proptest! {
        #[test]
        fn inverse_undoes_forward(j1 in -160.0f64..160.0, j2 in -25.0f64..85.0, j3 in -25.0f64..105.0, j4 in -150.0f64..150.0) {
            prop_assume!((j3 - j2).abs() <= 60.0);
            let g = Mg400Geometry::default();
            let pose = g.forward(&Joints::new(j1, j2, j3, j4));
            let back = g.inverse(&pose).unwrap();
            let again = g.forward(&back);
            prop_assert!(again.distance_mm(&pose) < 1e-6);
            prop_assert!(again.yaw_error_deg(&pose) < 1e-6);
            prop_assert!((back.j2_deg - j2).abs() < 1e-6 && (back.j3_deg - j3).abs() < 1e-6);
        }
    }
}
