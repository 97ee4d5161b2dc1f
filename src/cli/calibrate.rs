//! `rig calibrate`: the pixel-to-mm calibration of one sensor.
//!
//! ```text
//! rig calibrate --sensor tactip [--out FILE] [--sim-truth FILE] [--grid 5 --span-mm 4]
//! rig calibrate --sensor tactip --interactive
//! rig calibrate --sensor vitac --from-dataset DIR
//! ```
//!
//! - Automatic (default): presses the calibration indenter at a grid of offsets and at three
//!   press depths (for the depth-dependent scale) on the configured rig (the built-in simulated rig without a configuration), detects each
//!   contact, fits, prints the mapping with the residual as the last line, and saves to
//!   `--out` (default `calibration/<sensor>.toml`, which `rig collect` and
//!   `rig synth --fill-missing` then use). `--sim-truth FILE` gives the simulated sensor a
//!   known ground-truth calibration to recover.
//! - `--interactive`: the same presses, one at a time, through the terminal wizard
//!   (`calibration::wizard`); needs a terminal.
//! - `--from-dataset DIR`: fits from frames whose poses are known: a rig dataset
//!   (`poses.csv`, `reference.png`, `images/`) or the MultiDiffSense example folder
//!   (`csv/1.csv`, `tactile/1/<Sensor>/target/`), whose missing no-contact frame is estimated
//!   as the per-pixel median of its frames.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use clap::Args as ClapArgs;
use image::RgbImage;

use crate::calibration::detect::ContactDetector;
use crate::calibration::fit::{FitOptions, PointFit, fit_points};
use crate::calibration::press::{ArmStation, Press, PressPattern, indenter_mesh, sensor_point_mm};
use crate::calibration::wizard::{LineIo, WizardOutcome, describe_fit, run_wizard};
use crate::calibration::{Calibration, FitPoint};
use crate::config::{RigConfig, SensorBackend, SensorConfig};
use crate::geometry::objects::ObjectChoice;
use crate::jobs::CalibrateRequest;
use crate::jobs::calibrate::PressOutcome;
use crate::jobs::{JobRequest, Observer};
use crate::pose::Pose;
use crate::rigs::Rig;
use crate::sensor::SensorKind;
use crate::sensor::SensorSet;

/// The accuracy the calibration should reach (the paper's figure), px RMS.
pub const TARGET_RMS_PX: f64 = 5.0;

/// Arguments of `rig calibrate`.
#[derive(Debug, ClapArgs)]
pub struct Args {
    /// Sensor to calibrate: tactip, vitac or vitactip.
    #[arg(long)]
    pub sensor: SensorKind,
    /// Where to save the calibration (default `calibration/<sensor>.toml`).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Run the terminal wizard: say what to mount, show each detection, allow redo and skip,
    /// ask before saving.
    #[arg(long, conflicts_with = "from_dataset")]
    pub interactive: bool,
    /// Fit from a dataset with known poses instead of pressing (a rig dataset or the
    /// MultiDiffSense example folder).
    #[arg(long, value_name = "DIR")]
    pub from_dataset: Option<PathBuf>,
    /// Simulated rig: the sensor's ground-truth calibration (what the run should recover).
    #[arg(long, value_name = "FILE")]
    pub sim_truth: Option<PathBuf>,
    /// Presses per axis of the grid.
    #[arg(long, default_value_t = 5)]
    pub grid: usize,
    /// Half the grid's side, mm.
    #[arg(long, default_value_t = 4.0)]
    pub span_mm: f64,
    /// Extra indentations (mm, comma-separated) pressed at a 3 x 3 layer (centre, edge
    /// midpoints, corners) each; they measure the depth-dependent scale (0 = none).
    #[arg(long, value_delimiter = ',', default_value = "-0.5,0.5", allow_hyphen_values = true)]
    pub depths_mm: Vec<f64>,
    /// Seed of the simulated sensor's noise.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    #[command(flatten)]
    pub rig: crate::cli::shared::RigTarget,
}

impl Args {
    /// The automatic calibration these arguments ask for.
    pub fn request(&self) -> CalibrateRequest {
        CalibrateRequest {
            sensor: self.sensor,
            out: self.out.clone(),
            grid: self.grid,
            span_mm: self.span_mm,
            depths_mm: self.depths_mm.clone(),
        }
    }
}

