//! Scene descriptions: which effect stages a simulated sensor runs, and their few parameters.
//!
//! A [`Scene`] is read from TOML (or taken from a named preset) and lists [`Stage`]s. The
//! renderer runs exactly the listed stages that apply to the sensor kind, nothing else; the
//! static look (skin, illumination, field of view, markers at rest) is precomputed and is not
//! a stage.
//!
//! ```toml
//! name = "custom"
//! stages = ["contact_deformation", "marker_displacement", "see_through", "noise"]
//! noise_sigma_levels = 3.0
//! ```

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

/// One separable effect of the sensor simulation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Stage {
    /// Elastic spread of the skin around the contact (the skin is dragged in beyond the
    /// footprint of the object).
    ContactDeformation,
    /// Lateral displacement of the markers (pins) by the skin deformation.
    MarkerDisplacement,
    /// The object seen through a transparent skin (ViTac, ViTacTip), with the glow it scatters.
    SeeThrough,
    /// Brightness change of the tilted skin under the sensor's illumination.
    Shading,
    /// Radial fall-off of the lens and illumination.
    Vignetting,
    /// Read and shot noise of the image sensor, seeded per frame.
    Noise,
    /// Blur of the contact imprint along its image-space motion during the exposure (the
    /// camera and the skin move with the arm, so the static look does not streak).
    MotionBlur,
    /// The camera hands out the frame of one frame period earlier (applied by `SimCamera`).
    StaleFrame,
}

impl Stage {
    /// Every stage, in pipeline order.
    pub const ALL: [Stage; 8] = [
        Stage::ContactDeformation,
        Stage::MarkerDisplacement,
        Stage::SeeThrough,
        Stage::Shading,
        Stage::MotionBlur,
        Stage::Vignetting,
        Stage::Noise,
        Stage::StaleFrame,
    ];
    /// Number of stages.
    pub const COUNT: usize = Self::ALL.len();

    /// Dense index in `0..COUNT`, for per-stage arrays.
    pub const fn index(self) -> usize {
        match self {
            Stage::ContactDeformation => 0,
            Stage::MarkerDisplacement => 1,
            Stage::SeeThrough => 2,
            Stage::Shading => 3,
            Stage::MotionBlur => 4,
            Stage::Vignetting => 5,
            Stage::Noise => 6,
            Stage::StaleFrame => 7,
        }
    }

    /// The snake_case name used in scene files.
    pub const fn name(self) -> &'static str {
        match self {
            Stage::ContactDeformation => "contact_deformation",
            Stage::MarkerDisplacement => "marker_displacement",
            Stage::SeeThrough => "see_through",
            Stage::Shading => "shading",
            Stage::MotionBlur => "motion_blur",
            Stage::Vignetting => "vignetting",
            Stage::Noise => "noise",
            Stage::StaleFrame => "stale_frame",
        }
    }
}

impl fmt::Display for Stage {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Stage {
    type Err = SceneError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let wanted = s.trim().to_ascii_lowercase().replace('-', "_");
        Stage::ALL.into_iter().find(|st| st.name() == wanted).ok_or_else(|| SceneError::UnknownStage { name: s.to_string() })
    }
}

/// Errors reading a scene.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    #[error("unknown scene preset {name:?} (known: {})", Scene::PRESETS.join(", "))]
    UnknownPreset { name: String },
    #[error("unknown stage {name:?} (known: {})", Stage::ALL.map(|s| s.name()).join(", "))]
    UnknownStage { name: String },
    #[error("invalid scene TOML")]
    Toml {
        #[source]
        source: crate::untrusted::SyntaxError,
    },
    #[error("scene parameter {field} must be finite and >= 0, got {value}")]
    BadParameter { field: &'static str, value: f32 },
}

/// Which stages a simulated sensor runs, with their parameters.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    /// Name for logs (the preset name, or what the file says).
    #[serde(default = "default_name")]
    pub name: String,
    /// The stages to run; order in the file does not matter (the pipeline order is fixed).
    pub stages: Vec<Stage>,
    /// Standard deviation of the read noise, 8-bit levels.
    #[serde(default = "default_noise_sigma")]
    pub noise_sigma_levels: f32,
    /// Longest motion-blur streak, px (a guard against absurd speeds).
    #[serde(default = "default_max_blur")]
    pub max_blur_px: f32,
}

fn default_name() -> String {
    "custom".to_string()
}
fn default_noise_sigma() -> f32 {
    2.5
}
fn default_max_blur() -> f32 {
    48.0
}

