//! `rig render`, `rig objects` and `rig compare-real` through the binary.

use std::path::{Path, PathBuf};
use std::process::Command;

use rig::cli::sensor_bridge::simulator_available;
use rig::geometry::objects::object_names;

fn rig() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_rig"));
    c.current_dir(env!("CARGO_MANIFEST_DIR"));
    c
}

fn shared() -> PathBuf {
    let s = std::env::var("RIG_SHARED").unwrap_or_else(|_| "../shared".to_string());
    Path::new(env!("CARGO_MANIFEST_DIR")).join(s)
}

fn run(c: &mut Command) -> (bool, String) {
    let out = c.output().expect("rig runs");
    (out.status.success(), format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr)))
}

#[test]
fn render_every_object_as_depth_and_control() {
    let dir = tempfile::tempdir().unwrap();
    for name in object_names() {
        for view in ["depth", "control"] {
            let out = dir.path().join(format!("{name}_{view}.png"));
            let (ok, text) = run(rig()
                .args(["render", "--object", name, "--pose", "0.5,-1,1.5,-30", "--sensor", view, "--size", "128x96", "--out"])
                .arg(&out));
            assert!(ok, "{name} {view}: {text}");
            let img = image::open(&out).unwrap();
            assert_eq!((img.width(), img.height()), (128, 96));
            match view {
                "depth" => assert!(matches!(img, image::DynamicImage::ImageLuma16(_)), "{name}: depth is 16-bit grey"),
                _ => assert!(matches!(img, image::DynamicImage::ImageRgb8(_))),
            }
        }
    }
}

#[test]
fn render_tactile_sensors_or_say_why_not() {
    let dir = tempfile::tempdir().unwrap();
    for sensor in ["tactip", "vitac", "vitactip"] {
        let out = dir.path().join(format!("{sensor}.png"));
        let (ok, text) = run(rig()
            .args(["render", "--object", "sphere", "--pose", "0,0,1.5,0", "--sensor", sensor, "--size", "128x128"])
            .arg("--calibration")
            .arg(format!("calibration/mds-example-{sensor}.toml"))
            .arg("--out")
            .arg(&out));
        if simulator_available() {
            assert!(ok && out.is_file(), "{sensor}: {text}");
        } else {
            assert!(!ok && text.contains("sensor simulator not available"), "{sensor}: {text}");
        }
    }
}

#[test]
fn render_rejects_bad_input_clearly() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.png");
    let (ok, text) = run(rig().args(["render", "--object", "teapot", "--pose", "0,0,1,0", "--sensor", "depth", "--out"]).arg(&out));
    assert!(!ok && text.contains("unknown object"), "{text}");
    let (ok, text) = run(rig().args(["render", "--object", "edge", "--pose", "0,0,1", "--sensor", "depth", "--out"]).arg(&out));
    assert!(!ok && text.contains("x,y,z,yaw"), "{text}");
    let (ok, text) = run(rig().args(["render", "--object", "edge", "--pose", "0,0,1,0", "--sensor", "gelsight", "--out"]).arg(&out));
    assert!(!ok && text.contains("gelsight"), "{text}");
    let bad = dir.path().join("bad.stl");
    std::fs::write(&bad, b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0\n").unwrap();
    let (ok, text) = run(rig().args(["render", "--stl"]).arg(&bad).args(["--pose", "0,0,1,0", "--sensor", "depth", "--out"]).arg(&out));
    assert!(!ok && text.contains("bad.stl") && text.contains("line 4"), "{text}");
}

#[test]
fn render_real_stl_with_fitted_calibration() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("c.png");
    let stl = shared().join("real-sample/multidiffsense-example/stl/1.stl");
    let (ok, text) = run(rig()
        .args(["render", "--stl"])
        .arg(&stl)
        .args(["--pose", "-3.06,-2.04,2.3,-89.8", "--sensor", "control", "--calibration", "calibration/mds-example-vitac.toml", "--out"])
        .arg(&out));
    assert!(ok, "{text}");
    let img = image::open(&out).unwrap().to_rgb8();
    // The ridge of real ViTac frame 0 lies around (260, 270): yellow there, background far away.
    assert_eq!(img.get_pixel(260, 270).0, rig::geometry::control::viridis(1.0));
    assert_eq!(img.get_pixel(260, 100).0, rig::geometry::control::viridis(0.0));
}

