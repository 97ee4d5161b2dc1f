//! The contact-overlap calibration fit on synthetic frames, and SSIM against closed forms.

use glam::Vec3;
use image::{Rgb, RgbImage};
use rig::calibration::Calibration;
use rig::calibration::contact_fit::{ContactFitOptions, FitFrame, FitTarget, fit_contact};
use rig::geometry::raster::render_depth;
use rig::geometry::shapes::box_mesh;
use rig::metrics::{psnr, ssim, ssim_masked};
use rig::pose::Pose;

/// A "real" frame: a bright ridge on a textured background where `truth` puts it.
fn synthetic_frame(mesh: &rig::geometry::stl::Mesh, pose: &Pose, truth: &Calibration) -> RgbImage {
    let d = render_depth(mesh, pose, truth, 256, 256, 1);
    RgbImage::from_fn(256, 256, |x, y| {
        let h = d.get(x, y).unwrap();
        let base = 90 + ((x * 7 + y * 13) % 23) as u8;
        if h > 0.0 { Rgb([250, 250, 245]) } else { Rgb([base, base - 20, base - 40]) }
    })
}

#[test]
fn fit_recovers_a_known_calibration() {
    let mesh = box_mesh(Vec3::new(-1.0, -8.0, 0.0), Vec3::new(1.0, 8.0, 10.0));
    let truth =
        Calibration { centre_px: [135.0, 121.0], scale_px_per_mm: [9.0, -9.0], rotation_deg: 20.0, ..Calibration::default_for(256, 256) };
    let poses = [(-3.0, -2.0, -90.0), (3.5, 1.8, -89.0), (1.8, -4.5, -87.0), (-3.6, 4.4, -86.0), (0.0, 0.0, -60.0)];
    let frames: Vec<FitFrame> = poses
        .iter()
        .enumerate()
        .map(|(i, &(x, y, yaw))| {
            let pose = Pose::new(x, y, 1.5, yaw);
            FitFrame { name: format!("f{i}"), pose, image: synthetic_frame(&mesh, &pose, &truth) }
        })
        .collect();
    let opts = ContactFitOptions {
        work_size: 128,
        start_scales_px_per_mm: vec![8.0],
        fit_pose_correction: false,
        refine_best: 3,
        max_evaluations: 300,
        ..ContactFitOptions::default()
    };
    let fit = fit_contact(&mesh, &frames, &FitTarget::Edges, &opts).unwrap();
    let c = &fit.calibration;
    // Rectangles are symmetric: compare where points land, not the parameters.
    for (x, y) in [(0.0, 0.0), (4.0, 0.0), (0.0, 4.0), (-3.0, 2.0)] {
        let (u, v) = c.mm_to_px(x, y);
        let (ut, vt) = truth.mm_to_px(x, y);
        assert!((u - ut).abs() < 4.0 && (v - vt).abs() < 4.0, "({x},{y}): fitted ({u:.1},{v:.1}) truth ({ut:.1},{vt:.1}); {c:?}");
    }
    assert!(fit.residuals_px.iter().all(|r| *r < 4.0), "{:?}", fit.residuals_px);
    assert_eq!(c.fit.as_ref().unwrap().frames.len(), 5);
}

#[test]
fn ssim_of_flat_images_matches_the_closed_form() {
    // Zero variance: SSIM = (2ab + C1) / (a^2 + b^2 + C1), C1 = (0.01 * 255)^2.
    let (a, b) = (100.0f64, 140.0f64);
    let c1 = (0.01f64 * 255.0).powi(2);
    let expected = (2.0 * a * b + c1) / (a * a + b * b + c1);
    let ia = RgbImage::from_pixel(30, 30, Rgb([100, 100, 100]));
    let ib = RgbImage::from_pixel(30, 30, Rgb([140, 140, 140]));
    assert!((ssim(&ia, &ib).unwrap() - expected).abs() < 1e-9);
    // PSNR: MSE 1600 -> 10 log10(255^2 / 1600).
    assert!((psnr(&ia, &ib).unwrap() - 10.0 * (255.0f64 * 255.0 / 1600.0).log10()).abs() < 1e-9);
    let mask: Vec<bool> = (0..900).map(|i| i % 30 > 15).collect();
    assert!((ssim_masked(&ia, &ib, &mask).unwrap() - expected).abs() < 1e-9);
}

#[test]
fn ssim_of_an_edge_shift_is_between_zero_and_one() {
    let edge = |shift: u32| RgbImage::from_fn(40, 40, |x, _| if x < 20 + shift { Rgb([0, 0, 0]) } else { Rgb([255, 255, 255]) });
    let s1 = ssim(&edge(0), &edge(1)).unwrap();
    let s3 = ssim(&edge(0), &edge(3)).unwrap();
    assert!(s1 < 1.0 && s3 < s1 && s3 > 0.0, "{s1} {s3}");
}

/// Against scikit-image 0.26 on real frames:
/// `structural_similarity(a, b, channel_axis=2, gaussian_weights=True, sigma=1.5,
/// use_sample_covariance=False, data_range=255)` and `peak_signal_noise_ratio(a, b,
/// data_range=255)`, computed once with skimage and written here as reference values.
#[test]
fn ssim_and_psnr_match_scikit_image_on_real_frames() {
    let root = std::path::PathBuf::from(std::env::var("RIG_SHARED").unwrap_or_else(|_| "../shared".to_string()))
        .join("real-sample/multidiffsense-example/tactile/1");
    let load = |p: &str| image::open(root.join(p)).unwrap_or_else(|e| panic!("{p}: {e} (set RIG_SHARED)")).to_rgb8();
    let cases = [
        ("ViTac/target/1_ViTac_0.png", "ViTac/target/1_ViTac_1.png", 0.9190462484044947, 22.070848519835078),
        ("TacTip/target/1_TacTip_0.png", "TacTip/target/1_TacTip_3.png", 0.8505309769135733, 20.3036512042533),
    ];
    for (a, b, ssim_ref, psnr_ref) in cases {
        let (ia, ib) = (load(a), load(b));
        let s = ssim(&ia, &ib).unwrap();
        let p = psnr(&ia, &ib).unwrap();
        assert!((s - ssim_ref).abs() < 1e-6, "{a} vs {b}: SSIM {s} skimage {ssim_ref}");
        assert!((p - psnr_ref).abs() < 1e-6, "{a} vs {b}: PSNR {p} skimage {psnr_ref}");
    }
}
