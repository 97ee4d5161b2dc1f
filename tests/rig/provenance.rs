//! Provenance of captured frames: `rig collect` on the simulated rig writes `source=simulated`
//! rows and a manifest naming every simulated part; `rig dataset verify` counts rows by source
//! and reads datasets from before the capture chain; `rig dataset merge` refuses to mix real
//! and simulated frames unless `--allow-mixed`.

use std::path::Path;
use std::process::{Command, Output};

use rig::dataset::Manifest;

fn rig() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_rig"));
    c.current_dir(env!("CARGO_MANIFEST_DIR"));
    c.env_remove("RIG_CONFIG");
    c
}

fn text(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned() + &String::from_utf8_lossy(&o.stderr)
}

/// The data lines of `poses.csv`.
fn lines(dir: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(dir.join("poses.csv")).unwrap_or_else(|e| panic!("reading {}: {e}", dir.display()));
    text.lines().skip(1).map(str::to_string).collect()
}

/// The `source` cell of a data line (column 11 of the header).
fn source_of(line: &str) -> &str {
    line.split(',').nth(10).unwrap_or_default()
}

/// A copy of dataset `from` at `to` with only the rows `keep` (their images only), each row's
/// source replaced by `source` when given.
fn copy_rows(from: &Path, to: &Path, keep: std::ops::Range<usize>, source: Option<&str>) {
    std::fs::create_dir_all(to.join("images")).expect("mkdir");
    std::fs::copy(from.join("manifest.toml"), to.join("manifest.toml")).expect("copy manifest");
    std::fs::copy(from.join("reference.png"), to.join("reference.png")).expect("copy reference");
    let text = std::fs::read_to_string(from.join("poses.csv")).expect("read csv");
    let mut out = text.lines().next().unwrap_or_default().to_string() + "\n";
    for line in text.lines().skip(1).skip(keep.start).take(keep.len()) {
        let mut cells: Vec<&str> = line.split(',').collect();
        if let Some(s) = source {
            cells[10] = s;
        }
        let image = cells[9];
        std::fs::copy(from.join(image), to.join(image)).expect("copy image");
        out.push_str(&cells.join(","));
        out.push('\n');
    }
    std::fs::write(to.join("poses.csv"), out).expect("write csv");
}

/// `manifest.toml` of `dir` without its capture chain, as rig wrote it before the field.
fn strip_capture(dir: &Path) {
    let path = dir.join("manifest.toml");
    let text = std::fs::read_to_string(&path).expect("read manifest");
    let mut out = String::new();
    let mut in_capture = false;
    for line in text.lines() {
        if line.starts_with('[') {
            in_capture = line.trim_start_matches('[').starts_with("capture");
        }
        if !in_capture {
            out.push_str(line);
            out.push('\n');
        }
    }
    assert!(out.len() < text.len(), "the manifest had a capture chain:\n{text}");
    std::fs::write(&path, out).expect("write manifest");
}

