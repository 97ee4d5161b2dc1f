//! `rig eval --downstream`: is the fill worth training on? MultiDiffSense's downstream
//! protocol as a command. Per sensor, a pose regressor ([`super::regressor`]: ResNet18's
//! layout) is trained on three sets of the same size—captured rows only, half captured and
//! half synthetic, synthetic rows only—and scored on held-out captured rows: MSE, RMSE, MAE
//! and R² of X (mm), Z (mm) and yaw (deg), over several seeds with their spread.
//!
//! ```text
//! DIR (datasets: captured + synthetic rows) ──per sensor──► captured rows ──split(seed)──► test (20%)
//!                                                                 │                         │
//!                                                                 ▼ train pool              │
//!   synthetic rows (DIR's, or --synthetic's), minus test poses ──► synthetic pool           │
//!   per seed: draw n from each pool ──► real only | mixed | synthetic only ──train──► score ◄┘
//! ```
//!
//! The split into training pool and test rows is drawn once (from `seed`); each of the
//! `seeds` runs draws its own training subsets, initial weights, batch order and
//! augmentation (from `seed + k`), and the three sets of one run share the initial weights.
//! A row at the pose of a test row (same object, same commanded pose) never trains, synthetic
//! or captured: with twins (`--synthetic` from `rig synth --poses-of`), or a pose collected
//! twice, the test poses stay unseen. Two datasets that are one (the same folder, or the same
//! object with the same rows: a copy) are refused, and the images are read by the dataset
//! rules `rig dataset verify` checks ([`crate::dataset::DatasetImages`]: each of its dataset's
//! size), so what verify calls unclean is not trained on.

use std::path::{Path, PathBuf};
use std::time::Instant;

use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;

use super::error::EvalError;
use super::pairing::{DatasetInfo, resized, same_pose};
use super::regressor::{CHANNELS, OUTPUTS, RegressorConfig, RegressorError, TrainDevice, cuda_built, train_and_predict};
use crate::dataset::DatasetImages;
use crate::dataset::{PoseRow, Source};
use crate::pose::Pose;
use crate::sensor::SensorKind;

/// The components predicted, in the regressor's output order, with their units.
pub const COMPONENTS: [(&str, &str); OUTPUTS] = [("X", "mm"), ("Z", "mm"), ("yaw", "deg")];
/// Share of each sensor's captured rows held out for testing (the paper's 80/20 split).
pub const TEST_FRACTION: f64 = 0.2;
/// Fewest held-out rows, and fewest training rows, a sensor needs.
pub const MIN_TEST_ROWS: usize = 5;
pub const MIN_TRAIN_ROWS: usize = 8;
/// Bounds checked before anything is read or allocated.
pub const MAX_SIZE_PX: usize = 512;
pub const MAX_WIDTH: usize = 256;
pub const MAX_EPOCHS: usize = 10_000;
pub const MAX_SEEDS: u32 = 100;
/// The images of one sensor, as float tensors, may take at most this much memory.
pub const MAX_IMAGE_BYTES: u64 = 4 << 30;

/// Preset sizes of the protocol.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Scale {
    /// Minutes on a CPU: width 8 (ResNet18: 64), 32 px, 15 epochs, learning rate 3e-3.
    Small,
    /// MultiDiffSense's: width 64, 224 px, 100 epochs, batch 8, AdamW 1e-4 (days on a 2-core CPU).
    Paper,
}

impl Scale {
    /// The regressor this scale trains.
    pub fn config(self) -> RegressorConfig {
        match self {
            Scale::Small => RegressorConfig {
                size_px: 32,
                width: 8,
                epochs: 15,
                batch: 8,
                learning_rate: 3e-3,
                weight_decay: 0.01,
                photometric_jitter: 0.1,
            },
            Scale::Paper => RegressorConfig {
                size_px: 224,
                width: 64,
                epochs: 100,
                batch: 8,
                learning_rate: 1e-4,
                weight_decay: 0.01,
                photometric_jitter: 0.1,
            },
        }
    }
}

/// The three training sets.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum TrainingSet {
    /// Captured rows only.
    Real,
    /// Half captured rows (rounded up), half synthetic.
    Mixed,
    /// Synthetic rows only.
    Synthetic,
}

