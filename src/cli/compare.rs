//! `rig compare-real`: the simulator against the real MultiDiffSense example frames.
//!
//! ```text
//! rig compare-real [--sample DIR] [--calibration-dir calibration] [--fit] [--out DIR]
//! ```
//!
//! For each sensor (TacTip, ViTac, ViTacTip) and each real frame 0-5 of the sample it renders
//! the straight edge (`stl/1.stl`) at the logged pose through `calibration/mds-example-<sensor>.toml`
//! and prints SSIM against the real frame over the whole frame and over the contact region,
//! next to the pose-blind baseline (the mean of the other real frames of that sensor).
//!
//! - Logged pose to render pose: x, y, yaw as logged; indentation = 1.5 mm (the contact depth
//!   of the collection, `WorkFrame::contact_depth_mm`) - the logged z. The sign is read off the
//!   frames: the two frames with the lowest z (2 and 3, z = -0.77 and -0.93 mm) show the
//!   largest contact regions on all three sensors and the largest TacTip pin shifts (3-5 px,
//!   against 0-1 px for frames 4 and 5), and rendering with `+ z` lowers the TacTip
//!   contact-region SSIM from 0.420 to 0.381 with everything else equal.
//! - The simulator starts from the median of the sensor's *other* real frames
//!   ([`simulator_reference`], leave one out) and renders the scene of [`comparison_scene`]
//!   (no noise); `--procedural` uses its modelled look instead, `--scene` another scene.
//! - No-contact look: per pixel, the median of the sensor's real frames whose rendered
//!   footprint (dilated by [`FOOTPRINT_MARGIN_PX`]) does not cover that pixel (all frames where
//!   every frame covers it). There is no real no-contact frame in the sample.
//! - Contact region of a frame: pixels whose summed absolute RGB difference from the
//!   no-contact look exceeds [`CONTACT_THRESHOLD`]. Footprint IoU: overlap of that region with
//!   the rendered footprint, a check of the calibration independent of the simulator.
//! - `--fit` first refits the calibrations (see `calibration::contact_fit`) and writes them.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use clap::Args as ClapArgs;
use image::{Rgb, RgbImage, imageops};

use super::sensor_bridge::{render_tactile_with, simulator_available};
use crate::calibration::Calibration;
use crate::calibration::contact_fit::{ContactFitOptions, FitFrame, FitTarget, fit_contact};
use crate::geometry::raster::render_depth;
use crate::geometry::stl::Mesh;
use crate::imaging::{difference_mask, dilate_mask, iou, mean_image, median_image, median_image_excluding};
use crate::metrics::{ssim, ssim_masked};
use crate::pose::Pose;
use crate::sensor::SensorKind;
use crate::sim::sensor::{Scene, Stage};

/// Indentation at logged z = 0, mm (MultiDiffSense collects at about 1.5 mm); the indentation
/// of a frame is this minus its logged z.
pub const CONTACT_DEPTH_MM: f64 = 1.5;
/// Margin around a rendered footprint that counts as "touched" for the no-contact estimate, px.
pub const FOOTPRINT_MARGIN_PX: u32 = 16;
/// Summed |RGB| difference from the no-contact look that makes a pixel part of the contact region.
pub const CONTACT_THRESHOLD: u32 = 60;
/// Frames compared (the sample holds 0-5; 6-10 are held back upstream).
pub const FRAMES: std::ops::RangeInclusive<usize> = 0..=5;

/// Fit order: the sharpest outlines first, so their result seeds the others.
pub const FIT_ORDER: [SensorKind; 3] = [SensorKind::ViTacTip, SensorKind::ViTac, SensorKind::TacTip];