#[test]
fn simulated_collection_says_so_and_merge_keeps_sources_apart() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let config = tmp.path().join("rig.toml");
    std::fs::write(
        &config,
        "[modbus.light]\ntransport = \"sim\"\nsim = \"light\"\nrequired = false\ntimeout_ms = 200\n\
         read = [{ name = \"level_permille\", register = 0 }]\n",
    )
    .expect("config");
    let out = tmp.path().join("sim");
    let o = rig()
        .args(["collect", "--object", "sphere", "--sensor", "tactip,vitac", "--seed", "5", "--poses", "4", "--out"])
        .arg(&out)
        .arg("--config")
        .arg(&config)
        .output()
        .expect("running rig collect");
    assert!(o.status.success(), "rig collect failed:\n{}", text(&o));
    let sim = out.join("sphere").join("tactip");

    // Rows say simulated, never real.
    let rows = lines(&sim);
    assert_eq!(rows.len(), 4);
    assert!(rows.iter().all(|l| source_of(l) == "simulated"), "rows:\n{}", rows.join("\n"));

    // The manifest names every simulated part.
    let manifest = Manifest::load(&sim).expect("manifest");
    let capture = manifest.capture.expect("a capture chain");
    assert_eq!((capture.arm.backend.as_str(), capture.arm.simulated), ("sim-mg400", true));
    let sensors: Vec<(&str, &str, bool)> = capture.sensors.iter().map(|p| (p.name.as_str(), p.backend.as_str(), p.simulated)).collect();
    assert_eq!(sensors, [("tactip", "sim", true), ("vitac", "sim", true)]);
    // Each sensor's stream: the simulated one's rendered size and rate, no wire format.
    for part in &capture.sensors {
        assert_eq!((part.resolution_px, part.requested_fps, part.format.as_deref()), (Some([512, 512]), Some(30), None), "{part:?}");
    }
    assert_eq!(capture.arm.address, None, "the simulated arm runs in-process");
    // The simulated MG400 runs the default profile's firmware, and says it is simulated.
    assert_eq!(capture.arm.firmware.as_deref(), Some("1.6.0.0 (simulated)"));
    let modbus: Vec<(&str, bool)> = capture.modbus.iter().map(|p| (p.name.as_str(), p.simulated)).collect();
    assert_eq!(modbus, [("modbus.light", true)]);

    // verify counts by source and names the chain.
    let v = rig().args(["dataset", "verify"]).arg(&sim).output().expect("verify");
    assert!(v.status.success(), "{}", text(&v));
    assert!(text(&v).contains("rows 4 (0 real, 4 simulated, 0 synthetic)"), "{}", text(&v));
    assert!(text(&v).contains("arm sim-mg400 (simulated), tactip sim (simulated), vitac sim (simulated)"), "{}", text(&v));

    // A dataset from before the field: rows `real`, no capture chain. It still reads, its rows
    // kept as they are, and verify says the manifest predates the field.
    let old = tmp.path().join("old");
    copy_rows(&sim, &old, 0..2, Some("real"));
    strip_capture(&old);
    assert_eq!(Manifest::load(&old).expect("old manifest").capture, None);
    let v = rig().args(["dataset", "verify"]).arg(&old).output().expect("verify");
    assert!(v.status.success(), "{}", text(&v));
    assert!(text(&v).contains("rows 2 (2 real, 0 simulated, 0 synthetic)"), "{}", text(&v));
    assert!(text(&v).contains("the manifest predates the field"), "{}", text(&v));
    assert!(lines(&old).iter().all(|l| source_of(l) == "real"));

    // Merging real and simulated frames is refused (bad input, exit code 2), nothing written.
    let part = tmp.path().join("part");
    copy_rows(&sim, &part, 2..4, None);
    let merged = tmp.path().join("merged");
    let m = rig().args(["dataset", "merge", "--out"]).arg(&merged).arg(&part).arg(&old).output().expect("merge");
    assert_eq!(m.status.code(), Some(2), "{}", text(&m));
    assert!(text(&m).contains("refusing to mix real and simulated frames"), "{}", text(&m));
    assert!(text(&m).contains("--allow-mixed"), "{}", text(&m));
    assert!(!merged.exists(), "a refused merge must write nothing");

    // With --allow-mixed it merges, and verify counts both.
    let m = rig().args(["dataset", "merge", "--allow-mixed", "--out"]).arg(&merged).arg(&part).arg(&old).output().expect("merge");
    assert!(m.status.success(), "{}", text(&m));
    let v = rig().args(["dataset", "verify"]).arg(&merged).output().expect("verify");
    assert!(v.status.success(), "{}", text(&v));
    assert!(text(&v).contains("rows 4 (2 real, 2 simulated, 0 synthetic)"), "{}", text(&v));
}

/// Keeps the first `keep` data lines of `dir/poses.csv` (their images become orphans, which a
/// resume deletes and captures again), as a run interrupted after `keep` poses leaves it.
fn truncate_rows(dir: &Path, keep: usize) {
    let path = dir.join("poses.csv");
    let text = std::fs::read_to_string(&path).expect("read csv");
    let kept: Vec<&str> = text.lines().take(1 + keep).collect();
    std::fs::write(&path, kept.join("\n") + "\n").expect("write csv");
}

#[test]
fn simulated_stream_counts_say_so_and_a_resumed_run_adds_to_them() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let out = tmp.path().join("sim");
    let collect = |resume: bool| {
        let mut c = rig();
        c.args(["collect", "--object", "sphere", "--sensor", "tactip,vitac", "--seed", "3", "--poses", "4", "--out"]).arg(&out);
        if resume {
            c.arg("--resume");
        }
        let o = c.output().expect("running rig collect");
        assert!(o.status.success(), "rig collect failed:\n{}", text(&o));
    };
    let datasets = [out.join("sphere").join("tactip"), out.join("sphere").join("vitac")];
    // Every sensor part of every manifest: (name, simulated, frames received, dropped,
    // measured rate, measured time).
    let counts = |dir: &Path| {
        let manifest = Manifest::load(dir).expect("manifest");
        let capture = manifest.capture.expect("a capture chain");
        capture
            .sensors
            .iter()
            .map(|p| (p.name.clone(), p.simulated, p.frames_received, p.frames_dropped, p.measured_fps, p.stream_s))
            .collect::<Vec<_>>()
    };

    collect(false);
    // Each simulated sensor rendered the reference frame and one frame per pose; it drops
    // nothing and measures nothing (no rate, no stream time: its rate is the nominal one).
    for dir in &datasets {
        assert_eq!(
            counts(dir),
            [("tactip".to_string(), true, Some(5), Some(0), None, None), ("vitac".to_string(), true, Some(5), Some(0), None, None)],
            "{}",
            dir.display()
        );
        let text = std::fs::read_to_string(dir.join("manifest.toml")).expect("manifest text");
        assert!(!text.contains("measured_fps") && !text.contains("stream_s"), "{text}");
    }

    // As if interrupted after two poses: the resumed run captures the other two, and its
    // frames are added to the first run's.
    for dir in &datasets {
        truncate_rows(dir, 2);
    }
    collect(true);
    for dir in &datasets {
        assert_eq!(lines(dir).len(), 4, "{}", dir.display());
        assert_eq!(Manifest::load(dir).expect("manifest").resumed_utc.len(), 1);
        assert_eq!(
            counts(dir),
            [("tactip".to_string(), true, Some(7), Some(0), None, None), ("vitac".to_string(), true, Some(7), Some(0), None, None)],
            "{}",
            dir.display()
        );
    }
}
