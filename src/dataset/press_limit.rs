//! Rows that press past a sensor's press limit: `rig dataset verify` reports them, since `rig
//! audit` presses a dataset's rows again and refuses (before the arm moves) any past the
//! limit ([`crate::fence`]). Kept apart from [`mod@super::verify`], which checks the files.

use std::path::Path;

use super::durable::{MAX_POSES_CSV_BYTES, read_below};
use super::{DatasetError, POSES_FILE, VerifyIssue, parse_csv};
use crate::pose::{WorkFrame, within_press_limit};

/// The rows of `dir/poses.csv` whose commanded pose presses deeper than `max_indentation_mm`
/// in `work_frame` (the contact depth plus the row's `z_mm`), as issues naming `limit` (how
/// the limit reads, e.g. `vitac's press limit of 2.5 mm`). Malformed lines are left to
/// [`mod@super::verify`].
pub fn rows_past_press_limit(
    dir: &Path,
    work_frame: &WorkFrame,
    max_indentation_mm: f64,
    limit: &str,
) -> Result<Vec<VerifyIssue>, DatasetError> {
    let bytes = read_below(dir, Path::new(POSES_FILE), MAX_POSES_CSV_BYTES)?;
    let parsed = parse_csv(&bytes);
    let mut issues = Vec::new();
    for l in &parsed.lines {
        let Ok(row) = &l.row else { continue };
        let depth_mm = work_frame.press_depth_mm(&row.commanded());
        if !within_press_limit(depth_mm, max_indentation_mm) {
            issues.push(VerifyIssue::PastPressLimit { pose_id: row.pose_id, line: l.line, depth_mm, limit: limit.to_string() });
        }
    }
    Ok(issues)
}
