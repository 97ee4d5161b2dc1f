//! The fence in front of the arm: every pose that reaches an arm is checked here first.
//!
//! A pose reaches an arm from a plan (`rig collect`, `--resume`, a daemon `collect` job, `rig
//! bench`), from a dataset's rows (`rig audit`, a daemon `audit` job), or from a calibration's
//! press pattern (`rig calibrate`, `--interactive`, a daemon `calibrate` job, `rig bench`). Each
//! one passes [`Fence::check`] before the arm moves at all: every pose of the run (its approach
//! and contact poses, and the no-contact reference pose above the origin) inside the firmware
//! profile's workspace, and every press within the sensor's press limit. The first pose that is
//! not is refused ([`FenceError`], exit code 2) with its id, its values and the limit it broke.
//!
//! | path | checked when the request is resolved | checked again where the arm is driven |
//! |---|---|---|
//! | plan, `--resume`, daemon collect, bench | `CollectRequest::prepare` | `jobs::collect::run` |
//! | audit (dataset rows), daemon audit | `AuditRequest::prepare` | `jobs::collect::run` |
//! | calibration, daemon calibrate, bench | `CalibrateRequest::prepare` | `run_pattern` and each press of `ArmStation` |
//! | `rig calibrate --interactive` | the pattern | the pattern after the depth question, and each press |
//! | `rig replay` (no arm: the recording answers) | | `jobs::collect::run`, workspace only ([`Fence::replayed`]) |
//!
//! **Indentation.** Plan poses live in the work frame ([`WorkFrame`]): `z_mm` is extra
//! indentation beyond the work frame's `contact_depth_mm`, counted from `origin`, the tool pose
//! at which the sensor tip just touches the object's top. The skin is therefore pressed
//! `contact_depth_mm + z_mm` deep at a pose ([`WorkFrame::press_depth_mm`]), and that is what the press
//! limit bounds ([`PressLimit`]: `[sensors.<name>] max_indentation_mm`, else the sensor's
//! default). Where an object's top rises above the origin's touching point within the plan's x
//! and y, the skin there is pressed deeper by the rise: set the origin on the highest point.
//! A run that presses several sensors (the simulated rig captures all three at once) is
//! bounded by the lowest of their limits.
//!
//! A passed check returns the run's [`Envelope`]: the base-frame ranges the arm will visit and
//! the deepest press against its limit, which the dry runs print.

use std::fmt;

use crate::arm::ArmError;
use crate::arm::profile::FirmwareProfile;
use crate::config::{PressLimit, RigConfig};
use crate::plan::PlannedPose;
use crate::pose::{Pose, WorkFrame, within_press_limit};
use crate::sensor::SensorKind;

/// Where the poses a fence guards come from; names a pose in a refusal.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PoseSource {
    /// A plan's poses (by pose id).
    Plan,
    /// Rows of a dataset's `poses.csv` (by pose id): what `rig audit` presses again.
    DatasetRows,
    /// A calibration's press pattern (by its index).
    Presses,
}

impl PoseSource {
    /// `plan pose 7`, `pose 7 of the dataset's poses.csv`, `calibration press 8`; `None` is the
    /// no-contact reference pose.
    pub fn describe(self, pose_id: Option<u32>) -> String {
        match (self, pose_id) {
            (_, None) => "the no-contact reference pose above the plan origin".to_string(),
            (PoseSource::Plan, Some(id)) => format!("plan pose {id}"),
            (PoseSource::DatasetRows, Some(id)) => format!("pose {id} of the dataset's poses.csv"),
            (PoseSource::Presses, Some(k)) => format!("calibration press {}", u64::from(k) + 1),
        }
    }
}

/// A pose the fence refused, before anything moved.
#[derive(Debug, thiserror::Error)]
pub enum FenceError {
    /// `pose_id` is `None` for the no-contact reference pose above the plan origin.
    #[error("{} {plan_pose} is outside the arm's workspace ({which} pose {base_pose}): {limit}", .poses.describe(*.pose_id))]
    Unreachable { poses: PoseSource, pose_id: Option<u32>, plan_pose: Pose, base_pose: Pose, which: &'static str, limit: String },
    /// The press would indent the skin past the sensor's limit.
    #[error(
        "{} {plan_pose} presses {indentation_mm:.3} mm into the skin (contact depth {contact_depth_mm:.3} mm + z {:.3} mm), beyond {limit}",
        .poses.describe(Some(*.pose_id)), .plan_pose.z_mm
    )]
    TooDeep { poses: PoseSource, pose_id: u32, plan_pose: Pose, indentation_mm: f64, contact_depth_mm: f64, limit: PressLimit },
}

