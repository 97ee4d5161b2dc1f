//! rig against MultiDiffSense's own sampler, on packages exported from MultiDiffSense
//! checkpoints by `tools/export_package.py --original-ckpt`.
//!
//! Plain test: the committed `tests/data/mds-small-package/`, exported from a small random
//! checkpoint built with MultiDiffSense's own classes (`tests/data/mds-small/`, made by
//! `tools/make_mds_small.sh`), whose references MultiDiffSense's `ControlLDM.log_images` produced
//! from the same `x_T`. `rig synth one --init-latents x_T.npy --dump-raw` (the real binary) must
//! reproduce all four (4 and 50 DDIM steps, guidance 1 and 9) to under 1e-4 before clamping, and
//! the text embeddings too. The checkpoint's CLIP weights differ from `clip/`'s, so matching
//! embeddings also shows the exporter took CLIP from the checkpoint.
//!
//! Opt-in (`--ignored`, needs the Python tools in `.venv`): the export itself, from the
//! MultiDiffSense kit's `tiny_cldm.ckpt` (`$RIG_SHARED/multidiffsense-cldm-kit`) as a plain
//! `{"state_dict"}` file and as a Lightning training checkpoint, into fresh folders, then the
//! same parity against the kit's references.

use std::path::{Path, PathBuf};
use std::process::Command;

use rig::synth::npy::NpyArray;
use rig::synth::{ImageRange, Pipeline, RuntimeOptions};

/// Largest difference allowed between rig's raw output and MultiDiffSense's.
const TOLERANCE: f32 = 1e-4;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn shared() -> PathBuf {
    let rel = std::env::var("RIG_SHARED").unwrap_or_else(|_| "../shared".to_string());
    let p = PathBuf::from(rel);
    if p.is_absolute() { p } else { root().join(p) }
}

fn read(path: &Path) -> NpyArray {
    NpyArray::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// NHWC `[1, H, W, C]` as NCHW `[1, C, H, W]`.
fn nhwc_to_nchw(a: &NpyArray) -> NpyArray {
    let [n, h, w, c] = a.shape[..] else { panic!("expected NHWC, got {:?}", a.shape) };
    let mut data = vec![0.0; a.data.len()];
    for b in 0..n {
        for y in 0..h {
            for x in 0..w {
                for ch in 0..c {
                    data[((b * c + ch) * h + y) * w + x] = a.data[((b * h + y) * w + x) * c + ch];
                }
            }
        }
    }
    NpyArray { shape: vec![n, c, h, w], data }
}

fn max_abs_diff(a: &NpyArray, b: &NpyArray) -> f32 {
    assert_eq!(a.shape, b.shape, "shapes differ");
    a.data.iter().zip(&b.data).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
}

/// `rig synth one` on `kit`'s hint, prompt and `x_T.npy` with `extra` flags; the raw output
/// (NCHW) and what the command printed.
fn synth_one(package: &Path, kit: &Path, out: &Path, tag: &str, extra: &[&str]) -> (NpyArray, String) {
    let prompt = std::fs::read_to_string(kit.join("prompt.txt")).unwrap_or_else(|e| panic!("{}: {e}", kit.display()));
    let raw = out.join(format!("{tag}.npy"));
    let output = Command::new(env!("CARGO_BIN_EXE_rig"))
        .args(["synth", "one", "--model"])
        .arg(package)
        .arg("--control")
        .arg(kit.join("hint.png"))
        .args(["--prompt", &prompt, "--init-latents"])
        .arg(kit.join("x_T.npy"))
        .arg("--out")
        .arg(out.join(format!("{tag}.png")))
        .arg("--dump-raw")
        .arg(&raw)
        .args(extra)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&output.stdout).to_string();
    assert!(output.status.success(), "rig synth one {extra:?}: {}{text}", String::from_utf8_lossy(&output.stderr));
    (nhwc_to_nchw(&read(&raw)), text)
}

