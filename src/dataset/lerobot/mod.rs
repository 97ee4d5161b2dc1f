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
//! meta/episodes/chunk-CCC/file-FFF.parquet     one row per episode: length, frame range, tasks,
//!                                              data file, per-episode stats (stats/<key>/<stat>)
//! data/chunk-CCC/file-FFF.parquet              one row per frame
//! ```
//!
//! **Mapping.** One *frame* per pose. An *episode* is a run of one object's poses in pose_id
//! order (the plan's grid order): a new episode starts at each object and wherever the data
//! file in progress is full, so that every episode lies in one data file, as LeRobot's
//! loader expects. When several sensors' datasets of an object are exported together they
//! were collected together (one press, every sensor captured), so a frame holds one image key
//! per sensor; the export refuses datasets whose poses or measured poses disagree (export them
//! one at a time instead). Every episode must hold the same sensors (LeRobot's features are
//! dataset-wide).
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
//! **Streaming.** Frames are written one at a time: a frame's images are read, decoded for the
//! stats and the shape check, written as a one-row batch, and dropped. The parquet writer holds
//! at most one row group (at most [`ROW_GROUP_BYTES`]) before it reaches the file, and a data
//! file is closed before the next frame would take it past the size bound (`--max-file-mb`,
//! LeRobot's `data_files_size_in_mb`, 100 by default, counted in 10^6 bytes so that a file is
//! under the bound in LeRobot's MiB too). meta/episodes rolls the same way. So memory depends on
//! the frame in flight and the row group, not on the number of frames; what grows with them is
//! one small record per pose (its poses and sources, a few dozen bytes).
//!
//! **Stats** are exact (every frame, every pixel), where LeRobot samples images and bins
//! quantiles; image stats are per channel on [0, 1], shaped `[3, 1, 1]` as LeRobot's are, from
//! a 256-bin histogram per channel (exact for 8-bit pixels, and constant in size). Vector stats
//! are computed at the end of each episode, and for the whole dataset at the end, from the
//! per-pose records already held, one feature at a time.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use arrow_array::builder::{Float64Builder, Int64Builder, ListBuilder, StringBuilder};
use arrow_array::{
    Array, ArrayRef, BinaryArray, BooleanArray, FixedSizeListArray, Float32Array, Int64Array, RecordBatch, StringArray, StructArray,
};
use arrow_schema::{DataType, Field, Fields, Schema, SchemaRef};
use parquet::file::properties::{EnabledStatistics, WriterProperties};
use parquet::schema::types::ColumnPath;
use serde_json::{Value, json};

use super::{DatasetError, Manifest, Source, durable, find_datasets, image_rel_path, read_rows};
use crate::pose::Pose;
use crate::sensor::SensorKind;

mod error;
mod rolling;
mod stats;

pub use error::LerobotError;
pub use rolling::{CHUNKS_SIZE, chunk_file};
pub use stats::QUANTILES;

use error::{io_err, write_err};
use rolling::{ParquetOut, RollingFiles};
use stats::{FeatureStats, ImageStats, StatsByFeature, VecStats, stats_json};

