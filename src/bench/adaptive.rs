//! The cost of choosing in an adaptive collection (`rig collect --adaptive`): model calls and
//! wall time per round, at each number of seeds per pose.
//!
//! Each setting runs the real command as a child process (`rig collect --adaptive` on the
//! built-in simulated rig, one sensor, the bench's model package) on a full 5 x 5 x 1 x 2 =
//! 50-pose grid with a budget of 15 presses in 3 rounds, and reads the line each round prints
//! (`round 2/3: 5 poses (by acquisition, N model calls in T s): ...`). Round 1 is
//! space-filling and costs no model call; it is left out of the table.
//!
//! The `adaptive-scale` knob ([`measure_scale`]) times the rest of choosing, the arithmetic
//! over the plan's poses, at the scale knob's three plan sizes.

use std::ffi::OsString;
use std::path::Path;
use std::time::Instant;

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
            "Model calls of a round: one for each pose pressed in the round before (its measured error); from 8 pressed \
             poses on, K for each pressed pose whose spread is not yet measured (the evidence the terms' weights are \
             judged by); and M x K for the candidates' spread (M = max(4 x the round's presses, 16)) where the spread's \
             weight is above 0. *choosing* is the round's wall time before its first press; *per call* divides it by \
             the calls."
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

/// Share of the plan an arithmetic run presses, and its rounds.
const SCALE_SHARE: f64 = 0.3;
const SCALE_ROUNDS: usize = 4;

/// The seconds each round's arithmetic takes on a plan of `n` poses (the scale knob's lab
/// grid, Latin hypercube): round 1 by farthest points, each later round the terms' weights
/// (each press's nearest other press and its error regressed from the others), the
/// candidates by distance and the error regressed at every unpressed pose, and the batch
/// picked, with the model's evidence (a spread per candidate and per press, an error per
/// press) drawn from a seeded generator in place of model calls. Returns the presses a round
/// and the seconds of each round.
pub fn choosing_arithmetic(n: usize) -> Result<(usize, Vec<f64>), BenchError> {
    use crate::plan::adaptive::{self, Scored, Weights};
    use rand::{RngExt, SeedableRng};
    let spec = super::scale::lab_scale_plan(n);
    let poses = spec.sample()?;
    let points = adaptive::normalised(&spec, &poses);
    let ids: Vec<u32> = poses.iter().map(|p| p.pose_id).collect();
    let at: std::collections::HashMap<u32, usize> = ids.iter().enumerate().map(|(i, &id)| (id, i)).collect();
    let budget = ((n as f64 * SCALE_SHARE).round() as usize).max(SCALE_ROUNDS);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    let mut pressed: Vec<usize> = Vec::new();
    let mut seconds = Vec::new();
    for round in 1..=SCALE_ROUNDS {
        let count = adaptive::round_size(budget, SCALE_ROUNDS, round);
        let t = Instant::now();
        let picks: Vec<usize> = if round == 1 {
            adaptive::farthest_points(&points, &ids, &pressed, count, spec.seed).into_iter().map(|p| p.0).collect()
        } else {
            let measured: Vec<([f64; 4], f64)> = pressed.iter().map(|&i| (points[i], rng.random_range(0.0..0.3))).collect();
            let pressed_spread: Vec<f64> = pressed.iter().map(|_| rng.random_range(0.0..10.0)).collect();
            let errors = adaptive::ErrorModel::new(&measured);
            let errors_measured: Vec<f64> = measured.iter().map(|m| m.1).collect();
            // The weights as measured (drawn evidence predicts nothing, so they come out near
            // 0); the candidates chosen with the error's weight at least 0.5 and the spread
            // drawn whatever its weight, so that the arithmetic of every term is timed: the
            // error regressed at every unpressed pose, and the spread's scaling.
            let weights =
                Weights::measured(errors.distance_weight(), adaptive::term_weight(&pressed_spread, &errors_measured), errors.weight());
            let free = points.len() - pressed.len();
            let candidates = adaptive::candidates_to_score(
                &points,
                &ids,
                &pressed,
                Some((&errors, Weights { error: weights.error.max(0.5), ..weights })),
                adaptive::scored_count(count, free),
            );
            let scored: Vec<Scored> = candidates
                .iter()
                .map(|&index| Scored { index, spread: Some(rng.random_range(0.0..10.0)), error: errors.at(&points[index]).unwrap_or(0.0) })
                .collect();
            adaptive::acquisition_batch(&points, &ids, &pressed, &scored, weights, count, round)
                .iter()
                .filter_map(|c| at.get(&c.pose_id).copied())
                .collect()
        };
        seconds.push(t.elapsed().as_secs_f64());
        pressed.extend(picks);
    }
    Ok((adaptive::round_size(budget, SCALE_ROUNDS, 1), seconds))
}