#[derive(Debug, ClapArgs)]
pub struct Args {
    /// The MultiDiffSense example folder (holds csv/, stl/, tactile/).
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

/// The real sample: the object, the logged poses (render convention) and the frames.
pub struct RealSample {
    pub mesh: Mesh,
    /// Render pose per image index.
    pub poses: BTreeMap<usize, Pose>,
    /// Frames per sensor, (image index, image), in index order.
    pub frames: BTreeMap<&'static str, Vec<(usize, RgbImage)>>,
}

/// Default sample folder: `$RIG_SHARED/real-sample/multidiffsense-example` (RIG_SHARED
/// defaults to `../shared`).
pub fn default_sample_dir() -> PathBuf {
    let shared = std::env::var("RIG_SHARED").unwrap_or_else(|_| "../shared".to_string());
    Path::new(&shared).join("real-sample/multidiffsense-example")
}

/// Reads the Lepora/MultiDiffSense pose CSV: image index -> render pose. Rows with an empty
/// pose (the unfilled template rows) are skipped.
pub fn read_lepora_poses(path: &Path) -> anyhow::Result<BTreeMap<usize, Pose>> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    let mut poses = BTreeMap::new();
    for row in crate::dataset::export::parse_mds(&bytes, path)? {
        // image_name is frame_<i>_0.png.
        let index = row
            .image_name
            .strip_prefix("frame_")
            .and_then(|s| s.split('_').next())
            .and_then(|s| s.parse::<usize>().ok())
            .with_context(|| format!("{}: image_name {:?} is not frame_<i>_0.png", path.display(), row.image_name))?;
        // Logged z grows away from the object (see the module docs): a lower z presses deeper.
        poses.insert(index, Pose::new(row.pose[0], row.pose[1], CONTACT_DEPTH_MM - row.pose[2], row.pose[5]));
    }
    Ok(poses)
}

/// Loads the sample folder (object 1).
pub fn load_real_sample(dir: &Path) -> anyhow::Result<RealSample> {
    let mesh = Mesh::load(dir.join("stl/1.stl"))?;
    let poses = read_lepora_poses(&dir.join("csv/1.csv"))?;
    let mut frames = BTreeMap::new();
    for sensor in SensorKind::ALL {
        let name = sensor.label();
        let mut list: Vec<(usize, RgbImage)> = Vec::new();
        for i in FRAMES {
            let p = dir.join(format!("tactile/1/{name}/target/1_{name}_{i}.png"));
            if !p.is_file() {
                continue;
            }
            let img = image::open(&p).with_context(|| format!("reading {}", p.display()))?.to_rgb8();
            // The per-pixel statistics below need one size per sensor.
            if let Some((_, first)) = list.first()
                && first.dimensions() != img.dimensions()
            {
                bail!(
                    "{}: {}x{} differs from the sensor's other frames ({}x{})",
                    p.display(),
                    img.width(),
                    img.height(),
                    first.width(),
                    first.height()
                );
            }
            if img.width() < 16 || img.height() < 16 {
                bail!("{}: {}x{} is too small to compare", p.display(), img.width(), img.height());
            }
            list.push((i, img));
        }
        frames.insert(name, list);
    }
    Ok(RealSample { mesh, poses, frames })
}

fn pose_of(sample: &RealSample, index: usize) -> anyhow::Result<Pose> {
    sample.poses.get(&index).copied().with_context(|| format!("no pose row for frame {index}"))
}

/// Fit target per sensor: outlines for see-through skins, marker displacement for TacTip.
pub fn fit_target(sensor: SensorKind, frames: &[&RgbImage]) -> FitTarget {
    match sensor {
        SensorKind::TacTip => FitTarget::Difference { reference: median_image(frames) },
        SensorKind::ViTac | SensorKind::ViTacTip => FitTarget::Edges,
    }
}

/// Fits `calibration/mds-example-<sensor>.toml` for one sensor of the sample.
pub fn fit_sensor(
    sample: &RealSample,
    sensor: SensorKind,
    seeds: &[Calibration],
) -> anyhow::Result<crate::calibration::contact_fit::ContactFit> {
    let list = sample.frames.get(sensor.label()).map(Vec::as_slice).unwrap_or(&[]);
    if list.is_empty() {
        bail!("no {} frames in the sample", sensor.label());
    }
    let frames: Vec<FitFrame> = list
        .iter()
        .map(|(i, img)| Ok(FitFrame { name: format!("1_{}_{i}.png", sensor.label()), pose: pose_of(sample, *i)?, image: img.clone() }))
        .collect::<anyhow::Result<_>>()?;
    let refs: Vec<&RgbImage> = list.iter().map(|(_, img)| img).collect();
    let target = fit_target(sensor, &refs);
    let full = list[0].1.width();
    let mut opts = ContactFitOptions { extra_starts: seeds.to_vec(), final_size: Some(full), ..ContactFitOptions::default() };
    if sensor == SensorKind::TacTip && !seeds.is_empty() {
        // Markers alone barely constrain the pose correction, which belongs to the pose log
        // (shared by all three sensors), not to the camera: take the see-through sensors' mean.
        opts.fit_pose_correction = false;
        opts.fixed_pose_correction = Some(mean_correction(seeds));
    }
    Ok(fit_contact(&sample.mesh, &frames, &target, &opts)?)
}

