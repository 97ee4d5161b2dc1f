//! Property tests of the robust point fit: finite results (or a clear error) for any finite
//! input, degenerate sets refused, known maps recovered through noise and outliers.

use proptest::prelude::*;
use rig::calibration::fit::{FitError, FitOptions, fit_points};
use rig::calibration::{Calibration, FitPoint};

fn calibration(cu: f64, cv: f64, sx: f64, sy: f64, rot: f64) -> Calibration {
    Calibration { centre_px: [cu, cv], scale_px_per_mm: [sx, sy], rotation_deg: rot, ..Calibration::default_for(512, 512) }
}

fn finite_f64() -> impl Strategy<Value = f64> {
    prop_oneof![-1e3..1e3f64, prop::num::f64::NORMAL | prop::num::f64::SUBNORMAL | prop::num::f64::ZERO, Just(f64::MAX), Just(-f64::MAX),]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    #[test]
    fn any_finite_input_gives_finite_numbers_or_an_error(
        raw in prop::collection::vec((finite_f64(), finite_f64(), finite_f64(), finite_f64()), 0..12)
    ) {
        let points: Vec<FitPoint> = raw.iter().map(|&(a, b, c, d)| FitPoint::new([a, b], [c, d])).collect();
        if let Ok(fit) = fit_points(&points, &FitOptions::default(), "prop") {
            let c = &fit.calibration;
            let nums = [c.centre_px[0], c.centre_px[1], c.scale_px_per_mm[0], c.scale_px_per_mm[1], c.rotation_deg,
                fit.rms_px, fit.rms_mm, fit.max_px, fit.condition, fit.shear];
            prop_assert!(nums.iter().chain(&fit.residuals_px).all(|v| v.is_finite()), "{fit:?}");
            prop_assert!(c.validate("prop").is_ok());
            prop_assert_eq!(fit.residuals_px.len(), points.len());
        }
    }

    #[test]
    fn collinear_points_are_refused(
        ox in -20.0..20.0f64, oy in -20.0..20.0f64, angle in 0.0..360.0f64,
        ts in prop::collection::vec(-10.0..10.0f64, 3..15),
    ) {
        prop_assume!(ts.iter().fold(f64::MIN, |m, t| m.max(*t)) - ts.iter().fold(f64::MAX, |m, t| m.min(*t)) > 0.1);
        let (s, c) = angle.to_radians().sin_cos();
        let truth = calibration(250.0, 260.0, 9.0, 8.0, 5.0);
        let points: Vec<FitPoint> = ts.iter().map(|t| {
            let mm = [ox + c * t, oy + s * t];
            let (u, v) = truth.mm_to_px(mm[0], mm[1]);
            FitPoint::new(mm, [u, v])
        }).collect();
        let r = fit_points(&points, &FitOptions::default(), "prop");
        prop_assert!(matches!(r, Err(FitError::Collinear { .. })), "{r:?}");
    }

    #[test]
    fn recovers_known_maps_through_noise_and_an_outlier(
        cu in 100.0..400.0f64, cv in 100.0..400.0f64,
        sx in 5.0..15.0f64, sy_abs in 5.0..15.0f64, mirror in any::<bool>(), rot in -180.0..180.0f64,
        noise in prop::collection::vec((-0.2..0.2f64, -0.2..0.2f64), 25),
        bad in 0usize..25, bad_px in 20.0..80.0f64,
    ) {
        let sy = if mirror { -sy_abs } else { sy_abs };
        let truth = calibration(cu, cv, sx, sy, rot);
        let mut points = Vec::new();
        for (k, (nu, nv)) in noise.iter().enumerate() {
            let mm = [(k % 5) as f64 * 2.0 - 4.0, (k / 5) as f64 * 2.0 - 4.0];
            let (u, v) = truth.mm_to_px(mm[0], mm[1]);
            points.push(FitPoint::new(mm, [u + nu, v + nv]));
        }
        points[bad].px[0] += bad_px;
        let fit = fit_points(&points, &FitOptions::default(), "prop").unwrap();
        prop_assert!(!fit.inlier[bad]);
        prop_assert!(fit.rms_px < 0.3, "{}", fit.rms_px);
        let c = &fit.calibration;
        // The same map whatever sign convention the fit chose: compare images of test points.
        for (x, y) in [(0.0, 0.0), (5.0, -3.0), (-4.0, 4.0)] {
            let (a, b) = truth.mm_to_px(x, y);
            let (p, q) = c.mm_to_px(x, y);
            prop_assert!((a - p).hypot(b - q) < 0.5, "({x}, {y}): {a},{b} vs {p},{q}");
        }
        prop_assert!((c.scale_px_per_mm[0] - sx).abs() < 0.1 && (c.scale_px_per_mm[1] - sy).abs() < 0.1, "{c:?}");
    }
}

