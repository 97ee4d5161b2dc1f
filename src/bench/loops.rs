//! Inner loops against the implementation each replaced and against a peer, measured side by
//! side in this run: SSIM ([`metrics::ssim`](crate::metrics::ssim)) against
//! [`metrics::ssim_reference`](crate::metrics::ssim_reference) (the whole-plane code it
//! replaced) and against scikit-image's `structural_similarity` with the same definition, run
//! by [`BenchConfig::peer_python`] when that Python has scikit-image; and control maps
//! ([`render_depth_into`](crate::geometry::raster::render_depth_into) on a prepared mesh, in
//! parallel) against the renderer they replaced
//! ([`render_depth_reference`](crate::geometry::raster::render_depth_reference), one map after
//! the other); and synthesis (rig's [`Pipeline`](crate::synth::Pipeline)) against
//! `tools/ort_pipeline.py`, the same loop in Python onnxruntime, run by the same Python when it
//! has onnxruntime.
//!
//! The pair is two seeded textures of `image_px` x `image_px` px (SSIM's cost does not depend
//! on the content). Each side is timed `loop_repeats` times per round, the rounds interleaved;
//! the fastest call is reported, the figure least disturbed by other load. Accuracy: the
//! absolute difference of each side's value from rig's.

use std::path::Path;
use std::process::Command;
use std::time::Instant;

use image::RgbImage;

use super::error::BenchError;
use super::knob::{BenchConfig, Knob};
use super::plot::{Plot, Series};
use super::table::{Column, KnobReport, Row};
use crate::metrics::{ssim, ssim_reference};
use crate::synth::npy::NpyArray;

/// The peer's script (`tools/ssim_skimage.py`), run with `python -c`, so the bench needs no
/// checkout beside the binary.
const SKIMAGE_SCRIPT: &str = include_str!("../../tools/ssim_skimage.py");

/// The synthesis peer's script (`tools/ort_pipeline.py`: the same loop as rig's pipeline in
/// Python onnxruntime), run with `python -c`.
const ORT_SCRIPT: &str = include_str!("../../tools/ort_pipeline.py");

/// DDIM steps and guidance of the synthesis loop: `rig synth --fill-missing`'s defaults.
const SYNTH_STEPS: usize = 20;
const SYNTH_GUIDANCE: f32 = 1.0;

/// Rounds of the interleaved timing.
const ROUNDS: usize = 3;

/// A seeded `side` x `side` RGB texture: an 8 px checkerboard with noise on it.
pub fn texture(side: u32, seed: u32) -> RgbImage {
    let mut s = seed.wrapping_mul(2_654_435_761).max(1);
    RgbImage::from_fn(side, side, |x, y| {
        s ^= s << 13;
        s ^= s >> 17;
        s ^= s << 5;
        let base = ((x / 8 + y / 8) % 2 * 120) as u8;
        image::Rgb([base.wrapping_add((s & 63) as u8), base.wrapping_add(((s >> 8) & 63) as u8), ((s >> 16) & 255) as u8])
    })
}

/// Fastest seconds of `repeats` calls, and the value.
fn fastest_of(repeats: usize, mut f: impl FnMut() -> Result<f64, BenchError>) -> Result<(f64, f64), BenchError> {
    let mut best = f64::INFINITY;
    let mut value = f64::NAN;
    for _ in 0..repeats.max(1) {
        let t = Instant::now();
        value = std::hint::black_box(f()?);
        best = best.min(t.elapsed().as_secs_f64());
    }
    Ok((best, value))
}

/// Runs a peer script and reads the JSON object on the last line of its output; a peer that
/// cannot run, fails or prints no JSON is a reason, not an error.
fn run_peer(python: &Path, cmd: &mut Command) -> Result<serde_json::Value, String> {
    let out = cmd.output().map_err(|e| format!("cannot run {}: {e}", python.display()))?;
    if !out.status.success() {
        let last = String::from_utf8_lossy(&out.stderr).lines().last().unwrap_or("failed").to_string();
        return Err(format!("{}: {last}", python.display()));
    }
    let stdout = String::from_utf8_lossy(&out.stdout);
    serde_json::from_str(stdout.lines().last().unwrap_or("")).map_err(|e| format!("the peer printed no JSON: {e}"))
}

