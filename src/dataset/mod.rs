//! Datasets on disk: layout, CSV rows, the crash-safe writer, verification, export dialects
//! and merging of shards.
//!
//! Layout of one dataset directory (default `datasets/<object>/<sensor>/`):
//!
//! ```text
//! manifest.toml          plan, object (STL path + sha256), sensor, calibration, firmware profile,
//!                        rig version, start/resume/end times (see [`Manifest`])
//! poses.csv              one row per captured or synthesised pose (see [`PoseRow`])
//! images/<pose_id>.png   the frame of that pose
//! reference.png          the no-contact frame
//! order.csv              the poses a collection visits, in its order, kept before its first
//!                        pose (see [`order`]); absent in datasets no collection wrote
//! adaptive.csv           an adaptive collection's choices, round by round (see [`choices`]),
//!                        in place of order.csv; absent in every other dataset
//! ```
//!
//! Durability ([`DatasetWriter`]): an image is written to a temporary name in `images/`,
//! fsynced and renamed (and the directory fsynced) before its CSV row is appended with one
//! `write` of the whole line and fsynced. So at any instant the CSV lists only images that
//! exist, and the only damage a kill can leave is a torn last line, a temporary file, or an
//! image whose row was never written; [`DatasetWriter::resume`] repairs all three and takes
//! the set of done pose ids from the CSV. [`verify()`] reports what is wrong without touching
//! anything; [`export`] writes the MultiDiffSense (MDS) and tactile-bench CSV dialects and
//! reads the MDS one; [`lerobot`] writes a LeRobot v3 dataset (parquet); [`merge()`] joins shards written by `rig synth --fill-missing --shard`.

pub mod choices;
pub mod durable;
mod error;
pub mod export;
#[cfg(feature = "lerobot")]
pub mod lerobot;
pub mod manifest;
pub mod merge;
pub mod named;
pub mod order;
pub mod press_limit;
pub mod verify;
pub mod writer;

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::pose::Pose;

pub use error::{DatasetError, RowProblem};
pub use manifest::{AuditFigure, AuditSummary, CaptureChain, CapturePart, Manifest, ObjectInfo, SynthesisInfo};
pub use merge::{MergeOptions, MergeReport, merge};
pub use verify::{CaptureNote, DatasetImages, VerifyIssue, VerifyReport, verify};
pub use writer::DatasetWriter;

/// The default bound on a LeRobot export's parquet files, MB of 10^6 bytes (LeRobot's default
/// `data_files_size_in_mb`), and the largest accepted; here so that the command line offers them
/// in builds without the `lerobot` feature too.
pub const LEROBOT_FILE_MB: u64 = 100;
pub const LEROBOT_MAX_FILE_MB: u64 = 2000;

/// File names inside a dataset directory.
pub const MANIFEST_FILE: &str = "manifest.toml";
pub const POSES_FILE: &str = "poses.csv";
pub const IMAGES_DIR: &str = "images";
pub const REFERENCE_FILE: &str = "reference.png";

/// The columns of `poses.csv`, in order (the header line).
pub const COLUMNS: [&str; 18] = [
    "pose_id",
    "x_mm",
    "y_mm",
    "z_mm",
    "yaw_deg",
    "meas_x_mm",
    "meas_y_mm",
    "meas_z_mm",
    "meas_yaw_deg",
    "image",
    "source",
    "t_capture_s",
    "model",
    "seed",
    "steps",
    "guidance",
    "n_frames",
    "modbus",
];

/// The columns of datasets written before the `modbus` column existed. Readers accept both
/// headers; a writer that appends to such a dataset first upgrades it (see [`DatasetWriter`]).
pub const LEGACY_COLUMNS: &[&str] = COLUMNS.split_at(COLUMNS.len() - 1).0;

/// Which header a `poses.csv` has.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CsvLayout {
    /// [`COLUMNS`]: the current header, with `modbus`.
    Current,
    /// [`LEGACY_COLUMNS`]: a dataset from before the `modbus` column.
    Legacy,
}

impl CsvLayout {
    /// The layout a header line names, if it is one rig writes or wrote.
    pub fn of_header(header: &str) -> Option<Self> {
        if header == COLUMNS.join(",") {
            Some(Self::Current)
        } else if header == LEGACY_COLUMNS.join(",") {
            Some(Self::Legacy)
        } else {
            None
        }
    }