/// Every reference of `kit` (`ref/samples_S{4,50}.npy` at guidance 1, `ref/samples_cfg9_S{4,50}.npy`
/// at guidance 9, `ref/text_embedding_{cond,uncond}.npy`) against rig on `package`.
fn check_against_references(package: &Path, kit: &Path) {
    let tmp = tempfile::tempdir().unwrap();
    let mut report = Vec::new();
    for steps in ["4", "50"] {
        for (guidance, reference) in [("1", format!("samples_S{steps}")), ("9", format!("samples_cfg9_S{steps}"))] {
            let (got, printed) = synth_one(package, kit, tmp.path(), &reference, &["--steps", steps, "--guidance", guidance]);
            assert!(printed.contains(&format!("{steps} steps ddim, guidance {guidance}, eta 0")), "{printed}");
            let want = read(&kit.join("ref").join(format!("{reference}.npy")));
            let d = max_abs_diff(&got, &want);
            report.push(format!("{reference}: max |rig - MultiDiffSense| = {d:.2e}"));
            assert!(d < TOLERANCE, "{}: {reference} (steps {steps}, guidance {guidance}) differs by {d:.3e}", package.display());
        }
    }
    let mut pipeline = Pipeline::load(package, &RuntimeOptions::default()).unwrap();
    let prompt = std::fs::read_to_string(kit.join("prompt.txt")).unwrap();
    for (text, name) in [(prompt.as_str(), "text_embedding_cond"), ("", "text_embedding_uncond")] {
        let want = read(&kit.join("ref").join(format!("{name}.npy")));
        let got = NpyArray { shape: want.shape.clone(), data: pipeline.embed(text).unwrap() };
        let d = max_abs_diff(&got, &want);
        report.push(format!("{name}: max |rig - MultiDiffSense| = {d:.2e}"));
        assert!(d < TOLERANCE, "{}: {name} differs by {d:.3e}", package.display());
    }
    eprintln!("{}:\n  {}", package.display(), report.join("\n  "));
}

fn small_package() -> PathBuf {
    root().join("tests/data/mds-small-package")
}

fn small_kit() -> PathBuf {
    root().join("tests/data/mds-small")
}

#[test]
fn exported_small_checkpoint_reproduces_multidiffsense_sampler() {
    check_against_references(&small_package(), &small_kit());
}

#[test]
fn package_defaults_are_multidiffsense_sampling() {
    // No sampling flags: the package's model.toml says DDIM, 50 steps, eta 0, guidance 1, which
    // is what MultiDiffSense's scripts save (samples_S50).
    let tmp = tempfile::tempdir().unwrap();
    let (got, printed) = synth_one(&small_package(), &small_kit(), tmp.path(), "defaults", &[]);
    assert!(printed.contains("50 steps ddim, guidance 1, eta 0"), "{printed}");
    let d = max_abs_diff(&got, &read(&small_kit().join("ref/samples_S50.npy")));
    assert!(d < TOLERANCE, "defaults differ from MultiDiffSense's saved sample by {d:.3e}");
    let info = Command::new(env!("CARGO_BIN_EXE_rig")).args(["synth", "info", "--model"]).arg(small_package()).output().unwrap();
    let text = String::from_utf8_lossy(&info.stdout);
    assert!(info.status.success(), "{text}{}", String::from_utf8_lossy(&info.stderr));
    assert!(text.contains("sampling     sampler ddim, steps 50, eta 0, guidance 1 (model.toml; flags override)"), "{text}");
}

#[test]
fn ddim_timesteps_are_multidiffsense_ones() {
    // For 4 and 50 steps MultiDiffSense's DDIMSampler visits range(0, 1000, 1000 // S) + 1, the
    // timesteps of diffusers' DDIM with leading spacing and steps_offset 1 (its meta.json).
    let pipeline = Pipeline::load(&small_package(), &RuntimeOptions::default()).unwrap();
    let meta: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(small_kit().join("ref/meta.json")).unwrap()).unwrap();
    for steps in [4usize, 50] {
        let want: Vec<i64> =
            meta["runs"][steps.to_string()]["ddim_timesteps"].as_array().unwrap().iter().map(|v| v.as_i64().unwrap()).collect();
        let mut got = pipeline.package().schedule.timesteps(steps).unwrap();
        got.reverse();
        assert_eq!(got, want, "{steps} steps");
    }
}

#[test]
fn min_max_image_range_is_what_multidiffsense_saves() {
    let tmp = tempfile::tempdir().unwrap();
    let (raw, printed) = synth_one(&small_package(), &small_kit(), tmp.path(), "minmax", &["--steps", "4", "--image-range", "minmax"]);
    assert!(printed.contains("image range minmax"), "{printed}");
    synth_one(&small_package(), &small_kit(), tmp.path(), "clamp", &["--steps", "4"]);
    let minmax = image::open(tmp.path().join("minmax.png")).unwrap().to_rgb8();
    let clamp = image::open(tmp.path().join("clamp.png")).unwrap().to_rgb8();
    // The PNG is the library's min-max mapping of the raw output...
    let [_, c, h, w] = raw.shape[..] else { unreachable!() };
    let nhwc: Vec<f32> = (0..h * w * c).map(|i| raw.data[(i % c) * h * w + i / c]).collect();
    assert_eq!(minmax, rig::synth::pipeline::raw_to_rgb8(&nhwc, w as u32, h as u32, ImageRange::MinMax));
    // ...spanning 0..=255, and not the clamp (the raw range is about [-1.3, 1.8]).
    let (lo, hi) = minmax.as_raw().iter().fold((255u8, 0u8), |(lo, hi), &v| (lo.min(v), hi.max(v)));
    assert_eq!((lo, hi), (0, 255));
    let worst = minmax.as_raw().iter().zip(clamp.as_raw()).map(|(a, b)| a.abs_diff(*b)).max().unwrap();
    eprintln!("min-max against clamp: up to {worst} grey levels");
    assert!(worst > 10, "min-max and clamp PNGs differ by only {worst} levels");
}

