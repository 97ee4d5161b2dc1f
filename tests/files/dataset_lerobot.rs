//! The LeRobot v3 export read back with the `parquet` crate's arrow reader: layout, schema,
//! one row per pose, poses and sources as in the datasets, image bytes as on disk, stats; and
//! the refusals (poses or measurements that disagree between sensors, sensor sets that differ
//! between objects, an output folder in use, an unclean dataset). `tests/lerobot/run.sh`
//! checks the same export with pyarrow, Pillow and, opt-in, LeRobot's own loader.

use std::collections::BTreeMap;
use std::fs::File;
use std::path::Path;

use arrow_array::cast::AsArray;
use arrow_array::types::{Float32Type, Int64Type};
use arrow_array::{Array, RecordBatch};
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
use rig::dataset::lerobot::{LerobotError, LerobotOptions, export_lerobot};
use rig::dataset::{DatasetWriter, Manifest, ObjectInfo, PoseRow, Source};
use rig::pose::Pose;
use rig::sensor::SensorKind;

fn read_parquet(path: &Path) -> Vec<RecordBatch> {
    let file = File::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let reader = ParquetRecordBatchReaderBuilder::try_new(file).expect("parquet footer").build().expect("reader");
    reader.map(|b| b.expect("batch")).collect()
}

fn image(seed: u8, w: u32, h: u32) -> image::RgbImage {
    image::RgbImage::from_fn(w, h, |x, y| image::Rgb([seed, (x * 7 + y) as u8, (y * 3) as u8 ^ seed]))
}

/// Measured pose of pose `id`: a little off the commanded one, as an arm's readback is.
fn measured(p: Pose, id: u32) -> Pose {
    Pose::new(p.x_mm + 0.01 * f64::from(id), p.y_mm - 0.003, p.z_mm + 0.02, p.yaw_deg + 0.1)
}

/// A commanded pose of pose `id` (yaw within the ±720° a row may hold).
fn commanded(id: u32) -> Pose {
    Pose::new(f64::from(id) * 0.5 - 2.0, 1.0 - f64::from(id % 3), 0.25 * f64::from(id % 2), f64::from(id % 48) * 15.0 - 45.0)
}

/// A dataset of `sensor` for `object` with poses `captured` (captured rows, measured) and
/// `synthetic` (synthetic rows, no measurement).
fn dataset(root: &Path, object: &str, sensor: SensorKind, captured: &[u32], synthetic: &[u32], simulated: bool) {
    let dir = root.join(object).join(sensor.name());
    let mut w = DatasetWriter::create(&dir, Manifest::new(sensor, ObjectInfo::named(object), None)).expect("create");
    let seed = sensor as u8 * 40;
    for &id in captured {
        let c = commanded(id);
        let row = PoseRow::captured(id, c, measured(c, id), 10.0 + f64::from(id), Source::captured(simulated));
        w.append(row, &image(seed + id as u8, 24, 16)).expect("append");
    }
    for &id in synthetic {
        let row = PoseRow::synthetic(id, commanded(id), "tiny", 7, 20, 1.0);
        w.append(row, &image(seed + id as u8, 24, 16)).expect("append");
    }
    w.finish().expect("finish");
}

fn column_i64(batches: &[RecordBatch], name: &str) -> Vec<i64> {
    batches
        .iter()
        .flat_map(|b| b.column_by_name(name).unwrap_or_else(|| panic!("no column {name}")).as_primitive::<Int64Type>().values().to_vec())
        .collect()
}

fn column_pose(batches: &[RecordBatch], name: &str) -> Vec<[f32; 4]> {
    let mut out = Vec::new();
    for b in batches {
        let list = b.column_by_name(name).unwrap_or_else(|| panic!("no column {name}")).as_fixed_size_list();
        assert_eq!(list.value_length(), 4);
        let values = list.values().as_primitive::<Float32Type>();
        for i in 0..list.len() {
            out.push([0, 1, 2, 3].map(|k| values.value(i * 4 + k)));
        }
    }
    out
}

fn column_strings(batches: &[RecordBatch], name: &str) -> Vec<String> {
    batches
        .iter()
        .flat_map(|b| {
            b.column_by_name(name).expect("column").as_string::<i32>().iter().map(|s| s.expect("not null").to_string()).collect::<Vec<_>>()
        })
        .collect()
}

fn f32s(p: Pose) -> [f32; 4] {
    [p.x_mm as f32, p.y_mm as f32, p.z_mm as f32, p.yaw_deg as f32]
}

