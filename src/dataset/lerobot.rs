//! The LeRobot v3 export (`rig dataset export --format lerobot`): rig datasets as a LeRobot
//! dataset that `lerobot`'s `LeRobotDataset` loads from a local folder.
//!
//! **Layout** (LeRobot's `codebase_version` v3.0; every file written by the `parquet` and
//! `arrow` crates):
//!
//! ```text
//! meta/info.json                               features, fps, counts, path templates
//! meta/stats.json                              min, max, mean, std, count, q01..q99 per feature
//! meta/tasks.parquet                           task_index with the task text as pandas index
//! meta/episodes/chunk-000/file-000.parquet     one row per episode: length, frame range, tasks,
//!                                              data file, per-episode stats (stats/<key>/<stat>)
//! data/chunk-000/file-NNN.parquet              one row per frame, one row group per episode
//! ```
//!
//! **Mapping.** One *episode* per object: the poses of one collection, in pose_id order (the
//! plan's grid order). One *frame* per pose. When several sensors' datasets of an object are
//! exported together they were collected together (one press, every sensor captured), so a
//! frame holds one image key per sensor; the export refuses datasets whose poses or measured
//! poses disagree (export them one at a time instead). Every episode must hold the same
//! sensors (LeRobot's features are dataset-wide).
//!
//! | LeRobot feature | dtype, shape | from |
//! |---|---|---|
//! | `observation.state` | float32 `[4]` | the measured pose (x_mm, y_mm, z_mm, yaw_deg, work frame); the commanded pose where no sensor measured one (synthetic rows) |
//! | `action` | float32 `[4]` | the commanded pose (what the plan asked the arm for) |
//! | `observation.images.<sensor>` | image `[H, W, 3]` | the frame's PNG, bytes as in the dataset (other colour types re-encoded as 8-bit RGB) |
//! | `state_measured` | bool `[1]` | true when `observation.state` was measured |
//! | `pose_id` | int64 `[1]` | rig's pose_id |
//! | `source.<sensor>` | string `[1]` | the row's `source`: `real`, `simulated` or `synthetic` |
//! | `timestamp` | float32 `[1]` | `frame_index / fps` (poses are not a time series; `--fps` sets the spacing) |
//! | `frame_index`, `episode_index`, `index`, `task_index` | int64 `[1]` | LeRobot's bookkeeping |
//!
//! Stats are exact (every frame, every pixel), where LeRobot samples images and bins
//! quantiles; image stats are per channel on [0, 1], shaped `[3, 1, 1]` as LeRobot's are.

use std::collections::{BTreeMap, BTreeSet};
use std::fs::File;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use arrow_array::builder::{Float64Builder, Int64Builder, ListBuilder, StringBuilder};
use arrow_array::{
    Array, ArrayRef, BinaryArray, BooleanArray, FixedSizeListArray, Float32Array, Int64Array, RecordBatch, StringArray, StructArray,
};
use arrow_schema::{DataType, Field, Fields, Schema, SchemaRef};
use parquet::arrow::ArrowWriter;
use parquet::file::properties::WriterProperties;
use serde_json::{Value, json};

use super::{DatasetError, Manifest, PoseRow, Source, durable, find_datasets, read_rows};
use crate::pose::Pose;
use crate::sensor::SensorKind;

/// LeRobot's dataset format version written here.
pub const CODEBASE_VERSION: &str = "v3.0";
/// Files per chunk folder (LeRobot's default).
pub const CHUNKS_SIZE: u64 = 1000;
/// A data file is closed at the end of the episode that takes it past this size (LeRobot's
/// default `data_files_size_in_mb`).
pub const DATA_FILE_SIZE_MB: u64 = 100;
/// The quantiles in the stats, as LeRobot names them (`q01` is the 1 % quantile).
pub const QUANTILES: [(&str, f64); 5] = [("q01", 0.01), ("q10", 0.10), ("q50", 0.50), ("q90", 0.90), ("q99", 0.99)];
/// Frames per record batch written (a batch holds their encoded images in memory).
const BATCH_FRAMES: usize = 32;
/// The names of the pose vector's components (`observation.state`, `action`).
pub const POSE_NAMES: [&str; 4] = ["x_mm", "y_mm", "z_mm", "yaw_deg"];
/// Two poses that differ by no more than this (mm or degrees) are the same measurement.
const SAME_POSE: f64 = 1e-9;

/// What the export writes besides the frames.
#[derive(Debug, Clone, PartialEq)]
pub struct LerobotOptions {
    /// `meta/info.json`'s fps; frame `i` of an episode gets `timestamp = i / fps`.
    pub fps: u32,
    /// The task text of every episode; default `press <sensors> against <object>`.
    pub task: Option<String>,
    /// `meta/info.json`'s robot_type; default from the capture chain's arm (`dobot_mg400`,
    /// `dobot_magician`), else `unknown`.
    pub robot_type: Option<String>,
}

impl Default for LerobotOptions {
    fn default() -> Self {
        Self { fps: 1, task: None, robot_type: None }
    }
}

/// What an export wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct LerobotSummary {
    pub episodes: usize,
    pub frames: usize,
    /// The sensors, one image key each.
    pub sensors: Vec<SensorKind>,
    /// Images that were not 8-bit RGB and were re-encoded.
    pub reencoded: usize,
    /// The data files, relative to the output folder.
    pub data_files: Vec<String>,
}

/// Errors of the LeRobot export.
#[derive(Debug, thiserror::Error)]
pub enum LerobotError {
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    #[error("{root} holds no rig dataset (no manifest.toml in it, nor in <object>/<sensor>/ below it)")]
    NoDatasets { root: PathBuf },
    /// The datasets cannot form one LeRobot dataset as they are.
    #[error("cannot export these datasets as one LeRobot dataset: {reason}")]
    Layout { reason: String },
    #[error("{out} exists and is not an empty folder; refusing to overwrite it (give a new --out)")]
    OutNotEmpty { out: PathBuf },
    #[error("{0}")]
    BadOption(String),
    #[error("writing {path}: {reason}")]
    Write { path: PathBuf, reason: String },
}