    /// The column names of this layout.
    pub fn columns(self) -> &'static [&'static str] {
        match self {
            Self::Current => &COLUMNS,
            Self::Legacy => LEGACY_COLUMNS,
        }
    }
}
/// Where a row's image came from.
///
/// `real` and `simulated` frames are both *captured*: a sensor (a physical one, or the
/// simulated one of the simulated rig) took them at a pose the arm reached, with a measured
/// pose and a capture time. `synthetic` frames were synthesised by the model. A frame from a
/// simulated sensor is never called real.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Source {
    /// Captured by a physical sensor on the rig.
    Real,
    /// Captured by a simulated sensor (the simulated rig).
    Simulated,
    /// Synthesised by the diffusion model.
    Synthetic,
}

impl Source {
    /// Every source, in the order reports count them.
    pub const ALL: [Source; 3] = [Source::Real, Source::Simulated, Source::Synthetic];

    /// True for frames a sensor took (`real` or `simulated`), false for synthesised ones.
    pub fn is_captured(self) -> bool {
        matches!(self, Source::Real | Source::Simulated)
    }

    /// The source of frames captured by a sensor that is simulated or not.
    pub fn captured(simulated: bool) -> Self {
        if simulated { Source::Simulated } else { Source::Real }
    }
}

impl std::fmt::Display for Source {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Source::Real => "real",
            Source::Simulated => "simulated",
            Source::Synthetic => "synthetic",
        })
    }
}

/// One row of `poses.csv`. Poses are in the work frame (z is extra indentation).
///
/// Columns beyond the contract: `steps` and `guidance` (diffusion steps and guidance scale of
/// a synthetic image), `n_frames` (frames averaged into a real image; empty when one), and
/// `modbus` (the Modbus peripherals' readings at capture, `<peripheral>.<reading>=<value>`
/// joined by `;` in peripheral-name then configured order, a value left empty when an
/// optional peripheral did not answer; empty when no peripheral is configured and for
/// synthetic rows; see [`crate::io::modbus`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoseRow {
    /// Stable grid id of the pose (see [`crate::plan`]).
    pub pose_id: u32,
    /// Commanded pose.
    pub x_mm: f64,
    pub y_mm: f64,
    pub z_mm: f64,
    pub yaw_deg: f64,
    /// Measured pose from the arm's feedback at capture; empty for synthetic rows.
    pub meas_x_mm: Option<f64>,
    pub meas_y_mm: Option<f64>,
    pub meas_z_mm: Option<f64>,
    pub meas_yaw_deg: Option<f64>,
    /// Image path relative to the dataset directory, always `images/<pose_id>.png` (the writer
    /// sets it).
    pub image: String,
    pub source: Source,
    /// Capture time on the rig clock, s; empty for synthetic rows.
    pub t_capture_s: Option<f64>,
    /// Model package name of a synthetic image.
    pub model: Option<String>,
    /// Sampler seed of a synthetic image.
    pub seed: Option<u64>,
    /// Diffusion steps of a synthetic image.
    pub steps: Option<u32>,
    /// Classifier-free guidance scale of a synthetic image.
    pub guidance: Option<f64>,
    /// Frames averaged into a real image.
    pub n_frames: Option<u32>,
    /// Modbus readings at capture (`light.level_permille=800;force.force_N=1.25`); absent in
    /// datasets from before the column existed.
    #[serde(default)]
    pub modbus: Option<String>,
}

impl PoseRow {
    /// A row with only the commanded pose and the source; every optional column empty.
    pub fn commanded_only(pose_id: u32, commanded: Pose, source: Source) -> Self {
        Self {
            pose_id,
            x_mm: commanded.x_mm,
            y_mm: commanded.y_mm,
            z_mm: commanded.z_mm,
            yaw_deg: commanded.yaw_deg,
            meas_x_mm: None,
            meas_y_mm: None,
            meas_z_mm: None,
            meas_yaw_deg: None,
            image: image_rel_path(pose_id),
            source,
            t_capture_s: None,
            model: None,
            seed: None,
            steps: None,
            guidance: None,
            n_frames: None,
            modbus: None,
        }
    }