#[test]
fn two_objects_three_sensors_export_one_frame_per_pose_with_every_sensor() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let root = tmp.path().join("datasets");
    for s in SensorKind::ALL {
        dataset(&root, "edge", s, &[3, 1, 7], &[2, 5], true);
        dataset(&root, "sphere", s, &[4, 0], &[9], true);
    }
    let out = tmp.path().join("lerobot");
    let summary = export_lerobot(&root, &out, &LerobotOptions { fps: 10, ..LerobotOptions::default() }).expect("export");
    assert_eq!((summary.episodes, summary.frames, summary.reencoded), (2, 8, 0));
    assert_eq!(summary.sensors, SensorKind::ALL.to_vec());

    let info: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(out.join("meta/info.json")).expect("info")).expect("json");
    assert_eq!(info["codebase_version"], "v3.0");
    assert_eq!((info["total_episodes"].as_u64(), info["total_frames"].as_u64(), info["fps"].as_u64()), (Some(2), Some(8), Some(10)));
    assert_eq!(info["features"]["observation.images.vitac"]["shape"], serde_json::json!([16, 24, 3]));
    assert_eq!(info["features"]["observation.state"]["names"], serde_json::json!(["x_mm", "y_mm", "z_mm", "yaw_deg"]));

    let data = read_parquet(&out.join("data/chunk-000/file-000.parquet"));
    let schema = data[0].schema();
    let mut columns: Vec<&str> = schema.fields().iter().map(|f| f.name().as_str()).collect();
    let mut features: Vec<&str> = info["features"].as_object().expect("features").keys().map(String::as_str).collect();
    columns.sort_unstable();
    features.sort_unstable();
    assert_eq!(columns, features, "every column is a feature and every feature a column");

    // Episodes in object order (edge, sphere), frames in pose_id order.
    assert_eq!(column_i64(&data, "pose_id"), vec![1, 2, 3, 5, 7, 0, 4, 9]);
    assert_eq!(column_i64(&data, "episode_index"), vec![0, 0, 0, 0, 0, 1, 1, 1]);
    assert_eq!(column_i64(&data, "frame_index"), vec![0, 1, 2, 3, 4, 0, 1, 2]);
    assert_eq!(column_i64(&data, "index"), (0..8).collect::<Vec<_>>());
    let ids = column_i64(&data, "pose_id");
    let actions = column_pose(&data, "action");
    let states = column_pose(&data, "observation.state");
    let synthetic = [2u32, 5, 9];
    for (k, &id) in ids.iter().enumerate() {
        let id = id as u32;
        assert_eq!(actions[k], f32s(commanded(id)), "action of pose {id} is its commanded pose");
        let want = if synthetic.contains(&id) { commanded(id) } else { measured(commanded(id), id) };
        assert_eq!(states[k], f32s(want), "state of pose {id}: measured where measured, else commanded");
    }
    let measured_flags: Vec<bool> = data
        .iter()
        .flat_map(|b| b.column_by_name("state_measured").expect("column").as_boolean().iter().map(|v| v.expect("set")).collect::<Vec<_>>())
        .collect();
    assert_eq!(measured_flags, ids.iter().map(|&id| !synthetic.contains(&(id as u32))).collect::<Vec<_>>());
    let sources = column_strings(&data, "source.vitactip");
    assert_eq!(sources, ids.iter().map(|&id| if synthetic.contains(&(id as u32)) { "synthetic" } else { "simulated" }).collect::<Vec<_>>());
    let timestamps: Vec<f32> =
        data.iter().flat_map(|b| b.column_by_name("timestamp").expect("ts").as_primitive::<Float32Type>().values().to_vec()).collect();
    assert_eq!(timestamps, vec![0.0, 0.1, 0.2, 0.3, 0.4, 0.0, 0.1, 0.2]);

    // The image struct holds the PNG exactly as the dataset has it.
    for s in SensorKind::ALL {
        let mut k = 0;
        for b in &data {
            let st = b.column_by_name(&format!("observation.images.{}", s.name())).expect("image column").as_struct();
            let bytes = st.column_by_name("bytes").expect("bytes").as_binary::<i32>();
            for i in 0..st.len() {
                let object = if k < 5 { "edge" } else { "sphere" };
                let file = root.join(object).join(s.name()).join(format!("images/{}.png", ids[k]));
                assert_eq!(bytes.value(i), std::fs::read(&file).expect("image").as_slice(), "{}", file.display());
                k += 1;
            }
        }
        assert_eq!(k, 8);
    }

    // Episodes: ranges, tasks and the data file they are in.
    let episodes = read_parquet(&out.join("meta/episodes/chunk-000/file-000.parquet"));
    assert_eq!(column_i64(&episodes, "length"), vec![5, 3]);
    assert_eq!(column_i64(&episodes, "dataset_from_index"), vec![0, 5]);
    assert_eq!(column_i64(&episodes, "dataset_to_index"), vec![5, 8]);
    assert_eq!(column_i64(&episodes, "data/file_index"), vec![0, 0]);
    assert_eq!(column_strings(&episodes, "rig/object"), vec!["edge", "sphere"]);
    let tasks = read_parquet(&out.join("meta/tasks.parquet"));
    assert_eq!(
        column_strings(&tasks, "task"),
        vec!["press the TacTip, ViTac, ViTacTip sensors against the edge", "press the TacTip, ViTac, ViTacTip sensors against the sphere"]
    );
    assert_eq!(column_i64(&data, "task_index"), vec![0, 0, 0, 0, 0, 1, 1, 1]);
    let file = File::open(out.join("meta/tasks.parquet")).expect("tasks");
    let builder = ParquetRecordBatchReaderBuilder::try_new(file).expect("footer");
    let pandas = builder.schema().metadata().get("pandas").cloned().expect("pandas metadata: LeRobot reads the task text from the index");
    assert!(pandas.contains(r#""index_columns": ["task"]"#) || pandas.contains(r#""index_columns":["task"]"#), "{pandas}");

    // Stats: exact over the frames.
    let stats: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("meta/stats.json")).expect("stats")).expect("json");
    let xs: Vec<f64> = actions.iter().map(|a| f64::from(a[0])).collect();
    let want_min = xs.iter().copied().fold(f64::INFINITY, f64::min);
    assert!((stats["action"]["min"][0].as_f64().expect("min") - want_min).abs() < 1e-6);
    assert_eq!(stats["action"]["count"], serde_json::json!([8]));
    assert_eq!(stats["observation.images.tactip"]["count"], serde_json::json!([8]));
    let mean = &stats["observation.images.tactip"]["mean"];
    assert_eq!(mean.as_array().map(Vec::len), Some(3), "image stats are per channel, [3][1][1]");
    assert!(mean[0][0][0].as_f64().is_some_and(|v| (0.0..=1.0).contains(&v)));
}

