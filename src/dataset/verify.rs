//! Read-only check of a dataset directory: rows against images, duplicates, malformed lines,
//! leftovers of a killed run, symlinks and other entries that are not regular files, and every
//! image decoded and its size checked against the reference frame's (or, without one, the
//! first image's) and against the camera format the manifest's capture chain names. Nothing is
//! modified; [`super::DatasetWriter::resume`] repairs what it can.
//!
//! The checks are the readers' too, so that what verify calls unclean no command takes as
//! data: a row is checked by [`super::PoseRow::problem`] whoever parses it (verify reports a
//! malformed row, [`super::read_rows`] refuses the dataset), and an image is read by
//! [`DatasetImages`], which verify and the readers that train or measure on images
//! (`rig eval --downstream`) share: through the opener, decoded with bounds, and of the
//! dataset's size.

use std::collections::{BTreeMap, BTreeSet};
use std::fmt;
use std::path::{Path, PathBuf};

use super::choices::CHOICES_FILE;
use super::durable::{Kind, MAX_IMAGE_BYTES, MAX_POSES_CSV_BYTES, decode_image, entry_exists, read_below};
use super::order::{MAX_ORDER_BYTES, ORDER_FILE, parse_order};
use super::writer::{image_file_pose_id, is_temp_name};
use super::{CaptureChain, DatasetError, IMAGES_DIR, MANIFEST_FILE, Manifest, POSES_FILE, REFERENCE_FILE, Source, parse_csv};

/// One problem found by [`verify`].
#[derive(Debug, Clone, PartialEq)]
pub enum VerifyIssue {
    /// A row whose image file does not exist.
    MissingImage { pose_id: u32, path: PathBuf },
    /// An image (or other file) in `images/` that no row names.
    OrphanImage { path: PathBuf },
    /// A pose id with more than one row.
    DuplicateRow { pose_id: u32, first_line: u64, line: u64 },
    /// A line that does not parse as a row (wrong field count, bad number, bad image path...).
    MalformedRow { line: u64, reason: String },
    /// Bytes after the last newline: an append interrupted mid-line.
    TornLastLine { bytes: u64 },
    /// A temporary file left by an interrupted write.
    TempFile { path: PathBuf },
    /// The header line is not rig's.
    BadHeader { found: String },
    /// The manifest is missing or unreadable.
    BadManifest { reason: String },
    /// An entry that is a symlink (never followed) or not what the layout says (a folder
    /// named like an image, a FIFO...).
    NotRegular { path: PathBuf, reason: String },
    /// An image (or `reference.png`) that does not decode: empty, truncated, not a PNG.
    BadImage { path: PathBuf, reason: String },
    /// An image (or `reference.png`) whose size differs from the frame size the manifest's
    /// capture chain gives the dataset's camera.
    NotCameraFormat { path: PathBuf, found: (u32, u32), camera: (u32, u32) },
    /// An image whose size differs from the dataset's.
    WrongSize { path: PathBuf, found: (u32, u32), expected: (u32, u32) },
    /// A row that presses past the sensor's press limit ([`super::press_limit`]).
    PastPressLimit { pose_id: u32, line: u64, depth_mm: f64, limit: String },
    /// `order.csv` does not parse, or lists a pose outside the manifest's plan grid.
    BadOrder { reason: String },
    /// Captured rows (real or simulated) whose poses the kept order does not list: the order
    /// is not the collection's.
    UnorderedRows { rows: usize, first_pose_id: u32 },
    /// An adaptive collection's `adaptive.csv` does not parse, is missing where rows were
    /// captured, lists a pose outside the plan grid, or does not keep the manifest's budget.
    BadChoices { reason: String },
    /// Captured rows whose poses the adaptive collection's choices do not list.
    UnchosenRows { rows: usize, first_pose_id: u32 },
}

/// A dataset's images as verify reads them, for any reader: each read through the opener (no
/// symlink below the dataset, a regular file, bounded), decoded with bounds, and refused
/// ([`DatasetError::WrongImageSize`]) unless it has the dataset's size: the reference frame's,
/// or without one, the first image's read.
#[derive(Debug)]
pub struct DatasetImages {
    dir: PathBuf,
    size: Option<(u32, u32)>,
}

