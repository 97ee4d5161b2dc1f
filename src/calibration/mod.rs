//! The sensor calibration: sensor-frame millimetres to image pixels.
//!
//! The sensor frame has its origin at the sensor centre and the x/y axes of the work frame
//! (rotated with the sensor's yaw). A [`Calibration`] maps a point there to a pixel of the
//! sensor image:
//!
//! ```text
//! [u, v] = centre_px + R(rotation_deg) * [scale_x * x_mm, scale_y * y_mm]
//! ```
//!
//! with `u` the column and `v` the row (rows grow downwards). A negative scale mirrors an axis,
//! which is how a camera that sees the skin from behind is described. Stored as TOML
//! (`calibration/<name>.toml`); the optional [`FitRecord`] keeps the data and residuals of the
//! fit that produced it. [`contact_fit`] fits one to real frames of a known object.

pub mod contact_fit;
pub mod detect;
pub mod fit;
pub mod press;
pub mod wizard;

use std::path::Path;

use serde::{Deserialize, Serialize};

/// Where `rig calibrate` saves a sensor's calibration and where `rig collect` and
/// `rig synth --fill-missing` look for it: `calibration/<sensor>.toml` (relative to the working
/// directory).
pub fn saved_path(sensor: &str) -> std::path::PathBuf {
    Path::new("calibration").join(format!("{sensor}.toml"))
}

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
        source: toml::de::Error,
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
    pub mm: [f64; 2],
    pub px: [f64; 2],
}

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
    /// How strongly indentation shows in the image per mm (used by sensor renderers), 0 = none.
    #[serde(default)]
    pub depth_scale_per_mm: f64,
    /// How this calibration was fitted, if it was.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fit: Option<FitRecord>,
    /// Maps a commanded work-frame x/y offset (mm) to the offset the object really shows under
    /// the sensor (row-major 2 x 2 matrix); `None` is the identity, the rigid model. Fitted
    /// when a rig's logged poses do not move the image as the rigid model says (the
    /// MultiDiffSense example does not: see the README, "Comparing with reality").
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
        let text = std::fs::read_to_string(path).map_err(|source| CalibrationError::Read { path: name.clone(), source })?;
        Self::from_toml(&text, &name)
    }

    /// Parses and validates calibration TOML; `name` is used in errors.
    pub fn from_toml(text: &str, name: &str) -> Result<Self, CalibrationError> {
        let calib: Calibration =
            toml::from_str(text).map_err(|source| CalibrationError::Parse { path: name.to_string(), source })?;
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
        let bad = |field, value: String, why| {
            Err(CalibrationError::Invalid { path: name.to_string(), field, value, why })
        };
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
        if !self.depth_scale_per_mm.is_finite() {
            return bad("depth_scale_per_mm", self.depth_scale_per_mm.to_string(), "must be finite");
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

    /// Image pixel (column, row) of a sensor-frame point in mm.
    pub fn mm_to_px(&self, x_mm: f64, y_mm: f64) -> (f64, f64) {
        let (s, c) = self.rotation_deg.to_radians().sin_cos();
        let (a, b) = (self.scale_px_per_mm[0] * x_mm, self.scale_px_per_mm[1] * y_mm);
        (self.centre_px[0] + c * a - s * b, self.centre_px[1] + s * a + c * b)
    }

    /// Sensor-frame point in mm of an image pixel (column, row); inverse of [`Self::mm_to_px`].
    pub fn px_to_mm(&self, u_px: f64, v_px: f64) -> (f64, f64) {
        let (s, c) = self.rotation_deg.to_radians().sin_cos();
        let (du, dv) = (u_px - self.centre_px[0], v_px - self.centre_px[1]);
        let (a, b) = (c * du + s * dv, -s * du + c * dv);
        (a / self.scale_px_per_mm[0], b / self.scale_px_per_mm[1])
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
