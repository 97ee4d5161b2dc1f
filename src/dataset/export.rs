//! CSV dialects of other tools.
//!
//! **MDS** (the Lepora lab's MG400 collection code, used by MultiDiffSense; a real file is in
//! `../shared/real-sample/multidiffsense-example/csv/1.csv`):
//!
//! | column | meaning |
//! |---|---|
//! | `image_name` | `frame_<i>_0.png`, `i` the 0-based row index |
//! | `data_name` | `frame_<i>` |
//! | `obj_id` | object id |
//! | `pose_id` | 1-based row index (not rig's grid id) |
//! | `pose_1`, `pose_2`, `pose_3` | x mm, y mm, z mm (indentation) |
//! | `pose_4`, `pose_5` | unused, 0 |
//! | `pose_6` | yaw deg |
//! | `move_1..move_6` | per-pose perturbation, 0 in rig's exports |
//!
//! Upstream files are 500-row templates whose unfilled rows are all empty (`,,,`);
//! [`import_mds`] skips those. Numbers are written in Rust's shortest round-trip form, so an
//! import-export-import cycle keeps every value bit for bit.
//!
//! **tactile-bench**: `sensor_image,object_label,pose_x,pose_y,pose_z,pose_Rx,pose_Ry,pose_Rz`
//! (mm and degrees; rig writes Rx = Ry = 0 and Rz = yaw), followed by rig's `pose_id` and
//! `source` so rows stay traceable.
//!
//! Both exports write the commanded pose (what the plan asked for), as the MDS files do.

use std::io::Write;
use std::path::Path;

use super::{DatasetError, PoseRow};
use crate::pose::Pose;

/// The MDS header, in order.
pub const MDS_COLUMNS: [&str; 16] = [
    "image_name",
    "data_name",
    "obj_id",
    "pose_id",
    "pose_1",
    "pose_2",
    "pose_3",
    "pose_4",
    "pose_5",
    "pose_6",
    "move_1",
    "move_2",
    "move_3",
    "move_4",
    "move_5",
    "move_6",
];

/// The tactile-bench header, in order.
pub const TACTILE_BENCH_COLUMNS: [&str; 10] =
    ["sensor_image", "object_label", "pose_x", "pose_y", "pose_z", "pose_Rx", "pose_Ry", "pose_Rz", "pose_id", "source"];

/// One filled row of an MDS file.
#[derive(Debug, Clone, PartialEq)]
pub struct MdsRow {
    pub image_name: String,
    pub data_name: String,
    pub obj_id: String,
    /// The file's own 1-based pose counter.
    pub pose_id: u32,
    /// `pose_1..pose_6`: x mm, y mm, z mm, unused, unused, yaw deg.
    pub pose: [f64; 6],
    /// `move_1..move_6`.
    pub moves: [f64; 6],
}

impl MdsRow {
    /// The work-frame pose (`pose_1`, `pose_2`, `pose_3`, `pose_6`).
    pub fn work_pose(&self) -> Pose {
        Pose::new(self.pose[0], self.pose[1], self.pose[2], self.pose[5])
    }

    /// The row index `i` of `frame_<i>_0.png` (which names the image `<obj>_<Sensor>_<i>.png`
    /// in MultiDiffSense's layout), if the name has that form.
    pub fn frame_index(&self) -> Option<u32> {
        self.image_name.strip_prefix("frame_")?.strip_suffix("_0.png")?.parse().ok()
    }
}

/// Largest MDS CSV read (upstream files are 500-row templates of a few tens of kB).
pub const MAX_MDS_BYTES: u64 = 64 << 20;

/// Reads an MDS file (a regular file of at most [`MAX_MDS_BYTES`]), skipping the empty
/// template rows.
pub fn import_mds(path: &Path) -> Result<Vec<MdsRow>, DatasetError> {
    let bytes = crate::untrusted::read_bytes(path, MAX_MDS_BYTES).map_err(DatasetError::io("reading", path))?;
    parse_mds(&bytes, path)
}

