//! Depth rasteriser, calibration and control image against hand-computed geometry.

use std::path::PathBuf;

use glam::Vec3;
use proptest::prelude::*;
use rig::calibration::Calibration;
use rig::geometry::DepthMap;
use rig::geometry::control::{control_image, control_values, depth_from_png16, depth_png16, viridis};
use rig::geometry::objects::load_object;
use rig::geometry::raster::render_depth;
use rig::geometry::shapes::box_mesh;
use rig::geometry::stl::Mesh;
use rig::pose::Pose;

fn shared() -> PathBuf {
    PathBuf::from(std::env::var("RIG_SHARED").unwrap_or_else(|_| "../shared".to_string()))
}

/// Pixels covered, pixels in contact, and the contact centroid.
fn footprint(d: &DepthMap) -> (usize, usize, (f64, f64)) {
    let (mut covered, mut contact, mut sx, mut sy) = (0, 0, 0.0, 0.0);
    for y in 0..d.height {
        for x in 0..d.width {
            let h = d.get(x, y).unwrap();
            if h > DepthMap::BACKGROUND_MM {
                covered += 1;
            }
            if h > 0.0 {
                contact += 1;
                sx += x as f64 + 0.5;
                sy += y as f64 + 0.5;
            }
        }
    }
    (covered, contact, (sx / contact.max(1) as f64, sy / contact.max(1) as f64))
}

#[test]
fn real_edge_footprint_is_the_ridge_top() {
    let mesh = Mesh::load(shared().join("real-sample/multidiffsense-example/stl/1.stl")).unwrap();
    let calib = Calibration { scale_px_per_mm: [10.0, 10.0], ..Calibration::default_for(512, 512) };
    let d = render_depth(&mesh, &Pose::new(0.0, 0.0, 1.0, 0.0), &calib, 512, 512, 1);
    let (covered, contact, (cx, cy)) = footprint(&d);
    // Ridge top 2 x 16 mm at 10 px/mm; the whole 16 x 16 mm plinth is covered.
    assert_eq!(contact, 20 * 160);
    assert_eq!(covered, 160 * 160);
    assert!((cx - 256.0).abs() < 1e-9 && (cy - 256.0).abs() < 1e-9);
    assert!((d.max_indentation_mm() - 1.0).abs() < 1e-5);
    // The plinth top (z = 10) lies 9 mm below the skin plane.
    assert!((d.get(256 + 50, 256).unwrap() + 9.0).abs() < 1e-4);
}

#[test]
fn sphere_cap_follows_the_spherical_profile() {
    let mesh = load_object("sphere").unwrap();
    let calib = Calibration::default_for(512, 512);
    let z = 1.0;
    let d = render_depth(&mesh, &Pose::new(0.0, 0.0, z, 0.0), &calib, 512, 512, 1);
    let (_, contact, _) = footprint(&d);
    // Contact disc radius of a 6 mm sphere pressed 1 mm: sqrt(2 r z - z^2) = sqrt(11) mm.
    let r_px = 11f64.sqrt() * 8.5;
    let expected = std::f64::consts::PI * r_px * r_px;
    assert!((contact as f64 - expected).abs() / expected < 0.03, "{contact} vs {expected}");
    // 2 mm off centre the surface is r - sqrt(r^2 - 4) lower.
    let h = d.get(256 + 17, 256).unwrap() as f64;
    let expected_h = z - (6.0 - (36.0f64 - (17.5f64 / 8.5).powi(2)).sqrt());
    assert!((h - expected_h).abs() < 0.02, "{h} vs {expected_h}");
}

#[test]
fn nothing_touches_above_the_object() {
    let mesh = load_object("cuboid").unwrap();
    let d = render_depth(&mesh, &Pose::new(0.0, 0.0, -0.5, 0.0), &Calibration::default_for(128, 128), 128, 128, 1);
    assert_eq!(d.max_indentation_mm(), 0.0);
    assert!((d.get(64, 64).unwrap() + 0.5).abs() < 1e-5);
}

#[test]
fn rendering_is_deterministic_and_size_follows_the_request() {
    let mesh = load_object("pacman").unwrap();
    let calib = Calibration::default_for(512, 512);
    let pose = Pose::new(0.7, -1.2, 1.5, 33.0);
    let a = render_depth(&mesh, &pose, &calib, 320, 200, 2);
    assert_eq!((a.width, a.height, a.height_mm.len()), (320, 200, 64_000));
    assert_eq!(a, render_depth(&mesh, &pose, &calib, 320, 200, 2));
}

#[test]
fn control_image_and_depth16_of_a_render() {
    let mesh = load_object("cone").unwrap();
    let d = render_depth(&mesh, &Pose::new(0.0, 0.0, 1.5, 0.0), &Calibration::default_for(256, 256), 256, 256, 1);
    let c = control_image(&d);
    assert_eq!(c.dimensions(), (256, 256));
    // The apex is nearest: yellow end of viridis; background the purple end.
    assert_eq!(c.get_pixel(128, 128).0, viridis(1.0));
    assert_eq!(c.get_pixel(0, 0).0, viridis(0.0));
    assert!(control_values(&d).iter().all(|v| (0.0..=1.0).contains(v)));
    let back = depth_from_png16(&depth_png16(&d));
    for (a, b) in d.height_mm.iter().zip(&back.height_mm) {
        assert!((a - b).abs() < 1e-3);
    }
}