    /// A row captured by a physical sensor: commanded and measured work-frame poses and the
    /// capture time.
    pub fn real(pose_id: u32, commanded: Pose, measured: Pose, t_capture_s: f64) -> Self {
        Self::captured(pose_id, commanded, measured, t_capture_s, Source::Real)
    }

    /// A captured row of `source` (`real` or `simulated`): commanded and measured work-frame
    /// poses and the capture time.
    pub fn captured(pose_id: u32, commanded: Pose, measured: Pose, t_capture_s: f64, source: Source) -> Self {
        Self {
            meas_x_mm: Some(measured.x_mm),
            meas_y_mm: Some(measured.y_mm),
            meas_z_mm: Some(measured.z_mm),
            meas_yaw_deg: Some(measured.yaw_deg),
            t_capture_s: Some(t_capture_s),
            ..Self::commanded_only(pose_id, commanded, source)
        }
    }

    /// This row with the Modbus readings text (an empty text leaves the column empty).
    pub fn with_modbus(mut self, readings: String) -> Self {
        self.modbus = (!readings.is_empty()).then_some(readings);
        self
    }

    /// A synthesised row with its provenance.
    pub fn synthetic(pose_id: u32, commanded: Pose, model: &str, seed: u64, steps: u32, guidance: f64) -> Self {
        Self {
            model: Some(model.to_string()),
            seed: Some(seed),
            steps: Some(steps),
            guidance: Some(guidance),
            ..Self::commanded_only(pose_id, commanded, Source::Synthetic)
        }
    }

    /// The commanded work-frame pose.
    pub fn commanded(&self) -> Pose {
        Pose::new(self.x_mm, self.y_mm, self.z_mm, self.yaw_deg)
    }

    /// The measured work-frame pose, when all four components are present.
    pub fn measured(&self) -> Option<Pose> {
        Some(Pose::new(self.meas_x_mm?, self.meas_y_mm?, self.meas_z_mm?, self.meas_yaw_deg?))
    }

    /// Why this row is not acceptable in a dataset, if it is not.
    pub fn problem(&self) -> Option<RowProblem> {
        if !self.commanded().is_finite() {
            return Some(RowProblem::NonFinitePose);
        }
        let meas = [self.meas_x_mm, self.meas_y_mm, self.meas_z_mm, self.meas_yaw_deg];
        if meas.iter().flatten().any(|v| !v.is_finite()) || self.t_capture_s.is_some_and(|t| !t.is_finite()) {
            return Some(RowProblem::NonFiniteMeasurement);
        }
        // Finite is not enough: z = 1e308 would reach a regressor or a renderer as a number.
        let coordinates = [
            ("x_mm", Some(self.x_mm), MAX_ROW_OFFSET_MM),
            ("y_mm", Some(self.y_mm), MAX_ROW_OFFSET_MM),
            ("z_mm", Some(self.z_mm), MAX_ROW_OFFSET_MM),
            ("yaw_deg", Some(self.yaw_deg), MAX_ROW_YAW_DEG),
            ("meas_x_mm", self.meas_x_mm, MAX_ROW_OFFSET_MM),
            ("meas_y_mm", self.meas_y_mm, MAX_ROW_OFFSET_MM),
            ("meas_z_mm", self.meas_z_mm, MAX_ROW_OFFSET_MM),
            ("meas_yaw_deg", self.meas_yaw_deg, MAX_ROW_YAW_DEG),
        ];
        if let Some((field, Some(value), max)) = coordinates.into_iter().find(|(_, v, max)| v.is_some_and(|v| v.abs() > *max)) {
            return Some(RowProblem::PoseOutOfRange { field, value, max });
        }
        if self.image != image_rel_path(self.pose_id) {
            return Some(RowProblem::ImagePath { expected: image_rel_path(self.pose_id), found: self.image.clone() });
        }
        None
    }
}

/// Largest work-frame offset of a row's pose (x, y, z, commanded or measured), mm: beyond the
/// reach of any desktop arm from the object it presses.
pub const MAX_ROW_OFFSET_MM: f64 = 1000.0;
/// Largest work-frame yaw of a row, degrees (two turns either way).
pub const MAX_ROW_YAW_DEG: f64 = 720.0;

/// The image path of a pose relative to the dataset directory.
pub fn image_rel_path(pose_id: u32) -> String {
    format!("{IMAGES_DIR}/{pose_id}.png")
}

