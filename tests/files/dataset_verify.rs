//! `verify` finds each kind of damage; `merge` joins shards and refuses conflicts, and a merge
//! that appends nothing reads no image and writes nothing; the CLI's `rig dataset verify` exits
//! 1 on a damaged dataset; no bytes make the parsers panic.

use std::path::{Path, PathBuf};
use std::process::Command;

use image::RgbImage;
use proptest::prelude::*;
use rig::dataset::{
    DatasetError, DatasetWriter, Manifest, MergeOptions, ObjectInfo, PoseRow, SynthesisInfo, VerifyIssue, merge, read_rows, verify,
};
use rig::plan::PlanSpec;
use rig::pose::Pose;

fn manifest() -> Manifest {
    Manifest::new(rig::sensor::SensorKind::ViTac, ObjectInfo::named("sphere"), Some(PlanSpec::default()))
}

fn img(v: u8) -> RgbImage {
    RgbImage::from_fn(4, 4, |x, _| image::Rgb([v, x as u8, 0]))
}

fn synth_row(id: u32, seed: u64) -> PoseRow {
    let pose = PlanSpec::default().pose_of(id).expect("on grid");
    PoseRow::synthetic(id, pose, "mds-sd15", seed, 50, 1.0)
}

fn dataset(dir: &Path, ids: &[u32]) {
    let mut w = DatasetWriter::create(dir, manifest()).expect("create");
    for &id in ids {
        w.append(synth_row(id, id as u64), &img(id as u8)).expect("append");
    }
    w.finish().expect("finish");
}

/// A dataset `top/name` of synthetic rows `ids`.
fn shard(top: &Path, name: &str, ids: &[u32]) -> PathBuf {
    let d = top.join(name);
    dataset(&d, ids);
    d
}

#[test]
fn verify_reports_every_kind_of_damage() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("ds");
    dataset(&dir, &[1, 2, 3, 4]);
    let clean = verify(&dir).expect("verify");
    assert!(clean.is_clean(), "{clean}");
    assert_eq!((clean.rows, clean.images, clean.synthetic), (4, 4, 4));

    std::fs::remove_file(dir.join("images/2.png")).expect("rm");
    std::fs::write(dir.join("images/9.png"), b"png").expect("orphan");
    std::fs::write(dir.join("images/.5.png.tmp"), b"tmp").expect("tmp");
    let csv = dir.join("poses.csv");
    let mut text = std::fs::read_to_string(&csv).expect("read");
    let line3 = text.lines().nth(3).expect("row of pose 3").to_string();
    text.push_str(&format!("{line3}\n"));
    text.push_str("7,1,2,3\n");
    text.push_str("8,0,0,0,0,,,,,images/8.png,real,1.0,,,,,");
    std::fs::write(&csv, text).expect("write");

    let r = verify(&dir).expect("verify");
    assert!(!r.is_clean());
    assert_eq!((r.missing, r.orphan, r.duplicated, r.malformed, r.temp_files), (1, 1, 1, 2, 1), "{r}");
    assert!(r.issues.contains(&VerifyIssue::MissingImage { pose_id: 2, path: dir.join("images/2.png") }));
    assert!(r.issues.contains(&VerifyIssue::DuplicateRow { pose_id: 3, first_line: 4, line: 6 }));
    assert!(r.issues.iter().any(|i| matches!(i, VerifyIssue::TornLastLine { .. })));

    // The CLI prints the report and exits 1.
    let out = Command::new(env!("CARGO_BIN_EXE_rig")).args(["dataset", "verify"]).arg(&dir).output().expect("run rig");
    assert_eq!(out.status.code(), Some(1));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("missing 1, orphan 1, duplicated 1, malformed 2, temp files 1"), "{stdout}");
    // Resume refuses a duplicated row rather than guessing.
    assert!(matches!(DatasetWriter::resume(&dir, manifest()), Err(DatasetError::DuplicateRow { pose_id: 3, .. })));
}

