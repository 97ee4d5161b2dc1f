//! Numerical-stability property tests: the hard cases users hit must give finite numbers, or an
//! error where the input is ill-posed, never NaN, Inf or a panic.
//!
//! - diffusion schedulers (DDIM, DPM-Solver++ 2M) over whole runs, so the first and the last
//!   timestep are always exercised, with classifier-free guidance up to 20, every prediction
//!   type, eta up to 1 and step counts from 1 to the training length;
//! - SSIM of flat (constant) images, where the variance terms vanish;
//! - yaw wrap-around at +-90 and +-180 degrees (`wrap_deg`, the work frame, plan motion cost);
//! - MG400 kinematics near its singular configurations (folded arm, full stretch, the J1
//!   axis) and the profile's reachability check built on it.
//!
//! Half precision: the synthesis pipeline has no float16 path (the package loader accepts
//! float32 tensors only and refuses a float16 export), so there is nothing to round-trip.

use image::{GrayImage, Luma, Rgb, RgbImage};
use proptest::prelude::*;
use rig::arm::kinematics::{KinematicsError, Mg400Geometry};
use rig::arm::profile::FirmwareProfile;
use rig::metrics::{MetricsError, mse, psnr, ssim, ssim_gray};
use rig::pose::{Pose, WorkFrame, wrap_deg};
use rig::synth::scheduler::{NoiseSchedule, Scheduler, SchedulerConfig, SchedulerKind};

/// Stable Diffusion 1.5's scheduler (what the model packages ship), with a chosen prediction type.
fn sd15(prediction: &str, clip_sample: bool) -> NoiseSchedule {
    let config = SchedulerConfig {
        num_train_timesteps: 1000,
        beta_start: 0.00085,
        beta_end: 0.012,
        beta_schedule: "scaled_linear".into(),
        clip_sample,
        set_alpha_to_one: false,
        steps_offset: 1,
        prediction_type: prediction.into(),
        ..SchedulerConfig::default()
    };
    NoiseSchedule::new(config).expect("SD 1.5 schedule")
}

