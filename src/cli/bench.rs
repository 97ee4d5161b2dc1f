//! `rig bench`: what accuracy costs in time.
//!
//! ```text
//! rig bench [--quick] [--out DIR] [--only synthesis,control,...] [--model DIR] [--python PATH]
//! ```
//!
//! Measures every knob (see [`crate::bench`]) in one run on this machine and writes
//! `DIR/report.md` with one table and one SVG plot per knob (default `out/bench`). `--quick`
//! uses fewer poses and repetitions (a few minutes). A knob that fails is reported in the file
//! and makes the command exit with status 1 after the report is written.

use std::path::PathBuf;

use anyhow::{Context, bail};
use clap::Args as ClapArgs;

use crate::bench::{BenchConfig, Knob, default_synth_model, write_report};

/// Arguments of `rig bench`.
#[derive(Debug, ClapArgs)]
pub struct Args {
    /// Fewer poses and repetitions: the whole report in a few minutes.
    #[arg(long)]
    pub quick: bool,
    /// Folder for report.md and the plots.
    #[arg(long, default_value = "out/bench")]
    pub out: PathBuf,
    /// Measure only these knobs (comma-separated): synthesis, control, collection, adaptive,
    /// adaptive-scale, calibration, plan-order, sensor, loops, scale.
    #[arg(long, value_delimiter = ',')]
    pub only: Vec<Knob>,
    /// Model package for the synthesis and adaptive knobs (default: models/default if present, else the tiny
    /// test package).
    #[arg(long, value_name = "DIR")]
    pub model: Option<PathBuf>,
    /// A Python with scikit-image, Pillow and numpy (and onnxruntime and tokenizers for the
    /// synthesis row): the loops knob times scikit-image's SSIM and a Python onnxruntime
    /// synthesis loop beside rig's with it (left out without one).
    #[arg(long, value_name = "PATH", env = "RIG_PYTHON")]
    pub python: Option<PathBuf>,
}

/// Runs `rig bench`.
pub fn run(args: Args) -> anyhow::Result<()> {
    let model = args.model.clone().unwrap_or_else(default_synth_model);
    let mut config = if args.quick { BenchConfig::quick(model) } else { BenchConfig::full(model) };
    config.peer_python = args.python.clone();
    if !args.only.is_empty() {
        config.knobs = Knob::ALL.into_iter().filter(|k| args.only.contains(k)).collect();
    }
    let runtime = tokio::runtime::Runtime::new().context("starting the async runtime")?;
    let work = args.out.join("work");
    let report = runtime.block_on(crate::bench::run(&config, &work, |line| eprintln!("bench: {line}")));
    let written = write_report(&report, &args.out).with_context(|| format!("writing the report into {}", args.out.display()))?;
    for path in &written {
        println!("wrote {}", path.display());
    }
    println!("total {:.1} s ({} build)", report.total_s, report.machine.build_profile);
    if !report.failed.is_empty() {
        let names: Vec<&str> = report.failed.iter().map(|(k, _)| k.name()).collect();
        bail!("{} knob(s) could not be measured: {} (see {})", names.len(), names.join(", "), args.out.join("report.md").display());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[test]
    fn parses_quick_out_and_only() {
        let cli = crate::cli::Cli::try_parse_from(["rig", "bench", "--quick", "--out", "o", "--only", "control,plan-order"]).unwrap();
        let crate::cli::Command::Bench(a) = cli.command else { panic!("not bench") };
        assert!(a.quick);
        assert_eq!(a.out, PathBuf::from("o"));
        assert_eq!(a.only, vec![Knob::Control, Knob::PlanOrder]);
        assert!(crate::cli::Cli::try_parse_from(["rig", "bench", "--only", "nope"]).is_err());
    }
}
