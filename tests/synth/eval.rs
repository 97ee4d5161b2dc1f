//! `rig eval` on small simulated datasets written with the library: an identical twin scores
//! perfectly, the nearest-neighbour baseline beats the pose-blind one when a close pose was
//! collected, unpaired and seen poses are counted, and bad input exits 2. Also `rig synth
//! --poses-of` with the tiny model package.

use std::path::{Path, PathBuf};
use std::process::Command;

use image::RgbImage;
use rig::calibration::Calibration;
use rig::dataset::{DatasetWriter, Manifest, ObjectInfo, PoseRow, Source};
use rig::eval::{EvalOptions, EvalReport, Figure, Method, MethodRow, PairRecord, Verdict, evaluate};
use rig::geometry::objects::load_object;
use rig::geometry::raster::render_depth;
use rig::pose::Pose;
use rig::sensor::SensorKind;
use rig::sim::sensor::{MotionState, Scene, SensorSim};

/// Image size of the simulated datasets, px (rendered larger than they are measured, as the
/// rig's 512 px frames are, so the resize averages the sensor noise down a little).
const SIZE: u32 = 256;
/// Size the evaluation measures at, px.
const EVAL: u32 = 128;

/// A simulated sensor at [`SIZE`] with the default calibration.
fn sensor(kind: SensorKind, seed: u64) -> SensorSim {
    let calib = Calibration::default_for(SIZE, SIZE);
    SensorSim::new(kind, Scene::preset("full").expect("scene"), SIZE, SIZE, calib.scale_px_per_mm[0] as f32, seed)
}

/// What `sim` shows with `object` at `pose` (contact depth 1.5 mm, as an uncalibrated collection).
fn render(sim: &SensorSim, object: &str, pose: Pose, key: u64) -> RgbImage {
    let mesh = load_object(object).expect("object");
    let calib = Calibration::default_for(SIZE, SIZE);
    let object_pose = Pose { z_mm: pose.z_mm + 1.5, ..pose };
    sim.render(&render_depth(&mesh, &object_pose, &calib, SIZE, SIZE, 1), &MotionState::STILL, key)
}

/// Writes a dataset of `images` (pose id, pose, image) with rows of `source`.
fn write(dir: &Path, object: &str, kind: SensorKind, reference: &RgbImage, images: &[(u32, Pose, RgbImage)], source: Source) {
    let mut manifest = Manifest::new(kind, ObjectInfo::named(object), None);
    manifest.calibration = Some("default".into());
    let mut w = DatasetWriter::create(dir, manifest).expect("create dataset");
    w.write_reference(reference).expect("reference");
    for (id, pose, img) in images {
        let row = match source {
            Source::Real | Source::Simulated => PoseRow::commanded_only(*id, *pose, source),
            Source::Synthetic => PoseRow::synthetic(*id, *pose, "test", 0, 1, 1.0),
        };
        w.append(row, img).expect("append");
    }
    w.finish().expect("finish");
}

/// Test poses: in contact, spread over x, y and yaw.
fn test_poses() -> Vec<(u32, Pose)> {
    vec![
        (1, Pose::new(0.0, 0.0, 0.0, 0.0)),
        (2, Pose::new(2.0, -1.0, 0.5, 30.0)),
        (3, Pose::new(-2.0, 1.5, -0.5, -45.0)),
        (4, Pose::new(1.0, 2.0, 0.0, 60.0)),
    ]
}

/// Training poses well away from the test poses.
fn train_poses() -> Vec<(u32, Pose)> {
    vec![(10, Pose::new(4.0, 4.0, 0.0, 90.0)), (11, Pose::new(-4.0, -4.0, 1.0, -90.0)), (12, Pose::new(4.0, -4.0, -1.0, 75.0))]
}

/// Picks the synthetic side's poses from the test poses.
type PoseSelection = dyn Fn(&[(u32, Pose)]) -> Vec<(u32, Pose)>;

struct Sets {
    _tmp: tempfile::TempDir,
    real: PathBuf,
    synthetic: PathBuf,
    collected: PathBuf,
}

