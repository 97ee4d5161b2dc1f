//! `rig bench`: what accuracy costs in time, knob by knob, measured in one run.
//!
//! Every knob of rig trades accuracy for time. [`run`] measures each one on this machine and
//! returns a [`BenchReport`]; [`write_report`] writes it as `report.md` with one table and one
//! SVG plot per knob. One file per knob:
//!
//! | knob | module | accuracy | time |
//! |---|---|---|---|
//! | synthesis steps and scheduler | [`synthesis`] | SSIM to the 50-step image and to the simulated sensor | s per image |
//! | control-image supersampling | [`control`] | edge error against an 8x reference | ms per map |
//! | settle time, frames averaged | [`collection`] | image noise between two captures | s per pose (modelled and simulated) |
//! | calibration points | [`calibration`] | map error against the simulated truth | s of arm time |
//! | plan order | [`plan_order`] | (none: same poses) | total motion time |
//! | sensor-simulator stages | [`sensor`] | SSIM to the full scene | ms per frame |
//!
//! Data flow: [`BenchConfig`] (sizes, counts, which knobs) -> one `measure` function per knob
//! -> [`KnobReport`] (columns, rows, a [`plot::Plot`]) -> [`write_report`]. A knob that fails
//! (no ONNX Runtime, say) is reported as failed with its error; the others still run.

// A knob's error is returned once per knob; it keeps the job's error whole (unboxed) so that
// the exit-code table finds it by type in the chain.
#![allow(clippy::result_large_err)]

pub mod calibration;
pub mod collection;
pub mod control;
pub mod machine;
pub mod plan_order;
pub mod plot;
pub mod sensor;
pub mod synthesis;

use std::fmt;
use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::time::Instant;

pub use machine::MachineInfo;
use plot::Plot;

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
}

impl Knob {
    /// Every knob, in report order.
    pub const ALL: [Knob; 6] = [Knob::Synthesis, Knob::Control, Knob::Collection, Knob::Calibration, Knob::PlanOrder, Knob::Sensor];

    /// The name used on the command line and for the plot file (`<name>.svg`).
    pub fn name(self) -> &'static str {
        match self {
            Knob::Synthesis => "synthesis",
            Knob::Control => "control",
            Knob::Collection => "collection",
            Knob::Calibration => "calibration",
            Knob::PlanOrder => "plan-order",
            Knob::Sensor => "sensor",
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
#[error("unknown knob {given:?} (known: synthesis, control, collection, calibration, plan-order, sensor)")]
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
            ..Self::quick(synth_model)
        }
    }
}

/// The model package the synthesis knob uses by default: the one `rig synth` uses.
pub use crate::synth::fill::default_model as default_synth_model;

/// How a table column is printed.
#[derive(Debug, Clone, PartialEq)]
pub struct Column {
    pub name: String,
    /// Digits after the decimal point.
    pub decimals: usize,
}

impl Column {
    pub fn new(name: &str, decimals: usize) -> Self {
        Self { name: name.to_string(), decimals }
    }
}

/// One table row: a label and one number per [`Column`] (NaN prints as `n/a`).
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    pub label: String,
    pub values: Vec<f64>,
}

/// The measurements of one knob.
#[derive(Debug, Clone, PartialEq)]
pub struct KnobReport {
    pub knob: Knob,
    pub title: String,
    /// Header of the label column.
    pub label_column: String,
    pub columns: Vec<Column>,
    pub rows: Vec<Row>,
    /// Markdown lines: what was measured, how, and what to read from it.
    pub notes: Vec<String>,
    pub plot: Plot,
}

impl KnobReport {
    /// The table as Markdown.
    pub fn markdown_table(&self) -> String {
        let mut out = format!("| {} |", self.label_column);
        for c in &self.columns {
            out.push_str(&format!(" {} |", c.name));
        }
        out.push_str("\n|---|");
        for _ in &self.columns {
            out.push_str("---:|");
        }
        out.push('\n');
        for row in &self.rows {
            out.push_str(&format!("| {} |", row.label));
            for (c, v) in self.columns.iter().zip(&row.values) {
                if v.is_finite() {
                    out.push_str(&format!(" {:.*} |", c.decimals, v));
                } else {
                    out.push_str(" n/a |");
                }
            }
            out.push('\n');
        }
        out
    }
}