impl Scene {
    /// Names accepted by [`Scene::preset`].
    pub const PRESETS: [&'static str; 4] = ["full", "fast", "minimal", "none"];

    /// A scene with these stages and default parameters.
    pub fn with_stages(name: &str, stages: &[Stage]) -> Self {
        let mut s = Self {
            name: name.to_string(),
            stages: stages.to_vec(),
            noise_sigma_levels: default_noise_sigma(),
            max_blur_px: default_max_blur(),
        };
        s.normalise();
        s
    }

    /// A named preset:
    /// - `full`: every stage;
    /// - `fast`: the contact signal and the cheap look stages (deformation, marker
    ///   displacement, see-through, vignetting) for bulk collection;
    /// - `minimal`: only the contact signal (marker displacement, see-through);
    /// - `none`: no stage at all, the static sensor look.
    pub fn preset(name: &str) -> Result<Self, SceneError> {
        use Stage::*;
        let stages: &[Stage] = match name.trim().to_ascii_lowercase().as_str() {
            "full" => &Stage::ALL,
            "fast" => &[ContactDeformation, MarkerDisplacement, SeeThrough, Vignetting],
            "minimal" => &[MarkerDisplacement, SeeThrough],
            "none" => &[],
            _ => return Err(SceneError::UnknownPreset { name: name.to_string() }),
        };
        Ok(Self::with_stages(&name.trim().to_ascii_lowercase(), stages))
    }

    /// Parses a scene file (see the module docs for the format).
    pub fn from_toml(text: &str) -> Result<Self, SceneError> {
        let mut s: Scene =
            toml::from_str(text).map_err(|e| SceneError::Toml { source: crate::untrusted::SyntaxError::from_toml(&e, text) })?;
        for (field, value) in [("noise_sigma_levels", s.noise_sigma_levels), ("max_blur_px", s.max_blur_px)] {
            if !value.is_finite() || value < 0.0 {
                return Err(SceneError::BadParameter { field, value });
            }
        }
        s.normalise();
        Ok(s)
    }

    /// Either a preset name or a path to a TOML file.
    pub fn preset_or_file(spec: &str) -> Result<Self, SceneLoadError> {
        if Self::PRESETS.contains(&spec.trim().to_ascii_lowercase().as_str()) {
            return Ok(Self::preset(spec)?);
        }
        if !std::path::Path::new(spec).exists() {
            return Err(SceneLoadError::NotFound { spec: spec.to_string() });
        }
        let text = crate::untrusted::read_text(std::path::Path::new(spec), crate::untrusted::MAX_CONFIG_BYTES)
            .map_err(|source| SceneLoadError::Read { path: spec.to_string(), source })?;
        Ok(Self::from_toml(&text)?)
    }

    /// The scene as TOML.
    pub fn to_toml(&self) -> String {
        // Serialising a struct of strings, enums and floats cannot fail.
        toml::to_string(self).unwrap_or_default()
    }

    /// True when the scene lists `stage`.
    pub fn has(&self, stage: Stage) -> bool {
        self.stages.contains(&stage)
    }

    fn normalise(&mut self) {
        self.stages.sort_by_key(|s| s.index());
        self.stages.dedup();
    }
}

/// Errors loading a scene given on the command line.
#[derive(Debug, thiserror::Error)]
pub enum SceneLoadError {
    #[error("{spec:?} is neither a scene preset ({}) nor a file", Scene::PRESETS.join(", "))]
    NotFound { spec: String },
    #[error("cannot read scene file {path}")]
    Read {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error(transparent)]
    Scene(#[from] SceneError),
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_and_toml() {
        assert_eq!(Scene::preset("full").unwrap().stages.len(), Stage::COUNT);
        assert!(Scene::preset("none").unwrap().stages.is_empty());
        assert!(matches!(Scene::preset("nope"), Err(SceneError::UnknownPreset { .. })));
        let s = Scene::from_toml("stages = [\"noise\", \"see_through\", \"noise\"]\nnoise_sigma_levels = 4.0").unwrap();
        assert_eq!(s.stages, vec![Stage::SeeThrough, Stage::Noise]);
        assert_eq!(s.noise_sigma_levels, 4.0);
        assert!(Scene::from_toml("stages = [\"sparkle\"]").is_err());
        assert!(Scene::from_toml("stages = []\nbogus = 1").is_err());
        assert!(matches!(Scene::from_toml("stages = []\nmax_blur_px = -1.0"), Err(SceneError::BadParameter { field: "max_blur_px", .. })));
        let full = Scene::preset("full").unwrap();
        assert_eq!(Scene::from_toml(&full.to_toml()).unwrap(), full);
        assert_eq!("Motion-Blur".parse::<Stage>().unwrap(), Stage::MotionBlur);
    }
}
