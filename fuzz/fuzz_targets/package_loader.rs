//! Fuzzes the model-package loader's three text files: `model.toml`, the scheduler's
//! `scheduler_config.json` and `tokenizer/tokenizer.json`. The input is the three files joined
//! by NUL bytes (a missing part is empty). Each must parse and validate, or be refused, without
//! panicking and without allocating by a number it holds: a config that validates builds its
//! noise schedule and samplers for the package's step count and the largest the schedule
//! allows (the arrays a 1e12 `num_train_timesteps` once asked 4 TB for), and takes a step.
//!
//! `model.toml` and the scheduler compile from rig's own source files (`#[path]` modules:
//! src/synth/model_toml.rs, scheduler.rs, limits.rs, settings.rs, src/untrusted.rs and the
//! opener it reads through, src/confine.rs). The
//! tokenizer is loaded with the calls `synth::text::PromptTokenizer::load` makes (that file
//! needs ONNX Runtime, so the calls are repeated here): the `tokenizers` crate's JSON reader,
//! the end-token lookup, fixed truncation and padding to 77, and one encode.
#![no_main]
#![allow(dead_code)]

#[path = "../../src/synth/limits.rs"]
mod limits;
#[path = "../../src/synth/model_toml.rs"]
mod model_toml;
#[path = "../../src/synth/scheduler.rs"]
mod scheduler;
#[path = "../../src/synth/settings.rs"]
mod settings;
#[path = "../../src/synth/tokenizer_json.rs"]
mod tokenizer_json;
#[path = "../../src/untrusted.rs"]
mod untrusted;
#[path = "../../src/confine.rs"]
mod confine;

use libfuzzer_sys::fuzz_target;
use scheduler::{NoiseSchedule, Scheduler, SchedulerConfig, SchedulerKind};

/// What rig's loader bounds `tokenizer.json` to (`synth::text::MAX_TOKENIZER_BYTES` is 64 MiB;
/// fuzz inputs are far smaller).
const SEQUENCE_LEN: usize = 77;

fn model_toml(bytes: &[u8]) -> Option<model_toml::ModelConfig> {
    model_toml::ModelConfig::parse(std::str::from_utf8(bytes).ok()?).ok()
}

fn schedule(bytes: &[u8], config: Option<&model_toml::ModelConfig>) {
    let Ok(text) = std::str::from_utf8(bytes) else { return };
    let Ok(parsed) = SchedulerConfig::from_json(text) else { return };
    let Ok(schedule) = NoiseSchedule::new(parsed) else { return };
    let package_steps = config.and_then(|c| c.sampling_steps);
    for kind in [SchedulerKind::Ddim, SchedulerKind::DpmSolverPp2m] {
        let max = schedule.max_steps(kind);
        assert!(max <= limits::MAX_STEPS, "{max} steps");
        for steps in [Some(1), Some(max), package_steps].into_iter().flatten() {
            if schedule.check_steps(kind, steps).is_err() {
                continue;
            }
            let eta = config.and_then(|c| c.eta).unwrap_or(0.0);
            let Ok(mut sampler) = Scheduler::new(&schedule, kind, steps, eta) else { continue };
            assert_eq!(sampler.timesteps().len(), steps);
            let sample = [0.5f32, -1.0, 2.0, 0.25];
            let noise = sampler.needs_noise().then_some([1.0f32, 0.0, -1.0, 0.5]);
            let _ = sampler.step(&schedule, &[0.1, -0.2, 0.3, -0.4], &sample, noise.as_ref().map(|n| &n[..]));
        }
    }
}

fn tokenizer(bytes: &[u8], end_token: &str) {
    use tokenizers::{
        PaddingDirection, PaddingParams, PaddingStrategy, TruncationDirection, TruncationParams, TruncationStrategy,
    };
    // rig reads the file through `tokenizer_json::parse`, which turns a panic inside the crate
    // into a refusal; libFuzzer's panic hook aborts at once, so the default hook stands in while
    // it runs (any panic outside the guard still aborts).
    let hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    let parsed = tokenizer_json::parse(bytes);
    std::panic::set_hook(hook);
    let Ok(mut tokenizer) = parsed else { return };
    let Some(end_id) = tokenizer.token_to_id(end_token) else { return };
    let truncation = TruncationParams {
        direction: TruncationDirection::Right,
        max_length: SEQUENCE_LEN,
        strategy: TruncationStrategy::LongestFirst,
        stride: 0,
    };
    if tokenizer.with_truncation(Some(truncation)).is_err() {
        return;
    }
    tokenizer.with_padding(Some(PaddingParams {
        strategy: PaddingStrategy::Fixed(SEQUENCE_LEN),
        direction: PaddingDirection::Right,
        pad_to_multiple_of: None,
        pad_id: end_id,
        pad_type_id: 0,
        pad_token: end_token.to_string(),
    }));
    let hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    let _ = tokenizer_json::encode(&tokenizer, "{'sensor_context': 'captured by TacTip.', 'object_pose': {'x': 0.1, 'yaw': 15.0}}");
    std::panic::set_hook(hook);
}

fuzz_target!(|data: &[u8]| {
    let mut parts = data.splitn(3, |b| *b == 0);
    let (toml, json, tok) = (parts.next().unwrap_or_default(), parts.next().unwrap_or_default(), parts.next().unwrap_or_default());
    let config = model_toml(toml);
    schedule(json, config.as_ref());
    let end_token = config.as_ref().map_or("<|endoftext|>", |c| c.end_token.as_str());
    tokenizer(tok, end_token);
});
