//! `rig eval`: SSIM, PSNR, MSE and pose recoverability of synthetic images against real ones,
//! beside the pose-blind and nearest-neighbour baselines (see [`crate::eval`]).

use std::io::Write;
use std::path::PathBuf;

use anyhow::{Context, bail};
use clap::Args as ClapArgs;

use crate::eval::{ContactEstimator, EvalOptions, evaluate};

/// `rig eval` arguments.
#[derive(Debug, ClapArgs)]
pub struct Args {
    /// The true images: a dataset or a folder of `<object>/<sensor>` datasets (captured rows:
    /// `source=real`, or `simulated` from the simulated rig).
    #[arg(long, value_name = "DIR")]
    pub real: PathBuf,
    /// Their synthetic twins (rows `source=synthetic`), e.g. from `rig synth --poses-of`.
    #[arg(long, value_name = "DIR")]
    pub synthetic: PathBuf,
    /// The collected (training) set: baselines come from it and poses it holds are dropped.
    /// Repeatable; default: the real rows of the --synthetic datasets.
    #[arg(long, value_name = "DIR")]
    pub collected: Vec<PathBuf>,
    /// Only this object of the real and synthetic sides (repeatable; default: all).
    #[arg(long, value_name = "NAME")]
    pub object: Vec<String>,
    /// Every image is resized to N x N px before it is measured (128: the default model's).
    #[arg(long, value_name = "N", default_value_t = 128)]
    pub size: u32,
    /// What the test set is, for the table's heading.
    #[arg(long, value_name = "TEXT", default_value = "test set")]
    pub label: String,
    /// Append the Markdown table to FILE.
    #[arg(long, value_name = "FILE")]
    pub markdown: Option<PathBuf>,
    /// Write the results as JSON to FILE.
    #[arg(long, value_name = "FILE")]
    pub json: Option<PathBuf>,
    /// Write every method's figures on every pair as CSV to FILE (which poses a method gets
    /// wrong; the table's means are over these lines).
    #[arg(long, value_name = "FILE")]
    pub pairs: Option<PathBuf>,
    /// Judge every sensor's images with this contact estimator, BLUR_DIVISOR,REGION_FRACTION
    /// (e.g. 64,0.3), instead of each sensor's own: to choose one for a new sensor on its true
    /// images (tools/tune_estimator.sh).
    #[arg(long, value_name = "DIV,FRAC", value_parser = ContactEstimator::parse)]
    pub estimator: Option<ContactEstimator>,
}

/// Runs `rig eval`.
pub fn run(args: Args) -> anyhow::Result<()> {
    for (flag, dir) in std::iter::once(("--real", &args.real))
        .chain(std::iter::once(("--synthetic", &args.synthetic)))
        .chain(args.collected.iter().map(|c| ("--collected", c)))
    {
        if !dir.is_dir() {
            bail!(crate::cli::usage(&format!("{flag} {}: no such directory", dir.display())));
        }
    }
    let options = EvalOptions { objects: args.object.clone(), estimator: args.estimator, ..EvalOptions::at_size(args.size, &args.label) };
    // Every evaluation error is bad input: missing, unpaired or inconsistent datasets.
    let report = evaluate(&args.real, &args.synthetic, &args.collected, &options)
        .map_err(|e| anyhow::Error::new(crate::cli::usage(&e.to_string())))?;
    let table = report.to_markdown();
    println!("{table}");
    if let Some(path) = &args.markdown {
        let mut f =
            std::fs::OpenOptions::new().create(true).append(true).open(path).with_context(|| format!("opening {}", path.display()))?;
        writeln!(f, "{table}").with_context(|| format!("writing {}", path.display()))?;
    }
    if let Some(path) = &args.json {
        std::fs::write(path, report.to_json()).with_context(|| format!("writing {}", path.display()))?;
    }
    if let Some(path) = &args.pairs {
        let file = std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?;
        report.write_pairs_csv(std::io::BufWriter::new(file)).with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}