#[test]
fn the_export_refuses_what_cannot_be_one_lerobot_dataset() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let opts = LerobotOptions::default();
    let layout = |root: &Path, what: &str| match export_lerobot(root, &tmp.path().join(format!("out-{what}")), &opts) {
        Err(LerobotError::Layout { reason }) => reason,
        other => panic!("{what}: expected a layout refusal, got {other:?}"),
    };

    // A sensor lacks a pose the other has.
    let a = tmp.path().join("a");
    dataset(&a, "edge", SensorKind::TacTip, &[1, 2], &[], false);
    dataset(&a, "edge", SensorKind::ViTac, &[1], &[], false);
    let reason = layout(&a, "missing");
    assert!(reason.contains("only in the first: [2]") && reason.contains("--fill-missing"), "{reason}");

    // Sensors of one object measured different poses: not captured at one press.
    let b = tmp.path().join("b");
    dataset(&b, "edge", SensorKind::TacTip, &[1], &[], false);
    let dir = b.join("edge/vitac");
    let mut w = DatasetWriter::create(&dir, Manifest::new(SensorKind::ViTac, ObjectInfo::named("edge"), None)).expect("create");
    let c = commanded(1);
    w.append(PoseRow::captured(1, c, Pose::new(9.0, 9.0, 9.0, 9.0), 1.0, Source::Real), &image(1, 24, 16)).expect("append");
    w.finish().expect("finish");
    let reason = layout(&b, "measured");
    assert!(reason.contains("measured different poses"), "{reason}");

    // Objects with different sensor sets.
    let c = tmp.path().join("c");
    dataset(&c, "edge", SensorKind::TacTip, &[1], &[], false);
    dataset(&c, "sphere", SensorKind::ViTac, &[1], &[], false);
    let reason = layout(&c, "sensors");
    assert!(reason.contains("same image keys"), "{reason}");

    // One sensor's frames in two sizes (each dataset clean, but an image feature has one shape).
    let d = tmp.path().join("d");
    for (object, w) in [("edge", 24), ("sphere", 16)] {
        let dir = d.join(object).join("tactip");
        let mut wr = DatasetWriter::create(&dir, Manifest::new(SensorKind::TacTip, ObjectInfo::named(object), None)).expect("create");
        wr.append(PoseRow::captured(1, commanded(1), commanded(1), 1.0, Source::Real), &image(1, w, 16)).expect("append");
        wr.finish().expect("finish");
    }
    let reason = layout(&d, "sizes");
    assert!(reason.contains("16x16 px but the sensor's other frames are 24x16"), "{reason}");

    // An output folder in use is never touched; an empty one is filled.
    let e = tmp.path().join("e");
    dataset(&e, "edge", SensorKind::TacTip, &[1, 2], &[], false);
    let used = tmp.path().join("used");
    std::fs::create_dir(&used).expect("mkdir");
    std::fs::write(used.join("sentinel"), b"keep").expect("sentinel");
    assert!(matches!(export_lerobot(&e, &used, &opts), Err(LerobotError::OutNotEmpty { .. })));
    assert_eq!(std::fs::read(used.join("sentinel")).expect("sentinel"), b"keep");
    assert_eq!(std::fs::read_dir(&used).expect("ls").count(), 1);
    let empty = tmp.path().join("empty");
    std::fs::create_dir(&empty).expect("mkdir");
    export_lerobot(&e, &empty, &opts).expect("an empty folder is fine");
    assert!(empty.join("meta/info.json").is_file());

    // An unclean dataset (an image missing for a row) is refused, naming verify.
    std::fs::remove_file(e.join("edge/tactip/images/2.png")).expect("rm");
    let err = export_lerobot(&e, &tmp.path().join("out-unclean"), &opts).expect_err("unclean");
    assert!(err.to_string().contains("rig dataset verify"), "{err}");
    assert!(!tmp.path().join("out-unclean").exists(), "a refused export leaves nothing behind");

    // fps 0 and a multi-line task are bad options.
    let bad = LerobotOptions { fps: 0, ..LerobotOptions::default() };
    assert!(matches!(export_lerobot(&e, &tmp.path().join("out-fps"), &bad), Err(LerobotError::BadOption(_))));
    let bad = LerobotOptions { task: Some("a\nb".into()), ..LerobotOptions::default() };
    assert!(matches!(export_lerobot(&e, &tmp.path().join("out-task"), &bad), Err(LerobotError::BadOption(_))));
    let leftovers: BTreeMap<String, ()> = std::fs::read_dir(tmp.path())
        .expect("ls")
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains("partial"))
        .map(|n| (n, ()))
        .collect();
    assert!(leftovers.is_empty(), "temporary folders left: {leftovers:?}");
}