impl TrainingSet {
    pub const ALL: [TrainingSet; 3] = [TrainingSet::Real, TrainingSet::Mixed, TrainingSet::Synthetic];

    /// As the table names it.
    pub fn label(self) -> &'static str {
        match self {
            TrainingSet::Real => "100% real",
            TrainingSet::Mixed => "50% real + 50% synthetic",
            TrainingSet::Synthetic => "100% synthetic",
        }
    }

    fn needs_synthetic(self) -> bool {
        self != TrainingSet::Real
    }
}

/// Settings of a downstream evaluation.
#[derive(Debug, Clone)]
pub struct DownstreamOptions {
    pub scale: Scale,
    /// The regressor (the scale's, with any overrides).
    pub regressor: RegressorConfig,
    /// Runs per training set.
    pub seeds: u32,
    /// The split's seed; run k uses `seed + k`.
    pub seed: u64,
    /// Rows per training set (default: the smaller of the training pool and the synthetic pool).
    pub train_size: Option<usize>,
    /// Only these sensors (empty: every sensor found).
    pub sensors: Vec<SensorKind>,
    /// Only these objects (empty: all).
    pub objects: Vec<String>,
    /// Which sets to train (empty: all three).
    pub sets: Vec<TrainingSet>,
    /// Where the synthetic rows come from (default: the datasets under the root).
    pub synthetic_root: Option<PathBuf>,
    /// The control: training labels permuted (test labels untouched), so nothing can be learnt.
    pub shuffle_labels: bool,
    pub device: TrainDevice,
}

impl DownstreamOptions {
    /// The scale's defaults: three seeds from seed 1, every sensor, object and set, on the CPU.
    pub fn at_scale(scale: Scale) -> Self {
        Self {
            scale,
            regressor: scale.config(),
            seeds: 3,
            seed: 1,
            train_size: None,
            sensors: Vec::new(),
            objects: Vec::new(),
            sets: Vec::new(),
            synthetic_root: None,
            shuffle_labels: false,
            device: TrainDevice::Cpu,
        }
    }

    fn sets(&self) -> Vec<TrainingSet> {
        let mut sets = if self.sets.is_empty() { TrainingSet::ALL.to_vec() } else { self.sets.clone() };
        sets.sort();
        sets.dedup();
        sets
    }
}

/// What stops a downstream evaluation.
#[derive(Debug, thiserror::Error)]
pub enum DownstreamError {
    #[error(transparent)]
    Eval(Box<EvalError>),
    #[error("{what} {value}: at most {max}")]
    Bound { what: &'static str, value: u64, max: u64 },
    #[error("{what} must be at least {min}")]
    Zero { what: &'static str, min: u64 },
    #[error("no dataset of sensor {sensor} under {dir}{objects}")]
    NoSensor { sensor: SensorKind, dir: PathBuf, objects: String },
    #[error(
        "{sensor}: {captured} captured rows give {test} test and {train} training rows; the protocol needs at least {MIN_TEST_ROWS} and {MIN_TRAIN_ROWS} (collect more poses)"
    )]
    TooFewCaptured { sensor: SensorKind, captured: usize, test: usize, train: usize },
    #[error(
        "{sensor}: {available} synthetic rows not at a test pose under {dir}; the {set} set needs at least {needed} (fill with `rig synth --fill-missing`, or --sets real)"
    )]
    TooFewSynthetic { sensor: SensorKind, available: usize, needed: usize, set: &'static str, dir: PathBuf },
    #[error("--train-size {asked}: {sensor} has only {real} captured training rows and {synthetic} synthetic rows")]
    TrainSize { asked: usize, sensor: SensorKind, real: usize, synthetic: usize },
    #[error(
        "{sensor}: {images} images at {size_px} px take {bytes} bytes as tensors, over the {MAX_IMAGE_BYTES}-byte bound (use a smaller --size)"
    )]
    TooLarge { sensor: SensorKind, images: usize, size_px: usize, bytes: u64 },
    #[error("--device cuda: {0}")]
    Device(String),
    /// Two datasets that are one: pooling both would put a test row's twin in training.
    #[error("{first} and {second} are the same dataset ({why}); pooling both would train on the test rows' twins (keep one of them)")]
    DuplicateDataset { first: PathBuf, second: PathBuf, why: &'static str },
    #[error("{sensor}, {set}, seed {seed}: {source}")]
    Training {
        sensor: SensorKind,
        set: &'static str,
        seed: u64,
        #[source]
        source: RegressorError,
    },
}