/// The workspace and the press limit every pose of one run must keep to.
#[derive(Debug, Clone)]
pub struct Fence {
    profile: FirmwareProfile,
    /// `None` only for a replay, whose arm is a recording ([`Fence::replayed`]).
    press: Option<PressLimit>,
    poses: PoseSource,
}

impl Fence {
    /// A fence of `profile`'s workspace and `press`, guarding poses from `poses`.
    pub fn new(profile: FirmwareProfile, press: PressLimit, poses: PoseSource) -> Self {
        Self { profile, press: Some(press), poses }
    }

    /// The fence of a run that presses `sensors` on `config`'s rig, within `profile`'s
    /// workspace: the lowest press limit of the sensors (of all three when none is named).
    pub fn for_run(profile: FirmwareProfile, config: &RigConfig, sensors: &[SensorKind], poses: PoseSource) -> Self {
        let kinds = if sensors.is_empty() { &SensorKind::ALL[..] } else { sensors };
        let press = kinds
            .iter()
            .map(|&k| config.press_limit(k))
            .min_by(|a, b| a.max_indentation_mm.total_cmp(&b.max_indentation_mm))
            .unwrap_or_else(|| config.press_limit(SensorKind::ViTac));
        Self::new(profile, press, poses)
    }

    /// The fence of a replayed run: the recorded profile's workspace and no press limit. A
    /// replay's arm is the recording (nothing presses); the recorded run passed its own fence.
    pub fn replayed(profile: FirmwareProfile) -> Self {
        Self { profile, press: None, poses: PoseSource::Plan }
    }

    /// The press limit, `None` for a replay.
    pub fn press_limit(&self) -> Option<PressLimit> {
        self.press
    }

    /// The firmware profile whose workspace bounds the poses.
    pub fn profile(&self) -> &FirmwareProfile {
        &self.profile
    }

    /// Checks every pose of a run in `work_frame`, and the no-contact reference pose above the
    /// origin, before anything moves; returns what the run will visit.
    pub fn check(&self, work_frame: &WorkFrame, poses: &[PlannedPose]) -> Result<Envelope, FenceError> {
        let mut envelope = Envelope::new(self.press);
        let reference = work_frame.approach_pose(&Pose::default());
        self.reachable(None, &Pose::default(), "approach", reference)?;
        envelope.add(&reference);
        for planned in poses {
            let indentation = self.check_pose(work_frame, planned.pose_id, &planned.pose, &mut envelope)?;
            if envelope.deepest.as_ref().is_none_or(|(_, deepest)| indentation > *deepest) {
                envelope.deepest = Some((self.poses.describe(Some(planned.pose_id)), indentation));
            }
        }
        Ok(envelope)
    }

    /// [`check`](Self::check) for a calibration's press offsets, numbered by their index.
    pub fn check_offsets(&self, work_frame: &WorkFrame, offsets: &[Pose]) -> Result<Envelope, FenceError> {
        let poses: Vec<PlannedPose> = offsets.iter().zip(0u32..).map(|(pose, pose_id)| PlannedPose { pose_id, pose: *pose }).collect();
        self.check(work_frame, &poses)
    }

    /// Checks one pose (a press about to be made); for paths that also check each pose as it
    /// comes.
    pub fn check_one(&self, work_frame: &WorkFrame, pose_id: u32, plan_pose: &Pose) -> Result<(), FenceError> {
        self.check_pose(work_frame, pose_id, plan_pose, &mut Envelope::new(self.press)).map(drop)
    }