/// Parses MDS bytes (`path` names the source in errors). Columns are found by header name,
/// so reordered or extra columns are accepted. `image_name` and `obj_id` become file names on
/// import, so each must be a plain file name (no `/`, no `..`); errors name the line and the
/// column, not the field's text.
pub fn parse_mds(bytes: &[u8], path: &Path) -> Result<Vec<MdsRow>, DatasetError> {
    let bad = |line: u64, reason: String| DatasetError::MalformedMds { path: path.to_path_buf(), line, reason };
    let mut rdr = csv::ReaderBuilder::new().has_headers(true).flexible(true).from_reader(bytes);
    let headers = rdr.headers().map_err(|e| bad(1, crate::untrusted::sanitise(&e.to_string())))?.clone();
    let mut index = [0usize; 16];
    for (k, name) in MDS_COLUMNS.iter().enumerate() {
        index[k] = headers.iter().position(|h| h.trim() == *name).ok_or_else(|| bad(1, format!("missing column {name}")))?;
    }
    let mut rows = Vec::new();
    for record in rdr.records() {
        let record = record.map_err(|e| bad(e.position().map(|p| p.line()).unwrap_or(0), crate::untrusted::sanitise(&e.to_string())))?;
        let line = record.position().map(|p| p.line()).unwrap_or(0);
        if record.iter().all(|f| f.trim().is_empty()) {
            continue; // template row
        }
        let field = |k: usize| record.get(index[k]).unwrap_or("").trim();
        let number = |k: usize| -> Result<f64, DatasetError> {
            field(k)
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| bad(line, format!("{} is not a finite number", MDS_COLUMNS[k])))
        };
        let image_name = field(0).to_string();
        if image_name.is_empty() {
            return Err(bad(line, "image_name is empty".to_string()));
        }
        for (k, name) in [(0, "image_name"), (2, "obj_id")] {
            if !field(k).is_empty() && !super::durable::is_plain_file_name(field(k)) {
                return Err(bad(line, format!("{name} is not a plain file name (no `/`, no `..`)")));
            }
        }
        let pose_id = field(3).parse::<u32>().map_err(|_| bad(line, "pose_id is not a non-negative integer".to_string()))?;
        let mut pose = [0.0; 6];
        let mut moves = [0.0; 6];
        for j in 0..6 {
            pose[j] = number(4 + j)?;
            moves[j] = number(10 + j)?;
        }
        rows.push(MdsRow { image_name, data_name: field(1).to_string(), obj_id: field(2).to_string(), pose_id, pose, moves });
    }
    Ok(rows)
}

/// A dataset row for an imported MDS row: pose id = the MDS pose id, commanded pose = the
/// MDS pose, source `real`, no measured pose or capture time (MDS files carry neither).
pub fn pose_row_from_mds(row: &MdsRow) -> PoseRow {
    PoseRow::commanded_only(row.pose_id, row.work_pose(), super::Source::Real)
}

/// MDS rows for dataset rows, in the given order: row `i` becomes `frame_<i>_0.png` with MDS
/// pose id `i + 1`.
pub fn mds_rows_from(rows: &[PoseRow], obj_id: &str) -> Vec<MdsRow> {
    rows.iter()
        .enumerate()
        .map(|(i, r)| MdsRow {
            image_name: format!("frame_{i}_0.png"),
            data_name: format!("frame_{i}"),
            obj_id: obj_id.to_string(),
            pose_id: i as u32 + 1,
            pose: [r.x_mm, r.y_mm, r.z_mm, 0.0, 0.0, r.yaw_deg],
            moves: [0.0; 6],
        })
        .collect()
}

/// Writes MDS rows with the MDS header.
pub fn export_mds(rows: &[MdsRow], out: impl Write) -> Result<(), DatasetError> {
    let mut w = csv::Writer::from_writer(out);
    let csv_err = |source| DatasetError::CsvWrite { source };
    w.write_record(MDS_COLUMNS).map_err(csv_err)?;
    for r in rows {
        let mut rec: Vec<String> = vec![r.image_name.clone(), r.data_name.clone(), r.obj_id.clone(), r.pose_id.to_string()];
        rec.extend(r.pose.iter().chain(r.moves.iter()).map(|v| v.to_string()));
        w.write_record(&rec).map_err(csv_err)?;
    }
    w.flush().map_err(|e| DatasetError::CsvWrite { source: e.into() })
}

