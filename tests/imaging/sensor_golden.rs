//! Golden frames of the simulated sensors: a SHA-256 of the bytes of every frame of a broad
//! sweep (each kind; every preset scene, every stage alone and the full scene without each
//! stage; several sizes; contacts in the middle, at the image's edges, with NaN heights, of
//! another size; still and moving; drawn and measured looks) against
//! `tests/golden/sensor-frames.txt`, drawn by the AVX2 row code where the CPU has it and by the
//! portable row code. Any change to what a simulated sensor shows changes a
//! line; `RIG_BLESS=1` rewrites the file after a deliberate change.

use std::fmt::Write as _;
use std::path::PathBuf;

use image::RgbImage;
use rig::geometry::DepthMap;
use rig::sensor::SensorKind;
use rig::sim::sensor::{MotionState, Scene, SensorSim, Stage, shapes};
use sha2::{Digest, Sha256};

/// The contacts, by name, at `w` x `h` and `k` px/mm.
fn contacts(w: u32, h: u32, k: f32) -> Vec<(&'static str, DepthMap)> {
    let mut nan = shapes::sphere(w, h, k, 0.5, 0.0, 6.0, 1.0);
    for (i, v) in nan.height_mm.iter_mut().enumerate() {
        if i % 97 == 0 {
            *v = f32::NAN;
        }
    }
    vec![
        ("empty", DepthMap::empty(w, h)),
        ("bar", shapes::bar(w, h, k, 0.5, 1.0, 10.0, 33.0, 4.0, 1.0)),
        ("sphere", shapes::sphere(w, h, k, -1.0, 0.7, 6.0, 1.2)),
        ("edge-near", shapes::straight_edge(w, h, k, 2.0, 35.0, -0.3)),
        ("bar-top", shapes::bar(w, h, k, 0.0, -(h as f32) / k / 2.0 + 0.8, 0.0, 40.0, 3.0, 0.8)),
        ("bar-bottom", shapes::bar(w, h, k, 1.0, h as f32 / k / 2.0 - 0.8, 5.0, 40.0, 3.0, 0.8)),
        ("bar-left", shapes::bar(w, h, k, -(w as f32) / k / 2.0 + 1.0, 0.0, 90.0, 30.0, 3.0, 0.9)),
        ("nan", nan),
        ("other-size", shapes::sphere(w / 2 + 3, h / 3 + 1, k / 2.0, 0.3, 0.2, 6.0, 1.0)),
    ]
}

/// Scenes: the presets, each stage alone and the full scene without each stage.
fn scenes() -> Vec<Scene> {
    let mut out: Vec<Scene> = Scene::PRESETS.iter().map(|p| Scene::preset(p).expect("preset")).collect();
    for stage in Stage::ALL {
        out.push(Scene::with_stages(&format!("only-{stage}"), &[stage]));
        let without: Vec<Stage> = Stage::ALL.into_iter().filter(|s| *s != stage).collect();
        out.push(Scene::with_stages(&format!("no-{stage}"), &without));
    }
    out
}

/// A measured-looking no-contact frame: smooth shading with dark dots, as a real sensor's.
fn reference_frame(w: u32, h: u32) -> RgbImage {
    RgbImage::from_fn(w, h, |x, y| {
        let dot = (x % 11 < 3) && (y % 13 < 3);
        let base = 40 + (x * 150 / w.max(1)) as u8 + (y * 50 / h.max(1)) as u8;
        if dot { image::Rgb([20, 18, 25]) } else { image::Rgb([base, base.saturating_sub(10), base / 2 + 30]) }
    })
}

fn digest(img: &RgbImage) -> String {
    hex::encode(Sha256::digest(img.as_raw()))[..24].to_string()
}

fn sweep() -> String {
    let mut out = String::new();
    let moving = MotionState { speed_px_per_s: 500.0, direction_rad: 0.6, exposure_s: 0.016 };
    let streak = MotionState { speed_px_per_s: 4000.0, direction_rad: -2.2, exposure_s: 0.02 };
    for kind in SensorKind::ALL {
        for scene in scenes() {
            // Every scene at a small odd size, with every contact.
            for (w, h) in [(97u32, 61u32)] {
                let k = 8.5 * w as f32 / 640.0 * 3.0;
                let sim = SensorSim::new(kind, scene.clone(), w, h, k, 5);
                let measured = SensorSim::new(kind, scene.clone(), w, h, k, 5).with_reference(&reference_frame(w, h)).expect("size");
                for (name, depth) in contacts(w, h, k) {
                    for (look, s) in [("drawn", &sim), ("measured", &measured)] {
                        for (m, motion) in [("still", MotionState::STILL), ("moving", moving)] {
                            let img = s.render(&depth, &motion, 3);
                            writeln!(out, "{} {} {w}x{h} {name} {look} {m} {}", kind, scene.name, digest(&img)).ok();
                        }
                    }
                }
            }
        }
        // The presets at full sizes.
        for preset in Scene::PRESETS {
            for (w, h) in [(640u32, 480u32), (256, 256)] {
                let k = 8.5 * w.min(h) as f32 / 480.0;
                let sim = SensorSim::new(kind, Scene::preset(preset).expect("preset"), w, h, k, 1);
                let measured = SensorSim::new(kind, Scene::preset(preset).expect("preset"), w, h, k, 1)
                    .with_reference(&reference_frame(w, h))
                    .expect("size");
                for (name, depth) in contacts(w, h, k).into_iter().filter(|(n, _)| ["bar", "bar-bottom", "nan", "empty"].contains(n)) {
                    for (look, s) in [("drawn", &sim), ("measured", &measured)] {
                        for (m, motion) in [("still", MotionState::STILL), ("streak", streak)] {
                            let img = s.render(&depth, &motion, 11);
                            writeln!(out, "{} {preset} {w}x{h} {name} {look} {m} {}", kind, digest(&img)).ok();
                        }
                    }
                }
            }
        }
    }
    out
}

#[test]
fn simulated_frames_match_the_golden_digests() {
    check_against_golden(sweep(), true);
}

/// The portable row code gives the same frames as the AVX2 copy the CPU may run.
#[test]
fn the_portable_row_code_matches_the_golden_digests() {
    rig::sim::sensor::use_portable_rows(true);
    check_against_golden(sweep(), false);
}

/// Compares `got` with the golden file, after writing it there first when `bless` and
/// `RIG_BLESS` is set.
fn check_against_golden(got: String, bless: bool) {
    let golden: PathBuf = [env!("CARGO_MANIFEST_DIR"), "tests", "golden", "sensor-frames.txt"].iter().collect();
    if bless && std::env::var_os("RIG_BLESS").is_some() {
        std::fs::write(&golden, &got).expect("writing golden file");
    }
    let expected = std::fs::read_to_string(&golden).unwrap_or_else(|e| panic!("golden {}: {e} (RIG_BLESS=1 writes it)", golden.display()));
    let differing: Vec<String> = got
        .lines()
        .zip(expected.lines())
        .filter(|(a, b)| a != b)
        .map(|(a, b)| format!("  got      {a}\n  expected {b}"))
        .take(10)
        .collect();
    assert!(
        differing.is_empty() && got.lines().count() == expected.lines().count(),
        "{} of {} frames differ from {} (first ones below):\n{}",
        got.lines().zip(expected.lines()).filter(|(a, b)| a != b).count(),
        expected.lines().count(),
        golden.display(),
        differing.join("\n")
    );
}
