//! Sensor simulator: stages switched on against SSIM to the full scene against ms per frame.
//!
//! For each sensor kind a 33 x 4 mm bar pressed 1 mm, seen while the arm moves at 400 px/s
//! over a 16 ms exposure (so motion blur has something to do), is rendered with the stages
//! switched on one after the other in pipeline order (cumulative: `none`, `+ contact_deformation`,
//! ... up to the full scene), then with each stage left out of the full scene. Every frame
//! uses the same noise key, so the full scene compared with itself scores exactly 1. Stages
//! that do not apply to a kind are skipped; `stale_frame` is applied by the camera, not the
//! renderer, and costs nothing here.

use std::time::Instant;

use super::error::BenchError;
use super::knob::{BenchConfig, Knob};
use super::plot::{Plot, Series};
use super::table::{Column, KnobReport, Row, fastest};
use crate::calibration::DEFAULT_SCALE_PX_PER_MM_AT_512;
use crate::geometry::DepthMap;
use crate::metrics::ssim;
use crate::sensor::SensorKind;
use crate::sim::sensor::{MotionState, Scene, SensorSim, Stage, shapes};

/// Fastest of `frames` renders (after one warm-up), ms, and the last image.
fn time_render(sim: &SensorSim, depth: &DepthMap, motion: &MotionState, frames: usize) -> (f64, image::RgbImage) {
    let mut image = sim.render(depth, motion, 7);
    let mut times = Vec::new();
    for _ in 0..frames.max(1) {
        let t = Instant::now();
        image = sim.render(depth, motion, 7);
        times.push(t.elapsed().as_secs_f64() * 1e3);
    }
    (fastest(&times), image)
}

/// The renderer's stages that apply to `kind`, in pipeline order.
pub fn render_stages(kind: SensorKind) -> Vec<Stage> {
    Stage::ALL.into_iter().filter(|s| *s != Stage::StaleFrame && s.applies_to(kind)).collect()
}

/// One row per stage set per kind.
pub fn measure(config: &BenchConfig) -> Result<KnobReport, BenchError> {
    let px = config.image_px;
    let px_per_mm = (DEFAULT_SCALE_PX_PER_MM_AT_512 * px as f64 / 512.0) as f32;
    let depth = shapes::bar(px, px, px_per_mm, 0.5, 1.0, 10.0, 33.0, 4.0, 1.0);
    let motion = MotionState { speed_px_per_s: 400.0 * px as f32 / 512.0, direction_rad: 0.4, exposure_s: 0.016 };
    let mut rows = Vec::new();
    let mut series = Vec::new();
    for kind in SensorKind::ALL {
        let stages = render_stages(kind);
        let sim_of = |name: &str, on: &[Stage]| SensorSim::new(kind, Scene::with_stages(name, on), px, px, px_per_mm, 1);
        let (t_full, full) = time_render(&sim_of("full", &stages), &depth, &motion, config.sensor_frames);
        let mut cumulative = Series { name: format!("{}: stages added", kind.label()), ..Default::default() };
        for k in 0..=stages.len() {
            let on = &stages[..k];
            let (ms, img) = if k == stages.len() {
                (t_full, full.clone())
            } else {
                time_render(&sim_of("partial", on), &depth, &motion, config.sensor_frames)
            };
            let s = ssim(&img, &full)?;
            let label = match k {
                0 => "none".to_string(),
                _ if k == stages.len() => format!("full (+ {})", stages[k - 1].name()),
                _ => format!("+ {}", stages[k - 1].name()),
            };
            rows.push(Row { label: format!("{} {label}", kind.label()), values: vec![k as f64, s, ms] });
            cumulative.points.push([ms, s]);
            cumulative.labels.push(if k == 0 { "none".into() } else { stages[k - 1].name().to_string() });
        }
        series.push(cumulative);
        for stage in &stages {
            let without: Vec<Stage> = stages.iter().copied().filter(|s| s != stage).collect();
            let (ms, img) = time_render(&sim_of("without", &without), &depth, &motion, config.sensor_frames);
            let s = ssim(&img, &full)?;
            rows.push(Row { label: format!("{} full - {}", kind.label(), stage.name()), values: vec![without.len() as f64, s, ms] });
        }
    }
    Ok(KnobReport {
        knob: Knob::Sensor,
        title: "Sensor simulator: stages".into(),
        label_column: "sensor, stages".into(),
        columns: vec![Column::new("stages on", 0), Column::new("SSIM to full", 4), Column::new("ms per frame", 2)],
        rows,
        notes: vec![
            format!(
                "{px} x {px} px, {px_per_mm:.2} px/mm; a 33 x 4 mm bar pressed 1 mm, arm moving at {:.0} px/s over a 16 ms exposure; \
                 the same noise key for every frame. Rows `+ stage` add the stages one by one in pipeline order (the last row \
                 before `full` has every stage but the last); rows `full - stage` leave one stage out of the full scene.",
                motion.speed_px_per_s
            ),
            format!(
                "SSIM (11x11 Gaussian window, 8-bit, mean over RGB) to the full scene; ms per frame = fastest of {} renders \
                 after a warm-up.",
                config.sensor_frames.max(1)
            ),
        ],
        plot: Plot {
            title: "Sensor simulator: SSIM to the full scene against time (stages added in order)".into(),
            x_label: "ms per frame".into(),
            y_label: "SSIM to the full scene".into(),
            series,
            lines: true,
        },
    })
}
