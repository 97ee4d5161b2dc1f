//! End-to-end tests of `rig collect` on the built-in simulated rig: the real binary, the real
//! MG400 client over loopback TCP against the simulated controller, simulated sensors, and the
//! crash-safe dataset.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use rand::{RngExt, SeedableRng};

fn rig() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_rig"));
    c.current_dir(env!("CARGO_MANIFEST_DIR"));
    c.env_remove("RIG_CONFIG");
    c
}

fn collect_args(out: &Path, poses: usize, seed: u64, sensor: &str) -> Vec<String> {
    vec![
        "collect".into(),
        "--object".into(),
        "sphere".into(),
        "--poses".into(),
        poses.to_string(),
        "--seed".into(),
        seed.to_string(),
        "--sensor".into(),
        sensor.into(),
        "--out".into(),
        out.display().to_string(),
    ]
}

/// `poses.csv` without the columns that hold wall-clock-dependent values.
fn csv_without_time(path: &Path) -> String {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("reading {}: {e}", path.display()));
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap_or_default().split(',').collect();
    let keep: Vec<usize> = (0..header.len()).filter(|&i| !header[i].starts_with("t_")).collect();
    let mut out = String::new();
    for line in std::iter::once(header.join(",")).chain(lines.map(str::to_string)) {
        let cells: Vec<&str> = line.split(',').collect();
        let kept: Vec<&str> = keep.iter().filter_map(|&i| cells.get(i).copied()).collect();
        out.push_str(&kept.join(","));
        out.push('\n');
    }
    out
}

fn verify(dir: &Path) -> String {
    let out = rig().args(["dataset", "verify"]).arg(dir).output().expect("running rig dataset verify");
    let text = String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "verify {} failed:\n{text}", dir.display());
    text
}

fn rows(dir: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(dir.join("poses.csv")).unwrap_or_default();
    text.lines().skip(1).map(|l| l.split(',').next().unwrap_or_default().to_string()).collect()
}

#[test]
fn seeded_collection_is_reproducible_and_matches_the_golden_file() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
    for out in [&a, &b] {
        let o = rig().args(collect_args(out, 50, 1, "all")).output().expect("running rig collect");
        let stdout = String::from_utf8_lossy(&o.stdout);
        assert!(o.status.success(), "rig collect failed:\n{stdout}\n{}", String::from_utf8_lossy(&o.stderr));
        assert!(stdout.lines().next().unwrap_or_default().contains("simulated rig"), "first line must say so:\n{stdout}");
    }
    for sensor in ["tactip", "vitac", "vitactip"] {
        let (da, db) = (a.join("sphere").join(sensor), b.join("sphere").join(sensor));
        assert_eq!(rows(&da).len(), 50, "{sensor}: 50 rows");
        let images = std::fs::read_dir(da.join("images")).expect("images dir").count();
        assert_eq!(images, 50, "{sensor}: 50 images");
        assert!(da.join("reference.png").is_file(), "{sensor}: reference frame");
        let (ca, cb) = (csv_without_time(&da.join("poses.csv")), csv_without_time(&db.join("poses.csv")));
        assert_eq!(ca, cb, "{sensor}: two seeded runs differ");
        let golden: PathBuf =
            [env!("CARGO_MANIFEST_DIR"), "tests", "golden", &format!("collect-sphere-50-seed1-{sensor}.csv")].iter().collect();
        if std::env::var_os("RIG_BLESS").is_some() {
            std::fs::write(&golden, &ca).expect("writing golden file");
        }
        let expected =
            std::fs::read_to_string(&golden).unwrap_or_else(|e| panic!("golden {}: {e} (RIG_BLESS=1 writes it)", golden.display()));
        assert_eq!(ca, expected, "{sensor}: CSV differs from {}", golden.display());
        for id in rows(&da).iter().take(5) {
            let ia = image::open(da.join("images").join(format!("{id}.png"))).expect("image a").to_rgb8();
            let ib = image::open(db.join("images").join(format!("{id}.png"))).expect("image b").to_rgb8();
            let differing = ia.as_raw().iter().zip(ib.as_raw()).filter(|(x, y)| x != y).count();
            assert_eq!(differing, 0, "{sensor} pose {id}: {differing} channel values differ between seeded runs");
        }
        verify(&da);
    }
}

