//! A missing or broken ONNX Runtime library is a clear error, not a panic. Kept in its own test
//! binary: once a process has loaded ONNX Runtime it stays loaded.

use std::path::Path;

use rig::synth::{Pipeline, RuntimeOptions, SynthError};

#[test]
fn missing_and_broken_library() {
    let package = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/tiny-package");
    let opts = RuntimeOptions { ort_lib: Some("/nonexistent/libonnxruntime.so".into()), ..Default::default() };
    let e = Pipeline::load(&package, &opts).unwrap_err();
    assert!(matches!(e, SynthError::OrtLibraryMissing { .. }), "{e}");
    assert!(e.to_string().contains("/nonexistent/libonnxruntime.so"), "{e}");

    let dir = tempfile::tempdir().unwrap();
    let e = Pipeline::load(&package, &RuntimeOptions { ort_lib: Some(dir.path().into()), ..Default::default() }).unwrap_err();
    assert!(matches!(e, SynthError::OrtLibraryNotFound { .. }), "{e}");
    assert!(e.to_string().contains("scripts/setup.sh"), "{e}");

    let fake = dir.path().join("libonnxruntime.so");
    std::fs::write(&fake, b"not a shared library").unwrap();
    let e = Pipeline::load(&package, &RuntimeOptions { ort_lib: Some(fake.clone()), ..Default::default() }).unwrap_err();
    assert!(matches!(e, SynthError::OrtLoad { .. }), "{e}");
    assert!(e.to_string().contains(&fake.display().to_string()), "{e}");
}