    /// The press limit, then the workspace of the approach and the contact pose; returns the
    /// indentation.
    fn check_pose(&self, work_frame: &WorkFrame, pose_id: u32, plan_pose: &Pose, envelope: &mut Envelope) -> Result<f64, FenceError> {
        let indentation = work_frame.press_depth_mm(plan_pose);
        if let Some(limit) = self.press
            && !within_press_limit(indentation, limit.max_indentation_mm)
        {
            return Err(FenceError::TooDeep {
                poses: self.poses,
                pose_id,
                plan_pose: *plan_pose,
                indentation_mm: indentation,
                contact_depth_mm: work_frame.contact_depth_mm,
                limit,
            });
        }
        for (which, base_pose) in [("approach", work_frame.approach_pose(plan_pose)), ("contact", work_frame.contact_pose(plan_pose))] {
            self.reachable(Some(pose_id), plan_pose, which, base_pose)?;
            envelope.add(&base_pose);
        }
        Ok(indentation)
    }

    fn reachable(&self, pose_id: Option<u32>, plan_pose: &Pose, which: &'static str, base_pose: Pose) -> Result<(), FenceError> {
        let limit = match self.profile.check_reachable(&base_pose) {
            Ok(()) => return Ok(()),
            Err(ArmError::Unreachable { limit, .. }) => limit,
            Err(other) => other.to_string(),
        };
        Err(FenceError::Unreachable { poses: self.poses, pose_id, plan_pose: *plan_pose, base_pose, which, limit })
    }
}

/// What a run that passed the fence visits: the base-frame ranges of every pose the arm is
/// sent to, and the deepest press against the press limit.
#[derive(Debug, Clone, PartialEq)]
pub struct Envelope {
    pub x_mm: [f64; 2],
    pub y_mm: [f64; 2],
    pub z_mm: [f64; 2],
    pub yaw_deg: [f64; 2],
    /// The deepest press (the pose, named, and its indentation in mm); `None` with no press.
    pub deepest: Option<(String, f64)>,
    /// The press limit it was checked against (`None`: a replay).
    pub limit: Option<PressLimit>,
}

impl Envelope {
    fn new(limit: Option<PressLimit>) -> Self {
        let empty = [f64::INFINITY, f64::NEG_INFINITY];
        Self { x_mm: empty, y_mm: empty, z_mm: empty, yaw_deg: empty, deepest: None, limit }
    }

    fn add(&mut self, p: &Pose) {
        for (range, v) in [(&mut self.x_mm, p.x_mm), (&mut self.y_mm, p.y_mm), (&mut self.z_mm, p.z_mm), (&mut self.yaw_deg, p.yaw_deg)] {
            range[0] = range[0].min(v);
            range[1] = range[1].max(v);
        }
    }

    /// `arm envelope (base frame): x 295.0..305.0 mm, ...` and `deepest press: ...`, the two
    /// lines the dry runs print.
    pub fn lines(&self) -> [String; 2] {
        let r = |[lo, hi]: [f64; 2]| format!("{lo:.1}..{hi:.1}");
        let ranges = format!(
            "arm envelope (base frame): x {} mm, y {} mm, z {} mm, yaw {} deg",
            r(self.x_mm),
            r(self.y_mm),
            r(self.z_mm),
            r(self.yaw_deg)
        );
        let press = match (&self.deepest, &self.limit) {
            (None, _) => "deepest press: none (no press in this run)".to_string(),
            (Some((pose, mm)), Some(limit)) => format!("deepest press: {mm:.3} mm ({pose}), within {limit}"),
            (Some((pose, mm)), None) => format!("deepest press: {mm:.3} mm ({pose})"),
        };
        [ranges, press]
    }
}

impl fmt::Display for Envelope {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let [ranges, press] = self.lines();
        write!(f, "{ranges}\n{press}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn planned(pose_id: u32, z_mm: f64) -> PlannedPose {
        PlannedPose { pose_id, pose: Pose::new(0.0, 0.0, z_mm, 0.0) }
    }

    fn fence(limit_mm: f64) -> Fence {
        let press = PressLimit { sensor: SensorKind::TacTip, max_indentation_mm: limit_mm, configured: true };
        Fence::new(FirmwareProfile::default_mg400(), press, PoseSource::Plan)
    }

