//! `model.toml`, the model package's own settings: parsed from text in two stages (serde, then
//! checked: every number bounded by [`super::limits`] before it sizes anything). It stands
//! alone (serde, toml and thiserror; [`super::limits`], [`super::settings`],
//! [`crate::untrusted`]), so the package loader's fuzz target (`fuzz/fuzz_targets/package_loader.rs`)
//! compiles it without ONNX Runtime. [`super::package`] reads the file and names it in errors.
//!
//! ```toml
//! name = "multidiffsense-sd15"
//! resolution = [512, 512]            # width, height in pixels (default 512 x 512)
//! modalities = ["TacTip", "ViTac", "ViTacTip"]
//! prompt_template = "multidiffsense" # the only template so far: prompt::mds_prompt
//! latent_scale = 0.18215
//! hint_encoding = "rgb01"            # control RGB scaled to [0,1] ("rgb11": to [-1,1])
//! control_colour_map = "viridis"     # the control is a depth map colour-mapped with viridis
//!                                    # (MultiDiffSense); left out: any 8-bit RGB control image
//! vae_scale_factor = 8               # image pixels per latent pixel
//! end_token = "<|endoftext|>"        # padding token of the tokenizer
//! sampling_steps = 20                # 1 to 10000 (limits::MAX_STEPS)
//! guidance = 1.0
//! sampler = "dpm++2m"
//! eta = 0.0
//! ```

use serde::Deserialize;

use super::settings::SchedulerKind;

/// Why a `model.toml` text was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ModelTomlError {
    #[error("{0}")]
    Syntax(crate::untrusted::SyntaxError),
    #[error("{field} = {value:?} is not valid: {reason}")]
    Bad { field: &'static str, value: String, reason: &'static str },
}

/// How the control image is turned into the ControlNet's `controlnet_cond` tensor.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HintEncoding {
    /// RGB / 255, in [0, 1] (MultiDiffSense, diffusers' ControlNet pipelines).
    Rgb01,
    /// RGB / 127.5 - 1, in [-1, 1].
    Rgb11,
}

/// The colour map a package's control images are drawn with, when it declares one
/// (`control_colour_map`): a control image that cannot be one (every pixel grey) is refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ControlColourMap {
    /// MultiDiffSense's: the inverted depth map through matplotlib's viridis (no grey in it).
    Viridis,
}

/// `model.toml` as written (first stage).
#[derive(Debug, Deserialize)]
struct RawModelToml {
    name: String,
    #[serde(default = "default_resolution")]
    resolution: [u32; 2],
    #[serde(default)]
    modalities: Vec<String>,
    #[serde(default = "default_template")]
    prompt_template: String,
    #[serde(default = "default_latent_scale")]
    latent_scale: f64,
    #[serde(default = "default_hint")]
    hint_encoding: String,
    #[serde(default)]
    control_colour_map: Option<String>,
    #[serde(default = "default_vae_scale")]
    vae_scale_factor: u32,
    #[serde(default = "default_end_token")]
    end_token: String,
    #[serde(default)]
    sampling_steps: Option<usize>,
    #[serde(default)]
    guidance: Option<f32>,
    #[serde(default)]
    sampler: Option<String>,
    #[serde(default)]
    eta: Option<f32>,
}

fn default_resolution() -> [u32; 2] {
    [512, 512]
}
fn default_template() -> String {
    "multidiffsense".to_string()
}
fn default_latent_scale() -> f64 {
    0.18215
}
fn default_hint() -> String {
    "rgb01".to_string()
}
fn default_vae_scale() -> u32 {
    8
}
fn default_end_token() -> String {
    "<|endoftext|>".to_string()
}

/// `model.toml`, validated (second stage).
#[derive(Debug, Clone, PartialEq)]
pub struct ModelConfig {
    pub name: String,
    pub width_px: u32,
    pub height_px: u32,
    pub modalities: Vec<String>,
    pub prompt_template: String,
    pub latent_scale: f32,
    pub hint_encoding: HintEncoding,
    /// The colour map the control images are drawn with, if the package declares one; `None`:
    /// any 8-bit RGB control image (as diffusers' ControlNet pipelines read, grey included).
    pub control_colour_map: Option<ControlColourMap>,
    pub vae_scale_factor: u32,
    pub end_token: String,
    /// Sampling steps the model is meant to be sampled with, if the package says.
    pub sampling_steps: Option<usize>,
    /// Classifier-free guidance scale the model is meant to be sampled with, if the package says.
    pub guidance: Option<f32>,
    /// The sampler the model is meant to be sampled with, if the package says.
    pub sampler: Option<SchedulerKind>,
    /// DDIM eta the model is meant to be sampled with, if the package says.
    pub eta: Option<f32>,
}

