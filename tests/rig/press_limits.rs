//! The press limit on every path a pose reaches the arm by, on the built-in simulated rig: a
//! plan, `--resume`, an audit (a dataset's rows), a calibration, and (in `daemon_api`) the
//! daemon's jobs. Each is refused before the arm moves (exit 2, no dataset or file started),
//! naming the pose and the limit; `rig dataset verify` reports rows past the limit.

use std::path::Path;

use crate::run::{expect_code, rig};

/// The plan: 20 to 30 mm of extra indentation, at one spot.
const DEEP_PLAN: &str = "sampling = \"full\"\norder = \"optimised\"\nx_mm = { min = 0.0, max = 0.0, step = 1.0 }\n\
     y_mm = { min = 0.0, max = 0.0, step = 1.0 }\nz_mm = { min = 20.0, max = 30.0, step = 5.0 }\n\
     yaw_deg = { min = 0.0, max = 0.0, step = 1.0 }\n";

/// `rig ARGS --dry-run`, then `rig ARGS`: both refused with exit 2 before anything moves;
/// their outputs.
fn refused_dry_and_real(dir: &Path, args: &[&str]) -> [String; 2] {
    let dry: Vec<&str> = args.iter().copied().chain(["--dry-run"]).collect();
    [expect_code(&rig(dir, &dry), 2), expect_code(&rig(dir, args), 2)]
}

/// A work frame whose first touch is `contact_depth_mm` deep (the default origin).
fn frame_config(contact_depth_mm: f64) -> String {
    format!("[work_frame]\norigin = {{ x_mm = 300.0, y_mm = 0.0, z_mm = -20.0, yaw_deg = 0.0 }}\ncontact_depth_mm = {contact_depth_mm}\n")
}

#[test]
fn a_plan_past_the_press_limit_is_refused_before_anything_moves() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path();
    std::fs::write(dir.join("deep.toml"), DEEP_PLAN).expect("plan");
    for t in refused_dry_and_real(dir, &["collect", "--plan", "deep.toml", "--sensor", "tactip", "--out", "out"]) {
        assert!(
            t.contains("plan pose 0 (x 0.000 mm, y 0.000 mm, z 20.000 mm, yaw 0.000 deg) presses 21.500 mm into the skin"),
            "the refusal names the pose and its depth: {t}"
        );
        assert!(t.contains("beyond tactip's press limit of 5 mm (TacTip's default"), "the refusal names the limit: {t}");
        assert!(!dir.join("out").exists(), "nothing may start: {t}");
    }
    // All three sensors at once are bounded by the lowest limit (ViTac's 2.5 mm): a plan
    // pressing 3.5 mm passes TacTip alone but not all three, unless rig.toml raises ViTac's
    // and ViTacTip's.
    std::fs::write(dir.join("three.toml"), DEEP_PLAN.replace("min = 20.0, max = 30.0, step = 5.0", "min = 2.0, max = 2.0, step = 1.0"))
        .expect("plan");
    expect_code(&rig(dir, &["collect", "--plan", "three.toml", "--sensor", "tactip", "--dry-run"]), 0);
    let t = expect_code(&rig(dir, &["collect", "--plan", "three.toml", "--dry-run"]), 2);
    assert!(t.contains("presses 3.500 mm") && t.contains("vitac's press limit of 2.5 mm"), "{t}");
    std::fs::write(dir.join("raised.toml"), "[sensors.vitac]\nmax_indentation_mm = 4.0\n[sensors.vitactip]\nmax_indentation_mm = 3.5\n")
        .expect("config");
    let t = expect_code(&rig(dir, &["collect", "--plan", "three.toml", "--config", "raised.toml", "--dry-run"]), 0);
    assert!(t.contains("deepest press: 3.500 mm (plan pose 0), within vitactip's press limit of 3.5 mm (set by"), "{t}");
}

#[test]
fn a_resume_in_a_deeper_work_frame_is_refused_and_the_dataset_is_untouched() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path();
    let args = ["collect", "--poses", "3", "--seed", "2", "--sensor", "tactip", "--out", "out"];
    expect_code(&rig(dir, &args), 0);
    // An interrupted run: the last row (and its image) never made it.
    let ds = dir.join("out/sphere/tactip");
    let csv = std::fs::read_to_string(ds.join("poses.csv")).expect("csv");
    let mut lines: Vec<&str> = csv.lines().collect();
    let last = lines.pop().expect("a row");
    let id = last.split(',').next().expect("pose_id");
    std::fs::remove_file(ds.join(format!("images/{id}.png"))).expect("image");
    std::fs::write(ds.join("poses.csv"), lines.join("\n") + "\n").expect("csv");
    let before = std::fs::read(ds.join("poses.csv")).expect("csv");

    // The bench's work frame now touches 7 mm deep: every pose of the plan presses past 5 mm.
    std::fs::write(dir.join("deeper.toml"), frame_config(7.0)).expect("config");
    let resume: Vec<&str> = args.iter().copied().chain(["--resume", "--config", "deeper.toml"]).collect();
    let t = expect_code(&rig(dir, &resume), 2);
    assert!(t.contains("into the skin (contact depth 7.000 mm") && t.contains("tactip's press limit of 5 mm"), "{t}");
    assert_eq!(std::fs::read(ds.join("poses.csv")).expect("csv"), before, "no row added: {t}");
    assert!(!ds.join(format!("images/{id}.png")).exists(), "no image written: {t}");
    // In the frame it was collected in, the same resume finishes the dataset.
    let t = expect_code(&rig(dir, &[&args[..], &["--resume"]].concat()), 0);
    assert!(t.contains("collected 1 poses (2 already present"), "{t}");
}

