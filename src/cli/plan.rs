//! `rig plan show`: prints a plan's grid, its sampled poses and the motion time before and
//! after ordering. [`PlanFlags`] is the shared set of plan flags (`rig collect` and `rig synth`
//! flatten it into their own arguments).

use std::path::PathBuf;

use anyhow::Context;

use crate::plan::{AxisRange, Order, PlanSpec, Sampling, TrapezoidMotionModel};
use crate::pose::Pose;

/// Plan file and per-field overrides. Flags override the file; without a file they override
/// [`PlanSpec::default`] (the paper's ranges).
#[derive(Debug, Clone, Default, clap::Args)]
pub struct PlanFlags {
    /// Plan TOML file (see plans/default.toml).
    #[arg(long = "plan", value_name = "FILE")]
    pub plan_file: Option<PathBuf>,
    /// x range in mm, min:max:step.
    #[arg(long = "x", value_name = "MIN:MAX:STEP", allow_hyphen_values = true)]
    pub x_mm: Option<AxisRange>,
    /// y range in mm, min:max:step.
    #[arg(long = "y", value_name = "MIN:MAX:STEP", allow_hyphen_values = true)]
    pub y_mm: Option<AxisRange>,
    /// z (extra indentation) range in mm, min:max:step.
    #[arg(long = "z", value_name = "MIN:MAX:STEP", allow_hyphen_values = true)]
    pub z_mm: Option<AxisRange>,
    /// yaw range in degrees, min:max:step.
    #[arg(long = "yaw", value_name = "MIN:MAX:STEP", allow_hyphen_values = true)]
    pub yaw_deg: Option<AxisRange>,
    /// full, random or lhs.
    #[arg(long)]
    pub sampling: Option<Sampling>,
    /// Number of poses to sample (random, lhs).
    #[arg(long = "n")]
    pub n_poses: Option<usize>,
    /// Sampler seed.
    #[arg(long)]
    pub seed: Option<u64>,
    /// as-sampled, random or optimised.
    #[arg(long)]
    pub order: Option<Order>,
}

impl PlanFlags {
    /// The validated plan these flags describe.
    pub fn resolve(&self) -> anyhow::Result<PlanSpec> {
        let mut spec = match &self.plan_file {
            Some(path) => PlanSpec::load(path)?,
            None => PlanSpec::default(),
        };
        if let Some(r) = self.x_mm {
            spec.x_mm = r;
        }
        if let Some(r) = self.y_mm {
            spec.y_mm = r;
        }
        if let Some(r) = self.z_mm {
            spec.z_mm = r;
        }
        if let Some(r) = self.yaw_deg {
            spec.yaw_deg = r;
        }
        if let Some(s) = self.sampling {
            spec.sampling = s;
            // `full` takes no count; a count from the file or default would only be refused.
            if s == Sampling::Full && self.n_poses.is_none() {
                spec.n_poses = None;
            }
        }
        if let Some(n) = self.n_poses {
            spec.n_poses = Some(n);
        }
        if let Some(seed) = self.seed {
            spec.seed = seed;
        }
        if let Some(o) = self.order {
            spec.order = o;
        }
        spec.validate().context("invalid plan")?;
        Ok(spec)
    }
}

/// `rig plan ...`
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    pub command: PlanCommand,
}

#[derive(Debug, clap::Subcommand)]
pub enum PlanCommand {
    /// Print the grid size, the sampled poses in visiting order and the motion time before
    /// and after ordering (stand-in trapezoid model: 100 mm/s, 180 deg/s, 0.4 s per pose).
    #[command(after_help = crate::cli::examples::PLAN_SHOW)]
    Show {
        #[command(flatten)]
        plan: PlanFlags,
        /// Print only the summary, not the poses.
        #[arg(long)]
        summary: bool,
        /// Show the rounds of the adaptive collection in this dataset (its manifest's plan and
        /// choices) instead of a plan.
        #[arg(long, value_name = "DATASET", conflicts_with_all = ["plan_file", "x_mm", "y_mm", "z_mm", "yaw_deg", "sampling", "n_poses", "seed", "order"])]
        rounds: Option<PathBuf>,
        /// With --rounds: draw the plan's poses, coloured by the round that pressed them, as
        /// an SVG scatter.
        #[arg(long, value_name = "FILE", requires = "rounds")]
        svg: Option<PathBuf>,
        /// With --svg: the two axes of the picture (of x, y, z, yaw).
        #[arg(long, value_name = "A,B", default_value = "x,y", requires = "svg")]
        axes: String,
    },
}

pub fn run(args: Args) -> anyhow::Result<()> {
    match args.command {
        PlanCommand::Show { rounds: Some(dataset), svg, axes, .. } => show_rounds(&dataset, svg.as_deref(), &axes),
        PlanCommand::Show { plan, summary, .. } => show(&plan, summary),
    }
}

