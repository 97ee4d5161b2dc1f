//! The crash-safe, append-only dataset writer.
//!
//! Order of durable steps for one pose (a SIGKILL may land between any two):
//!
//! 1. encode the PNG in memory, write it to `images/.<pose_id>.png.tmp`, fsync the file;
//! 2. rename it to `images/<pose_id>.png`, fsync `images/`;
//! 3. append the CSV line to `poses.csv` with one `write` call, fsync the file.
//!
//! What each kill point leaves, and what [`DatasetWriter::resume`] does with it:
//! before 2, a temp file (deleted); between 2 and 3, an image without a row (an orphan,
//! deleted so the pose is captured again); during 3, a torn last line without its newline
//! (truncated away, and its image becomes an orphan). The set of done pose ids is the set of
//! complete CSV rows, each of which names an image that was durable before the row was.
//!
//! A writer holds an exclusive lock (`flock`) on the dataset folder itself, taken before it looks at
//! or creates anything there, so two processes never write one dataset at once (two runs
//! racing into an empty folder: the second is told the dataset is held by another process);
//! the kernel drops the lock when the process dies, so a killed run never blocks its resume.
//!
//! Nothing inside the dataset is followed through a symlink ([`super::durable`]): a symlinked
//! `images/`, `poses.csv`, `manifest.toml` or image is an error, never a place to write.
//!
//! Every write goes through folder descriptors the writer opens once and holds
//! ([`crate::confine::RootDir`]): the dataset folder, and `images/` below it (opened with
//! `O_NOFOLLOW | O_DIRECTORY`, so a symlink there is refused). An image's temp file is created
//! and renamed relative to the held `images/` descriptor, so swapping `images/` for a symlink
//! while a run writes cannot send an image anywhere else: it lands in the folder that was
//! checked, and its row is appended only after it is durable there. `poses.csv` is opened once
//! through the held dataset descriptor, and refused when it has another name (a hard link:
//! appending would grow a file outside the dataset).

use std::collections::BTreeSet;
use std::fs::File;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

use image::RgbImage;

use super::durable::dataset_error;
use super::manifest::{Manifest, utc_now};
use super::{
    COLUMNS, CsvLayout, DatasetError, IMAGES_DIR, MANIFEST_FILE, POSES_FILE, PoseRow, REFERENCE_FILE, RowProblem, header_line,
    image_rel_path, parse_csv, row_line, strict_rows,
};
use crate::confine::{EntryKind, RootDir};

/// Appends rows and images to one dataset directory. See the module docs for the guarantees.
#[derive(Debug)]
pub struct DatasetWriter {
    dir: PathBuf,
    manifest: Manifest,
    /// The dataset folder, open and `flock`ed for the writer's life; every write in it goes
    /// through this descriptor.
    root: RootDir,
    /// `images/`, opened once below `root` without following a symlink.
    images: RootDir,
    csv: File,
    /// Length of `poses.csv` after the last complete line, to undo a failed partial append.
    csv_len: u64,
    done: BTreeSet<u32>,
    /// Bytes this writer may still write before it reports a full disk (fault injection:
    /// `[sim.faults] disk_budget_bytes`); `None` = only the real disk's limit.
    budget_left_bytes: Option<u64>,
}

impl DatasetWriter {
    /// Starts a new dataset in `dir` (created if absent). Refuses a directory that holds
    /// anything, so an existing dataset is never overwritten.
    pub fn create(dir: &Path, manifest: Manifest) -> Result<Self, DatasetError> {
        let root = lock_dir(dir, true)?;
        Self::create_locked(dir, manifest, root)
    }

    fn create_locked(dir: &Path, manifest: Manifest, root: RootDir) -> Result<Self, DatasetError> {
        if !root.entries("").map_err(dataset_error)?.is_empty() {
            return Err(DatasetError::NotEmpty { dir: dir.to_path_buf() });
        }
        root.create_dir_all(IMAGES_DIR).map_err(dataset_error)?;
        manifest.store_in(&root)?;
        root.write_atomic(POSES_FILE, header_line().as_bytes()).map_err(dataset_error)?;
        if let Some(parent) = dir.parent().filter(|p| !p.as_os_str().is_empty()) {
            super::durable::fsync_dir(parent)?;
        }
        Self::open_existing(dir, manifest, false, root)
    }

