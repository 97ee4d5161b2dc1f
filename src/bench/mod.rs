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
//! | inner loops against the code they replaced and their peers | [`loops`] | difference from rig's value | ms per call, ratios |
//! | adaptive collection: seeds per pose | [`adaptive`] | (none: the cost of choosing) | model calls and s per round |
//! | adaptive collection: the choosing arithmetic at three plan sizes | [`adaptive`] | (none: what choosing costs as the plan grows) | s per round, growth exponents |
//! | scale: ordering, collection, verify, merge, LeRobot export, replay at three sizes | [`scale`] | (none: what the work costs as it grows) | wall s and peak memory, growth exponents |
//!
//! Data flow: [`BenchConfig`] (sizes, counts, which knobs) -> one `measure` function per knob
//! -> [`KnobReport`] (columns, rows, a [`plot::Plot`]) -> [`write_report`]. A knob that fails
//! (no ONNX Runtime, say) is reported as failed with its error; the others still run.

// A knob's error is returned once per knob; it keeps the job's error whole (unboxed) so that
// the exit-code table finds it by type in the chain.
#![allow(clippy::result_large_err)]

pub mod adaptive;
pub mod calibration;
pub mod collection;
pub mod control;
mod error;
mod knob;
pub mod loops;
pub mod machine;
pub mod plan_order;
pub mod plot;
pub mod scale;
pub mod sensor;
pub mod synthesis;
mod table;

use std::path::{Path, PathBuf};
use std::time::Instant;

pub use error::BenchError;
pub use knob::{BenchConfig, Knob, KnobParseError};
pub use machine::MachineInfo;
pub use table::{Column, KnobReport, Row};

/// The model package the synthesis knob uses by default: the one `rig synth` uses.
pub use crate::synth::fill::default_model as default_synth_model;

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
            Knob::Loops => loops::measure(config, &work_dir.join("loops")),
            Knob::Scale => scale::measure(config, &work_dir.join("scale")),
            Knob::Adaptive => adaptive::measure(config, &work_dir.join("adaptive")),
            Knob::AdaptiveScale => adaptive::measure_scale(config),
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

#[cfg(test)]
mod tests {
    use super::plot::Plot;
    use super::table::{fastest, mean};
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