/// An I/O error as the dataset module reports it (a full disk says what to do).
fn io_err(op: &'static str, path: &Path) -> impl FnOnce(std::io::Error) -> LerobotError {
    let to_dataset = DatasetError::io(op, path);
    move |source| LerobotError::Dataset(to_dataset(source))
}

/// One sensor's dataset of an object.
struct SensorData {
    sensor: SensorKind,
    dir: PathBuf,
    manifest: Manifest,
    rows: BTreeMap<u32, PoseRow>,
}

/// One frame's poses, as the sensors agree on them ([`frame_poses`]).
#[derive(Debug, Clone, Copy)]
struct FramePoses {
    pose_id: u32,
    commanded: Pose,
    /// The measured pose, or the commanded one when no sensor measured it.
    state: Pose,
    measured: bool,
}

/// One object's datasets: one episode.
struct EpisodeData {
    object: String,
    sensors: Vec<SensorData>,
    frames: Vec<FramePoses>,
}

/// Exports every dataset under `root` (a dataset, an object folder `<object>/<sensor>/`, or a
/// folder of objects) into `out` as a LeRobot v3 dataset. `out` must be absent or an empty
/// folder; the export is written to a temporary sibling and renamed into place when complete,
/// so a failed or killed export leaves no partial dataset at `out`.
pub fn export_lerobot(root: &Path, out: &Path, options: &LerobotOptions) -> Result<LerobotSummary, LerobotError> {
    if options.fps == 0 {
        return Err(LerobotError::BadOption("--fps must be at least 1".into()));
    }
    if let Some(task) = &options.task
        && (task.trim().is_empty() || task.contains(['\n', '\r']))
    {
        return Err(LerobotError::BadOption("--task must be one non-empty line".into()));
    }
    check_out(out)?;
    let episodes = load_episodes(root)?;
    let sensors: Vec<SensorKind> = episodes[0].sensors.iter().map(|s| s.sensor).collect();
    let parent = out.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let name = out.file_name().ok_or_else(|| LerobotError::BadOption(format!("--out {} has no folder name", out.display())))?;
    let tmp = parent.join(format!(".{}.partial-{}", name.to_string_lossy(), std::process::id()));
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).map_err(io_err("removing", &tmp))?;
    }
    std::fs::create_dir_all(&tmp).map_err(io_err("creating", &tmp))?;
    let result = write_all(&tmp, &episodes, &sensors, options);
    let summary = match result {
        Ok(s) => s,
        Err(e) => {
            let _ = std::fs::remove_dir_all(&tmp);
            return Err(e);
        }
    };
    if out.exists() {
        // check_out found it empty.
        std::fs::remove_dir(out).map_err(io_err("replacing", out))?;
    }
    std::fs::rename(&tmp, out).map_err(io_err("moving the export to", out))?;
    Ok(summary)
}

/// `out` must be absent, or an empty folder (not a symlink).
fn check_out(out: &Path) -> Result<(), LerobotError> {
    match out.symlink_metadata() {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(io_err("checking", out)(e)),
        Ok(meta) if meta.is_dir() => {
            let mut entries = std::fs::read_dir(out).map_err(io_err("reading", out))?;
            if entries.next().is_some() { Err(LerobotError::OutNotEmpty { out: out.to_path_buf() }) } else { Ok(()) }
        }
        Ok(_) => Err(LerobotError::OutNotEmpty { out: out.to_path_buf() }),
    }
}

/// Reads the datasets under `root`, grouped into episodes by object, and checks that they fit
/// one LeRobot dataset.
fn load_episodes(root: &Path) -> Result<Vec<EpisodeData>, LerobotError> {
    let dirs = find_datasets(root)?;
    if dirs.is_empty() {
        return Err(LerobotError::NoDatasets { root: root.to_path_buf() });
    }
    let mut by_object: BTreeMap<String, Vec<SensorData>> = BTreeMap::new();
    for dir in dirs {
        let manifest = Manifest::load(&dir)?;
        let rows = read_rows(&dir)?.into_iter().map(|r| (r.pose_id, r)).collect();
        let group = by_object.entry(manifest.object.name.clone()).or_default();
        if let Some(other) = group.iter().find(|s| s.sensor == manifest.sensor) {
            return Err(LerobotError::Layout {
                reason: format!(
                    "{} and {} are both {} datasets of object {:?}; export them separately",
                    other.dir.display(),
                    dir.display(),
                    manifest.sensor,
                    manifest.object.name
                ),
            });
        }
        group.push(SensorData { sensor: manifest.sensor, dir, manifest, rows });
    }
    let mut episodes = Vec::new();
    for (object, mut sensors) in by_object {
        sensors.sort_by_key(|s| s.sensor);
        let frames = joint_frames(&object, &sensors)?;
        episodes.push(EpisodeData { object, sensors, frames });
    }
    let first: Vec<SensorKind> = episodes[0].sensors.iter().map(|s| s.sensor).collect();
    for e in &episodes[1..] {
        let these: Vec<SensorKind> = e.sensors.iter().map(|s| s.sensor).collect();
        if these != first {
            return Err(LerobotError::Layout {
                reason: format!(
                    "object {:?} has sensors {} but {:?} has {}: every episode of a LeRobot dataset has the same image keys",
                    episodes[0].object,
                    sensor_list(&first),
                    e.object,
                    sensor_list(&these)
                ),
            });
        }
    }
    Ok(episodes)
}

fn sensor_list(sensors: &[SensorKind]) -> String {
    sensors.iter().map(|s| s.name()).collect::<Vec<_>>().join(", ")
}