/// The kept order (`order.csv`) is optional; when present it must parse, list only poses of
/// the plan's grid and list every captured row's pose.
#[test]
fn verify_checks_the_kept_order() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("ds");
    let mut w = DatasetWriter::create(&dir, manifest()).expect("create");
    let pose = |id: u32| PlanSpec::default().pose_of(id).expect("on grid");
    for id in [3, 1] {
        w.append(PoseRow::captured(id, pose(id), pose(id), 0.0, rig::dataset::Source::Simulated), &img(id as u8)).expect("append");
    }
    w.append(synth_row(2, 2), &img(2)).expect("append");
    w.finish().expect("finish");
    let r = verify(&dir).expect("verify");
    assert!(r.is_clean() && r.order.is_none(), "no kept order is clean: {r}");
    assert!(r.to_string().contains("kept order: none"), "{r}");

    let order = dir.join("order.csv");
    // Synthetic rows need not be in it; captured ones must.
    std::fs::write(&order, "pose_id\n3\n1\n9\n").expect("order");
    let r = verify(&dir).expect("verify");
    assert!(r.is_clean(), "{r}");
    assert_eq!(r.order, Some(3));
    std::fs::write(&order, "pose_id\n3\n9\n").expect("order");
    let r = verify(&dir).expect("verify");
    assert_eq!(r.issues, vec![VerifyIssue::UnorderedRows { rows: 1, first_pose_id: 1 }], "{r}");
    std::fs::write(&order, "pose_id\n3\n1\n7865\n").expect("order");
    let r = verify(&dir).expect("verify");
    assert!(matches!(&r.issues[..], [VerifyIssue::BadOrder { reason }] if reason.contains("7865 is outside")), "{r}");
    std::fs::write(&order, "pose_id\n3\n1\n3\n").expect("order");
    let r = verify(&dir).expect("verify");
    assert!(matches!(&r.issues[..], [VerifyIssue::BadOrder { reason }] if reason.contains("line 4")), "{r}");
    std::fs::remove_file(&order).expect("rm");
    std::os::unix::fs::symlink(dir.join("poses.csv"), &order).expect("symlink");
    let r = verify(&dir).expect("verify");
    assert_eq!(r.not_regular, 1, "{r}");
}

#[test]
fn merge_joins_shards_and_refuses_conflicts() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let a = shard(tmp.path(), "a", &[0, 2, 4]);
    let b = shard(tmp.path(), "b", &[1, 3, 4]); // 4 is in both, identical
    let out = tmp.path().join("out");
    let report = merge(&[a.clone(), b.clone()], &out, MergeOptions::default()).expect("merge");
    assert_eq!((report.appended, report.already_present), (5, 1));
    let ids: Vec<u32> = read_rows(&out).expect("rows").iter().map(|r| r.pose_id).collect();
    assert_eq!(ids, vec![0, 1, 2, 3, 4]);
    assert!(verify(&out).expect("verify").is_clean());
    // Merging again adds nothing.
    let again = merge(&[a.clone(), b], &out, MergeOptions::default()).expect("merge again");
    assert_eq!((again.appended, again.already_present), (0, 6));

    // A shard whose row 2 differs (another seed) conflicts; nothing is written.
    let c = tmp.path().join("c");
    let mut w = DatasetWriter::create(&c, manifest()).expect("create");
    w.append(synth_row(2, 77), &img(2)).expect("append");
    w.append(synth_row(5, 5), &img(5)).expect("append");
    w.finish().expect("finish");
    let err = merge(&[c], &out, MergeOptions::default()).unwrap_err();
    assert!(matches!(err, DatasetError::MergeConflict { pose_id: 2, .. }), "{err}");
    assert_eq!(read_rows(&out).expect("rows").len(), 5);

    // A shard of another sensor is refused by name.
    let d = tmp.path().join("d");
    let mut m = manifest();
    m.sensor = rig::sensor::SensorKind::TacTip;
    DatasetWriter::create(&d, m).expect("create").finish().expect("finish");
    let err = merge(&[a, d], &tmp.path().join("out2"), MergeOptions::default()).unwrap_err();
    assert!(matches!(err, DatasetError::ManifestMismatch { field: "sensor", .. }), "{err}");
}

