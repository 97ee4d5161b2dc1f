//! Calibration: number of press points against the error of the fitted map against seconds
//! of arm time.
//!
//! Each grid runs the automatic calibration ([`crate::jobs::calibrate::press_and_fit`] over an
//! [`ArmStation`](crate::calibration::press::ArmStation), what
//! `rig calibrate` runs) on the built-in simulated rig, whose TacTip renders through a known
//! ground-truth calibration (anisotropic, rotated, off-centre). The fitted map is compared
//! with the truth over the pressed area ([`map_error_px`]); the fit's own RMS residual is
//! reported beside it. Arm time is modelled from the firmware profile ([`modelled_arm_s`]);
//! the wall time of the simulated run is given beside it (the simulated rig's own clock is
//! not: it runs at a multiple of real time, so rendering time enters it multiplied).

use std::path::Path;
use std::sync::Arc;

use super::collection::FRAME_PERIOD_S;
use super::error::BenchError;
use super::knob::{BenchConfig, Knob};
use super::plot::{Plot, Series};
use super::table::{Column, KnobReport, Row};
use crate::arm::profile::FirmwareProfile;
use crate::calibration::Calibration;
use crate::calibration::press::{Press, PressError, PressPattern, indenter_mesh};
use crate::camera::v4l2::CameraSettings;
use crate::config::{ArmBackend, RigConfig, SensorBackend, SensorConfig};
use crate::geometry::objects::ObjectChoice;
use crate::jobs::calibrate::{PressOutcome, press_and_fit};
use crate::jobs::{JobError, Observer};
use crate::pose::{Pose, WorkFrame};
use crate::rigs::Rig;
use crate::sensor::SensorKind;
use crate::sensor::SensorSet;

/// Half the side of the pressed square, mm (`rig calibrate`'s default span).
pub const HALF_SPAN_MM: f64 = 4.0;

/// The simulated sensor's ground truth for frames of `px` x `px` (the calibration CLI
/// test's truth, scaled): centre off by a few px, 9.4 / 8.6 px/mm at 512 px, turned 6°.
pub fn truth_for(px: u32) -> Calibration {
    let s = px as f64 / 512.0;
    Calibration {
        centre_px: [262.3 * s, 249.1 * s],
        scale_px_per_mm: [9.4 * s, 8.6 * s],
        rotation_deg: 6.0,
        ..Calibration::default_for(px, px)
    }
}

/// `cols` x `rows` presses over ±`half_span_mm` at the contact depth (a single row or
/// column sits on the axis).
pub fn rect_pattern(cols: usize, rows: usize, half_span_mm: f64) -> PressPattern {
    let at = |k: usize, n: usize| if n < 2 { 0.0 } else { -half_span_mm + 2.0 * half_span_mm * k as f64 / (n - 1) as f64 };
    let mut offsets = Vec::new();
    for j in 0..rows {
        for i in 0..cols {
            offsets.push(Pose::new(at(i, cols), at(j, rows), 0.0, 0.0));
        }
    }
    PressPattern { offsets }
}

/// Mean and largest distance, px, between where `fit` and `truth` put sensor-frame points
/// on a 9 x 9 grid over ±`half_span_mm`.
pub fn map_error_px(fit: &Calibration, truth: &Calibration, half_span_mm: f64) -> (f64, f64) {
    let mut d = Vec::new();
    for j in 0..9 {
        for i in 0..9 {
            let (x, y) = (-half_span_mm + half_span_mm * i as f64 / 4.0, -half_span_mm + half_span_mm * j as f64 / 4.0);
            let (a, b) = (fit.mm_to_px(x, y), truth.mm_to_px(x, y));
            d.push((a.0 - b.0).hypot(a.1 - b.1));
        }
    }
    (super::table::mean(&d), d.iter().copied().fold(0.0, f64::max))
}

/// Modelled arm seconds of a run: reference above the origin, then per press travel to
/// above the offset, descent, settle and one frame, retract; finally back above the origin.
pub fn modelled_arm_s(profile: &FirmwareProfile, work_frame: &WorkFrame, pattern: &PressPattern, settle_s: f64) -> f64 {
    let origin_above = work_frame.approach_pose(&Pose::default());
    let mut at = origin_above;
    let mut total = settle_s + FRAME_PERIOD_S;
    for offset in &pattern.offsets {
        let (above, contact) = (work_frame.approach_pose(offset), work_frame.contact_pose(offset));
        total += profile.motion_time_s(&at, &above)
            + profile.motion_time_s(&above, &contact)
            + settle_s
            + FRAME_PERIOD_S
            + profile.motion_time_s(&contact, &above);
        at = above;
    }
    total + profile.motion_time_s(&at, &origin_above)
}