impl From<EvalError> for DownstreamError {
    fn from(e: EvalError) -> Self {
        DownstreamError::Eval(Box::new(e))
    }
}

impl DownstreamError {
    /// Everything but a failure inside training is bad input (exit 2).
    pub fn is_bad_input(&self) -> bool {
        !matches!(self, DownstreamError::Training { .. })
    }
}

/// One component's figures on the test rows.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct ComponentScore {
    pub mse: f64,
    pub rmse: f64,
    pub mae: f64,
    /// 1 - SSE / SST about the test rows' mean; None where the test rows do not vary.
    pub r2: Option<f64>,
}

impl ComponentScore {
    /// The figures of `predicted` against `truth`.
    pub fn of(predicted: &[f64], truth: &[f64]) -> Self {
        let n = truth.len().max(1) as f64;
        let mean = truth.iter().sum::<f64>() / n;
        let sse: f64 = predicted.iter().zip(truth).map(|(p, t)| (p - t).powi(2)).sum();
        let sst: f64 = truth.iter().map(|t| (t - mean).powi(2)).sum();
        let mae = predicted.iter().zip(truth).map(|(p, t)| (p - t).abs()).sum::<f64>() / n;
        let mse = sse / n;
        Self { mse, rmse: mse.sqrt(), mae, r2: (sst > 1e-12).then(|| 1.0 - sse / sst) }
    }
}

/// A figure over the seeds: mean and sample standard deviation.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Spread {
    pub mean: f64,
    pub sd: f64,
}

impl Spread {
    pub fn of(values: &[f64]) -> Option<Self> {
        if values.is_empty() {
            return None;
        }
        let n = values.len() as f64;
        let mean = values.iter().sum::<f64>() / n;
        let sd = if values.len() > 1 { (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt() } else { 0.0 };
        Some(Self { mean, sd })
    }
}

/// One training set of one sensor: every seed's scores.
#[derive(Debug, Clone, serde::Serialize)]
pub struct SetResult {
    pub set: TrainingSet,
    pub label: &'static str,
    /// Captured and synthetic rows it trained on.
    pub real_rows: usize,
    pub synthetic_rows: usize,
    /// Per seed, per component ([`COMPONENTS`] order).
    pub seeds: Vec<SeedResult>,
}

#[derive(Debug, Clone, serde::Serialize)]
pub struct SeedResult {
    pub seed: u64,
    pub scores: [ComponentScore; OUTPUTS],
    pub training_s: f64,
}

impl SetResult {
    /// Mean and spread of one figure of component `c` over the seeds.
    pub fn spread(&self, c: usize, figure: impl Fn(&ComponentScore) -> Option<f64>) -> Option<Spread> {
        let values: Vec<f64> = self.seeds.iter().filter_map(|s| figure(&s.scores[c])).collect();
        if values.len() < self.seeds.len() { None } else { Spread::of(&values) }
    }
}

/// One sensor's results.
#[derive(Debug, Clone, serde::Serialize)]
pub struct SensorResult {
    pub sensor: SensorKind,
    /// Datasets the rows came from.
    pub datasets: Vec<PathBuf>,
    pub captured_rows: usize,
    pub test_rows: usize,
    pub training_pool: usize,
    /// Synthetic rows usable for training (not at a test pose).
    pub synthetic_pool: usize,
    /// Synthetic rows left out because a test row has their pose.
    pub synthetic_at_test_poses: usize,
    /// Rows per training set.
    pub train_size: usize,
    pub sets: Vec<SetResult>,
    /// Components the captured images cannot show ([`super::downstream_notes`]).
    pub ambiguous: Vec<super::downstream_notes::Ambiguity>,
}

/// The whole evaluation.
#[derive(Debug, Clone, serde::Serialize)]
pub struct DownstreamReport {
    pub root: PathBuf,
    pub synthetic_root: Option<PathBuf>,
    pub scale: Scale,
    pub regressor: RegressorConfig,
    pub seeds: u32,
    pub seed: u64,
    pub shuffle_labels: bool,
    pub device: TrainDevice,
    pub sensors: Vec<SensorResult>,
    pub seconds: f64,
}

/// One row ready to train on or test with.
struct Sample {
    label: [f32; OUTPUTS],
    /// `3 x size x size`, values in [0, 1].
    pixels: Vec<f32>,
}

fn label_of(row: &PoseRow) -> [f32; OUTPUTS] {
    [row.x_mm as f32, row.z_mm as f32, row.yaw_deg as f32]
}

fn to_chw(img: &image::RgbImage) -> Vec<f32> {
    let (w, h) = img.dimensions();
    let plane = (w * h) as usize;
    let mut out = vec![0f32; CHANNELS * plane];
    for (i, p) in img.pixels().enumerate() {
        for c in 0..CHANNELS {
            out[c * plane + i] = p.0[c] as f32 / 255.0;
        }
    }
    out
}

/// Every dataset under `root`, read once (manifest and rows).
fn load_all(root: &Path) -> Result<Vec<DatasetInfo>, DownstreamError> {
    let dirs = crate::dataset::find_datasets(root).map_err(|source| EvalError::Dataset { dir: root.to_path_buf(), source })?;
    if dirs.is_empty() {
        return Err(EvalError::NoDatasets { side: "downstream", dir: root.to_path_buf() }.into());
    }
    dirs.iter().map(|d| DatasetInfo::load(d).map_err(DownstreamError::from)).collect()
}

/// The datasets of one sensor (and the chosen objects).
fn of_sensor<'a>(all: &'a [DatasetInfo], sensor: SensorKind, objects: &[String]) -> Vec<&'a DatasetInfo> {
    all.iter().filter(|d| d.manifest.sensor == sensor && (objects.is_empty() || objects.contains(&d.manifest.object.name))).collect()
}