/// A fill's shards carry `[synthesis]` (which model, at what sizes); merged into the dataset
/// they were filled from (which has none) or into a new folder after a shard without one, the
/// output records the latest synthesis, so `rig audit` can still name an upscale.
#[test]
fn a_merge_carries_the_synthesis_record_of_the_shards() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let record = |model: &str| SynthesisInfo {
        model: model.into(),
        model_dir: format!("./models/{model}"),
        model_resolution_px: [128, 128],
        image_resolution_px: [512, 512],
    };
    let filled = |name: &str, ids: &[u32], synthesis: Option<SynthesisInfo>| {
        let d = tmp.path().join(name);
        let mut w = DatasetWriter::create(&d, Manifest { synthesis, ..manifest() }).expect("create");
        for &id in ids {
            w.append(synth_row(id, id as u64), &img(id as u8)).expect("append");
        }
        w.finish().expect("finish");
        d
    };
    let collection = filled("collection", &[0, 1], None);
    let shard1 = filled("shard1", &[2, 3], Some(record("first")));
    let shard2 = filled("shard2", &[4], Some(record("second")));
    merge(&[shard1.clone(), shard2.clone()], &collection, MergeOptions::default()).expect("merge into the collection");
    let m = Manifest::load(&collection).expect("manifest");
    assert_eq!(m.synthesis, Some(record("second")), "the latest shard's record");
    assert_eq!(read_rows(&collection).expect("rows").len(), 5);
    assert!(verify(&collection).expect("verify").is_clean());

    let bare = filled("bare", &[5], None);
    let out = tmp.path().join("out");
    merge(&[bare, shard1], &out, MergeOptions::default()).expect("merge into a new folder");
    assert_eq!(Manifest::load(&out).expect("manifest").synthesis, Some(record("first")));
}

/// Every file below `dir`: relative path -> (inode, length, mtime, bytes).
fn snapshot(dir: &Path) -> std::collections::BTreeMap<PathBuf, (u64, u64, std::time::SystemTime, Vec<u8>)> {
    use std::os::unix::fs::MetadataExt;
    let mut out = std::collections::BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).expect("ls") {
            let path = e.expect("entry").path();
            let meta = std::fs::symlink_metadata(&path).expect("lstat");
            if meta.is_dir() {
                stack.push(path);
            } else {
                let rel = path.strip_prefix(dir).expect("below").to_path_buf();
                out.insert(rel, (meta.ino(), meta.len(), meta.modified().expect("mtime"), std::fs::read(&path).expect("read")));
            }
        }
    }
    out
}

#[test]
fn a_merge_that_appends_nothing_reads_no_image_and_changes_nothing() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let a = shard(tmp.path(), "a", &[0, 2, 4]);
    let b = shard(tmp.path(), "b", &[1, 3]);
    let out = tmp.path().join("out");
    let report = merge(&[a.clone(), b.clone()], &out, MergeOptions::default()).expect("merge");
    assert_eq!((report.appended, report.already_present), (5, 0));
    let before = snapshot(&out);
    assert_eq!(before.len(), 7, "manifest, poses.csv and five images: {:?}", before.keys().collect::<Vec<_>>());

    // An image of an input that no longer decodes (same length, other bytes): verify would
    // refuse the input, so merging again succeeds only if no image is read.
    let png = a.join("images/2.png");
    let len = std::fs::metadata(&png).expect("png").len() as usize;
    std::fs::write(&png, vec![0xAB; len]).expect("corrupt");
    assert!(!verify(&a).expect("verify").is_clean());
    std::thread::sleep(std::time::Duration::from_millis(20));
    let again = merge(&[a.clone(), b.clone()], &out, MergeOptions::default()).expect("merging again reads no image");
    assert_eq!((again.appended, again.already_present), (0, 5));
    assert!(snapshot(&out) == before, "the output changed: a merge that appends nothing writes nothing");

    // A merge that has something to append reads the images: the unclean input is refused and
    // the output is left as it was.
    let c = shard(tmp.path(), "c", &[5]);
    let err = merge(&[a.clone(), c.clone()], &out, MergeOptions::default()).expect_err("unclean input");
    assert!(matches!(&err, DatasetError::Unclean { dir, .. } if *dir == a), "{err}");
    assert!(snapshot(&out) == before);

    // A pose the output has, with the same row but an image of another size, is a conflict
    // found without reading either image.
    let d = tmp.path().join("d");
    let mut w = DatasetWriter::create(&d, manifest()).expect("create");
    w.append(synth_row(3, 3), &RgbImage::from_fn(9, 9, |x, y| image::Rgb([x as u8 * 20, y as u8 * 20, 7]))).expect("append");
    w.finish().expect("finish");
    let err = merge(&[d], &out, MergeOptions::default()).expect_err("conflict");
    assert!(matches!(err, DatasetError::MergeConflict { pose_id: 3, .. }), "{err}");
    assert!(snapshot(&out) == before);

    // The CLI says what it did (and exits 0).
    let cli =
        Command::new(env!("CARGO_BIN_EXE_rig")).args(["dataset", "merge", "--out"]).arg(&out).arg(&a).arg(&b).output().expect("run rig");
    assert_eq!(cli.status.code(), Some(0), "{}", String::from_utf8_lossy(&cli.stderr));
    assert!(String::from_utf8_lossy(&cli.stdout).contains("0 rows appended, 5 already present"));
    assert!(snapshot(&out) == before);
}