/// Real test sets for `objects` on ViTac, synthetic twins made by `twin` from the real image,
/// and a collected set at `train` poses (plus `extra` poses per object).
fn make_sets(
    objects: &[&str],
    twin: &dyn Fn(u32, &RgbImage) -> RgbImage,
    synthetic_poses: &PoseSelection,
    extra_train: &[(u32, Pose)],
) -> Sets {
    let tmp = tempfile::tempdir().expect("tempdir");
    let (real, synthetic, collected) = (tmp.path().join("real"), tmp.path().join("synth"), tmp.path().join("train"));
    let kind = SensorKind::ViTac;
    for object in objects {
        let test_sim = sensor(kind, 22);
        // The same sensor unit (same static look) as the test set; its own noise.
        let train_sim = sensor(kind, 22);
        let reference = test_sim.reference();
        let real_images: Vec<(u32, Pose, RgbImage)> =
            test_poses().into_iter().map(|(id, p)| (id, p, render(&test_sim, object, p, id as u64))).collect();
        write(&real.join(object).join("vitac"), object, kind, &reference, &real_images, Source::Real);
        let synth_images: Vec<(u32, Pose, RgbImage)> = synthetic_poses(&test_poses())
            .into_iter()
            .map(|(id, p)| {
                let truth = real_images.iter().find(|(i, _, _)| *i == id).map(|(_, _, img)| img.clone());
                let img = match truth {
                    Some(t) => twin(id, &t),
                    None => render(&test_sim, object, p, 1000 + id as u64),
                };
                (id, p, img)
            })
            .collect();
        write(&synthetic.join(object).join("vitac"), object, kind, &reference, &synth_images, Source::Synthetic);
        let mut train: Vec<(u32, Pose)> = train_poses();
        train.extend_from_slice(extra_train);
        let train_images: Vec<(u32, Pose, RgbImage)> =
            train.into_iter().map(|(id, p)| (id, p, render(&train_sim, object, p, 5000 + id as u64))).collect();
        write(&collected.join(object).join("vitac"), object, kind, &train_sim.reference(), &train_images, Source::Real);
    }
    Sets { _tmp: tmp, real, synthetic, collected }
}

fn row(report: &EvalReport, method: Method) -> &MethodRow {
    report.rows.iter().find(|r| r.sensor == "vitac" && r.method == method).expect("row")
}

fn same(_: u32, img: &RgbImage) -> RgbImage {
    img.clone()
}

fn all(p: &[(u32, Pose)]) -> Vec<(u32, Pose)> {
    p.to_vec()
}