/// A deterministic pseudo-random vector in [-amp, amp].
fn values(seed: u64, n: usize, amp: f32) -> Vec<f32> {
    let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    (0..n)
        .map(|_| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            ((s >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0) as f32 * amp
        })
        .collect()
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    /// A whole sampling run stays finite whatever the guidance (0..=20), kind, prediction,
    /// eta and step count; the model's noise estimate is the guided `u + g (c - u)`.
    #[test]
    fn schedulers_stay_finite_with_guidance_up_to_20(
        dpm in any::<bool>(),
        prediction in prop::sample::select(vec!["epsilon", "v_prediction", "sample"]),
        clip in any::<bool>(),
        steps in prop::sample::select(vec![1usize, 2, 3, 10, 20, 50, 999, 1000]),
        eta in 0.0f32..=1.0,
        guidance in 0.0f32..=20.0,
        seed in any::<u64>(),
    ) {
        let schedule = sd15(prediction, clip);
        let kind = if dpm { SchedulerKind::DpmSolverPp2m } else { SchedulerKind::Ddim };
        if dpm && steps >= 1000 {
            // DPM-Solver++'s grid needs steps + 1 points of the 1000.
            prop_assert!(Scheduler::new(&schedule, kind, steps, eta).is_err());
            return Ok(());
        }
        let mut scheduler = Scheduler::new(&schedule, kind, steps, eta).expect("valid settings");
        let ts = scheduler.timesteps().to_vec();
        prop_assert_eq!(ts.len(), steps);
        // Leading spacing with steps_offset 1 reaches t = 1000 at 1000 steps (diffusers too);
        // alpha_prod clamps it to the last trained step.
        prop_assert!(ts.iter().all(|&t| (0..=1000).contains(&t)), "timesteps {:?}", &ts[..ts.len().min(5)]);
        for &t in [ts[0], ts[ts.len() - 1], -1, 0, 999].iter() {
            let a = schedule.alpha_prod(t);
            prop_assert!(a.is_finite() && a > 0.0 && a <= 1.0, "alpha_prod({}) = {}", t, a);
        }
        let n = 64;
        // A standard-normal-sized latent; extreme model outputs at the ends of the range.
        let mut sample = values(seed, n, 4.0);
        // Long runs: check a bounded number of steps at both ends (first and last timesteps)
        // instead of all 1000, to keep the test quick; the scheduler's state carries over.
        let check: Vec<usize> = (0..steps).filter(|&i| i < 8 || i + 8 >= steps).collect();
        for (k, &i) in check.iter().enumerate() {
            if k > 0 && check[k - 1] + 1 != i {
                // Skipped steps still advance the scheduler (it counts its own steps).
                for _ in check[k - 1] + 1..i {
                    let eps = values(seed ^ 0xAA, n, 1.0);
                    sample = scheduler.step(&schedule, &eps, &sample, None);
                }
            }
            let uncond = values(seed.wrapping_add(i as u64), n, 3.0);
            let cond = values(seed.wrapping_add(i as u64) ^ 0x55, n, 3.0);
            let eps: Vec<f32> = uncond.iter().zip(&cond).map(|(&u, &c)| u + guidance * (c - u)).collect();
            let noise = scheduler.needs_noise().then(|| values(seed ^ i as u64, n, 3.0));
            sample = scheduler.step(&schedule, &eps, &sample, noise.as_deref());
            prop_assert!(sample.iter().all(|v| v.is_finite()), "step {} of {} (t = {}) gave {:?}", i, steps, ts[i], &sample[..4]);
        }
    }

    /// SSIM, MSE and PSNR of flat images: finite, SSIM in [-1, 1], 1 for identical images.
    #[test]
    fn metrics_of_flat_images_are_finite(a in any::<u8>(), b in any::<u8>(), w in 11u32..40, h in 11u32..40) {
        let fa = RgbImage::from_pixel(w, h, Rgb([a, a, a]));
        let fb = RgbImage::from_pixel(w, h, Rgb([b, b, b]));
        let s = ssim(&fa, &fb).expect("same size, big enough");
        prop_assert!(s.is_finite() && (-1.0..=1.0).contains(&s), "ssim {}", s);
        let same = ssim(&fa, &fa).expect("ssim");
        prop_assert!((same - 1.0).abs() < 1e-9, "ssim of an image with itself {}", same);
        let g = ssim_gray(&GrayImage::from_pixel(w, h, Luma([a])), &GrayImage::from_pixel(w, h, Luma([b]))).expect("ssim");
        prop_assert!(g.is_finite() && (-1.0..=1.0).contains(&g));
        let m = mse(&fa, &fb).expect("mse");
        prop_assert!(m.is_finite() && m >= 0.0);
        // PSNR of identical images is +inf by definition; anything else is finite.
        let p = psnr(&fa, &fb).expect("psnr");
        prop_assert!(if a == b { p.is_infinite() && p > 0.0 } else { p.is_finite() }, "psnr {}", p);
    }

    /// wrap_deg lands in (-180, 180], is 360-periodic, and keeps +-90 and 180 where they are.
    #[test]
    fn wrap_deg_is_periodic_and_in_range(a in -1.0e6f64..1.0e6, k in -50i32..50) {
        let w = wrap_deg(a);
        prop_assert!(w > -180.0 && w <= 180.0, "wrap_deg({}) = {}", a, w);
        let shifted = wrap_deg(a + 360.0 * k as f64);
        prop_assert!(wrap_deg(shifted - w).abs() < 1e-6, "{} vs {}", shifted, w);
    }

    /// The work frame's base <-> plan conversion round-trips around the yaw wrap, with the
    /// frame itself rotated near +-90 and +-180 degrees.
    #[test]
    fn work_frame_round_trips_across_the_yaw_wrap(
        origin_yaw in prop::sample::select(vec![-180.0f64, -90.0, 90.0, 180.0, 179.999, -179.999]),
        jitter in -1e-3f64..1e-3,
        x in -30.0f64..30.0, y in -30.0f64..30.0, z in -2.0f64..3.0,
        yaw in prop::sample::select(vec![-180.0f64, -90.0, 0.0, 90.0, 180.0, 179.5, -179.5]),
    ) {
        let mut frame = WorkFrame::default();
        frame.origin.yaw_deg = origin_yaw + jitter;
        let plan = Pose::new(x, y, z, yaw);
        let base = frame.contact_pose(&plan);
        prop_assert!(base.is_finite());
        let back = frame.plan_pose(&base);
        prop_assert!(back.distance_mm(&plan) < 1e-9, "{} -> {} -> {}", plan, base, back);
        prop_assert!(back.yaw_error_deg(&plan) < 1e-9);
        prop_assert!(plan.yaw_error_deg(&Pose::new(x, y, z, yaw + 360.0)) < 1e-9);
    }

    /// Motion time between poses either side of the yaw wrap is finite, non-negative and
    /// symmetric.
    #[test]
    fn motion_time_across_the_yaw_wrap_is_finite(
        yaw_a in prop::sample::select(vec![-180.0f64, -90.0, 90.0, 180.0]),
        da in -0.5f64..0.5, db in -0.5f64..0.5,
    ) {
        let profile = FirmwareProfile::default_mg400();
        let frame = WorkFrame::default();
        let a = frame.approach_pose(&Pose::new(1.0, 0.0, 0.0, yaw_a + da));
        let b = frame.approach_pose(&Pose::new(-1.0, 2.0, 0.0, -yaw_a + db));
        let ab = profile.motion_time_s(&a, &b);
        let ba = profile.motion_time_s(&b, &a);
        prop_assert!(ab.is_finite() && ab >= 0.0, "{} -> {}: {}", a, b, ab);
        prop_assert!((ab - ba).abs() < 1e-9 * ab.max(1.0), "{} vs {}", ab, ba);
    }

    /// Inverse kinematics near the folded singularity, full stretch and the J1 axis gives
    /// finite joints that reproduce the pose, or an error, never NaN.
    #[test]
    fn kinematics_near_singular_configurations(
        which in 0usize..3,
        eps in prop::sample::select(vec![0.0f64, 1e-12, 1e-9, 1e-6, 1e-3, 0.1]),
        angle in -180.0f64..180.0,
        yaw in -180.0f64..180.0,
    ) {
        let g = Mg400Geometry::default();
        let reach = g.link2_mm + g.link3_mm;
        let (s, c) = angle.to_radians().sin_cos();
        // Wrist point relative to J2 in the arm's (r, z) plane, then the tool pose.
        let (r, z) = match which {
            0 => (eps * c, eps * s),                               // folded: on J2
            1 => ((reach - eps) * c, (reach - eps) * s),           // stretched
            _ => (-g.r_offset_mm + eps, 100.0 * s),                 // tool on the J1 axis
        };
        let radius = r + g.r_offset_mm;
        let pose = Pose::new(radius, 0.0, z + g.z_offset_mm, yaw);
        match g.inverse(&pose) {
            Ok(j) => {
                let a = j.to_array();
                prop_assert!(a.iter().all(|v| v.is_finite()), "{} -> {:?}", pose, j);
                let again = g.forward(&j);
                prop_assert!(again.distance_mm(&pose) < 1e-3, "{} -> {:?} -> {}", pose, j, again);
            }
            Err(KinematicsError::NonFinite) => prop_assert!(false, "finite pose {} called non-finite", pose),
            Err(_) => {}
        }
        let profile = FirmwareProfile::default_mg400();
        if let Ok(j) = profile.reach(&pose) {
            prop_assert!(j.to_array().iter().all(|v| v.is_finite()), "reach {} -> {:?}", pose, j);
        }
    }
}