/// The images (at `size` px) and labels of `rows` (dataset index, row), in their order, read
/// by the dataset rules (`images[i]` reads dataset `i`'s).
fn load_samples(images: &mut [DatasetImages], rows: &[(usize, &PoseRow)], size: u32) -> Result<Vec<Sample>, DownstreamError> {
    let mut out = Vec::with_capacity(rows.len());
    for (i, row) in rows {
        let reader = &mut images[*i];
        let img =
            reader.read(Path::new(&row.image)).map_err(|source| EvalError::Dataset { dir: reader.dir().to_path_buf(), source })?.to_rgb8();
        out.push(Sample { label: label_of(row), pixels: to_chw(&resized(img, size)) });
    }
    Ok(out)
}

/// The image readers of `datasets`, each sized by its reference frame.
fn readers_of(datasets: &[&DatasetInfo]) -> Result<Vec<DatasetImages>, DownstreamError> {
    datasets
        .iter()
        .map(|d| DatasetImages::open(&d.dir).map_err(|source| DownstreamError::from(EvalError::Dataset { dir: d.dir.clone(), source })))
        .collect()
}

/// Refuses two of `datasets` that are one dataset: the same folder (its device and inode), or
/// the same object and sensor with the same rows (a copy).
fn refuse_duplicates(datasets: &[&DatasetInfo]) -> Result<(), DownstreamError> {
    use std::os::unix::fs::MetadataExt;
    let identity = |d: &DatasetInfo| std::fs::metadata(&d.dir).ok().map(|m| (m.dev(), m.ino()));
    for (k, b) in datasets.iter().enumerate() {
        for a in &datasets[..k] {
            let why = if identity(a).is_some() && identity(a) == identity(b) {
                "one folder"
            } else if a.key() == b.key() && !a.rows.is_empty() && a.rows == b.rows {
                "the same object, sensor and rows: a copy"
            } else {
                continue;
            };
            return Err(DownstreamError::DuplicateDataset { first: a.dir.clone(), second: b.dir.clone(), why });
        }
    }
    Ok(())
}