/// An object's frames in pose id order: every sensor must have the same pose ids, and agree on
/// each one's poses.
fn joint_frames(object: &str, sensors: &[SensorData]) -> Result<Vec<FramePoses>, LerobotError> {
    let first = &sensors[0];
    let ids: BTreeSet<u32> = first.rows.keys().copied().collect();
    if ids.is_empty() {
        return Err(LerobotError::Layout { reason: format!("{} has no rows", first.dir.display()) });
    }
    for other in &sensors[1..] {
        let theirs: BTreeSet<u32> = other.rows.keys().copied().collect();
        if theirs != ids {
            let only = |a: &BTreeSet<u32>, b: &BTreeSet<u32>| a.difference(b).take(5).map(u32::to_string).collect::<Vec<_>>().join(", ");
            return Err(LerobotError::Layout {
                reason: format!(
                    "object {object:?}: {} has {} poses and {} has {} (only in the first: [{}], only in the second: [{}]); \
                     a frame needs every sensor's image: fill the missing poses (`rig synth --fill-missing`) or export the sensors separately",
                    first.dir.display(),
                    ids.len(),
                    other.dir.display(),
                    theirs.len(),
                    only(&ids, &theirs),
                    only(&theirs, &ids)
                ),
            });
        }
    }
    ids.into_iter().map(|id| frame_poses(object, sensors, id)).collect()
}

/// A frame's commanded pose and its state (measured pose, or the commanded one when no sensor
/// measured it) with whether it was measured. The sensors must agree on both.
fn frame_poses(object: &str, sensors: &[SensorData], pose_id: u32) -> Result<FramePoses, LerobotError> {
    fn row<'a>(object: &str, s: &'a SensorData, pose_id: u32) -> Result<&'a PoseRow, LerobotError> {
        s.rows
            .get(&pose_id)
            .ok_or_else(|| LerobotError::Layout { reason: format!("object {object:?}: {} has no pose {pose_id}", s.dir.display()) })
    }
    let first = row(object, &sensors[0], pose_id)?;
    let commanded = first.commanded();
    let mut measured: Option<(Pose, &SensorData)> = None;
    for s in sensors {
        let r = row(object, s, pose_id)?;
        if !same_pose(r.commanded(), commanded) {
            return Err(LerobotError::Layout {
                reason: format!(
                    "object {object:?} pose {pose_id}: {} and {} command different poses; they are not one collection, export them separately",
                    sensors[0].dir.display(),
                    s.dir.display()
                ),
            });
        }
        if let Some(m) = r.measured() {
            match &measured {
                Some((seen, by)) if !same_pose(*seen, m) => {
                    return Err(LerobotError::Layout {
                        reason: format!(
                            "object {object:?} pose {pose_id}: {} and {} measured different poses, so they were not captured at one press; export them separately",
                            by.dir.display(),
                            s.dir.display()
                        ),
                    });
                }
                Some(_) => {}
                None => measured = Some((m, s)),
            }
        }
    }
    Ok(match measured {
        Some((m, _)) => FramePoses { pose_id, commanded, state: m, measured: true },
        None => FramePoses { pose_id, commanded, state: commanded, measured: false },
    })
}

fn same_pose(a: Pose, b: Pose) -> bool {
    (a.x_mm - b.x_mm).abs() <= SAME_POSE
        && (a.y_mm - b.y_mm).abs() <= SAME_POSE
        && (a.z_mm - b.z_mm).abs() <= SAME_POSE
        && (a.yaw_deg - b.yaw_deg).abs() <= SAME_POSE
}

fn pose_vec(p: Pose) -> [f64; 4] {
    [p.x_mm, p.y_mm, p.z_mm, p.yaw_deg]
}

/// The feature key of a sensor's images.
pub fn image_key(sensor: SensorKind) -> String {
    format!("observation.images.{}", sensor.name())
}

/// The feature key of a sensor's `source` column.
pub fn source_key(sensor: SensorKind) -> String {
    format!("source.{}", sensor.name())
}

/// Exact statistics of a vector feature over a set of frames.
#[derive(Debug, Clone, Default)]
struct VecStats {
    /// Values by component.
    dims: Vec<Vec<f64>>,
}

impl VecStats {
    fn new(dims: usize) -> Self {
        Self { dims: vec![Vec::new(); dims] }
    }
    fn push(&mut self, values: &[f64]) {
        for (d, v) in self.dims.iter_mut().zip(values) {
            d.push(*v);
        }
    }
    fn count(&self) -> usize {
        self.dims.first().map_or(0, Vec::len)
    }
    /// `stat -> per-component values`, LeRobot's names.
    fn table(&self) -> Vec<(String, Vec<f64>)> {
        let mut sorted = self.dims.clone();
        for d in &mut sorted {
            d.sort_by(f64::total_cmp);
        }
        let per = |f: &dyn Fn(&[f64]) -> f64| sorted.iter().map(|d| f(d)).collect::<Vec<f64>>();
        let mut out = vec![
            ("min".to_string(), per(&|d| d.first().copied().unwrap_or(0.0))),
            ("max".to_string(), per(&|d| d.last().copied().unwrap_or(0.0))),
            ("mean".to_string(), per(&|d| mean_std(d).0)),
            ("std".to_string(), per(&|d| mean_std(d).1)),
        ];
        for (name, q) in QUANTILES {
            out.push((name.to_string(), per(&|d| quantile_sorted(d, q))));
        }
        out
    }
}

/// Mean and population standard deviation (numpy's default, ddof = 0).
fn mean_std(values: &[f64]) -> (f64, f64) {
    if values.is_empty() {
        return (0.0, 0.0);
    }
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let var = values.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / n;
    (mean, var.sqrt())
}

/// The `q` quantile of sorted values, numpy's default (linear) method.
fn quantile_sorted(sorted: &[f64], q: f64) -> f64 {
    let Some(last) = sorted.len().checked_sub(1) else { return 0.0 };
    let pos = q * last as f64;
    let lo = pos.floor() as usize;
    let hi = (lo + 1).min(last);
    let frac = pos - lo as f64;
    sorted[lo] + (sorted[hi] - sorted[lo]) * frac
}