#[test]
fn objects_generate_and_contact_sheet() {
    let dir = tempfile::tempdir().unwrap();
    let (ok, text) = run(rig().args(["objects", "generate", "--out"]).arg(dir.path()));
    assert!(ok, "{text}");
    for name in object_names() {
        let generated = std::fs::read(dir.path().join(format!("{name}.stl"))).unwrap();
        assert!(rig::geometry::stl::Mesh::from_bytes(&generated).is_ok());
    }
    let sheet = dir.path().join("sheet.png");
    let (ok, text) = run(rig().args(["objects", "contact-sheet", "--render-size", "128", "--tile", "64", "--out"]).arg(&sheet));
    assert!(ok, "{text}");
    let img = image::open(&sheet).unwrap();
    // 5 columns, 8 rows of 64 px tiles with 4 px gaps.
    assert_eq!((img.width(), img.height()), (5 * 68 + 4, 8 * 68 + 4));
}

#[test]
fn compare_real_prints_baseline_per_sensor() {
    let dir = tempfile::tempdir().unwrap();
    let (ok, text) =
        run(rig().args(["compare-real", "--sample"]).arg(shared().join("real-sample/multidiffsense-example")).arg("--out").arg(dir.path()));
    assert!(ok, "{text}");
    for sensor in ["TacTip", "ViTac", "ViTacTip"] {
        let line = text
            .lines()
            .find(|l| l.split_whitespace().nth(1) == Some(sensor) && l.contains("mean"))
            .unwrap_or_else(|| panic!("no mean line for {sensor}: {text}"));
        let nums: Vec<f64> = line.split_whitespace().filter_map(|w| w.parse().ok()).collect();
        // object id, contact%, fp-IoU, base whole, base contact (simulator columns may be n/a).
        assert!(nums.len() >= 5, "{line}");
        assert!(nums.iter().all(|v| v.is_finite()), "{line}");
    }
    assert!(dir.path().join("1_vitac_0.png").is_file());
}

/// The simulator's mean contact SSIM for `sensor` in a `rig compare-real` table.
fn sim_contact_mean(text: &str, sensor: &str) -> f64 {
    let line = text
        .lines()
        .find(|l| l.split_whitespace().nth(1) == Some(sensor) && l.contains("mean"))
        .unwrap_or_else(|| panic!("no mean line for {sensor}: {text}"));
    let sim: Option<f64> = line.split_whitespace().nth_back(1).and_then(|w| w.parse().ok());
    sim.unwrap_or_else(|| panic!("no simulator contact SSIM in {line}"))
}

/// `--skin NAME=VALUE` sets a skin parameter for the comparison (a tight and a wide elastic
/// spread score differently from the committed one), and a name or value it does not
/// know is refused with exit 2 before anything is rendered.
#[test]
fn compare_real_sets_skin_parameters_and_refuses_unknown_ones() {
    let sample = shared().join("real-sample/multidiffsense-example");
    let compare = |extra: &[&str]| {
        let (ok, text) = run(rig().args(["compare-real", "--sensor", "vitac", "--sample"]).arg(&sample).args(extra));
        assert!(ok, "{text}");
        sim_contact_mean(&text, "ViTac")
    };
    let committed = compare(&[]);
    let tight = compare(&["--skin", "spread_mm=0.5"]);
    let flat = compare(&["--skin", "spread_mm=6", "--skin", "clear_mm=2"]);
    assert!(tight != committed && flat != committed && tight != flat, "{committed} {tight} {flat}");
    for bad in ["nope=1", "spread_mm=0.1", "spread_mm=NaN", "spread_mm"] {
        let out = rig().args(["compare-real", "--sensor", "vitac", "--skin", bad]).output().unwrap();
        let text = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{bad}: {text}");
        assert!(text.contains("--skin"), "{bad}: {text}");
    }
}

/// The frame indices of the `rig compare-real` lines of `object` and `sensor`, and whether a
/// mean line follows them.
fn compared_frames(text: &str, object: &str, sensor: &str) -> (Vec<usize>, bool) {
    let lines: Vec<Vec<&str>> = text
        .lines()
        .map(|l| l.split_whitespace().collect::<Vec<_>>())
        .filter(|w| w.len() > 3 && w[0] == object && w[1] == sensor)
        .collect();
    let frames = lines.iter().filter_map(|w| w[2].parse().ok()).collect();
    (frames, lines.iter().any(|w| w[2] == "mean"))
}