/// What one calibration run gave.
#[derive(Debug, Clone, PartialEq)]
pub struct CalibrationRun {
    pub presses: usize,
    pub detected: usize,
    /// NaN when the fit failed (too few or degenerate points).
    pub map_error_mean_px: f64,
    pub map_error_max_px: f64,
    pub fit_rms_px: f64,
    pub modelled_arm_s: f64,
    pub wall_s: f64,
}

/// One automatic run of `pattern` on a fresh simulated rig.
pub async fn run_once(config: &BenchConfig, pattern: &PressPattern, work_dir: &Path) -> Result<CalibrationRun, BenchError> {
    let px = config.calib_image_px;
    let kind = SensorKind::TacTip;
    let truth = truth_for(px);
    std::fs::create_dir_all(work_dir).map_err(|e| BenchError::io(work_dir, e))?;
    let truth_path = work_dir.join("truth.toml");
    let text = truth.to_toml().map_err(|e| BenchError::Io { path: truth_path.clone(), source: std::io::Error::other(e) })?;
    std::fs::write(&truth_path, text).map_err(|e| BenchError::io(&truth_path, e))?;
    let mut rig_config = RigConfig::builtin_sim();
    rig_config.arm.backend = ArmBackend::Simulated { time_scale: config.sim_time_scale };
    rig_config.sensors = vec![SensorConfig {
        name: kind.to_string(),
        backend: SensorBackend::Simulated,
        calibration: Some(truth_path),
        scene: "full".into(),
        width: px,
        height: px,
        camera: CameraSettings { width: px, height: px, ..CameraSettings::default() },
        max_indentation_mm: None,
    }];
    let profile = crate::rigs::profile_for(&rig_config)?;
    let modelled = modelled_arm_s(&profile, &rig_config.work_frame, pattern, rig_config.collect.settle_s);
    let object = ObjectChoice::built_in("indenter", indenter_mesh());
    let clock = crate::rigs::clock_for(&rig_config);
    let mut rig = Rig::open(&rig_config, &object, &SensorSet::one(kind), 0, Arc::clone(&clock)).await?;
    let camera = rig.cameras.pop().ok_or(BenchError::Empty { knob: Knob::Calibration, reason: "the simulated rig opened no camera" })?;
    let mut detected = 0;
    let mut count = |_: usize, press: &Press| detected += usize::from(press.contact.is_ok());
    let t_wall = std::time::Instant::now();
    let result = press_and_fit(&mut rig.arm, camera, kind, &rig_config, pattern, &Observer::hidden(), &mut count).await;
    let wall_s = t_wall.elapsed().as_secs_f64();
    rig.shutdown().await;
    let (mean_px, max_px, rms_px) = match result {
        Ok(PressOutcome::Fitted { fit, .. }) => {
            let (mean_px, max_px) = map_error_px(&fit.calibration, &truth, HALF_SPAN_MM);
            (mean_px, max_px, fit.rms_px)
        }
        // Too few or degenerate points is a result of this knob, not a failure of the bench.
        Err(JobError::Press(PressError::Fit(_))) => (f64::NAN, f64::NAN, f64::NAN),
        Ok(PressOutcome::Cancelled { .. }) => return Err(BenchError::Empty { knob: Knob::Calibration, reason: "the run was cancelled" }),
        Err(e) => return Err(e.into()),
    };
    Ok(CalibrationRun {
        presses: pattern.offsets.len(),
        detected,
        map_error_mean_px: mean_px,
        map_error_max_px: max_px,
        fit_rms_px: rms_px,
        modelled_arm_s: modelled,
        wall_s,
    })
}