fn show(flags: &PlanFlags, summary: bool) -> anyhow::Result<()> {
    let spec = flags.resolve()?;
    let model = TrapezoidMotionModel::default();
    let cost = move |a: &Pose, b: &Pose| model.time_s(a, b);
    let plan = spec.build(&cost)?;
    let [nx, ny, nz, nyaw] = spec.axis_counts();
    let axis = |r: &AxisRange, unit: &str| format!("[{}, {}] step {} {unit}", r.min, r.max, r.step);
    println!("grid: {nx} x {ny} x {nz} x {nyaw} = {} poses", spec.grid_len());
    println!(
        "  x {}, y {}, z {}, yaw {}",
        axis(&spec.x_mm, "mm"),
        axis(&spec.y_mm, "mm"),
        axis(&spec.z_mm, "mm"),
        axis(&spec.yaw_deg, "deg")
    );
    println!("sampling: {}, {} poses, seed {}, order {}", spec.sampling, plan.poses.len(), spec.seed, spec.order);
    let ratio = if plan.motion_time_before_s > 0.0 { plan.motion_time_after_s / plan.motion_time_before_s } else { 1.0 };
    println!("motion time: {:.1} s as sampled, {:.1} s in this order ({ratio:.2}x)", plan.motion_time_before_s, plan.motion_time_after_s);
    if !summary {
        println!("{:>5} {:>8} {:>8} {:>8} {:>8} {:>8}", "#", "pose_id", "x_mm", "y_mm", "z_mm", "yaw_deg");
        for (i, p) in plan.poses.iter().enumerate() {
            println!("{:>5} {:>8} {:>8.3} {:>8.3} {:>8.3} {:>8.3}", i, p.pose_id, p.pose.x_mm, p.pose.y_mm, p.pose.z_mm, p.pose.yaw_deg);
        }
    }
    Ok(())
}

/// A pose's value on one axis.
type AxisValue = fn(&Pose) -> f64;

/// The value of `pose` on the axis named `name` (`x`, `y`, `z`, `yaw`) and the axis' label.
fn axis_of(name: &str) -> Option<(AxisValue, &'static str)> {
    match name.trim() {
        "x" => Some((|p: &Pose| p.x_mm, "x mm")),
        "y" => Some((|p: &Pose| p.y_mm, "y mm")),
        "z" => Some((|p: &Pose| p.z_mm, "z mm")),
        "yaw" => Some((|p: &Pose| p.yaw_deg, "yaw deg")),
        _ => None,
    }
}

/// `rig plan show --rounds DATASET [--svg FILE]`: the rounds an adaptive collection recorded,
/// one line per choice with the terms that chose it, and optionally the picture.
fn show_rounds(dataset: &std::path::Path, svg: Option<&std::path::Path>, axes: &str) -> anyhow::Result<()> {
    let manifest = crate::dataset::Manifest::load(dataset)?;
    let Some(settings) = manifest.adaptive else {
        anyhow::bail!(crate::cli::usage(&format!(
            "{} is not an adaptive collection (its manifest has no [adaptive]); `rig collect --adaptive` makes one",
            dataset.display()
        )));
    };
    let Some(spec) = manifest.plan else {
        anyhow::bail!(crate::cli::usage(&format!("{}: its manifest has no plan", dataset.display())));
    };
    let choices = crate::dataset::choices::read_choices(dataset)?.unwrap_or_default();
    let record = crate::plan::adaptive::AdaptiveRecord { settings, choices };
    let s = &record.settings;
    println!(
        "adaptive collection: budget {}, {} rounds, {} seeds per pose, model {}, steps {}; {} poses chosen of a {}-pose grid",
        s.budget,
        s.rounds,
        s.seeds_per_pose,
        s.model,
        s.steps,
        record.choices.len(),
        spec.grid_len()
    );
    let term = |v: Option<f64>| v.map(|x| format!("{x:.3}")).unwrap_or_else(|| "-".into());
    println!(
        "{:>5} {:>8} {:>14} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8}",
        "round", "pose_id", "reason", "distance", "spread", "error", "score", "w dist", "w spread", "w error"
    );
    for c in &record.choices {
        let reason = match c.reason {
            crate::plan::adaptive::ChoiceReason::SpaceFilling => "space-filling",
            crate::plan::adaptive::ChoiceReason::Acquisition => "acquisition",
        };
        println!(
            "{:>5} {:>8} {:>14} {:>8.3} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8}",
            c.round,
            c.pose_id,
            reason,
            c.distance,
            term(c.spread),
            term(c.error),
            term(c.score),
            term(c.distance_weight),
            term(c.spread_weight),
            term(c.error_weight)
        );
    }
    let Some(svg) = svg else { return Ok(()) };
    let names: Vec<&str> = axes.split(',').collect();
    let (Some((fx, lx)), Some((fy, ly))) = (names.first().and_then(|a| axis_of(a)), names.get(1).and_then(|a| axis_of(a))) else {
        anyhow::bail!(crate::cli::usage(&format!("--axes {axes}: name two of x, y, z, yaw, as in --axes x,yaw")));
    };
    use crate::bench::plot::{Plot, Series};
    let chosen: std::collections::HashMap<u32, usize> = record.choices.iter().map(|c| (c.pose_id, c.round)).collect();
    let mut series = vec![Series { name: "not pressed (filled)".into(), ..Series::default() }];
    for round in 1..=record.rounds_recorded() {
        series.push(Series { name: format!("round {round}"), ..Series::default() });
    }
    // Every grid pose, one point each; poses that project onto one point draw over each other,
    // the pressed ones last.
    for p in spec.grid() {
        let k = chosen.get(&p.pose_id).copied().unwrap_or(0);
        series[k].points.push([fx(&p.pose), fy(&p.pose)]);
    }
    let plot = Plot {
        title: format!("adaptive collection {}: {} presses by round", dataset.display(), record.choices.len()),
        x_label: lx.into(),
        y_label: ly.into(),
        series,
        lines: false,
    };
    crate::bench::plot::write_svg(&plot, svg)?;
    println!("wrote {}", svg.display());
    Ok(())
}
