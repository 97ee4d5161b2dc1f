//! The calibration model: sensor-frame millimetres to image pixels, and its store.
//!
//! The bottom of [`crate::calibration`]: it uses nothing else in rig, so [`crate::geometry`]
//! can render through it while detection, fitting and the press procedure (above geometry)
//! produce it.
//!
//! The sensor frame has its origin at the sensor centre and the x/y axes of the work frame
//! (rotated with the sensor's yaw). A [`Calibration`] maps a point there to a pixel of the
//! sensor image:
//!
//! ```text
//! f(d)   = 1 + depth_scale_per_mm * d
//! [u, v] = centre_px + R(rotation_deg) * f(d) * [scale_x * x_mm, scale_y * y_mm]
//! ```
//!
//! with `u` the column and `v` the row (rows grow downwards). A negative scale mirrors an axis,
//! which is how a camera that sees the skin from behind is described. `d` is the press depth:
//! how far the skin is indented at the contact, mm (the `z_mm` of an object pose in
//! [`crate::geometry::raster`]: 0 = the skin just touches the object's top). A skin pressed
//! deeper brings the object closer to the camera behind it, so it looks larger about the
//! centre: the px/mm scales at depth `d` are `scale_px_per_mm * f(d)`. With
//! `depth_scale_per_mm = 0` (the default) the depth does not matter, and depth 0 is always the
//! plain map ([`Calibration::mm_to_px`]). Stored as TOML (`calibration/<name>.toml`); the
//! optional [`FitRecord`] keeps the data and residuals of the fit that produced it.

use std::path::Path;

use serde::{Deserialize, Serialize};

/// Pixel scale of [`Calibration::default_for`] at 512 px image width, px/mm.
pub const DEFAULT_SCALE_PX_PER_MM_AT_512: f64 = 8.5;

/// Errors loading, saving or validating a calibration.
#[derive(Debug, thiserror::Error)]
pub enum CalibrationError {
    #[error("calibration {path}: cannot read: {source}")]
    Read {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("calibration {path}: cannot write: {source}")]
    Write {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("calibration {path}: not valid calibration TOML: {source}")]
    Parse {
        path: String,
        #[source]
        source: crate::untrusted::SyntaxError,
    },
    #[error("calibration: cannot encode as TOML: {source}")]
    Encode {
        #[source]
        source: toml::ser::Error,
    },
    #[error("calibration {path}: {field} = {value} is invalid ({why})")]
    Invalid { path: String, field: &'static str, value: String, why: &'static str },
}

/// How a calibration was fitted: the data, the residuals and the method, kept for audit.
/// Every field has a default so other fits can add theirs.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct FitRecord {
    /// What produced the calibration (e.g. `contact-overlap`).
    pub method: String,
    /// Frames or captures the fit used.
    pub frames: Vec<String>,
    /// Correspondences, if the fit used points: sensor-frame mm and image px.
    pub points: Vec<FitPoint>,
    /// Residual per frame or point, px.
    pub residuals_px: Vec<f64>,
    /// Root mean square of `residuals_px`, px.
    pub rms_px: Option<f64>,
    /// Overlap (intersection over union) per frame, for overlap fits.
    pub iou: Vec<f64>,
    /// Free-form remarks on the fit's quality or caveats.
    pub notes: String,
}

/// One fitted correspondence.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FitPoint {
    /// Sensor-frame position of the contact, mm.
    pub mm: [f64; 2],
    /// Where it was detected in the image (column, row), px.
    pub px: [f64; 2],
    /// Press depth (skin indentation) the point was taken at, mm; 0 in files from before the
    /// depth term.
    #[serde(default)]
    pub depth_mm: f64,
}

impl FitPoint {
    /// A correspondence taken at press depth 0.
    pub fn new(mm: [f64; 2], px: [f64; 2]) -> Self {
        Self { mm, px, depth_mm: 0.0 }
    }
}

/// Largest `|depth_scale_per_mm|` accepted, 1/mm: 20 % per mm of indentation is already far
/// beyond any sensor's optics, and the bound keeps the scale factor positive over any
/// realistic press (up to 5 mm).
pub const MAX_DEPTH_SCALE_PER_MM: f64 = 0.2;

