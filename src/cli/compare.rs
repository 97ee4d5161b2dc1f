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
//! - `--fit-skin` fits each sensor's skin (`sim::sensor::SkinModel`, the parameters its
//!   stages read) to the frames of `--frames` (default 1-5), prints the fit with its residuals
//!   and a leave-one-out cross-validation, and compares nothing else.
//! - `--fit` first refits the calibrations to the first object's frames
//!   (`calibration::contact_fit::fit_sensor`, in `FIT_ORDER`, each seeded with the ones
//!   before) and writes them.

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::Args as ClapArgs;

use super::sensor_bridge::{render_tactile_with, simulator_available};
use crate::calibration::Calibration;
use crate::calibration::contact_fit::{FIT_ORDER, FitFrame, fit_sensor};
use crate::eval::compare_real::{
    CompareOptions, CompareRealError, FrameScores, ParameterRange, PreparedSensor, RealSample, compare_sensor, cross_validate,
    fit_parameters,
};
use crate::sensor::SensorKind;
use crate::sim::sensor::{SKIN_PARAMETERS, Scene, SkinModel, SkinParameter, Stage};

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
    /// Fit each sensor's skin model to the frames instead (with its residuals and a
    /// leave-one-out cross-validation).
    #[arg(long)]
    pub fit_skin: bool,
    /// Sets a parameter of each compared sensor's skin, `NAME=VALUE` (repeatable; a name of
    /// `sim::sensor::SKIN_PARAMETERS`, within its range), e.g. `--skin lateral_mm=1.5`.
    /// With `--fit-skin` the value is held where the fit does not search it.
    #[arg(long = "skin", value_name = "NAME=VALUE", value_parser = parse_skin_setting)]
    pub skin: Vec<SkinSetting>,
    /// Image indices to use, `A-B` or `A` (default: every frame; `--fit-skin`: 1-5).
    #[arg(long, value_parser = parse_frames)]
    pub frames: Option<(usize, usize)>,
    /// Only these sensors (repeatable; default: all three).
    #[arg(long = "sensor")]
    pub sensors: Vec<SensorKind>,
}

/// One `--skin NAME=VALUE`: a parameter of the skin model and the value it takes.
#[derive(Debug, Clone, Copy)]
pub struct SkinSetting {
    pub parameter: SkinParameter,
    pub value: f32,
}

/// `NAME=VALUE` for a parameter of [`SKIN_PARAMETERS`], the value finite and within its range.
fn parse_skin_setting(text: &str) -> Result<SkinSetting, String> {
    let names = || SKIN_PARAMETERS.iter().map(|p| p.name).collect::<Vec<_>>().join(", ");
    let (name, value) = text.split_once('=').ok_or_else(|| format!("{text:?} is not NAME=VALUE (names: {})", names()))?;
    let parameter = SKIN_PARAMETERS
        .into_iter()
        .find(|p| p.name == name.trim())
        .ok_or_else(|| format!("{:?} is not a skin parameter (names: {})", name.trim(), names()))?;
    let value = value.trim().parse::<f32>().ok().filter(|v| v.is_finite()).ok_or_else(|| format!("{value:?} is not a number"))?;
    if !(parameter.min..=parameter.max).contains(&value) {
        return Err(format!("{} = {value} is outside its range {}..{}", parameter.name, parameter.min, parameter.max));
    }
    Ok(SkinSetting { parameter, value })
}

/// `kind`'s committed skin with `settings` applied.
fn skin_with(kind: SensorKind, settings: &[SkinSetting]) -> SkinModel {
    let mut skin = SkinModel::of(kind);
    for s in settings {
        s.parameter.set(&mut skin, s.value);
    }
    skin
}