/// LeRobot's dataset format version written here.
pub const CODEBASE_VERSION: &str = "v3.0";
/// The default bound on a data file, MB (LeRobot's default `data_files_size_in_mb`).
pub const DATA_FILE_SIZE_MB: u64 = super::LEROBOT_FILE_MB;
/// The largest `--max-file-mb`: a file's image column stays far from the 2^31 bytes past which
/// pyarrow cannot read a column whole.
pub const MAX_FILE_SIZE_MB: u64 = super::LEROBOT_MAX_FILE_MB;
/// Bytes in the MB of `--max-file-mb` (10^6: a file under N x 10^6 bytes is under LeRobot's
/// N MiB as well).
const BYTES_PER_MB: u64 = 1_000_000;
/// The largest row group written, bytes. The parquet writer holds a row group's encoded columns
/// in memory until it is complete, so this bounds the export's memory besides the frame in
/// flight; smaller bounds on the file get smaller row groups (an eighth of the file).
pub const ROW_GROUP_BYTES: u64 = 8 << 20;
/// The smallest row group bound, bytes (so that a small `--max-file-mb` does not make a row
/// group, and its footer entry, per frame).
const MIN_ROW_GROUP_BYTES: u64 = 64 << 10;
/// The names of the pose vector's components (`observation.state`, `action`).
pub const POSE_NAMES: [&str; 4] = ["x_mm", "y_mm", "z_mm", "yaw_deg"];
/// Two poses that differ by no more than this (mm or degrees) are the same measurement.
const SAME_POSE: f64 = 1e-9;
/// The numeric features with stats and their widths, in `meta/stats.json`'s order.
const VECTOR_FEATURES: [(&str, usize); 8] = [
    ("action", 4),
    ("episode_index", 1),
    ("frame_index", 1),
    ("index", 1),
    ("observation.state", 4),
    ("pose_id", 1),
    ("task_index", 1),
    ("timestamp", 1),
];

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
    /// The bound on each parquet file, MB of 10^6 bytes (`data_files_size_in_mb`), 1 to
    /// [`MAX_FILE_SIZE_MB`].
    pub max_file_mb: u64,
}

impl Default for LerobotOptions {
    fn default() -> Self {
        Self { fps: 1, task: None, robot_type: None, max_file_mb: DATA_FILE_SIZE_MB }
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
    /// The data files, in order.
    pub data_files: Vec<DataFile>,
}

/// One data file of an export.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DataFile {
    /// Relative to the output folder: `data/chunk-CCC/file-FFF.parquet`.
    pub path: String,
    pub bytes: u64,
}

/// One sensor's dataset of an object, its rows reduced to what the export writes.
struct SensorData {
    sensor: SensorKind,
    dir: PathBuf,
    manifest: Manifest,
    /// Each frame's `source`, in the object's frame order.
    sources: Vec<Source>,
}

/// One sensor's dataset while its rows are joined with the others'.
struct SensorRows {
    sensor: SensorKind,
    dir: PathBuf,
    manifest: Manifest,
    rows: BTreeMap<u32, super::PoseRow>,
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

/// One object's datasets: the frames of one or more episodes.
struct ObjectData {
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
    if !(1..=MAX_FILE_SIZE_MB).contains(&options.max_file_mb) {
        return Err(LerobotError::BadOption(format!("--max-file-mb must be 1 to {MAX_FILE_SIZE_MB}")));
    }
    check_out(out)?;
    let objects = load_objects(root)?;
    let sensors: Vec<SensorKind> = objects[0].sensors.iter().map(|s| s.sensor).collect();
    let parent = out.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let name = out.file_name().ok_or_else(|| LerobotError::BadOption(format!("--out {} has no folder name", out.display())))?;
    let tmp = parent.join(format!(".{}.partial-{}", name.to_string_lossy(), std::process::id()));
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).map_err(io_err("removing", &tmp))?;
    }
    std::fs::create_dir_all(&tmp).map_err(io_err("creating", &tmp))?;
    let result = write_all(&tmp, &objects, &sensors, options);
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

