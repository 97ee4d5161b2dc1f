//! The [`Pipeline`] of a rig built without the `synth` feature (no ONNX Runtime, no
//! tokenizer): [`Pipeline::load`] refuses with [`FeatureMissing`], so no value of the type can
//! exist, and every caller (the fill job, the daemon, `rig synth`, the benchmark) compiles
//! unchanged and stops at the load with a message that says how to rebuild.

use std::path::Path;

use super::SynthError;
use super::package::ModelPackage;
use super::pipeline::{CancelCheck, GenerateOutput, GenerateRequest, SynthTiming};
use super::runtime::RuntimeOptions;
use crate::features::{Feature, FeatureMissing};

/// A loaded model package; in this build none can be loaded.
#[derive(Debug)]
pub struct Pipeline {
    never: std::convert::Infallible,
}

impl Pipeline {
    /// Always [`SynthError::FeatureMissing`]: this build cannot run a model.
    pub fn load(_model_dir: &Path, _opts: &RuntimeOptions) -> Result<Pipeline, SynthError> {
        Err(FeatureMissing { feature: Feature::Synth, needed_by: "running a model package" }.into())
    }
    pub fn guidance_passes(&self) -> String {
        match self.never {}
    }
    pub fn io_binding(&self) -> bool {
        match self.never {}
    }
    pub fn timing(&self) -> SynthTiming {
        match self.never {}
    }
    pub fn set_cancel(&mut self, _cancel: Option<CancelCheck>) {
        match self.never {}
    }
    pub fn size_multiple(&self) -> u32 {
        match self.never {}
    }
    pub fn check_request(&self, _r: &GenerateRequest) -> Result<(), SynthError> {
        match self.never {}
    }
    pub fn package_hash(&self) -> &str {
        match self.never {}
    }
    pub fn resolution(&self) -> (u32, u32) {
        match self.never {}
    }
    pub fn latent_shape(&self) -> [usize; 4] {
        match self.never {}
    }
    pub fn package(&self) -> &ModelPackage {
        match self.never {}
    }
    pub fn library(&self) -> &Path {
        match self.never {}
    }
    pub fn library_origin(&self) -> &'static str {
        match self.never {}
    }
    pub fn token_ids(&self, _prompt: &str) -> Result<Vec<u32>, SynthError> {
        match self.never {}
    }
    pub fn embed(&mut self, _prompt: &str) -> Result<Vec<f32>, SynthError> {
        match self.never {}
    }
    pub fn cached_prompts(&self) -> usize {
        match self.never {}
    }
    pub fn generate(&mut self, _request: &GenerateRequest) -> Result<GenerateOutput, SynthError> {
        match self.never {}
    }
    pub fn generate_batch(&mut self, _requests: &[GenerateRequest]) -> Result<Vec<GenerateOutput>, SynthError> {
        match self.never {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn load_says_the_build_has_no_synth_feature_and_exits_1() {
        let e = Pipeline::load(Path::new("models/default"), &RuntimeOptions::default()).expect_err("no ONNX Runtime in this build");
        assert!(matches!(e, SynthError::FeatureMissing(FeatureMissing { feature: Feature::Synth, .. })), "{e:?}");
        assert!(e.to_string().contains("built without the `synth` feature"), "{e}");
        assert_eq!(crate::report::exit_code(&anyhow::Error::new(e)), 1);
    }
}
