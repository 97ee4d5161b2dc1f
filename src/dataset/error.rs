//! The dataset module's error: one enum for reading, writing, verifying and merging
//! datasets, so the exit-code table classifies them in one place.

use std::path::PathBuf;

/// Errors of the dataset module.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    #[error("{op} {path}: {source}")]
    Io {
        op: &'static str,
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The disk (or the injected byte budget) is full. Nothing durable was lost: the writer
    /// only ever lands whole images before their rows.
    #[error(
        "disk full while {op} {path} (everything written before is intact: free some space, then run the same command again; \
         `rig collect` and `rig dataset import` continue with --resume, `rig synth` and `rig dataset merge` continue by themselves)"
    )]
    DiskFull {
        op: &'static str,
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{dir} already holds a dataset (or other files); refusing to overwrite it. Use --resume to continue it")]
    NotEmpty { dir: PathBuf },
    #[error("STL {path} named by {manifest} does not exist (give the dataset its STL there, or re-collect with --stl)")]
    StlMissing { path: String, manifest: PathBuf },
    #[error("STL {path} named by {manifest} is not the file the dataset was made with (its sha256 differs)")]
    StlChanged { path: PathBuf, manifest: PathBuf },
    /// An STL path outside the dataset and the working folder that is not the file the
    /// manifest's sha256 names: refused in the same words whether or not a file is there, so
    /// nothing is learned about files outside ([`crate::dataset::named`]).
    #[error(
        "STL {path} named by {manifest} is not a path below the dataset folder or the working folder, and outside them rig reads \
         only the file whose sha256 the manifest records: this is not that file, or it is not there (put the original back, or \
         copy the STL into the dataset folder and name it relative to the dataset)"
    )]
    StlUnusable { path: String, manifest: PathBuf },
    /// A file the manifest names that rig may not read ([`crate::dataset::named`]).
    #[error(transparent)]
    Named(#[from] crate::dataset::named::NamedFileError),
    #[error("folder {dir} does not exist")]
    FolderMissing { dir: PathBuf },
    #[error("{dir} is not a dataset: {missing} is missing")]
    NotADataset { dir: PathBuf, missing: &'static str },
    #[error("dataset {dir} was written with a different {field}: it has {existing}, this run asks for {requested}")]
    ManifestMismatch { dir: PathBuf, field: &'static str, existing: String, requested: String },
    #[error("cannot read manifest {path}: {source}")]
    ManifestParse {
        path: PathBuf,
        #[source]
        source: crate::untrusted::SyntaxError,
    },
    #[error("manifest {path}: its plan is not valid: {source}")]
    ManifestPlan {
        path: PathBuf,
        #[source]
        source: crate::plan::PlanError,
    },
    #[error("cannot write manifest: {source}")]
    ManifestWrite {
        #[source]
        source: toml::ser::Error,
    },
    /// `found` is kept for callers but never printed: it is the file's first line.
    #[error("{path}: line 1 is not a header rig knows; expected {expected:?}")]
    BadHeader { path: PathBuf, found: String, expected: String },
    #[error("{path} line {line}: malformed row: {reason}")]
    MalformedRow { path: PathBuf, line: u64, reason: String },
    #[error("{path} line {line}: pose_id {pose_id} already has a row (line {first_line})")]
    DuplicateRow { path: PathBuf, line: u64, first_line: u64, pose_id: u32 },
    #[error("pose_id {pose_id} already has a row in this dataset")]
    DuplicatePose { pose_id: u32 },
    #[error("row for pose_id {pose_id} is invalid: {problem}")]
    InvalidRow { pose_id: u32, problem: RowProblem },
    #[error("row for pose_id {pose_id} names {path} but the image is missing; run `rig dataset verify`")]
    MissingImage { pose_id: u32, path: PathBuf },
    #[error("cannot encode image for pose_id {pose_id}: {source}")]
    Encode {
        pose_id: u32,
        #[source]
        source: image::ImageError,
    },
    #[error("dataset {path} is held by another process (another rig is writing it); wait for it to finish, or stop it")]
    Locked { path: PathBuf },
    #[error("{path} is a symlink; rig does not follow symlinks inside a dataset")]
    Symlink { path: PathBuf },
    #[error("{path} is not {expected}")]
    NotRegular { path: PathBuf, expected: &'static str },
    #[error("{path} is larger than the {max_bytes} bytes rig reads from it")]
    TooLarge { path: PathBuf, max_bytes: u64 },
    #[error("{path} is not a readable image: {reason}")]
    BadImage { path: PathBuf, reason: String },
    /// `order.csv` does not parse: wrong header, a line that is not a pose id, a pose twice.
    #[error("{path} line {line}: {reason} (the kept order is `pose_id`, then one pose id per line, each once)")]
    BadOrder { path: PathBuf, line: u64, reason: String },
    /// `adaptive.csv` does not parse: wrong header, a malformed line, a pose twice, rounds out
    /// of order.
    #[error(
        "{path} line {line}: {reason} (an adaptive collection's choices: `pose_id,round,reason,distance,spread,error,score`, round by round)"
    )]
    BadChoices { path: PathBuf, line: u64, reason: String },
    /// `adaptive.csv` parses but is not this collection's record.
    #[error("{path} is not the record of this adaptive collection: {reason} (a collection's recorded rounds are pressed as recorded)")]
    ChoicesMismatch { path: PathBuf, reason: String },
    /// `order.csv` parses but is not an order of the poses it is read for.
    #[error(
        "{path} is not an order of the poses this run visits (the plan's, or the audit's draw): {mismatch} (move the file \
         away to order them again; the rows already collected stay)"
    )]
    OrderMismatch {
        path: PathBuf,
        #[source]
        mismatch: crate::plan::OrderMismatch,
    },
    /// An image of another size than the dataset's (its reference frame's, or its first
    /// image's): what `rig dataset verify` reports, refused by the readers.
    #[error(
        "image {path} is {}x{} px, the dataset's images are {}x{} px (`rig dataset verify` reports it; rig reads no dataset whose images differ in size)",
        found.0, found.1, expected.0, expected.1
    )]
    WrongImageSize { path: PathBuf, found: (u32, u32), expected: (u32, u32) },
    #[error("{path} line {line}: malformed MDS row: {reason}")]
    MalformedMds { path: PathBuf, line: u64, reason: String },
    #[error("cannot write CSV: {source}")]
    CsvWrite {
        #[source]
        source: csv::Error,
    },
    #[error("{dir} does not verify clean ({issues} issues); run `rig dataset verify` on it")]
    Unclean { dir: PathBuf, issues: usize },
    #[error("merge conflict on pose_id {pose_id}: {first} and {second} disagree")]
    MergeConflict { pose_id: u32, first: PathBuf, second: PathBuf },
    /// A merge would put frames of a real rig and of the simulated rig in one dataset.
    #[error(
        "refusing to mix real and simulated frames: {real} has real rows, {simulated} has simulated rows (pass --allow-mixed to merge them anyway)"
    )]
    MixedSources { real: PathBuf, simulated: PathBuf },
    /// A path below the dataset (or the folder holding datasets) broke the opener's rules: a
    /// symlink on the way, not a regular file, too large ([`crate::confine`]).
    #[error(transparent)]
    Confined(#[from] crate::confine::ConfineError),
}

