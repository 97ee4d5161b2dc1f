//! Synthesis: sampling steps and sampler against SSIM against seconds per image.
//!
//! For a few poses of a library object the control image is rendered at the model's
//! resolution as `rig synth --fill-missing` renders it (2 x 2 supersampling) and synthesised
//! with every (sampler, steps) pair from the same initial noise. Each image is compared with
//!
//! - the image of the same sampler at the most steps (50: MultiDiffSense's setting), which
//!   says how far fewer steps move the result, and
//! - the ground truth: the simulated sensor's frame of the same pose (full scene, arm still),
//!   rendered at the sensor's size and resized to the model's resolution.
//!
//! Time is the wall time of `Pipeline::generate` per image after one warm-up image, on the
//! CPU through ONNX Runtime loaded as `rig synth` loads it.

use std::time::Instant;

use image::RgbImage;
use image::imageops::FilterType;

use super::error::BenchError;
use super::knob::{BenchConfig, Knob};
use super::plot::{Plot, Series};
use super::table::{Column, KnobReport, Row, mean};
use crate::calibration::Calibration;
use crate::geometry::control::control_image;
use crate::geometry::objects::load_object;
use crate::geometry::raster::render_depth;
use crate::metrics::ssim;
use crate::pose::{Pose, WorkFrame};
use crate::sensor::SensorKind;
use crate::sim::sensor::{MotionState, Scene, SensorSim};
use crate::synth::prompt::mds_prompt;
use crate::synth::{GenerateRequest, Pipeline, RuntimeOptions};

/// Object the synthesis knob renders.
pub const OBJECT: &str = "pacman";

/// Plan poses (work frame) the synthesis knob uses.
pub fn poses(n: usize) -> Vec<Pose> {
    [Pose::new(0.5, -1.0, 0.0, 15.0), Pose::new(-2.0, 1.5, 0.5, -45.0), Pose::new(2.0, 2.0, -0.5, 60.0)]
        .into_iter()
        .cycle()
        .take(n)
        .collect()
}