/// Exact per-channel statistics of 8-bit RGB images (a histogram per channel).
#[derive(Debug, Clone)]
struct ImageStats {
    hist: [[u64; 256]; 3],
    images: u64,
}

impl Default for ImageStats {
    fn default() -> Self {
        Self { hist: [[0; 256]; 3], images: 0 }
    }
}

impl ImageStats {
    fn push(&mut self, image: &image::RgbImage) {
        for px in image.pixels() {
            for c in 0..3 {
                self.hist[c][usize::from(px.0[c])] += 1;
            }
        }
        self.images += 1;
    }
    fn merge(&mut self, other: &ImageStats) {
        for c in 0..3 {
            for v in 0..256 {
                self.hist[c][v] += other.hist[c][v];
            }
        }
        self.images += other.images;
    }
    /// `stat -> per-channel value` on [0, 1].
    fn table(&self) -> Vec<(String, Vec<f64>)> {
        let per = |f: &dyn Fn(&[u64; 256]) -> f64| self.hist.iter().map(|h| f(h) / 255.0).collect::<Vec<f64>>();
        let mut out = vec![
            ("min".to_string(), per(&|h| h.iter().position(|&n| n > 0).unwrap_or(0) as f64)),
            ("max".to_string(), per(&|h| h.iter().rposition(|&n| n > 0).unwrap_or(0) as f64)),
            ("mean".to_string(), per(&|h| hist_mean_std(h).0)),
            ("std".to_string(), per(&|h| hist_mean_std(h).1)),
        ];
        for (name, q) in QUANTILES {
            out.push((name.to_string(), per(&|h| hist_quantile(h, q))));
        }
        out
    }
}

fn hist_mean_std(h: &[u64; 256]) -> (f64, f64) {
    let n: u64 = h.iter().sum();
    if n == 0 {
        return (0.0, 0.0);
    }
    let mean = h.iter().enumerate().map(|(v, &c)| v as f64 * c as f64).sum::<f64>() / n as f64;
    let var = h.iter().enumerate().map(|(v, &c)| (v as f64 - mean).powi(2) * c as f64).sum::<f64>() / n as f64;
    (mean, var.sqrt())
}

/// The value at 0-based rank `k` of the histogram's sorted values.
fn hist_rank(h: &[u64; 256], k: u64) -> f64 {
    let mut seen = 0u64;
    for (v, &c) in h.iter().enumerate() {
        seen += c;
        if seen > k {
            return v as f64;
        }
    }
    255.0
}

/// The `q` quantile of the histogram's values, numpy's linear method (as on the sorted pixels).
fn hist_quantile(h: &[u64; 256], q: f64) -> f64 {
    let n: u64 = h.iter().sum();
    let Some(last) = n.checked_sub(1) else { return 0.0 };
    let pos = q * last as f64;
    let lo = pos.floor() as u64;
    let hi = (lo + 1).min(last);
    let (a, b) = (hist_rank(h, lo), hist_rank(h, hi));
    a + (b - a) * (pos - lo as f64)
}

/// Statistics of every numeric and image feature over some frames.
#[derive(Debug, Clone)]
struct Stats {
    vectors: BTreeMap<String, VecStats>,
    images: BTreeMap<String, ImageStats>,
}

impl Stats {
    fn new(sensors: &[SensorKind]) -> Self {
        let mut vectors = BTreeMap::new();
        for key in ["observation.state", "action"] {
            vectors.insert(key.to_string(), VecStats::new(4));
        }
        for key in ["pose_id", "timestamp", "frame_index", "episode_index", "index", "task_index"] {
            vectors.insert(key.to_string(), VecStats::new(1));
        }
        let images = sensors.iter().map(|&s| (image_key(s), ImageStats::default())).collect();
        Self { vectors, images }
    }
    fn push(&mut self, key: &str, values: &[f64]) {
        if let Some(v) = self.vectors.get_mut(key) {
            v.push(values);
        }
    }
    fn extend(&mut self, other: &Stats) {
        for (k, v) in &other.vectors {
            if let Some(mine) = self.vectors.get_mut(k) {
                for (a, b) in mine.dims.iter_mut().zip(&v.dims) {
                    a.extend_from_slice(b);
                }
            }
        }
        for (k, v) in &other.images {
            self.images.entry(k.clone()).or_default().merge(v);
        }
    }
    /// `feature -> stat -> value` as `meta/stats.json` holds it: vectors as lists, image stats
    /// as [3][1][1], `count` as a one-element list.
    fn json(&self) -> Value {
        let mut out = serde_json::Map::new();
        for (k, v) in &self.vectors {
            let mut m = serde_json::Map::new();
            for (stat, values) in v.table() {
                m.insert(stat, json!(values));
            }
            m.insert("count".into(), json!([v.count()]));
            out.insert(k.clone(), Value::Object(m));
        }
        for (k, v) in &self.images {
            let mut m = serde_json::Map::new();
            for (stat, values) in v.table() {
                m.insert(stat, json!(values.iter().map(|x| vec![vec![*x]]).collect::<Vec<_>>()));
            }
            m.insert("count".into(), json!([v.images]));
            out.insert(k.clone(), Value::Object(m));
        }
        Value::Object(out)
    }
}

/// The data files' arrow schema, in `meta/info.json`'s feature order.
fn data_schema(sensors: &[SensorKind]) -> SchemaRef {
    let pose = DataType::FixedSizeList(Arc::new(Field::new("item", DataType::Float32, true)), 4);
    let mut fields = vec![Field::new("observation.state", pose.clone(), true), Field::new("action", pose, true)];
    for &s in sensors {
        fields.push(Field::new(image_key(s), DataType::Struct(image_fields()), true));
    }
    fields.push(Field::new("state_measured", DataType::Boolean, true));
    fields.push(Field::new("pose_id", DataType::Int64, true));
    for &s in sensors {
        fields.push(Field::new(source_key(s), DataType::Utf8, true));
    }
    fields.push(Field::new("timestamp", DataType::Float32, true));
    for k in ["frame_index", "episode_index", "index", "task_index"] {
        fields.push(Field::new(k, DataType::Int64, true));
    }
    Arc::new(Schema::new(fields))
}

