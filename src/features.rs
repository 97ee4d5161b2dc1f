//! The optional parts of this build (Cargo features, all on by default) and the error a command
//! gets when it needs one that was left out.
//!
//! - `synth`: ONNX Runtime (`ort`) and the prompt tokenizer (`tokenizers`): `rig synth`,
//!   `rig fill`, the daemon's synth jobs and the synthesis benchmark. Without it
//!   [`crate::synth::Pipeline::load`] returns [`FeatureMissing`]; everything else of
//!   [`crate::synth`] (settings, limits, prompts, schedulers, control images) stays.
//! - `lerobot`: arrow and parquet, for `rig dataset export --format lerobot`.
//! - `downstream`: candle, the pose regressor of `rig eval --downstream`
//!   ([`crate::eval::regressor`]); without it training returns [`FeatureMissing`].
//!
//! A command that needs a missing feature still parses; it stops before doing any work with
//! [`FeatureMissing`], exit code 1 (general failure: the input is fine, the build lacks the part).

/// One optional part of rig.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Feature {
    /// ONNX Runtime and the tokenizer: image synthesis.
    Synth,
    /// arrow and parquet: the LeRobot export.
    Lerobot,
    /// candle: the pose regressor of `rig eval --downstream`.
    Downstream,
}

impl Feature {
    /// Every feature, in the order `rig --version` lists them.
    pub const ALL: [Feature; 3] = [Feature::Synth, Feature::Lerobot, Feature::Downstream];

    /// Its name in Cargo.toml's `[features]`.
    pub fn name(self) -> &'static str {
        match self {
            Feature::Synth => "synth",
            Feature::Lerobot => "lerobot",
            Feature::Downstream => "downstream",
        }
    }

    /// Whether this build has it.
    pub fn built(self) -> bool {
        match self {
            Feature::Synth => cfg!(feature = "synth"),
            Feature::Lerobot => cfg!(feature = "lerobot"),
            Feature::Downstream => cfg!(feature = "downstream"),
        }
    }

    /// `Ok` when this build has the feature, else the error that names what needed it.
    pub fn require(self, needed_by: &'static str) -> Result<(), FeatureMissing> {
        if self.built() { Ok(()) } else { Err(FeatureMissing { feature: self, needed_by }) }
    }
}

/// A command or job needs a part this build was made without.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "this rig was built without the `{}` feature, which {needed_by} needs; rebuild with `cargo build --release --features {}` \
     (or without `--no-default-features`: it is on by default)",
    feature.name(),
    feature.name()
)]
pub struct FeatureMissing {
    pub feature: Feature,
    /// The command or job that needs it, e.g. `rig synth`.
    pub needed_by: &'static str,
}

/// The features this build has, comma-separated (`none` when it has none).
pub fn built_list() -> String {
    let names: Vec<&str> = Feature::ALL.into_iter().filter(|f| f.built()).map(Feature::name).collect();
    if names.is_empty() { "none".to_string() } else { names.join(",") }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn require_follows_the_build_and_names_the_feature_and_the_command() {
        for feature in Feature::ALL {
            match feature.require("rig frobnicate") {
                Ok(()) => assert!(feature.built()),
                Err(e) => {
                    assert!(!feature.built());
                    let text = e.to_string();
                    assert!(text.contains(&format!("without the `{}` feature", feature.name())), "{text}");
                    assert!(text.contains("rig frobnicate"), "{text}");
                }
            }
        }
        assert_eq!(Feature::Synth.built(), cfg!(feature = "synth"));
        assert_eq!(Feature::Lerobot.built(), cfg!(feature = "lerobot"));
        assert_eq!(built_list().contains("synth"), cfg!(feature = "synth"));
    }
}
