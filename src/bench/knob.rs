//! The knobs `rig bench` measures and what to measure of them ([`BenchConfig`]).

use std::fmt;
use std::path::PathBuf;
use std::str::FromStr;

use crate::synth::SchedulerKind;

/// One knob of the report.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Knob {
    Synthesis,
    Control,
    Collection,
    Calibration,
    PlanOrder,
    Sensor,
    Loops,
    Scale,
    Adaptive,
    AdaptiveScale,
}

impl Knob {
    /// Every knob, in report order.
    pub const ALL: [Knob; 10] = [
        Knob::Synthesis,
        Knob::Control,
        Knob::Collection,
        Knob::Calibration,
        Knob::PlanOrder,
        Knob::Sensor,
        Knob::Loops,
        Knob::Scale,
        Knob::Adaptive,
        Knob::AdaptiveScale,
    ];

    /// The name used on the command line and for the plot file (`<name>.svg`).
    pub fn name(self) -> &'static str {
        match self {
            Knob::Synthesis => "synthesis",
            Knob::Control => "control",
            Knob::Collection => "collection",
            Knob::Calibration => "calibration",
            Knob::PlanOrder => "plan-order",
            Knob::Sensor => "sensor",
            Knob::Loops => "loops",
            Knob::Scale => "scale",
            Knob::Adaptive => "adaptive",
            Knob::AdaptiveScale => "adaptive-scale",
        }
    }
}

impl fmt::Display for Knob {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A knob name that is not one of [`Knob::ALL`].
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error(
    "unknown knob {given:?} (known: synthesis, control, collection, calibration, plan-order, sensor, loops, scale, adaptive, adaptive-scale)"
)]
pub struct KnobParseError {
    pub given: String,
}

impl FromStr for Knob {
    type Err = KnobParseError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let wanted = s.trim().to_ascii_lowercase().replace('_', "-");
        Knob::ALL.into_iter().find(|k| k.name() == wanted).ok_or_else(|| KnobParseError { given: s.to_string() })
    }
}

/// What to measure and how much of it.
#[derive(Debug, Clone, PartialEq)]
pub struct BenchConfig {
    /// Label of the configuration in the report (`quick`, `full`, ...).
    pub label: String,
    /// Knobs to run, in report order.
    pub knobs: Vec<Knob>,
    /// Model package for the synthesis knob.
    pub synth_model: PathBuf,
    /// Poses synthesised per (scheduler, steps) cell.
    pub synth_poses: usize,
    /// Step counts; the largest is the reference the others are compared with.
    pub synth_steps: Vec<usize>,
    pub synth_schedulers: Vec<SchedulerKind>,
    /// Classifier-free guidance of the synthesis runs (1: unguided, as `rig synth --fill-missing`
    /// samples and as models/default was trained).
    pub synth_guidance: f32,
    /// Side of the square control maps and sensor frames, px.
    pub image_px: u32,
    /// Supersampling factors compared...
    pub control_supersample: Vec<u32>,
    /// ...against this one.
    pub control_reference_supersample: u32,
    /// Library objects rendered (each at `control_poses` poses).
    pub control_objects: Vec<String>,
    pub control_poses: usize,
    /// Distinct poses of each collection run (each is captured twice, for the noise measure).
    pub collect_poses: usize,
    /// Settle times compared (at `collect_frames[0]` frames).
    pub collect_settle_s: Vec<f64>,
    /// Frame counts averaged (at the default settle time).
    pub collect_frames: Vec<u32>,
    /// Simulated-rig time scale of the collection and calibration runs.
    pub sim_time_scale: f64,
    /// Side of the calibration sensor's frames, px (the contact detector is tuned for 512).
    pub calib_image_px: u32,
    /// Press grids `(columns, rows)`; `columns * rows` points each.
    pub calib_grids: Vec<(usize, usize)>,
    /// Poses of each plan.
    pub plan_poses: usize,
    pub plan_seeds: Vec<u64>,
    /// Timed frames per sensor-simulator cell (the fastest is reported).
    pub sensor_frames: usize,
    /// Calls per side and round of the inner-loop comparison (the fastest is reported).
    pub loop_repeats: usize,
    /// The Python that runs the inner loops' peers (scikit-image for SSIM); `None` leaves the
    /// peers out.
    pub peer_python: Option<PathBuf>,
    /// Scale: the three plan sizes the ordering (and the adaptive choosing arithmetic) is
    /// measured at, poses.
    pub scale_plan_poses: Vec<usize>,
    /// Scale: the three sizes of the frame stages (collection, verify, merge, export, replay).
    pub scale_frames: Vec<usize>,
    /// Scale: side of the simulated sensor's frames, px.
    pub scale_image_px: u32,
    /// The `rig` executable the scale stages run as child processes; `None`: this executable
    /// (a test sets the binary cargo built).
    pub rig_exe: Option<PathBuf>,
    /// Adaptive collection: the seeds per pose measured, and the model's sampling steps.
    pub adaptive_seeds_per_pose: Vec<usize>,
    pub adaptive_steps: usize,
}

impl BenchConfig {
    /// `rig bench --quick`: everything, with few poses and repetitions (a few minutes).
    pub fn quick(synth_model: PathBuf) -> Self {
        Self {
            label: "quick".into(),
            knobs: Knob::ALL.to_vec(),
            synth_model,
            synth_poses: 1,
            synth_steps: vec![5, 10, 20, 50],
            synth_schedulers: vec![SchedulerKind::Ddim, SchedulerKind::DpmSolverPp2m],
            synth_guidance: 1.0,
            image_px: 512,
            control_supersample: vec![1, 2, 3, 4],
            control_reference_supersample: 8,
            control_objects: vec!["pacman".into(), "cross".into()],
            control_poses: 1,
            collect_poses: 2,
            collect_settle_s: vec![0.0, 0.1, 0.2, 0.5],
            collect_frames: vec![1, 2, 4, 8],
            sim_time_scale: 20.0,
            calib_image_px: 512,
            calib_grids: vec![(2, 2), (3, 2), (3, 3), (4, 4), (5, 5)],
            plan_poses: 500,
            plan_seeds: vec![0],
            sensor_frames: 3,
            loop_repeats: 5,
            peer_python: None,
            scale_plan_poses: vec![1_000, 3_000, 10_000],
            scale_frames: vec![50, 150, 500],
            scale_image_px: 128,
            rig_exe: None,
            adaptive_seeds_per_pose: vec![2],
            adaptive_steps: 5,
        }
    }

    /// `rig bench`: more poses and repetitions than [`quick`](Self::quick).
    pub fn full(synth_model: PathBuf) -> Self {
        Self {
            label: "full".into(),
            synth_poses: 3,
            control_objects: vec!["pacman".into(), "cross".into(), "sphere".into(), "edge".into()],
            control_poses: 3,
            collect_poses: 5,
            plan_seeds: vec![0, 1, 2],
            sensor_frames: 10,
            loop_repeats: 20,
            scale_plan_poses: vec![10_000, 30_000, 100_000],
            scale_frames: vec![500, 1_500, 5_000],
            adaptive_seeds_per_pose: vec![2, 4],
            adaptive_steps: 20,
            ..Self::quick(synth_model)
        }
    }
}
