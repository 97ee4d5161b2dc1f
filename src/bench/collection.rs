//! Collection: settle time and frames averaged against image noise against seconds per pose.
//!
//! Each setting runs the real collection job ([`crate::jobs::collect::run`]) on the built-in simulated rig
//! (simulated MG400 over loopback TCP with a scaled clock, one simulated ViTacTip, full
//! scene) over a plan that visits every pose twice in a row (retract, re-approach), so
//!
//! - **image noise** ([`pair_noise_levels`]) is the standard deviation of the difference of
//!   the two captures of a pose divided by √2: the noise of one capture, in 8-bit levels,
//!   including whatever the re-approach does not repeat. It needs no noise-free image, so
//!   the same measure works on a real rig.
//! - **seconds per pose** are given two ways: *modelled* arm time (the firmware profile's
//!   motion model for travel, descent and retract, plus the settle time, plus one frame
//!   period per frame) and the bench's wall time per capture on the simulated rig. The
//!   simulated rig's own clock is not reported: it runs at a multiple of real time, so this
//!   machine's rendering time enters it multiplied by the time scale.

use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use image::RgbImage;

use super::error::BenchError;
use super::knob::{BenchConfig, Knob};
use super::plot::{Plot, Series};
use super::table::{Column, KnobReport, Row, mean};
use crate::arm::profile::FirmwareProfile;
use crate::camera::v4l2::CameraSettings;
use crate::config::{ArmBackend, CollectConfig, RigConfig, SensorBackend, SensorConfig};
use crate::dataset::{ObjectInfo, image_rel_path};
use crate::geometry::objects::ObjectChoice;
use crate::io::modbus::NoPeripherals;
use crate::jobs::Observer;
use crate::jobs::collect::{CollectSetup, SensorFeed};
use crate::metrics::MetricsError;
use crate::plan::{PlanSpec, PlannedPose};
use crate::pose::{Pose, WorkFrame};
use crate::rigs::Rig;
use crate::sensor::SensorKind;
use crate::sensor::SensorSet;

/// Frame period of the simulated cameras, s.
pub const FRAME_PERIOD_S: f64 = 1.0 / 30.0;

/// Noise of one capture from two captures of the same scene: the standard deviation of their
/// pixel differences (all channels) divided by √2, in 8-bit levels.
pub fn pair_noise_levels(a: &RgbImage, b: &RgbImage) -> Result<f64, MetricsError> {
    if a.dimensions() != b.dimensions() {
        return Err(MetricsError::SizeMismatch { a_width: a.width(), a_height: a.height(), b_width: b.width(), b_height: b.height() });
    }
    let n = a.as_raw().len();
    if n == 0 {
        return Ok(0.0);
    }
    let diffs = a.as_raw().iter().zip(b.as_raw()).map(|(x, y)| *x as f64 - *y as f64);
    let (sum, sum2) = diffs.fold((0.0, 0.0), |(s, s2), d| (s + d, s2 + d * d));
    let m = sum / n as f64;
    Ok(((sum2 / n as f64 - m * m).max(0.0) / 2.0).sqrt())
}

/// Distinct plan poses of the noise runs (work frame, inside the default plan's ranges).
pub fn poses(n: usize) -> Vec<Pose> {
    (0..n)
        .map(|k| Pose::new(-4.0 + 2.0 * (k % 5) as f64, 3.0 - 1.5 * (k % 4) as f64, 0.25 * (k % 3) as f64, -60.0 + 30.0 * (k % 5) as f64))
        .collect()
}

/// Modelled arm seconds per pose of `poses` visited in order from above the plan origin.
pub fn modelled_s_per_pose(profile: &FirmwareProfile, work_frame: &WorkFrame, poses: &[Pose], settle_s: f64, frames: u32) -> f64 {
    if poses.is_empty() {
        return f64::NAN;
    }
    let mut previous = Pose::default();
    let mut total = 0.0;
    for p in poses {
        let (above, contact) = (work_frame.approach_pose(p), work_frame.contact_pose(p));
        total += profile.pose_cost_s(work_frame, &previous, p)
            + profile.motion_time_s(&above, &contact)
            + profile.motion_time_s(&contact, &above)
            + settle_s
            + frames.max(1) as f64 * FRAME_PERIOD_S;
        previous = *p;
    }
    total / poses.len() as f64
}

/// What one collection run measured.
#[derive(Debug, Clone, PartialEq)]
pub struct CollectRun {
    pub noise_levels: f64,
    pub modelled_s_per_pose: f64,
    pub wall_s_per_pose: f64,
}

