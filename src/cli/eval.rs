//! `rig eval`: SSIM, PSNR, MSE and pose recoverability of synthetic images against real ones,
//! beside the pose-blind and nearest-neighbour baselines (see [`crate::eval`]); and
//! `rig eval --downstream`, MultiDiffSense's downstream protocol ([`crate::eval::downstream`]).

use std::io::Write;
use std::path::PathBuf;

use anyhow::{Context, bail};
use clap::Args as ClapArgs;

use crate::eval::downstream::{DownstreamOptions, Scale, TrainingSet, downstream};
use crate::eval::regressor::TrainDevice;
use crate::eval::{ContactEstimator, EvalOptions, evaluate};
use crate::sensor::SensorKind;

/// `rig eval` arguments.
#[derive(Debug, ClapArgs)]
pub struct Args {
    /// The true images: a dataset or a folder of `<object>/<sensor>` datasets (captured rows:
    /// `source=real`, or `simulated` from the simulated rig).
    #[arg(long, value_name = "DIR", required_unless_present = "downstream", conflicts_with = "downstream")]
    pub real: Option<PathBuf>,
    /// Their synthetic twins (rows `source=synthetic`), e.g. from `rig synth --poses-of`. With
    /// --downstream: where the synthetic training rows come from (default: the DIR datasets'
    /// own synthetic rows).
    #[arg(long, value_name = "DIR", required_unless_present = "downstream")]
    pub synthetic: Option<PathBuf>,
    /// The collected (training) set: baselines come from it and poses it holds are dropped.
    /// Repeatable; default: the real rows of the --synthetic datasets.
    #[arg(long, value_name = "DIR", conflicts_with = "downstream")]
    pub collected: Vec<PathBuf>,
    /// Only this object of the real and synthetic sides (repeatable; default: all).
    #[arg(long, value_name = "NAME")]
    pub object: Vec<String>,
    /// Every image is resized to N x N px before it is measured (default 128, the default
    /// model's; with --downstream, the regressor's input, default the --scale's).
    #[arg(long, value_name = "N")]
    pub size: Option<u32>,
    /// What the test set is, for the table's heading.
    #[arg(long, value_name = "TEXT", default_value = "test set", conflicts_with = "downstream")]
    pub label: String,
    /// MultiDiffSense's downstream table: per sensor, a pose regressor (ResNet18 layout)
    /// trained on 100% real, 50/50 and 100% synthetic rows of DIR's datasets (captured rows
    /// and `rig synth --fill-missing` rows), scored on held-out real rows (X, Z, yaw).
    #[arg(long, value_name = "DIR")]
    pub downstream: Option<PathBuf>,
    /// With --downstream: `small` (width 8, 32 px, 15 epochs, lr 3e-3: minutes on a CPU) or `paper`
    /// (ResNet18's width 64, 224 px, 100 epochs, AdamW 1e-4: MultiDiffSense's scale).
    #[arg(long, value_enum, default_value_t = Scale::Small, requires = "downstream")]
    pub scale: Scale,
    /// With --downstream: training epochs (default: the --scale's).
    #[arg(long, value_name = "N", requires = "downstream")]
    pub epochs: Option<usize>,
    /// With --downstream: the first stage's channels (ResNet18: 64; default: the --scale's).
    #[arg(long, value_name = "N", requires = "downstream")]
    pub width: Option<usize>,
    /// With --downstream: runs per training set (their spread is the table's ± figure).
    #[arg(long, value_name = "N", default_value_t = 3, requires = "downstream")]
    pub seeds: u32,
    /// With --downstream: the split's seed; run k uses SEED + k.
    #[arg(long, value_name = "SEED", default_value_t = 1, requires = "downstream")]
    pub seed: u64,
    /// With --downstream: rows per training set (default: the smaller of the real training
    /// pool and the synthetic rows).
    #[arg(long, value_name = "N", requires = "downstream")]
    pub train_size: Option<usize>,
    /// With --downstream: only this sensor (repeatable; any case; default: every sensor found).
    #[arg(long, value_name = "SENSOR", requires = "downstream")]
    pub sensor: Vec<SensorKind>,
    /// With --downstream: only these training sets (comma-separated; default: all three).
    #[arg(long, value_enum, value_delimiter = ',', requires = "downstream")]
    pub sets: Vec<TrainingSet>,
    /// With --downstream: the control run: training labels shuffled, so R² should be near 0.
    #[arg(long, requires = "downstream")]
    pub shuffle_labels: bool,
    /// With --downstream: where the regressor trains (`cuda` needs a build with the
    /// `downstream-cuda` feature).
    #[arg(long, value_enum, default_value_t = TrainDevice::Cpu, requires = "downstream")]
    pub device: TrainDevice,
    /// Append the Markdown table to FILE.
    #[arg(long, value_name = "FILE")]
    pub markdown: Option<PathBuf>,
    /// Write the results as JSON to FILE.
    #[arg(long, value_name = "FILE")]
    pub json: Option<PathBuf>,
    /// Write every method's figures on every pair as CSV to FILE (which poses a method gets
    /// wrong; the table's means are over these lines).
    #[arg(long, value_name = "FILE", conflicts_with = "downstream")]
    pub pairs: Option<PathBuf>,
    /// Judge every sensor's images with this contact estimator, BLUR_DIVISOR,REGION_FRACTION
    /// (e.g. 64,0.3), instead of each sensor's own: to choose one for a new sensor on its true
    /// images (tools/tune_estimator.sh).
    #[arg(long, value_name = "DIV,FRAC", value_parser = ContactEstimator::parse, conflicts_with = "downstream")]
    pub estimator: Option<ContactEstimator>,
}