/// Dataset directories under `root`: `root` itself when it holds a manifest, else its
/// subfolders that do, and theirs (two levels: `<object>/<sensor>`), sorted. `root` is the
/// operator's (or a request's, already confined to the data roots); below it nothing is
/// followed through a symlink ([`crate::confine`]): a symlinked folder or manifest where a
/// dataset could be is an error, not a dataset somewhere else.
pub fn find_datasets(root: &std::path::Path) -> Result<Vec<PathBuf>, DatasetError> {
    use crate::confine::{EntryKind, RootDir};
    require_folder(root)?;
    let dir = RootDir::open(root)?;
    let has_manifest = |rel: &std::path::Path| -> Result<bool, DatasetError> {
        match dir.stat(rel.join(MANIFEST_FILE))? {
            None => Ok(false),
            Some(info) if info.kind == EntryKind::File => Ok(true),
            Some(info) if info.kind == EntryKind::Symlink => Err(DatasetError::Symlink { path: root.join(rel).join(MANIFEST_FILE) }),
            Some(_) => Err(DatasetError::NotRegular { path: root.join(rel).join(MANIFEST_FILE), expected: "a regular file" }),
        }
    };
    if has_manifest(std::path::Path::new(""))? {
        return Ok(vec![root.to_path_buf()]);
    }
    let children = |rel: &std::path::Path| -> Result<Vec<PathBuf>, DatasetError> {
        let mut v = Vec::new();
        for entry in dir.entries(rel)? {
            match entry.kind {
                EntryKind::Folder => v.push(rel.join(&entry.name)),
                EntryKind::Symlink => return Err(DatasetError::Symlink { path: root.join(rel).join(&entry.name) }),
                EntryKind::File | EntryKind::Other => {}
            }
        }
        Ok(v)
    };
    let mut found = Vec::new();
    for a in children(std::path::Path::new(""))? {
        if has_manifest(&a)? {
            found.push(root.join(a));
            continue;
        }
        for b in children(&a)? {
            if has_manifest(&b)? {
                found.push(root.join(b));
            }
        }
    }
    Ok(found)
}

/// Reads every row of `dir/poses.csv`, failing on a malformed or duplicated row (a torn last
/// line is ignored, as resume would truncate it). Rows come in file order.
pub fn read_rows(dir: &std::path::Path) -> Result<Vec<PoseRow>, DatasetError> {
    require_folder(dir)?;
    let path = dir.join(POSES_FILE);
    let bytes = durable::read_below(dir, std::path::Path::new(POSES_FILE), durable::MAX_POSES_CSV_BYTES)?;
    let parsed = parse_csv(&bytes);
    if parsed.layout.is_none() {
        return Err(DatasetError::BadHeader { path, found: parsed.header.unwrap_or_default(), expected: COLUMNS.join(",") });
    }
    strict_rows(parsed.lines, &path)
}

/// The rows of parsed lines, failing on the first malformed or duplicated one.
pub(crate) fn strict_rows(lines: Vec<ParsedLine>, path: &std::path::Path) -> Result<Vec<PoseRow>, DatasetError> {
    let mut first_line = std::collections::BTreeMap::new();
    let mut rows = Vec::with_capacity(lines.len());
    for l in lines {
        let row = l.row.map_err(|reason| DatasetError::MalformedRow { path: path.to_path_buf(), line: l.line, reason })?;
        if let Some(&first) = first_line.get(&row.pose_id) {
            return Err(DatasetError::DuplicateRow { path: path.to_path_buf(), line: l.line, first_line: first, pose_id: row.pose_id });
        }
        first_line.insert(row.pose_id, l.line);
        rows.push(row);
    }
    Ok(rows)
}

/// Serialises one row as a complete CSV line (with its trailing newline).
pub(crate) fn row_line(row: &PoseRow) -> Result<Vec<u8>, DatasetError> {
    let mut w = csv::WriterBuilder::new().has_headers(false).from_writer(Vec::new());
    w.serialize(row).map_err(|source| DatasetError::CsvWrite { source })?;
    w.into_inner().map_err(|e| DatasetError::CsvWrite { source: csv::Error::from(e.into_error()) })
}