/// scikit-image's fastest seconds and value on the pair saved as `a` and `b`, or why not.
fn skimage(python: &Path, a: &Path, b: &Path, repeats: usize) -> Result<(f64, f64), String> {
    let mut cmd = Command::new(python);
    cmd.args(["-c", SKIMAGE_SCRIPT]).args([a, b]).args(["--repeats", &repeats.max(1).to_string(), "--json"]);
    let v = run_peer(python, &mut cmd)?;
    match (v["min_s"].as_f64(), v["ssim"].as_f64()) {
        (Some(s), Some(value)) => Ok((s, value)),
        _ => Err("the peer's JSON lacks min_s or ssim".into()),
    }
}

/// Poses of the control-map loop.
const CONTROL_POSES: usize = 48;

/// Seconds per control map of rig and of the code it replaced, and the largest channel
/// difference between their maps.
struct ControlMaps {
    rig_s: f64,
    previous_s: f64,
    max_difference: u8,
}

/// Times [`CONTROL_POSES`] control maps of the library sphere, `side` px, both ways.
fn control_maps(side: u32, repeats: usize) -> Result<ControlMaps, BenchError> {
    use crate::geometry::control::control_image;
    use crate::geometry::raster::{PreparedMesh, RasterScratch, render_depth_into, render_depth_reference};
    use crate::geometry::{DepthMap, shapes::object_mesh};
    use crate::pose::Pose;
    use rayon::prelude::*;
    let mesh = object_mesh("sphere").ok_or(BenchError::Empty { knob: Knob::Loops, reason: "the library has no sphere" })?;
    let prepared = PreparedMesh::for_many_renders(&mesh);
    let calib = crate::calibration::Calibration::default_for(side, side);
    let poses: Vec<Pose> = (0..CONTROL_POSES)
        .map(|k| {
            let t = k as f64 / CONTROL_POSES as f64;
            Pose::new(-5.0 + 10.0 * t, 4.0 - 8.0 * (t * 7.0).fract(), 1.5 + (t * 3.0).fract() * 2.0, -90.0 + 180.0 * (t * 5.0).fract())
        })
        .collect();
    let rig = || -> Vec<RgbImage> {
        poses
            .par_iter()
            .map_init(
                || (RasterScratch::default(), DepthMap::empty(0, 0)),
                |(scratch, depth), pose| {
                    render_depth_into(&prepared, pose, &calib, side, side, 2, scratch, depth);
                    control_image(depth)
                },
            )
            .collect()
    };
    let previous =
        || -> Vec<RgbImage> { poses.iter().map(|p| control_image(&render_depth_reference(&mesh, p, &calib, side, side, 2))).collect() };
    let (mut rig_s, mut previous_s) = (f64::INFINITY, f64::INFINITY);
    let (mut ours, mut theirs) = (Vec::new(), Vec::new());
    for _ in 0..ROUNDS * repeats.max(1) {
        let t = Instant::now();
        ours = std::hint::black_box(rig());
        rig_s = rig_s.min(t.elapsed().as_secs_f64());
        let t = Instant::now();
        theirs = std::hint::black_box(previous());
        previous_s = previous_s.min(t.elapsed().as_secs_f64());
    }
    let max_difference =
        ours.iter().zip(&theirs).flat_map(|(a, b)| a.as_raw().iter().zip(b.as_raw())).map(|(x, y)| x.abs_diff(*y)).max().unwrap_or(0);
    let n = CONTROL_POSES as f64;
    Ok(ControlMaps { rig_s: rig_s / n, previous_s: previous_s / n, max_difference })
}

/// Python onnxruntime's fastest seconds per image on the same package, control image, prompt
/// and initial latents, and its raw decoder output; or why not.
fn ort_python(python: &Path, model: &Path, work_dir: &Path, prompt: &str, images: usize) -> Result<(f64, Vec<f32>), String> {
    let raw = work_dir.join("raw.npy");
    let mut cmd = Command::new(python);
    cmd.args(["-c", ORT_SCRIPT])
        .arg("--model")
        .arg(model)
        .arg("--control")
        .arg(work_dir.join("control.png"))
        .arg("--init-latents")
        .arg(work_dir.join("latents.npy"))
        .arg("--dump-raw")
        .arg(&raw)
        .args(["--prompt", prompt, "--steps", &SYNTH_STEPS.to_string(), "--guidance", &SYNTH_GUIDANCE.to_string()])
        .args(["--images", &images.max(1).to_string(), "--json"]);
    let v = run_peer(python, &mut cmd)?;
    let seconds = v["min_s"].as_f64().ok_or("the peer's JSON lacks min_s")?;
    let raw = NpyArray::read(&raw).map_err(|e| format!("the peer's raw output: {e}"))?;
    Ok((seconds, raw.data))
}