/// `A-B` or `A` as an inclusive range of image indices.
fn parse_frames(text: &str) -> Result<(usize, usize), String> {
    let bad = || format!("{text:?} is not A-B or A (image indices, A <= B)");
    let (a, b) = text.split_once('-').unwrap_or((text, text));
    let (a, b) = (a.trim().parse::<usize>().map_err(|_| bad())?, b.trim().parse::<usize>().map_err(|_| bad())?);
    if a > b {
        return Err(bad());
    }
    Ok((a, b))
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

/// `--fit-skin`: for each sensor, fits the parameters of its skin its stages read
/// ([`SkinModel::fitted_parameters`]) to all the sample's frames, starting from the kind's
/// committed skin; prints the fitted values, each frame's contact-region SSIM and residual
/// beside the baseline's, then a leave-one-out cross-validation (fit on the other frames,
/// score the one left out).
fn fit_skins(
    sample: &RealSample,
    calibrations: &[(SensorKind, Calibration)],
    scene: &Scene,
    measured: bool,
    settings: &[SkinSetting],
) -> anyhow::Result<()> {
    let frames = |sensor| sample.frames_of(sensor).iter().map(|(i, _)| i.to_string()).collect::<Vec<_>>().join(", ");
    for (sensor, calib) in calibrations {
        let sensor = *sensor;
        if sample.frames_of(sensor).len() < 3 {
            println!("{}: {} frame(s), a fit with a cross-validation needs three; skipped", sensor.label(), sample.frames_of(sensor).len());
            continue;
        }
        let prepared = PreparedSensor::new(sample, sensor, calib, measured)?;
        let committed = skin_with(sensor, settings);
        let params = SkinModel::fitted_parameters(sensor);
        let skin_of = |values: &[f64]| {
            let mut skin = committed;
            for (p, v) in params.iter().zip(values) {
                p.set(&mut skin, *v as f32);
            }
            skin
        };
        let render = |values: &[f64], depth: &_, calib: &_, seed, reference: Option<&_>| {
            render_tactile_with(sensor, depth, calib, seed, scene, reference, Some(&skin_of(values))).ok()
        };
        let start: Vec<f64> = params.iter().map(|p| f64::from(p.start)).collect();
        let ranges: Vec<ParameterRange> = params.iter().map(|p| ParameterRange { min: f64::from(p.min), max: f64::from(p.max) }).collect();
        let all: Vec<usize> = (0..prepared.frames.len()).collect();
        let fit = fit_parameters(&prepared, &all, &start, &ranges, &render);
        println!(
            "{} skin fitted on frames {} ({} candidates; mean contact SSIM {:.3}):",
            sensor.label(),
            frames(sensor),
            fit.evaluations,
            fit.score
        );
        for (p, (was, now)) in params.iter().zip(start.iter().zip(&fit.parameters)) {
            println!("  {:<18} {:>7.3} (search started at {:.3}, committed {:.3})", p.name, now, was, p.get(&committed));
        }
        println!("  {:>5} {:>10} {:>10} {:>12} {:>12}", "frame", "sim cont.", "base cont.", "committed", "residual");
        let fitted = |d: &_, c: &_, seed, r: Option<&_>| render(&fit.parameters, d, c, seed, r);
        let kept = |d: &_, c: &_, seed, r: Option<&_>| render_tactile_with(sensor, d, c, seed, scene, r, Some(&committed)).ok();
        let fmt = |v: Option<f64>| v.map(|x| format!("{x:.3}")).unwrap_or_else(|| "n/a".to_string());
        for (k, f) in prepared.frames.iter().enumerate() {
            println!(
                "  {:>5} {:>10} {:>10.3} {:>12} {:>12}",
                f.index,
                fmt(prepared.contact_ssim(k, &fitted)),
                f.baseline_contact,
                fmt(prepared.contact_ssim(k, &kept)),
                prepared.contact_residual(k, &fitted).map(|r| format!("{r:.1} levels")).unwrap_or_else(|| "n/a".to_string())
            );
        }
        println!("  leave-one-out: fitted on the other frames, scored on the one left out");
        println!("  {:>5} {:>10} {:>10} {:>8}  fitted on the others", "frame", "sim cont.", "base cont.", "sim-base");
        let folds = cross_validate(&prepared, &start, &ranges, &render);
        for f in &folds {
            let values: Vec<String> = params.iter().zip(&f.parameters).map(|(p, v)| format!("{} {v:.3}", p.name)).collect();
            println!(
                "  {:>5} {:>10.3} {:>10.3} {:>+8.3}  {}",
                f.index,
                f.sim_contact,
                f.baseline_contact,
                f.sim_contact - f.baseline_contact,
                values.join(", ")
            );
        }
        let n = folds.len() as f64;
        let (sim, base) = (folds.iter().map(|f| f.sim_contact).sum::<f64>() / n, folds.iter().map(|f| f.baseline_contact).sum::<f64>() / n);
        println!("  {:>5} {:>10.3} {:>10.3} {:>+8.3}", "mean", sim, base, sim - base);
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
    for sensor in SensorKind::ALL.into_iter().filter(|s| args.sensors.is_empty() || args.sensors.contains(s)) {
        let path = args.calibration_dir.join(format!("mds-example-{sensor}.toml"));
        let calib = Calibration::load(&path).with_context(|| format!("{}: run with --fit to create {}", sensor.label(), path.display()))?;
        calibrations.push((sensor, calib));
    }
    let frames = args.frames.or(args.fit_skin.then_some((1, 5)));
    let load = |id: &str| -> anyhow::Result<RealSample> {
        let mut sample = RealSample::load_object(&dir, id).with_context(context)?;
        if let Some((a, b)) = frames {
            sample.retain_frames(|i| (a..=b).contains(&i));
        }
        Ok(sample)
    };
    if args.fit_skin {
        let sample = load(&ids[0])?;
        return fit_skins(&sample, &calibrations, &scene, !args.procedural, &args.skin);
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
        let sample = load(id)?;
        for (sensor, calib) in &calibrations {
            let sensor = *sensor;
            let frames = sample.frames_of(sensor).len();
            if frames < 2 {
                // The baseline and the no-contact look need the sensor's other frames.
                skipped.push(format!("object {id} {}: {frames} frame(s), need two", sensor.label()));
                continue;
            }
            let skin = skin_with(sensor, &args.skin);
            let render = |depth: &_, calib: &_, seed, reference: Option<&_>| {
                render_tactile_with(sensor, depth, calib, seed, &scene, reference, Some(&skin)).ok()
            };
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
