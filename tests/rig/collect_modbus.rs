//! `rig collect` on the simulated rig with simulated Modbus peripherals: a force sensor whose
//! reading follows the arm's indentation and an illumination controller, both real Modbus TCP
//! servers on loopback. Checks the `modbus` column per row, the failure policy when a
//! peripheral stops answering mid-run, and resume after a kill.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

/// N per mm in the configs below.
const STIFFNESS_N_PER_MM: f64 = 2.0;
/// The default work frame's contact depth, mm.
const CONTACT_DEPTH_MM: f64 = 1.5;

fn rig() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_rig"));
    c.current_dir(env!("CARGO_MANIFEST_DIR"));
    c.env_remove("RIG_CONFIG");
    c
}

/// A config with a force sensor (required unless `force_optional`) and an optional light;
/// `force_silent_after` makes the force sensor stop answering after that many requests.
fn write_config(dir: &Path, force_optional: bool, force_silent_after: Option<u64>) -> PathBuf {
    let mut text = format!(
        "[modbus.force]\ntransport = \"sim\"\nsim = \"force\"\nsim_stiffness_n_per_mm = {STIFFNESS_N_PER_MM}\ntimeout_ms = 200\n\
         required = {}\n\
         read = [{{ name = \"force_N\", kind = \"input\", register = 0, words = 2, signed = true, scale = 0.001 }}]\n",
        !force_optional
    );
    if let Some(n) = force_silent_after {
        text.push_str(&format!("sim_stop_answering_after = {n}\n"));
    }
    text.push_str(
        "[modbus.light]\ntransport = \"sim\"\nsim = \"light\"\nrequired = false\ntimeout_ms = 200\n\
         before_capture = [{ register = 0, value = 800 }]\nafter_capture = [{ register = 0, value = 0 }]\n\
         read = [{ name = \"level_permille\", register = 0 }]\n",
    );
    let path = dir.join(format!("rig-{force_optional}-{force_silent_after:?}.toml"));
    std::fs::write(&path, text).expect("writing config");
    path
}

fn collect(config: &Path, out: &Path, poses: usize, resume: bool) -> Command {
    let mut c = rig();
    c.args(["collect", "--object", "sphere", "--sensor", "tactip,vitac", "--seed", "3", "--poses"])
        .arg(poses.to_string())
        .arg("--out")
        .arg(out)
        .arg("--config")
        .arg(config);
    if resume {
        c.arg("--resume");
    }
    c
}

fn text(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned() + &String::from_utf8_lossy(&o.stderr)
}

/// A row of `poses.csv` as a map from column name to cell.
fn rows(dir: &Path) -> Vec<std::collections::BTreeMap<String, String>> {
    let mut r = csv::Reader::from_path(dir.join("poses.csv")).expect("poses.csv");
    let header: Vec<String> = r.headers().expect("header").iter().map(str::to_string).collect();
    assert_eq!(header.last().map(String::as_str), Some("modbus"), "{header:?}");
    r.records()
        .map(|rec| {
            let rec = rec.expect("record");
            header.iter().cloned().zip(rec.iter().map(str::to_string)).collect()
        })
        .collect()
}

/// The named value of a `modbus` cell: `Some(None)` when the name is there with no value.
fn reading(cell: &str, name: &str) -> Option<Option<f64>> {
    cell.split(';').find_map(|item| {
        let (n, v) = item.split_once('=')?;
        (n == name).then(|| if v.is_empty() { None } else { Some(v.parse().expect("a number")) })
    })
}

fn verify(dir: &Path) {
    let o = rig().args(["dataset", "verify"]).arg(dir).output().expect("rig dataset verify");
    assert!(o.status.success(), "verify {}:\n{}", dir.display(), text(&o));
}