    /// Continues the dataset in `dir` exactly where a previous (possibly killed) run stopped,
    /// or creates it when `dir` is absent or empty. Refuses when the existing manifest's
    /// sensor, object or plan differ from `manifest`'s, naming the field. The existing
    /// manifest is kept (its start time included) and this run's start is added to
    /// `resumed_utc`.
    pub fn resume(dir: &Path, manifest: Manifest) -> Result<Self, DatasetError> {
        let root = lock_dir(dir, true)?;
        if root.entries("").map_err(dataset_error)?.is_empty() {
            return Self::create_locked(dir, manifest, root);
        }
        if remove_creation_stub(&root)? {
            return Self::create_locked(dir, manifest, root);
        }
        let existing = Manifest::load(dir)?;
        existing.check_same_dataset(&manifest, dir)?;
        Self::open_existing(dir, existing, true, root)
    }

    /// [`resume`](Self::resume) when `resume` is set (the `--resume` flag), else
    /// [`create`](Self::create).
    pub fn start(dir: &Path, manifest: Manifest, resume: bool) -> Result<Self, DatasetError> {
        if resume { Self::resume(dir, manifest) } else { Self::create(dir, manifest) }
    }

    /// Opens an existing dataset to append to it under its own manifest (what
    /// `rig synth --fill-missing` does), repairing it as [`resume`](Self::resume) does.
    pub fn open(dir: &Path) -> Result<Self, DatasetError> {
        let root = lock_dir(dir, false)?;
        if !exists(&root, MANIFEST_FILE, EntryKind::File)? {
            return Err(DatasetError::NotADataset { dir: dir.to_path_buf(), missing: MANIFEST_FILE });
        }
        let existing = Manifest::load(dir)?;
        Self::open_existing(dir, existing, true, root)
    }

    fn open_existing(dir: &Path, mut manifest: Manifest, resumed: bool, root: RootDir) -> Result<Self, DatasetError> {
        let csv_path = dir.join(POSES_FILE);
        if !exists(&root, POSES_FILE, EntryKind::File)? {
            // Killed between the manifest and the header of a new dataset.
            root.write_atomic(POSES_FILE, header_line().as_bytes()).map_err(dataset_error)?;
        }
        let mut csv = root.open_append(POSES_FILE).map_err(dataset_error)?;
        if csv.metadata().map_err(DatasetError::io("reading", &csv_path))?.len() > super::durable::MAX_POSES_CSV_BYTES {
            return Err(DatasetError::TooLarge { path: csv_path, max_bytes: super::durable::MAX_POSES_CSV_BYTES });
        }

        let mut bytes = Vec::new();
        csv.read_to_end(&mut bytes).map_err(DatasetError::io("reading", &csv_path))?;
        let parsed = parse_csv(&bytes);
        let layout = parsed.layout;
        let complete_len = parsed.complete_len as usize;
        match parsed.header.as_deref() {
            Some(_) if layout.is_some() => {
                if parsed.torn_bytes > 0 {
                    tracing::warn!(bytes = parsed.torn_bytes, "truncating a torn last line of {}", csv_path.display());
                    csv.set_len(parsed.complete_len).map_err(DatasetError::io("truncating", &csv_path))?;
                    csv.sync_all().map_err(DatasetError::io("syncing", &csv_path))?;
                }
            }
            None if parsed.lines.is_empty() => {
                csv.set_len(0).map_err(DatasetError::io("truncating", &csv_path))?;
                csv.write_all(header_line().as_bytes()).map_err(DatasetError::io("writing", &csv_path))?;
                csv.sync_all().map_err(DatasetError::io("syncing", &csv_path))?;
            }
            found => {
                return Err(DatasetError::BadHeader {
                    path: csv_path,
                    found: found.unwrap_or_default().to_string(),
                    expected: COLUMNS.join(","),
                });
            }
        }

        let done: BTreeSet<u32> = strict_rows(parsed.lines, &csv_path)?.iter().map(|r| r.pose_id).collect();
        if layout == Some(CsvLayout::Legacy) {
            // Only after every row parsed: a damaged file is reported, never rewritten.
            csv = upgrade_legacy_csv(&root, &bytes[..complete_len], csv)?;
        }

        remove_temp_files(&root)?;
        exists(&root, REFERENCE_FILE, EntryKind::File)?;
        let images = root.create_dir_all(IMAGES_DIR).map_err(dataset_error)?;
        remove_temp_files(&images)?;
        let mut present = BTreeSet::new();
        for entry in images.entries("").map_err(dataset_error)? {
            let Some(id) = entry.name.to_str().and_then(image_file_pose_id) else { continue };
            // An image must be a regular file: a symlink here could name any file on the machine.
            let path = images.path().join(&entry.name);
            match entry.kind {
                EntryKind::File => {}
                EntryKind::Symlink => return Err(DatasetError::Symlink { path }),
                _ => return Err(DatasetError::NotRegular { path, expected: "a regular file" }),
            }
            if done.contains(&id) {
                present.insert(id);
            } else {
                // Its row never became durable: capture this pose again.
                tracing::info!(pose_id = id, "removing orphan image");
                images.remove_file(&entry.name).map_err(dataset_error)?;
            }
        }
        images.sync().map_err(dataset_error)?;
        if let Some(&pose_id) = done.difference(&present).next() {
            return Err(DatasetError::MissingImage { pose_id, path: dir.join(image_rel_path(pose_id)) });
        }

        if resumed {
            manifest.resumed_utc.push(utc_now());
            manifest.store_in(&root)?;
        }
        let csv_len = csv.metadata().map_err(DatasetError::io("reading", &csv_path))?.len();
        Ok(Self { dir: dir.to_path_buf(), manifest, root, images, csv, csv_len, done, budget_left_bytes: None })
    }