#[test]
fn an_identical_twin_scores_ssim_one_mse_zero_and_the_true_image_pose_errors() {
    let sets = make_sets(&["edge", "sphere"], &same, &all, &[]);
    let options = EvalOptions::at_size(EVAL, "identical");
    let report = evaluate(&sets.real, &sets.synthetic, std::slice::from_ref(&sets.collected), &options).expect("evaluate");
    assert_eq!(report.counts.pairs, 8);
    assert_eq!(report.counts.dropped_seen, 0);
    let model = row(&report, Method::Model);
    let truth = row(&report, Method::TrueImage);
    assert_eq!(model.n, 8);
    assert!((model.ssim.expect("ssim") - 1.0).abs() < 1e-12, "{model:?}");
    assert_eq!(model.mse, Some(0.0));
    assert_eq!(model.psnr_db, Some(f64::INFINITY));
    assert!(model.n_contact > 0 && (model.contact_ssim.expect("contact ssim") - 1.0).abs() < 1e-12);
    assert_eq!(model.position_vs_true_mm, Some(0.0), "{model:?}");
    assert_eq!(model.yaw_vs_true_deg, Some(0.0), "edge poses have an observable yaw: {model:?}");
    assert_eq!(model.position_err_mm, truth.position_err_mm);
    assert_eq!(model.yaw_err_deg, truth.yaw_err_deg);
    // The estimator finds the contact on the true images, and close to where the mesh says.
    assert_eq!(truth.position_found, truth.position_attempts);
    assert!(truth.position_err_mm.expect("pos err") < 1.5, "{truth:?}");
    // Sphere poses have a disc contact: yaw is not observable there.
    assert!(report.counts.yaw_unobservable >= 4, "{:?}", report.counts);
    // Baselines are worse than a perfect twin.
    for m in [Method::PoseBlind, Method::NearestNeighbour] {
        let b = row(&report, m);
        assert_eq!(b.n, 8, "{m:?}");
        assert!(b.ssim.expect("ssim") < 1.0 && b.mse.expect("mse") > 0.0, "{b:?}");
    }
    // The per-pair records: every method on every pair, and the table's means are theirs.
    assert_eq!(report.pairs.len(), 8 * Method::ALL.len());
    for method in Method::ALL {
        for sensor in ["tactip", "vitac", "vitactip"] {
            let mine: Vec<_> = report.pairs.iter().filter(|p| p.method == method.label() && p.sensor == sensor).collect();
            let Some(r) = report.rows.iter().find(|r| r.method == method && r.sensor == sensor) else { continue };
            let mean = |f: fn(&PairRecord) -> Option<f64>| {
                let v: Vec<f64> = mine.iter().filter_map(|p| f(p)).collect();
                (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
            };
            let close = |a: Option<f64>, b: Option<f64>| match (a, b) {
                (Some(a), Some(b)) => (a - b).abs() < 1e-9,
                (a, b) => a == b,
            };
            assert!(close(mean(|p| p.position_err_mm), r.position_err_mm), "{method:?} {sensor}: {r:?}");
            assert!(close(mean(|p| p.yaw_err_deg), r.yaw_err_deg), "{method:?} {sensor}: {r:?}");
            assert!(close(mean(|p| p.contact_ssim), r.contact_ssim), "{method:?} {sensor}: {r:?}");
            assert_eq!(mine.iter().filter(|p| p.yaw_err_deg.is_some()).count(), r.yaw_found, "{method:?} {sensor}");
        }
    }
    let mut csv = Vec::new();
    report.write_pairs_csv(&mut csv).expect("csv");
    let csv = String::from_utf8(csv).expect("utf-8");
    assert_eq!(csv.lines().count(), 1 + report.pairs.len());
    assert!(csv.starts_with("pair,object,sensor,pose_id,x_mm,y_mm,z_mm,yaw_deg,method,ssim,contact_ssim,"), "{csv}");
    // Paired comparisons: 8 pairs per sensor is too few for a verdict, but the means are there.
    let nn_ssim = report
        .comparisons
        .iter()
        .find(|c| c.sensor == "vitac" && c.baseline == Method::NearestNeighbour && c.figure == Figure::ContactSsim)
        .expect("vitac comparison");
    assert_eq!(nn_ssim.verdict, Verdict::TooFewPairs);
    assert!((nn_ssim.model_mean - 1.0).abs() < 1e-12 && nn_ssim.difference > 0.0, "{nn_ssim:?}");
    // The twin is the true image, so every comparison equals its ceiling (the true image in
    // the model's place), the contact SSIM one included (the true image scores 1 there).
    assert!(!report.comparisons.is_empty());
    for c in &report.comparisons {
        let t = c.true_image.as_ref().unwrap_or_else(|| panic!("no ceiling: {c:?}"));
        assert_eq!((t.n, t.verdict), (c.n, c.verdict), "{c:?}");
        assert!((t.difference - c.difference).abs() < 1e-12 && (t.true_mean - c.model_mean).abs() < 1e-12, "{c:?}");
    }
    let md = report.to_markdown();
    assert!(md.contains("| vitac | model | 8 | 1.000 | inf | 0.0 |"), "{md}");
    assert!(md.contains("| true image - baseline | can a model win |") && md.contains("| too few pairs |"), "{md}");
    assert!(md.contains("| vitac | nearest-neighbour | contact SSIM | "), "{md}");
    // Only the edge.
    let edge_only = EvalOptions { objects: vec!["edge".into()], ..options.clone() };
    let report = evaluate(&sets.real, &sets.synthetic, std::slice::from_ref(&sets.collected), &edge_only).expect("evaluate");
    assert_eq!((report.counts.pairs, report.counts.real_datasets, report.counts.yaw_unobservable), (4, 1, 0));
    assert!(!md.contains("NaN"), "{md}");
}

#[test]
fn nearest_neighbour_at_a_close_pose_beats_pose_blind_in_the_contact_region() {
    // The collected set has every test pose moved by 0.5 mm (and 15 degrees for one).
    let close: Vec<(u32, Pose)> = test_poses()
        .into_iter()
        .map(|(id, p)| (100 + id, Pose::new(p.x_mm + 0.5, p.y_mm - 0.5, p.z_mm, p.yaw_deg + if id == 2 { 15.0 } else { 0.0 })))
        .collect();
    // The model's images are blank (the reference): it knows nothing.
    let reference = sensor(SensorKind::ViTac, 22).reference();
    let blank = move |_: u32, _: &RgbImage| reference.clone();
    let sets = make_sets(&["sphere", "edge"], &blank, &all, &close);
    let report =
        evaluate(&sets.real, &sets.synthetic, std::slice::from_ref(&sets.collected), &EvalOptions::at_size(EVAL, "nn")).expect("evaluate");
    let nn = row(&report, Method::NearestNeighbour);
    let blind = row(&report, Method::PoseBlind);
    let model = row(&report, Method::Model);
    assert!(nn.contact_ssim > blind.contact_ssim, "nn {nn:?}\nblind {blind:?}");
    assert!(nn.contact_mse < blind.contact_mse, "nn {nn:?}\nblind {blind:?}");
    assert!(nn.position_err_mm < blind.position_err_mm.or(Some(f64::INFINITY)), "nn {nn:?}\nblind {blind:?}");
    // A blank image has no contact: its pose errors are counted as not found, never NaN.
    assert_eq!(model.position_found, 0, "{model:?}");
    assert_eq!(model.position_err_mm, None);
    assert!(report.to_markdown().contains(&format!("n/a (0/{})", model.position_attempts)));
}

#[test]
fn unpaired_poses_are_reported_not_paired() {
    // The synthetic side lacks pose 4 and has a pose 9 the real side lacks.
    let shifted = |p: &[(u32, Pose)]| {
        let mut v: Vec<(u32, Pose)> = p.iter().filter(|(id, _)| *id != 4).copied().collect();
        v.push((9, Pose::new(3.0, 3.0, 0.0, 15.0)));
        v
    };
    let sets = make_sets(&["sphere"], &same, &shifted, &[]);
    let report =
        evaluate(&sets.real, &sets.synthetic, std::slice::from_ref(&sets.collected), &EvalOptions::at_size(EVAL, "u")).expect("evaluate");
    assert_eq!(report.counts.pairs, 3);
    assert_eq!((report.counts.unpaired_real, report.counts.unpaired_synthetic), (1, 1));
    let examples = report.counts.unpaired_examples.join("; ");
    assert!(examples.contains("real sphere/vitac pose_id 4") && examples.contains("synthetic sphere/vitac pose_id 9"), "{examples}");
    assert!(report.to_markdown().contains("Without a twin: 1 real, 1 synthetic poses"));
}

#[test]
fn a_pose_in_the_collected_set_is_dropped_as_seen() {
    let seen = vec![(50, Pose::new(2.0, -1.0, 0.5, 30.0))]; // test pose 2
    let sets = make_sets(&["sphere"], &same, &all, &seen);
    let report =
        evaluate(&sets.real, &sets.synthetic, std::slice::from_ref(&sets.collected), &EvalOptions::at_size(EVAL, "s")).expect("evaluate");
    assert_eq!(report.counts.dropped_seen, 1);
    assert_eq!(report.counts.pairs, 3);
    assert_eq!(row(&report, Method::Model).n, 3);
    // Without --collected the synthetic datasets' real rows are the collected set: none here,
    // so nothing is dropped and the baselines are n/a.
    let report = evaluate(&sets.real, &sets.synthetic, &[], &EvalOptions::at_size(EVAL, "s")).expect("evaluate");
    assert_eq!((report.counts.dropped_seen, report.counts.pairs), (0, 4));
    assert_eq!(report.counts.sensors_without_baseline, vec!["vitac".to_string()]);
    assert_eq!(row(&report, Method::PoseBlind).ssim, None);
}

fn rig() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_rig"));
    c.current_dir(env!("CARGO_MANIFEST_DIR"));
    c.env_remove("RIG_CONFIG");
    c
}