/// Reads the datasets under `root`, grouped by object, and checks that they fit one LeRobot
/// dataset. One object's rows are held at a time, while they are joined into frames.
fn load_objects(root: &Path) -> Result<Vec<ObjectData>, LerobotError> {
    let dirs = find_datasets(root)?;
    if dirs.is_empty() {
        return Err(LerobotError::NoDatasets { root: root.to_path_buf() });
    }
    let mut by_object: BTreeMap<String, Vec<(SensorKind, PathBuf, Manifest)>> = BTreeMap::new();
    for dir in dirs {
        let manifest = Manifest::load(&dir)?;
        let group = by_object.entry(manifest.object.name.clone()).or_default();
        if let Some((_, other, _)) = group.iter().find(|(s, _, _)| *s == manifest.sensor) {
            return Err(LerobotError::Layout {
                reason: format!(
                    "{} and {} are both {} datasets of object {:?}; export them separately",
                    other.display(),
                    dir.display(),
                    manifest.sensor,
                    manifest.object.name
                ),
            });
        }
        group.push((manifest.sensor, dir, manifest));
    }
    let mut objects: Vec<ObjectData> = Vec::new();
    for (object, mut group) in by_object {
        group.sort_by_key(|(s, _, _)| *s);
        let these: Vec<SensorKind> = group.iter().map(|(s, _, _)| *s).collect();
        if let Some(first) = objects.first() {
            let theirs: Vec<SensorKind> = first.sensors.iter().map(|s| s.sensor).collect();
            if these != theirs {
                return Err(LerobotError::Layout {
                    reason: format!(
                        "object {:?} has sensors {} but {:?} has {}: every episode of a LeRobot dataset has the same image keys",
                        first.object,
                        sensor_list(&theirs),
                        object,
                        sensor_list(&these)
                    ),
                });
            }
        }
        let mut with_rows = Vec::with_capacity(group.len());
        for (sensor, dir, manifest) in group {
            let rows = read_rows(&dir)?.into_iter().map(|r| (r.pose_id, r)).collect();
            with_rows.push(SensorRows { sensor, dir, manifest, rows });
        }
        let frames = joint_frames(&object, &with_rows)?;
        let sensors = with_rows
            .into_iter()
            .map(|s| {
                let sources = frames.iter().map(|f| s.rows.get(&f.pose_id).map_or(Source::Synthetic, |r| r.source)).collect();
                SensorData { sensor: s.sensor, dir: s.dir, manifest: s.manifest, sources }
            })
            .collect();
        objects.push(ObjectData { object, sensors, frames });
    }
    Ok(objects)
}

fn sensor_list(sensors: &[SensorKind]) -> String {
    sensors.iter().map(|s| s.name()).collect::<Vec<_>>().join(", ")
}

/// An object's frames in pose id order: every sensor must have the same pose ids, and agree on
/// each one's poses.
fn joint_frames(object: &str, sensors: &[SensorRows]) -> Result<Vec<FramePoses>, LerobotError> {
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
fn frame_poses(object: &str, sensors: &[SensorRows], pose_id: u32) -> Result<FramePoses, LerobotError> {
    fn row<'a>(object: &str, s: &'a SensorRows, pose_id: u32) -> Result<&'a super::PoseRow, LerobotError> {
        s.rows
            .get(&pose_id)
            .ok_or_else(|| LerobotError::Layout { reason: format!("object {object:?}: {} has no pose {pose_id}", s.dir.display()) })
    }
    let first = row(object, &sensors[0], pose_id)?;
    let commanded = first.commanded();
    let mut measured: Option<(Pose, &SensorRows)> = None;
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
struct FrameOut<'a> {
    poses: &'a FramePoses,
    /// Per sensor: the PNG bytes and the `path` stored with them.
    images: &'a [(Vec<u8>, String)],
    sources: Vec<Source>,
    frame_index: u64,
    episode_index: u64,
    index: u64,
    task_index: u64,
    fps: u32,
}

/// A one-row record batch of `frame`.
fn batch_of(schema: &SchemaRef, frame: &FrameOut) -> Result<RecordBatch, String> {
    let pose = |p: Pose| -> Result<ArrayRef, String> {
        let values: Vec<f32> = pose_vec(p).iter().map(|&v| v as f32).collect();
        let item = Arc::new(Field::new("item", DataType::Float32, true));
        FixedSizeListArray::try_new(item, 4, Arc::new(Float32Array::from(values)), None)
            .map(|a| Arc::new(a) as ArrayRef)
            .map_err(|e| e.to_string())
    };
    let mut columns: Vec<ArrayRef> = vec![pose(frame.poses.state)?, pose(frame.poses.commanded)?];
    for (bytes, path) in frame.images {
        let bytes = BinaryArray::from_iter_values([bytes.as_slice()]);
        let paths = StringArray::from_iter_values([path.as_str()]);
        let image =
            StructArray::try_new(image_fields(), vec![Arc::new(bytes) as ArrayRef, Arc::new(paths)], None).map_err(|e| e.to_string())?;
        columns.push(Arc::new(image));
    }
    columns.push(Arc::new(BooleanArray::from(vec![frame.poses.measured])));
    columns.push(Arc::new(Int64Array::from(vec![i64::from(frame.poses.pose_id)])));
    for source in &frame.sources {
        columns.push(Arc::new(StringArray::from_iter_values([source.to_string()])));
    }
    columns.push(Arc::new(Float32Array::from(vec![timestamp(frame.frame_index, frame.fps)])));
    for v in [frame.frame_index, frame.episode_index, frame.index, frame.task_index] {
        columns.push(Arc::new(Int64Array::from(vec![i64::try_from(v).unwrap_or(i64::MAX)])));
    }
    RecordBatch::try_new(schema.clone(), columns).map_err(|e| e.to_string())
}