    /// Limits the bytes of images and rows this writer may write; past it every write fails
    /// as a full disk would (`ENOSPC`), before anything of that write lands. Simulates a full
    /// disk without a size-limited filesystem.
    pub fn with_byte_budget(mut self, budget_bytes: Option<u64>) -> Self {
        self.budget_left_bytes = budget_bytes;
        self
    }

    /// Takes `bytes` from the budget, or fails with the error a full disk gives.
    fn spend(&mut self, bytes: u64, path: &Path) -> Result<(), DatasetError> {
        match self.budget_left_bytes {
            Some(left) if bytes > left => Err(DatasetError::io("writing", path)(std::io::Error::from_raw_os_error(libc::ENOSPC))),
            Some(left) => {
                self.budget_left_bytes = Some(left - bytes);
                Ok(())
            }
            None => Ok(()),
        }
    }

    /// The dataset directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The manifest in force (the existing one when resumed).
    pub fn manifest(&self) -> &Manifest {
        &self.manifest
    }

    /// Pose ids that have a durable row.
    pub fn done_ids(&self) -> &BTreeSet<u32> {
        &self.done
    }

    /// Whether the dataset has its no-contact reference frame (a regular `reference.png`).
    pub fn has_reference(&self) -> bool {
        matches!(self.root.stat(REFERENCE_FILE), Ok(Some(info)) if info.kind == EntryKind::File)
    }

    /// Writes (or replaces) `reference.png` atomically.
    pub fn write_reference(&mut self, image: &RgbImage) -> Result<(), DatasetError> {
        let png = encode_png(image, u32::MAX)?;
        self.spend(png.len() as u64, &self.dir.join(REFERENCE_FILE))?;
        self.root.write_atomic(REFERENCE_FILE, &png).map_err(dataset_error)
    }

    /// Durably appends one pose: image first, then its row. Sets `row.image` to
    /// `images/<pose_id>.png`. Refuses a pose id that already has a row.
    pub fn append(&mut self, row: PoseRow, image: &RgbImage) -> Result<(), DatasetError> {
        if self.done.contains(&row.pose_id) {
            return Err(DatasetError::DuplicatePose { pose_id: row.pose_id });
        }
        let png = encode_png(image, row.pose_id)?;
        self.append_png(row, &png)
    }

    /// [`append`](Self::append) with an already encoded PNG (merging copies files unchanged).
    pub(crate) fn append_png(&mut self, mut row: PoseRow, png: &[u8]) -> Result<(), DatasetError> {
        let pose_id = row.pose_id;
        if self.done.contains(&pose_id) {
            return Err(DatasetError::DuplicatePose { pose_id });
        }
        row.image = image_rel_path(pose_id);
        if let Some(problem) = row.problem() {
            return Err(DatasetError::InvalidRow { pose_id, problem });
        }
        let line = row_line(&row)?;
        if line.iter().filter(|&&b| b == b'\n').count() != 1 {
            return Err(DatasetError::InvalidRow { pose_id, problem: RowProblem::Multiline });
        }

        let name = format!("{pose_id}.png");
        self.spend((png.len() + line.len()) as u64, &self.images.path().join(&name))?;
        // Into the `images/` folder held since the writer opened (whatever its name now leads
        // to), durable before the row is.
        self.images.write_atomic(&name, png).map_err(dataset_error)?;

        let csv_path = self.dir.join(POSES_FILE);
        // One write call of the whole line: a kill leaves either nothing or a prefix of it.
        let result = match self.csv.write(&line) {
            Ok(n) if n == line.len() => Ok(()),
            Ok(n) => self.csv.write_all(&line[n..]),
            Err(e) => Err(e),
        }
        .and_then(|()| self.csv.sync_data());
        if let Err(e) = result {
            // Undo a partial line so later appends do not glue onto it.
            let _ = self.csv.set_len(self.csv_len);
            return Err(DatasetError::io("appending to", csv_path)(e));
        }
        self.csv_len += line.len() as u64;
        self.done.insert(pose_id);
        Ok(())
    }

