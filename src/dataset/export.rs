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
//! | `pose_1`, `pose_2`, `pose_3` | x mm, y mm, z mm (the tool's height offset, see below) |
//! | `pose_4`, `pose_5` | unused, 0 |
//! | `pose_6` | yaw deg |
//! | `move_1..move_6` | per-pose perturbation, 0 in rig's exports |
//!
//! Upstream files are 500-row templates whose unfilled rows are all empty (`,,,`);
//! [`import_mds`] skips those. Numbers are written in Rust's shortest round-trip form, so an
//! import-export-import cycle keeps every value bit for bit.
//!
//! **Depth convention.** `pose_3` is the tool's logged z offset from the nominal contact
//! height, positive *up*, away from the object: a lower `pose_3` presses deeper. The skin
//! indentation (the `z_mm` of a render pose, [`crate::geometry::raster`]) is
//! [`MDS_CONTACT_DEPTH_MM`] `- pose_3`, and rig's work-frame z (the extra indentation beyond
//! the contact depth, positive deeper, [`crate::pose::WorkFrame`]) is `-pose_3`: that is what
//! [`MdsRow::work_pose`] returns and [`mds_rows_from`] writes back. Read off the real sample
//! (`../shared/real-sample/multidiffsense-example`): frames 0 and 2 press the edge at the same
//! place and yaw (x, y, yaw = -3.06, -2.04, -89.8 and -3.22, -2.01, -89.0) at `pose_3` = +0.80
//! and -0.77 mm, and frame 2 shows the deeper press on every sensor that has both: the TacTip's
//! 20 largest pin shifts average 5.2 px against 3.8 px (100 pins move more than 1 px against
//! 73), the ViTac imprint's outline is larger (radius 35.8 against 32.5 px) and its contact
//! region covers 4.7 % of the frame against 3.0 %. Over all six frames the two lowest `pose_3`
//! (frames 2 and 3) move the TacTip's pins most. The nominal depth itself is not in the file:
//! 1.5 mm is rig's default contact depth, and every logged frame touches (the shallowest,
//! `pose_3` = +0.80, still shows a contact), so it is at least 0.8 mm. MultiDiffSense's prompt
//! carries `pose_3` as logged (`'z': 0.8` for frame 0), i.e. minus rig's work-frame z.
//!
//! **tactile-bench**: `sensor_image,object_label,pose_x,pose_y,pose_z,pose_Rx,pose_Ry,pose_Rz`
//! (mm and degrees; rig writes Rx = Ry = 0 and Rz = yaw), followed by rig's `pose_id` and
//! `source` so rows stay traceable. This is the `targets.csv` of the Lepora lab's collection
//! code (github.com/dexterousrobot/tactile_image_processing,
//! `tactile_image_processing/collect_data/setup_targets.py` writes the header, `collect_data.py`
//! drives the robot by it). **`pose_z` is positive deeper**, into the object: in `collect_data.py`
//! the robot starts "50mm above workframe origin" at `(0, 0, -50, 0, 0, 0)` and moves "above the
//! target pose" to `pose - clearance` with `clearance = (0, 0, 10, 0, 0, 0)`, and its task limits
//! press at `pose_z` from 1 to 5 mm (`pose_llims`/`pose_ulims`, e.g. `(-5, 0, 3, 0, 0, -180)` to
//! `(5, 0, 4, 0, 0, 180)`). rig's work-frame z is positive deeper too ([`crate::pose::WorkFrame`]),
//! so `pose_z` is the row's `z_mm` with its sign: a deeper press is a larger `pose_z`. (An MDS
//! row imported with `pose_3` = +0.80, which is 0.80 mm *shallower*, exports `pose_z` = -0.80.)
//! The origin is rig's: `pose_z` = 0 is the contact depth, not the object's surface.
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

/// The skin indentation at `pose_3 = 0`, mm: rig's default contact depth
/// ([`crate::pose::WorkFrame`]), which the MultiDiffSense example is consistent with (see the
/// module docs, "Depth convention").
pub const MDS_CONTACT_DEPTH_MM: f64 = 1.5;

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
    /// `pose_1..pose_6` as logged: x mm, y mm, z mm (positive up: see the module docs), unused,
    /// unused, yaw deg.
    pub pose: [f64; 6],
    /// `move_1..move_6`.
    pub moves: [f64; 6],
}