/// Runs every (sampler, steps) pair on every pose; one row per pair.
pub fn measure(config: &BenchConfig) -> Result<KnobReport, BenchError> {
    let t_load = Instant::now();
    let mut pipeline = Pipeline::load(&config.synth_model, &RuntimeOptions::default())?;
    let load_s = t_load.elapsed().as_secs_f64();
    let (w, h) = pipeline.resolution();
    let package = pipeline.package();
    let model_name = package.config.name.clone();
    let kind = [SensorKind::ViTacTip, SensorKind::TacTip, SensorKind::ViTac]
        .into_iter()
        .find(|k| package.config.modalities.iter().any(|m| m == k.label()))
        .unwrap_or(SensorKind::ViTacTip);
    let mesh = load_object(OBJECT)?;
    let contact_depth_mm = WorkFrame::default().contact_depth_mm;
    let px = config.image_px;
    let sensor_calib = Calibration::default_for(px, px);
    let sensor = SensorSim::new(
        kind,
        Scene::preset("full").unwrap_or_else(|_| Scene::with_stages("full", &[])),
        px,
        px,
        sensor_calib.scale_px_per_mm[0] as f32,
        1,
    );
    let model_calib = Calibration::default_for(w, h);
    struct Case {
        control: RgbImage,
        prompt: String,
        truth: RgbImage,
    }
    let cases: Vec<Case> = poses(config.synth_poses)
        .iter()
        .enumerate()
        .map(|(k, p)| {
            let object_pose = Pose { z_mm: p.z_mm + contact_depth_mm, ..*p };
            let control = control_image(&render_depth(&mesh, &object_pose, &model_calib, w, h, 2));
            let seen = sensor.render(&render_depth(&mesh, &object_pose, &sensor_calib, px, px, 1), &MotionState::STILL, k as u64);
            let truth = image::imageops::resize(&seen, w, h, FilterType::Triangle);
            Case { control, prompt: mds_prompt(kind, p), truth }
        })
        .collect();
    let Some(&reference_steps) = config.synth_steps.iter().max() else {
        return Err(BenchError::Empty { knob: Knob::Synthesis, reason: "no step counts" });
    };
    if cases.is_empty() {
        return Err(BenchError::Empty { knob: Knob::Synthesis, reason: "no poses" });
    }
    // Warm-up: the first run of a session allocates and optimises; keep it out of the timings.
    let warm = GenerateRequest { steps: 2, guidance: config.synth_guidance, ..GenerateRequest::new(&cases[0].control, &cases[0].prompt) };
    pipeline.generate(&warm)?;

    let mut steps = config.synth_steps.clone();
    steps.sort_unstable();
    steps.dedup();
    let mut rows = Vec::new();
    let mut series = Vec::new();
    for &scheduler in &config.synth_schedulers {
        // images[steps index][case]
        let mut images: Vec<Vec<RgbImage>> = Vec::new();
        let mut seconds: Vec<Vec<f64>> = Vec::new();
        for &n in &steps {
            let (mut imgs, mut secs) = (Vec::new(), Vec::new());
            for (k, case) in cases.iter().enumerate() {
                let req = GenerateRequest {
                    steps: n,
                    guidance: config.synth_guidance,
                    scheduler,
                    seed: k as u64,
                    ..GenerateRequest::new(&case.control, &case.prompt)
                };
                let t = Instant::now();
                let out = pipeline.generate(&req)?;
                secs.push(t.elapsed().as_secs_f64());
                imgs.push(out.image);
            }
            images.push(imgs);
            seconds.push(secs);
        }
        let reference_index = steps.iter().position(|&n| n == reference_steps).unwrap_or(steps.len() - 1);
        let mut s = Series { name: scheduler.to_string(), ..Default::default() };
        for (i, &n) in steps.iter().enumerate() {
            let mut to_ref = Vec::new();
            let mut to_truth = Vec::new();
            for (k, case) in cases.iter().enumerate() {
                to_ref.push(ssim(&images[i][k], &images[reference_index][k])?);
                to_truth.push(ssim(&images[i][k], &case.truth)?);
            }
            let secs = mean(&seconds[i]);
            rows.push(Row { label: format!("{scheduler}, {n} steps"), values: vec![n as f64, mean(&to_ref), mean(&to_truth), secs] });
            s.points.push([secs, mean(&to_ref)]);
            s.labels.push(format!("{n}"));
        }
        series.push(s);
    }
    Ok(KnobReport {
        knob: Knob::Synthesis,
        title: "Synthesis: sampling steps and sampler".into(),
        label_column: "sampler, steps".into(),
        columns: vec![
            Column::new("steps", 0),
            Column::new(&format!("SSIM to {reference_steps} steps"), 4),
            Column::new("SSIM to sim. sensor", 4),
            Column::new("s per image", 3),
        ],
        rows,
        notes: vec![
            format!(
                "Model `{}` (`{}`, {w} x {h} px, loaded in {load_s:.1} s), guidance {}, {} {} pose(s) of object `{OBJECT}`, \
                 the same seed per pose for every sampler and step count. CPU execution.",
                config.synth_model.display(),
                model_name,
                config.synth_guidance,
                cases.len(),
                kind.label()
            ),
            format!(
                "*SSIM to {reference_steps} steps*: to the image of the same sampler with {reference_steps} steps. *SSIM to sim. sensor*: \
                 to the simulated {} frame of the same pose ({px} px, full scene, resized to {w} x {h}); a model trained on the \
                 simulator should approach it, the tiny random test package does not. *s per image*: mean wall time of one \
                 image after a warm-up.",
                kind.label()
            ),
        ],
        plot: Plot {
            title: format!("Synthesis: SSIM to {reference_steps} steps against time"),
            x_label: "s per image".into(),
            y_label: format!("SSIM to the {reference_steps}-step image"),
            series,
            lines: true,
        },
    })
}