/// Runs `rig calibrate`.
pub fn run(args: Args) -> anyhow::Result<()> {
    let standalone =
        [("--interactive", args.interactive), ("--from-dataset", args.from_dataset.is_some()), ("--sim-truth", args.sim_truth.is_some())];
    if let Some(daemon) = args.rig.daemon("the automatic presses", &standalone)? {
        let mut request = args.request();
        request.out = request.out.as_deref().map(super::shared::absolute);
        return crate::cli::daemon::submit_and_follow(daemon, JobRequest::Calibrate(request));
    }
    let request = args.request();
    let out = request.out_path();
    if let Some(dir) = &args.from_dataset {
        return from_dataset(&args, dir, &out);
    }
    if args.interactive && !std::io::stdin().is_terminal() {
        bail!(crate::cli::usage("--interactive needs a terminal on stdin (run it in a terminal, or drop --interactive)"));
    }
    let mut config = args.rig.rig_config()?;
    if let Some(truth) = &args.sim_truth {
        set_sim_truth(&mut config, args.sensor, truth)?;
    }
    println!("{}", config.describe());
    let (pattern, envelope) = request.prepare(&config)?;
    println!("{}", request.pattern_line(&pattern));
    let runtime = tokio::runtime::Runtime::new().context("starting the async runtime")?;
    if args.rig.dry_run {
        let object = ObjectChoice::built_in("indenter", indenter_mesh());
        let outputs = [out.display().to_string()];
        return runtime.block_on(super::shared::dry_run(&config, &object, &SensorSet::one(args.sensor), args.seed, &envelope, &outputs));
    }
    runtime.block_on(press_and_fit(&args, config, pattern, &out))
}

/// Points the configured (or added) simulated sensor entry at the ground-truth file.
fn set_sim_truth(config: &mut RigConfig, kind: SensorKind, truth: &Path) -> anyhow::Result<()> {
    let calib = Calibration::load(truth)?;
    let name = kind.to_string();
    match config.sensors.iter_mut().find(|s| s.name == name) {
        Some(s) => {
            if s.backend != SensorBackend::Simulated {
                bail!(crate::cli::usage("--sim-truth needs a simulated sensor; the configuration names real hardware"));
            }
            s.calibration = Some(truth.to_path_buf());
        }
        None => config.sensors.push(SensorConfig {
            name,
            backend: SensorBackend::Simulated,
            calibration: Some(truth.to_path_buf()),
            scene: "full".into(),
            width: calib.image_size[0],
            height: calib.image_size[1],
            camera: crate::camera::v4l2::CameraSettings { width: calib.image_size[0], height: calib.image_size[1], ..Default::default() },
            max_indentation_mm: None,
        }),
    }
    Ok(())
}

async fn press_and_fit(args: &Args, config: RigConfig, pattern: PressPattern, out: &Path) -> anyhow::Result<()> {
    let object = ObjectChoice::built_in("indenter", indenter_mesh());
    let clock = crate::rigs::clock_for(&config);
    let mut rig = Rig::open(&config, &object, &SensorSet::one(args.sensor), args.seed, clock).await?;
    let camera = rig.cameras.pop().context("the rig opened no camera")?;
    if args.interactive {
        let sensor_name = args.sensor.to_string();
        let detector =
            ContactDetector::for_sensor(args.sensor, config.sensors.iter().find(|s| s.name == sensor_name).map_or(512, |s| s.width));
        let fence = crate::jobs::calibrate::fence(&config, args.sensor)?;
        let mut station = ArmStation::new(&mut rig.arm, camera, config.work_frame, config.collect.clone(), detector, fence);
        // Ctrl-C: the answer being waited for (or the next one, after the current press) reads
        // as a quit, so the wizard retracts the arm; nothing is saved.
        let cancel = super::shared::cancel_on_interrupt("finishing the current press, then retracting the arm; nothing is saved")?;
        let mut io = LineIo { input: std::io::BufReader::new(CancellableStdin::new(cancel.clone())), output: std::io::stdout() };
        let outcome = run_wizard(&mut io, &mut station, &pattern, &FitOptions::default(), &sensor_name, &out.display().to_string()).await?;
        let size = station.reference.as_ref().map(|r| [r.width(), r.height()]);
        drop(station);
        rig.shutdown().await;
        if *cancel.borrow() {
            println!("interrupted; the arm is retracted and {} was not written", out.display());
            bail!(crate::cli::ExitStatus(4));
        }
        let WizardOutcome::Save(fit) = outcome else { return Ok(()) };
        let mut fit = *fit;
        if let Some(size) = size {
            fit.calibration.image_size = size;
        }
        return save_and_report(&fit, out, args.sim_truth.as_deref(), false);
    }
    let total = pattern.offsets.len();
    // Ctrl-C: finish the current press, retract, disable, save nothing (as `rig collect`).
    let cancel = super::shared::cancel_on_interrupt("finishing the current press, then retracting and disabling the arm")?;
    let observer = Observer { progress: indicatif::ProgressBar::hidden(), cancel };
    let mut print = |k: usize, press: &Press| match &press.contact {
        Ok(c) => {
            println!(
                "press {:>2}/{total} at ({:+.2}, {:+.2}) mm depth {:+.2}: {c}",
                k + 1,
                press.offset.x_mm,
                press.offset.y_mm,
                press.offset.z_mm
            )
        }
        Err(e) => println!("press {:>2}/{total} at ({:+.2}, {:+.2}) mm: no detection: {e}", k + 1, press.offset.x_mm, press.offset.y_mm),
    };
    let run = crate::jobs::calibrate::press_and_fit(&mut rig.arm, camera, args.sensor, &config, &pattern, &observer, &mut print).await;
    rig.shutdown().await;
    match run? {
        PressOutcome::Cancelled { done, total } => {
            println!("interrupted after {done} of {total} presses; the arm is retracted and {} was not written", out.display());
            bail!(crate::cli::ExitStatus(4));
        }
        PressOutcome::Fitted { fit, .. } => save_and_report(&fit, out, args.sim_truth.as_deref(), true),
    }
}