/// Hugging Face `datasets`' image struct.
fn image_fields() -> Fields {
    Fields::from(vec![Field::new("bytes", DataType::Binary, true), Field::new("path", DataType::Utf8, true)])
}

/// `meta/info.json`'s `features`, in the data files' column order.
fn features_json(sensors: &[SensorKind], image_shapes: &BTreeMap<SensorKind, [u32; 2]>) -> Value {
    let mut f = serde_json::Map::new();
    let scalar = |dtype: &str| json!({"dtype": dtype, "shape": [1], "names": null});
    f.insert("observation.state".into(), json!({"dtype": "float32", "shape": [4], "names": POSE_NAMES}));
    f.insert("action".into(), json!({"dtype": "float32", "shape": [4], "names": POSE_NAMES}));
    for s in sensors {
        let [w, h] = image_shapes.get(s).copied().unwrap_or([0, 0]);
        f.insert(image_key(*s), json!({"dtype": "image", "shape": [h, w, 3], "names": ["height", "width", "channels"]}));
    }
    f.insert("state_measured".into(), scalar("bool"));
    f.insert("pose_id".into(), scalar("int64"));
    for s in sensors {
        f.insert(source_key(*s), scalar("string"));
    }
    f.insert("timestamp".into(), scalar("float32"));
    for k in ["frame_index", "episode_index", "index", "task_index"] {
        f.insert(k.into(), scalar("int64"));
    }
    Value::Object(f)
}

/// One frame as it goes into a record batch.
struct FrameOut {
    state: [f64; 4],
    action: [f64; 4],
    measured: bool,
    pose_id: u32,
    images: Vec<(Vec<u8>, String)>,
    sources: Vec<Source>,
    frame_index: u64,
    episode_index: u64,
    index: u64,
    task_index: u64,
    fps: u32,
}

fn batch_of(schema: &SchemaRef, frames: &[FrameOut], sensors: usize) -> Result<RecordBatch, String> {
    let poses = |f: &dyn Fn(&FrameOut) -> [f64; 4]| -> Result<ArrayRef, String> {
        let values: Vec<f32> = frames.iter().flat_map(|fr| f(fr).map(|v| v as f32)).collect();
        let item = Arc::new(Field::new("item", DataType::Float32, true));
        FixedSizeListArray::try_new(item, 4, Arc::new(Float32Array::from(values)), None)
            .map(|a| Arc::new(a) as ArrayRef)
            .map_err(|e| e.to_string())
    };
    let mut columns: Vec<ArrayRef> = vec![poses(&|f| f.state)?, poses(&|f| f.action)?];
    for s in 0..sensors {
        let bytes = BinaryArray::from_iter_values(frames.iter().map(|f| f.images[s].0.as_slice()));
        let paths = StringArray::from_iter_values(frames.iter().map(|f| f.images[s].1.as_str()));
        let image =
            StructArray::try_new(image_fields(), vec![Arc::new(bytes) as ArrayRef, Arc::new(paths)], None).map_err(|e| e.to_string())?;
        columns.push(Arc::new(image));
    }
    columns.push(Arc::new(BooleanArray::from(frames.iter().map(|f| f.measured).collect::<Vec<_>>())));
    columns.push(Arc::new(Int64Array::from(frames.iter().map(|f| i64::from(f.pose_id)).collect::<Vec<_>>())));
    for s in 0..sensors {
        columns.push(Arc::new(StringArray::from_iter_values(frames.iter().map(|f| f.sources[s].to_string()))));
    }
    columns.push(Arc::new(Float32Array::from(frames.iter().map(|f| timestamp(f.frame_index, f.fps)).collect::<Vec<_>>())));
    let int = |g: &dyn Fn(&FrameOut) -> u64| -> ArrayRef {
        Arc::new(Int64Array::from(frames.iter().map(|f| i64::try_from(g(f)).unwrap_or(i64::MAX)).collect::<Vec<_>>()))
    };
    columns.push(int(&|f| f.frame_index));
    columns.push(int(&|f| f.episode_index));
    columns.push(int(&|f| f.index));
    columns.push(int(&|f| f.task_index));
    RecordBatch::try_new(schema.clone(), columns).map_err(|e| e.to_string())
}

/// A frame's timestamp, s.
fn timestamp(frame_index: u64, fps: u32) -> f32 {
    (frame_index as f64 / f64::from(fps)) as f32
}

/// A parquet file being written, with the path its errors name.
struct ParquetOut {
    path: PathBuf,
    writer: ArrowWriter<File>,
}

impl ParquetOut {
    fn create(path: &Path, schema: SchemaRef) -> Result<Self, LerobotError> {
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir).map_err(io_err("creating", dir))?;
        }
        let file = File::create(path).map_err(io_err("creating", path))?;
        let props = WriterProperties::builder().set_max_row_group_row_count(Some(1 << 20)).build();
        let writer = ArrowWriter::try_new(file, schema, Some(props)).map_err(|e| write_err(path, e))?;
        Ok(Self { path: path.to_path_buf(), writer })
    }
    fn write(&mut self, batch: &RecordBatch) -> Result<(), LerobotError> {
        self.writer.write(batch).map_err(|e| write_err(&self.path, e))
    }
    /// Ends the current row group.
    fn flush(&mut self) -> Result<(), LerobotError> {
        self.writer.flush().map_err(|e| write_err(&self.path, e))
    }
    fn close(self) -> Result<(), LerobotError> {
        let file = self.writer.into_inner().map_err(|e| write_err(&self.path, e))?;
        file.sync_all().map_err(io_err("syncing", &self.path))
    }
}

fn write_err(path: &Path, e: impl std::fmt::Display) -> LerobotError {
    LerobotError::Write { path: path.to_path_buf(), reason: e.to_string() }
}

