//! Joining datasets: shards written by `rig synth --fill-missing --shard i/n` (each its own
//! dataset directory) into one. Every input must describe the same dataset (sensor, object,
//! plan). A pose id present in several places must carry the same row there, and the same
//! image bytes, otherwise nothing is written and the conflict is reported.
//!
//! **Streaming.** A merge decides from the manifests and the CSVs first, holding one row per
//! pose and no image. When every input row is already in the output (merging again), it stops
//! there: no image is read, nothing is written. Otherwise every input verifies clean (which
//! decodes each image, one at a time, and refuses symlinks, so a merge copies only regular image
//! files that belong to the datasets named), a pose that two inputs both bring is compared byte
//! for byte (two images in memory), and then each new row is appended with its image, copied
//! unchanged, one image at a time. So memory does not grow with the number of images.
//!
//! A pose the output already has is skipped when the input's row is identical and its image
//! file has the same size as the output's: the output's image is its own and is not read again
//! (a differing size is a conflict).
//!
//! Frames of a real rig and of the simulated rig (rows of source `real` and `simulated`, in
//! the inputs or the output) are not merged into one dataset unless the caller allows it
//! ([`MergeOptions::allow_mixed`]): a dataset that mixes them can no longer be used as
//! either.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::durable::{Kind, MAX_IMAGE_BYTES, entry_exists, read_below, write_atomic};
use super::{DatasetError, DatasetWriter, MANIFEST_FILE, Manifest, PoseRow, REFERENCE_FILE, Source, read_rows, verify};
use crate::confine::{EntryKind, RootDir};

/// How [`merge`] treats its inputs.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct MergeOptions {
    /// Merge even when the result would hold both `real` and `simulated` rows.
    pub allow_mixed: bool,
}

/// What [`merge`] did.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MergeReport {
    pub inputs: usize,
    /// Rows appended to the output.
    pub appended: usize,
    /// Rows the output (or an earlier input) already had, identical.
    pub already_present: usize,
}

/// Where a pose's row was first found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Origin {
    /// The output dataset, before the merge.
    Out,
    /// Input `i`.
    Input(usize),
}

/// A pose's row and where it was first found.
struct Seen {
    origin: Origin,
    row: PoseRow,
}

/// What the merge will do, decided from the manifests and CSVs alone.
#[derive(Default)]
struct MergePlan {
    seen: BTreeMap<u32, Seen>,
    /// Pose ids to append, in the order found.
    new_ids: Vec<u32>,
    /// Poses that a later input brings too, not in the output: `(pose_id, input)`; their images
    /// are compared with the first input's before anything is written.
    repeated: Vec<(u32, usize)>,
    already_present: usize,
    /// The first conflict found (reported after the mixed-sources check, which comes first).
    conflict: Option<DatasetError>,
    /// The first dataset holding rows of each captured source.
    first_of: BTreeMap<Source, PathBuf>,
}

/// Merges the datasets `inputs` into `out` (created from the first input's manifest when
/// absent, appended to under its own manifest otherwise).
pub fn merge(inputs: &[PathBuf], out: &Path, options: MergeOptions) -> Result<MergeReport, DatasetError> {
    let mut manifests = Vec::with_capacity(inputs.len());
    for dir in inputs {
        manifests.push(Manifest::load(dir)?);
    }
    let Some(first) = manifests.first().cloned() else {
        return Ok(MergeReport { inputs: 0, appended: 0, already_present: 0 });
    };
    let out_exists = out.join(MANIFEST_FILE).exists();
    let out_manifest = if out_exists { Manifest::load(out)? } else { first.clone() };
    for (dir, m) in inputs.iter().zip(&manifests) {
        out_manifest.check_same_dataset(m, dir)?;
    }

    // Decide everything before reading an image or writing anything.
    let plan = plan_merge(inputs, out, out_exists)?;
    if !options.allow_mixed
        && let (Some(real), Some(simulated)) = (plan.first_of.get(&Source::Real), plan.first_of.get(&Source::Simulated))
    {
        return Err(DatasetError::MixedSources { real: real.clone(), simulated: simulated.clone() });
    }
    if let Some(conflict) = plan.conflict {
        return Err(conflict);
    }
    let reference_src = reference_source(inputs, out)?;
    let report = MergeReport { inputs: inputs.len(), appended: plan.new_ids.len(), already_present: plan.already_present };
    if out_exists && plan.new_ids.is_empty() && reference_src.is_none() {
        // Merging again: every row is there already. Nothing to read, nothing to write.
        return Ok(report);
    }

    for dir in inputs {
        let report = verify(dir)?;
        if !report.is_clean() {
            return Err(DatasetError::Unclean { dir: dir.clone(), issues: report.issues.len() });
        }
    }
    for &(pose_id, later) in &plan.repeated {
        let Some(Seen { origin: Origin::Input(first), row }) = plan.seen.get(&pose_id) else { continue };
        let (a, b) = (&inputs[*first], &inputs[later]);
        // One pair of images in memory at a time.
        if read_image(a, row)? != read_image(b, row)? {
            return Err(DatasetError::MergeConflict { pose_id, first: a.clone(), second: b.clone() });
        }
    }

    let mut writer = if out_exists { DatasetWriter::open(out)? } else { DatasetWriter::create(out, first)? };
    let mut new_ids = plan.new_ids;
    new_ids.sort_unstable();
    let mut seen = plan.seen;
    for id in &new_ids {
        if let Some(Seen { origin: Origin::Input(i), row }) = seen.remove(id) {
            let png = read_image(&inputs[i], &row)?;
            writer.append_png(row, &png)?;
        }
    }
    if let Some(src) = reference_src {
        let bytes = read_below(src, Path::new(REFERENCE_FILE), MAX_IMAGE_BYTES)?;
        write_atomic(out, REFERENCE_FILE, &bytes)?;
    }
    // The record of the last synthesis (`[synthesis]`: model, its resolution, the written
    // size) travels with the synthesised rows: shards of a fill carry it, and the dataset they
    // are merged into (often the collection itself, which has none) would otherwise lose what
    // `rig audit`'s verdict reads. The last input holding one is the latest synthesis.
    if let Some(synthesis) = manifests.iter().rev().find_map(|m| m.synthesis.clone())
        && writer.manifest().synthesis.as_ref() != Some(&synthesis)
    {
        writer.update_manifest(|m| m.synthesis = Some(synthesis))?;
    }
    writer.finish()?;
    Ok(report)
}

