//! Frames per second of the simulated sensors at 640x480, full and minimal scenes, on one
//! thread and on every thread of the machine (frames rendered in parallel, as the simulated
//! cameras of a collection do). `cargo bench --bench sensor_fps` (release). Each figure is the
//! best of `SENSOR_FPS_ROUNDS` rounds (default 5) of `SENSOR_FPS_FRAMES` frames (default 200);
//! `SENSOR_FPS_ONLY=vitac:full` runs one cell.
//!
//! The object is the sensor benchmark's 33 x 4 mm bar pressed 1 mm, seen while the arm moves
//! at 400 px/s over a 16 ms exposure (so motion blur has work to do in the full scene).

use std::hint::black_box;
use std::time::Instant;

use rayon::prelude::*;
use rig::sensor::SensorKind;
use rig::sim::sensor::{MotionState, Scene, SensorSim, shapes};

fn env(name: &str, default: usize) -> usize {
    std::env::var(name).ok().and_then(|v| v.parse().ok()).unwrap_or(default).max(1)
}

fn main() {
    let bench = std::env::args().any(|a| a == "--bench");
    let (w, h) = if bench { (640, 480) } else { (64, 48) };
    let frames = if bench { env("SENSOR_FPS_FRAMES", 200) } else { 4 };
    let rounds = if bench { env("SENSOR_FPS_ROUNDS", 5) } else { 1 };
    let px_per_mm = 8.5 * w as f32 / 640.0;
    let depth = shapes::bar(w, h, px_per_mm, 0.5, 1.0, 10.0, 33.0, 4.0, 1.0);
    let motion = MotionState { speed_px_per_s: 400.0, direction_rad: 0.4, exposure_s: 0.016 };
    println!(
        "sensor_fps: {w}x{h}, {frames} frames x best of {rounds} rounds; {} threads; 33 x 4 mm bar pressed 1 mm, arm moving",
        rayon::current_num_threads()
    );
    println!("{:<10} {:<8} {:>14} {:>12} {:>16}", "sensor", "scene", "ms/frame (1)", "fps (1)", "fps (all threads)");
    let only = std::env::var("SENSOR_FPS_ONLY").ok();
    for kind in SensorKind::ALL {
        for scene in ["full", "minimal"] {
            if only.as_ref().is_some_and(|o| *o != format!("{}:{scene}", kind.label().to_lowercase())) {
                continue;
            }
            let sim = SensorSim::new(kind, Scene::preset(scene).expect("preset"), w, h, px_per_mm, 1);
            black_box(sim.render(&depth, &motion, 0));
            let (mut one, mut all) = (f64::INFINITY, f64::INFINITY);
            for _ in 0..rounds {
                let t = Instant::now();
                for k in 0..frames as u64 {
                    black_box(sim.render(&depth, &motion, k));
                }
                one = one.min(t.elapsed().as_secs_f64());
                let t = Instant::now();
                (0..frames as u64).into_par_iter().for_each(|k| {
                    black_box(sim.render(&depth, &motion, k));
                });
                all = all.min(t.elapsed().as_secs_f64());
            }
            let n = frames as f64;
            println!("{:<10} {:<8} {:>14.3} {:>12.0} {:>16.0}", kind.label(), scene, one / n * 1e3, n / one, n / all);
        }
    }
}