fn chunk_file(kind: &str, file_index: u64) -> String {
    format!("{kind}/chunk-{:03}/file-{:03}.parquet", file_index / CHUNKS_SIZE, file_index % CHUNKS_SIZE)
}

/// Where an episode's rows went.
struct EpisodeOut {
    index: u64,
    object: String,
    task_index: u64,
    length: u64,
    from: u64,
    data_file: u64,
    stats: Stats,
}

/// Reads a frame's PNG (a regular file, bounded), checks its size against the sensor's other
/// frames (`expected`), and returns the bytes to store (re-encoded when not 8-bit RGB) and the
/// decoded image for the stats.
fn frame_image(
    pose_id: u32,
    dir: &Path,
    image: &str,
    expected: Option<[u32; 2]>,
    reencoded: &mut usize,
) -> Result<(Vec<u8>, image::RgbImage), LerobotError> {
    let path = &dir.join(image);
    // Through the opener: a symlinked `images/` (or image) is refused, not read.
    let bytes = match durable::read_below(dir, Path::new(image), durable::MAX_IMAGE_BYTES) {
        Err(DatasetError::Confined(crate::confine::ConfineError::Missing { .. })) => {
            return Err(DatasetError::MissingImage { pose_id, path: path.to_path_buf() }.into());
        }
        other => other?,
    };
    let decoded = durable::decode_image(&bytes).map_err(|reason| DatasetError::BadImage { path: path.to_path_buf(), reason })?;
    let size = [decoded.width(), decoded.height()];
    match expected {
        Some(e) if e != size => {
            return Err(LerobotError::Layout {
                reason: format!(
                    "{} is {}x{} px but the sensor's other frames are {}x{}: an image feature has one shape",
                    path.display(),
                    size[0],
                    size[1],
                    e[0],
                    e[1]
                ),
            });
        }
        _ => {}
    }
    if let image::DynamicImage::ImageRgb8(rgb) = decoded {
        return Ok((bytes, rgb));
    }
    let rgb = decoded.to_rgb8();
    let mut png = Vec::new();
    rgb.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .map_err(|e| DatasetError::BadImage { path: path.to_path_buf(), reason: format!("re-encoding as RGB: {e}") })?;
    *reencoded += 1;
    Ok((png, rgb))
}

fn default_task(object: &str, sensors: &[SensorKind]) -> String {
    let names: Vec<&str> = sensors.iter().map(|s| s.label()).collect();
    format!("press the {} sensor{} against the {object}", names.join(", "), if names.len() > 1 { "s" } else { "" })
}

fn robot_type(episodes: &[EpisodeData], options: &LerobotOptions) -> String {
    if let Some(r) = &options.robot_type {
        return r.clone();
    }
    let backend = episodes.iter().flat_map(|e| &e.sensors).find_map(|s| s.manifest.capture.as_ref().map(|c| c.arm.backend.clone()));
    match backend.as_deref() {
        Some("mg400" | "sim-mg400") => "dobot_mg400".into(),
        Some("magician") => "dobot_magician".into(),
        _ => "unknown".into(),
    }
}

fn write_all(
    tmp: &Path,
    episodes: &[EpisodeData],
    sensors: &[SensorKind],
    options: &LerobotOptions,
) -> Result<LerobotSummary, LerobotError> {
    let schema = data_schema(sensors);
    let mut tasks: Vec<String> = Vec::new();
    let mut image_shapes: BTreeMap<SensorKind, [u32; 2]> = BTreeMap::new();
    let mut reencoded = 0usize;
    let mut outs: Vec<EpisodeOut> = Vec::new();
    let mut data_file = 0u64;
    let mut writer: Option<ParquetOut> = None;
    let mut index = 0u64;
    let mut data_files = Vec::new();
    for (e, episode) in episodes.iter().enumerate() {
        let task = options.task.clone().unwrap_or_else(|| default_task(&episode.object, sensors));
        let task_index = match tasks.iter().position(|t| *t == task) {
            Some(i) => i,
            None => {
                tasks.push(task);
                tasks.len() - 1
            }
        } as u64;
        if writer.is_none() {
            let rel = chunk_file("data", data_file);
            writer = Some(ParquetOut::create(&tmp.join(&rel), schema.clone())?);
            data_files.push(rel);
        }
        let w = writer.as_mut().ok_or_else(|| write_err(tmp, "no data file open"))?;
        let mut stats = Stats::new(sensors);
        let from = index;
        let mut batch: Vec<FrameOut> = Vec::with_capacity(BATCH_FRAMES);
        for (i, frame) in episode.frames.iter().enumerate() {
            let FramePoses { pose_id, commanded, state, measured } = *frame;
            let mut images = Vec::with_capacity(sensors.len());
            let mut sources = Vec::with_capacity(sensors.len());
            for s in &episode.sensors {
                let row = s.rows.get(&pose_id).ok_or_else(|| LerobotError::Layout {
                    reason: format!("object {:?}: {} has no pose {pose_id}", episode.object, s.dir.display()),
                })?;
                let (bytes, rgb) = frame_image(pose_id, &s.dir, &row.image, image_shapes.get(&s.sensor).copied(), &mut reencoded)?;
                image_shapes.insert(s.sensor, [rgb.width(), rgb.height()]);
                if let Some(h) = stats.images.get_mut(&image_key(s.sensor)) {
                    h.push(&rgb);
                }
                images.push((bytes, format!("{}/{}/{}", episode.object, s.sensor.name(), row.image)));
                sources.push(row.source);
            }
            let frame_index = i as u64;
            let fr = FrameOut {
                state: pose_vec(state),
                action: pose_vec(commanded),
                measured,
                pose_id,
                images,
                sources,
                frame_index,
                episode_index: e as u64,
                index,
                task_index,
                fps: options.fps,
            };
            // The stats are of the values stored (float32), as a reader computes them.
            stats.push("observation.state", &fr.state.map(|v| f64::from(v as f32)));
            stats.push("action", &fr.action.map(|v| f64::from(v as f32)));
            stats.push("pose_id", &[f64::from(pose_id)]);
            stats.push("timestamp", &[f64::from(timestamp(frame_index, options.fps))]);
            stats.push("frame_index", &[frame_index as f64]);
            stats.push("episode_index", &[e as f64]);
            stats.push("index", &[index as f64]);
            stats.push("task_index", &[task_index as f64]);
            batch.push(fr);
            index += 1;
            if batch.len() == BATCH_FRAMES {
                w.write(&batch_of(&schema, &batch, sensors.len()).map_err(|r| write_err(&w.path, r))?)?;
                batch.clear();
            }
        }
        if !batch.is_empty() {
            w.write(&batch_of(&schema, &batch, sensors.len()).map_err(|r| write_err(&w.path, r))?)?;
        }
        w.flush()?;
        outs.push(EpisodeOut { index: e as u64, object: episode.object.clone(), task_index, length: index - from, from, data_file, stats });
        let size = std::fs::metadata(&w.path).map(|m| m.len()).unwrap_or(0);
        if size >= DATA_FILE_SIZE_MB << 20
            && let Some(w) = writer.take()
        {
            w.close()?;
            data_file += 1;
        }
    }
    if let Some(w) = writer.take() {
        w.close()?;
    }
    write_episodes(tmp, &outs, &tasks)?;
    write_tasks(tmp, &tasks)?;
    let mut all = Stats::new(sensors);
    for o in &outs {
        all.extend(&o.stats);
    }
    write_json(&tmp.join("meta"), "stats.json", &all.json())?;
    let total_frames = index;
    let info = json!({
        "codebase_version": CODEBASE_VERSION,
        "robot_type": robot_type(episodes, options),
        "total_episodes": outs.len(),
        "total_frames": total_frames,
        "total_tasks": tasks.len(),
        "chunks_size": CHUNKS_SIZE,
        "data_files_size_in_mb": DATA_FILE_SIZE_MB,
        "video_files_size_in_mb": 200,
        "fps": options.fps,
        "splits": {"train": format!("0:{}", outs.len())},
        "data_path": "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet",
        "video_path": null,
        "features": features_json(sensors, &image_shapes),
    });
    write_json(&tmp.join("meta"), "info.json", &info)?;
    Ok(LerobotSummary {
        episodes: outs.len(),
        frames: usize::try_from(total_frames).unwrap_or(usize::MAX),
        sensors: sensors.to_vec(),
        reencoded,
        data_files,
    })
}