/// The header line of `poses.csv` (with its newline).
pub(crate) fn header_line() -> String {
    format!("{}\n", COLUMNS.join(","))
}

/// One parsed line of `poses.csv`.
#[derive(Debug)]
pub(crate) struct ParsedLine {
    /// 1-based line number in the file.
    pub line: u64,
    pub row: Result<PoseRow, String>,
}

/// The parse of a `poses.csv` body: the header, the complete lines, and the length of a torn
/// tail (bytes after the last newline; a kill mid-write leaves one).
#[derive(Debug)]
pub(crate) struct ParsedCsv {
    pub header: Option<String>,
    /// The header's layout; `None` when it is neither (every line is then malformed).
    pub layout: Option<CsvLayout>,
    pub lines: Vec<ParsedLine>,
    pub complete_len: u64,
    pub torn_bytes: u64,
}

/// Parses `poses.csv` bytes; never fails, problems are per line.
pub(crate) fn parse_csv(bytes: &[u8]) -> ParsedCsv {
    let complete_len = bytes.iter().rposition(|&b| b == b'\n').map(|i| i + 1).unwrap_or(0);
    let torn_bytes = (bytes.len() - complete_len) as u64;
    let complete = &bytes[..complete_len];
    let mut header = None;
    let mut layout = None;
    let mut lines = Vec::new();
    for (i, raw) in complete.split(|&b| b == b'\n').enumerate() {
        let line = i as u64 + 1;
        let raw = raw.strip_suffix(b"\r").unwrap_or(raw);
        if i == 0 {
            let text = String::from_utf8_lossy(raw).into_owned();
            layout = CsvLayout::of_header(&text);
            header = Some(text);
            continue;
        }
        if raw.is_empty() {
            continue; // the split after the final newline, or a blank line
        }
        if raw.len() > durable::MAX_CSV_LINE_BYTES {
            lines.push(ParsedLine {
                line,
                row: Err(format!("line of {} bytes, longer than the {} a row may be", raw.len(), durable::MAX_CSV_LINE_BYTES)),
            });
            continue;
        }
        lines.push(ParsedLine { line, row: parse_row(raw, layout.unwrap_or(CsvLayout::Current)) });
    }
    ParsedCsv { header, layout, lines, complete_len: complete_len as u64, torn_bytes }
}

fn parse_row(raw: &[u8], layout: CsvLayout) -> Result<PoseRow, String> {
    let mut rdr = csv::ReaderBuilder::new().has_headers(false).from_reader(raw);
    let mut record = csv::StringRecord::new();
    match rdr.read_record(&mut record) {
        Ok(true) => {}
        Ok(false) => return Err("empty line".to_string()),
        Err(e) => return Err(crate::untrusted::sanitise(&e.to_string())),
    }
    let columns = layout.columns();
    if record.len() != columns.len() {
        return Err(format!("{} fields, expected {}", record.len(), columns.len()));
    }
    let headers = csv::StringRecord::from(columns.to_vec());
    let row: PoseRow = record.deserialize(Some(&headers)).map_err(|e| crate::untrusted::sanitise(&e.to_string()))?;
    if let Some(p) = row.problem() {
        return Err(p.to_string());
    }
    Ok(row)
}