fn check_bounds(options: &DownstreamOptions) -> Result<(), DownstreamError> {
    let r = &options.regressor;
    for (what, value, max) in [
        ("--size", r.size_px as u64, MAX_SIZE_PX as u64),
        ("--width", r.width as u64, MAX_WIDTH as u64),
        ("--epochs", r.epochs as u64, MAX_EPOCHS as u64),
        ("--seeds", options.seeds as u64, MAX_SEEDS as u64),
    ] {
        if value > max {
            return Err(DownstreamError::Bound { what, value, max });
        }
    }
    for (what, value, min) in [
        ("--size", r.size_px as u64, 16),
        ("--width", r.width as u64, 1),
        ("--epochs", r.epochs as u64, 1),
        ("--seeds", options.seeds as u64, 1),
        ("--batch", r.batch as u64, 2),
    ] {
        if value < min {
            return Err(DownstreamError::Zero { what, min });
        }
    }
    if r.batch > 1024 {
        return Err(DownstreamError::Bound { what: "--batch", value: r.batch as u64, max: 1024 });
    }
    if options.device == TrainDevice::Cuda && !cuda_built() {
        return Err(DownstreamError::Device(
            "this rig was built without CUDA training (cargo feature `downstream-cuda`, which needs the CUDA toolkit to build)".into(),
        ));
    }
    Ok(())
}

/// Runs the protocol on the datasets under `root` (see the module docs). `progress` gets one
/// line per trained regressor.
pub fn downstream(root: &Path, options: &DownstreamOptions, mut progress: impl FnMut(&str)) -> Result<DownstreamReport, DownstreamError> {
    check_bounds(options)?;
    let started = Instant::now();
    let synthetic_root = options.synthetic_root.as_deref().unwrap_or(root);
    let captured = load_all(root)?;
    let synthetic = match &options.synthetic_root {
        Some(other) => Some(load_all(other)?),
        None => None,
    };
    let sources = Sources { root, synthetic_root, captured: &captured, synthetic: synthetic.as_deref().unwrap_or(&captured) };
    // Every sensor with a dataset, in rig's order, unless some are chosen.
    let sensors: Vec<SensorKind> = if options.sensors.is_empty() {
        SensorKind::ALL.into_iter().filter(|k| captured.iter().any(|d| d.manifest.sensor == *k)).collect()
    } else {
        options.sensors.clone()
    };
    let sets = options.sets();
    let mut results = Vec::new();
    for sensor in sensors {
        results.push(one_sensor(&sources, sensor, &sets, options, &mut progress)?);
    }
    Ok(DownstreamReport {
        root: root.to_path_buf(),
        synthetic_root: options.synthetic_root.clone(),
        scale: options.scale,
        regressor: options.regressor.clone(),
        seeds: options.seeds,
        seed: options.seed,
        shuffle_labels: options.shuffle_labels,
        device: options.device,
        sensors: results,
        seconds: started.elapsed().as_secs_f64(),
    })
}

/// The datasets read from the root and from where the synthetic rows come from (the same
/// datasets unless `--synthetic` names another folder).
struct Sources<'a> {
    root: &'a Path,
    synthetic_root: &'a Path,
    captured: &'a [DatasetInfo],
    synthetic: &'a [DatasetInfo],
}