/// Stdin for the wizard, read on a thread of its own so that a Ctrl-C ends a wait for an
/// answer: once `cancel` is set, reads give the end of input, which the wizard takes as a quit
/// (retracting the arm), instead of the signal killing the process with the arm wherever it was.
struct CancellableStdin {
    chunks: std::sync::mpsc::Receiver<Vec<u8>>,
    pending: std::collections::VecDeque<u8>,
    cancel: tokio::sync::watch::Receiver<bool>,
}

impl CancellableStdin {
    fn new(cancel: tokio::sync::watch::Receiver<bool>) -> Self {
        let (tx, chunks) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            use std::io::Read;
            let mut buf = [0u8; 1024];
            // Ends at the end of input or a read error; the reader then sees a disconnect.
            while let Ok(n @ 1..) = std::io::stdin().read(&mut buf) {
                if tx.send(buf[..n].to_vec()).is_err() {
                    break;
                }
            }
        });
        Self { chunks, pending: std::collections::VecDeque::new(), cancel }
    }
}

impl std::io::Read for CancellableStdin {
    fn read(&mut self, out: &mut [u8]) -> std::io::Result<usize> {
        use std::sync::mpsc::RecvTimeoutError;
        while self.pending.is_empty() {
            if *self.cancel.borrow() {
                return Ok(0);
            }
            match self.chunks.recv_timeout(std::time::Duration::from_millis(50)) {
                Ok(chunk) => self.pending.extend(chunk),
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => return Ok(0),
            }
        }
        let n = out.len().min(self.pending.len());
        for (slot, byte) in out.iter_mut().zip(self.pending.drain(..n)) {
            *slot = byte;
        }
        Ok(n)
    }
}

/// Saves the calibration and prints the mapping (only the residual when the wizard has shown
/// it already); the residual is the last line.
fn save_and_report(fit: &PointFit, out: &Path, truth: Option<&Path>, mapping: bool) -> anyhow::Result<()> {
    crate::jobs::calibrate::save(fit, out)?;
    println!("saved {}", out.display());
    if let Some(truth) = truth {
        let t = Calibration::load(truth)?;
        let c = &fit.calibration;
        println!(
            "ground truth: centre ({:.2}, {:.2}) px, scale x {:.3} y {:.3} px/mm, rotation {:.3} deg, depth {:+.4} /mm; fit error: centre {:.3} px, scale {:.4} / {:.4} px/mm, rotation {:.4} deg, depth {:+.4} /mm",
            t.centre_px[0],
            t.centre_px[1],
            t.scale_px_per_mm[0],
            t.scale_px_per_mm[1],
            t.rotation_deg,
            t.depth_scale_per_mm,
            (c.centre_px[0] - t.centre_px[0]).hypot(c.centre_px[1] - t.centre_px[1]),
            c.scale_px_per_mm[0] - t.scale_px_per_mm[0],
            c.scale_px_per_mm[1] - t.scale_px_per_mm[1],
            crate::pose::wrap_deg(c.rotation_deg - t.rotation_deg),
            c.depth_scale_per_mm - t.depth_scale_per_mm
        );
    }
    if mapping {
        for line in describe_fit(fit) {
            println!("{line}");
        }
    } else {
        println!("{}", fit.residual_line());
    }
    Ok(())
}

