//! Milliseconds per frame of the simulated sensors with each stage on and off, at 640x480
//! and 512x512. `cargo bench --bench sensor_stages` (release); add `--profile dev` for a
//! quick debug-profile run. Set `SENSOR_BENCH_MS` to change the time spent per cell
//! (default 300 ms), `SENSOR_BENCH_KIND` (`tactip`, ...) and `SENSOR_BENCH_SIZE` (`512x512`)
//! to run one kind or one size only. Figures are the fastest frame of each cell (robust to other load).
//!
//! Columns: `alone` = a scene with only that stage; `full` = every stage; `full - stage` =
//! every stage but that one; `cost` = full minus (full - stage); `timed in full` = the mean
//! wall time of the stage itself inside the full scene (from the simulator's own per-stage
//! timers, `SensorSim::with_stage_timing`, run on a second simulator since they read the
//! clock on every pixel row; they keep other load on the machine out of the other stages'
//! figures). Stale
//! frames are applied by the camera, not the renderer, so they cost nothing here.

use std::hint::black_box;
use std::time::{Duration, Instant};

use rig::sensor::SensorKind;
use rig::sim::sensor::{MotionState, Scene, SensorSim, Stage, shapes};

fn ms_per_frame(sim: &SensorSim, depth: &rig::geometry::DepthMap, motion: &MotionState, budget: Duration) -> f64 {
    // Warm up, then time frames until the budget is spent; report the fastest frame, which
    // is the least disturbed by other load on the machine.
    for k in 0..2 {
        black_box(sim.render(depth, motion, k));
    }
    let mut times = Vec::new();
    let start = Instant::now();
    let mut key = 2;
    while (start.elapsed() < budget || times.len() < 5) && times.len() < 200 {
        let t = Instant::now();
        black_box(sim.render(depth, motion, key));
        times.push(t.elapsed().as_secs_f64() * 1e3);
        key += 1;
    }
    times.sort_by(|a, b| a.total_cmp(b));
    times[0]
}

fn main() {
    // `cargo test --all-targets` runs this binary without `--bench`: render one frame of each
    // kind as a smoke test and leave the timing to `cargo bench`.
    if !std::env::args().any(|a| a == "--bench") {
        for kind in SensorKind::ALL {
            let sim = SensorSim::new(kind, Scene::preset("full").expect("preset"), 64, 48, 2.0, 1);
            let img = sim.render(&shapes::sphere(64, 48, 2.0, 0.0, 0.0, 6.0, 1.0), &MotionState::STILL, 0);
            assert_eq!(img.dimensions(), (64, 48));
        }
        println!("sensor_stages: smoke run only (timings with `cargo bench --bench sensor_stages`)");
        return;
    }
    let budget = Duration::from_millis(std::env::var("SENSOR_BENCH_MS").ok().and_then(|v| v.parse().ok()).unwrap_or(300));
    let motion = MotionState { speed_px_per_s: 400.0, direction_rad: 0.4, exposure_s: 0.016 };
    let px_per_mm = 8.5;
    println!("sensor_stages: ms/frame (fastest of the runs); object: 33 x 4 mm bar pressed 1 mm; motion 400 px/s x 16 ms");
    let only_kind: Option<SensorKind> = std::env::var("SENSOR_BENCH_KIND").ok().and_then(|k| k.parse().ok());
    let only_size = std::env::var("SENSOR_BENCH_SIZE").ok();
    for (w, h) in [(640u32, 480u32), (512, 512)] {
        if only_size.as_ref().is_some_and(|s| *s != format!("{w}x{h}")) {
            continue;
        }
        let depth = shapes::bar(w, h, px_per_mm, 0.5, 1.0, 10.0, 33.0, 4.0, 1.0);
        for kind in SensorKind::ALL.into_iter().filter(|k| only_kind.is_none_or(|o| o == *k)) {
            let full = Scene::preset("full").expect("preset");
            let sim = |scene: Scene| SensorSim::new(kind, scene, w, h, px_per_mm, 1);
            let t_full = ms_per_frame(&sim(full.clone()), &depth, &motion, budget);
            // The stage timers read the clock on every pixel row: a separate, timed simulator.
            let timed_sim = sim(full.clone()).with_stage_timing();
            ms_per_frame(&timed_sim, &depth, &motion, budget);
            let in_full = timed_sim.stage_counts();
            let t_full_still = ms_per_frame(&sim(full.clone()), &depth, &MotionState::STILL, budget);
            let t_none = ms_per_frame(&sim(Scene::preset("none").expect("preset")), &depth, &motion, budget);
            let t_fast = ms_per_frame(&sim(Scene::preset("fast").expect("preset")), &depth, &motion, budget);
            println!();
            println!("{} {w}x{h}: none {t_none:.2}  fast {t_fast:.2}  full {t_full:.2}  full, arm still {t_full_still:.2}", kind.label());
            println!("  {:<20} {:>9} {:>9} {:>13} {:>8} {:>13}", "stage", "alone", "full", "full - stage", "cost", "timed in full");
            for stage in Stage::ALL {
                if !stage.applies_to(kind) {
                    println!("  {:<20} {:>9}", stage.name(), "n/a");
                    continue;
                }
                let alone = ms_per_frame(&sim(Scene::with_stages("alone", &[stage])), &depth, &motion, budget);
                let without: Vec<Stage> = full.stages.iter().copied().filter(|s| *s != stage).collect();
                let t_without = ms_per_frame(&sim(Scene::with_stages("without", &without)), &depth, &motion, budget);
                println!(
                    "  {:<20} {:>9.2} {:>9.2} {:>13.2} {:>8.2} {:>13.2}",
                    stage.name(),
                    alone,
                    t_full,
                    t_without,
                    t_full - t_without,
                    in_full.mean_ms(stage)
                );
            }
        }
    }
}