/// [`DatasetError::FolderMissing`] when nothing exists at `dir` (not even a dangling link), so
/// a mistyped dataset folder reads "folder X does not exist" rather than a missing file inside
/// it. Anything else there is left to the reader that follows.
pub fn require_folder(dir: &std::path::Path) -> Result<(), DatasetError> {
    match std::fs::symlink_metadata(dir) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Err(DatasetError::FolderMissing { dir: dir.to_path_buf() }),
        _ => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A finite pose far beyond any rig (z = 1e308) is a row problem: verify reports the line
    /// as malformed and every reader refuses it, as it does a NaN.
    #[test]
    fn poses_beyond_any_rig_are_row_problems() {
        let mut row = PoseRow::real(3, Pose::new(1.0, -2.5, 0.5, 15.0), Pose::new(1.01, -2.49, 0.52, 15.1), 12.25);
        assert_eq!(row.problem(), None);
        row.z_mm = 1e308;
        assert!(matches!(row.problem(), Some(RowProblem::PoseOutOfRange { field: "z_mm", .. })));
        row.z_mm = 0.5;
        row.meas_yaw_deg = Some(-1e6);
        assert!(matches!(row.problem(), Some(RowProblem::PoseOutOfRange { field: "meas_yaw_deg", .. })));
        let mut bytes = header_line().into_bytes();
        row.meas_yaw_deg = Some(15.0);
        row.x_mm = 1000.5;
        let mut w = csv::WriterBuilder::new().has_headers(false).from_writer(Vec::new());
        w.serialize(&row).unwrap();
        bytes.extend(w.into_inner().unwrap());
        let p = parse_csv(&bytes);
        assert!(p.lines[0].row.as_ref().is_err_and(|e| e.contains("x_mm = 1000.5")), "{:?}", p.lines[0].row);
    }

    #[test]
    fn row_round_trip_and_torn_tail() {
        let a = PoseRow::real(3, Pose::new(1.0, -2.5, 0.5, 15.0), Pose::new(1.01, -2.49, 0.52, 15.1), 12.25);
        let b = PoseRow::synthetic(4, Pose::new(0.0, 0.0, -1.0, -90.0), "mds-v1", 42, 50, 1.0);
        let mut bytes = header_line().into_bytes();
        bytes.extend(row_line(&a).unwrap());
        bytes.extend(row_line(&b).unwrap());
        let full = bytes.len() as u64;
        bytes.extend(&row_line(&a).unwrap()[..10]);
        let p = parse_csv(&bytes);
        assert_eq!(p.header.as_deref(), Some(COLUMNS.join(",").as_str()));
        assert_eq!(p.complete_len, full);
        assert_eq!(p.torn_bytes, 10);
        assert_eq!(p.lines.len(), 2);
        assert_eq!(p.lines[0].row.as_ref().unwrap(), &a);
        assert_eq!(p.lines[1].row.as_ref().unwrap(), &b);
        assert_eq!(p.lines[1].line, 3);
    }

    #[test]
    fn bad_rows_are_reported_not_panicked() {
        let mut bytes = header_line().into_bytes();
        bytes.extend(b"1,2,3\n");
        bytes.extend(b"x,0,0,0,0,,,,,images/x.png,real,,,,,,,\n");
        bytes.extend(b"5,0,0,0,0,,,,,images/6.png,real,,,,,,,\n");
        bytes.extend(b"5,0,0,0,NaN,,,,,images/5.png,real,,,,,,,\n");
        // A legacy (17-column) line under the current header.
        bytes.extend(b"5,0,0,0,0,,,,,images/5.png,real,,,,,,\n");
        bytes.extend(b"\xff\xfe,\"\n");
        let p = parse_csv(&bytes);
        assert_eq!(p.lines.len(), 6);
        assert!(p.lines.iter().all(|l| l.row.is_err()), "{:?}", p.lines);
    }

    #[test]
    fn legacy_rows_read_and_modbus_round_trips() {
        let mut bytes = format!("{}\n", LEGACY_COLUMNS.join(",")).into_bytes();
        bytes.extend(b"5,1,2,0.5,0,1,2,0.5,0,images/5.png,real,3.25,,,,,\n");
        let p = parse_csv(&bytes);
        assert_eq!(p.layout, Some(CsvLayout::Legacy));
        let row = p.lines[0].row.as_ref().unwrap();
        assert_eq!(row.pose_id, 5);
        assert_eq!(row.modbus, None);
        // An 18-field line under the legacy header is malformed.
        bytes.extend(b"6,1,2,0.5,0,1,2,0.5,0,images/6.png,real,3.25,,,,,,\n");
        assert!(parse_csv(&bytes).lines[1].row.is_err());

        let a = PoseRow::real(3, Pose::new(1.0, -2.5, 0.5, 15.0), Pose::new(1.0, -2.5, 0.5, 15.0), 1.0)
            .with_modbus("light.level_permille=800;force.force_N=1.25;force.temp_C=".into());
        let mut bytes = header_line().into_bytes();
        bytes.extend(row_line(&a).unwrap());
        let p = parse_csv(&bytes);
        assert_eq!(p.layout, Some(CsvLayout::Current));
        assert_eq!(p.lines[0].row.as_ref().unwrap(), &a);
        assert_eq!(PoseRow::real(3, Pose::default(), Pose::default(), 1.0).with_modbus(String::new()).modbus, None);
    }
}