impl DatasetImages {
    /// The images of the dataset at `dir`, their size taken from its `reference.png` when it
    /// has one (a reference that is a symlink or does not decode is an error).
    pub fn open(dir: &Path) -> Result<Self, DatasetError> {
        let mut images = Self::with_size(dir, None);
        if entry_exists(&dir.join(REFERENCE_FILE), Kind::File)? {
            images.read(Path::new(REFERENCE_FILE))?;
        }
        Ok(images)
    }

    /// The images of the dataset at `dir` whose size is `size` (`None`: the first image read
    /// sets it).
    pub fn with_size(dir: &Path, size: Option<(u32, u32)>) -> Self {
        Self { dir: dir.to_path_buf(), size }
    }

    /// The dataset's folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The dataset's image size, once known.
    pub fn size(&self) -> Option<(u32, u32)> {
        self.size
    }

    /// Reads and decodes the image `rel` (a path below the dataset, `images/3.png`) and checks
    /// its size; an image that decodes is returned with its size error, so verify can go on.
    fn read_checked(&mut self, rel: &Path) -> Result<(image::DynamicImage, Result<(), DatasetError>), DatasetError> {
        let path = self.dir.join(rel);
        let bytes = read_below(&self.dir, rel, MAX_IMAGE_BYTES)?;
        let image = decode_image(&bytes).map_err(|reason| DatasetError::BadImage { path: path.clone(), reason })?;
        let found = (image.width(), image.height());
        let expected = *self.size.get_or_insert(found);
        let sized = if found == expected { Ok(()) } else { Err(DatasetError::WrongImageSize { path, found, expected }) };
        Ok((image, sized))
    }

    /// Reads, decodes and checks the image `rel`: any failure verify would report is an error.
    pub fn read(&mut self, rel: &Path) -> Result<image::DynamicImage, DatasetError> {
        let (image, sized) = self.read_checked(rel)?;
        sized.map(|()| image)
    }
}

impl fmt::Display for VerifyIssue {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            VerifyIssue::MissingImage { pose_id, path } => {
                write!(f, "missing image: pose_id {pose_id} has a row but {} does not exist", path.display())
            }
            VerifyIssue::OrphanImage { path } => write!(f, "orphan image: no row names {}", path.display()),
            VerifyIssue::DuplicateRow { pose_id, first_line, line } => {
                write!(f, "duplicated row: pose_id {pose_id} on line {line} (first on line {first_line})")
            }
            VerifyIssue::MalformedRow { line, reason } => write!(f, "malformed row on line {line}: {reason}"),
            VerifyIssue::TornLastLine { bytes } => {
                write!(f, "torn last line: {bytes} bytes without a newline (an interrupted append)")
            }
            VerifyIssue::TempFile { path } => write!(f, "temporary file left behind: {}", path.display()),
            VerifyIssue::BadHeader { .. } => write!(f, "line 1 of {POSES_FILE} is not a header rig knows"),
            VerifyIssue::BadManifest { reason } => write!(f, "manifest: {reason}"),
            VerifyIssue::NotRegular { path, reason } => write!(f, "{}: {reason}", path.display()),
            VerifyIssue::BadImage { path, reason } => write!(f, "unreadable image {}: {reason}", path.display()),
            VerifyIssue::NotCameraFormat { path, found, camera } => write!(
                f,
                "image {} is {}x{} px, the manifest's camera format is {}x{}",
                path.display(),
                found.0,
                found.1,
                camera.0,
                camera.1
            ),
            VerifyIssue::WrongSize { path, found, expected } => {
                write!(f, "image {} is {}x{} px, the dataset's images are {}x{}", path.display(), found.0, found.1, expected.0, expected.1)
            }
            VerifyIssue::PastPressLimit { pose_id, line, depth_mm, limit } => {
                write!(f, "past the press limit: pose_id {pose_id} on line {line} presses {depth_mm:.3} mm into the skin, beyond {limit}")
            }
            VerifyIssue::BadOrder { reason } => write!(f, "kept order {ORDER_FILE}: {reason}"),
            VerifyIssue::BadChoices { reason } => write!(f, "adaptive choices {CHOICES_FILE}: {reason}"),
            VerifyIssue::UnchosenRows { rows, first_pose_id } => write!(
                f,
                "adaptive choices {CHOICES_FILE}: {rows} captured rows are not among them (first: pose_id {first_pose_id}); they are not this collection's choices"
            ),
            VerifyIssue::UnorderedRows { rows, first_pose_id } => write!(
                f,
                "kept order {ORDER_FILE}: {rows} captured rows are not in it (first: pose_id {first_pose_id}); it is not this collection's order"
            ),
        }
    }
}

