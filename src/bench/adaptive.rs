//! The cost of choosing in an adaptive collection (`rig collect --adaptive`): model calls and
//! wall time per round, at each number of seeds per pose.
//!
//! Each setting runs the real command as a child process (`rig collect --adaptive` on the
//! built-in simulated rig, one sensor, the bench's model package) on a full 5 x 5 x 1 x 2 =
//! 50-pose grid with a budget of 15 presses in 3 rounds, and reads the line each round prints
//! (`round 2/3: 5 poses (by acquisition, N model calls in T s): ...`). Round 1 is
//! space-filling and costs no model call; it is left out of the table.

use std::ffi::OsString;
use std::path::Path;

use super::error::BenchError;
use super::knob::{BenchConfig, Knob};
use super::plot::{Plot, Series};
use super::table::{Column, KnobReport, Row};

/// The plan of every run: the full grid of x, y in [-2, 2] mm by 1 mm, z 0, yaw 0 or 45 deg.
const PLAN: &str = "sampling = \"full\"\nseed = 3\norder = \"optimised\"\n\
    [x_mm]\nmin = -2.0\nmax = 2.0\nstep = 1.0\n[y_mm]\nmin = -2.0\nmax = 2.0\nstep = 1.0\n\
    [z_mm]\nmin = 0.0\nmax = 0.0\nstep = 1.0\n[yaw_deg]\nmin = 0.0\nmax = 45.0\nstep = 45.0\n";
const PLAN_POSES: usize = 50;
const BUDGET: usize = 15;
const ROUNDS: usize = 3;

/// (round, model calls, seconds) of every `round r/R: ... (by acquisition, N model calls in T s)`
/// line of `log`.
pub fn parse_rounds(log: &str) -> Vec<(usize, usize, f64)> {
    log.lines()
        .filter_map(|line| {
            let round = line.strip_prefix("round ")?.split('/').next()?.parse().ok()?;
            let rest = line.split("(by acquisition, ").nth(1)?;
            let calls = rest.split(' ').next()?.parse().ok()?;
            let seconds = rest.split(" model calls in ").nth(1)?.split(' ').next()?.parse().ok()?;
            Some((round, calls, seconds))
        })
        .collect()
}

pub fn measure(config: &BenchConfig, work_dir: &Path) -> Result<KnobReport, BenchError> {
    let exe = super::scale::rig_exe(config)?;
    std::fs::create_dir_all(work_dir).map_err(|e| BenchError::io(work_dir, e))?;
    let work = work_dir.canonicalize().map_err(|e| BenchError::io(work_dir, e))?;
    let plan = work.join("plan.toml");
    std::fs::write(&plan, PLAN).map_err(|e| BenchError::io(&plan, e))?;
    let model = std::path::absolute(&config.synth_model).map_err(|e| BenchError::io(&config.synth_model, e))?;
    let mut rows = Vec::new();
    let mut series = Vec::new();
    for &seeds in &config.adaptive_seeds_per_pose {
        let out = work.join(format!("seeds{seeds}"));
        let log = work.join(format!("seeds{seeds}.log"));
        let mut args: Vec<OsString> = ["collect", "--adaptive", "--sensor", "tactip", "--rounds"].iter().map(OsString::from).collect();
        args.push(ROUNDS.to_string().into());
        args.extend(["--budget".into(), BUDGET.to_string().into(), "--seeds-per-pose".into(), seeds.to_string().into()]);
        args.extend(["--steps".into(), config.adaptive_steps.to_string().into()]);
        args.extend(["--model".into(), model.clone().into_os_string(), "--plan".into(), plan.clone().into_os_string()]);
        args.extend(["--out".into(), out.into_os_string()]);
        super::scale::run_child(&exe, &args, &work, &log)?;
        let text = std::fs::read_to_string(&log).map_err(|e| BenchError::io(&log, e))?;
        let mut points = Series { name: format!("{seeds} seeds per pose"), ..Series::default() };
        for (round, calls, seconds) in parse_rounds(&text) {
            let per_call_ms = if calls > 0 { seconds / calls as f64 * 1e3 } else { f64::NAN };
            rows.push(Row {
                label: format!("{seeds} seeds, round {round}"),
                values: vec![seeds as f64, calls as f64, seconds, per_call_ms],
            });
            points.points.push([round as f64, seconds]);
            points.labels.push(format!("{calls} calls"));
        }
        series.push(points);
    }
    if rows.is_empty() {
        return Err(BenchError::Empty { knob: Knob::Adaptive, reason: "no round chose by acquisition" });
    }
    Ok(KnobReport {
        knob: Knob::Adaptive,
        title: "Adaptive collection: the cost of choosing a round".into(),
        label_column: "setting".into(),
        columns: vec![
            Column::new("seeds per pose", 0),
            Column::new("model calls", 0),
            Column::new("choosing [s]", 2),
            Column::new("per call [ms]", 1),
        ],
        rows,
        notes: vec![
            format!(
                "`rig collect --adaptive --sensor tactip --budget {BUDGET} --rounds {ROUNDS} --seeds-per-pose K --steps {} --model {}` \
                 on the built-in simulated rig, a full {PLAN_POSES}-pose grid; each row is one round after the first \
                 (round 1 is space-filling, no model call).",
                config.adaptive_steps,
                config.synth_model.display()
            ),
            "Model calls of a round: M x K for the spread (M = max(4 x the round's presses, 16) candidates scored) plus one \
             for each pose pressed in the round before (its measured error). *choosing* is the round's wall time before \
             its first press; *per call* divides it by the calls."
                .into(),
        ],
        plot: Plot {
            title: "Adaptive collection: time to choose a round".into(),
            x_label: "round".into(),
            y_label: "choosing [s]".into(),
            series,
            lines: true,
        },
    })
}

#[cfg(test)]
mod tests {
    #[test]
    fn round_lines_are_read() {
        let log = "round 1/3: 5 poses (space-filling): 1 2\nround 2/3: 5 poses (by acquisition, 90 model calls in 1.5 s): 3\n\
                   round 3/3: 5 poses (as recorded): 4\n";
        assert_eq!(super::parse_rounds(log), vec![(2, 90, 1.5)]);
    }
}