#[test]
fn too_few_and_coincident_points_are_refused() {
    let p = FitPoint::new([1.0, 2.0], [3.0, 4.0]);
    assert_eq!(fit_points(&[], &FitOptions::default(), ""), Err(FitError::TooFewPoints { given: 0, needed: 3 }));
    assert!(matches!(fit_points(&[p, p], &FitOptions::default(), ""), Err(FitError::TooFewPoints { given: 2, .. })));
    assert!(matches!(fit_points(&[p; 10], &FitOptions::default(), ""), Err(FitError::AllAtOneSpot { .. })));
    let e = fit_points(&[p; 10], &FitOptions::default(), "").unwrap_err();
    assert!(e.to_string().contains("one spot"), "{e}");
}

#[test]
fn the_fit_record_keeps_points_and_residuals() {
    let truth = calibration(240.0, 270.0, 10.8, 11.7, -3.0);
    let points: Vec<FitPoint> = [(-3.0, -3.0), (3.0, -3.0), (3.0, 3.0), (-3.0, 3.0), (0.0, 0.0)]
        .iter()
        .map(|&(x, y)| {
            let (u, v) = truth.mm_to_px(x, y);
            FitPoint::new([x, y], [u, v])
        })
        .collect();
    let fit = fit_points(&points, &FitOptions::default(), "record").unwrap();
    let text = fit.calibration.to_toml().unwrap();
    let back = Calibration::from_toml(&text, "t").unwrap();
    let record = back.fit.unwrap();
    assert_eq!(record.method, "record");
    assert_eq!(record.points, points);
    assert_eq!(record.residuals_px.len(), 5);
    assert!(fit.residual_line().starts_with("residual 0.00 px"), "{}", fit.residual_line());
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 128, ..ProptestConfig::default() })]

    /// Detection never panics, whatever the bytes and sizes.
    #[test]
    fn detectors_never_panic(
        w in 0u32..24, h in 0u32..24, w2 in 0u32..24,
        bytes in prop::collection::vec(any::<u8>(), 0..(24 * 24 * 3)),
        bytes2 in prop::collection::vec(any::<u8>(), 0..(24 * 24 * 3)),
    ) {
        use rig::calibration::detect::{ContactDetector, DetectOptions, ImprintOptions, MarkerOptions};
        let img = |w: u32, h: u32, b: &[u8]| {
            image::RgbImage::from_fn(w, h, |x, y| {
                let i = ((y * w + x) * 3) as usize;
                image::Rgb([0, 1, 2].map(|k| b.get(i + k).copied().unwrap_or(0)))
            })
        };
        let (a, b, c) = (img(w, h, &bytes), img(w, h, &bytes2), img(w2, h, &bytes2));
        for d in [
            ContactDetector::Difference(DetectOptions::default()),
            ContactDetector::Markers(MarkerOptions::default()),
            ContactDetector::Imprint(ImprintOptions::default()),
            ContactDetector::Imprint(ImprintOptions::with_markers(24)),
        ] {
            if let Ok(found) = d.detect(&a, &b) {
                prop_assert!(found.centroid_px.iter().all(|v| v.is_finite()));
            }
            let _ = d.detect(&a, &c);
        }
    }
}