/// Sensor-frame mm to image pixels (see the module docs for the model).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Calibration {
    /// Pixel of the sensor centre (column, row).
    pub centre_px: [f64; 2],
    /// Pixels per mm along the sensor x and y axes (before rotation); negative mirrors.
    pub scale_px_per_mm: [f64; 2],
    /// Rotation of the sensor axes in the image, degrees (positive turns x towards +row).
    pub rotation_deg: f64,
    /// Image size the calibration belongs to (width, height), px.
    pub image_size: [u32; 2],
    /// Relative change of the px/mm scales per mm of press depth, 1/mm: at depth `d` mm the
    /// scales are `scale_px_per_mm * (1 + depth_scale_per_mm * d)` (see the module docs);
    /// 0 = the image scale does not depend on the depth.
    #[serde(default)]
    pub depth_scale_per_mm: f64,
    /// How this calibration was fitted, if it was.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fit: Option<FitRecord>,
    /// Maps a commanded work-frame x/y offset (mm) to the offset the object really shows under
    /// the sensor (row-major 2 x 2 matrix); `None` is the identity, the rigid model. Fitted
    /// when a rig's logged poses do not move the image as the rigid model says (the
    /// MultiDiffSense example does not: see the guide, `docs/src/calibration.md`, "Fitting to the
    /// real frames").
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pose_xy_correction: Option<[[f64; 2]; 2]>,
}

impl Calibration {
    /// A plausible calibration for an uncalibrated sensor: centre of the image, about
    /// 8.5 px/mm at 512 px width (scaled with the width), no rotation.
    pub fn default_for(width: u32, height: u32) -> Self {
        let s = DEFAULT_SCALE_PX_PER_MM_AT_512 * width as f64 / 512.0;
        Self {
            centre_px: [width as f64 / 2.0, height as f64 / 2.0],
            scale_px_per_mm: [s, s],
            rotation_deg: 0.0,
            image_size: [width, height],
            depth_scale_per_mm: 0.0,
            fit: None,
            pose_xy_correction: None,
        }
    }