/// The Python that runs the exporter: $RIG_PYTHON, else .venv/bin/python.
fn python() -> PathBuf {
    std::env::var_os("RIG_PYTHON").map(PathBuf::from).unwrap_or_else(|| root().join(".venv/bin/python"))
}

fn run_python(args: &[&std::ffi::OsStr]) -> String {
    let started = std::time::Instant::now();
    let output = Command::new(python()).args(args).current_dir(root()).output().unwrap_or_else(|e| {
        panic!("{}: {e} (make the venv: python3 -m venv .venv && .venv/bin/pip install -r tools/requirements.txt)", python().display())
    });
    let text = format!("{}{}", String::from_utf8_lossy(&output.stdout), String::from_utf8_lossy(&output.stderr));
    assert!(output.status.success(), "{:?} failed:\n{text}", args);
    eprintln!("{:?}: {:.0} s", args.iter().take(2).collect::<Vec<_>>(), started.elapsed().as_secs_f64());
    text
}

fn export(ckpt: &Path, kit: &Path, out: &Path) -> String {
    run_python(&[
        "tools/export_package.py".as_ref(),
        "--original-ckpt".as_ref(),
        ckpt.as_os_str(),
        "--original-config".as_ref(),
        kit.join("tiny_cldm.yaml").as_os_str(),
        "--clip-dir".as_ref(),
        kit.join("clip").as_os_str(),
        "--out".as_ref(),
        out.as_os_str(),
    ])
}

#[test]
#[ignore = "needs the Python tools (tools/requirements.txt) in .venv and $RIG_SHARED/multidiffsense-cldm-kit; about 5 min"]
fn kit_checkpoint_exports_in_both_forms_and_reproduces_multidiffsense() {
    let kit = shared().join("multidiffsense-cldm-kit");
    assert!(kit.join("tiny_cldm.ckpt").is_file(), "{} has no tiny_cldm.ckpt (set RIG_SHARED)", kit.display());
    let tmp = tempfile::tempdir().unwrap();

    // The plain {"state_dict"} file.
    let plain = tmp.path().join("plain-package");
    let log = export(&kit.join("tiny_cldm.ckpt"), &kit, &plain);
    assert!(log.contains("{'state_dict'} file"), "{log}");
    assert!(log.contains("text encoder checkpoint cond_stage_model.transformer.*"), "{log}");
    check_against_references(&plain, &kit);

    // The Lightning training checkpoint train.py writes, with hyper_parameters as Lightning's
    // AttributeDict (read through the exporter's stand-in).
    let lightning = tmp.path().join("lightning.ckpt");
    run_python(&[
        "tools/make_lightning_checkpoint.py".as_ref(),
        kit.join("tiny_cldm.ckpt").as_os_str(),
        lightning.as_os_str(),
        "--hparams".as_ref(),
    ]);
    let package = tmp.path().join("lightning-package");
    let log = export(&lightning, &kit, &package);
    assert!(log.contains("Lightning training checkpoint (Lightning 2.6.6, epoch 119, global_step 78840"), "{log}");
    check_against_references(&package, &kit);
    // The same weights give the same package files (the name aside).
    for model in ["text_encoder", "controlnet", "unet", "vae_decoder"] {
        let a = std::fs::read(plain.join(model).join("model.onnx")).unwrap();
        let b = std::fs::read(package.join(model).join("model.onnx")).unwrap();
        assert!(a == b, "{model}/model.onnx differs between the plain and the Lightning export");
    }

    // A checkpoint whose unpickling would run code is refused, and the code does not run.
    let evil = tmp.path().join("code.ckpt");
    let marker = tmp.path().join("ran");
    run_python(&[
        "tools/make_lightning_checkpoint.py".as_ref(),
        kit.join("tiny_cldm.ckpt").as_os_str(),
        evil.as_os_str(),
        "--code".as_ref(),
        marker.as_os_str(),
    ]);
    let output = Command::new(python())
        .args(["tools/export_package.py", "--original-ckpt"])
        .arg(&evil)
        .arg("--original-config")
        .arg(kit.join("tiny_cldm.yaml"))
        .arg("--clip-dir")
        .arg(kit.join("clip"))
        .arg("--out")
        .arg(tmp.path().join("refused"))
        .current_dir(root())
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success() && text.contains("refusing to unpickle posix.system"), "{text}");
    assert!(!marker.exists(), "unpickling the checkpoint ran its code");
    assert!(!tmp.path().join("refused/model.toml").exists());
}