/// One run per configured grid.
pub async fn measure(config: &BenchConfig, work_dir: &Path) -> Result<KnobReport, BenchError> {
    let mut rows = Vec::new();
    let mut series = Series { name: format!("TacTip {} px", config.calib_image_px), ..Default::default() };
    for &(cols, nrows) in &config.calib_grids {
        let pattern = rect_pattern(cols, nrows, HALF_SPAN_MM);
        let r = run_once(config, &pattern, work_dir).await?;
        rows.push(Row {
            label: format!("{cols} x {nrows}"),
            values: vec![
                r.presses as f64,
                r.detected as f64,
                r.map_error_mean_px,
                r.map_error_max_px,
                r.fit_rms_px,
                r.modelled_arm_s,
                r.wall_s,
            ],
        });
        series.points.push([r.modelled_arm_s, r.map_error_mean_px]);
        series.labels.push(format!("{}", r.presses));
    }
    if rows.is_empty() {
        return Err(BenchError::Empty { knob: Knob::Calibration, reason: "no press grids" });
    }
    let t = truth_for(config.calib_image_px);
    Ok(KnobReport {
        knob: Knob::Calibration,
        title: "Calibration: number of points".into(),
        label_column: "grid".into(),
        columns: vec![
            Column::new("points", 0),
            Column::new("detected", 0),
            Column::new("map error, mean [px]", 3),
            Column::new("map error, max [px]", 3),
            Column::new("fit RMS [px]", 3),
            Column::new("arm s, modelled", 1),
            Column::new("wall s, sim. rig", 1),
        ],
        rows,
        notes: vec![
            format!(
                "`rig calibrate`'s automatic run on the built-in simulated rig (clock {}x): a grid of presses of the 8 mm indenter \
                 over ±{HALF_SPAN_MM} mm, TacTip at {px} x {px} px rendering through the ground truth centre ({:.1}, {:.1}) px, \
                 {:.2} / {:.2} px/mm, {:.0}°.",
                config.sim_time_scale,
                t.centre_px[0],
                t.centre_px[1],
                t.scale_px_per_mm[0],
                t.scale_px_per_mm[1],
                t.rotation_deg,
                px = config.calib_image_px
            ),
            format!(
                "Map error = distance between where the fitted and the true calibration put a sensor-frame point, over a 9 x 9 \
                 grid spanning ±{HALF_SPAN_MM} mm (mean and max). Fit RMS = the fit's own residual over its points. Arm s, \
                 modelled = firmware-profile motion times of every move plus settle and one frame per press (a real MG400 at \
                 100 % speed); wall s = this machine's time for the simulated run."
            ),
        ],
        plot: Plot {
            title: "Calibration: map error against arm time".into(),
            x_label: "arm seconds (modelled)".into(),
            y_label: "map error vs truth, mean [px]".into(),
            series: vec![series],
            lines: true,
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rect_pattern_spans_the_square() {
        let p = rect_pattern(3, 2, 4.0);
        assert_eq!(p.offsets.len(), 6);
        assert!(p.offsets.iter().any(|o| o.x_mm == 0.0 && o.y_mm == 4.0));
        assert!(p.offsets.iter().all(|o| o.x_mm.abs() <= 4.0 && o.y_mm.abs() == 4.0));
        assert_eq!(rect_pattern(1, 1, 4.0).offsets, vec![Pose::new(0.0, 0.0, 0.0, 0.0)]);
    }

    #[test]
    fn map_error_is_zero_for_the_truth_and_measures_a_shift() {
        let t = truth_for(512);
        assert_eq!(map_error_px(&t, &t, 4.0), (0.0, 0.0));
        let shifted = Calibration { centre_px: [t.centre_px[0] + 3.0, t.centre_px[1] + 4.0], ..t.clone() };
        let (mean, max) = map_error_px(&shifted, &t, 4.0);
        assert!((mean - 5.0).abs() < 1e-9 && (max - 5.0).abs() < 1e-9);
        // A scale error grows towards the edges of the grid.
        let scaled = Calibration { scale_px_per_mm: [t.scale_px_per_mm[0] * 1.01, t.scale_px_per_mm[1]], ..t.clone() };
        let (mean, max) = map_error_px(&scaled, &t, 4.0);
        assert!(max > mean && (max - 0.01 * 9.4 * 4.0).abs() < 1e-6, "{mean} {max}");
    }

    #[test]
    fn modelled_arm_time_grows_with_presses() {
        let profile = FirmwareProfile::default_mg400();
        let wf = WorkFrame::default();
        let small = modelled_arm_s(&profile, &wf, &rect_pattern(2, 2, 4.0), 0.2);
        let large = modelled_arm_s(&profile, &wf, &rect_pattern(5, 5, 4.0), 0.2);
        assert!(small > 4.0 * 0.2 && large > small * 4.0, "{small} {large}");
    }
}