/// What [`verify`] found. Counts are of distinct problems; `issues` has the details.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct VerifyReport {
    /// Complete, well-formed rows (duplicates included).
    pub rows: usize,
    /// Files named `<pose_id>.png` in `images/`.
    pub images: usize,
    /// Rows of source `real` / `simulated` / `synthetic`.
    pub real: usize,
    pub simulated: usize,
    pub synthetic: usize,
    /// What the manifest says captured the frames.
    pub capture: CaptureNote,
    pub missing: usize,
    pub orphan: usize,
    pub duplicated: usize,
    /// Malformed lines, the torn last line included.
    pub malformed: usize,
    pub temp_files: usize,
    /// Images (and the reference) that do not decode or have the wrong size.
    pub bad_images: usize,
    /// Symlinks and entries of the wrong kind.
    pub not_regular: usize,
    pub has_reference: bool,
    /// Poses the kept order (`order.csv`) lists; `None` when the dataset keeps none (or it is
    /// unreadable, an issue).
    pub order: Option<usize>,
    pub issues: Vec<VerifyIssue>,
}

/// The manifest's capture chain as [`verify`] found it.
#[derive(Debug, Clone, Default, PartialEq)]
pub enum CaptureNote {
    /// The manifest is missing or unreadable (reported as an issue).
    #[default]
    Unknown,
    /// The manifest names what captured the frames.
    Recorded(Box<CaptureChain>),
    /// The manifest has no capture chain: it predates the field (or no rig captured this
    /// dataset: synthesised or imported). Not an issue; old datasets stay clean.
    Absent,
}

impl fmt::Display for CaptureNote {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CaptureNote::Unknown => write!(f, "capture: unknown (no readable manifest)"),
            CaptureNote::Absent => write!(f, "capture: not recorded (the manifest predates the field, or no rig captured this dataset)"),
            CaptureNote::Recorded(chain) => {
                let parts: Vec<String> = std::iter::once(&chain.arm)
                    .chain(&chain.sensors)
                    .chain(&chain.modbus)
                    .map(|p| {
                        let mut s = format!("{} {}", p.name, p.backend);
                        if let Some(address) = &p.address {
                            s.push_str(&format!(" at {address}"));
                        }
                        if p.simulated {
                            s.push_str(" (simulated)");
                        }
                        s
                    })
                    .collect();
                write!(f, "capture: {}", parts.join(", "))
            }
        }
    }
}

impl VerifyReport {
    /// Rows of `source`.
    pub fn count(&self, source: Source) -> usize {
        match source {
            Source::Real => self.real,
            Source::Simulated => self.simulated,
            Source::Synthetic => self.synthetic,
        }
    }

    /// True when nothing is wrong (a missing `reference.png` is allowed: synthetic-only
    /// datasets have none).
    pub fn is_clean(&self) -> bool {
        self.issues.is_empty()
    }

    /// `clean` or `NOT clean`: the report's last line (`rig dataset verify` prefixes it with
    /// the dataset, so a run over several datasets says which one each verdict is).
    pub fn verdict(&self) -> &'static str {
        if self.is_clean() { "clean" } else { "NOT clean" }
    }
}

impl fmt::Display for VerifyReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "rows {} ({} real, {} simulated, {} synthetic), images {}, reference.png {}",
            self.rows,
            self.real,
            self.simulated,
            self.synthetic,
            self.images,
            if self.has_reference { "present" } else { "absent" }
        )?;
        writeln!(f, "{}", self.capture)?;
        match self.order {
            Some(n) => writeln!(f, "kept order: {n} poses ({ORDER_FILE})")?,
            None => writeln!(f, "kept order: none")?,
        }
        writeln!(
            f,
            "missing {}, orphan {}, duplicated {}, malformed {}, temp files {}, bad images {}, not regular files {}",
            self.missing, self.orphan, self.duplicated, self.malformed, self.temp_files, self.bad_images, self.not_regular
        )?;
        for issue in &self.issues {
            writeln!(f, "  {issue}")?;
        }
        write!(f, "{}", self.verdict())
    }
}

