//! The automatic calibration run: press an indenter at a pattern of offsets, detect, fit.
//!
//! A [`PressStation`] is what the run (and the interactive [`super::wizard`]) needs from the
//! rig: a no-contact reference frame, and a press at a work-frame offset that returns what the
//! camera saw. [`ArmStation`] implements it over the [`Arm`] and [`Camera`] seams with the
//! steps the collection job is built of ([`move_and_wait`], [`capture_settled`]): move above,
//! descend, wait for arrival, settle, capture, retract. So the same run calibrates the
//! simulated rig and a real bench. Before the reference frame, the run hands the whole pattern
//! to [`PressStation::check_pattern`]: [`ArmStation`] passes it through its [`Fence`] (the
//! workspace, the sensor's press limit) and presses only offsets of a pattern that passed.
//!
//! Each detected press gives one [`FitPoint`]: the indenter's position in the sensor frame
//! (the negated measured work-frame offset turned by the yaw, the render convention of
//! [`crate::geometry::raster`]), the press depth at arrival (the skin indentation: the
//! measured extra indentation plus the work frame's contact depth, which the depth-dependent
//! scale is fitted against) and the detected centroid in px. [`run_pattern`] presses the whole
//! [`PressPattern`] (a grid at the contact depth and 3 x 3 layers at other depths) and hands
//! the points to [`fit_points`].

use std::future::Future;
use std::ops::ControlFlow;
use std::time::Duration;

use image::RgbImage;

use super::FitPoint;
use super::detect::{Contact, ContactDetector, DetectError};
use super::fit::{FitError, FitOptions, PointFit, fit_points};
use crate::arm::{Arm, ArmError, MoveKind, move_and_wait};
use crate::camera::{Camera, CameraError, capture_settled};
use crate::config::CollectConfig;
use crate::fence::{Fence, FenceError};
use crate::geometry::stl::Mesh;
use crate::pose::{Pose, WorkFrame};

/// Radius of the calibration indenter, mm. Large enough that its dent moves a few dozen
/// markers of a TacTip (whose displacement field locates it to a fraction of a pixel), small
/// enough that its imprint stays inside the field of view over the press pattern.
pub const INDENTER_RADIUS_MM: f32 = 8.0;

/// The calibration indenter: a sphere of [`INDENTER_RADIUS_MM`] whose top is at the library
/// objects' top height, so it presses like them.
pub fn indenter_mesh() -> Mesh {
    let top = crate::geometry::shapes::TOP_MM;
    crate::geometry::shapes::sphere_mesh(glam::Vec3::new(0.0, 0.0, top - INDENTER_RADIUS_MM), INDENTER_RADIUS_MM, 32, 64)
}