/// Seconds per image of rig's pipeline (fastest of `images` after a warm-up) and of Python
/// onnxruntime's with the largest difference of their raw decoder outputs from the same
/// initial latents (the reason when not measured), DDIM [`SYNTH_STEPS`] steps.
#[allow(clippy::type_complexity)]
fn synthesis(config: &BenchConfig, work_dir: &Path, images: usize) -> Result<(f64, Result<(f64, f64), String>), BenchError> {
    use crate::synth::{GenerateRequest, Pipeline, RuntimeOptions, SchedulerKind};
    let mut pipeline = Pipeline::load(&config.synth_model, &RuntimeOptions::default())?;
    let (w, h) = pipeline.resolution();
    let mesh = crate::geometry::shapes::object_mesh("sphere")
        .ok_or(BenchError::Empty { knob: Knob::Loops, reason: "the library has no sphere" })?;
    let pose = crate::pose::Pose::new(1.0, -0.5, 1.5, 30.0);
    let depth = crate::geometry::raster::render_depth(&mesh, &pose, &crate::calibration::Calibration::default_for(w, h), w, h, 2);
    let control = crate::geometry::control::control_image(&depth);
    let prompt = crate::synth::prompt::mds_prompt(crate::sensor::SensorKind::ViTac, &pose);
    // Seeded initial latents, handed to both sides.
    let shape = pipeline.latent_shape();
    let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(7);
    let latents = crate::synth::pipeline::gaussian(&mut rng, shape.iter().product());
    let request = GenerateRequest {
        steps: SYNTH_STEPS,
        guidance: SYNTH_GUIDANCE,
        scheduler: SchedulerKind::Ddim,
        init_latents: Some(&latents),
        ..GenerateRequest::new(&control, &prompt)
    };
    let ours = pipeline.generate(&request)?.raw.data;
    let (rig_s, _) = fastest_of(images, || {
        pipeline.generate(&request)?;
        Ok(0.0)
    })?;
    let peer = match &config.peer_python {
        None => Err("no Python given (`--python` or `$RIG_PYTHON`)".to_string()),
        Some(python) => {
            std::fs::create_dir_all(work_dir).map_err(|e| BenchError::io(work_dir, e))?;
            let path = work_dir.join("control.png");
            control.save(&path).map_err(|e| BenchError::io(&path, std::io::Error::other(e)))?;
            let npy = NpyArray::new(shape.to_vec(), latents.clone()).map_err(|e| BenchError::io(&path, std::io::Error::other(e)))?;
            let latents_path = work_dir.join("latents.npy");
            npy.write(&latents_path).map_err(|e| BenchError::io(&latents_path, std::io::Error::other(e)))?;
            ort_python(python, &config.synth_model, work_dir, &prompt, images).and_then(|(s, theirs)| {
                if theirs.len() != ours.len() {
                    return Err(format!("the peer's image has {} values, rig's {}", theirs.len(), ours.len()));
                }
                let diff = ours.iter().zip(&theirs).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
                Ok((s, diff as f64))
            })
        }
    };
    Ok((rig_s, peer))
}