    /// Loads and validates a calibration TOML file.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, CalibrationError> {
        let path = path.as_ref();
        let name = path.display().to_string();
        let text = crate::untrusted::read_text(path, crate::untrusted::MAX_CONFIG_BYTES)
            .map_err(|source| CalibrationError::Read { path: name.clone(), source })?;
        Self::from_toml(&text, &name)
    }

    /// Parses and validates calibration TOML; `name` is used in errors.
    pub fn from_toml(text: &str, name: &str) -> Result<Self, CalibrationError> {
        let calib: Calibration = toml::from_str(text)
            .map_err(|e| CalibrationError::Parse { path: name.to_string(), source: crate::untrusted::SyntaxError::from_toml(&e, text) })?;
        calib.validate(name)?;
        Ok(calib)
    }

    /// Writes the calibration as TOML.
    pub fn save(&self, path: impl AsRef<Path>) -> Result<(), CalibrationError> {
        let path = path.as_ref();
        let text = self.to_toml()?;
        std::fs::write(path, text).map_err(|source| CalibrationError::Write { path: path.display().to_string(), source })
    }

    /// The TOML text of this calibration.
    pub fn to_toml(&self) -> Result<String, CalibrationError> {
        toml::to_string(self).map_err(|source| CalibrationError::Encode { source })
    }

    /// Checks that every number is usable.
    pub fn validate(&self, name: &str) -> Result<(), CalibrationError> {
        let bad = |field, value: String, why| Err(CalibrationError::Invalid { path: name.to_string(), field, value, why });
        if !self.centre_px.iter().all(|c| c.is_finite()) {
            return bad("centre_px", format!("{:?}", self.centre_px), "must be finite");
        }
        if !self.scale_px_per_mm.iter().all(|s| s.is_finite() && s.abs() > 1e-6) {
            return bad("scale_px_per_mm", format!("{:?}", self.scale_px_per_mm), "must be finite and non-zero");
        }
        if !self.rotation_deg.is_finite() {
            return bad("rotation_deg", self.rotation_deg.to_string(), "must be finite");
        }
        if self.image_size.contains(&0) {
            return bad("image_size", format!("{:?}", self.image_size), "must be positive");
        }
        if let Some(m) = self.pose_xy_correction
            && !m.iter().flatten().all(|v| v.is_finite())
        {
            return bad("pose_xy_correction", format!("{m:?}"), "must be finite");
        }
        if !self.depth_scale_per_mm.is_finite() || self.depth_scale_per_mm.abs() > MAX_DEPTH_SCALE_PER_MM {
            return bad("depth_scale_per_mm", self.depth_scale_per_mm.to_string(), "must be finite and within ±0.2 per mm");
        }
        Ok(())
    }

    /// The same calibration for an image of another size (the optics scale with the image).
    /// Exact when the aspect ratio is kept or the rotation is a multiple of 180 degrees; a
    /// rotated calibration resized anisotropically would need a shear the model does not have.
    pub fn scaled_to(&self, width: u32, height: u32) -> Self {
        let kx = width as f64 / self.image_size[0] as f64;
        let ky = height as f64 / self.image_size[1] as f64;
        Self {
            centre_px: [self.centre_px[0] * kx, self.centre_px[1] * ky],
            scale_px_per_mm: [self.scale_px_per_mm[0] * kx, self.scale_px_per_mm[1] * ky],
            image_size: [width, height],
            ..self.clone()
        }
    }

    /// The x/y offset (mm) the object shows under the sensor for a commanded work-frame offset
    /// (applies [`Self::pose_xy_correction`]).
    pub fn effective_offset_mm(&self, x_mm: f64, y_mm: f64) -> (f64, f64) {
        match self.pose_xy_correction {
            Some([[a, b], [c, d]]) => (a * x_mm + b * y_mm, c * x_mm + d * y_mm),
            None => (x_mm, y_mm),
        }
    }

    /// The factor `1 + depth_scale_per_mm * depth_mm` the px/mm scales are multiplied by at
    /// press depth `depth_mm` (see the module docs). Kept at least 1e-3 so that a depth far
    /// outside the calibrated range cannot fold the image over; a non-finite depth counts as 0.
    pub fn depth_factor(&self, depth_mm: f64) -> f64 {
        let d = if depth_mm.is_finite() { depth_mm } else { 0.0 };
        (1.0 + self.depth_scale_per_mm * d).max(1e-3)
    }

    /// The px/mm scales (x, y) at press depth `depth_mm`.
    pub fn scale_at_depth(&self, depth_mm: f64) -> [f64; 2] {
        let f = self.depth_factor(depth_mm);
        [self.scale_px_per_mm[0] * f, self.scale_px_per_mm[1] * f]
    }

    /// Image pixel (column, row) of a sensor-frame point in mm at press depth 0 (the plain map;
    /// [`Self::mm_to_px_at_depth`] for a pressed point).
    pub fn mm_to_px(&self, x_mm: f64, y_mm: f64) -> (f64, f64) {
        self.mm_to_px_at_depth(x_mm, y_mm, 0.0)
    }

    /// Image pixel (column, row) of a sensor-frame point in mm seen at press depth `depth_mm`.
    pub fn mm_to_px_at_depth(&self, x_mm: f64, y_mm: f64, depth_mm: f64) -> (f64, f64) {
        let (s, c) = self.rotation_deg.to_radians().sin_cos();
        let [sx, sy] = self.scale_at_depth(depth_mm);
        let (a, b) = (sx * x_mm, sy * y_mm);
        (self.centre_px[0] + c * a - s * b, self.centre_px[1] + s * a + c * b)
    }

    /// Sensor-frame point in mm of an image pixel (column, row) at press depth 0; inverse of
    /// [`Self::mm_to_px`].
    pub fn px_to_mm(&self, u_px: f64, v_px: f64) -> (f64, f64) {
        self.px_to_mm_at_depth(u_px, v_px, 0.0)
    }

    /// Sensor-frame point in mm of an image pixel seen at press depth `depth_mm`; inverse of
    /// [`Self::mm_to_px_at_depth`].
    pub fn px_to_mm_at_depth(&self, u_px: f64, v_px: f64, depth_mm: f64) -> (f64, f64) {
        let (s, c) = self.rotation_deg.to_radians().sin_cos();
        let (du, dv) = (u_px - self.centre_px[0], v_px - self.centre_px[1]);
        let (a, b) = (c * du + s * dv, -s * du + c * dv);
        let [sx, sy] = self.scale_at_depth(depth_mm);
        (a / sx, b / sy)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_scales_with_width() {
        let c = Calibration::default_for(512, 512);
        assert_eq!(c.mm_to_px(0.0, 0.0), (256.0, 256.0));
        let (u, _) = c.mm_to_px(1.0, 0.0);
        assert!((u - 256.0 - 8.5).abs() < 1e-9);
        assert!((Calibration::default_for(256, 256).scale_px_per_mm[0] - 4.25).abs() < 1e-12);
    }

    #[test]
    fn px_mm_round_trip_with_rotation_and_mirror() {
        let c = Calibration {
            centre_px: [250.0, 261.0],
            scale_px_per_mm: [9.0, -8.0],
            rotation_deg: 33.0,
            image_size: [512, 512],
            depth_scale_per_mm: 0.0,
            fit: None,
            pose_xy_correction: None,
        };
        for (x, y) in [(0.0, 0.0), (3.0, -4.0), (-7.5, 2.25)] {
            let (u, v) = c.mm_to_px(x, y);
            let (x2, y2) = c.px_to_mm(u, v);
            assert!((x - x2).abs() < 1e-9 && (y - y2).abs() < 1e-9);
        }
        // 90 degrees turns +x into +row.
        let r = Calibration { rotation_deg: 90.0, ..Calibration::default_for(512, 512) };
        let (u, v) = r.mm_to_px(1.0, 0.0);
        assert!((u - 256.0).abs() < 1e-9 && (v - 264.5).abs() < 1e-9);
    }

    #[test]
    fn depth_term_scales_about_the_centre() {
        let c = Calibration {
            centre_px: [250.0, 261.0],
            scale_px_per_mm: [9.0, -8.0],
            rotation_deg: 20.0,
            depth_scale_per_mm: 0.05,
            ..Calibration::default_for(512, 512)
        };
        // Depth 0 is the plain map; at 2 mm every offset from the centre grows by 1.1.
        assert_eq!(c.mm_to_px(3.0, -1.0), c.mm_to_px_at_depth(3.0, -1.0, 0.0));
        let (u0, v0) = c.mm_to_px(3.0, -1.0);
        let (u2, v2) = c.mm_to_px_at_depth(3.0, -1.0, 2.0);
        assert!((u2 - 250.0 - 1.1 * (u0 - 250.0)).abs() < 1e-9 && (v2 - 261.0 - 1.1 * (v0 - 261.0)).abs() < 1e-9);
        assert_eq!(c.scale_at_depth(2.0), [9.0 * 1.1, -8.0 * 1.1]);
        let (x, y) = c.px_to_mm_at_depth(u2, v2, 2.0);
        assert!((x - 3.0).abs() < 1e-9 && (y + 1.0).abs() < 1e-9);
        // A depth far outside any press cannot flip the image.
        assert!(c.depth_factor(-1e6) > 0.0 && c.depth_factor(f64::NAN) == 1.0);
        let mut bad = c.clone();
        bad.depth_scale_per_mm = 0.5;
        assert!(matches!(bad.validate("b"), Err(CalibrationError::Invalid { field: "depth_scale_per_mm", .. })));
        let text = c.to_toml().unwrap();
        assert_eq!(Calibration::from_toml(&text, "t").unwrap(), c);
    }

    #[test]
    fn scaled_to_keeps_points_in_place_relative_to_the_image() {
        let c = Calibration {
            centre_px: [250.0, 261.0],
            scale_px_per_mm: [18.0, -18.0],
            rotation_deg: 170.0,
            pose_xy_correction: Some([[0.4, -0.3], [0.3, 0.4]]),
            ..Calibration::default_for(512, 512)
        };
        let half = c.scaled_to(256, 256);
        assert_eq!(half.image_size, [256, 256]);
        let (u, v) = c.mm_to_px(3.0, -2.0);
        let (uh, vh) = half.mm_to_px(3.0, -2.0);
        assert!((uh - u / 2.0).abs() < 1e-9 && (vh - v / 2.0).abs() < 1e-9, "({uh}, {vh}) vs ({u}, {v})");
        assert_eq!(half.effective_offset_mm(1.0, 0.0), (0.4, 0.3));
    }

    #[test]
    fn toml_round_trip_and_validation() {
        let mut c = Calibration::default_for(512, 512);
        c.fit = Some(FitRecord { method: "test".into(), residuals_px: vec![1.0, 2.0], ..Default::default() });
        let text = c.to_toml().unwrap();
        assert_eq!(Calibration::from_toml(&text, "t").unwrap(), c);
        let minimal = "centre_px = [1.0, 2.0]\nscale_px_per_mm = [8.0, 8.0]\nrotation_deg = 0.0\nimage_size = [512, 512]\n";
        assert_eq!(Calibration::from_toml(minimal, "m").unwrap().depth_scale_per_mm, 0.0);
        let zero = minimal.replace("[8.0, 8.0]", "[0.0, 8.0]");
        assert!(matches!(Calibration::from_toml(&zero, "z"), Err(CalibrationError::Invalid { field: "scale_px_per_mm", .. })));
        assert!(matches!(Calibration::from_toml("centre_px = 3", "p"), Err(CalibrationError::Parse { .. })));
    }
}
