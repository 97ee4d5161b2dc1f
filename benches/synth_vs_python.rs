//! Seconds per image: rig's pipeline against Python onnxruntime driving the same package the
//! same way (tools/ort_pipeline.py: same batching, same DDIM, same session calls), side by side.
//!
//!     cargo bench --bench synth_vs_python                 # release profile
//!     cargo test --bench synth_vs_python -- --bench       # dev profile (what docs/src/benchmarks.md quotes)
//!
//! Settings from the environment: RIG_BENCH_MODEL (package, default the tiny test package),
//! RIG_BENCH_STEPS (20), RIG_BENCH_IMAGES (3 timed images after one warm-up), RIG_BENCH_SIZES
//! (`64x64,256x256`), RIG_BENCH_GUIDANCE (`7.5,1`), RIG_BENCH_THREADS (threads per session for
//! both sides; default ONNX Runtime's choice), RIG_PYTHON (`.venv/bin/python`). Without
//! The ratio compares the fastest image of each side, the figure least disturbed by other load
//! on the machine. Without `--bench` (as `cargo test --all-targets` runs it) it makes one 2-step image and exits, so
//! the suite stays fast.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use rig::synth::{GenerateRequest, Pipeline, RuntimeOptions};

fn env_or(name: &str, default: &str) -> String {
    std::env::var(name).unwrap_or_else(|_| default.to_string())
}

fn parse_size(s: &str) -> Option<(u32, u32)> {
    let (w, h) = s.split_once('x')?;
    Some((w.trim().parse().ok()?, h.trim().parse().ok()?))
}

/// Python's (mean, min) seconds per image, or why there are none.
#[allow(clippy::too_many_arguments)]
fn python_seconds(
    python: &str,
    model: &Path,
    control: &Path,
    prompt: &str,
    steps: usize,
    guidance: f32,
    images: usize,
    size: (u32, u32),
    threads: Option<usize>,
) -> Result<(f64, f64), String> {
    let mut cmd = Command::new(python);
    cmd.arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/ort_pipeline.py"));
    if let Some(n) = threads {
        cmd.args(["--threads", &n.to_string()]);
    }
    let out = cmd
        .args(["--model", &model.display().to_string(), "--control", &control.display().to_string(), "--prompt", prompt])
        .args(["--steps", &steps.to_string(), "--guidance", &guidance.to_string(), "--images", &images.to_string()])
        .args(["--size", &format!("{}x{}", size.0, size.1), "--json"])
        .output()
        .map_err(|e| format!("cannot run {python}: {e}"))?;
    if !out.status.success() {
        return Err(format!("python failed: {}", String::from_utf8_lossy(&out.stderr).lines().last().unwrap_or("")));
    }
    let text = String::from_utf8_lossy(&out.stdout);
    let line = text.lines().last().unwrap_or("");
    let field = |key: &str| -> Result<f64, String> {
        let pattern = format!("\"{key}\": ");
        let start = line.find(&pattern).ok_or(format!("no {key} in python output"))? + pattern.len();
        let rest = &line[start..];
        let end = rest.find([',', '}']).unwrap_or(rest.len());
        rest[..end].trim().parse::<f64>().map_err(|e| format!("bad {key}: {e}"))
    };
    Ok((field("mean_s")?, field("min_s")?))
}

fn main() {
    let bench = std::env::args().any(|a| a == "--bench");
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let model = PathBuf::from(env_or("RIG_BENCH_MODEL", &root.join("tests/data/tiny-package").display().to_string()));
    let control_path = root.join("tests/data/tiny-reference/control.png");
    let control = match image::open(&control_path) {
        Ok(i) => i.to_rgb8(),
        Err(e) => {
            eprintln!("synth_vs_python: cannot read {}: {e}", control_path.display());
            return;
        }
    };
    let prompt = rig::synth::prompt::mds_prompt(rig::sensor::SensorKind::ViTac, &rig::pose::Pose::new(0.12, -0.34, 1.5, 15.0));
    let threads: Option<usize> = std::env::var("RIG_BENCH_THREADS").ok().and_then(|t| t.parse().ok());
    let opts = RuntimeOptions { intra_threads: threads, ..Default::default() };
    let mut pipeline = match Pipeline::load(&model, &opts) {
        Ok(p) => p,
        Err(e) => {
            eprintln!("synth_vs_python: skipped: {e}");
            return;
        }
    };
    if !bench {
        let req = GenerateRequest { steps: 2, ..GenerateRequest::new(&control, &prompt) };
        match pipeline.generate(&req) {
            Ok(_) => println!("synth_vs_python: smoke run ok (pass --bench for the comparison)"),
            Err(e) => {
                eprintln!("synth_vs_python: smoke run failed: {e}");
                std::process::exit(1);
            }
        }
        return;
    }
    let steps: usize = env_or("RIG_BENCH_STEPS", "20").parse().unwrap_or(20);
    let images: usize = env_or("RIG_BENCH_IMAGES", "3").parse().unwrap_or(3).max(1);
    let sizes: Vec<(u32, u32)> = env_or("RIG_BENCH_SIZES", "64x64,256x256").split(',').filter_map(parse_size).collect();
    let guidances: Vec<f32> = env_or("RIG_BENCH_GUIDANCE", "7.5,1").split(',').filter_map(|g| g.trim().parse().ok()).collect();
    let python = env_or("RIG_PYTHON", &root.join(".venv/bin/python").display().to_string());

    println!(
        "package {} ({}), DDIM {steps} steps, {images} timed images after 1 warm-up, CPU, threads per session: {}",
        model.display(),
        pipeline.package().config.name,
        threads.map_or("default".to_string(), |t| t.to_string())
    );
    println!("| size | guidance | rig s/image, mean (min) | python onnxruntime s/image, mean (min) | rig / python (of the mins) |");
    println!("|---|---|---|---|---|");
    for &size in &sizes {
        for &guidance in &guidances {
            let req = GenerateRequest { steps, guidance, size: Some(size), ..GenerateRequest::new(&control, &prompt) };
            let mut times = Vec::new();
            for i in 0..=images {
                let r = GenerateRequest { seed: i as u64, ..req };
                let t = Instant::now();
                if let Err(e) = pipeline.generate(&r) {
                    eprintln!("rig failed: {e}");
                    return;
                }
                if i > 0 {
                    times.push(t.elapsed().as_secs_f64());
                }
            }
            let rig_mean = times.iter().sum::<f64>() / times.len() as f64;
            let rig_min = times.iter().copied().fold(f64::INFINITY, f64::min);
            let (py, ratio) = match python_seconds(&python, &model, &control_path, &prompt, steps, guidance, images, size, threads) {
                Ok((mean, min)) => (format!("{mean:.3} ({min:.3})"), format!("{:.2}", rig_min / min)),
                Err(e) => (format!("n/a ({e})"), "n/a".to_string()),
            };
            println!("| {}x{} | {guidance} | {rig_mean:.3} ({rig_min:.3}) | {py} | {ratio} |", size.0, size.1);
        }
    }
}