    /// Changes the manifest in force and writes it atomically (what a collection does at its
    /// end with the stream counts of its cameras).
    pub fn update_manifest(&mut self, change: impl FnOnce(&mut Manifest)) -> Result<(), DatasetError> {
        change(&mut self.manifest);
        self.manifest.store_in(&self.root)
    }

    /// Records the end time in the manifest and releases the dataset.
    pub fn finish(mut self) -> Result<Manifest, DatasetError> {
        self.manifest.ended_utc = Some(utc_now());
        self.manifest.store_in(&self.root)?;
        Ok(self.manifest)
    }
}

/// Rewrites a `poses.csv` from before the `modbus` column with the current header and an
/// empty `modbus` field on every row, so that appended rows match the header. `legacy` is the
/// file's complete lines (a torn tail already cut). Crash-safe like every other write (temp
/// file, fsync, rename, fsync the directory): a kill leaves the old file or the new one, and
/// either resumes. Each row keeps its bytes; only `,` is added before its line end. Returns the
/// new file, opened for appending and locked (the old handle, and its lock, are dropped).
fn upgrade_legacy_csv(root: &RootDir, legacy: &[u8], old: File) -> Result<File, DatasetError> {
    let csv_path = root.path().join(POSES_FILE);
    let mut upgraded = header_line().into_bytes();
    for line in legacy.split_inclusive(|&b| b == b'\n').skip(1) {
        let body = line.strip_suffix(b"\n").unwrap_or(line);
        let (body, cr) = match body.strip_suffix(b"\r") {
            Some(b) => (b, &b"\r"[..]),
            None => (body, &b""[..]),
        };
        if body.is_empty() {
            continue;
        }
        upgraded.extend_from_slice(body);
        upgraded.push(b',');
        upgraded.extend_from_slice(cr);
        upgraded.push(b'\n');
    }
    tracing::info!("adding the modbus column to {}", csv_path.display());
    root.write_atomic(POSES_FILE, &upgraded).map_err(dataset_error)?;
    let csv = root.open_append(POSES_FILE).map_err(dataset_error)?;
    drop(old);
    Ok(csv)
}

fn encode_png(image: &RgbImage, pose_id: u32) -> Result<Vec<u8>, DatasetError> {
    let mut png = Vec::new();
    image
        .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .map_err(|source| DatasetError::Encode { pose_id, source })?;
    Ok(png)
}

/// The pose id of an image file name `<pose_id>.png`.
pub(crate) fn image_file_pose_id(name: &str) -> Option<u32> {
    let stem = name.strip_suffix(".png")?;
    if stem.is_empty() || !stem.bytes().all(|b| b.is_ascii_digit()) || (stem.len() > 1 && stem.starts_with('0')) {
        return None;
    }
    stem.parse().ok()
}

/// True for the writer's temporary files (`.<name>.tmp`).
pub(crate) fn is_temp_name(name: &str) -> bool {
    name.starts_with('.') && name.ends_with(".tmp")
}

/// Whether `name` in `folder` exists as `kind`: `Ok(false)` when absent, an error when it is a
/// symlink or something else (never followed).
fn exists(folder: &RootDir, name: &str, kind: EntryKind) -> Result<bool, DatasetError> {
    let path = || folder.path().join(name);
    match folder.stat(name).map_err(dataset_error)? {
        None => Ok(false),
        Some(info) if info.kind == kind => Ok(true),
        Some(info) if info.kind == EntryKind::Symlink => Err(DatasetError::Symlink { path: path() }),
        Some(_) => Err(DatasetError::NotRegular { path: path(), expected: kind.describe() }),
    }
}

