//! Clear errors for broken packages: missing files and models whose tensors do not fit the
//! package contract. Each error must name the file and the tensor.

use std::path::{Path, PathBuf};

use rig::synth::{Pipeline, RuntimeOptions, SynthError};

fn tiny() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/tiny-package")
}

/// A copy of the tiny package in a temp dir, for breaking.
fn copy_package() -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    for f in rig::synth::package::PACKAGE_FILES {
        let to = dir.path().join(f);
        std::fs::create_dir_all(to.parent().unwrap()).unwrap();
        std::fs::copy(tiny().join(f), to).unwrap();
    }
    dir
}

#[test]
fn missing_model_file_is_named() {
    let dir = copy_package();
    std::fs::remove_file(dir.path().join("unet/model.onnx")).unwrap();
    std::fs::remove_file(dir.path().join("tokenizer/tokenizer.json")).unwrap();
    let e = Pipeline::load(dir.path(), &RuntimeOptions::default()).unwrap_err();
    let text = e.to_string();
    assert!(matches!(e, SynthError::MissingFiles { ref missing, .. } if missing.len() == 2), "{text}");
    assert!(text.contains("unet/model.onnx") && text.contains("tokenizer/tokenizer.json"), "{text}");
}

#[test]
fn missing_package_dir_lists_everything() {
    let e = Pipeline::load(Path::new("/nonexistent/package"), &RuntimeOptions::default()).unwrap_err();
    assert!(matches!(e, SynthError::MissingFiles { ref missing, .. } if missing.len() == 7), "{e}");
}

#[test]
fn unet_without_residual_inputs_names_file_and_tensor() {
    let dir = copy_package();
    // A ControlNet where the UNet should be: same first inputs, no residual inputs.
    std::fs::copy(tiny().join("controlnet/model.onnx"), dir.path().join("unet/model.onnx")).unwrap();
    let e = Pipeline::load(dir.path(), &RuntimeOptions::default()).unwrap_err();
    let text = e.to_string();
    match &e {
        SynthError::MissingTensor { file, tensor, direction, available } => {
            assert!(file.ends_with("unet/model.onnx"), "{text}");
            assert_eq!(tensor, "down_block_additional_residual_0");
            assert_eq!(*direction, "input");
            assert!(available.contains(&"controlnet_cond".to_string()));
        }
        other => panic!("unexpected error: {other}"),
    }
    assert!(text.contains("unet/model.onnx") && text.contains("down_block_additional_residual_0"), "{text}");
}

#[test]
fn text_encoder_with_wrong_input_names_file_and_tensor() {
    let dir = copy_package();
    std::fs::copy(tiny().join("vae_decoder/model.onnx"), dir.path().join("text_encoder/model.onnx")).unwrap();
    let e = Pipeline::load(dir.path(), &RuntimeOptions::default()).unwrap_err();
    let text = e.to_string();
    assert!(matches!(&e, SynthError::MissingTensor { tensor, .. } if tensor == "input_ids"), "{text}");
    assert!(text.contains("text_encoder/model.onnx") && text.contains("latent_sample"), "{text}");
}

#[test]
fn vae_decoder_with_wrong_inputs_names_file_and_tensor() {
    let dir = copy_package();
    // The UNet where the decoder goes: it takes `sample`, not `latent_sample`.
    std::fs::copy(tiny().join("unet/model.onnx"), dir.path().join("vae_decoder/model.onnx")).unwrap();
    let e = Pipeline::load(dir.path(), &RuntimeOptions::default()).unwrap_err();
    assert!(
        matches!(&e, SynthError::MissingTensor { tensor, file, .. } if tensor == "latent_sample" && file.ends_with("vae_decoder/model.onnx")),
        "{e}"
    );
}

