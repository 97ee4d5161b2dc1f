//! The synthesis settings a job request names, as types: the sampler, how images are saved,
//! the twins' size and the shard. They stand alone (std, serde, clap and thiserror only), as do
//! [`super::limits`], so the daemon's request decoding can be fuzzed without the rest of rig
//! (`fuzz/fuzz_targets/job_request.rs`).

use std::str::FromStr;

/// A sampler name rig does not know.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("sampler {value:?} is not supported (ddim, dpm++2m)")]
pub struct UnknownSampler {
    pub value: String,
}

/// Which sampler the pipeline runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum SchedulerKind {
    /// diffusers' `DDIMScheduler` (what MultiDiffSense samples with, 50 steps, eta 0).
    #[default]
    Ddim,
    /// DPM-Solver++ 2M: second-order multistep; similar quality in fewer steps (about 20).
    DpmSolverPp2m,
}

impl SchedulerKind {
    /// `ddim` or `dpm++2m`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Ddim => "ddim",
            Self::DpmSolverPp2m => "dpm++2m",
        }
    }
}

impl std::fmt::Display for SchedulerKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for SchedulerKind {
    type Err = UnknownSampler;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "ddim" => Ok(Self::Ddim),
            "dpm++2m" | "dpmpp2m" | "dpm-solver++2m" | "dpmsolver++" => Ok(Self::DpmSolverPp2m),
            _ => Err(UnknownSampler { value: s.to_string() }),
        }
    }
}

impl serde::Serialize for SchedulerKind {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.collect_str(self)
    }
}

impl<'de> serde::Deserialize<'de> for SchedulerKind {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let text = <std::borrow::Cow<'de, str>>::deserialize(deserializer)?;
        text.parse().map_err(serde::de::Error::custom)
    }
}

/// How the decoder's output (nominally in [-1, 1]) becomes 8-bit pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ImageRange {
    /// `round(clamp(x / 2 + 0.5, 0, 1) * 255)`, as diffusers writes images: the same value is
    /// always the same grey, whatever else is in the image.
    #[default]
    Clamp,
    /// Each image stretched from its own minimum to its own maximum (over its three channels),
    /// as MultiDiffSense's generate.py and test.py save them: `normalise(x) = (x - min) / (max -
    /// min + 1e-8)`, then torchvision's `save_image`, `floor(v * 255 + 0.5)`. Its darkest pixel is
    /// always 0 and its brightest 255, so brightness is not comparable between images.
    #[value(name = "minmax")]
    MinMax,
}

impl std::fmt::Display for ImageRange {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            ImageRange::Clamp => "clamp",
            ImageRange::MinMax => "minmax",
        })
    }
}

/// The image size of a synthetic twin (`synth::fill::synthesise_poses_of`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum TwinSize {
    /// The model's resolution: its output as it came (the reference is resized to match).
    #[default]
    Model,
    /// The source dataset's frame size, as `--fill-missing` writes (the output resized).
    Source,
}

/// A shard not written `i/n` with `1 <= i <= n`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("shard {text:?}: write it i/n with 1 <= i <= n (e.g. 2/4)")]
pub struct BadShard {
    pub text: String,
}

/// One of `count` disjoint parts of the work, 1-based.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    pub index: u32,
    pub count: u32,
}

impl Shard {
    /// The whole work.
    pub const ALL: Shard = Shard { index: 1, count: 1 };

    /// Whether `pose_id` belongs to this shard.
    pub fn owns(&self, pose_id: u32) -> bool {
        pose_id % self.count == self.index - 1
    }
}

impl FromStr for Shard {
    type Err = BadShard;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let bad = || BadShard { text: s.to_string() };
        let (i, n) = s.split_once('/').ok_or_else(bad)?;
        let index: u32 = i.trim().parse().map_err(|_| bad())?;
        let count: u32 = n.trim().parse().map_err(|_| bad())?;
        if count == 0 || index == 0 || index > count {
            return Err(bad());
        }
        Ok(Shard { index, count })
    }
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

impl serde::Serialize for Shard {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.collect_str(self)
    }
}

impl<'de> serde::Deserialize<'de> for Shard {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let text = <std::borrow::Cow<'de, str>>::deserialize(deserializer)?;
        text.parse().map_err(serde::de::Error::custom)
    }
}

/// The defaults of the settings a fill request may leave out (`synth::fill::FillOptions`).
pub mod defaults {
    /// Sampling steps when neither the request nor the package names them.
    pub const STEPS: usize = 20;
    /// Guidance when neither the request nor the package names it (1: unguided).
    pub const GUIDANCE: f32 = 1.0;
    /// ControlNet conditioning scale (1: as trained).
    pub const CONDITIONING_SCALE: f32 = 1.0;
    /// Poses per model call.
    pub const BATCH: usize = 4;
    /// Supersampling of the control image's depth map.
    pub const SUPERSAMPLE: u32 = 2;
}