/// A creation killed before the manifest landed leaves only temp files and an empty
/// `images/`; removes them and reports true. Anything else is left alone (false).
fn remove_creation_stub(root: &RootDir) -> Result<bool, DatasetError> {
    let names = |entries: Vec<crate::confine::Entry>| -> Vec<String> {
        entries.into_iter().map(|e| e.name.to_string_lossy().into_owned()).collect()
    };
    let top = names(root.entries("").map_err(dataset_error)?);
    let images_is_dir = exists(root, IMAGES_DIR, EntryKind::Folder)?;
    let stub_top = top.iter().all(|n| (n == IMAGES_DIR && images_is_dir) || is_temp_name(n));
    if !stub_top {
        return Ok(false);
    }
    if images_is_dir {
        let images = root.open_dir(IMAGES_DIR).map_err(dataset_error)?;
        if !names(images.entries("").map_err(dataset_error)?).iter().all(|n| is_temp_name(n)) {
            return Ok(false);
        }
        remove_temp_files(&images)?;
        root.remove_dir(IMAGES_DIR).map_err(dataset_error)?;
    }
    remove_temp_files(root)?;
    Ok(true)
}

/// Removes the writer's temp files (`.<name>.tmp`) in `folder`: a symlinked one is removed as
/// the link, never its target.
fn remove_temp_files(folder: &RootDir) -> Result<(), DatasetError> {
    let mut removed = false;
    for entry in folder.entries("").map_err(dataset_error)? {
        let removable = matches!(entry.kind, EntryKind::File | EntryKind::Symlink);
        if removable && is_temp_name(&entry.name.to_string_lossy()) {
            folder.remove_file(&entry.name).map_err(dataset_error)?;
            removed = true;
        }
    }
    if removed {
        folder.sync().map_err(dataset_error)?;
    }
    Ok(())
}

/// Opens the dataset folder (created first when `create` and absent) and takes its lock.
fn lock_dir(dir: &Path, create: bool) -> Result<RootDir, DatasetError> {
    if create {
        std::fs::create_dir_all(dir).map_err(DatasetError::io("creating", dir))?;
    }
    let folder = match RootDir::open(dir) {
        Err(crate::confine::ConfineError::NotFolder { .. }) => {
            return Err(DatasetError::NotRegular { path: dir.to_path_buf(), expected: "a folder" });
        }
        other => other.map_err(dataset_error)?,
    };
    lock_exclusive(&folder, dir)?;
    Ok(folder)
}

fn lock_exclusive(folder: &RootDir, path: &Path) -> Result<(), DatasetError> {
    // `flock(LOCK_EX | LOCK_NB)`: advisory, whole-file, dropped with the descriptor (and so
    // when the process dies).
    match rustix::fs::flock(folder, rustix::fs::FlockOperation::NonBlockingLockExclusive) {
        Ok(()) => Ok(()),
        Err(rustix::io::Errno::WOULDBLOCK) => Err(DatasetError::Locked { path: path.to_path_buf() }),
        Err(e) => Err(DatasetError::Io { op: "locking", path: path.to_path_buf(), source: e.into() }),
    }
}

#[cfg(test)]
mod tests {
    use std::fs::OpenOptions;

    use super::*;
    use crate::dataset::{ObjectInfo, Source};
    use crate::pose::Pose;

    fn manifest() -> Manifest {
        Manifest::new(crate::sensor::SensorKind::TacTip, ObjectInfo::named("edge"), Some(crate::plan::PlanSpec::default()))
    }

    fn img(v: u8) -> RgbImage {
        RgbImage::from_fn(8, 6, |x, y| image::Rgb([v, x as u8, y as u8]))
    }

    fn row(id: u32) -> PoseRow {
        PoseRow::real(id, Pose::new(id as f64, 0.0, 0.0, 0.0), Pose::new(id as f64 + 0.01, 0.0, 0.0, 0.0), id as f64)
    }