impl DatasetError {
    pub(crate) fn io(op: &'static str, path: impl Into<PathBuf>) -> impl FnOnce(std::io::Error) -> Self {
        let path = path.into();
        move |source| {
            // ENOSPC and EDQUOT: say what to do, not only what failed.
            if source.kind() == std::io::ErrorKind::StorageFull || source.kind() == std::io::ErrorKind::QuotaExceeded {
                DatasetError::DiskFull { op, path, source }
            } else {
                DatasetError::Io { op, path, source }
            }
        }
    }
}

/// What is wrong with a row's content.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RowProblem {
    #[error("commanded pose is not finite")]
    NonFinitePose,
    #[error("measured pose or capture time is not finite")]
    NonFiniteMeasurement,
    #[error("image column is not {expected:?}")]
    ImagePath { expected: String, found: String },
    #[error("a text field contains a line break")]
    Multiline,
    /// A pose coordinate beyond what any rig can press ([`super::MAX_ROW_OFFSET_MM`],
    /// [`super::MAX_ROW_YAW_DEG`]).
    #[error("{field} = {} is beyond ±{max} (no rig presses there)", short_number(*value))]
    PoseOutOfRange { field: &'static str, value: f64, max: f64 },
}

/// `value` as a person writes it: plainly, or in exponent form when it is huge (`1e308`).
fn short_number(value: f64) -> String {
    if value.abs() >= 1e9 { format!("{value:e}") } else { value.to_string() }
}