/// An image of noise (PNG cannot shrink it): `w` x `h` x 3 bytes and a little more on disk.
fn noise(seed: u32, w: u32, h: u32) -> image::RgbImage {
    let mut state = seed.wrapping_mul(2_654_435_761).wrapping_add(1);
    image::RgbImage::from_fn(w, h, |_, _| {
        let mut px = [0u8; 3];
        for c in &mut px {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            *c = (state >> 24) as u8;
        }
        image::Rgb(px)
    })
}

/// A dataset of captured rows `ids` with noise images of `w` x `h`.
fn noisy_dataset(root: &Path, object: &str, sensor: SensorKind, ids: &[u32], w: u32, h: u32) {
    let dir = root.join(object).join(sensor.name());
    let mut wr = DatasetWriter::create(&dir, Manifest::new(sensor, ObjectInfo::named(object), None)).expect("create");
    for &id in ids {
        let c = commanded(id);
        let row = PoseRow::captured(id, c, measured(c, id), f64::from(id), Source::Simulated);
        wr.append(row, &noise(id * 7 + sensor as u32, w, h)).expect("append");
    }
    wr.finish().expect("finish");
}

/// The rows of every data file, in file order, each file read whole.
fn read_data_files(out: &Path, files: &[rig::dataset::lerobot::DataFile]) -> Vec<(String, Vec<RecordBatch>)> {
    files.iter().map(|f| (f.path.clone(), read_parquet(&out.join(&f.path)))).collect()
}