/// `dir/name` as pretty JSON, written atomically and durably ([`durable::write_atomic`]).
fn write_json(dir: &Path, name: &str, value: &Value) -> Result<(), LerobotError> {
    std::fs::create_dir_all(dir).map_err(io_err("creating", dir))?;
    let text = serde_json::to_string_pretty(value).map_err(|e| write_err(&dir.join(name), e))? + "\n";
    Ok(durable::write_atomic(dir, name, text.as_bytes())?)
}

/// `meta/tasks.parquet`: `task_index` with the task text as the pandas index (LeRobot reads it
/// with `pandas.read_parquet` and takes a frame's task from the index).
fn write_tasks(tmp: &Path, tasks: &[String]) -> Result<(), LerobotError> {
    let pandas = json!({
        "index_columns": ["task"],
        "column_indexes": [{"name": null, "field_name": null, "pandas_type": "unicode", "numpy_type": "object", "metadata": {"encoding": "UTF-8"}}],
        "columns": [
            {"name": "task_index", "field_name": "task_index", "pandas_type": "int64", "numpy_type": "int64", "metadata": null},
            {"name": "task", "field_name": "task", "pandas_type": "unicode", "numpy_type": "object", "metadata": null},
        ],
        "creator": {"library": "rig", "version": crate::version()},
        "pandas_version": "2.2.3",
    });
    // pyarrow takes a file's schema metadata from its embedded arrow schema when there is one.
    let schema = Arc::new(Schema::new_with_metadata(
        vec![Field::new("task_index", DataType::Int64, true), Field::new("task", DataType::Utf8, true)],
        std::collections::HashMap::from([("pandas".to_string(), pandas.to_string())]),
    ));
    let path = tmp.join("meta/tasks.parquet");
    let batch = RecordBatch::try_new(
        schema.clone(),
        vec![Arc::new(Int64Array::from_iter_values(0..tasks.len() as i64)), Arc::new(StringArray::from_iter_values(tasks))],
    )
    .map_err(|e| write_err(&path, e))?;
    let mut out = ParquetOut::create(&path, schema)?;
    out.write(&batch)?;
    out.close()
}

/// Named arrow columns being gathered for one record batch.
#[derive(Default)]
struct Columns {
    fields: Vec<Field>,
    arrays: Vec<ArrayRef>,
}

impl Columns {
    fn push(&mut self, name: impl Into<String>, array: ArrayRef) {
        self.fields.push(Field::new(name, array.data_type().clone(), true));
        self.arrays.push(array);
    }
    fn push_ints(&mut self, name: &str, values: impl Iterator<Item = u64>) {
        self.push(name, Arc::new(Int64Array::from_iter_values(values.map(|v| i64::try_from(v).unwrap_or(i64::MAX)))));
    }
    /// `stats/<key>/<stat>` for every stat of `tables` (one table per episode, as lists;
    /// image stats nested [3][1][1] as LeRobot shapes them) and `stats/<key>/count`.
    fn push_stats(&mut self, key: &str, tables: &[Vec<(String, Vec<f64>)>], counts: &[u64], image: bool) {
        let Some(first) = tables.first() else { return };
        for (s, (stat, _)) in first.iter().enumerate() {
            let values = |t: &Vec<(String, Vec<f64>)>| t.get(s).map(|(_, v)| v.clone()).unwrap_or_default();
            let column: ArrayRef = if image {
                let mut b = ListBuilder::new(ListBuilder::new(ListBuilder::new(Float64Builder::new())));
                for t in tables {
                    for v in values(t) {
                        b.values().values().values().append_value(v);
                        b.values().values().append(true);
                        b.values().append(true);
                    }
                    b.append(true);
                }
                Arc::new(b.finish())
            } else {
                let mut b = ListBuilder::new(Float64Builder::new());
                for t in tables {
                    b.values().append_slice(&values(t));
                    b.append(true);
                }
                Arc::new(b.finish())
            };
            self.push(format!("stats/{key}/{stat}"), column);
        }
        let mut b = ListBuilder::new(Int64Builder::new());
        for &n in counts {
            b.values().append_value(i64::try_from(n).unwrap_or(i64::MAX));
            b.append(true);
        }
        self.push(format!("stats/{key}/count"), Arc::new(b.finish()));
    }
}

