//! How the step loop feeds the models: classifier-free guidance as one batch of two against
//! two passes, I/O binding against plain copies (bit-identical on the CPU), the timing report,
//! and a GPU provider that is not there.

use std::path::{Path, PathBuf};
use std::process::Command;

use rig::synth::{GenerateOutput, GenerateRequest, Pipeline, RuntimeOptions, SchedulerKind};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn tiny() -> PathBuf {
    root().join("tests/data/tiny-package")
}

fn control() -> image::RgbImage {
    image::open(root().join("tests/data/tiny-reference/control.png")).unwrap().to_rgb8()
}

/// Two images (different seeds, prompts and samplers' noise) in one batch, as a fill makes them.
fn run(package: &Path, opts: &RuntimeOptions, guidance: f32, scheduler: SchedulerKind, eta: f32) -> Vec<GenerateOutput> {
    let mut pipeline = Pipeline::load(package, opts).unwrap();
    let control = control();
    let size = Some(pipeline.resolution());
    let requests: Vec<GenerateRequest> = [(3, "a tactile image, pressed"), (11, "another prompt")]
        .into_iter()
        .map(|(seed, prompt)| GenerateRequest { steps: 4, guidance, seed, scheduler, eta, size, ..GenerateRequest::new(&control, prompt) })
        .collect();
    pipeline.generate_batch(&requests).unwrap()
}

fn max_abs_diff(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
}

#[test]
fn two_pass_guidance_gives_the_batched_images() {
    let batched = RuntimeOptions::default();
    let two_pass = RuntimeOptions { force_two_pass: true, ..RuntimeOptions::default() };
    for (guidance, scheduler, eta) in
        [(9.0, SchedulerKind::Ddim, 0.0), (7.5, SchedulerKind::Ddim, 0.5), (4.0, SchedulerKind::DpmSolverPp2m, 0.0)]
    {
        let a = run(&tiny(), &batched, guidance, scheduler, eta);
        let b = run(&tiny(), &two_pass, guidance, scheduler, eta);
        assert_eq!(a.len(), 2);
        for (x, y) in a.iter().zip(&b) {
            let d = max_abs_diff(&x.raw.data, &y.raw.data);
            eprintln!("guidance {guidance} {scheduler}: max |batched - two passes| = {d:.2e}");
            assert!(d <= 1e-5, "guidance {guidance}: two passes differ from one batch by {d}");
        }
        // The two images differ from each other: each pass got its own rows.
        assert!(max_abs_diff(&a[0].raw.data, &a[1].raw.data) > 1e-3);
    }
    let p = Pipeline::load(&tiny(), &two_pass).unwrap();
    assert!(p.guidance_passes().starts_with("two passes"), "{}", p.guidance_passes());
    let p = Pipeline::load(&tiny(), &batched).unwrap();
    assert!(p.guidance_passes().starts_with("one batch of two"), "{}", p.guidance_passes());
}

/// I/O binding changes where tensors live, not what is computed: on the CPU the raw output is
/// the same to the bit as copying every tensor in and out, guided or not, for the tiny package
/// and the shipped default model.
#[test]
fn io_binding_leaves_cpu_output_bit_identical() {
    let bound = RuntimeOptions::default();
    let copied = RuntimeOptions { without_io_binding: true, ..RuntimeOptions::default() };
    let mut packages = vec![tiny()];
    if root().join("models/default/model.toml").is_file() {
        packages.push(root().join("models/default"));
    }
    for package in &packages {
        for guidance in [1.0, 9.0] {
            let a = run(package, &bound, guidance, SchedulerKind::Ddim, 0.0);
            let b = run(package, &copied, guidance, SchedulerKind::Ddim, 0.0);
            for (x, y) in a.iter().zip(&b) {
                let same = x.raw.data.iter().zip(&y.raw.data).all(|(p, q)| p.to_bits() == q.to_bits());
                assert!(
                    same && x.raw.shape == y.raw.shape,
                    "{}: guidance {guidance}: bound and copied outputs differ by {:e}",
                    package.display(),
                    max_abs_diff(&x.raw.data, &y.raw.data)
                );
            }
        }
    }
}

#[test]
fn timing_counts_load_and_images() {
    let mut pipeline = Pipeline::load(&tiny(), &RuntimeOptions::default()).unwrap();
    let t = pipeline.timing();
    assert!(t.load_s > 0.0 && t.images == 0 && t.steady_per_image_s().is_none(), "{t:?}");
    let control = control();
    let request = GenerateRequest { steps: 3, guidance: 1.0, size: Some(pipeline.resolution()), ..GenerateRequest::new(&control, "p") };
    pipeline.generate_batch(&[request, GenerateRequest { seed: 1, ..request }]).unwrap();
    pipeline.generate(&request).unwrap();
    let t = pipeline.timing();
    assert_eq!(t.images, 3);
    assert!(t.generate_s >= t.warmup_s && t.steady_per_image_s().is_some(), "{t:?}");
}

fn rig() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_rig"));
    c.current_dir(env!("CARGO_MANIFEST_DIR"));
    c.env_remove("RIG_CONFIG");
    c
}

fn output(c: &mut Command) -> (i32, String) {
    let o = c.output().expect("running rig");
    (o.status.code().unwrap_or(-1), String::from_utf8_lossy(&o.stdout).into_owned() + &String::from_utf8_lossy(&o.stderr))
}

#[test]
fn cli_reports_guidance_passes_and_timing() {
    let (code, text) = output(rig().args(["synth", "info", "--model"]).arg(tiny()));
    assert_eq!(code, 0, "{text}");
    assert!(text.contains("guidance     one batch of two"), "{text}");
    let (code, text) = output(rig().args(["synth", "info", "--two-pass-guidance", "--model"]).arg(tiny()));
    assert_eq!(code, 0, "{text}");
    assert!(text.contains("guidance     two passes a step (--two-pass-guidance)"), "{text}");

    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("one.png");
    let (code, text) = output(
        rig()
            .args(["synth", "one", "--prompt", "p", "--steps", "3", "--guidance", "3", "--model"])
            .arg(tiny())
            .arg("--control")
            .arg(root().join("tests/data/tiny-reference/control.png"))
            .arg("--out")
            .arg(&out),
    );
    assert_eq!(code, 0, "{text}");
    let line = text.lines().find(|l| l.starts_with("timing: load ")).unwrap_or_else(|| panic!("no timing line: {text}"));
    assert!(line.contains(" s, warm-up ") && line.contains(" s an image steady state (1 image)"), "{line}");
    assert!(out.is_file());
}

/// The CPU build of ONNX Runtime has no CUDA or TensorRT: asking for them fails with exit 1
/// (set-up, faults.md) and a message naming the provider and the library, before any image.
#[test]
fn a_gpu_provider_the_library_lacks_fails_cleanly() {
    for provider in ["cuda", "tensorrt"] {
        let (code, text) = output(rig().args(["synth", "info", "--provider", provider, "--device-id", "0", "--model"]).arg(tiny()));
        assert_eq!(code, 1, "{provider}: {text}");
        assert!(text.contains(&format!("execution provider {provider} is not available")), "{provider}: {text}");
        assert!(!text.contains("panicked"), "{text}");
    }
}
