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
            .find(|l| l.starts_with(sensor) && l.contains("mean"))
            .unwrap_or_else(|| panic!("no mean line for {sensor}: {text}"));
        let nums: Vec<f64> = line.split_whitespace().filter_map(|w| w.parse().ok()).collect();
        // contact%, fp-IoU, base whole, base contact (simulator columns may be n/a).
        assert!(nums.len() >= 4, "{line}");
        assert!(nums.iter().all(|v| v.is_finite()), "{line}");
    }
    assert!(dir.path().join("vitac_0.png").is_file());
}