/// Reads the rows of the output (when it exists) and of every input, one dataset at a time,
/// and decides which rows to append. No image is read: a pose the output has is checked by
/// its row and the size of its image file.
fn plan_merge(inputs: &[PathBuf], out: &Path, out_exists: bool) -> Result<MergePlan, DatasetError> {
    let mut plan = MergePlan::default();
    if out_exists {
        for row in read_rows(out)? {
            plan.note_source(row.source, out);
            plan.seen.insert(row.pose_id, Seen { origin: Origin::Out, row });
        }
    }
    let out_root = if out_exists { Some(RootDir::open(out)?) } else { None };
    for (i, dir) in inputs.iter().enumerate() {
        let root = RootDir::open(dir)?;
        for row in read_rows(dir)? {
            plan.note_source(row.source, dir);
            let pose_id = row.pose_id;
            let Some(first) = plan.seen.get(&pose_id) else {
                plan.new_ids.push(pose_id);
                plan.seen.insert(pose_id, Seen { origin: Origin::Input(i), row });
                continue;
            };
            let first_dir = match first.origin {
                Origin::Out => out,
                Origin::Input(k) => inputs[k].as_path(),
            };
            let same = first.row == row
                && match (first.origin, &out_root) {
                    (Origin::Out, Some(out_root)) => {
                        matches!((image_len(out_root, &first.row)?, image_len(&root, &row)?), (Some(a), Some(b)) if a == b)
                    }
                    _ => {
                        plan.repeated.push((pose_id, i));
                        true
                    }
                };
            if same {
                plan.already_present += 1;
            } else if plan.conflict.is_none() {
                plan.conflict = Some(DatasetError::MergeConflict { pose_id, first: first_dir.to_path_buf(), second: dir.clone() });
            }
        }
    }
    Ok(plan)
}

impl MergePlan {
    fn note_source(&mut self, source: Source, dir: &Path) {
        if source.is_captured() {
            self.first_of.entry(source).or_insert_with(|| dir.to_path_buf());
        }
    }
}

/// The size of a row's image file, `None` when it is absent or not a regular file.
fn image_len(root: &RootDir, row: &PoseRow) -> Result<Option<u64>, DatasetError> {
    Ok(root.stat(&row.image)?.filter(|info| info.kind == EntryKind::File).map(|info| info.len_bytes))
}

/// The input whose `reference.png` the output takes: the first input that has one, when the
/// output has none.
fn reference_source<'a>(inputs: &'a [PathBuf], out: &Path) -> Result<Option<&'a PathBuf>, DatasetError> {
    if entry_exists(&out.join(REFERENCE_FILE), Kind::File)? {
        return Ok(None);
    }
    for dir in inputs {
        if entry_exists(&dir.join(REFERENCE_FILE), Kind::File)? {
            return Ok(Some(dir));
        }
    }
    Ok(None)
}

/// The bytes of a row's image: a regular file below `dir` with no symlink on the way, bounded.
fn read_image(dir: &Path, row: &PoseRow) -> Result<Vec<u8>, DatasetError> {
    read_below(dir, Path::new(&row.image), MAX_IMAGE_BYTES)
}