/// The `adaptive-scale` knob: [`choosing_arithmetic`] at the scale knob's three plan sizes,
/// with the growth exponent of each cost.
pub fn measure_scale(config: &BenchConfig) -> Result<KnobReport, BenchError> {
    let mut rows = Vec::new();
    let mut first = Series { name: "round 1 (space-filling)".into(), ..Series::default() };
    let mut later = Series { name: "slowest later round (acquisition)".into(), ..Series::default() };
    for &n in &config.scale_plan_poses {
        let (per_round, seconds) = choosing_arithmetic(n)?;
        let slowest = seconds[1..].iter().copied().fold(0.0, f64::max);
        rows.push(Row { label: format!("{n} poses"), values: vec![n as f64, per_round as f64, seconds[0], slowest, seconds.iter().sum()] });
        first.points.push([n as f64, seconds[0]]);
        later.points.push([n as f64, slowest]);
    }
    if rows.is_empty() {
        return Err(BenchError::Empty { knob: Knob::AdaptiveScale, reason: "no plan size to measure" });
    }
    let exponent = |s: &Series| super::scale::growth_exponent(&s.points.iter().map(|p| (p[0], p[1])).collect::<Vec<_>>());
    let (e1, e2) = (exponent(&first), exponent(&later));
    Ok(KnobReport {
        knob: Knob::AdaptiveScale,
        title: "Adaptive collection: the arithmetic of choosing as the plan grows".into(),
        label_column: "plan".into(),
        columns: vec![
            Column::new("plan poses", 0),
            Column::new("presses a round", 0),
            Column::new("round 1 [s]", 3),
            Column::new("slowest later round [s]", 3),
            Column::new("all rounds [s]", 3),
        ],
        rows,
        notes: vec![
            format!(
                "The choices of `rig collect --adaptive --budget B --rounds {SCALE_ROUNDS}` with B = {:.0} % of a plan of N poses of the \
                 lab-scale grid (`plans/lab-scale.toml`, Latin hypercube, seed 0), in process, without the model: its evidence \
                 (the spread at each press and each scored candidate, the error at each press) is drawn from a seeded generator. The model's \
                 calls are the `adaptive` knob's; this is what choosing costs besides them.",
                SCALE_SHARE * 100.0
            ),
            format!(
                "Growth exponent (slope of ln s against ln N; 1 linear, 2 quadratic): round 1 {e1:.2}, the slowest later round {e2:.2}. \
                 Round 1 is greedy farthest-point sampling, O(N x presses); a later round weighs its terms at the presses, \
                 finds every pose's nearest press and regresses the error at every unpressed pose in k-d trees \
                 (O(N log presses)), and picks its batch from 4 x presses candidates, updating each one's distance after each \
                 pick (O(candidates x presses a round)): quadratic in N at a fixed share."
            ),
        ],
        plot: Plot {
            title: "Adaptive collection: choosing arithmetic against plan size".into(),
            x_label: "plan poses".into(),
            y_label: "seconds".into(),
            series: vec![first, later],
            lines: true,
        },
    })
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_arithmetic_presses_the_budget_over_its_rounds() {
        let (per_round, seconds) = super::choosing_arithmetic(200).expect("arithmetic");
        assert_eq!((per_round, seconds.len()), (15, super::SCALE_ROUNDS));
        assert!(seconds.iter().all(|s| s.is_finite() && *s >= 0.0), "{seconds:?}");
    }

    #[test]
    fn round_lines_are_read() {
        let log = "round 1/3: 5 poses (space-filling): 1 2\nround 2/3: 5 poses (by acquisition, 90 model calls in 1.5 s): 3\n\
                   round 3/3: 5 poses (as recorded): 4\n";
        assert_eq!(super::parse_rounds(log), vec![(2, 90, 1.5)]);
    }
}