/// Checks the dataset in `dir` without modifying it. Fails only when `dir` has no
/// `poses.csv` or cannot be read.
pub fn verify(dir: &Path) -> Result<VerifyReport, DatasetError> {
    super::require_folder(dir)?;
    let csv_path = dir.join(POSES_FILE);
    if !entry_exists(&csv_path, Kind::File)? {
        return Err(DatasetError::NotADataset { dir: dir.to_path_buf(), missing: POSES_FILE });
    }
    let bytes = read_below(dir, Path::new(POSES_FILE), MAX_POSES_CSV_BYTES)?;
    let parsed = parse_csv(&bytes);
    let mut report = VerifyReport::default();

    let mut grid_len = None;
    // The frame size the manifest gives the camera, if it gives one.
    let mut camera = None;
    let mut adaptive = None;
    match entry_exists(&dir.join(MANIFEST_FILE), Kind::File) {
        Ok(false) => report.issues.push(VerifyIssue::BadManifest { reason: format!("{MANIFEST_FILE} is missing") }),
        Ok(true) => match Manifest::load(dir) {
            Ok(m) => {
                grid_len = m.plan.as_ref().map(|p| p.grid_len());
                camera = camera_format(&m);
                adaptive = m.adaptive;
                report.capture = m.capture.map_or(CaptureNote::Absent, |c| CaptureNote::Recorded(Box::new(c)));
            }
            Err(e) => report.issues.push(VerifyIssue::BadManifest { reason: e.to_string() }),
        },
        Err(e) => report.issues.push(VerifyIssue::BadManifest { reason: e.to_string() }),
    }
    // The dataset's image size: the reference frame's, else the first image's.
    let mut images = DatasetImages::with_size(dir, None);
    let reference = dir.join(REFERENCE_FILE);
    match entry_exists(&reference, Kind::File) {
        Ok(true) => {
            report.has_reference = true;
            let size = check_image(&mut images, Path::new(REFERENCE_FILE), &mut report);
            check_camera_format(&reference, size, None, camera, &mut report);
        }
        Ok(false) => {}
        Err(e) => not_regular(&mut report, &reference, &e),
    }
    // Both the current header and the one from before the `modbus` column are clean.
    if parsed.layout.is_none() {
        report.issues.push(VerifyIssue::BadHeader { found: parsed.header.clone().unwrap_or_default() });
    }

    let mut first_line: BTreeMap<u32, u64> = BTreeMap::new();
    for l in &parsed.lines {
        match &l.row {
            Ok(row) => {
                report.rows += 1;
                match row.source {
                    Source::Real => report.real += 1,
                    Source::Simulated => report.simulated += 1,
                    Source::Synthetic => report.synthetic += 1,
                }
                if let Some(&first) = first_line.get(&row.pose_id) {
                    report.duplicated += 1;
                    report.issues.push(VerifyIssue::DuplicateRow { pose_id: row.pose_id, first_line: first, line: l.line });
                } else {
                    first_line.insert(row.pose_id, l.line);
                }
            }
            Err(reason) => {
                report.malformed += 1;
                report.issues.push(VerifyIssue::MalformedRow { line: l.line, reason: reason.clone() });
            }
        }
    }
    if parsed.torn_bytes > 0 {
        report.malformed += 1;
        report.issues.push(VerifyIssue::TornLastLine { bytes: parsed.torn_bytes });
    }

    for name in list_names(dir)? {
        if is_temp_name(&name) {
            report.temp_files += 1;
            report.issues.push(VerifyIssue::TempFile { path: dir.join(name) });
        }
    }
    let images_dir = dir.join(IMAGES_DIR);
    let mut present = BTreeSet::new();
    let images_ok = match entry_exists(&images_dir, Kind::Folder) {
        Ok(is_dir) => is_dir,
        Err(e) => {
            not_regular(&mut report, &images_dir, &e);
            false
        }
    };
    if images_ok {
        for name in list_names(&images_dir)? {
            let path = images_dir.join(&name);
            if is_temp_name(&name) {
                report.temp_files += 1;
                report.issues.push(VerifyIssue::TempFile { path });
            } else if let Some(id) = image_file_pose_id(&name) {
                if let Err(e) = entry_exists(&path, Kind::File) {
                    // Not counted as present: a row naming it has no image rig will read.
                    not_regular(&mut report, &path, &e);
                    continue;
                }
                report.images += 1;
                present.insert(id);
                if !first_line.contains_key(&id) {
                    report.orphan += 1;
                    report.issues.push(VerifyIssue::OrphanImage { path: path.clone() });
                }
                let expected = images.size();
                let size = check_image(&mut images, &Path::new(IMAGES_DIR).join(&name), &mut report);
                check_camera_format(&path, size, expected, camera, &mut report);
            } else {
                report.orphan += 1;
                report.issues.push(VerifyIssue::OrphanImage { path });
            }
        }
    }
    for &id in first_line.keys() {
        if !present.contains(&id) {
            report.missing += 1;
            report.issues.push(VerifyIssue::MissingImage { pose_id: id, path: dir.join(super::image_rel_path(id)) });
        }
    }
    check_order(dir, &parsed.lines, grid_len, &mut report);
    check_choices(dir, adaptive, &parsed.lines, grid_len, &mut report);
    Ok(report)
}