/// Runs the collection job once with `settle_s` and `frames` (averaged) into `dir`.
pub async fn run_once(config: &BenchConfig, settle_s: f64, frames: u32, dir: &Path) -> Result<CollectRun, BenchError> {
    let kind = SensorKind::ViTacTip;
    let px = config.image_px;
    let mut rig_config = RigConfig::builtin_sim();
    rig_config.arm.backend = ArmBackend::Simulated { time_scale: config.sim_time_scale };
    rig_config.collect = CollectConfig { settle_s, frames_per_pose: frames, average_frames: true, ..CollectConfig::default() };
    rig_config.sensors = vec![SensorConfig {
        name: kind.to_string(),
        backend: SensorBackend::Simulated,
        calibration: None,
        scene: "full".into(),
        width: px,
        height: px,
        camera: CameraSettings { width: px, height: px, ..CameraSettings::default() },
        max_indentation_mm: None,
    }];
    let distinct = poses(config.collect_poses.max(1));
    let plan: Vec<PlannedPose> = distinct
        .iter()
        .enumerate()
        .flat_map(|(k, p)| [PlannedPose { pose_id: 2 * k as u32, pose: *p }, PlannedPose { pose_id: 2 * k as u32 + 1, pose: *p }])
        .collect();
    let visited: Vec<Pose> = plan.iter().map(|p| p.pose).collect();
    let profile = crate::rigs::profile_for(&rig_config)?;
    let modelled = modelled_s_per_pose(&profile, &rig_config.work_frame, &visited, settle_s, frames);

    let object = ObjectChoice::resolve("pacman", None).map_err(crate::rigs::RigError::from)?;
    let clock = crate::rigs::clock_for(&rig_config);
    let mut rig = Rig::open(&rig_config, &object, &SensorSet::one(kind), 0, Arc::clone(&clock)).await?;
    // A fresh dataset per run: the scratch folder of an earlier run would make this a resume.
    let _ = std::fs::remove_dir_all(dir);
    let camera = rig.cameras.pop().ok_or(BenchError::Empty { knob: Knob::Collection, reason: "the simulated rig opened no camera" })?;
    // The collection job itself, writing `<dir>/pacman/vitactip`.
    let setup = CollectSetup {
        object: ObjectInfo { name: object.name.clone(), stl_path: None, stl_sha256: Some(object.sha256.clone()) },
        plan_spec: PlanSpec::default(),
        poses: plan.clone(),
        profile_name: profile.name.clone(),
        work_frame: rig_config.work_frame,
        options: rig_config.collect.clone(),
        out: dir.to_path_buf(),
        resume: false,
        disk_budget_bytes: None,
        arm: crate::jobs::collect::arm_part(&rig_config, &profile),
        modbus: Vec::new(),
        fence: crate::fence::Fence::for_run(profile.clone(), &rig_config, &[kind], crate::fence::PoseSource::Plan),
        adaptive: None,
    };
    let capture = camera.capture_part();
    let feeds = vec![SensorFeed { camera, sensor: kind, calibration: "default".into(), capture }];
    let t_wall = Instant::now();
    let result = crate::jobs::collect::run(&setup, &mut rig.arm, feeds, NoPeripherals, Arc::clone(&clock), Observer::hidden(), None).await;
    let wall_s = t_wall.elapsed().as_secs_f64();
    rig.shutdown().await;
    result?;

    let dataset = setup.dataset_dir(kind);
    let load = |id: u32| -> Result<RgbImage, BenchError> {
        let path = dataset.join(image_rel_path(id));
        image::open(&path).map(|i| i.to_rgb8()).map_err(|e| BenchError::Io { path: path.clone(), source: std::io::Error::other(e) })
    };
    let mut noise = Vec::new();
    for k in 0..distinct.len() as u32 {
        noise.push(pair_noise_levels(&load(2 * k)?, &load(2 * k + 1)?)?);
    }
    let captures = plan.len() as f64;
    Ok(CollectRun { noise_levels: mean(&noise), modelled_s_per_pose: modelled, wall_s_per_pose: wall_s / captures })
}

