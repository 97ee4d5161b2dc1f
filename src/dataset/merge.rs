//! Joining datasets: shards written by `rig synth --fill-missing --shard i/n` (each its own
//! dataset directory) into one. Every input must verify clean and describe the same dataset
//! (sensor, object, plan). A pose id present in several places must carry the same row and
//! the same image bytes there, otherwise nothing is written and the conflict is reported.
//! Merging again is harmless: rows already in the output are skipped. Every input verifies
//! clean first, which decodes each image and refuses symlinks, so a merge copies only regular
//! image files that belong to the datasets named.
//!
//! Frames of a real rig and of the simulated rig (rows of source `real` and `simulated`, in
//! the inputs or the output) are not merged into one dataset unless the caller allows it
//! ([`MergeOptions::allow_mixed`]): a dataset that mixes them can no longer be used as
//! either.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::durable::{Kind, MAX_IMAGE_BYTES, entry_exists, read_below, write_atomic};
use super::{DatasetError, DatasetWriter, Manifest, PoseRow, REFERENCE_FILE, Source, read_rows, verify};

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

/// Merges the datasets `inputs` into `out` (created from the first input's manifest when
/// absent, appended to under its own manifest otherwise).
pub fn merge(inputs: &[PathBuf], out: &Path, options: MergeOptions) -> Result<MergeReport, DatasetError> {
    let mut manifests = Vec::with_capacity(inputs.len());
    for dir in inputs {
        let report = verify(dir)?;
        if !report.is_clean() {
            return Err(DatasetError::Unclean { dir: dir.clone(), issues: report.issues.len() });
        }
        manifests.push(Manifest::load(dir)?);
    }
    let Some(first) = manifests.first().cloned() else {
        return Ok(MergeReport { inputs: 0, appended: 0, already_present: 0 });
    };
    let out_exists = out.join(super::MANIFEST_FILE).exists();
    if !options.allow_mixed {
        let mut dirs: Vec<&Path> = inputs.iter().map(PathBuf::as_path).collect();
        if out_exists {
            dirs.insert(0, out);
        }
        check_not_mixed(&dirs)?;
    }
    let mut writer = if out_exists { DatasetWriter::open(out)? } else { DatasetWriter::create(out, first)? };
    for (dir, m) in inputs.iter().zip(&manifests) {
        writer.manifest().check_same_dataset(m, dir)?;
    }

    // Decide everything before writing anything.
    let mut chosen: BTreeMap<u32, (PathBuf, PoseRow, Vec<u8>)> = BTreeMap::new();
    for row in read_rows(out)? {
        let png = read_image(out, &row)?;
        chosen.insert(row.pose_id, (out.to_path_buf(), row, png));
    }
    let mut already_present = 0;
    let mut new_ids = Vec::new();
    for dir in inputs {
        for row in read_rows(dir)? {
            let png = read_image(dir, &row)?;
            match chosen.get(&row.pose_id) {
                Some((first_dir, first_row, first_png)) => {
                    if *first_row != row || *first_png != png {
                        return Err(DatasetError::MergeConflict { pose_id: row.pose_id, first: first_dir.clone(), second: dir.clone() });
                    }
                    already_present += 1;
                }
                None => {
                    new_ids.push(row.pose_id);
                    chosen.insert(row.pose_id, (dir.clone(), row, png));
                }
            }
        }
    }
    new_ids.sort_unstable();
    for id in &new_ids {
        if let Some((_, row, png)) = chosen.remove(id) {
            writer.append_png(row, &png)?;
        }
    }
    let mut reference_src = None;
    for dir in inputs {
        if entry_exists(&dir.join(REFERENCE_FILE), Kind::File)? {
            reference_src = Some(dir);
            break;
        }
    }
    if let Some(src) = reference_src.filter(|_| !out.join(REFERENCE_FILE).exists()) {
        let bytes = read_below(src, Path::new(REFERENCE_FILE), MAX_IMAGE_BYTES)?;
        write_atomic(out, REFERENCE_FILE, &bytes)?;
    }
    writer.finish()?;
    Ok(MergeReport { inputs: inputs.len(), appended: new_ids.len(), already_present })
}

/// Refuses when `dirs` hold both `real` and `simulated` rows, naming the first dataset of each.
fn check_not_mixed(dirs: &[&Path]) -> Result<(), DatasetError> {
    let mut first_of: BTreeMap<Source, PathBuf> = BTreeMap::new();
    for dir in dirs {
        for row in read_rows(dir)?.iter().filter(|r| r.source.is_captured()) {
            first_of.entry(row.source).or_insert_with(|| dir.to_path_buf());
        }
    }
    match (first_of.remove(&Source::Real), first_of.remove(&Source::Simulated)) {
        (Some(real), Some(simulated)) => Err(DatasetError::MixedSources { real, simulated }),
        _ => Ok(()),
    }
}

/// The bytes of a row's image: a regular file below `dir` with no symlink on the way, bounded.
fn read_image(dir: &Path, row: &PoseRow) -> Result<Vec<u8>, DatasetError> {
    read_below(dir, Path::new(&row.image), MAX_IMAGE_BYTES)
}