/// Every row's force is stiffness x (contact depth + measured press depth), and the light was
/// on (800 per mille) while it was read.
fn check_forces(dir: &Path, expect_rows: usize) -> Vec<(f64, f64)> {
    let rows = rows(dir);
    assert_eq!(rows.len(), expect_rows, "{}", dir.display());
    let mut by_depth = Vec::new();
    for row in &rows {
        let cell = &row["modbus"];
        let force_n = reading(cell, "force.force_N").flatten().unwrap_or_else(|| panic!("no force in {cell:?}"));
        let meas_z_mm: f64 = row["meas_z_mm"].parse().expect("meas_z_mm");
        let expected = STIFFNESS_N_PER_MM * (CONTACT_DEPTH_MM + meas_z_mm).max(0.0);
        assert!((force_n - expected).abs() < 0.01, "pose {}: force {force_n} N, expected {expected} N", row["pose_id"]);
        assert_eq!(reading(cell, "light.level_permille"), Some(Some(800.0)), "{cell}");
        let z_mm: f64 = row["z_mm"].parse().expect("z_mm");
        by_depth.push((z_mm, force_n));
    }
    by_depth
}

#[test]
fn force_is_logged_per_row_and_grows_with_press_depth() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let config = write_config(tmp.path(), false, None);
    let out = tmp.path().join("out");
    let o = collect(&config, &out, 12, false).output().expect("rig collect");
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("Modbus peripherals: force"), "the banner names them:\n{}", text(&o));
    let mut by_depth = Vec::new();
    for sensor in ["tactip", "vitac"] {
        let dir = out.join("sphere").join(sensor);
        verify(&dir);
        by_depth = check_forces(&dir, 12);
    }
    // The same pose has the same readings in both sensors' rows.
    let (a, b) = (rows(&out.join("sphere/tactip")), rows(&out.join("sphere/vitac")));
    for (ra, rb) in a.iter().zip(&b) {
        assert_eq!((&ra["pose_id"], &ra["modbus"]), (&rb["pose_id"], &rb["modbus"]));
    }
    // Deeper presses read more force, and the plan covers more than one depth.
    by_depth.sort_by(|x, y| x.0.total_cmp(&y.0));
    assert!(by_depth.windows(2).all(|w| w[0].0 == w[1].0 || w[1].1 > w[0].1), "{by_depth:?}");
    assert!(by_depth.first().map(|f| f.1) < by_depth.last().map(|l| l.1), "{by_depth:?}");
}

#[test]
fn an_optional_sensor_that_goes_silent_leaves_empty_values_and_the_run_finishes() {
    let tmp = tempfile::tempdir().expect("tempdir");
    // The reference frame and the first three poses read the force, then it stops answering.
    let config = write_config(tmp.path(), true, Some(4));
    let out = tmp.path().join("out");
    let o = collect(&config, &out, 6, false).output().expect("rig collect");
    assert!(o.status.success(), "{}", text(&o));
    let dir = out.join("sphere/tactip");
    verify(&dir);
    let forces: Vec<Option<Option<f64>>> = rows(&dir).iter().map(|r| reading(&r["modbus"], "force.force_N")).collect();
    assert_eq!(forces.len(), 6);
    assert!(forces[..3].iter().all(|f| matches!(f, Some(Some(_)))), "{forces:?}");
    assert!(forces[3..].iter().all(|f| *f == Some(None)), "silent: name kept, value empty: {forces:?}");
    // The light kept answering throughout.
    assert!(rows(&dir).iter().all(|r| reading(&r["modbus"], "light.level_permille") == Some(Some(800.0))));
}

#[test]
fn a_required_sensor_that_goes_silent_stops_the_run_and_a_resume_finishes_it() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let silent = write_config(tmp.path(), false, Some(4));
    let out = tmp.path().join("out");
    let o = collect(&silent, &out, 6, false).output().expect("rig collect");
    assert_eq!(o.status.code(), Some(3), "a spent peripheral is a hardware fault:\n{}", text(&o));
    assert!(text(&o).contains("gave up after 4 attempts") && text(&o).contains("modbus force"), "{}", text(&o));
    for sensor in ["tactip", "vitac"] {
        let dir = out.join("sphere").join(sensor);
        verify(&dir);
        check_forces(&dir, 3);
    }
    // The device answers again: the resume captures the rest, with forces.
    let healthy = write_config(tmp.path(), false, None);
    let o = collect(&healthy, &out, 6, true).output().expect("rig collect --resume");
    assert!(o.status.success(), "{}", text(&o));
    for sensor in ["tactip", "vitac"] {
        let dir = out.join("sphere").join(sensor);
        verify(&dir);
        check_forces(&dir, 6);
    }
}