/// A collected ViTac dataset whose rows are relabelled synthetic with `z_mm` set to `z` (what
/// an edited or corrupt `poses.csv` holds): `rig audit` would press them again.
fn dataset_with_synthetic_rows_at(dir: &Path, z: &str) -> std::path::PathBuf {
    expect_code(&rig(dir, &["collect", "--poses", "3", "--seed", "1", "--sensor", "vitac", "--out", "out"]), 0);
    let ds = dir.join("out/sphere/vitac");
    let csv = std::fs::read_to_string(ds.join("poses.csv")).expect("csv");
    let mut out = String::new();
    for (k, line) in csv.lines().enumerate() {
        if k == 0 {
            out.push_str(line);
        } else {
            let mut cells: Vec<&str> = line.split(',').collect();
            cells[3] = z;
            cells[10] = "synthetic";
            out.push_str(&cells.join(","));
        }
        out.push('\n');
    }
    std::fs::write(ds.join("poses.csv"), out).expect("csv");
    ds
}

#[test]
fn an_audit_of_rows_past_the_press_limit_is_refused_and_verify_reports_them() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path();
    let ds = dataset_with_synthetic_rows_at(dir, "30.0");
    let ds_arg = ds.to_str().expect("utf-8");
    for t in refused_dry_and_real(dir, &["audit", "--dataset", ds_arg, "--fraction", "1"]) {
        assert!(t.contains("of the dataset's poses.csv") && t.contains("presses 31.500 mm into the skin"), "{t}");
        assert!(t.contains("vitac's press limit of 2.5 mm"), "{t}");
        assert!(!ds.join("audit").exists(), "nothing may start: {t}");
    }
    let t = expect_code(&rig(dir, &["dataset", "verify", ds_arg]), 1);
    assert_eq!(t.matches("past the press limit: pose_id").count(), 3, "{t}");
    assert!(t.contains("presses 31.500 mm into the skin, beyond vitac's press limit of 2.5 mm") && t.contains("NOT clean"), "{t}");
}

#[test]
fn verify_checks_the_rows_against_the_configured_limit() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path();
    // 1.5 mm contact depth + 2 mm: past ViTac's default 2.5 mm, within a configured 4 mm.
    let ds = dataset_with_synthetic_rows_at(dir, "2.0");
    let ds_arg = ds.to_str().expect("utf-8");
    let t = expect_code(&rig(dir, &["dataset", "verify", ds_arg]), 1);
    assert!(t.contains("presses 3.500 mm into the skin, beyond vitac's press limit of 2.5 mm"), "{t}");
    std::fs::write(dir.join("rig.toml"), "[sensors.vitac]\nmax_indentation_mm = 4.0\n").expect("config");
    let t = expect_code(&rig(dir, &["dataset", "verify", ds_arg]), 0);
    assert!(t.ends_with(&format!("{ds_arg}: clean\n")), "./rig.toml's limit applies, and the verdict names the dataset: {t}");
    std::fs::rename(dir.join("rig.toml"), dir.join("bench.toml")).expect("mv");
    expect_code(&rig(dir, &["dataset", "verify", ds_arg, "--config", "bench.toml"]), 0);
}

#[test]
fn a_calibration_pressing_past_the_limit_is_refused_before_anything_moves() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path();
    // The default pattern presses 0.5 mm either side of the contact depth: with a 2.2 mm
    // contact depth its deepest layer (from press 35) presses 2.7 mm, past ViTac's 2.5 mm
    // (TacTip's 5 mm allows it).
    std::fs::write(dir.join("deep.toml"), frame_config(2.2)).expect("config");
    for t in refused_dry_and_real(dir, &["calibrate", "--sensor", "vitac", "--config", "deep.toml", "--out", "cal.toml"]) {
        assert!(
            t.contains("calibration press 35 (x 0.000 mm, y 0.000 mm, z 0.500 mm, yaw 0.000 deg) presses 2.700 mm into the skin (contact depth 2.200 mm + z 0.500 mm)"),
            "{t}"
        );
        assert!(t.contains("vitac's press limit of 2.5 mm"), "{t}");
        assert!(!dir.join("cal.toml").exists(), "nothing saved: {t}");
    }
    let t = expect_code(&rig(dir, &["calibrate", "--sensor", "tactip", "--config", "deep.toml", "--out", "cal.toml", "--dry-run"]), 0);
    assert!(t.contains("deepest press: 2.700 mm (calibration press 35)") && t.contains("tactip's press limit of 5 mm"), "{t}");
}