#[test]
fn sigkill_at_random_moments_then_resume_loses_and_duplicates_nothing() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let mut rng = rand::rngs::StdRng::seed_from_u64(0x5191_c111);
    let poses = 12;
    for run in 0..10u64 {
        let out = tmp.path().join(format!("run{run}"));
        let args = collect_args(&out, poses, 100 + run, "tactip,vitac");
        // Kill it at a random moment, possibly several times, then let a resume finish.
        let kills = 1 + run % 2;
        for _ in 0..kills {
            let mut child =
                rig().args(&args).arg("--resume").stdout(Stdio::null()).stderr(Stdio::null()).spawn().expect("spawning rig collect");
            let delay = Duration::from_millis(rng.random_range(150..2500));
            let start = Instant::now();
            while start.elapsed() < delay {
                if child.try_wait().expect("try_wait").is_some() {
                    break;
                }
                std::thread::sleep(Duration::from_millis(10));
            }
            let _ = child.kill(); // SIGKILL on Unix
            let _ = child.wait();
        }
        let o = rig().args(&args).arg("--resume").output().expect("resuming rig collect");
        assert!(o.status.success(), "run {run}: resume failed: {}", String::from_utf8_lossy(&o.stderr));
        for sensor in ["tactip", "vitac"] {
            let dir = out.join("sphere").join(sensor);
            let report = verify(&dir);
            let ids = rows(&dir);
            let mut unique = ids.clone();
            unique.sort();
            unique.dedup();
            assert_eq!(ids.len(), poses, "run {run} {sensor}: rows\n{report}");
            assert_eq!(unique.len(), poses, "run {run} {sensor}: duplicated rows\n{report}");
            let images = std::fs::read_dir(dir.join("images")).expect("images").count();
            assert_eq!(images, poses, "run {run} {sensor}: images\n{report}");
            // The order was kept once, before the first pose, whatever the kills interrupted.
            assert_eq!(kept_order(&dir).len(), poses, "run {run} {sensor}: kept order\n{report}");
            assert!(report.contains(&format!("kept order: {poses} poses")), "run {run} {sensor}\n{report}");
        }
    }
}

#[test]
fn existing_dataset_is_refused_without_resume() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let args = collect_args(tmp.path(), 3, 5, "tactip");
    let first = rig().args(&args).output().expect("rig collect");
    assert!(first.status.success(), "{}", String::from_utf8_lossy(&first.stderr));
    let before = std::fs::read(tmp.path().join("sphere/tactip/poses.csv")).expect("csv");
    let second = rig().args(&args).output().expect("rig collect again");
    assert!(!second.status.success());
    let err = String::from_utf8_lossy(&second.stderr);
    assert!(err.contains("--resume"), "the refusal should point at --resume: {err}");
    assert_eq!(std::fs::read(tmp.path().join("sphere/tactip/poses.csv")).expect("csv"), before, "nothing overwritten");
}

/// A dataset an earlier rig build collected on a built-in object recorded another sha256 of the same mesh
/// (its STL with the bare name as header): `--resume` takes it as the same object and keeps it.
#[test]
fn a_dataset_with_the_older_hash_of_a_built_in_object_resumes() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let args = collect_args(tmp.path(), 3, 5, "tactip");
    let first = rig().args(&args).output().expect("rig collect");
    assert!(first.status.success(), "{}", String::from_utf8_lossy(&first.stderr));
    let manifest = tmp.path().join("sphere/tactip/manifest.toml");
    let object = rig::geometry::objects::ObjectChoice::resolve("sphere", None).expect("the library sphere");
    let (current, legacy) = (object.sha256.clone(), object.legacy_sha256());
    assert_ne!(current, legacy);
    let text = std::fs::read_to_string(&manifest).expect("manifest");
    assert!(text.contains(&current), "the new collection records the library file's hash");
    std::fs::write(&manifest, text.replace(&current, &legacy)).expect("writing the older hash");
    let resumed = rig().args(&args).arg("--resume").output().expect("rig collect --resume");
    assert!(resumed.status.success(), "{}", String::from_utf8_lossy(&resumed.stderr));
    assert!(std::fs::read_to_string(&manifest).expect("manifest").contains(&legacy), "the dataset keeps the hash it has");
    // Another mesh's hash is still refused.
    std::fs::write(&manifest, std::fs::read_to_string(&manifest).expect("manifest").replace(&legacy, &"0".repeat(64))).expect("write");
    let refused = rig().args(&args).arg("--resume").output().expect("rig collect --resume");
    assert_eq!(refused.status.code(), Some(2), "{}", String::from_utf8_lossy(&refused.stderr));
}

#[test]
fn plan_outside_the_workspace_is_refused_before_anything_moves() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let cfg = tmp.path().join("rig.toml");
    // The object placed 437 mm out: the reference pose above it is within the MG400's 440 mm
    // reach, but plan poses up to 5 mm further out are not.
    std::fs::write(&cfg, "[work_frame]\norigin = { x_mm = 437.0, y_mm = 0.0, z_mm = 0.0, yaw_deg = 0.0 }\n").expect("write config");
    let o = rig().args(collect_args(&tmp.path().join("out"), 5, 1, "tactip")).arg("--config").arg(&cfg).output().expect("rig collect");
    assert_eq!(o.status.code(), Some(2), "a refused plan is bad input");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("outside the arm's workspace") && err.contains("plan pose"), "{err}");
    assert!(err.contains("radius"), "the message names the limit: {err}");
    assert!(!tmp.path().join("out/sphere/tactip/poses.csv").exists(), "no dataset may be started");
}

/// `order.csv` of a dataset: its pose ids, in order.
fn kept_order(dir: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(dir.join("order.csv")).unwrap_or_else(|e| panic!("order.csv of {}: {e}", dir.display()));
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("pose_id"), "{text}");
    lines.map(str::to_string).collect()
}

