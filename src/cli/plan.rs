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
    },
}

pub fn run(args: Args) -> anyhow::Result<()> {
    match args.command {
        PlanCommand::Show { plan, summary } => show(&plan, summary),
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