/// Sweeps the settle time (at the first frame count) and the frames averaged (at the default
/// settle time).
pub async fn measure(config: &BenchConfig, work_dir: &Path) -> Result<KnobReport, BenchError> {
    let default_settle = CollectConfig::default().settle_s;
    let first_frames = config.collect_frames.first().copied().unwrap_or(1);
    let mut rows = Vec::new();
    let mut settle_series = Series { name: format!("settle time ({first_frames} frame)"), ..Default::default() };
    let mut frame_series = Series { name: format!("frames averaged (settle {default_settle} s)"), ..Default::default() };
    // First the settle times at one frame, then the frame counts at the default settle time.
    let by_settle = config
        .collect_settle_s
        .iter()
        .map(|&settle| (settle, first_frames, format!("settle {settle} s, {first_frames} frame(s)"), format!("{settle} s"), true));
    let by_frames = config.collect_frames.iter().map(|&frames| {
        (default_settle, frames, format!("settle {default_settle} s, {frames} frame(s) averaged"), format!("{frames} fr"), false)
    });
    for (k, (settle, frames, label, point, settle_knob)) in by_settle.chain(by_frames).enumerate() {
        let r = run_once(config, settle, frames, &work_dir.join(format!("run{k}"))).await?;
        rows.push(Row { label, values: vec![settle, frames as f64, r.noise_levels, r.modelled_s_per_pose, r.wall_s_per_pose] });
        let series = if settle_knob { &mut settle_series } else { &mut frame_series };
        series.points.push([r.modelled_s_per_pose, r.noise_levels]);
        series.labels.push(point);
    }
    if rows.is_empty() {
        return Err(BenchError::Empty { knob: Knob::Collection, reason: "no settle times or frame counts" });
    }
    Ok(KnobReport {
        knob: Knob::Collection,
        title: "Collection: settle time and frames averaged".into(),
        label_column: "setting".into(),
        columns: vec![
            Column::new("settle [s]", 2),
            Column::new("frames", 0),
            Column::new("noise [levels]", 3),
            Column::new("arm s per pose, modelled", 3),
            Column::new("wall s per capture, sim. rig", 3),
        ],
        rows,
        notes: vec![
            format!(
                "`rig collect`'s job on the built-in simulated rig: simulated MG400 over loopback TCP (clock {}x real time), \
                 one simulated ViTacTip at {px} x {px} px (full scene), object `pacman`, {} poses each captured twice in a row \
                 (retract and re-approach between).",
                config.sim_time_scale,
                config.collect_poses.max(1),
                px = config.image_px
            ),
            "Noise = std of the difference of the two captures of a pose / √2 (one capture's noise, 8-bit levels, all \
             channels), mean over the poses. Averaging n frames should divide it by about √n (8-bit rounding sets a floor)."
                .to_string(),
            format!(
                "*arm s per pose, modelled* = firmware-profile motion time (travel between approach poses, descent, retract) \
                 + settle + frames x {:.1} ms frame period: arm time on a real MG400 at 100 % speed. *wall s per capture* = this \
                 machine's time per capture of the simulated run (scaled clock plus rendering; the reference frame and the \
                 final retract included).",
                FRAME_PERIOD_S * 1e3
            ),
            "The simulated arm has no ringing after arrival: once the settle time covers the end of the move the noise stops \
             changing. A real arm's settle time has to be chosen on the real rig, with this same two-capture measure."
                .to_string(),
        ],
        plot: Plot {
            title: "Collection: image noise against time per pose".into(),
            x_label: "arm s per pose (modelled)".into(),
            y_label: "noise of one capture [8-bit levels]".into(),
            series: vec![settle_series, frame_series],
            lines: true,
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identical_images_have_no_noise() {
        let a = RgbImage::from_fn(8, 8, |x, y| image::Rgb([x as u8 * 9, y as u8 * 7, 100]));
        assert_eq!(pair_noise_levels(&a, &a).unwrap(), 0.0);
    }

    #[test]
    fn noise_of_two_independent_captures_is_recovered() {
        // Each capture = base + independent ±s noise (two-point distribution, std s): the
        // difference has std s√2, so the estimate is s.
        let s = 4.0;
        let base = |x: u32, y: u32| 100.0 + (x * 3 + y) as f64 % 50.0;
        let sign = |k: u64| if crate::sim::sensor::stages::mix64(k) & 1 == 0 { 1.0 } else { -1.0 };
        let capture = |salt: u64| {
            RgbImage::from_fn(64, 64, |x, y| {
                let v = |c: u64| (base(x, y) + s * sign(salt ^ ((y * 64 + x) as u64 * 3 + c) << 8)) as u8;
                image::Rgb([v(0), v(1), v(2)])
            })
        };
        let e = pair_noise_levels(&capture(1), &capture(2)).unwrap();
        assert!((e - s).abs() < 0.2, "{e}");
        // A constant offset between the captures (exposure drift) is not noise.
        let one = capture(1);
        let brighter = RgbImage::from_fn(64, 64, |x, y| {
            let p = one.get_pixel(x, y).0;
            image::Rgb([p[0] + 10, p[1] + 10, p[2] + 10])
        });
        assert!(pair_noise_levels(&one, &brighter).unwrap() < 1e-9);
        assert!(pair_noise_levels(&one, &RgbImage::new(3, 3)).is_err());
    }

    #[test]
    fn modelled_time_grows_with_settle_and_frames() {
        let profile = FirmwareProfile::default_mg400();
        let wf = WorkFrame::default();
        let p = poses(3);
        let base = modelled_s_per_pose(&profile, &wf, &p, 0.0, 1);
        assert!(base.is_finite() && base > 0.0);
        assert!((modelled_s_per_pose(&profile, &wf, &p, 0.5, 1) - base - 0.5).abs() < 1e-9);
        assert!((modelled_s_per_pose(&profile, &wf, &p, 0.0, 4) - base - 3.0 * FRAME_PERIOD_S).abs() < 1e-9);
        assert!(modelled_s_per_pose(&profile, &wf, &[], 0.0, 1).is_nan());
    }
}
