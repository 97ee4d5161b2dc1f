//! `rig compare-real`: the simulator against the real MultiDiffSense example frames.
//!
//! ```text
//! rig compare-real [--sample DIR] [--calibration-dir calibration] [--fit] [--out DIR]
//! ```
//!
//! The sample is any MultiDiffSense-layout folder: for each object `<id>` (`csv/<id>.csv` with
//! `stl/<id>.stl`), each sensor (TacTip, ViTac, ViTacTip) and every real frame
//! `tactile/<id>/<Sensor>/target/<id>_<Sensor>_<i>.png` there is, it renders the object at the
//! frame's logged pose through `calibration/mds-example-<sensor>.toml` with the sensor
//! simulator and prints SSIM against the real frame over the whole frame and over the contact
//! region, next to the pose-blind baseline (the mean of the other real frames of that object
//! and sensor), then the means. An object and sensor with fewer than two frames is skipped
//! and named. The comparison is [`crate::eval::compare_real`]; the logged pose's depth
//! convention is [`crate::dataset::export`]'s. This command parses, wires the simulator in as
//! the renderer and prints.
//!
//! - The simulator starts from the median of the sensor's *other* real frames (leave one out)
//!   and renders the scene of [`comparison_scene`] (no noise); `--procedural` uses its
//!   modelled look instead, `--scene` another scene.
//! - `--fit` first refits the calibrations to the first object's frames
//!   (`calibration::contact_fit::fit_sensor`, in `FIT_ORDER`, each seeded with the ones
//!   before) and writes them.

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::Args as ClapArgs;

use super::sensor_bridge::{render_tactile_with, simulator_available};
use crate::calibration::Calibration;
use crate::calibration::contact_fit::{FIT_ORDER, FitFrame, fit_sensor};
use crate::eval::compare_real::{CompareOptions, CompareRealError, FrameScores, RealSample, compare_sensor};
use crate::sensor::SensorKind;
use crate::sim::sensor::{Scene, Stage};