fn require_dir(flag: &str, dir: &std::path::Path) -> anyhow::Result<()> {
    if !dir.is_dir() {
        bail!(crate::cli::usage(&format!("{flag} {}: no such directory", dir.display())));
    }
    Ok(())
}

/// Appends `table` to the --markdown file and writes `json` to the --json file.
fn write_outputs(args: &Args, table: &str, json: impl FnOnce() -> String) -> anyhow::Result<()> {
    if let Some(path) = &args.markdown {
        let mut f =
            std::fs::OpenOptions::new().create(true).append(true).open(path).with_context(|| format!("opening {}", path.display()))?;
        writeln!(f, "{table}").with_context(|| format!("writing {}", path.display()))?;
    }
    if let Some(path) = &args.json {
        std::fs::write(path, json()).with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}

/// Runs `rig eval --downstream`.
fn run_downstream(args: &Args, root: &std::path::Path) -> anyhow::Result<()> {
    crate::features::Feature::Downstream.require("`rig eval --downstream`")?;
    require_dir("--downstream", root)?;
    if let Some(s) = &args.synthetic {
        require_dir("--synthetic", s)?;
    }
    let mut options = DownstreamOptions::at_scale(args.scale);
    if let Some(size) = args.size {
        options.regressor.size_px = size as usize;
    }
    if let Some(epochs) = args.epochs {
        options.regressor.epochs = epochs;
    }
    if let Some(width) = args.width {
        options.regressor.width = width;
    }
    options.seeds = args.seeds;
    options.seed = args.seed;
    options.train_size = args.train_size;
    options.sensors = args.sensor.clone();
    options.objects = args.object.clone();
    options.sets = args.sets.clone();
    options.synthetic_root = args.synthetic.clone();
    options.shuffle_labels = args.shuffle_labels;
    options.device = args.device;
    let report = downstream(root, &options, |line| eprintln!("{line}"))
        .map_err(|e| if e.is_bad_input() { anyhow::Error::new(crate::cli::usage(&e.to_string())) } else { anyhow::Error::new(e) })?;
    let table = report.to_markdown();
    println!("{table}");
    write_outputs(args, &table, || report.to_json())
}

/// Runs `rig eval`.
pub fn run(args: Args) -> anyhow::Result<()> {
    // The outputs are written when the (possibly hours-long) evaluation ends: their folders are
    // checked first.
    for (flag, path) in [("--markdown", &args.markdown), ("--json", &args.json), ("--pairs", &args.pairs)] {
        if let Some(path) = path {
            super::shared::output_folder_exists(flag, path)?;
        }
    }
    if let Some(root) = &args.downstream {
        return run_downstream(&args, root);
    }
    let (Some(real), Some(synthetic)) = (&args.real, &args.synthetic) else {
        bail!(crate::cli::usage("rig eval needs --real and --synthetic (or --downstream DIR)"));
    };
    for (flag, dir) in std::iter::once(("--real", real))
        .chain(std::iter::once(("--synthetic", synthetic)))
        .chain(args.collected.iter().map(|c| ("--collected", c)))
    {
        require_dir(flag, dir)?;
    }
    let options = EvalOptions {
        objects: args.object.clone(),
        estimator: args.estimator,
        ..EvalOptions::at_size(args.size.unwrap_or(128), &args.label)
    };
    // Every evaluation error is bad input: missing, unpaired or inconsistent datasets.
    let report = evaluate(real, synthetic, &args.collected, &options).map_err(|e| anyhow::Error::new(crate::cli::usage(&e.to_string())))?;
    let table = report.to_markdown();
    println!("{table}");
    write_outputs(&args, &table, || report.to_json())?;
    if let Some(path) = &args.pairs {
        let file = std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?;
        report.write_pairs_csv(std::io::BufWriter::new(file)).with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}