fn run(mut c: Command) -> (i32, String) {
    let o = c.output().expect("running rig");
    let text = String::from_utf8_lossy(&o.stdout).into_owned() + &String::from_utf8_lossy(&o.stderr);
    (o.status.code().unwrap_or(-1), text)
}

fn eval_cmd(real: &Path, synthetic: &Path, extra: &[&str]) -> Command {
    let mut c = rig();
    c.arg("eval").arg("--real").arg(real).arg("--synthetic").arg(synthetic).args(extra);
    c
}

#[test]
fn cli_writes_the_table_and_json_and_bad_input_exits_2() {
    let sets = make_sets(&["sphere"], &same, &all, &[]);
    let md = sets._tmp.path().join("eval.md");
    let json = sets._tmp.path().join("eval.json");
    let mut c = eval_cmd(&sets.real, &sets.synthetic, &["--label", "unseen poses"]);
    c.arg("--collected").arg(&sets.collected).arg("--markdown").arg(&md).arg("--json").arg(&json);
    let (code, out) = run(c);
    assert_eq!(code, 0, "{out}");
    assert!(out.contains("### rig eval: unseen poses (128 px)") && out.contains("| vitac | nearest-neighbour | 4 |"), "{out}");
    let written = std::fs::read_to_string(&md).expect("markdown");
    assert!(written.contains("| vitac | pose-blind | 4 |"), "{written}");
    let parsed: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).expect("json")).expect("valid json");
    assert_eq!(parsed["counts"]["pairs"], 4);
    // Each sensor's own contact estimator, said in the table and the JSON...
    assert!(out.contains("Contact estimator: vitac blur size/128, region 0.4."), "{out}");
    assert_eq!(parsed["estimators"]["vitac"]["region_fraction"], 0.4);
    // ...or the one asked for, for every sensor.
    let (code, out) = run(eval_cmd(&sets.real, &sets.synthetic, &["--estimator", "64,0.3"]));
    assert_eq!(code, 0, "{out}");
    assert!(out.contains("Contact estimator: vitac blur size/64, region 0.3."), "{out}");
    let (code, out) = run(eval_cmd(&sets.real, &sets.synthetic, &["--estimator", "64,1.5"]));
    assert_eq!(code, 2, "{out}");
    assert!(out.contains("--estimator") && out.contains("BLUR_DIVISOR,REGION_FRACTION"), "{out}");
    let pairs_csv = sets._tmp.path().join("pairs.csv");
    let mut c = eval_cmd(&sets.real, &sets.synthetic, &[]);
    c.arg("--collected").arg(&sets.collected).arg("--pairs").arg(&pairs_csv);
    let (code, out) = run(c);
    assert_eq!(code, 0, "{out}");
    let mut reader = csv::Reader::from_path(&pairs_csv).expect("pairs csv");
    let header = reader.headers().expect("header").clone();
    let column = |name: &str| header.iter().position(|h| h == name).unwrap_or_else(|| panic!("no {name} column: {header:?}"));
    let (method, ssim) = (column("method"), column("ssim"));
    let records: Vec<csv::StringRecord> = reader.records().collect::<Result<_, _>>().expect("records");
    assert_eq!(records.len(), 4 * 4, "4 pairs, 4 methods");
    let model: Vec<_> = records.iter().filter(|r| &r[method] == "model").collect();
    assert_eq!(model.len(), 4);
    // An identical twin: SSIM 1 on every pair.
    assert!(model.iter().all(|r| r[ssim].parse::<f64>().is_ok_and(|s| (s - 1.0).abs() < 1e-12)), "{model:?}");

    // A missing directory.
    let (code, out) = run(eval_cmd(&sets.real, &sets._tmp.path().join("nope"), &[]));
    assert_eq!(code, 2, "{out}");
    assert!(out.contains("--synthetic") && out.contains("no such directory"), "{out}");
    // A directory without datasets.
    let empty = sets._tmp.path().join("empty");
    std::fs::create_dir_all(&empty).expect("mkdir");
    let (code, out) = run(eval_cmd(&empty, &sets.synthetic, &[]));
    assert_eq!(code, 2, "{out}");
    assert!(out.contains("no dataset under"), "{out}");
    // No pairs: the synthetic side is another object.
    let other = sets._tmp.path().join("other");
    let sim = sensor(SensorKind::ViTac, 22);
    let origin = Pose::new(0.0, 0.0, 0.0, 0.0);
    // One synthetic ViTac image of `object` at the origin pose, as pose 1 of `dir/object/vitac`.
    let write_one = |dir: &Path, object: &str, img: RgbImage| {
        write(&dir.join(object).join("vitac"), object, SensorKind::ViTac, &sim.reference(), &[(1, origin, img)], Source::Synthetic);
    };
    write_one(&other, "edge", render(&sim, "edge", origin, 1));
    let (code, out) = run(eval_cmd(&sets.real, &other, &[]));
    assert_eq!(code, 2, "{out}");
    assert!(out.contains("no pose pairs"), "{out}");
    // A synthetic twin of another size but the same shape is judged (both sides go to --size)...
    let twin_at = |name: &str, w: u32, h: u32| {
        let dir = sets._tmp.path().join(name);
        write_one(&dir, "sphere", image::imageops::resize(&render(&sim, "sphere", origin, 1), w, h, image::imageops::FilterType::Triangle));
        dir
    };
    let (code, out) = run(eval_cmd(&sets.real, &twin_at("small", 64, 64), &[]));
    assert_eq!(code, 0, "{out}");
    assert!(out.contains("1 pairs"), "{out}");
    // ...one of another shape is not a twin.
    let (code, out) = run(eval_cmd(&sets.real, &twin_at("wide", 64, 48), &[]));
    assert_eq!(code, 2, "{out}");
    assert!(out.contains("the real image is 256x256 px, the synthetic one 64x48 px: not the same shape"), "{out}");
    // A size below the SSIM window.
    let (code, out) = run(eval_cmd(&sets.real, &sets.synthetic, &["--size", "8"]));
    assert_eq!(code, 2, "{out}");
    // An object filter naming an object the real side lacks.
    let (code, out) = run(eval_cmd(&sets.real, &sets.synthetic, &["--object", "wedge"]));
    assert_eq!(code, 2, "{out}");
    assert!(out.contains("--object wedge"), "{out}");
}