#[test]
fn sigkill_then_resume_keeps_the_modbus_column_consistent() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let config = write_config(tmp.path(), false, None);
    let poses = 8;
    for (run, delay_ms) in [(0u32, 700u64), (1, 1600)] {
        let out = tmp.path().join(format!("run{run}"));
        let mut child = collect(&config, &out, poses, true).stdout(Stdio::null()).stderr(Stdio::null()).spawn().expect("spawn");
        let start = Instant::now();
        while start.elapsed() < Duration::from_millis(delay_ms) && child.try_wait().expect("try_wait").is_none() {
            std::thread::sleep(Duration::from_millis(10));
        }
        let _ = child.kill();
        let _ = child.wait();
        let o = collect(&config, &out, poses, true).output().expect("resume");
        assert!(o.status.success(), "run {run}: {}", text(&o));
        for sensor in ["tactip", "vitac"] {
            let dir = out.join("sphere").join(sensor);
            verify(&dir);
            check_forces(&dir, poses);
        }
    }
}

#[test]
fn a_recording_with_peripherals_replays_with_the_same_modbus_column() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let config = write_config(tmp.path(), false, None);
    // Small frames keep the recording small.
    let mut text_cfg = std::fs::read_to_string(&config).expect("config");
    text_cfg.push_str("[sensors.tactip]\nwidth = 48\nheight = 40\n[sensors.vitac]\nwidth = 48\nheight = 40\n");
    std::fs::write(&config, text_cfg).expect("config");
    let (recorded, replayed, rec) = (tmp.path().join("recorded"), tmp.path().join("replayed"), tmp.path().join("rec.bin"));
    let o = collect(&config, &recorded, 3, false).arg("--record").arg(&rec).output().expect("rig collect --record");
    assert!(o.status.success(), "{}", text(&o));
    let o = rig().arg("replay").arg(&rec).arg("--out").arg(&replayed).args(["--stall-s", "20"]).output().expect("rig replay");
    assert!(o.status.success(), "{}", text(&o));
    for sensor in ["tactip", "vitac"] {
        let (a, b) = (recorded.join("sphere").join(sensor), replayed.join("sphere").join(sensor));
        verify(&b);
        check_forces(&a, 3);
        // The recording holds each peripheral call's readings: every column replays exactly,
        // the modbus column included.
        let (ra, rb) = (rows(&a), rows(&b));
        assert_eq!(ra.len(), 3);
        assert!(ra.iter().all(|r| !r["modbus"].is_empty()), "{ra:?}");
        assert_eq!(ra, rb);
    }
    // One peripheral call the replay does not make is reported, not ignored: drop the last
    // recorded peripherals record.
    let mut r = rig::record::format::decode(&std::fs::read(&rec).expect("recording")).expect("decode");
    let last = r.events.iter().rposition(|e| matches!(e, rig::record::Event::Peripherals { .. })).expect("a peripherals record");
    r.events.remove(last);
    let mut bytes = rig::record::format::encode_preamble(&r.header_json);
    for e in &r.events {
        bytes.extend(rig::record::format::encode_event(e));
    }
    bytes.extend(rig::record::format::encode_end(r.events.len() as u64));
    let short = tmp.path().join("short.bin");
    std::fs::write(&short, bytes).expect("writing");
    let o = rig()
        .arg("replay")
        .arg(&short)
        .arg("--out")
        .arg(tmp.path().join("from-short"))
        .args(["--stall-s", "20"])
        .output()
        .expect("rig replay");
    assert_eq!(o.status.code(), Some(3), "{}", text(&o));
    assert!(text(&o).contains("peripherals call"), "{}", text(&o));
}