impl MdsRow {
    /// The work-frame pose in rig's convention: x = `pose_1`, y = `pose_2`, yaw = `pose_6`, and
    /// z = `-pose_3`, the indentation beyond the contact depth (positive deeper; see the module
    /// docs, "Depth convention").
    pub fn work_pose(&self) -> Pose {
        // `0.0 - z` rather than `-z`: a logged 0 stays 0, not -0.
        Pose::new(self.pose[0], self.pose[1], 0.0 - self.pose[2], self.pose[5])
    }

    /// The render pose ([`crate::geometry::raster`]): the work pose with z = the skin
    /// indentation, `contact_depth_mm - pose_3` ([`MDS_CONTACT_DEPTH_MM`] for the
    /// MultiDiffSense collections).
    pub fn render_pose(&self, contact_depth_mm: f64) -> Pose {
        let work = self.work_pose();
        Pose { z_mm: contact_depth_mm + work.z_mm, ..work }
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
/// pose id `i + 1`, and `pose_3` is minus the row's work-frame z (the inverse of
/// [`MdsRow::work_pose`]).
pub fn mds_rows_from(rows: &[PoseRow], obj_id: &str) -> Vec<MdsRow> {
    rows.iter()
        .enumerate()
        .map(|(i, r)| MdsRow {
            image_name: format!("frame_{i}_0.png"),
            data_name: format!("frame_{i}"),
            obj_id: obj_id.to_string(),
            pose_id: i as u32 + 1,
            pose: [r.x_mm, r.y_mm, 0.0 - r.z_mm, 0.0, 0.0, r.yaw_deg],
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
        assert_eq!(rows[0].pose[2], 0.7995462253753978);
        // Logged z is positive up: rig's work-frame z (positive deeper) is its negation, and
        // the indentation is the contact depth minus it.
        assert_eq!(rows[0].work_pose(), Pose::new(-3.06193989, -2.038885835, -0.7995462253753978, -89.79246118));
        assert_eq!(rows[0].render_pose(MDS_CONTACT_DEPTH_MM).z_mm, 1.5 - 0.7995462253753978);
        assert_eq!(mds_rows_from(&[pose_row_from_mds(&rows[0])], "1")[0].pose, rows[0].pose);
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

    /// `pose_z`'s sign against a row written by the tactile-bench convention: in the Lepora lab's
    /// collection code (github.com/dexterousrobot/tactile_image_processing,
    /// `tactile_image_processing/collect_data/collect_data.py` and `setup_targets.py`) the robot
    /// moves "above the target pose" to `pose - (0, 0, 10, 0, 0, 0)`, so a larger `pose_z` presses
    /// deeper. The row below is one of its `targets.csv` rows (edge task, `pose_z` sampled from
    /// 3 to 4 mm); its press re-collected by rig, deeper by the same amount, exports the same
    /// `pose_z`, and a shallower press a smaller one.
    #[test]
    fn tactile_bench_pose_z_is_positive_deeper_as_its_collection_code_writes_it() {
        let targets = "sensor_image,object_label,pose_x,pose_y,pose_z,pose_Rx,pose_Ry,pose_Rz\n\
                       image_1.png,edge,-2.5,0,3.5,0,0,45\n";
        let mut reader = csv::Reader::from_reader(targets.as_bytes());
        let headers = reader.headers().unwrap().clone();
        let record = reader.records().next().unwrap().unwrap();
        let field = |name: &str| -> f64 { record[headers.iter().position(|h| h == name).unwrap()].parse().unwrap() };
        let (x, y, z, yaw) = (field("pose_x"), field("pose_y"), field("pose_z"), field("pose_Rz"));
        // rig's work-frame z is positive deeper: the same press is z_mm = +3.5.
        let deeper = PoseRow::real(1, Pose::new(x, y, z, yaw), Pose::default(), 1.0);
        let shallower = PoseRow::real(2, Pose::new(x, y, z - 1.0, yaw), Pose::default(), 1.0);
        let mut out = Vec::new();
        export_tactile_bench(&[deeper, shallower], "edge", &mut out).unwrap();
        let mut exported = csv::Reader::from_reader(out.as_slice());
        let z_column = exported.headers().unwrap().iter().position(|h| h == "pose_z").unwrap();
        let z: Vec<f64> = exported.records().map(|r| r.unwrap()[z_column].parse().unwrap()).collect();
        assert_eq!(z, vec![3.5, 2.5], "pose_z keeps rig's sign: positive deeper");
        assert!(z[0] > z[1], "the deeper press has the larger pose_z, as in the collection code");
    }
}