#[test]
fn an_export_rolled_over_several_files_reads_back_frame_for_frame() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let root = tmp.path().join("datasets");
    // About 49 kB per image, 98 kB per frame: some nine frames fit a file of 1 MB.
    let edge: Vec<u32> = (0..30).collect();
    let sphere: Vec<u32> = (100..112).collect();
    for s in [SensorKind::TacTip, SensorKind::ViTac] {
        noisy_dataset(&root, "edge", s, &edge, 128, 128);
        noisy_dataset(&root, "sphere", s, &sphere, 128, 128);
    }
    let whole = tmp.path().join("whole");
    let one = export_lerobot(&root, &whole, &LerobotOptions { fps: 4, ..LerobotOptions::default() }).expect("export");
    assert_eq!((one.episodes, one.frames, one.data_files.len()), (2, 42, 1), "100 MB holds everything: {one:?}");

    let rolled = tmp.path().join("rolled");
    let opts = LerobotOptions { fps: 4, max_file_mb: 1, ..LerobotOptions::default() };
    let summary = export_lerobot(&root, &rolled, &opts).expect("export");
    assert_eq!(summary.frames, 42);
    assert!(summary.data_files.len() >= 4, "4 MB of frames in files of 1 MB: {:?}", summary.data_files);
    for (i, f) in summary.data_files.iter().enumerate() {
        assert_eq!(f.path, format!("data/chunk-000/file-{i:03}.parquet"));
        let on_disk = std::fs::metadata(rolled.join(&f.path)).expect("data file").len();
        assert_eq!(on_disk, f.bytes);
        assert!(on_disk <= 1_000_000, "{}: {on_disk} bytes, over --max-file-mb 1", f.path);
    }
    let mut names: Vec<String> = std::fs::read_dir(rolled.join("data/chunk-000"))
        .expect("ls")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(names.len(), summary.data_files.len(), "no other file in data/: {names:?}");
    let info: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(rolled.join("meta/info.json")).expect("info")).expect("json");
    assert_eq!(info["data_files_size_in_mb"], 1);
    assert_eq!(info["total_frames"], 42);
    assert_eq!(info["total_episodes"].as_u64(), Some(summary.episodes as u64));

    // Frame for frame, the rolled export holds what the one-file export holds.
    let per_file = read_data_files(&rolled, &summary.data_files);
    let rolled_batches: Vec<RecordBatch> = per_file.iter().flat_map(|(_, b)| b.clone()).collect();
    let whole_batches = read_parquet(&whole.join("data/chunk-000/file-000.parquet"));
    for column in ["pose_id", "index"] {
        assert_eq!(column_i64(&rolled_batches, column), column_i64(&whole_batches, column), "{column}");
    }
    assert_eq!(column_i64(&rolled_batches, "index"), (0..42).collect::<Vec<_>>());
    assert_eq!(column_pose(&rolled_batches, "action"), column_pose(&whole_batches, "action"));
    assert_eq!(column_pose(&rolled_batches, "observation.state"), column_pose(&whole_batches, "observation.state"));
    assert_eq!(column_strings(&rolled_batches, "source.vitac"), column_strings(&whole_batches, "source.vitac"));
    let ids = column_i64(&rolled_batches, "pose_id");
    for s in [SensorKind::TacTip, SensorKind::ViTac] {
        let mut k = 0;
        for b in &rolled_batches {
            let st = b.column_by_name(&format!("observation.images.{}", s.name())).expect("image column").as_struct();
            let bytes = st.column_by_name("bytes").expect("bytes").as_binary::<i32>();
            for i in 0..st.len() {
                let object = if ids[k] < 100 { "edge" } else { "sphere" };
                let file = root.join(object).join(s.name()).join(format!("images/{}.png", ids[k]));
                assert_eq!(bytes.value(i), std::fs::read(&file).expect("image").as_slice(), "{}", file.display());
                k += 1;
            }
        }
        assert_eq!(k, 42);
    }

    // Episodes: each lies whole in the data file it names, starts at frame 0, and holds one
    // object's poses; an object's poses run on across its episodes.
    let mut episode_files: Vec<String> = std::fs::read_dir(rolled.join("meta/episodes/chunk-000"))
        .expect("ls")
        .map(|e| e.expect("entry").path().to_string_lossy().into_owned())
        .collect();
    episode_files.sort();
    let episodes: Vec<RecordBatch> = episode_files.iter().flat_map(|f| read_parquet(Path::new(f))).collect();
    let lengths = column_i64(&episodes, "length");
    let from = column_i64(&episodes, "dataset_from_index");
    let to = column_i64(&episodes, "dataset_to_index");
    let file_index = column_i64(&episodes, "data/file_index");
    let objects = column_strings(&episodes, "rig/object");
    assert_eq!(lengths.len(), summary.episodes);
    assert!(summary.episodes > 2, "the objects' episodes end with the files: {lengths:?}");
    assert_eq!(column_i64(&episodes, "episode_index"), (0..summary.episodes as i64).collect::<Vec<_>>());
    assert_eq!(lengths.iter().sum::<i64>(), 42);
    let mut next = 0;
    for e in 0..lengths.len() {
        assert_eq!((from[e], to[e] - from[e]), (next, lengths[e]), "episode {e}");
        next = to[e];
        let (_, batches) = &per_file[file_index[e] as usize];
        let index = column_i64(batches, "index");
        assert!(index.contains(&from[e]) && index.contains(&(to[e] - 1)), "episode {e} is not whole in its file");
        let in_file: Vec<i64> = column_i64(batches, "episode_index").into_iter().filter(|&x| x == e as i64).collect();
        assert_eq!(in_file.len() as i64, lengths[e], "episode {e}: rows in its file");
        let frame_index: Vec<i64> = (from[e]..to[e]).map(|i| column_i64(&rolled_batches, "frame_index")[i as usize]).collect();
        assert_eq!(frame_index, (0..lengths[e]).collect::<Vec<_>>());
        let poses: Vec<i64> = (from[e]..to[e]).map(|i| ids[i as usize]).collect();
        assert!(poses.iter().all(|&p| (p < 100) == (objects[e] == "edge")), "episode {e} ({}) holds {poses:?}", objects[e]);
    }
    let timestamps: Vec<f32> = rolled_batches
        .iter()
        .flat_map(|b| b.column_by_name("timestamp").expect("ts").as_primitive::<Float32Type>().values().to_vec())
        .collect();
    let frame_index = column_i64(&rolled_batches, "frame_index");
    assert!(timestamps.iter().zip(&frame_index).all(|(&t, &f)| t == f as f32 / 4.0));

    // The dataset's stats are the same whichever way the frames are cut (the episode-wise ones
    // differ: frame_index and episode_index do), and count every frame.
    let stats = |dir: &Path| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(dir.join("meta/stats.json")).expect("stats")).expect("json")
    };
    let (a, b) = (stats(&whole), stats(&rolled));
    for key in ["action", "observation.state", "pose_id", "index", "observation.images.tactip", "observation.images.vitac"] {
        assert_eq!(a[key], b[key], "{key}");
    }
    assert_eq!(b["observation.images.vitac"]["count"], serde_json::json!([42]));
    // `stats/<key>/count` is a one-element list per episode.
    let counts: Vec<i64> = episodes
        .iter()
        .flat_map(|b| {
            let list = b.column_by_name("stats/observation.images.tactip/count").expect("count").as_list::<i32>();
            (0..list.len()).map(|i| list.value(i).as_primitive::<Int64Type>().values().to_vec()).collect::<Vec<_>>()
        })
        .map(|v| if let [n] = v[..] { n } else { panic!("count {v:?}") })
        .collect();
    assert_eq!(counts, lengths);
}

#[test]
fn a_frame_larger_than_a_file_is_refused() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let root = tmp.path().join("datasets");
    // Two images of about 0.6 MB: a frame of 1.2 MB, more than a file of 1 MB.
    for s in [SensorKind::TacTip, SensorKind::ViTac] {
        noisy_dataset(&root, "edge", s, &[1, 2], 460, 440);
    }
    let out = tmp.path().join("out");
    let opts = LerobotOptions { max_file_mb: 1, ..LerobotOptions::default() };
    let err = export_lerobot(&root, &out, &opts).expect_err("too large");
    assert!(matches!(err, LerobotError::RowTooLarge { bound_bytes: 1_000_000, .. }), "{err}");
    assert!(err.to_string().contains("--max-file-mb"), "{err}");
    assert!(!out.exists(), "a refused export leaves nothing behind");
    for bad in [0, 2001] {
        let opts = LerobotOptions { max_file_mb: bad, ..LerobotOptions::default() };
        assert!(matches!(export_lerobot(&root, &out, &opts), Err(LerobotError::BadOption(_))), "--max-file-mb {bad}");
    }
    export_lerobot(&root, &out, &LerobotOptions { max_file_mb: 2, ..LerobotOptions::default() }).expect("2 MB holds a frame");
}