/// `meta/episodes/chunk-000/file-000.parquet`: one row per episode, with its per-episode stats
/// as `stats/<feature>/<stat>` columns.
fn write_episodes(tmp: &Path, outs: &[EpisodeOut], tasks: &[String]) -> Result<(), LerobotError> {
    let path = tmp.join(chunk_file("meta/episodes", 0));
    let mut cols = Columns::default();
    cols.push_ints("episode_index", outs.iter().map(|o| o.index));
    let mut task_lists = ListBuilder::new(StringBuilder::new());
    for o in outs {
        let task = usize::try_from(o.task_index).ok().and_then(|i| tasks.get(i)).map_or("", String::as_str);
        task_lists.values().append_value(task);
        task_lists.append(true);
    }
    cols.push("tasks", Arc::new(task_lists.finish()));
    cols.push_ints("length", outs.iter().map(|o| o.length));
    cols.push_ints("data/chunk_index", outs.iter().map(|o| o.data_file / CHUNKS_SIZE));
    cols.push_ints("data/file_index", outs.iter().map(|o| o.data_file % CHUNKS_SIZE));
    cols.push_ints("dataset_from_index", outs.iter().map(|o| o.from));
    cols.push_ints("dataset_to_index", outs.iter().map(|o| o.from + o.length));
    cols.push_ints("meta/episodes/chunk_index", outs.iter().map(|_| 0));
    cols.push_ints("meta/episodes/file_index", outs.iter().map(|_| 0));
    cols.push("rig/object", Arc::new(StringArray::from_iter_values(outs.iter().map(|o| o.object.as_str()))));
    if let Some(first) = outs.first() {
        for key in first.stats.vectors.keys() {
            let stats: Vec<Option<&VecStats>> = outs.iter().map(|o| o.stats.vectors.get(key)).collect();
            let tables: Vec<_> = stats.iter().map(|v| v.map(VecStats::table).unwrap_or_default()).collect();
            let counts: Vec<u64> = stats.iter().map(|v| v.map_or(0, |v| v.count() as u64)).collect();
            cols.push_stats(key, &tables, &counts, false);
        }
        for key in first.stats.images.keys() {
            let stats: Vec<Option<&ImageStats>> = outs.iter().map(|o| o.stats.images.get(key)).collect();
            let tables: Vec<_> = stats.iter().map(|v| v.map(ImageStats::table).unwrap_or_default()).collect();
            let counts: Vec<u64> = stats.iter().map(|v| v.map_or(0, |v| v.images)).collect();
            cols.push_stats(key, &tables, &counts, true);
        }
    }
    let schema = Arc::new(Schema::new(cols.fields));
    let batch = RecordBatch::try_new(schema.clone(), cols.arrays).map_err(|e| write_err(&path, e))?;
    let mut out = ParquetOut::create(&path, schema)?;
    out.write(&batch)?;
    out.close()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_follow_numpys_linear_method() {
        let v = [1.0, 2.0, 3.0, 4.0, 10.0];
        // numpy.quantile([1, 2, 3, 4, 10], [0.01, 0.5, 0.9, 0.99]) = 1.04, 3.0, 7.6, 9.76
        assert!((quantile_sorted(&v, 0.01) - 1.04).abs() < 1e-12);
        assert_eq!(quantile_sorted(&v, 0.5), 3.0);
        assert!((quantile_sorted(&v, 0.9) - 7.6).abs() < 1e-12);
        assert!((quantile_sorted(&v, 0.99) - 9.76).abs() < 1e-12);
        assert_eq!(quantile_sorted(&[], 0.5), 0.0);
    }

    #[test]
    fn histogram_stats_equal_the_stats_of_the_pixels() {
        let values: Vec<u8> = vec![0, 3, 3, 7, 200, 255, 17, 17, 17, 90];
        let mut h = [0u64; 256];
        for &v in &values {
            h[usize::from(v)] += 1;
        }
        let mut sorted: Vec<f64> = values.iter().map(|&v| f64::from(v)).collect();
        sorted.sort_by(f64::total_cmp);
        for (_, q) in QUANTILES {
            assert!((hist_quantile(&h, q) - quantile_sorted(&sorted, q)).abs() < 1e-9, "q {q}");
        }
        let (m, s) = mean_std(&sorted);
        let (hm, hs) = hist_mean_std(&h);
        assert!((m - hm).abs() < 1e-9 && (s - hs).abs() < 1e-9);
    }

    #[test]
    fn image_stats_are_per_channel_on_the_unit_interval() {
        let mut img = image::RgbImage::new(2, 1);
        img.put_pixel(0, 0, image::Rgb([0, 255, 51]));
        img.put_pixel(1, 0, image::Rgb([255, 255, 153]));
        let mut st = ImageStats::default();
        st.push(&img);
        let t: BTreeMap<String, Vec<f64>> = st.table().into_iter().collect();
        assert_eq!(t["min"], vec![0.0, 1.0, 0.2]);
        assert_eq!(t["max"], vec![1.0, 1.0, 0.6]);
        assert!((t["mean"][0] - 0.5).abs() < 1e-12 && (t["mean"][2] - 0.4).abs() < 1e-12);
        assert!((t["std"][0] - 0.5).abs() < 1e-12 && t["std"][1] == 0.0);
    }
}