/// A frame's timestamp, s.
fn timestamp(frame_index: u64, fps: u32) -> f32 {
    (frame_index as f64 / f64::from(fps)) as f32
}

/// The parquet properties of the data files: row groups of at most `row_group_bytes`, and no
/// dictionary or statistics for the image columns (every value differs, and min/max of PNG
/// bytes say nothing).
fn data_props(sensors: &[SensorKind], row_group_bytes: u64) -> WriterProperties {
    let mut b = WriterProperties::builder()
        .set_max_row_group_bytes(Some(usize::try_from(row_group_bytes).unwrap_or(usize::MAX)))
        .set_created_by(format!("rig {}", crate::version()));
    for s in sensors {
        for leaf in ["bytes", "path"] {
            let column = ColumnPath::new(vec![image_key(*s), leaf.to_string()]);
            b = b.set_column_dictionary_enabled(column.clone(), false).set_column_statistics_enabled(column, EnabledStatistics::None);
        }
    }
    b.build()
}

/// The parquet properties of the metadata files.
fn meta_props(row_group_bytes: u64) -> WriterProperties {
    WriterProperties::builder()
        .set_max_row_group_bytes(Some(usize::try_from(row_group_bytes).unwrap_or(usize::MAX)))
        .set_created_by(format!("rig {}", crate::version()))
        .build()
}

/// The bytes a frame adds to a data file besides its images and their paths, generously: eight
/// floats, a flag, six integers, a source text per sensor and the length prefixes.
const FRAME_OVERHEAD_BYTES: u64 = 256;

/// The bytes a column of an episode's record adds to its file, generously: a stat of an image
/// feature is three floats with three levels of list offsets.
const EPISODE_COLUMN_BYTES: u64 = 64;

/// Where one episode lies: its object, its frames there, and its rows.
#[derive(Debug, Clone, Copy)]
struct EpisodeSpan {
    index: u64,
    /// Index into the exported objects.
    object: usize,
    /// Its first frame among the object's frames.
    first_frame: usize,
    /// Its first row (`index`) in the dataset.
    from: u64,
    length: u64,
    task_index: u64,
    /// The data file holding it.
    data_file: u64,
}

impl EpisodeSpan {
    /// The episode's frames, with their `frame_index`.
    fn frames<'a>(&self, objects: &'a [ObjectData]) -> impl Iterator<Item = (u64, &'a FramePoses)> + use<'a> {
        let length = usize::try_from(self.length).unwrap_or(usize::MAX);
        let frames = objects.get(self.object).map_or(&[][..], |o| &o.frames[..]);
        frames.iter().skip(self.first_frame).take(length).enumerate().map(|(k, f)| (k as u64, f))
    }
}

/// The episode being written: where it lies and its image histograms.
struct OpenEpisode {
    span: EpisodeSpan,
    images: Vec<ImageStats>,
}

/// Stats of the numeric features over `spans`, computed one feature at a time from the
/// frames' records (nothing is kept while frames are written).
fn vector_stats(spans: &[EpisodeSpan], objects: &[ObjectData], fps: u32) -> StatsByFeature {
    let mut out = StatsByFeature::new();
    for (key, width) in VECTOR_FEATURES {
        let mut v = VecStats::new(width);
        for span in spans {
            for (k, frame) in span.frames(objects) {
                v.push(&feature_values(key, span, k, frame, fps)[..width]);
            }
        }
        out.insert(key.to_string(), v.into_stats());
    }
    out
}