/// Writes dataset rows in the tactile-bench dialect.
pub fn export_tactile_bench(rows: &[PoseRow], object_label: &str, out: impl Write) -> Result<(), DatasetError> {
    let mut w = csv::Writer::from_writer(out);
    let csv_err = |source| DatasetError::CsvWrite { source };
    w.write_record(TACTILE_BENCH_COLUMNS).map_err(csv_err)?;
    for r in rows {
        let rec = [
            r.image.clone(),
            object_label.to_string(),
            r.x_mm.to_string(),
            r.y_mm.to_string(),
            r.z_mm.to_string(),
            "0".to_string(),
            "0".to_string(),
            r.yaw_deg.to_string(),
            r.pose_id.to_string(),
            r.source.to_string(),
        ];
        w.write_record(&rec).map_err(csv_err)?;
    }
    w.flush().map_err(|e| DatasetError::CsvWrite { source: e.into() })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn template_rows_skipped_and_partial_rows_refused() {
        let text = format!(
            "{}\nframe_0_0.png,frame_0,1,1,-3.06193989,-2.038885835,0.7995462253753978,0,0,-89.79246118,0,0,0,0,0,0\n,,,,,,,,,,,,,,,\n",
            MDS_COLUMNS.join(",")
        );
        let rows = parse_mds(text.as_bytes(), Path::new("t.csv")).unwrap();
        assert_eq!(rows.len(), 1);
        assert_eq!(rows[0].work_pose(), Pose::new(-3.06193989, -2.038885835, 0.7995462253753978, -89.79246118));
        assert_eq!(rows[0].frame_index(), Some(0));
        let partial = format!("{}\nframe_0_0.png,frame_0,1,1,,,,,,,,,,,,\n", MDS_COLUMNS.join(","));
        let err = parse_mds(partial.as_bytes(), Path::new("t.csv")).unwrap_err();
        assert!(matches!(err, DatasetError::MalformedMds { line: 2, .. }), "{err}");
        assert!(parse_mds(b"a,b\n1,2\n", Path::new("t.csv")).is_err());
        // Names that would leave the images folder, and values never echoed.
        for (image, obj) in [("../../outside.png", "1"), ("a/b.png", "1"), ("f.png", "../x"), ("..", "1")] {
            let text = format!("{}\n{image},frame_0,{obj},1,0,0,0,0,0,0,0,0,0,0,0,0\n", MDS_COLUMNS.join(","));
            let err = parse_mds(text.as_bytes(), Path::new("t.csv")).unwrap_err();
            assert!(
                err.to_string().contains("plain file name") && !err.to_string().contains("outside") && !err.to_string().contains("../x"),
                "{err}"
            );
        }
        let text = format!("{}\nf.png,frame_0,1,1,secret-value,0,0,0,0,0,0,0,0,0,0,0\n", MDS_COLUMNS.join(","));
        let err = parse_mds(text.as_bytes(), Path::new("t.csv")).unwrap_err();
        assert!(err.to_string().contains("pose_1") && !err.to_string().contains("secret-value"), "{err}");
        assert!(parse_mds(b"\xff\x00,\"", Path::new("t.csv")).is_err());
    }

    #[test]
    fn tactile_bench_header_and_values() {
        let row = PoseRow::real(7, Pose::new(1.5, -2.0, 0.5, 30.0), Pose::default(), 1.0);
        let mut out = Vec::new();
        export_tactile_bench(&[row], "edge", &mut out).unwrap();
        let text = String::from_utf8(out).unwrap();
        assert_eq!(
            text,
            "sensor_image,object_label,pose_x,pose_y,pose_z,pose_Rx,pose_Ry,pose_Rz,pose_id,source\n\
             images/7.png,edge,1.5,-2,0.5,0,0,30,7,real\n"
        );
    }
}