/// An adaptive collection's choices (`adaptive.csv`): they parse, list only poses of the
/// plan's grid, keep the manifest's budget round by round, and list every captured row's pose
/// (each round is recorded before its first press). A dataset whose manifest has no
/// `[adaptive]` must keep no choices.
fn check_choices(
    dir: &Path,
    settings: Option<crate::plan::adaptive::AdaptiveSettings>,
    lines: &[super::ParsedLine],
    grid_len: Option<u64>,
    report: &mut VerifyReport,
) {
    let path = dir.join(CHOICES_FILE);
    let exists = match entry_exists(&path, Kind::File) {
        Ok(exists) => exists,
        Err(e) => return not_regular(report, &path, &e),
    };
    let mut captured = lines.iter().filter_map(|l| l.row.as_ref().ok()).filter(|r| r.source.is_captured()).map(|r| r.pose_id).peekable();
    let Some(settings) = settings else {
        if exists {
            report.issues.push(VerifyIssue::BadChoices { reason: "present, but the manifest has no [adaptive]".to_string() });
        }
        return;
    };
    if !exists {
        if captured.peek().is_some() {
            report.issues.push(VerifyIssue::BadChoices { reason: "missing, and the adaptive collection has captured rows".to_string() });
        }
        return;
    }
    let choices = match super::choices::read_choices(dir) {
        Ok(choices) => choices.unwrap_or_default(),
        Err(e) => return report.issues.push(VerifyIssue::BadChoices { reason: e.to_string() }),
    };
    let record = crate::plan::adaptive::AdaptiveRecord { settings, choices };
    if let Err(reason) = record.check_choices("the plan's grid", |id| grid_len.is_none_or(|grid| u64::from(id) < grid)) {
        report.issues.push(VerifyIssue::BadChoices { reason });
    }
    let chosen: std::collections::HashSet<u32> = record.choices.iter().map(|c| c.pose_id).collect();
    let unchosen: Vec<u32> = captured.filter(|id| !chosen.contains(id)).collect();
    if let Some(&first_pose_id) = unchosen.first() {
        report.issues.push(VerifyIssue::UnchosenRows { rows: unchosen.len(), first_pose_id });
    }
}