/// The value of the numeric feature `key` at frame `k` of `span`, as stored (float32 where the
/// column is, so the stats are of what a reader gets).
fn feature_values(key: &str, span: &EpisodeSpan, k: u64, frame: &FramePoses, fps: u32) -> [f64; 4] {
    let stored = |p: Pose| pose_vec(p).map(|v| f64::from(v as f32));
    let one = |v: f64| [v, 0.0, 0.0, 0.0];
    match key {
        "observation.state" => stored(frame.state),
        "action" => stored(frame.commanded),
        "pose_id" => one(f64::from(frame.pose_id)),
        "timestamp" => one(f64::from(timestamp(k, fps))),
        "frame_index" => one(k as f64),
        "episode_index" => one(span.index as f64),
        "index" => one((span.from + k) as f64),
        "task_index" => one(span.task_index as f64),
        _ => [0.0; 4],
    }
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

fn robot_type(objects: &[ObjectData], options: &LerobotOptions) -> String {
    if let Some(r) = &options.robot_type {
        return r.clone();
    }
    let backend = objects.iter().flat_map(|o| &o.sensors).find_map(|s| s.manifest.capture.as_ref().map(|c| c.arm.backend.clone()));
    match backend.as_deref() {
        Some("mg400" | "sim-mg400") => "dobot_mg400".into(),
        Some("magician") => "dobot_magician".into(),
        _ => "unknown".into(),
    }
}

/// Writes the whole export into `tmp`: the frames one at a time into size-bounded data files,
/// an episode record as each episode ends, then the stats, tasks and info.
fn write_all(tmp: &Path, objects: &[ObjectData], sensors: &[SensorKind], options: &LerobotOptions) -> Result<LerobotSummary, LerobotError> {
    let schema = data_schema(sensors);
    let bound_bytes = options.max_file_mb * BYTES_PER_MB;
    let row_group_bytes = (bound_bytes / 8).clamp(MIN_ROW_GROUP_BYTES, ROW_GROUP_BYTES);
    let mut data = RollingFiles::new(tmp, "data", bound_bytes, data_props(sensors, row_group_bytes));
    let mut episodes =
        EpisodeFiles { files: RollingFiles::new(tmp, "meta/episodes", bound_bytes, meta_props(row_group_bytes)), tasks: Vec::new() };
    let mut image_shapes: BTreeMap<SensorKind, [u32; 2]> = BTreeMap::new();
    let mut image_stats: Vec<ImageStats> = vec![ImageStats::default(); sensors.len()];
    let mut reencoded = 0usize;
    let mut spans: Vec<EpisodeSpan> = Vec::new();
    let mut index = 0u64;
    for (o, object) in objects.iter().enumerate() {
        let task = options.task.clone().unwrap_or_else(|| default_task(&object.object, sensors));
        let task_index = episodes.task_index(task);
        let mut open: Option<OpenEpisode> = None;
        for (k, frame) in object.frames.iter().enumerate() {
            // The frame in flight: its images, read and decoded one sensor at a time.
            let mut images = Vec::with_capacity(sensors.len());
            let mut decoded = Vec::with_capacity(sensors.len());
            for s in &object.sensors {
                let rel = image_rel_path(frame.pose_id);
                let (bytes, rgb) = frame_image(frame.pose_id, &s.dir, &rel, image_shapes.get(&s.sensor).copied(), &mut reencoded)?;
                image_shapes.insert(s.sensor, [rgb.width(), rgb.height()]);
                images.push((bytes, format!("{}/{}/{rel}", object.object, s.sensor.name())));
                decoded.push(rgb);
            }
            let row_bytes = images.iter().map(|(b, p)| (b.len() + p.len()) as u64).sum::<u64>() + FRAME_OVERHEAD_BYTES;
            if data.make_room(row_bytes, &schema)?
                && let Some(done) = open.take()
            {
                // The file in progress is full: its last episode ends with it.
                spans.push(episodes.finish(done, objects, sensors, options.fps, &mut image_stats)?);
            }
            let episode = open.get_or_insert_with(|| OpenEpisode {
                span: EpisodeSpan {
                    index: spans.len() as u64,
                    object: o,
                    first_frame: k,
                    from: index,
                    length: 0,
                    task_index,
                    data_file: data.file_index(),
                },
                images: vec![ImageStats::default(); sensors.len()],
            });
            for (stats, rgb) in episode.images.iter_mut().zip(&decoded) {
                stats.push(rgb);
            }
            let row = FrameOut {
                poses: frame,
                images: &images,
                sources: object.sensors.iter().map(|s| s.sources.get(k).copied().unwrap_or(Source::Synthetic)).collect(),
                frame_index: episode.span.length,
                episode_index: episode.span.index,
                index,
                task_index,
                fps: options.fps,
            };
            data.write(&batch_of(&schema, &row).map_err(|r| write_err(tmp, r))?)?;
            episode.span.length += 1;
            index += 1;
        }
        if let Some(done) = open.take() {
            // An episode ends with its object, and a row group with the episode.
            data.end_row_group()?;
            spans.push(episodes.finish(done, objects, sensors, options.fps, &mut image_stats)?);
        }
    }
    let data_files = data.finish()?;
    let tasks = episodes.close()?;
    write_tasks(tmp, &tasks)?;
    let mut stats = vector_stats(&spans, objects, options.fps);
    for (s, st) in sensors.iter().zip(&image_stats) {
        stats.insert(image_key(*s), st.stats());
    }
    write_json(&tmp.join("meta"), "stats.json", &stats_json(&stats))?;
    let info = json!({
        "codebase_version": CODEBASE_VERSION,
        "robot_type": robot_type(objects, options),
        "total_episodes": spans.len(),
        "total_frames": index,
        "total_tasks": tasks.len(),
        "chunks_size": CHUNKS_SIZE,
        "data_files_size_in_mb": options.max_file_mb,
        "video_files_size_in_mb": 200,
        "fps": options.fps,
        "splits": {"train": format!("0:{}", spans.len())},
        "data_path": "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet",
        "video_path": null,
        "features": features_json(sensors, &image_shapes),
    });
    write_json(&tmp.join("meta"), "info.json", &info)?;
    Ok(LerobotSummary {
        episodes: spans.len(),
        frames: usize::try_from(index).unwrap_or(usize::MAX),
        sensors: sensors.to_vec(),
        reencoded,
        data_files: data_files.into_iter().map(|(path, bytes)| DataFile { path, bytes }).collect(),
    })
}

/// `meta/episodes/...`: one record per episode, written as each episode ends, and the tasks
/// they name.
struct EpisodeFiles {
    files: RollingFiles,
    tasks: Vec<String>,
}

impl EpisodeFiles {
    /// The index of `task`, added when new.
    fn task_index(&mut self, task: String) -> u64 {
        let i = match self.tasks.iter().position(|t| *t == task) {
            Some(i) => i,
            None => {
                self.tasks.push(task);
                self.tasks.len() - 1
            }
        };
        i as u64
    }

    /// Ends `episode`: writes its record with its stats, adds its image histograms to the
    /// dataset's (`dataset_images`, one per sensor), and returns where it lies.
    fn finish(
        &mut self,
        episode: OpenEpisode,
        objects: &[ObjectData],
        sensors: &[SensorKind],
        fps: u32,
        dataset_images: &mut [ImageStats],
    ) -> Result<EpisodeSpan, LerobotError> {
        let span = episode.span;
        let mut stats = vector_stats(&[span], objects, fps);
        for ((s, st), all) in sensors.iter().zip(&episode.images).zip(dataset_images.iter_mut()) {
            stats.insert(image_key(*s), st.stats());
            all.merge(st);
        }
        let object = objects.get(span.object).map_or("", |o| o.object.as_str());
        // The record names its own file, so it is built again if it has to start the next one.
        let record = |file: u64| episode_record(&span, object, &self.tasks, &stats, file);
        let probe = record(self.files.file_index()).map_err(|e| write_err(Path::new("meta/episodes"), e))?;
        // A few numbers per column, and the texts (the builders' capacity says nothing of it).
        let task_len = usize::try_from(span.task_index).ok().and_then(|i| self.tasks.get(i)).map_or(0, String::len);
        let row_bytes = probe.num_columns() as u64 * EPISODE_COLUMN_BYTES + (object.len() + task_len) as u64;
        let schema = probe.schema();
        let batch = if self.files.make_room(row_bytes, &schema)? { record(self.files.file_index()) } else { Ok(probe) };
        self.files.write(&batch.map_err(|e| write_err(Path::new("meta/episodes"), e))?)?;
        Ok(span)
    }

    /// Closes the files; returns the tasks.
    fn close(self) -> Result<Vec<String>, LerobotError> {
        self.files.finish()?;
        Ok(self.tasks)
    }
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
    let mut out = ParquetOut::create(&path, schema, meta_props(ROW_GROUP_BYTES))?;
    out.write(&batch)?;
    out.close().map(|_| ())
}

/// Named arrow columns being gathered for a one-row record batch.
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
    fn push_ints(&mut self, name: &str, value: u64) {
        self.push(name, Arc::new(Int64Array::from(vec![i64::try_from(value).unwrap_or(i64::MAX)])));
    }
    /// `stats/<key>/<stat>` for every stat (as lists; image stats nested [3][1][1] as LeRobot
    /// shapes them) and `stats/<key>/count`.
    fn push_stats(&mut self, key: &str, stats: &FeatureStats) {
        for (stat, values) in &stats.table {
            let column: ArrayRef = if stats.image {
                let mut b = ListBuilder::new(ListBuilder::new(ListBuilder::new(Float64Builder::new())));
                for &v in values {
                    b.values().values().values().append_value(v);
                    b.values().values().append(true);
                    b.values().append(true);
                }
                b.append(true);
                Arc::new(b.finish())
            } else {
                let mut b = ListBuilder::new(Float64Builder::new());
                b.values().append_slice(values);
                b.append(true);
                Arc::new(b.finish())
            };
            self.push(format!("stats/{key}/{stat}"), column);
        }
        let mut b = ListBuilder::new(Int64Builder::new());
        b.values().append_value(i64::try_from(stats.count).unwrap_or(i64::MAX));
        b.append(true);
        self.push(format!("stats/{key}/count"), Arc::new(b.finish()));
    }
}