/// Moving the sensor by (dx, dy) at yaw moves the footprint by -(dx, dy) turned by -yaw,
/// through the calibration's rotation and scale; its area is the box's, within pixelisation.
fn footprint_check(dx: f64, dy: f64, yaw: f64, rot: f64, scale: f64, mirror: bool) -> Result<(), String> {
    fn ensure(ok: bool, what: String) -> Result<(), String> {
        if ok { Ok(()) } else { Err(what) }
    }
    let mesh = box_mesh(Vec3::new(-1.5, -1.0, 0.0), Vec3::new(1.5, 1.0, 4.0));
    let calib = Calibration {
        scale_px_per_mm: [scale, if mirror { -scale } else { scale }],
        rotation_deg: rot,
        ..Calibration::default_for(256, 256)
    };
    let d = render_depth(&mesh, &Pose::new(dx, dy, 0.5, yaw), &calib, 256, 256, 1);
    let (_, contact, (cx, cy)) = footprint(&d);
    // Pixel-centre sampling of a turned 3 x 2 mm rectangle: off by up to about half a pixel
    // along its edges, which is over 10% of the area at the smallest scales.
    let expected_area = 3.0 * 2.0 * scale * scale;
    let edge_px = 2.0 * (3.0 + 2.0) * scale;
    let tolerance = (0.1 * expected_area).max(0.5 * edge_px);
    ensure((contact as f64 - expected_area).abs() < tolerance, format!("{} vs {} (tolerance {})", contact, expected_area, tolerance))?;
    let (s, c) = (-yaw).to_radians().sin_cos();
    let (ox, oy) = (-dx, -dy);
    let (sx, sy) = (c * ox - s * oy, s * ox + c * oy);
    let (ex, ey) = calib.mm_to_px(sx, sy);
    ensure((cx - ex).abs() < 0.75 && (cy - ey).abs() < 0.75, format!("centroid ({}, {}) expected ({}, {})", cx, cy, ex, ey))?;
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    /// See [`footprint_check`].
    #[test]
    fn footprint_moves_with_the_pose(
        dx in -3.0f64..3.0, dy in -3.0f64..3.0, yaw in -180.0f64..180.0,
        rot in -90.0f64..90.0, scale in 6.0f64..12.0, mirror in any::<bool>(),
    ) {
        if let Err(e) = footprint_check(dx, dy, yaw, rot, scale, mirror) {
            prop_assert!(false, "{}", e);
        }
    }

    #[test]
    fn pose_correction_scales_the_offset(gain in 0.2f64..1.5, ang in -60.0f64..60.0, dx in -3.0f64..3.0) {
        let mesh = box_mesh(Vec3::new(-1.0, -1.0, 0.0), Vec3::new(1.0, 1.0, 4.0));
        let (s, c) = ang.to_radians().sin_cos();
        let corrected = Calibration {
            pose_xy_correction: Some([[gain * c, -gain * s], [gain * s, gain * c]]),
            ..Calibration::default_for(256, 256)
        };
        let plain = Calibration::default_for(256, 256);
        let a = render_depth(&mesh, &Pose::new(dx, 0.0, 0.5, 0.0), &corrected, 256, 256, 1);
        let b = render_depth(&mesh, &Pose::new(gain * c * dx, gain * s * dx, 0.5, 0.0), &plain, 256, 256, 1);
        prop_assert_eq!(a, b);
    }
}

#[test]
fn committed_calibrations_load_and_line_up_with_the_real_ridge() {
    // ViTac frame 0 of the real sample: the ridge spans about columns 118..402, rows 253..288.
    let calib = Calibration::load(concat!(env!("CARGO_MANIFEST_DIR"), "/calibration/mds-example-vitac.toml")).unwrap();
    let mesh = Mesh::load(shared().join("real-sample/multidiffsense-example/stl/1.stl")).unwrap();
    let pose = Pose::new(-3.06193989, -2.038885835, 1.5 + 0.7995462253753978, -89.79246118);
    let d = render_depth(&mesh, &pose, &calib, 512, 512, 1);
    let (_, contact, (cx, cy)) = footprint(&d);
    assert!((cx - 260.0).abs() < 12.0 && (cy - 270.0).abs() < 8.0, "centroid ({cx}, {cy})");
    let expected = 284.0 * 35.0;
    assert!((contact as f64 - expected).abs() / expected < 0.25, "{contact} px in contact");
    for sensor in ["tactip", "vitac", "vitactip"] {
        let c = Calibration::load(format!("{}/calibration/mds-example-{sensor}.toml", env!("CARGO_MANIFEST_DIR"))).unwrap();
        assert_eq!(c.image_size, [512, 512]);
        assert!(c.fit.as_ref().is_some_and(|f| !f.residuals_px.is_empty()), "{sensor}: fit record");
    }
}

/// A case proptest found at the smallest scale, where the rectangle's edge pixels are more than
/// 10% of its area (it failed the former 10% bound: 247 px against 222.7).
#[test]
fn footprint_at_the_smallest_scale() {
    footprint_check(-0.0909, -2.7129, -37.705, -52.611, 6.093, true).expect("footprint");
}