/// Errors that stop a run (a press that sees no contact is not one: it is reported per press).
#[derive(Debug, thiserror::Error)]
pub enum PressError {
    #[error(transparent)]
    Arm(#[from] ArmError),
    #[error(transparent)]
    Camera(#[from] CameraError),
    #[error("press requested before the no-contact reference frame was taken")]
    NoReference,
    #[error("fit: {0}")]
    Fit(#[from] FitError),
    #[error("cancelled after {done} of {total} presses (the arm retracted; no calibration fitted)")]
    Cancelled { done: usize, total: usize },
    /// A press outside the workspace or past the press limit, refused before anything moved.
    #[error(transparent)]
    Fence(#[from] FenceError),
    /// A press asked for at an offset of no pattern that passed the fence (a caller that
    /// skipped [`PressStation::check_pattern`]).
    #[error("press at {offset} refused: it is not in a press pattern checked against the workspace and the press limit")]
    Unchecked { offset: Pose },
}

/// Offsets (work frame, `z_mm` = extra indentation) the run presses at.
#[derive(Debug, Clone, PartialEq)]
pub struct PressPattern {
    pub offsets: Vec<Pose>,
}

impl PressPattern {
    /// An `n x n` grid over `±half_span_mm` at the contact depth, plus a 3 x 3 layer (centre,
    /// edge midpoints, corners) at each extra indentation in `extra_depths_mm`: the depth term
    /// ([`super::fit::DepthTerm`]) is conditioned by off-centre presses at other depths, the
    /// further out the better.
    pub fn grid(n: usize, half_span_mm: f64, extra_depths_mm: &[f64]) -> Self {
        let n = n.max(2);
        let at = |k: usize| -half_span_mm + 2.0 * half_span_mm * k as f64 / (n - 1) as f64;
        let mut offsets = Vec::new();
        for j in 0..n {
            for i in 0..n {
                offsets.push(Pose::new(at(i), at(j), 0.0, 0.0));
            }
        }
        Self { offsets }.with_extra_depths(extra_depths_mm)
    }

    /// The half span of the presses at the contact depth, mm (their largest |x| or |y|).
    pub fn half_span_mm(&self) -> f64 {
        self.offsets.iter().filter(|o| o.z_mm == 0.0).fold(0.0, |m, o| m.max(o.x_mm.abs()).max(o.y_mm.abs()))
    }

    /// The same presses at the contact depth, with the depth layers replaced by a 3 x 3 layer
    /// over the same half span at each of `extra_depths_mm` (0 and non-finite entries are
    /// dropped). The wizard uses it when the user gives other depths.
    pub fn with_extra_depths(&self, extra_depths_mm: &[f64]) -> Self {
        let half = self.half_span_mm();
        let mut offsets: Vec<Pose> = self.offsets.iter().copied().filter(|o| o.z_mm == 0.0).collect();
        for &dz in extra_depths_mm.iter().filter(|d| d.is_finite() && **d != 0.0) {
            for (x, y) in [(0.0, 0.0), (-1.0, -1.0), (0.0, -1.0), (1.0, -1.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0), (-1.0, 1.0), (-1.0, 0.0)]
            {
                offsets.push(Pose::new(x * half, y * half, dz, 0.0));
            }
        }
        Self { offsets }
    }

    /// The extra indentations pressed, mm, in order of first appearance.
    pub fn extra_depths_mm(&self) -> Vec<f64> {
        let mut depths: Vec<f64> = Vec::new();
        for o in self.offsets.iter().filter(|o| o.z_mm != 0.0) {
            if !depths.contains(&o.z_mm) {
                depths.push(o.z_mm);
            }
        }
        depths
    }
}

impl Default for PressPattern {
    /// 5 x 5 over ±4 mm, and a 3 x 3 layer each 0.5 mm shallower and deeper (43 presses).
    fn default() -> Self {
        Self::grid(5, 4.0, &[-0.5, 0.5])
    }
}

/// What one press saw.
#[derive(Debug, Clone, PartialEq)]
pub struct Press {
    /// The commanded offset.
    pub offset: Pose,
    /// The measured offset at arrival (work frame; `z_mm` is the indentation beyond the
    /// work frame's contact depth).
    pub measured: Pose,
    /// The press depth (skin indentation) at arrival, mm: the measured `z_mm` plus the
    /// contact depth, the `z_mm` of the object pose the sensor sees.
    pub depth_mm: f64,
    /// The detection, or why there was none.
    pub contact: Result<Contact, DetectError>,
}

impl Press {
    /// The fit correspondence, if the contact was found.
    pub fn point(&self) -> Option<FitPoint> {
        let c = self.contact.as_ref().ok()?;
        Some(FitPoint { mm: sensor_point_mm(&self.measured), px: c.centroid_px, depth_mm: self.depth_mm })
    }
}

/// Where the object's reference point lies in the sensor frame when the sensor is at
/// `offset` (render convention: the object appears at minus the offset, turned by -yaw).
pub fn sensor_point_mm(offset: &Pose) -> [f64; 2] {
    let (s, c) = (-offset.yaw_deg).to_radians().sin_cos();
    let (x, y) = (-offset.x_mm, -offset.y_mm);
    [c * x - s * y, s * x + c * y]
}

/// What a calibration run needs from the rig.
pub trait PressStation {
    /// Refuses `pattern` when a press of it lies outside the workspace or past the press
    /// limit; called before anything moves (a press whose pattern did not pass is refused).
    fn check_pattern(&mut self, pattern: &PressPattern) -> Result<(), PressError>;
    /// Takes the no-contact reference frame.
    fn take_reference(&mut self) -> impl Future<Output = Result<(), PressError>>;
    /// Presses at `offset` and detects the contact.
    fn press(&mut self, offset: Pose) -> impl Future<Output = Result<Press, PressError>>;
    /// Leaves the rig safe (retracted, disabled).
    fn finish(&mut self) -> impl Future<Output = Result<(), PressError>>;
}

/// [`PressStation`] over an arm and one camera.
pub struct ArmStation<'a, A: Arm, C: Camera> {
    pub arm: &'a mut A,
    pub camera: C,
    pub work_frame: WorkFrame,
    pub options: CollectConfig,
    pub detector: ContactDetector,
    /// The no-contact frame, once [`PressStation::take_reference`] has run.
    pub reference: Option<RgbImage>,
    /// The workspace and the press limit of the sensor being calibrated.
    fence: Fence,
    /// The offsets of the last pattern that passed the fence: the only ones pressed.
    checked: Vec<Pose>,
}

impl<'a, A: Arm, C: Camera> ArmStation<'a, A, C> {
    /// A station that presses within `fence` (no pattern checked yet).
    pub fn new(arm: &'a mut A, camera: C, work_frame: WorkFrame, options: CollectConfig, detector: ContactDetector, fence: Fence) -> Self {
        Self { arm, camera, work_frame, options, detector, reference: None, fence, checked: Vec::new() }
    }

    fn timeout(&self) -> Duration {
        Duration::from_secs_f64(self.options.move_timeout_s)
    }
}

impl<A: Arm, C: Camera> PressStation for ArmStation<'_, A, C> {
    fn check_pattern(&mut self, pattern: &PressPattern) -> Result<(), PressError> {
        self.checked.clear();
        self.fence.check_offsets(&self.work_frame, &pattern.offsets)?;
        self.checked = pattern.offsets.clone();
        Ok(())
    }

    async fn take_reference(&mut self) -> Result<(), PressError> {
        self.arm.enable().await?;
        let above = self.work_frame.approach_pose(&Pose::default());
        let timeout = self.timeout();
        let arrival = move_and_wait(&mut *self.arm, above, MoveKind::Joint, timeout).await?;
        let (image, _) = capture_settled(&mut self.camera, arrival.t_s + self.options.settle_s, self.options.capture_settings()).await?;
        self.reference = Some(image);
        Ok(())
    }

    async fn press(&mut self, offset: Pose) -> Result<Press, PressError> {
        // Only an offset of the checked pattern, checked again in the work frame it is pressed
        // in: nothing reaches the arm around the fence.
        let Some(k) = self.checked.iter().position(|o| *o == offset) else {
            return Err(PressError::Unchecked { offset });
        };
        self.fence.check_one(&self.work_frame, u32::try_from(k).unwrap_or(u32::MAX), &offset)?;
        let timeout = self.timeout();
        let above = self.work_frame.approach_pose(&offset);
        let contact_pose = self.work_frame.contact_pose(&offset);
        move_and_wait(&mut *self.arm, above, MoveKind::Joint, timeout).await?;
        let arrival = move_and_wait(&mut *self.arm, contact_pose, MoveKind::Linear, timeout).await?;
        let (image, _) = capture_settled(&mut self.camera, arrival.t_s + self.options.settle_s, self.options.capture_settings()).await?;
        move_and_wait(&mut *self.arm, above, MoveKind::Linear, timeout).await?;
        let reference = self.reference.as_ref().ok_or(PressError::NoReference)?;
        let contact = self.detector.detect(&image, reference);
        let measured = self.work_frame.plan_pose(&arrival.measured);
        let depth_mm = measured.z_mm + self.work_frame.contact_depth_mm;
        Ok(Press { offset, measured, depth_mm, contact })
    }

    async fn finish(&mut self) -> Result<(), PressError> {
        let above = self.work_frame.approach_pose(&Pose::default());
        let timeout = self.timeout();
        move_and_wait(&mut *self.arm, above, MoveKind::Linear, timeout).await?;
        self.arm.disable().await?;
        Ok(())
    }
}

/// A finished automatic run.
#[derive(Debug, Clone)]
pub struct PatternRun {
    pub presses: Vec<Press>,
    pub fit: PointFit,
}

/// Checks `pattern` ([`PressStation::check_pattern`]), takes the reference, presses every
/// offset, fits. `on_press` sees each press as it happens (progress output).
pub async fn run_pattern<S: PressStation>(
    station: &mut S,
    pattern: &PressPattern,
    fit_options: &FitOptions,
    mut on_press: impl FnMut(usize, &Press) -> ControlFlow<()>,
) -> Result<PatternRun, PressError> {
    station.check_pattern(pattern)?;
    station.take_reference().await?;
    let total = pattern.offsets.len();
    let mut presses = Vec::with_capacity(total);
    for (k, offset) in pattern.offsets.iter().enumerate() {
        let press = station.press(*offset).await?;
        let flow = on_press(k, &press);
        presses.push(press);
        if flow.is_break() && k + 1 < total {
            station.finish().await?;
            return Err(PressError::Cancelled { done: k + 1, total });
        }
    }
    station.finish().await?;
    let points: Vec<FitPoint> = presses.iter().filter_map(Press::point).collect();
    let fit = fit_points(&points, fit_options, "indenter-pattern")?;
    Ok(PatternRun { presses, fit })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pattern_covers_the_grid_and_depths() {
        let p = PressPattern::default();
        assert_eq!(p.offsets.len(), 25 + 18);
        assert!(p.offsets.iter().any(|o| o.x_mm == -4.0 && o.y_mm == 4.0));
        assert_eq!(p.offsets.iter().filter(|o| o.z_mm != 0.0).count(), 18);
        assert!(p.offsets.iter().any(|o| o.x_mm == 4.0 && o.y_mm == 0.0 && o.z_mm == -0.5));
        assert_eq!(p.half_span_mm(), 4.0);
        assert_eq!(p.extra_depths_mm(), vec![-0.5, 0.5]);
        let other = p.with_extra_depths(&[1.0, 0.0, f64::NAN]);
        assert_eq!(other.offsets.len(), 25 + 9);
        assert_eq!(other.extra_depths_mm(), vec![1.0]);
        assert_eq!(p.with_extra_depths(&[]).offsets.len(), 25);
    }

    /// A camera that sees a blank skin.
    struct BlankCamera;

    impl Camera for BlankCamera {
        fn name(&self) -> &str {
            "tactip"
        }
        async fn frame_after(&mut self, not_before_s: f64) -> Result<crate::camera::Frame, CameraError> {
            Ok(crate::camera::Frame { image: RgbImage::new(8, 8), t_capture_s: not_before_s, seq: 0 })
        }
    }

    /// The station presses only offsets of a pattern that passed its fence: a pattern deeper
    /// than the limit is refused before the arm is enabled or moved, and so is a press at an
    /// offset no checked pattern holds.
    #[tokio::test]
    async fn the_station_presses_only_within_a_checked_pattern() {
        use crate::config::PressLimit;
        use crate::fence::PoseSource;
        use crate::sensor::SensorKind;
        let mut arm = crate::arm::fake::CountingArm::default();
        let limit = PressLimit { sensor: SensorKind::ViTac, max_indentation_mm: 2.5, configured: false };
        let fence = Fence::new(crate::arm::profile::FirmwareProfile::default_mg400(), limit, PoseSource::Presses);
        let detector = ContactDetector::for_sensor(SensorKind::ViTac, 8);
        let options = CollectConfig { settle_s: 0.0, ..CollectConfig::default() };
        let mut station = ArmStation::new(&mut arm, BlankCamera, WorkFrame::default(), options, detector, fence);
        // 1.5 mm contact depth + 1.5 mm: 3 mm, past 2.5 mm.
        let deep = PressPattern::grid(2, 2.0, &[1.5]);
        let e = run_pattern(&mut station, &deep, &FitOptions::default(), |_, _| ControlFlow::Continue(())).await.unwrap_err();
        assert!(matches!(e, PressError::Fence(FenceError::TooDeep { pose_id: 4, .. })), "{e}");
        assert!(matches!(station.press(Pose::default()).await, Err(PressError::Unchecked { .. })));
        let shallow = PressPattern::grid(2, 2.0, &[0.5]);
        station.check_pattern(&shallow).expect("2 mm is within 2.5 mm");
        assert!(matches!(station.press(Pose::new(9.0, 0.0, 0.0, 0.0)).await, Err(PressError::Unchecked { .. })));
        drop(station);
        assert_eq!((arm.enables, arm.moves), (0, 0), "nothing moved");
    }

    #[test]
    fn sensor_point_is_the_negated_offset_turned_by_yaw() {
        assert_eq!(sensor_point_mm(&Pose::new(2.0, -1.0, 0.0, 0.0)), [-2.0, 1.0]);
        let p = sensor_point_mm(&Pose::new(1.0, 0.0, 0.0, 90.0));
        assert!((p[0] - 0.0).abs() < 1e-12 && (p[1] - 1.0).abs() < 1e-12, "{p:?}");
    }
}