/// One episode's record in `meta/episodes/...` (LeRobot's columns, then `rig/object`, then its
/// stats as `stats/<feature>/<stat>`), when it is in episodes file `meta_file`.
fn episode_record(
    span: &EpisodeSpan,
    object: &str,
    tasks: &[String],
    stats: &StatsByFeature,
    meta_file: u64,
) -> Result<RecordBatch, arrow_schema::ArrowError> {
    let mut cols = Columns::default();
    cols.push_ints("episode_index", span.index);
    let mut task_list = ListBuilder::new(StringBuilder::new());
    let task = usize::try_from(span.task_index).ok().and_then(|i| tasks.get(i)).map_or("", String::as_str);
    task_list.values().append_value(task);
    task_list.append(true);
    cols.push("tasks", Arc::new(task_list.finish()));
    cols.push_ints("length", span.length);
    cols.push_ints("data/chunk_index", span.data_file / CHUNKS_SIZE);
    cols.push_ints("data/file_index", span.data_file % CHUNKS_SIZE);
    cols.push_ints("dataset_from_index", span.from);
    cols.push_ints("dataset_to_index", span.from + span.length);
    cols.push_ints("meta/episodes/chunk_index", meta_file / CHUNKS_SIZE);
    cols.push_ints("meta/episodes/file_index", meta_file % CHUNKS_SIZE);
    cols.push("rig/object", Arc::new(StringArray::from_iter_values([object])));
    // Vectors first, then images, each in key order.
    for image in [false, true] {
        for (key, s) in stats.iter().filter(|(_, s)| s.image == image) {
            cols.push_stats(key, s);
        }
    }
    RecordBatch::try_new(Arc::new(Schema::new(cols.fields)), cols.arrays)
}
