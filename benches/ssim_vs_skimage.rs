//! Milliseconds per SSIM of a 512 x 512 RGB pair: rig's `metrics::ssim` against the
//! implementation it replaced (`metrics::ssim_reference`) and against scikit-image
//! (`tools/ssim_skimage.py`: `structural_similarity` with the same window, constants and border)
//! on the same two images, in interleaved rounds; and the values, which must agree to 1e-6.
//!
//!     cargo bench --bench ssim_vs_skimage                 # release profile (what the docs quote)
//!
//! Settings from the environment: RIG_BENCH_ROUNDS (5 rounds; each times every side
//! RIG_BENCH_REPEATS = 5 times), RIG_PYTHON (`.venv/bin/python`; a Python with scikit-image,
//! Pillow and numpy; without one the peer is left out and said so), RIG_SHARED (the pair is
//! frames 0 and 2 of the real TacTip sample when `$RIG_SHARED/real-sample` is there, else two
//! seeded textures). Ratios compare the fastest call of each side, the figure least disturbed by
//! other load. rig uses every core rayon sees (RAYON_NUM_THREADS sets it). Without `--bench` (as
//! `cargo test --all-targets` runs it) it checks one small pair against the reference and exits.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use image::RgbImage;
use rig::bench::loops::texture;
use rig::metrics::{ssim, ssim_reference};

fn env_or(name: &str, default: &str) -> String {
    std::env::var(name).unwrap_or_else(|_| default.to_string())
}

/// The pair and where it came from.
fn pair() -> (RgbImage, RgbImage, String) {
    let shared = PathBuf::from(env_or("RIG_SHARED", "../shared"));
    let dir = shared.join("real-sample/multidiffsense-example/tactile/1/TacTip/target");
    let load = |i: u32| image::open(dir.join(format!("1_TacTip_{i}.png"))).ok().map(|im| im.to_rgb8());
    match (load(0), load(2)) {
        (Some(a), Some(b)) if a.dimensions() == (512, 512) && b.dimensions() == (512, 512) => (a, b, "real TacTip frames 0 and 2".into()),
        _ => (texture(512, 1), texture(512, 2), "seeded 512 x 512 textures".into()),
    }
}

/// The fastest and mean seconds of `repeats` calls.
fn time(repeats: usize, mut f: impl FnMut() -> f64) -> (f64, f64, f64) {
    let mut times = Vec::with_capacity(repeats);
    let mut value = 0.0;
    for _ in 0..repeats {
        let t = Instant::now();
        value = std::hint::black_box(f());
        times.push(t.elapsed().as_secs_f64());
    }
    let min = times.iter().copied().fold(f64::INFINITY, f64::min);
    (min, times.iter().sum::<f64>() / times.len() as f64, value)
}

/// scikit-image's (fastest, mean, value), or why there is none.
fn skimage(python: &str, a: &Path, b: &Path, repeats: usize) -> Result<(f64, f64, f64), String> {
    let out = Command::new(python)
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/ssim_skimage.py"))
        .args([a, b])
        .args(["--repeats", &repeats.to_string(), "--json"])
        .output()
        .map_err(|e| format!("cannot run {python}: {e}"))?;
    if !out.status.success() {
        return Err(format!("{python}: {}", String::from_utf8_lossy(&out.stderr).lines().last().unwrap_or("failed")));
    }
    let v: serde_json::Value = serde_json::from_slice(out.stdout.trim_ascii()).map_err(|e| format!("bad JSON from the peer: {e}"))?;
    let field = |k: &str| v[k].as_f64().ok_or_else(|| format!("the peer's JSON has no {k}"));
    Ok((field("min_s")?, field("mean_s")?, field("ssim")?))
}

fn main() {
    if !std::env::args().any(|a| a == "--bench") {
        let (a, b) = (texture(64, 1), texture(64, 2));
        let (fast, slow) = (ssim(&a, &b).expect("ssim"), ssim_reference(&a, &b).expect("reference"));
        assert!((fast - slow).abs() < 1e-12, "{fast} vs {slow}");
        println!("ssim_vs_skimage: smoke ok (run with --bench to time)");
        return;
    }
    let rounds: usize = env_or("RIG_BENCH_ROUNDS", "5").parse().expect("RIG_BENCH_ROUNDS");
    let repeats: usize = env_or("RIG_BENCH_REPEATS", "5").parse().expect("RIG_BENCH_REPEATS");
    let python = env_or("RIG_PYTHON", ".venv/bin/python");
    let (a, b, what) = pair();
    let tmp = tempfile::tempdir().expect("tempdir");
    let (pa, pb) = (tmp.path().join("a.png"), tmp.path().join("b.png"));
    a.save(&pa).expect("a.png");
    b.save(&pb).expect("b.png");
    println!(
        "SSIM of one 512 x 512 RGB pair ({what}); {rounds} rounds of {repeats} calls per side; rig on {} rayon threads",
        rayon::current_num_threads()
    );
    let (mut rig_min, mut ref_min, mut peer_min) = (f64::INFINITY, f64::INFINITY, f64::INFINITY);
    let (mut rig_v, mut ref_v, mut peer_v) = (0.0, 0.0, None);
    let mut peer_error = None;
    for round in 0..rounds {
        let (m, mean, v) = time(repeats, || ssim(&a, &b).expect("ssim"));
        println!("round {round}: rig       fastest {:8.2} ms  mean {:8.2} ms  ssim {v:.12}", m * 1e3, mean * 1e3);
        (rig_min, rig_v) = (rig_min.min(m), v);
        let (m, mean, v) = time(repeats, || ssim_reference(&a, &b).expect("reference"));
        println!("round {round}: previous  fastest {:8.2} ms  mean {:8.2} ms  ssim {v:.12}", m * 1e3, mean * 1e3);
        (ref_min, ref_v) = (ref_min.min(m), v);
        match skimage(&python, &pa, &pb, repeats) {
            Ok((m, mean, v)) => {
                println!("round {round}: skimage   fastest {:8.2} ms  mean {:8.2} ms  ssim {v:.12}", m * 1e3, mean * 1e3);
                (peer_min, peer_v) = (peer_min.min(m), Some(v));
            }
            Err(e) => peer_error = Some(e),
        }
    }
    println!(
        "rig / previous: {:.3} ({:.2} ms against {:.2} ms); |rig - previous| = {:.1e}",
        rig_min / ref_min,
        rig_min * 1e3,
        ref_min * 1e3,
        (rig_v - ref_v).abs()
    );
    match (peer_v, peer_error) {
        (Some(pv), _) => {
            let diff = (rig_v - pv).abs();
            println!(
                "rig / scikit-image: {:.3} ({:.2} ms against {:.2} ms, {:.1}x faster); |rig - scikit-image| = {diff:.1e}",
                rig_min / peer_min,
                rig_min * 1e3,
                peer_min * 1e3,
                peer_min / rig_min
            );
            assert!(diff < 1e-6, "rig's SSIM {rig_v} and scikit-image's {pv} differ by {diff:e}");
        }
        (None, e) => println!("scikit-image left out: {}", e.unwrap_or_default()),
    }
}