    #[test]
    fn a_press_past_the_limit_is_refused_naming_the_pose_and_the_limit() {
        let wf = WorkFrame::default();
        let plan = vec![planned(3, 0.0), planned(7, 1.0), planned(9, 3.6)];
        // 1.5 mm contact depth + 3.6 mm = 5.1 mm, past 5 mm; the deepest before it is 2.5 mm.
        let e = fence(5.0).check(&wf, &plan).unwrap_err();
        assert!(matches!(e, FenceError::TooDeep { pose_id: 9, .. }), "{e}");
        let text = e.to_string();
        assert!(text.starts_with("plan pose 9 (x 0.000 mm, y 0.000 mm, z 3.600 mm, yaw 0.000 deg) presses 5.100 mm"), "{text}");
        assert!(text.contains("contact depth 1.500 mm + z 3.600 mm") && text.contains("tactip's press limit of 5 mm"), "{text}");
        let envelope = fence(5.1).check(&wf, &plan).expect("5.1 mm is within a 5.1 mm limit");
        assert_eq!(envelope.deepest, Some(("plan pose 9".to_string(), 1.5 + 3.6)));
        // The contact depth counts: the same plan in a frame that touches 2 mm deeper.
        let deeper = WorkFrame { contact_depth_mm: 4.5, ..wf };
        assert!(matches!(fence(5.1).check(&deeper, &plan[..2]), Err(FenceError::TooDeep { pose_id: 7, .. })));
        // Not a number is never within a limit.
        assert!(fence(5.0).check(&wf, &[planned(1, f64::NAN)]).is_err());
        // A replay's fence has no press limit but keeps the workspace.
        assert!(Fence::replayed(FirmwareProfile::default_mg400()).check(&wf, &plan).is_ok());
    }

    #[test]
    fn a_pose_outside_the_workspace_is_refused_and_the_envelope_covers_every_visited_pose() {
        let wf = WorkFrame::default();
        let e = fence(5.0).check(
            &WorkFrame { origin: Pose::new(437.0, 0.0, 0.0, 0.0), ..wf },
            &[planned(1, 0.0), { PlannedPose { pose_id: 4, pose: Pose::new(5.0, 0.0, 0.0, 0.0) } }],
        );
        let e = e.unwrap_err();
        assert!(matches!(e, FenceError::Unreachable { pose_id: Some(4), which: "approach", .. }), "{e}");
        assert!(e.to_string().contains("is outside the arm's workspace") && e.to_string().contains("radius"), "{e}");

        let plan = vec![PlannedPose { pose_id: 1, pose: Pose::new(-2.0, 3.0, -1.0, -45.0) }, planned(2, 1.0)];
        let envelope = fence(5.0).check(&wf, &plan).unwrap();
        // Origin (300, 0, -20); approach 10 mm above the touching height, contact 1.5 mm + z below.
        assert_eq!(envelope.x_mm, [298.0, 300.0]);
        assert_eq!(envelope.y_mm, [0.0, 3.0]);
        assert_eq!(envelope.z_mm, [-22.5, -10.0]);
        assert_eq!(envelope.yaw_deg, [-45.0, 0.0]);
        assert_eq!(envelope.deepest, Some(("plan pose 2".to_string(), 2.5)));
        let [ranges, press] = envelope.lines();
        assert_eq!(ranges, "arm envelope (base frame): x 298.0..300.0 mm, y 0.0..3.0 mm, z -22.5..-10.0 mm, yaw -45.0..0.0 deg");
        assert!(press.starts_with("deepest press: 2.500 mm (plan pose 2), within tactip's press limit of 5 mm"), "{press}");
    }

    #[test]
    fn a_run_of_several_sensors_keeps_to_the_lowest_limit() {
        let config = RigConfig::parse("[sensors.tactip]\nmax_indentation_mm = 4.0\n", std::path::Path::new("x")).unwrap();
        let profile = FirmwareProfile::default_mg400();
        let all = Fence::for_run(profile.clone(), &config, &SensorKind::ALL, PoseSource::Plan);
        assert_eq!(all.press_limit().map(|l| (l.sensor, l.max_indentation_mm)), Some((SensorKind::ViTac, 2.5)));
        let tactip = Fence::for_run(profile, &config, &[SensorKind::TacTip], PoseSource::Plan);
        assert_eq!(tactip.press_limit(), Some(PressLimit { sensor: SensorKind::TacTip, max_indentation_mm: 4.0, configured: true }));
        assert_eq!(PoseSource::Presses.describe(Some(0)), "calibration press 1");
        assert_eq!(PoseSource::DatasetRows.describe(Some(12)), "pose 12 of the dataset's poses.csv");
    }
}