/// Ill-posed scheduler settings are errors, not NaN.
#[test]
fn ill_posed_scheduler_settings_are_errors() {
    let schedule = sd15("epsilon", false);
    for steps in [0usize, 1001, usize::MAX] {
        assert!(Scheduler::new(&schedule, SchedulerKind::Ddim, steps, 0.0).is_err(), "steps {steps}");
        assert!(Scheduler::new(&schedule, SchedulerKind::DpmSolverPp2m, steps, 0.0).is_err(), "steps {steps}");
    }
    for eta in [f32::NAN, f32::INFINITY, -0.1] {
        assert!(Scheduler::new(&schedule, SchedulerKind::Ddim, 10, eta).is_err(), "eta {eta}");
    }
    let bad = SchedulerConfig { beta_start: f64::NAN, ..SchedulerConfig::default() };
    assert!(NoiseSchedule::new(bad).is_err(), "NaN beta_start");
    let bad = SchedulerConfig { beta_start: 0.5, beta_end: 1.5, ..SchedulerConfig::default() };
    assert!(NoiseSchedule::new(bad).is_err(), "betas above 1 make alpha_prod negative");
}

/// Images too small for the SSIM window, or of different sizes, are errors.
#[test]
fn ill_posed_metric_inputs_are_errors() {
    let tiny = RgbImage::from_pixel(3, 3, Rgb([9, 9, 9]));
    assert!(matches!(ssim(&tiny, &tiny), Err(MetricsError::TooSmall { .. })));
    let other = RgbImage::from_pixel(8, 8, Rgb([9, 9, 9]));
    let big = RgbImage::from_pixel(9, 8, Rgb([9, 9, 9]));
    assert!(matches!(ssim(&other, &big), Err(MetricsError::SizeMismatch { .. })));
}

/// Exactly folded and non-finite poses are errors.
#[test]
fn singular_and_non_finite_poses_are_errors() {
    let g = Mg400Geometry::default();
    let folded = Pose::new(g.r_offset_mm, 0.0, g.z_offset_mm, 0.0);
    assert!(matches!(g.inverse(&folded), Err(KinematicsError::Singular { .. })));
    for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        assert_eq!(g.inverse(&Pose::new(300.0, 0.0, bad, 0.0)), Err(KinematicsError::NonFinite));
        assert!(FirmwareProfile::default_mg400().reach(&Pose::new(bad, 0.0, 0.0, 0.0)).is_err());
    }
    assert!(wrap_deg(f64::NAN).is_nan(), "wrap_deg passes NaN through for the caller to refuse");
}