/// The sampling settings of a request: what was asked for, else the package's, else a fallback.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sampling {
    pub steps: usize,
    pub guidance: f32,
    pub sampler: SchedulerKind,
    pub eta: f32,
}

impl ModelConfig {
    /// The settings to sample with: each one asked for, else this package's, else `fallback`'s
    /// steps and guidance, DDIM and eta 0.
    pub fn sampling(
        &self,
        steps: Option<usize>,
        guidance: Option<f32>,
        sampler: Option<SchedulerKind>,
        eta: Option<f32>,
        fallback: (usize, f32),
    ) -> Sampling {
        Sampling {
            steps: steps.or(self.sampling_steps).unwrap_or(fallback.0),
            guidance: guidance.or(self.guidance).unwrap_or(fallback.1),
            sampler: sampler.or(self.sampler).unwrap_or_default(),
            eta: eta.or(self.eta).unwrap_or(0.0),
        }
    }

    /// Parses and validates the text of a `model.toml` ([`super::package`] reads the file).
    pub fn parse(text: &str) -> Result<Self, ModelTomlError> {
        let raw: RawModelToml =
            toml::from_str(text).map_err(|e| ModelTomlError::Syntax(crate::untrusted::SyntaxError::from_toml(&e, text)))?;
        let bad = |field, value: String, reason| ModelTomlError::Bad { field, value, reason };
        let hint_encoding = match raw.hint_encoding.as_str() {
            "rgb01" => HintEncoding::Rgb01,
            "rgb11" => HintEncoding::Rgb11,
            other => return Err(bad("hint_encoding", other.to_string(), "expected \"rgb01\" or \"rgb11\"")),
        };
        let control_colour_map = match raw.control_colour_map.as_deref() {
            None => None,
            Some("viridis") => Some(ControlColourMap::Viridis),
            Some(other) => {
                return Err(bad("control_colour_map", other.to_string(), "expected \"viridis\" (or leave it out: any 8-bit RGB control)"));
            }
        };
        if raw.prompt_template != "multidiffsense" {
            return Err(bad("prompt_template", raw.prompt_template, "the only template rig knows is \"multidiffsense\""));
        }
        if !(raw.latent_scale.is_finite() && raw.latent_scale > 0.0) {
            return Err(bad("latent_scale", raw.latent_scale.to_string(), "must be a positive number"));
        }
        let f = raw.vae_scale_factor;
        if f == 0 {
            return Err(bad("vae_scale_factor", f.to_string(), "must be positive"));
        }
        let [w, h] = raw.resolution;
        if w > super::limits::MAX_SIDE_PX || h > super::limits::MAX_SIDE_PX {
            return Err(bad("resolution", format!("{:?}", raw.resolution), "width and height must be at most 2048 px"));
        }
        if f > super::limits::MAX_SIDE_PX {
            return Err(bad("vae_scale_factor", f.to_string(), "must be at most 2048"));
        }
        if w == 0 || h == 0 || !w.is_multiple_of(f) || !h.is_multiple_of(f) {
            return Err(bad(
                "resolution",
                format!("{raw_res:?}", raw_res = raw.resolution),
                "must be positive multiples of vae_scale_factor",
            ));
        }
        if let Some(n) = raw.sampling_steps.filter(|n| super::limits::check_steps(Some(*n)).is_err()) {
            return Err(bad("sampling_steps", n.to_string(), "must be 1 to 10000 (no sampler takes more steps than training timesteps)"));
        }
        if let Some(g) = raw.guidance.filter(|g| super::limits::check_guidance(*g).is_err()) {
            return Err(bad("guidance", g.to_string(), "must be a number from 1 to 30 (1: unguided)"));
        }
        if let Some(eta) = raw.eta.filter(|e| super::limits::check_eta(*e).is_err()) {
            return Err(bad("eta", eta.to_string(), "must be a number from 0 to 1 (0: deterministic DDIM)"));
        }
        let sampler = match raw.sampler {
            None => None,
            Some(text) => Some(text.parse::<SchedulerKind>().map_err(|_| bad("sampler", text, "expected \"ddim\" or \"dpm++2m\""))?),
        };
        Ok(Self {
            name: raw.name,
            width_px: w,
            height_px: h,
            modalities: raw.modalities,
            prompt_template: raw.prompt_template,
            latent_scale: raw.latent_scale as f32,
            hint_encoding,
            control_colour_map,
            vae_scale_factor: f,
            end_token: raw.end_token,
            sampling_steps: raw.sampling_steps,
            guidance: raw.guidance,
            sampler,
            eta: raw.eta,
        })
    }
}