#[test]
fn bad_configs_are_named() {
    let dir = copy_package();
    std::fs::write(dir.path().join("scheduler/scheduler_config.json"), r#"{"beta_schedule": "sigmoid"}"#).unwrap();
    let e = Pipeline::load(dir.path(), &RuntimeOptions::default()).unwrap_err();
    assert!(matches!(e, SynthError::Scheduler { .. }), "{e}");
    assert!(e.to_string().contains("scheduler_config.json") && e.to_string().contains("sigmoid"), "{e}");

    let dir = copy_package();
    std::fs::write(dir.path().join("model.toml"), "name = \"x\"\nlatent_scale = -1.0\n").unwrap();
    let e = Pipeline::load(dir.path(), &RuntimeOptions::default()).unwrap_err();
    assert!(matches!(e, SynthError::BadModelConfig { field: "latent_scale", .. }), "{e}");

    let dir = copy_package();
    std::fs::write(dir.path().join("tokenizer/tokenizer.json"), "{}").unwrap();
    let e = Pipeline::load(dir.path(), &RuntimeOptions::default()).unwrap_err();
    assert!(matches!(e, SynthError::Tokenizer { .. }), "{e}");
}

#[test]
fn bad_requests_are_rejected() {
    let mut p = Pipeline::load(&tiny(), &RuntimeOptions::default()).unwrap();
    let control = image::RgbImage::new(64, 64);
    let base = rig::synth::GenerateRequest { steps: 2, ..rig::synth::GenerateRequest::new(&control, "x") };
    let short = [0.0f32; 10];
    let cases = [
        rig::synth::GenerateRequest { size: Some((60, 64)), ..base },
        rig::synth::GenerateRequest { init_latents: Some(&short), ..base },
        rig::synth::GenerateRequest { guidance: f32::NAN, ..base },
        rig::synth::GenerateRequest { conditioning_scale: f32::INFINITY, ..base },
    ];
    for req in cases {
        assert!(matches!(p.generate(&req), Err(SynthError::BadRequest { .. })));
    }
    // A step count the schedule cannot take is the request's, named as `steps`.
    assert!(matches!(p.generate(&rig::synth::GenerateRequest { steps: 0, ..base }), Err(SynthError::BadRequest { field: "steps", .. })));
    // A non-native size works when it is a multiple of 8 (the models are spatially dynamic).
    let out = p.generate(&rig::synth::GenerateRequest { size: Some((48, 32)), ..base }).unwrap();
    assert_eq!(out.image.dimensions(), (48, 32));
    assert_eq!(p.resolution(), (64, 64));
    assert_eq!(p.package_hash().len(), 64);
}

/// The tiny package with one model replaced by a graph from tests/data/broken-models
/// (tools/make_broken_models.py).
fn with_broken(model_dir: &str, broken: &str) -> SynthError {
    let dir = copy_package();
    let broken = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/broken-models").join(broken);
    std::fs::copy(broken, dir.path().join(model_dir).join("model.onnx")).unwrap();
    Pipeline::load(dir.path(), &RuntimeOptions::default()).unwrap_err()
}

#[test]
fn residual_count_mismatch_names_both_files() {
    let e = with_broken("unet", "unet_3_residuals.onnx");
    assert!(matches!(e, SynthError::ResidualCountMismatch { controlnet: 4, unet: 3, .. }), "{e}");
    let text = e.to_string();
    assert!(text.contains("controlnet/model.onnx") && text.contains("unet/model.onnx"), "{text}");
}

#[test]
fn float16_hint_names_tensor_and_type() {
    let e = with_broken("controlnet", "controlnet_fp16_cond.onnx");
    match &e {
        SynthError::WrongElementType { file, tensor, expected, .. } => {
            assert!(file.ends_with("controlnet/model.onnx"));
            assert_eq!(tensor, "controlnet_cond");
            assert_eq!(*expected, "float32");
        }
        other => panic!("unexpected error: {other}"),
    }
}

#[test]
fn float_ids_name_tensor_and_type() {
    let e = with_broken("text_encoder", "text_encoder_float_ids.onnx");
    assert!(matches!(&e, SynthError::WrongElementType { tensor, .. } if tensor == "input_ids"), "{e}");
    assert!(e.to_string().contains("int32 or int64"), "{e}");
}

#[test]
fn unknown_extra_input_is_named() {
    let e = with_broken("vae_decoder", "vae_decoder_extra_input.onnx");
    assert!(
        matches!(&e, SynthError::UnexpectedInput { tensor, file } if tensor == "return_dict" && file.ends_with("vae_decoder/model.onnx")),
        "{e}"
    );
}