/// Element-wise mean of the seeds' pose corrections (identity where a seed has none).
fn mean_correction(seeds: &[Calibration]) -> [[f64; 2]; 2] {
    let mut m = [[0.0; 2]; 2];
    for c in seeds {
        let s = c.pose_xy_correction.unwrap_or([[1.0, 0.0], [0.0, 1.0]]);
        for r in 0..2 {
            for k in 0..2 {
                m[r][k] += s[r][k] / seeds.len() as f64;
            }
        }
    }
    m
}

/// The scene the comparison renders by default: every stage except `noise` and
/// `stale_frame`. SSIM against one noisy real frame is highest for the noise-free expected
/// image (independent noise only lowers it), and the baseline, a mean of frames, is nearly
/// noise-free too; a still frame has nothing stale.
pub fn comparison_scene() -> Scene {
    let stages: Vec<Stage> = Stage::ALL.into_iter().filter(|s| !matches!(s, Stage::Noise | Stage::StaleFrame)).collect();
    Scene::with_stages("compare", &stages)
}

/// The measured no-contact look the simulator starts from: the per-pixel median of the
/// *other* real frames of the sensor only (leave one out: the simulator never sees the frame it
/// is scored on, and has the same information as the baseline). One median over the same
/// frames everywhere keeps the pins whole (they shift a little between frames; switching frame
/// sets per pixel, as the footprint-aware `median_image_excluding` does, tears them).
pub fn simulator_reference(others: &[&RgbImage]) -> RgbImage {
    median_image(others)
}

/// Scores of one frame.
#[derive(Debug, Clone, Copy)]
pub struct FrameScores {
    pub index: usize,
    pub contact_fraction: f64,
    pub footprint_iou: f64,
    pub baseline_whole: f64,
    pub baseline_contact: f64,
    pub sim_whole: Option<f64>,
    pub sim_contact: Option<f64>,
}

/// Compares one sensor; writes panels into `out` if given.
/// `procedural`: render the simulator's own modelled look instead of starting from the
/// measured (leave-one-out) no-contact look.
pub fn compare_sensor(
    sample: &RealSample,
    sensor: SensorKind,
    calib: &Calibration,
    out: Option<&Path>,
    procedural: bool,
    scene: &Scene,
) -> anyhow::Result<Vec<FrameScores>> {
    let list = sample.frames.get(sensor.label()).map(Vec::as_slice).unwrap_or(&[]);
    if list.len() < 2 {
        bail!("{}: need at least two real frames, have {}", sensor.label(), list.len());
    }
    let (w, h) = list[0].1.dimensions();
    let calib = calib.scaled_to(w, h);
    let mut depths = Vec::new();
    let mut footprints = Vec::new();
    for (i, _) in list {
        let d = render_depth(&sample.mesh, &pose_of(sample, *i)?, &calib, w, h, 2);
        footprints.push(d.height_mm.iter().map(|&v| v > 0.0).collect::<Vec<bool>>());
        depths.push(d);
    }
    let covered: Vec<Vec<bool>> = footprints.iter().map(|f| dilate_mask(f, w as usize, h as usize, FOOTPRINT_MARGIN_PX as usize)).collect();
    let all: Vec<&RgbImage> = list.iter().map(|(_, img)| img).collect();
    let no_contact = median_image_excluding(&all, &covered);
    let mut scores = Vec::new();
    for (k, (index, real)) in list.iter().enumerate() {
        let others: Vec<&RgbImage> = all.iter().enumerate().filter(|(j, _)| *j != k).map(|(_, f)| *f).collect();
        let baseline = mean_image(&others);
        let mask = difference_mask(real, &no_contact, CONTACT_THRESHOLD);
        let contact_fraction = mask.iter().filter(|&&m| m).count() as f64 / mask.len() as f64;
        // The simulator's static look: the no-contact look measured on the *other* frames
        // (leave one out), the same information the baseline has; the simulator adds the contact.
        let reference = (!procedural).then(|| simulator_reference(&others));
        let sim = render_tactile_with(sensor, &depths[k], &calib, *index as u64, scene, reference.as_ref()).ok();
        let masked = |img: &RgbImage| ssim_masked(real, img, &mask).ok();
        let s = FrameScores {
            index: *index,
            contact_fraction,
            footprint_iou: iou(&footprints[k], &mask),
            baseline_whole: ssim(real, &baseline)?,
            baseline_contact: masked(&baseline).unwrap_or(f64::NAN),
            sim_whole: sim.as_ref().map(|s| ssim(real, s)).transpose()?,
            sim_contact: sim.as_ref().and_then(masked),
        };
        if let Some(dir) = out {
            std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
            let panel = panel(real, &baseline, &footprints[k], &mask, sim.as_ref());
            let p = dir.join(format!("{sensor}_{index}.png"));
            panel.save(&p).with_context(|| format!("writing {}", p.display()))?;
        }
        scores.push(s);
    }
    if let Some(dir) = out {
        let p = dir.join(format!("{sensor}_no_contact.png"));
        no_contact.save(&p).with_context(|| format!("writing {}", p.display()))?;
    }
    Ok(scores)
}