fn one_sensor(
    sources: &Sources,
    sensor: SensorKind,
    sets: &[TrainingSet],
    options: &DownstreamOptions,
    progress: &mut impl FnMut(&str),
) -> Result<SensorResult, DownstreamError> {
    let objects_note = if options.objects.is_empty() { String::new() } else { format!(" (objects {})", options.objects.join(", ")) };
    let captured_sets = of_sensor(sources.captured, sensor, &options.objects);
    if captured_sets.is_empty() {
        return Err(DownstreamError::NoSensor { sensor, dir: sources.root.to_path_buf(), objects: objects_note });
    }
    let synthetic_sets = of_sensor(sources.synthetic, sensor, &options.objects);
    refuse_duplicates(&captured_sets)?;
    if !std::ptr::eq(sources.captured, sources.synthetic) {
        refuse_duplicates(&synthetic_sets)?;
    }

    // The split: captured rows in a seeded order, the first TEST_FRACTION held out.
    let mut captured: Vec<(usize, &PoseRow)> =
        captured_sets.iter().enumerate().flat_map(|(i, d)| d.captured_rows().map(move |r| (i, r))).collect();
    let mut rng = ChaCha8Rng::seed_from_u64(options.seed ^ (sensor as u64) << 32);
    captured.shuffle(&mut rng);
    let n_test = ((captured.len() as f64 * TEST_FRACTION).round() as usize).min(captured.len());
    let n_pool = captured.len() - n_test;
    if n_test < MIN_TEST_ROWS || n_pool < MIN_TRAIN_ROWS {
        return Err(DownstreamError::TooFewCaptured { sensor, captured: captured.len(), test: n_test, train: n_pool });
    }
    let (test_rows, pool_rows) = captured.split_at(n_test);
    let at_test_pose = |object: &str, pose: &Pose| {
        test_rows.iter().any(|(i, r)| captured_sets[*i].manifest.object.name == object && same_pose(&r.commanded(), pose))
    };
    // A pose collected twice trains on neither side of the split: its other capture is a
    // twin of the test row.
    let pool_rows: Vec<(usize, &PoseRow)> =
        pool_rows.iter().copied().filter(|(i, r)| !at_test_pose(&captured_sets[*i].manifest.object.name, &r.commanded())).collect();
    let n_pool = pool_rows.len();
    if n_pool < MIN_TRAIN_ROWS {
        return Err(DownstreamError::TooFewCaptured { sensor, captured: captured.len(), test: n_test, train: n_pool });
    }
    let mut synthetic: Vec<(usize, &PoseRow)> =
        synthetic_sets.iter().enumerate().flat_map(|(i, d)| d.rows_of(Source::Synthetic).map(move |r| (i, r))).collect();
    let before = synthetic.len();
    synthetic.retain(|(i, r)| !at_test_pose(&synthetic_sets[*i].manifest.object.name, &r.commanded()));
    let at_test_poses = before - synthetic.len();

    let needs_synthetic = sets.iter().any(|s| s.needs_synthetic());
    let n = match options.train_size {
        Some(asked) => {
            if asked > n_pool || (needs_synthetic && asked > synthetic.len()) || asked < MIN_TRAIN_ROWS {
                return Err(DownstreamError::TrainSize { asked, sensor, real: n_pool, synthetic: synthetic.len() });
            }
            asked
        }
        None if needs_synthetic => n_pool.min(synthetic.len()),
        None => n_pool,
    };
    if needs_synthetic && n < MIN_TRAIN_ROWS {
        let set = sets.iter().find(|s| s.needs_synthetic()).map_or("synthetic", |s| s.label());
        return Err(DownstreamError::TooFewSynthetic {
            sensor,
            available: synthetic.len(),
            needed: MIN_TRAIN_ROWS,
            set,
            dir: sources.synthetic_root.to_path_buf(),
        });
    }

    // Bound the tensors before reading a pixel.
    let size = options.regressor.size_px;
    let images = n_test + n_pool + if needs_synthetic { synthetic.len() } else { 0 };
    let bytes = images as u64 * (CHANNELS * size * size * 4) as u64;
    if bytes > MAX_IMAGE_BYTES {
        return Err(DownstreamError::TooLarge { sensor, images, size_px: size, bytes });
    }
    let mut captured_images = readers_of(&captured_sets)?;
    let test = load_samples(&mut captured_images, test_rows, size as u32)?;
    let pool = load_samples(&mut captured_images, &pool_rows, size as u32)?;
    let synthetic_samples =
        if needs_synthetic { load_samples(&mut readers_of(&synthetic_sets)?, &synthetic, size as u32)? } else { Vec::new() };
    let test_pixels: Vec<f32> = test.iter().flat_map(|s| s.pixels.iter().copied()).collect();
    let truth: Vec<[f32; OUTPUTS]> = test.iter().map(|s| s.label).collect();
    let looked: Vec<(u32, [f32; OUTPUTS], &[f32])> = test_rows
        .iter()
        .chain(pool_rows.iter())
        .zip(test.iter().chain(&pool))
        .map(|((_, r), s)| (r.pose_id, s.label, &s.pixels[..]))
        .collect();
    let ambiguous = super::downstream_notes::ambiguous_components(&looked, COMPONENTS.map(|c| c.0));

    let mut set_results: Vec<SetResult> = sets
        .iter()
        .map(|&set| {
            let (real_rows, synthetic_rows) = match set {
                TrainingSet::Real => (n, 0),
                TrainingSet::Mixed => (n.div_ceil(2), n / 2),
                TrainingSet::Synthetic => (0, n),
            };
            SetResult { set, label: set.label(), real_rows, synthetic_rows, seeds: Vec::new() }
        })
        .collect();
    for k in 0..options.seeds as u64 {
        let seed = options.seed.wrapping_add(k);
        let mut draw = ChaCha8Rng::seed_from_u64(seed ^ 0xd0_57a2 ^ (sensor as u64) << 40);
        let mut pick = |from: &'_ [Sample]| -> Vec<usize> { rand::seq::index::sample(&mut draw, from.len(), n).into_vec() };
        let real_pick: Vec<&Sample> = pick(&pool).into_iter().map(|i| &pool[i]).collect();
        let synthetic_pick: Vec<&Sample> =
            if needs_synthetic { pick(&synthetic_samples).into_iter().map(|i| &synthetic_samples[i]).collect() } else { Vec::new() };
        for result in &mut set_results {
            let chosen: Vec<&Sample> =
                real_pick.iter().take(result.real_rows).chain(synthetic_pick.iter().take(result.synthetic_rows)).copied().collect();
            let pixels: Vec<f32> = chosen.iter().flat_map(|s| s.pixels.iter().copied()).collect();
            let mut labels: Vec<[f32; OUTPUTS]> = chosen.iter().map(|s| s.label).collect();
            if options.shuffle_labels {
                labels.shuffle(&mut ChaCha8Rng::seed_from_u64(seed ^ 0x5_4ff1e));
            }
            let t0 = Instant::now();
            let mut last_loss = f32::NAN;
            let predicted =
                train_and_predict(&pixels, &labels, &test_pixels, &options.regressor, seed, options.device, |_, loss| last_loss = loss)
                    .map_err(|source| DownstreamError::Training { sensor, set: result.label, seed, source })?;
            let training_s = t0.elapsed().as_secs_f64();
            let scores = std::array::from_fn(|c| {
                let p: Vec<f64> = predicted.iter().map(|p| p[c] as f64).collect();
                let t: Vec<f64> = truth.iter().map(|t| t[c] as f64).collect();
                ComponentScore::of(&p, &t)
            });
            progress(&format!(
                "downstream: {sensor}, {}, seed {seed}: {} epochs on {} rows in {training_s:.1} s (last training loss {last_loss:.3})",
                result.label,
                options.regressor.epochs,
                chosen.len()
            ));
            result.seeds.push(SeedResult { seed, scores, training_s });
        }
    }
    Ok(SensorResult {
        sensor,
        datasets: captured_sets.iter().map(|d| d.dir.clone()).collect(),
        captured_rows: captured.len(),
        test_rows: n_test,
        training_pool: n_pool,
        synthetic_pool: synthetic.len(),
        synthetic_at_test_poses: at_test_poses,
        train_size: n,
        sets: set_results,
        ambiguous,
    })
}