#[test]
fn compare_real_reads_any_number_of_frames_and_objects() {
    let sample = shared().join("real-sample/multidiffsense-example");
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("mds");
    // Object 1: 11 frames per sensor (the sample's 11 pose rows; its images reused under the
    // missing indices). Object 2: three TacTip frames, no other sensor.
    for (object, sensors, frames) in [("1", &["TacTip", "ViTac", "ViTacTip"][..], 11), ("2", &["TacTip"][..], 3)] {
        std::fs::create_dir_all(dir.join("csv")).unwrap();
        std::fs::create_dir_all(dir.join("stl")).unwrap();
        std::fs::copy(sample.join("csv/1.csv"), dir.join(format!("csv/{object}.csv"))).unwrap();
        std::fs::copy(sample.join("stl/1.stl"), dir.join(format!("stl/{object}.stl"))).unwrap();
        for sensor in sensors {
            let from = sample.join(format!("tactile/1/{sensor}/target"));
            let mut have: Vec<PathBuf> = std::fs::read_dir(&from).unwrap().map(|e| e.unwrap().path()).collect();
            have.sort();
            assert!(!have.is_empty(), "{}", from.display());
            let to = dir.join(format!("tactile/{object}/{sensor}/target"));
            std::fs::create_dir_all(&to).unwrap();
            for i in 0..frames {
                std::fs::copy(&have[i % have.len()], to.join(format!("{object}_{sensor}_{i}.png"))).unwrap();
            }
        }
    }
    let (ok, text) = run(rig().args(["compare-real", "--sample"]).arg(&dir));
    assert!(ok, "{text}");
    for sensor in ["TacTip", "ViTac", "ViTacTip"] {
        assert_eq!(compared_frames(&text, "1", sensor), ((0..11).collect(), true), "object 1 {sensor}:\n{text}");
    }
    assert_eq!(compared_frames(&text, "2", "TacTip"), ((0..3).collect(), true), "{text}");
    assert!(text.contains("skipped object 2 ViTac: 0 frame(s), need two"), "{text}");

    // A folder with no object is bad input.
    let empty = tmp.path().join("empty");
    std::fs::create_dir_all(empty.join("csv")).unwrap();
    let out = rig().args(["compare-real", "--sample"]).arg(&empty).output().unwrap();
    assert_eq!(out.status.code(), Some(2), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(String::from_utf8_lossy(&out.stderr).contains("no object found"));
}

#[test]
fn render_starts_from_a_measured_reference_frame() {
    let reference = shared().join("real-sample/multidiffsense-example/tactile/1/TacTip/target/1_TacTip_0.png");
    let dir = tempfile::tempdir().unwrap();
    let render = |out: &Path, extra: &[&str]| {
        run(rig()
            .args(["render", "--object", "edge", "--pose", "0,0,1,0", "--sensor", "tactip", "--size", "512x512", "--out"])
            .arg(out)
            .args(extra))
    };
    let (with_ref, plain) = (dir.path().join("ref.png"), dir.path().join("plain.png"));
    let (ok, text) = render(&with_ref, &["--reference", reference.to_str().unwrap()]);
    assert!(ok, "{text}");
    let (ok, text) = render(&plain, &[]);
    assert!(ok, "{text}");
    // Mean |difference| per channel from the measured frame: the render that started from it
    // keeps its look away from the contact; the modelled one does not.
    let diff = |path: &Path| {
        let (a, b) = (image::open(path).unwrap().to_rgb8(), image::open(&reference).unwrap().to_rgb8());
        a.as_raw().iter().zip(b.as_raw()).map(|(x, y)| (*x as f64 - *y as f64).abs()).sum::<f64>() / a.as_raw().len() as f64
    };
    let (d_ref, d_plain) = (diff(&with_ref), diff(&plain));
    assert!(d_ref < 10.0 && d_ref * 2.0 < d_plain, "from the reference {d_ref:.1}, modelled {d_plain:.1}");

    // A reference of another size, or for a view that is not a sensor, is bad input.
    let out = rig()
        .args(["render", "--object", "edge", "--pose", "0,0,1,0", "--sensor", "tactip", "--size", "256x256", "--out"])
        .arg(dir.path().join("x.png"))
        .arg("--reference")
        .arg(&reference)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(String::from_utf8_lossy(&out.stderr).contains("512x512 px, the output is 256x256"));
    let out = rig()
        .args(["render", "--object", "edge", "--pose", "0,0,1,0", "--sensor", "depth", "--out"])
        .arg(dir.path().join("y.png"))
        .arg("--reference")
        .arg(&reference)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2), "{}", String::from_utf8_lossy(&out.stderr));
}