/// real | baseline | real with footprint outline | contact region | simulator (if any).
fn panel(real: &RgbImage, baseline: &RgbImage, footprint: &[bool], mask: &[bool], sim: Option<&RgbImage>) -> RgbImage {
    let (w, h) = real.dimensions();
    let mut overlay = real.clone();
    for (i, px) in overlay.pixels_mut().enumerate() {
        if footprint[i] {
            px.0 = [px.0[0] / 2 + 127, px.0[1] / 2, px.0[2] / 2];
        }
    }
    let region = RgbImage::from_fn(w, h, |x, y| {
        let i = (y * w + x) as usize;
        match (mask[i], footprint[i]) {
            (true, true) => Rgb([255, 255, 255]),
            (true, false) => Rgb([0, 160, 255]),
            (false, true) => Rgb([255, 60, 0]),
            (false, false) => Rgb([0, 0, 0]),
        }
    });
    let mut tiles = vec![real.clone(), baseline.clone(), overlay, region];
    if let Some(s) = sim {
        tiles.push(s.clone());
    }
    let mut out = RgbImage::new(w * tiles.len() as u32, h);
    for (k, t) in tiles.iter().enumerate() {
        imageops::replace(&mut out, t, (k as u32 * w) as i64, 0);
    }
    out
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let dir = args.sample.clone().unwrap_or_else(default_sample_dir);
    let sample =
        load_real_sample(&dir).with_context(|| format!("loading the real sample from {} (set --sample or RIG_SHARED)", dir.display()))?;
    if args.fit {
        std::fs::create_dir_all(&args.calibration_dir).with_context(|| format!("creating {}", args.calibration_dir.display()))?;
        // Same rig and pose log for all three: each fit also starts from the ones before it.
        let mut seeds: Vec<Calibration> = Vec::new();
        for sensor in FIT_ORDER {
            let fit = fit_sensor(&sample, sensor, &seeds)?;
            seeds.push(fit.calibration.clone());
            let path = args.calibration_dir.join(format!("mds-example-{sensor}.toml"));
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
    }
    println!("SSIM against the real frames (mean over frames; contact = pixels differing from the no-contact look)");
    println!(
        "{:<9} {:>5} {:>8} {:>8} | {:>10} {:>10} | {:>10} {:>10}",
        "sensor", "frame", "contact%", "fp-IoU", "sim whole", "base whole", "sim cont.", "base cont."
    );
    let scene = match &args.scene {
        Some(spec) => Scene::preset_or_file(spec)?,
        None => comparison_scene(),
    };
    let fmt = |v: Option<f64>| v.map(|x| format!("{x:.3}")).unwrap_or_else(|| "n/a".to_string());
    for sensor in SensorKind::ALL {
        let path = args.calibration_dir.join(format!("mds-example-{sensor}.toml"));
        let calib = Calibration::load(&path).with_context(|| format!("{}: run with --fit to create {}", sensor.label(), path.display()))?;
        let scores = compare_sensor(&sample, sensor, &calib, args.out.as_deref(), args.procedural, &scene)?;
        for s in &scores {
            println!(
                "{:<9} {:>5} {:>8.1} {:>8.3} | {:>10} {:>10.3} | {:>10} {:>10.3}",
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
        let mean_opt =
            |f: &dyn Fn(&FrameScores) -> Option<f64>| scores.iter().map(f).collect::<Option<Vec<f64>>>().map(|v| v.iter().sum::<f64>() / n);
        println!(
            "{:<9} {:>5} {:>8.1} {:>8.3} | {:>10} {:>10.3} | {:>10} {:>10.3}",
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
    if !simulator_available() {
        println!("note: sensor simulator not available in this build; simulator columns are n/a");
    }
    Ok(())
}