/// Errors of a bench run or of writing its report.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("plot {path}: {reason}")]
    Plot { path: PathBuf, reason: String },
    #[error("{0}")]
    Rig(#[from] crate::rigs::RigError),
    #[error("{0}")]
    Collect(#[from] crate::collect::CollectError),
    #[error("{0}")]
    Job(#[from] crate::jobs::JobError),
    #[error("{0}")]
    Dataset(#[from] crate::dataset::DatasetError),
    #[error("{0}")]
    Press(#[from] crate::calibration::press::PressError),
    #[error("{0}")]
    Synth(#[from] crate::synth::SynthError),
    #[error("{0}")]
    Plan(#[from] crate::plan::PlanError),
    #[error("{0}")]
    Metrics(#[from] crate::metrics::MetricsError),
    #[error("{0}")]
    Object(#[from] crate::geometry::objects::ObjectError),
    #[error("{knob}: nothing to measure ({reason})")]
    Empty { knob: Knob, reason: &'static str },
}

impl BenchError {
    fn io(path: &Path, source: std::io::Error) -> Self {
        Self::Io { path: path.to_path_buf(), source }
    }
}

/// A finished run: the machine, every knob measured (or why not), the total time.
#[derive(Debug)]
pub struct BenchReport {
    pub config: BenchConfig,
    pub machine: MachineInfo,
    pub knobs: Vec<KnobReport>,
    /// Knobs that failed, with the error.
    pub failed: Vec<(Knob, BenchError)>,
    pub total_s: f64,
}

/// Measures every knob of `config`. `work_dir` holds the scratch datasets of the collection
/// runs (removed afterwards); `progress` is told which knob starts.
pub async fn run(config: &BenchConfig, work_dir: &Path, mut progress: impl FnMut(&str)) -> BenchReport {
    let start = Instant::now();
    let machine = MachineInfo::collect();
    let mut knobs = Vec::new();
    let mut failed = Vec::new();
    for &knob in &config.knobs {
        progress(&format!("{knob}: measuring"));
        let t = Instant::now();
        let result = match knob {
            Knob::Synthesis => synthesis::measure(config),
            Knob::Control => control::measure(config),
            Knob::Collection => collection::measure(config, &work_dir.join("collection")).await,
            Knob::Calibration => calibration::measure(config, &work_dir.join("calibration")).await,
            Knob::PlanOrder => plan_order::measure(config),
            Knob::Sensor => sensor::measure(config),
        };
        match result {
            Ok(report) => {
                progress(&format!("{knob}: done in {:.1} s", t.elapsed().as_secs_f64()));
                knobs.push(report);
            }
            Err(e) => {
                progress(&format!("{knob}: failed: {e}"));
                failed.push((knob, e));
            }
        }
    }
    // Scratch data only; a leftover directory is harmless, so failing to remove it is not an error.
    let _ = std::fs::remove_dir_all(work_dir);
    BenchReport { config: config.clone(), machine, knobs, failed, total_s: start.elapsed().as_secs_f64() }
}

/// Writes `report.md` and one `<knob>.svg` per measured knob into `dir` (created); returns
/// the paths written.
pub fn write_report(report: &BenchReport, dir: &Path) -> Result<Vec<PathBuf>, BenchError> {
    std::fs::create_dir_all(dir).map_err(|e| BenchError::io(dir, e))?;
    let mut written = Vec::new();
    let mut md = String::new();
    md.push_str("# rig bench: what accuracy costs in time\n\n");
    md.push_str(&report.machine.markdown());
    md.push_str(&format!(
        "- configuration: `{}` ({}); total run time {:.1} s\n",
        report.config.label,
        report.config.knobs.iter().map(|k| k.name()).collect::<Vec<_>>().join(", "),
        report.total_s
    ));
    md.push_str(
        "- every figure of this report was measured in this one run, on this machine; times are wall \
         time unless a column says *modelled*. Plots: SVG drawn with `plotters` built \
         without default features (SVG backend, line and point series only), to keep rig's build time down.\n\n",
    );
    for k in &report.knobs {
        md.push_str(&format!("## {}\n\n", k.title));
        for n in &k.notes {
            md.push_str(n);
            md.push_str("\n\n");
        }
        md.push_str(&k.markdown_table());
        let svg = dir.join(format!("{}.svg", k.knob.name()));
        plot::write_svg(&k.plot, &svg)?;
        md.push_str(&format!("\n![{}]({}.svg)\n\n", k.title, k.knob.name()));
        written.push(svg);
    }
    for (knob, e) in &report.failed {
        md.push_str(&format!("## {knob}: not measured\n\n{e}\n\n"));
    }
    let path = dir.join("report.md");
    std::fs::write(&path, md).map_err(|e| BenchError::io(&path, e))?;
    written.insert(0, path);
    Ok(written)
}

/// Mean of a slice (NaN when empty).
pub(crate) fn mean(v: &[f64]) -> f64 {
    if v.is_empty() { f64::NAN } else { v.iter().sum::<f64>() / v.len() as f64 }
}

/// Smallest value of a slice (NaN when empty): the timing least disturbed by other load.
pub(crate) fn fastest(v: &[f64]) -> f64 {
    v.iter().copied().fold(f64::NAN, f64::min)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn knob_names_round_trip() {
        for k in Knob::ALL {
            assert_eq!(k.name().parse::<Knob>(), Ok(k));
        }
        assert_eq!("plan_order".parse::<Knob>(), Ok(Knob::PlanOrder));
        assert!("speed".parse::<Knob>().is_err());
    }

    #[test]
    fn table_prints_decimals_and_na() {
        let k = KnobReport {
            knob: Knob::PlanOrder,
            title: "t".into(),
            label_column: "order".into(),
            columns: vec![Column::new("a [s]", 1), Column::new("b", 3)],
            rows: vec![Row { label: "x".into(), values: vec![1.25, f64::NAN] }],
            notes: vec![],
            plot: Plot::default(),
        };
        let t = k.markdown_table();
        assert!(t.contains("| order | a [s] | b |"), "{t}");
        assert!(t.contains("| x | 1.2 | n/a |") || t.contains("| x | 1.3 | n/a |"), "{t}");
    }

    #[test]
    fn fastest_and_mean() {
        assert_eq!(fastest(&[3.0, 1.0, 2.0]), 1.0);
        assert!(fastest(&[]).is_nan());
        assert_eq!(mean(&[1.0, 3.0]), 2.0);
    }
}