/// Takes the last `k` rows (and their images) off a finished dataset: what a run killed `k`
/// poses before its end leaves once resumed. Returns their ids.
fn drop_last_rows(dir: &Path, k: usize) -> Vec<String> {
    let text = std::fs::read_to_string(dir.join("poses.csv")).expect("poses.csv");
    let lines: Vec<&str> = text.lines().collect();
    let keep = lines.len() - k;
    let dropped: Vec<String> = lines[keep..].iter().map(|l| l.split(',').next().unwrap_or_default().to_string()).collect();
    std::fs::write(dir.join("poses.csv"), lines[..keep].iter().map(|l| format!("{l}\n")).collect::<String>()).expect("poses.csv");
    for id in &dropped {
        std::fs::remove_file(dir.join("images").join(format!("{id}.png"))).expect("image");
    }
    dropped
}

/// A collection keeps its order in each dataset before the first pose, and a resume visits the
/// poses in the kept order, not in one computed again: here the kept order is rewritten
/// (reversed, still an order of the same plan), and the resumed poses follow it.
#[test]
fn resume_visits_the_kept_order_without_ordering_again() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let out = tmp.path().join("out");
    let args = collect_args(&out, 12, 5, "tactip,vitac");
    let o = rig().args(&args).output().expect("rig collect");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (tactip, vitac) = (out.join("sphere").join("tactip"), out.join("sphere").join("vitac"));
    let order = kept_order(&tactip);
    assert_eq!(order.len(), 12);
    assert_eq!(kept_order(&vitac), order, "every dataset of the run keeps the same order");
    assert_eq!(rows(&tactip), order, "the rows were captured in the kept order");

    // Five poses left in each dataset, and the kept order reversed.
    let dropped = drop_last_rows(&tactip, 5);
    assert_eq!(drop_last_rows(&vitac, 5), dropped);
    let reversed: Vec<String> = order.iter().rev().cloned().collect();
    for dir in [&tactip, &vitac] {
        std::fs::write(dir.join("order.csv"), format!("pose_id\n{}\n", reversed.join("\n"))).expect("order.csv");
    }
    let dry = rig().args(&args).args(["--resume", "--dry-run"]).output().expect("rig collect --dry-run");
    let stdout = String::from_utf8_lossy(&dry.stdout);
    assert!(stdout.contains("in the order kept in ") && stdout.contains("order.csv"), "{stdout}");
    let o = rig().args(&args).arg("--resume").output().expect("rig collect --resume");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let resumed: Vec<String> = dropped.iter().rev().cloned().collect();
    for dir in [&tactip, &vitac] {
        let now = rows(dir);
        assert_eq!(now[7..].to_vec(), resumed, "{}: the resumed poses follow the kept order", dir.display());
        assert_eq!(kept_order(dir), reversed, "the kept order is not rewritten");
        assert!(verify(dir).contains("kept order: 12 poses"));
    }
}

/// A dataset written before rig kept orders resumes: the plan is ordered as rig did then and
/// the order is kept. A kept order that is not the plan's is refused (exit 2), nothing moves.
#[test]
fn a_dataset_without_a_kept_order_resumes_and_a_foreign_one_is_refused() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let out = tmp.path().join("out");
    let args = collect_args(&out, 10, 6, "tactip");
    let o = rig().args(&args).output().expect("rig collect");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let dir = out.join("sphere").join("tactip");
    let order = kept_order(&dir);
    drop_last_rows(&dir, 4);
    std::fs::remove_file(dir.join("order.csv")).expect("remove order.csv");
    let o = rig().args(&args).arg("--resume").output().expect("rig collect --resume");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(String::from_utf8_lossy(&o.stdout).contains("in rig's order"), "{}", String::from_utf8_lossy(&o.stdout));
    assert_eq!(kept_order(&dir), order, "the same plan is ordered the same way, and kept");
    assert_eq!(rows(&dir).len(), 10);

    drop_last_rows(&dir, 2);
    let before = std::fs::read_to_string(dir.join("poses.csv")).expect("poses.csv");
    for (foreign, says) in [
        (format!("pose_id\n{}\n", order[..9].join("\n")), "lists 9 poses, the plan has 10"),
        (format!("pose_id\n{}\n7864\n", order[..9].join("\n")), "which is not one of the plan's"),
        (format!("pose_id\n{}\n{}\n", order[..9].join("\n"), order[0]), "line 11"),
        ("pose_id\nseven\n".to_string(), "line 2"),
    ] {
        std::fs::write(dir.join("order.csv"), &foreign).expect("order.csv");
        let o = rig().args(&args).arg("--resume").output().expect("rig collect --resume");
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{foreign:?}: {stderr}");
        assert!(stderr.contains("order.csv") && stderr.contains(says), "{foreign:?}: {stderr}");
        assert_eq!(std::fs::read_to_string(dir.join("poses.csv")).expect("poses.csv"), before, "nothing was collected");
    }
}