    #[test]
    fn a_spent_byte_budget_is_a_full_disk_and_the_dataset_resumes() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("ds");
        let one = encode_png(&img(1), 1).unwrap().len() as u64 + row_line(&row(1)).unwrap().len() as u64;
        // Room for two poses and a part of a third.
        let mut w = DatasetWriter::create(&dir, manifest()).unwrap().with_byte_budget(Some(2 * one + one / 2));
        w.append(row(1), &img(1)).unwrap();
        w.append(row(2), &img(2)).unwrap();
        let e = w.append(row(3), &img(3)).unwrap_err();
        assert!(matches!(&e, DatasetError::DiskFull { source, .. } if source.raw_os_error() == Some(libc::ENOSPC)), "{e}");
        // It suggests commands that exist: collect and import resume with --resume, a fill
        // (`rig synth`) by itself; there is no `rig synth --resume`.
        assert!(e.to_string().contains("--resume") && e.to_string().contains("`rig synth`"), "{e}");
        assert!(!e.to_string().contains("synth --resume"), "{e}");
        drop(w);
        let mut w = DatasetWriter::resume(&dir, manifest()).unwrap();
        assert_eq!(w.done_ids().iter().copied().collect::<Vec<_>>(), vec![1, 2]);
        w.append(row(3), &img(3)).unwrap();
        assert_eq!(crate::dataset::read_rows(&dir).unwrap().len(), 3);
    }

    #[test]
    fn writers_racing_into_an_empty_folder_one_wins_and_the_others_hear_it_is_held() {
        use std::sync::{Arc, Barrier};
        for _ in 0..10 {
            let tmp = tempfile::tempdir().unwrap();
            let dir = tmp.path().join("ds");
            let barrier = Arc::new(Barrier::new(4));
            let attempts: Vec<_> = (0..4)
                .map(|_| {
                    let (barrier, dir) = (Arc::clone(&barrier), dir.clone());
                    std::thread::spawn(move || {
                        barrier.wait();
                        let result = DatasetWriter::resume(&dir, manifest());
                        // Every attempt is made while the winner still holds its writer.
                        barrier.wait();
                        result.map(|_| ())
                    })
                })
                .collect();
            let results: Vec<_> = attempts.into_iter().map(|t| t.join().unwrap()).collect();
            assert_eq!(results.iter().filter(|r| r.is_ok()).count(), 1, "{results:?}");
            for e in results.iter().filter_map(|r| r.as_ref().err()) {
                assert!(matches!(e, DatasetError::Locked { .. }), "{e}");
                assert!(e.to_string().contains("held by another process"), "{e}");
            }
            assert!(crate::dataset::verify(&dir).unwrap().is_clean());
        }
    }

    #[test]
    fn symlinks_inside_a_dataset_are_refused_not_followed() {
        use std::os::unix::fs::symlink;
        let tmp = tempfile::tempdir().unwrap();
        let outside = tmp.path().join("outside");
        std::fs::create_dir(&outside).unwrap();
        std::fs::write(outside.join("secret"), "sentinel").unwrap();
        let make = |name: &str| {
            let dir = tmp.path().join(name);
            let mut w = DatasetWriter::create(&dir, manifest()).unwrap();
            w.append(row(1), &img(1)).unwrap();
            drop(w);
            dir
        };
        let dir = make("csv");
        std::fs::rename(dir.join(POSES_FILE), tmp.path().join("moved.csv")).unwrap();
        symlink(outside.join("secret"), dir.join(POSES_FILE)).unwrap();
        assert!(matches!(DatasetWriter::resume(&dir, manifest()), Err(DatasetError::Symlink { .. })));
        let dir = make("images");
        std::fs::remove_dir_all(dir.join(IMAGES_DIR)).unwrap();
        symlink(&outside, dir.join(IMAGES_DIR)).unwrap();
        assert!(matches!(DatasetWriter::resume(&dir, manifest()), Err(DatasetError::Symlink { .. })));
        let dir = make("image");
        std::fs::remove_file(dir.join("images/1.png")).unwrap();
        symlink(outside.join("secret"), dir.join("images/1.png")).unwrap();
        assert!(matches!(DatasetWriter::open(&dir), Err(DatasetError::Symlink { .. })));
        let dir = make("manifest");
        std::fs::rename(dir.join(MANIFEST_FILE), tmp.path().join("moved.toml")).unwrap();
        symlink(outside.join("secret"), dir.join(MANIFEST_FILE)).unwrap();
        assert!(matches!(DatasetWriter::open(&dir), Err(DatasetError::Symlink { .. })));
        assert_eq!(std::fs::read_to_string(outside.join("secret")).unwrap(), "sentinel");
        assert_eq!(std::fs::read_dir(&outside).unwrap().count(), 1, "nothing was written outside");
    }

    #[test]
    fn a_hard_linked_poses_csv_is_refused_and_left_alone() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("ds");
        let mut w = DatasetWriter::create(&dir, manifest()).unwrap();
        w.append(row(1), &img(1)).unwrap();
        drop(w);
        let outside = tmp.path().join("outside.csv");
        std::fs::rename(dir.join(POSES_FILE), &outside).unwrap();
        std::fs::hard_link(&outside, dir.join(POSES_FILE)).unwrap();
        let before = std::fs::read(&outside).unwrap();
        let e = DatasetWriter::resume(&dir, manifest()).unwrap_err();
        assert!(matches!(e, DatasetError::Confined(crate::confine::ConfineError::HardLinked { .. })), "{e}");
        assert!(e.to_string().contains("poses.csv") && e.to_string().contains("hard link"), "{e}");
        assert!(matches!(DatasetWriter::open(&dir), Err(DatasetError::Confined(_))));
        assert_eq!(std::fs::read(&outside).unwrap(), before);
    }

    /// The writer keeps the `images/` it opened: renamed away (a swap for a symlink), an image
    /// still lands in it, never in what the name leads to now.
    #[test]
    fn images_land_in_the_folder_opened_whatever_its_name_leads_to() {
        use std::os::unix::fs::symlink;
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("ds");
        let target = tmp.path().join("target");
        std::fs::create_dir(&target).unwrap();
        let mut w = DatasetWriter::create(&dir, manifest()).unwrap();
        std::fs::rename(dir.join(IMAGES_DIR), dir.join("images.real")).unwrap();
        symlink(&target, dir.join(IMAGES_DIR)).unwrap();
        w.append(row(1), &img(1)).unwrap();
        assert_eq!(std::fs::read_dir(&target).unwrap().count(), 0, "nothing through the link");
        assert!(dir.join("images.real/1.png").is_file());
    }

    #[test]
    fn enospc_from_the_os_is_a_disk_full_error() {
        let e = DatasetError::io("writing", "x")(std::io::Error::from_raw_os_error(libc::ENOSPC));
        assert!(matches!(e, DatasetError::DiskFull { .. }), "{e}");
        let e = DatasetError::io("writing", "x")(std::io::Error::from_raw_os_error(libc::EACCES));
        assert!(matches!(e, DatasetError::Io { .. }), "{e}");
    }

    #[test]
    fn create_refuses_non_empty_and_resume_repairs() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("ds");
        let mut w = DatasetWriter::create(&dir, manifest()).unwrap();
        w.write_reference(&img(0)).unwrap();
        for id in [4, 9, 2] {
            w.append(row(id), &img(id as u8)).unwrap();
        }
        assert!(matches!(w.append(row(9), &img(1)), Err(DatasetError::DuplicatePose { pose_id: 9 })));
        // A second writer is locked out while the first is open.
        assert!(matches!(DatasetWriter::open(&dir), Err(DatasetError::Locked { .. })));
        drop(w);
        assert!(matches!(DatasetWriter::create(&dir, manifest()), Err(DatasetError::NotEmpty { .. })));

        // Simulate a kill: orphan image, temp file, torn line.
        std::fs::write(dir.join("images/7.png"), b"x").unwrap();
        std::fs::write(dir.join("images/.8.png.tmp"), b"x").unwrap();
        let mut f = OpenOptions::new().append(true).open(dir.join(POSES_FILE)).unwrap();
        f.write_all(&row_line(&row(7)).unwrap()[..12]).unwrap();
        drop(f);

        let w = DatasetWriter::resume(&dir, manifest()).unwrap();
        assert_eq!(w.done_ids().iter().copied().collect::<Vec<_>>(), vec![2, 4, 9]);
        assert!(!dir.join("images/7.png").exists());
        assert!(!dir.join("images/.8.png.tmp").exists());
        assert_eq!(w.manifest().resumed_utc.len(), 1);
        let text = std::fs::read_to_string(dir.join(POSES_FILE)).unwrap();
        assert!(text.ends_with('\n') && text.lines().count() == 4, "{text}");
        let m = w.finish().unwrap();
        assert!(m.ended_utc.is_some());
        let back = image::open(dir.join("images/9.png")).unwrap().to_rgb8();
        assert_eq!(back, img(9));
    }

    #[test]
    fn resume_refuses_other_dataset_and_creates_when_absent() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("a/b");
        let w = DatasetWriter::resume(&dir, manifest()).unwrap();
        assert!(w.done_ids().is_empty());
        drop(w);
        let mut other = manifest();
        other.sensor = crate::sensor::SensorKind::ViTac;
        let err = DatasetWriter::resume(&dir, other).unwrap_err();
        assert!(matches!(err, DatasetError::ManifestMismatch { field: "sensor", .. }), "{err}");
        let mut other = manifest();
        other.plan.as_mut().unwrap().n_poses = Some(10);
        let err = DatasetWriter::resume(&dir, other).unwrap_err();
        assert!(matches!(err, DatasetError::ManifestMismatch { field: "plan", .. }), "{err}");
    }

    #[test]
    fn synthetic_rows_and_invalid_rows() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("ds");
        let mut w = DatasetWriter::create(&dir, manifest()).unwrap();
        w.append(PoseRow::synthetic(1, Pose::default(), "mds", 5, 50, 1.0), &img(1)).unwrap();
        let mut bad = row(2);
        bad.x_mm = f64::NAN;
        assert!(matches!(w.append(bad, &img(2)), Err(DatasetError::InvalidRow { pose_id: 2, .. })));
        let mut multi = PoseRow::synthetic(3, Pose::default(), "a\nb", 5, 50, 1.0);
        assert!(matches!(w.append(multi.clone(), &img(3)), Err(DatasetError::InvalidRow { pose_id: 3, .. })));
        multi.model = Some("ok".into());
        w.append(multi, &img(3)).unwrap();
        drop(w);
        let w = DatasetWriter::open(&dir).unwrap();
        assert_eq!(w.done_ids().len(), 2);
        let text = std::fs::read_to_string(dir.join(POSES_FILE)).unwrap();
        assert!(text.contains(",synthetic,"));
        assert!(matches!(Source::Real.to_string().as_str(), "real"));
    }

    #[test]
    fn a_dataset_from_before_the_modbus_column_reads_verifies_and_resumes() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("ds");
        let mut w = DatasetWriter::create(&dir, manifest()).unwrap();
        w.append(row(1), &img(1)).unwrap();
        w.append(row(2), &img(2)).unwrap();
        drop(w);
        // Rewrite it as an old rig wrote it: 17 columns, no modbus field; a torn tail too.
        let current = std::fs::read_to_string(dir.join(POSES_FILE)).unwrap();
        let mut legacy = format!("{}\n", crate::dataset::LEGACY_COLUMNS.join(","));
        for line in current.lines().skip(1) {
            legacy.push_str(line.strip_suffix(',').unwrap());
            legacy.push('\n');
        }
        let legacy_complete = legacy.clone();
        legacy.push_str("3,1,0,0");
        std::fs::write(dir.join(POSES_FILE), &legacy).unwrap();

        // Readers take it as it is.
        let report = crate::dataset::verify(&dir).unwrap();
        assert_eq!((report.rows, report.issues.len()), (2, 1), "only the torn tail: {report:?}");
        let rows = crate::dataset::read_rows(&dir).unwrap();
        assert_eq!(rows, vec![row(1), row(2)]);
        assert_eq!(std::fs::read_to_string(dir.join(POSES_FILE)).unwrap(), legacy, "readers never write");

        // A writer upgrades it: same rows, an empty modbus field each, then appends.
        let mut w = DatasetWriter::resume(&dir, manifest()).unwrap();
        assert_eq!(w.done_ids().iter().copied().collect::<Vec<_>>(), vec![1, 2]);
        w.append(row(3).with_modbus("force.force_N=1.5".into()), &img(3)).unwrap();
        drop(w);
        let text = std::fs::read_to_string(dir.join(POSES_FILE)).unwrap();
        let mut lines = text.lines();
        assert_eq!(lines.next(), Some(COLUMNS.join(",").as_str()));
        for (old, new) in legacy_complete.lines().skip(1).zip(lines.by_ref()) {
            assert_eq!(format!("{old},"), new);
        }
        assert!(lines.next().unwrap().ends_with(",force.force_N=1.5"), "{text}");
        assert!(crate::dataset::verify(&dir).unwrap().is_clean());
        assert_eq!(crate::dataset::read_rows(&dir).unwrap()[2].modbus.as_deref(), Some("force.force_N=1.5"));
    }

    #[test]
    fn resume_after_kill_during_creation() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("ds");
        std::fs::create_dir_all(dir.join(IMAGES_DIR)).unwrap();
        std::fs::write(dir.join(".manifest.toml.tmp"), b"partial").unwrap();
        let w = DatasetWriter::resume(&dir, manifest()).unwrap();
        assert!(w.done_ids().is_empty());
        assert!(!dir.join(".manifest.toml.tmp").exists());
    }

    #[test]
    fn image_names() {
        assert_eq!(image_file_pose_id("12.png"), Some(12));
        assert_eq!(image_file_pose_id("0.png"), Some(0));
        assert_eq!(image_file_pose_id("012.png"), None);
        assert_eq!(image_file_pose_id(".12.png.tmp"), None);
        assert_eq!(image_file_pose_id("a.png"), None);
        assert_eq!(image_file_pose_id("99999999999.png"), None);
    }
}