/// Measures the loops (see the module docs).
pub fn measure(config: &BenchConfig, work_dir: &Path) -> Result<KnobReport, BenchError> {
    let side = config.image_px.max(16);
    let (a, b) = (texture(side, 1), texture(side, 2));
    let peer_files = match &config.peer_python {
        Some(_) => {
            std::fs::create_dir_all(work_dir).map_err(|e| BenchError::io(work_dir, e))?;
            let (pa, pb) = (work_dir.join("a.png"), work_dir.join("b.png"));
            for (img, path) in [(&a, &pa), (&b, &pb)] {
                img.save(path).map_err(|e| BenchError::io(path, std::io::Error::other(e)))?;
            }
            Some((pa, pb))
        }
        None => None,
    };
    let repeats = config.loop_repeats;
    let (mut rig_s, mut prev_s, mut peer_s) = (f64::INFINITY, f64::INFINITY, f64::INFINITY);
    let (mut rig_v, mut prev_v, mut peer_v) = (f64::NAN, f64::NAN, None);
    let mut peer_note = match &config.peer_python {
        None => Some("no Python given (`--python` or `$RIG_PYTHON`)".to_string()),
        Some(_) => None,
    };
    for _ in 0..ROUNDS {
        let (s, v) = fastest_of(repeats, || Ok(ssim(&a, &b)?))?;
        (rig_s, rig_v) = (rig_s.min(s), v);
        let (s, v) = fastest_of(repeats, || Ok(ssim_reference(&a, &b)?))?;
        (prev_s, prev_v) = (prev_s.min(s), v);
        if let (Some(python), Some((pa, pb)), None) = (&config.peer_python, &peer_files, &peer_note) {
            match skimage(python, pa, pb, repeats) {
                Ok((s, v)) => (peer_s, peer_v) = (peer_s.min(s), Some(v)),
                Err(e) => peer_note = Some(e),
            }
        }
    }
    let ms = |s: f64| s * 1e3;
    let mut rows = vec![
        Row { label: "SSIM: rig".into(), values: vec![ms(rig_s), 1.0, 0.0] },
        Row { label: "SSIM: previous implementation".into(), values: vec![ms(prev_s), rig_s / prev_s, (prev_v - rig_v).abs()] },
    ];
    let mut series = vec![
        Series { name: "rig".into(), points: vec![[0.0, ms(rig_s)]], labels: vec![format!("{:.2} ms", ms(rig_s))] },
        Series { name: "previous implementation".into(), points: vec![[1.0, ms(prev_s)]], labels: vec![format!("{:.3}x", rig_s / prev_s)] },
    ];
    if let (Some(v), None) = (peer_v, &peer_note) {
        rows.push(Row { label: "SSIM: scikit-image".into(), values: vec![ms(peer_s), rig_s / peer_s, (v - rig_v).abs()] });
        series.push(Series {
            name: "scikit-image".into(),
            points: vec![[2.0, ms(peer_s)]],
            labels: vec![format!("{:.3}x", rig_s / peer_s)],
        });
    }
    // Control maps: the library sphere at poses across the workspace, 2 x 2 supersampling.
    let maps = control_maps(side, repeats)?;
    rows.push(Row { label: "control map: rig".into(), values: vec![ms(maps.rig_s), 1.0, 0.0] });
    rows.push(Row {
        label: "control map: previous implementation".into(),
        values: vec![ms(maps.previous_s), maps.rig_s / maps.previous_s, maps.max_difference as f64],
    });
    // Synthesis: rig's pipeline against the same loop in Python onnxruntime.
    let images = if repeats >= 10 { 3 } else { 2 };
    let (synth_rig_s, synth_peer) = synthesis(config, work_dir, images)?;
    rows.push(Row { label: "synthesis, per image: rig".into(), values: vec![ms(synth_rig_s), 1.0, 0.0] });
    if let Ok((peer_s, diff)) = &synth_peer {
        rows.push(Row { label: "synthesis, per image: Python onnxruntime".into(), values: vec![ms(*peer_s), synth_rig_s / peer_s, *diff] });
    }
    let mut notes = vec![format!(
        "SSIM of one {side} x {side} RGB pair (seeded textures), {ROUNDS} interleaved rounds of {repeats} calls per side, \
         the fastest call reported; rig on {} threads. `rig / this` is rig's time over this side's (below 1: rig is faster); \
         `Δ vs rig` is the absolute difference of this side's SSIM from rig's. scikit-image: `structural_similarity(..., \
         gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=255, channel_axis=2)`.",
        rayon::current_num_threads()
    )];
    if let Some(why) = peer_note {
        notes.push(format!("scikit-image not measured: {why}."));
    }
    notes.push(format!(
        "Synthesis: one image of `{}` (DDIM {SYNTH_STEPS} steps, guidance {SYNTH_GUIDANCE}, the defaults of \
         `rig synth --fill-missing`, a control map of the sphere at the package's resolution) by rig's pipeline and by \
         `tools/ort_pipeline.py`, the same loop in Python onnxruntime (same tokenisation, session calls and scheduler), \
         fastest of {images} images after a warm-up on each side, default threads, both from the same seeded initial \
         latents; `Δ vs rig` is the largest difference of the decoder's raw output (before the 8-bit conversion).",
        config.synth_model.display()
    ));
    if let Err(why) = &synth_peer {
        notes.push(format!("Python onnxruntime not measured: {why}."));
    }
    notes.push(format!(
        "Control map: the ControlNet hint of the library sphere at {CONTROL_POSES} poses, {side} x {side} px with 2 x 2 \
         supersampling, per map: rig renders them in parallel with a prepared mesh and buffers reused per thread (as \
         `rig render --controls-of` and `rig synth --fill-missing` do, without writing the PNG); the previous implementation \
         rendered each with a fresh full-size sample buffer, one after the other. Fastest of {} rounds. `Δ vs rig` is the \
         largest difference of a channel value between the two sides' maps.",
        ROUNDS * repeats.max(1)
    ));
    Ok(KnobReport {
        knob: Knob::Loops,
        title: "Inner loops: against the code they replaced and their peers".into(),
        label_column: "loop: implementation".into(),
        columns: vec![Column::new("fastest [ms]", 3), Column::new("rig / this", 3), Column::new("Δ vs rig (abs)", 12)],
        rows,
        notes,
        plot: Plot {
            title: "SSIM time".into(),
            x_label: "implementation (0 rig, 1 previous, 2 scikit-image)".into(),
            y_label: "ms per call".into(),
            series,
            lines: false,
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config(peer_python: Option<std::path::PathBuf>) -> BenchConfig {
        let tiny = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/tiny-package");
        BenchConfig { image_px: 40, loop_repeats: 1, peer_python, ..BenchConfig::quick(tiny) }
    }

    #[test]
    #[cfg_attr(not(feature = "synth"), ignore = "the loops knob runs the synthesis loop: needs the synth feature")]
    fn without_a_python_the_peer_is_left_out_and_said_so() {
        let tmp = tempfile::tempdir().unwrap();
        let r = measure(&config(None), tmp.path()).unwrap();
        assert_eq!(r.rows.len(), 5);
        assert!(r.rows[1].values[2] < 1e-12, "the previous code agrees: {:?}", r.rows[1]);
        assert!(r.rows[4].values[0] > 0.0, "rig's synthesis time: {:?}", r.rows[4]);
        assert!(r.notes.iter().any(|n| n.contains("Python onnxruntime not measured")), "{:?}", r.notes);
        assert_eq!(r.rows[2].label, "control map: rig");
        assert_eq!(r.rows[3].values[2], 0.0, "the previous renderer's maps are the same: {:?}", r.rows[3]);
        assert!(r.rows[3].values[0] > 0.0 && r.rows[3].values[1] > 0.0, "{:?}", r.rows[3]);
        assert!(r.notes.iter().any(|n| n.contains("scikit-image not measured")), "{:?}", r.notes);
    }

    #[test]
    #[cfg_attr(not(feature = "synth"), ignore = "the loops knob runs the synthesis loop: needs the synth feature")]
    fn the_peers_time_and_value_become_its_row() {
        use std::os::unix::fs::PermissionsExt;
        let tmp = tempfile::tempdir().unwrap();
        // A stand-in for Python: whatever it is asked, it answers 0.5 s and SSIM 0.25.
        let fake = tmp.path().join("python");
        std::fs::write(&fake, "#!/bin/sh\necho '{\"ssim\": 0.25, \"mean_s\": 0.6, \"min_s\": 0.5}'\n").unwrap();
        std::fs::set_permissions(&fake, std::fs::Permissions::from_mode(0o755)).unwrap();
        let r = measure(&config(Some(fake)), &tmp.path().join("work")).unwrap();
        // The stand-in writes no raw output for the synthesis peer: a note, not a row.
        assert_eq!(r.rows.len(), 6, "{:?}", r.notes);
        assert!(r.notes.iter().any(|n| n.contains("Python onnxruntime not measured") && n.contains("raw output")), "{:?}", r.notes);
        let (rig, peer) = (&r.rows[0], &r.rows[2]);
        assert_eq!(peer.values[0], 500.0);
        assert!((peer.values[1] - rig.values[0] / 500.0).abs() < 1e-12);
        let rig_value = ssim(&texture(40, 1), &texture(40, 2)).unwrap();
        assert!((peer.values[2] - (0.25 - rig_value).abs()).abs() < 1e-12);
        // A peer that fails is a note, not an error.
        let broken = tmp.path().join("broken");
        std::fs::write(&broken, "#!/bin/sh\necho 'no module named skimage' >&2\nexit 1\n").unwrap();
        std::fs::set_permissions(&broken, std::fs::Permissions::from_mode(0o755)).unwrap();
        let r = measure(&config(Some(broken)), &tmp.path().join("work2")).unwrap();
        assert_eq!(r.rows.len(), 5);
        assert!(r.notes.iter().any(|n| n.contains("no module named skimage")), "{:?}", r.notes);
    }
}