/// The kept order, when the dataset has one: it parses, lists only poses of the plan's grid,
/// and lists every captured row's pose (a collection keeps its order before its first pose).
fn check_order(dir: &Path, lines: &[super::ParsedLine], grid_len: Option<u64>, report: &mut VerifyReport) {
    let path = dir.join(ORDER_FILE);
    match entry_exists(&path, Kind::File) {
        Ok(false) => return,
        Ok(true) => {}
        Err(e) => return not_regular(report, &path, &e),
    }
    let ids = match read_below(dir, Path::new(ORDER_FILE), MAX_ORDER_BYTES).and_then(|bytes| parse_order(&bytes, &path)) {
        Ok(ids) => ids,
        Err(e) => return report.issues.push(VerifyIssue::BadOrder { reason: e.to_string() }),
    };
    report.order = Some(ids.len());
    if let Some(&outside) = grid_len.and_then(|grid| ids.iter().find(|&&id| u64::from(id) >= grid)) {
        report.issues.push(VerifyIssue::BadOrder { reason: format!("pose {outside} is outside the plan's grid") });
    }
    let listed: std::collections::HashSet<u32> = ids.into_iter().collect();
    let unordered: Vec<u32> = lines
        .iter()
        .filter_map(|l| l.row.as_ref().ok())
        .filter(|r| r.source.is_captured() && !listed.contains(&r.pose_id))
        .map(|r| r.pose_id)
        .collect();
    if let Some(&first_pose_id) = unordered.first() {
        report.issues.push(VerifyIssue::UnorderedRows { rows: unordered.len(), first_pose_id });
    }
}

fn not_regular(report: &mut VerifyReport, path: &Path, e: &DatasetError) {
    report.not_regular += 1;
    let reason = match e {
        DatasetError::Symlink { .. } | DatasetError::Confined(crate::confine::ConfineError::Symlink { .. }) => {
            "a symlink (rig does not follow symlinks inside a dataset)".to_string()
        }
        DatasetError::NotRegular { expected, .. } => format!("not {expected}"),
        other => other.to_string(),
    };
    report.issues.push(VerifyIssue::NotRegular { path: path.to_path_buf(), reason });
}

/// Reads the image `rel` through `images` (the readers' rules); records an issue when it does
/// not decode or is not the dataset's size. Returns its size when it decodes.
fn check_image(images: &mut DatasetImages, rel: &Path, report: &mut VerifyReport) -> Option<(u32, u32)> {
    let path = images.dir.join(rel);
    match images.read_checked(rel) {
        Ok((image, Ok(()))) => Some((image.width(), image.height())),
        Ok((_, Err(DatasetError::WrongImageSize { path, found, expected }))) => {
            report.bad_images += 1;
            report.issues.push(VerifyIssue::WrongSize { path, found, expected });
            Some(found)
        }
        Ok((_, Err(other))) | Err(other) => {
            report.bad_images += 1;
            let reason = match other {
                DatasetError::BadImage { reason, .. } => reason,
                other => other.to_string(),
            };
            report.issues.push(VerifyIssue::BadImage { path, reason });
            None
        }
    }
}

/// The frame size the manifest's capture chain gives the dataset's camera (the `resolution_px`
/// of the sensor part named like the dataset's sensor), if it gives one.
fn camera_format(manifest: &Manifest) -> Option<(u32, u32)> {
    let sensor = manifest.sensor.to_string();
    let part = manifest.capture.as_ref()?.sensors.iter().find(|p| p.name == sensor)?;
    part.resolution_px.map(|[width, height]| (width, height))
}

/// Records an issue when an image that decoded to `found` is not the camera's size. Apart from
/// the check against the dataset's size (the reference's), which images of one wrong size all
/// pass: a dataset of 1 x 1 images whose manifest says 64 x 64 is not clean. An image already
/// counted as of the wrong size for the dataset (`dataset`) is not counted twice.
fn check_camera_format(
    path: &Path,
    found: Option<(u32, u32)>,
    dataset: Option<(u32, u32)>,
    camera: Option<(u32, u32)>,
    report: &mut VerifyReport,
) {
    let (Some(found), Some(camera)) = (found, camera) else { return };
    if found != camera {
        if dataset.is_none_or(|size| size == found) {
            report.bad_images += 1;
        }
        report.issues.push(VerifyIssue::NotCameraFormat { path: path.to_path_buf(), found, camera });
    }
}

fn list_names(dir: &Path) -> Result<Vec<String>, DatasetError> {
    let mut names = Vec::new();
    for e in std::fs::read_dir(dir).map_err(DatasetError::io("listing", dir))? {
        names.push(e.map_err(DatasetError::io("listing", dir))?.file_name().to_string_lossy().into_owned());
    }
    names.sort();
    Ok(names)
}