#[test]
fn synth_poses_of_twins_exactly_the_real_poses_and_resumes() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let sim = sensor(SensorKind::ViTac, 22);
    let images: Vec<(u32, Pose, RgbImage)> =
        test_poses().into_iter().take(3).map(|(id, p)| (id, p, render(&sim, "sphere", p, id as u64))).collect();
    let real = tmp.path().join("real");
    write(&real.join("sphere").join("vitac"), "sphere", SensorKind::ViTac, &sim.reference(), &images, Source::Real);
    let out = tmp.path().join("synth");
    let synth_into = |out: &Path, extra: &[&str]| {
        let mut c = rig();
        c.args(["synth", "--steps", "2", "--batch", "2", "--poses-of"]).arg(&real).arg("--out").arg(out).args(extra);
        run(c)
    };
    let synth = |extra: &[&str]| synth_into(&out, extra);
    let (code, text) = synth(&[]);
    assert_eq!(code, 0, "{text}");
    assert!(text.contains("synthesised 3 poses"), "{text}");
    let twin = out.join("sphere").join("vitac");
    let rows = rig::dataset::read_rows(&twin).expect("rows");
    assert_eq!(rows.len(), 3);
    // The default model (models/default from this cwd) at its own resolution, not resampled.
    let model = rig::synth::package::ModelConfig::read(&Path::new(env!("CARGO_MANIFEST_DIR")).join("models/default/model.toml"))
        .expect("models/default");
    assert_ne!((model.width_px, model.height_px), (SIZE, SIZE), "the test needs a model whose size differs from the frames'");
    for (r, (id, p, _)) in rows.iter().zip(&images) {
        assert_eq!((r.pose_id, r.commanded(), r.source), (*id, *p, Source::Synthetic));
        let (w, h) = image::image_dimensions(twin.join(&r.image)).expect("image");
        assert_eq!((w, h), (model.width_px, model.height_px), "at the model's resolution");
    }
    let reference = image::image_dimensions(twin.join("reference.png")).expect("reference");
    assert_eq!(reference, (model.width_px, model.height_px), "the reference at the twins' size");
    // --twin-size source: resized to the real frames' size, as --fill-missing writes.
    let out_source = tmp.path().join("synth-source");
    let (code, text) = synth_into(&out_source, &["--twin-size", "source", "--limit", "1"]);
    assert_eq!(code, 0, "{text}");
    let twin_source = out_source.join("sphere").join("vitac");
    let rows_source = rig::dataset::read_rows(&twin_source).expect("rows");
    assert_eq!(rows_source.len(), 1);
    assert_eq!(image::image_dimensions(twin_source.join(&rows_source[0].image)).expect("image"), (SIZE, SIZE));
    assert_eq!(image::image_dimensions(twin_source.join("reference.png")).expect("reference"), (SIZE, SIZE));
    let m = Manifest::load(&twin).expect("manifest");
    assert_eq!((m.object.name.as_str(), m.sensor.name()), ("sphere", "vitac"));
    assert!(twin.join("reference.png").is_file());
    let (code, text) = synth(&[]);
    assert_eq!(code, 0, "{text}");
    assert!(text.contains("synthesised 0 poses"), "{text}");
    // The pair evaluates.
    let (code, text) = run(eval_cmd(&real, &out, &[]));
    assert_eq!(code, 0, "{text}");
    assert!(text.contains("3 pairs"), "{text}");
    // --poses-of without --out is bad input.
    let mut c = rig();
    c.args(["synth", "--poses-of"]).arg(&real);
    let (code, text) = run(c);
    assert_eq!(code, 2, "{text}");
}

/// Rewrites every row of the datasets under `root` from `source=real` to `source=simulated`.
fn mark_simulated(root: &Path) {
    for dir in rig::dataset::find_datasets(root).expect("datasets") {
        let csv = dir.join("poses.csv");
        let text = std::fs::read_to_string(&csv).expect("read csv");
        assert!(text.contains(",real,"), "{}", csv.display());
        std::fs::write(&csv, text.replace(",real,", ",simulated,")).expect("write csv");
    }
}

#[test]
fn simulated_captured_rows_stand_where_real_ones_do() {
    let sets = make_sets(&["edge"], &same, &all, &[]);
    let options = EvalOptions::at_size(EVAL, "captured");
    let real = evaluate(&sets.real, &sets.synthetic, std::slice::from_ref(&sets.collected), &options).expect("evaluate");
    mark_simulated(&sets.real);
    mark_simulated(&sets.collected);
    let simulated = evaluate(&sets.real, &sets.synthetic, std::slice::from_ref(&sets.collected), &options).expect("evaluate");
    assert!(simulated.counts.pairs > 0);
    assert_eq!(format!("{:?}", simulated.counts), format!("{:?}", real.counts));
    assert_eq!(simulated.to_markdown(), real.to_markdown());
}