/// `--from-dataset`: detect every frame against the reference, fit the known poses.
fn from_dataset(args: &Args, dir: &Path, out: &Path) -> anyhow::Result<()> {
    let (frames, reference) =
        if dir.join("csv/1.csv").is_file() { multidiffsense_frames(dir, args.sensor)? } else { rig_dataset_frames(dir)? };
    println!("{}: {} frames of {} with known poses", dir.display(), frames.len(), args.sensor);
    let detector = ContactDetector::for_sensor(args.sensor, reference.width());
    let mut points = Vec::new();
    let mut names = Vec::new();
    for (name, pose, image) in &frames {
        match detector.detect(image, &reference) {
            Ok(c) => {
                println!("{name}: pose ({:+.2}, {:+.2}) mm yaw {:+.1}: {c}", pose.x_mm, pose.y_mm, pose.yaw_deg);
                // Dataset poses log the indentation beyond the contact depth; the datasets do not
                // record the rig's contact depth, so the default one stands in.
                let depth_mm = pose.z_mm + crate::pose::WorkFrame::default().contact_depth_mm;
                points.push(FitPoint { mm: sensor_point_mm(pose), px: c.centroid_px, depth_mm });
                names.push(name.clone());
            }
            Err(e) => println!("{name}: no detection: {e}"),
        }
    }
    let options = FitOptions { image_size: [reference.width(), reference.height()], ..FitOptions::default() };
    let mut fit = fit_points(&points, &options, "dataset-contact-centroids")
        .with_context(|| format!("fitting the {} detected contacts of {}", points.len(), dir.display()))?;
    for (name, r) in names.iter().zip(&fit.residuals_px) {
        println!("{name}: residual {r:.2} px");
    }
    if let Some(record) = fit.calibration.fit.as_mut() {
        record.frames = names;
    }
    if fit.rms_px > TARGET_RMS_PX {
        println!(
            "warning: the residual is above the {TARGET_RMS_PX} px target: the logged poses do not move the contact as a rigid \
             pixel-to-mm map says (check the poses, or fit with a pose correction: rig compare-real --fit)"
        );
    }
    save_and_report(&fit, out, None, true)
}

type KnownFrames = (Vec<(String, Pose, RgbImage)>, RgbImage);

/// A rig dataset: captured rows, real or simulated (measured pose when logged), `reference.png`.
fn rig_dataset_frames(dir: &Path) -> anyhow::Result<KnownFrames> {
    let reference = dataset_rgb(dir, crate::dataset::REFERENCE_FILE)?;
    let rows = crate::dataset::read_rows(dir).with_context(|| format!("reading {}", dir.display()))?;
    let mut frames = Vec::new();
    for row in rows.iter().filter(|r| r.source.is_captured()) {
        let pose = row.measured().unwrap_or_else(|| row.commanded());
        frames.push((row.image.clone(), pose, dataset_rgb(dir, &row.image)?));
    }
    Ok((frames, reference))
}

/// The MultiDiffSense example: its frames with their logged poses (work frame, like a rig
/// dataset's); reference = per-pixel median.
fn multidiffsense_frames(dir: &Path, kind: SensorKind) -> anyhow::Result<KnownFrames> {
    let sample = crate::eval::compare_real::RealSample::load(dir)?;
    let images: Vec<&RgbImage> = sample.frames_of(kind).iter().map(|(_, img)| img).collect();
    if images.is_empty() {
        bail!("{}: no {} frames", dir.display(), kind.label());
    }
    let reference = crate::imaging::median_image(&images);
    Ok((sample.posed_frames(kind, crate::eval::compare_real::RealSample::work_pose)?, reference))
}

/// An image of the dataset at `dir` by the dataset rules: below it with no symlink, a regular
/// file, bounded, its pixel count bounded before decoding.
fn dataset_rgb(dir: &Path, rel: &str) -> anyhow::Result<RgbImage> {
    use crate::dataset::{DatasetError, durable};
    let bytes = durable::read_below(dir, Path::new(rel), durable::MAX_IMAGE_BYTES)?;
    let image = durable::decode_image(&bytes).map_err(|reason| DatasetError::BadImage { path: dir.join(rel), reason })?;
    Ok(image.to_rgb8())
}
