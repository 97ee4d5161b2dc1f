//! The kept order: `order.csv`, the poses a collection visits, in the order it visits them,
//! written once into each dataset before its first pose so that a resume, an audit's rerun or
//! anything else that needs the order reads it instead of ordering the plan again.
//!
//! ```text
//! pose_id
//! 4711
//! 4722
//! ...
//! ```
//!
//! One header line `pose_id`, then one decimal pose id per line, each once. A collection's
//! order lists exactly the poses its manifest's plan samples; an audit's (in
//! `<dataset>/audit/<object>/<sensor>/`) lists exactly its draw. Who reads it checks that: the
//! kept order must list the same set of poses as the plan it is read for
//! ([`crate::plan::in_kept_order`]), otherwise the run is refused and nothing moves.
//!
//! It is written through [`write_atomic`] (temp file, fsync, rename, fsync the folder): a kill
//! leaves no file or the whole file, never part of one, and no row of the run exists before
//! it. A dataset without one (written before rig kept orders, or by `rig synth`, `rig dataset
//! merge` or `rig dataset import`, which visit nothing) is still valid: a resume orders its plan
//! as rig did then and keeps that order. The file is read through the dataset opener (no
//! symlink, a regular file, at most [`MAX_ORDER_BYTES`]), and its lines are bounded by the
//! largest grid rig enumerates.

use std::path::Path;

use super::DatasetError;
use super::durable::{Kind, entry_exists, read_below, write_atomic};
use crate::plan::MAX_GRID_POINTS;

/// The file's name in a dataset folder.
pub const ORDER_FILE: &str = "order.csv";
/// Its header line.
pub const ORDER_HEADER: &str = "pose_id";
/// Largest `order.csv` read: a full grid of [`MAX_GRID_POINTS`] ids of at most 7 digits, a
/// `\r\n` each, and the header.
pub const MAX_ORDER_BYTES: u64 = MAX_GRID_POINTS * 9 + 64;

/// Whether the dataset at `dir` keeps an order (an error for a symlink or a folder there).
pub fn has_order(dir: &Path) -> Result<bool, DatasetError> {
    entry_exists(&dir.join(ORDER_FILE), Kind::File)
}

/// The order kept in the dataset at `dir`, `None` when it keeps none. Refuses a malformed
/// file (naming the line) and one that lists a pose twice.
pub fn read_order(dir: &Path) -> Result<Option<Vec<u32>>, DatasetError> {
    if !has_order(dir)? {
        return Ok(None);
    }
    let bytes = read_below(dir, Path::new(ORDER_FILE), MAX_ORDER_BYTES)?;
    parse_order(&bytes, &dir.join(ORDER_FILE)).map(Some)
}

/// Parses `order.csv` bytes (`path` names it in errors). Never panics.
pub fn parse_order(bytes: &[u8], path: &Path) -> Result<Vec<u32>, DatasetError> {
    let bad = |line: u64, reason: String| DatasetError::BadOrder { path: path.to_path_buf(), line, reason };
    let mut lines = bytes.split(|&b| b == b'\n').map(|l| l.strip_suffix(b"\r").unwrap_or(l));
    if lines.next() != Some(ORDER_HEADER.as_bytes()) {
        return Err(bad(1, format!("the header must be `{ORDER_HEADER}`")));
    }
    let mut ids = Vec::new();
    let mut seen = std::collections::HashSet::new();
    for (i, raw) in lines.enumerate() {
        let line = i as u64 + 2;
        if raw.is_empty() {
            continue; // the split after the final newline
        }
        if ids.len() as u64 >= MAX_GRID_POINTS {
            return Err(bad(line, format!("more than the {MAX_GRID_POINTS} poses a plan can have")));
        }
        let id = std::str::from_utf8(raw)
            .ok()
            .filter(|t| !t.is_empty() && t.bytes().all(|b| b.is_ascii_digit()))
            .and_then(|t| t.parse::<u32>().ok())
            .ok_or_else(|| bad(line, "not a pose id (a whole number)".to_string()))?;
        if !seen.insert(id) {
            return Err(bad(line, format!("pose {id} is listed twice")));
        }
        ids.push(id);
    }
    Ok(ids)
}

/// The bytes of `order.csv` for `ids`.
pub fn order_bytes(ids: &[u32]) -> Vec<u8> {
    let mut out = Vec::with_capacity(ORDER_HEADER.len() + 1 + ids.len() * 7);
    out.extend_from_slice(ORDER_HEADER.as_bytes());
    out.push(b'\n');
    for id in ids {
        out.extend_from_slice(id.to_string().as_bytes());
        out.push(b'\n');
    }
    out
}

/// Writes `ids` as the order kept in the dataset at `dir`, atomically and durably, unless it
/// keeps one already (that one stays: an order is written once). Returns whether it wrote.
pub fn keep_order(dir: &Path, ids: &[u32]) -> Result<bool, DatasetError> {
    if has_order(dir)? {
        return Ok(false);
    }
    write_atomic(dir, ORDER_FILE, &order_bytes(ids))?;
    Ok(true)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_refusals() {
        let dir = tempfile::tempdir().expect("tempdir");
        assert_eq!(read_order(dir.path()).expect("read"), None);
        assert!(keep_order(dir.path(), &[5, 0, 17]).expect("keep"));
        assert_eq!(std::fs::read_to_string(dir.path().join(ORDER_FILE)).expect("text"), "pose_id\n5\n0\n17\n");
        assert_eq!(read_order(dir.path()).expect("read"), Some(vec![5, 0, 17]));
        // Written once: a second call keeps the first order.
        assert!(!keep_order(dir.path(), &[1, 2]).expect("keep"));
        assert_eq!(read_order(dir.path()).expect("read"), Some(vec![5, 0, 17]));

        let path = Path::new("order.csv");
        assert_eq!(parse_order(b"pose_id\r\n3\r\n4", path).expect("crlf, no final newline"), vec![3, 4]);
        for (bytes, line) in [
            (&b"id\n1\n"[..], 1),
            (b"", 1),
            (b"pose_id\n1\n-2\n", 3),
            (b"pose_id\n1\n2.0\n", 3),
            (b"pose_id\n1\n99999999999\n", 3),
            (b"pose_id\n1\n 2\n", 3),
            (b"pose_id\n7\n8\n7\n", 4),
            (b"pose_id\n\xff\n", 2),
        ] {
            match parse_order(bytes, path) {
                Err(DatasetError::BadOrder { line: l, .. }) => assert_eq!(l, line, "{bytes:?}"),
                other => panic!("{bytes:?}: {other:?}"),
            }
        }
    }

    #[test]
    fn a_symlinked_order_is_refused() {
        let dir = tempfile::tempdir().expect("tempdir");
        std::fs::write(dir.path().join("elsewhere.csv"), "pose_id\n1\n").expect("write");
        std::os::unix::fs::symlink(dir.path().join("elsewhere.csv"), dir.path().join(ORDER_FILE)).expect("symlink");
        assert!(matches!(read_order(dir.path()), Err(DatasetError::Symlink { .. })));
        assert!(keep_order(dir.path(), &[1]).is_err());
    }
}