impl DownstreamReport {
    /// The table: per sensor and training set, MAE, RMSE and R² of each component on the
    /// held-out captured rows, mean ± sample standard deviation over the seeds.
    pub fn to_markdown(&self) -> String {
        let r = &self.regressor;
        let mut out = format!(
            "### rig eval --downstream: {}{}\n\n",
            self.root.display(),
            self.synthetic_root.as_ref().map(|s| format!(" (synthetic rows from {})", s.display())).unwrap_or_default()
        );
        out += &format!(
            "Regressor: ResNet18 layout at width {}, {} px RGB, {} epochs, batch {}, AdamW lr {:e} (weight decay {}), L1 loss, \
             photometric jitter ±{} (scale `{}`, device {}). {}{}\n\n",
            r.width,
            r.size_px,
            r.epochs,
            r.batch,
            r.learning_rate,
            r.weight_decay,
            r.photometric_jitter,
            serde_json::to_value(self.scale).ok().and_then(|v| v.as_str().map(String::from)).unwrap_or_default(),
            serde_json::to_value(self.device).ok().and_then(|v| v.as_str().map(String::from)).unwrap_or_default(),
            super::downstream_notes::seeds_sentence(self.seeds, self.seed),
            if self.shuffle_labels { " **Control: training labels shuffled.**" } else { "" }
        );
        out += "| sensor | trained on | n train | n test | X MAE (mm) | X RMSE (mm) | X R² | Z MAE (mm) | Z RMSE (mm) | Z R² | yaw MAE (deg) | yaw RMSE (deg) | yaw R² |\n";
        out += "|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
        for s in &self.sensors {
            for set in &s.sets {
                out += &format!("| {} | {} | {} | {} |", s.sensor.label(), set.label, s.train_size, s.test_rows);
                for c in 0..OUTPUTS {
                    let digits = if c == 2 { 2 } else { 3 };
                    let cell = |s: Option<Spread>, digits| {
                        super::downstream_notes::spread_cell(s.map(|s| (s.mean, s.sd)), digits, set.seeds.len())
                    };
                    out += &format!(
                        " {} | {} | {} |",
                        cell(set.spread(c, |x| Some(x.mae)), digits),
                        cell(set.spread(c, |x| Some(x.rmse)), digits),
                        cell(set.spread(c, |x| x.r2), 3)
                    );
                }
                out += "\n";
            }
        }
        out += "\n";
        for s in &self.sensors {
            out += &format!(
                "{}: {} captured rows ({} held out for testing, {} in the training pool), {} synthetic rows usable ({} left out: a test row has their pose).\n",
                s.sensor.label(),
                s.captured_rows,
                s.test_rows,
                s.training_pool,
                s.synthetic_pool,
                s.synthetic_at_test_poses
            );
        }
        out += &format!(
            "\nTrained {} regressors in {:.0} s.\n",
            self.sensors.iter().map(|s| s.sets.len()).sum::<usize>() * self.seeds as usize,
            self.seconds
        );
        let warnings =
            super::downstream_notes::warnings(self.sensors.iter().map(|s| (s.sensor.label().to_string(), s.test_rows, &s.ambiguous[..])));
        if !warnings.is_empty() {
            out += "\n";
            for w in warnings {
                out += &format!("{w}\n");
            }
        }
        out
    }

    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).unwrap_or_else(|e| format!("{{\"error\": \"{e}\"}}"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scores_match_their_definitions() {
        let s = ComponentScore::of(&[1.0, 2.0, 5.0], &[1.0, 3.0, 2.0]);
        assert!((s.mae - 4.0 / 3.0).abs() < 1e-12);
        assert!((s.mse - 10.0 / 3.0).abs() < 1e-12);
        assert!((s.rmse - (10.0f64 / 3.0).sqrt()).abs() < 1e-12);
        // truth mean 2, SST = 1 + 1 + 0 = 2, SSE = 10.
        assert!((s.r2.expect("r2") - (1.0 - 10.0 / 2.0)).abs() < 1e-12);
        assert_eq!(ComponentScore::of(&[1.0, 2.0], &[3.0, 3.0]).r2, None);
        let perfect = ComponentScore::of(&[1.0, 2.0, 3.0], &[1.0, 2.0, 3.0]);
        assert_eq!(perfect.r2, Some(1.0));
    }

    #[test]
    fn spread_is_mean_and_sample_sd() {
        let s = Spread::of(&[1.0, 2.0, 3.0]).expect("spread");
        assert!((s.mean - 2.0).abs() < 1e-12 && (s.sd - 1.0).abs() < 1e-12);
        assert_eq!(Spread::of(&[4.0]).map(|s| s.sd), Some(0.0));
        assert!(Spread::of(&[]).is_none());
    }

    #[test]
    fn bounds_are_checked_before_reading() {
        let mut o = DownstreamOptions::at_scale(Scale::Small);
        o.regressor.size_px = 4096;
        let err = downstream(Path::new("/nonexistent-rig-folder"), &o, |_| {}).unwrap_err();
        assert!(err.to_string().contains("--size 4096: at most 512"), "{err}");
        let mut o = DownstreamOptions::at_scale(Scale::Small);
        o.seeds = 0;
        assert!(
            downstream(Path::new("/nonexistent-rig-folder"), &o, |_| {}).unwrap_err().to_string().contains("--seeds must be at least 1")
        );
    }
}