#[test]
fn create_refuses_existing_dataset_via_cli_style_message() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("ds");
    dataset(&dir, &[1]);
    let err = DatasetWriter::create(&dir, manifest()).unwrap_err();
    assert!(err.to_string().contains("--resume"), "{err}");
    let row = PoseRow::real(1, Pose::default(), Pose::default(), 0.0);
    let mut w = DatasetWriter::resume(&dir, manifest()).expect("resume");
    assert!(matches!(w.append(row, &img(1)), Err(DatasetError::DuplicatePose { pose_id: 1 })));
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    #[test]
    fn parsers_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..400), keep_header in any::<bool>()) {
        let tmp = tempfile::tempdir().expect("tempdir");
        let dir = tmp.path().join("ds");
        dataset(&dir, &[]);
        let mut content = if keep_header { std::fs::read(dir.join("poses.csv")).expect("read") } else { Vec::new() };
        content.extend(&bytes);
        std::fs::write(dir.join("poses.csv"), &content).expect("write");
        let _ = verify(&dir).expect("verify reads any bytes");
        let _ = read_rows(&dir);
        let _ = DatasetWriter::open(&dir);
        let _ = rig::dataset::export::parse_mds(&bytes, Path::new("x.csv"));
    }
}

/// (Issue 44, break 3.) Images of one size that is not the camera's: a dataset of 1 x 1 images
/// whose manifest's capture chain says the camera gives 64 x 64 frames is not clean (the images
/// agree with each other and with `reference.png`, so only the manifest can tell).
#[test]
fn images_of_another_size_than_the_manifests_camera_are_reported() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("ds");
    let mut m = manifest();
    let camera = rig::dataset::CapturePart::new("vitac", "sim", true, None).with_stream(None, None, [64, 64], 30);
    m.capture = Some(rig::dataset::CaptureChain {
        arm: rig::dataset::CapturePart::new("arm", "sim-mg400", true, None),
        sensors: vec![rig::dataset::CapturePart::new("tactip", "sim", true, None).with_stream(None, None, [4, 4], 30), camera],
        modbus: Vec::new(),
    });
    let one_pixel = RgbImage::from_pixel(1, 1, image::Rgb([1, 2, 3]));
    let mut w = DatasetWriter::create(&dir, m).expect("create");
    w.write_reference(&one_pixel).expect("reference");
    for id in [1, 2] {
        w.append(synth_row(id, 0), &one_pixel).expect("append");
    }
    w.finish().expect("finish");
    let r = verify(&dir).expect("verify");
    assert_eq!(r.bad_images, 3, "{r}");
    assert!(r.issues.contains(&VerifyIssue::NotCameraFormat { path: dir.join("images/2.png"), found: (1, 1), camera: (64, 64) }), "{r}");
    let out = Command::new(env!("CARGO_BIN_EXE_rig")).args(["dataset", "verify"]).arg(&dir).output().expect("run rig");
    assert_eq!(out.status.code(), Some(1), "{}", String::from_utf8_lossy(&out.stdout));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("reference.png is 1x1 px, the manifest's camera format is 64x64"), "{stdout}");
}