#[derive(Debug, ClapArgs)]
pub struct Args {
    /// A MultiDiffSense-layout folder (`csv/<id>.csv`, `stl/<id>.stl`, `tactile/<id>/<Sensor>/target/`),
    /// any number of objects and frames; default: the MultiDiffSense example.
    #[arg(long, env = "RIG_REAL_SAMPLE")]
    pub sample: Option<PathBuf>,
    /// Folder of the `mds-example-<sensor>.toml` calibrations.
    #[arg(long, default_value = "calibration")]
    pub calibration_dir: PathBuf,
    /// Refit the calibrations to the frames and write them before comparing.
    #[arg(long)]
    pub fit: bool,
    /// Render the simulator's modelled static look (skin, pins, tube) instead of starting
    /// from the no-contact look measured on the other real frames.
    #[arg(long)]
    pub procedural: bool,
    /// Simulator scene (preset or TOML file); default: every stage but noise and stale frames
    /// (the expected image, see `comparison_scene`).
    #[arg(long)]
    pub scene: Option<String>,
    /// Write side-by-side panels (real | baseline | footprint | contact region | simulator) here.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// Default sample folder: `$RIG_SHARED/real-sample/multidiffsense-example` (RIG_SHARED
/// defaults to `../shared`).
pub fn default_sample_dir() -> PathBuf {
    let shared = std::env::var("RIG_SHARED").unwrap_or_else(|_| "../shared".to_string());
    Path::new(&shared).join("real-sample/multidiffsense-example")
}

/// The scene the comparison renders by default: every stage except `noise` and
/// `stale_frame`. SSIM against one noisy real frame is highest for the noise-free expected
/// image (independent noise only lowers it), and the baseline, a mean of frames, is nearly
/// noise-free too; a still frame has nothing stale.
pub fn comparison_scene() -> Scene {
    let stages: Vec<Stage> = Stage::ALL.into_iter().filter(|s| !matches!(s, Stage::Noise | Stage::StaleFrame)).collect();
    Scene::with_stages("compare", &stages)
}

/// Fits `calibration/mds-example-<sensor>.toml` for each sensor of the sample, in
/// [`FIT_ORDER`], each fit seeded with the ones before (same rig, same pose log).
fn fit_all(sample: &RealSample, calibration_dir: &Path) -> anyhow::Result<()> {
    std::fs::create_dir_all(calibration_dir).with_context(|| format!("creating {}", calibration_dir.display()))?;
    let mut seeds: Vec<Calibration> = Vec::new();
    for sensor in FIT_ORDER {
        let frames: Vec<FitFrame> = sample
            .posed_frames(sensor, RealSample::render_pose)?
            .into_iter()
            .map(|(name, pose, image)| FitFrame { name, pose, image })
            .collect();
        if frames.is_empty() {
            anyhow::bail!("no {} frames in the sample", sensor.label());
        }
        let fit = fit_sensor(&sample.mesh, sensor, &frames, &seeds)?;
        seeds.push(fit.calibration.clone());
        let path = calibration_dir.join(format!("mds-example-{sensor}.toml"));
        fit.calibration.save(&path)?;
        let c = &fit.calibration;
        println!(
            "fitted {}: centre ({:.1}, {:.1}) px, scale ({:.2}, {:.2}) px/mm, rotation {:.1} deg, correlation {:.3}, residual per frame [{}] px -> {}",
            sensor.label(),
            c.centre_px[0],
            c.centre_px[1],
            c.scale_px_per_mm[0],
            c.scale_px_per_mm[1],
            c.rotation_deg,
            fit.score,
            fit.residuals_px.iter().map(|r| format!("{r:.1}")).collect::<Vec<_>>().join(", "),
            path.display()
        );
    }
    Ok(())
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let dir = args.sample.clone().unwrap_or_else(default_sample_dir);
    let context = || format!("loading the real sample from {} (set --sample or RIG_SHARED)", dir.display());
    let ids = RealSample::object_ids(&dir).with_context(context)?;
    if ids.is_empty() {
        return Err(anyhow::Error::new(CompareRealError::NoObjects { dir: dir.clone() }).context(context()));
    }
    if args.fit {
        let first = RealSample::load_object(&dir, &ids[0]).with_context(context)?;
        fit_all(&first, &args.calibration_dir)?;
    }
    let scene = match &args.scene {
        Some(spec) => Scene::preset_or_file(spec)?,
        None => comparison_scene(),
    };
    let mut calibrations = Vec::new();
    for sensor in SensorKind::ALL {
        let path = args.calibration_dir.join(format!("mds-example-{sensor}.toml"));
        let calib = Calibration::load(&path).with_context(|| format!("{}: run with --fit to create {}", sensor.label(), path.display()))?;
        calibrations.push((sensor, calib));
    }
    println!("SSIM against the real frames (mean over frames; contact = pixels differing from the no-contact look)");
    println!(
        "{:<6} {:<9} {:>5} {:>8} {:>8} | {:>10} {:>10} | {:>10} {:>10}",
        "object", "sensor", "frame", "contact%", "fp-IoU", "sim whole", "base whole", "sim cont.", "base cont."
    );
    let options = CompareOptions { measured_reference: !args.procedural, panels: args.out.clone() };
    let fmt = |v: Option<f64>| v.map(|x| format!("{x:.3}")).unwrap_or_else(|| "n/a".to_string());
    let mut compared = 0usize;
    let mut skipped = Vec::new();
    for id in &ids {
        let sample = RealSample::load_object(&dir, id).with_context(context)?;
        for (sensor, calib) in &calibrations {
            let sensor = *sensor;
            let frames = sample.frames_of(sensor).len();
            if frames < 2 {
                // The baseline and the no-contact look need the sensor's other frames.
                skipped.push(format!("object {id} {}: {frames} frame(s), need two", sensor.label()));
                continue;
            }
            let render =
                |depth: &_, calib: &_, seed, reference: Option<&_>| render_tactile_with(sensor, depth, calib, seed, &scene, reference).ok();
            let scores = compare_sensor(&sample, sensor, calib, &render, &options)?;
            compared += scores.len();
            for s in &scores {
                println!(
                    "{:<6} {:<9} {:>5} {:>8.1} {:>8.3} | {:>10} {:>10.3} | {:>10} {:>10.3}",
                    id,
                    sensor.label(),
                    s.index,
                    100.0 * s.contact_fraction,
                    s.footprint_iou,
                    fmt(s.sim_whole),
                    s.baseline_whole,
                    fmt(s.sim_contact),
                    s.baseline_contact
                );
            }
            let n = scores.len() as f64;
            let mean = |f: &dyn Fn(&FrameScores) -> f64| scores.iter().map(f).sum::<f64>() / n;
            let mean_opt = |f: &dyn Fn(&FrameScores) -> Option<f64>| {
                scores.iter().map(f).collect::<Option<Vec<f64>>>().map(|v| v.iter().sum::<f64>() / n)
            };
            println!(
                "{:<6} {:<9} {:>5} {:>8.1} {:>8.3} | {:>10} {:>10.3} | {:>10} {:>10.3}",
                id,
                sensor.label(),
                "mean",
                100.0 * mean(&|s| s.contact_fraction),
                mean(&|s| s.footprint_iou),
                fmt(mean_opt(&|s| s.sim_whole)),
                mean(&|s| s.baseline_whole),
                fmt(mean_opt(&|s| s.sim_contact)),
                mean(&|s| s.baseline_contact)
            );
        }
    }
    for line in &skipped {
        println!("skipped {line}");
    }
    if compared == 0 {
        return Err(anyhow::Error::new(crate::cli::usage(&format!(
            "{}: no object has two frames of one sensor to compare (tactile/<id>/<Sensor>/target/<id>_<Sensor>_<i>.png)",
            dir.display()
        ))));
    }
    if !simulator_available() {
        println!("note: sensor simulator not available in this build; simulator columns are n/a");
    }
    Ok(())
}
