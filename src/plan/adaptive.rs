//! Choosing which poses of a plan an adaptive collection presses, round by round
//! (`rig collect --adaptive`). Pure arithmetic over the plan's poses: the evidence that costs
//! model calls (the spread of the model's images over seeds, the error of its images at the
//! poses already pressed) is measured by the job and handed in as numbers.
//!
//! ```text
//! round 1:  greedy farthest point in the normalised pose space (seeded start)
//! round r:  weights w(t) = max(0, correlation of term t with the errors measured at the
//!           pressed poses), each pose left out: its distance to the nearest other pressed
//!           pose, its error regressed from the others, its spread; every w 1 with fewer than
//!           8 presses, the distance 1 where no w is above 0
//!           the M unpressed poses best by w(d) s(distance) + w(e) s(error), scaled over
//!           every unpressed pose, are scored (the terms that cost no model call)
//!           a(p) = (w(d) s(distance) + w(s) s(spread) + w(e) s(error)) / (w(d) + w(s) + w(e))
//!           s(v) = (v - min) / (max - min) over the round's scored poses
//!           error(p): inverse-distance regression of the errors measured at the k nearest
//!           pressed poses; pick the best, update every distance, pick again ...
//! ```
//!
//! Everything here is deterministic given its inputs (ties go to the lower pose id), and what
//! was chosen is recorded ([`AdaptiveChoice`]) so that a resumed collection replays it.

use serde::{Deserialize, Serialize};

use super::kdtree::KdTree;
use super::{PlanSpec, PlannedPose};

/// How many unpressed poses a round scores with the model, at least: with fewer, a round's
/// batch would have little to choose from.
pub const MIN_SCORED: usize = 16;
/// Scored poses per pose of the round's batch.
pub const SCORED_PER_PICK: usize = 4;
/// Pressed poses the error regression averages over.
pub const ERROR_NEIGHBOURS: usize = 4;

/// What an adaptive collection was asked for; the same on every resume.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AdaptiveSettings {
    /// Real presses in all.
    pub budget: usize,
    /// Rounds the presses are split over.
    pub rounds: usize,
    /// Model images per scored pose, each with its own seed.
    pub seeds_per_pose: usize,
    /// The model package's name and content hash.
    pub model: String,
    pub model_sha256: String,
    /// Sampling steps of the model's images.
    pub steps: usize,
}

/// Why a pose was chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ChoiceReason {
    /// Round 1: the pose farthest from those already chosen.
    SpaceFilling,
    /// A later round: the highest acquisition score.
    Acquisition,
}

/// One chosen pose, as the dataset records it (a line of `adaptive.csv`,
/// [`crate::dataset::choices`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AdaptiveChoice {
    pub pose_id: u32,
    /// 1-based.
    pub round: usize,
    pub reason: ChoiceReason,
    /// Normalised distance to the nearest pose pressed or chosen before it.
    pub distance: f64,
    /// The acquisition's terms, each scaled to [0, 1] over the round's scored poses (the least
    /// 0, the most 1), and their weighted mean (`score`); absent in round 1, and the spread
    /// absent in a round that did not measure it (its weight was 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub spread: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub score: Option<f64>,
    /// The round's weights of the terms ([`Weights`]); absent in round 1, and in rounds
    /// recorded before the acquisition was weighted (where every term counted 1).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub distance_weight: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub spread_weight: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error_weight: Option<f64>,
}

/// An adaptive collection's settings (the manifest's `[adaptive]`) and every choice made so
/// far, in order (the dataset's `adaptive.csv`).
#[derive(Debug, Clone, PartialEq)]
pub struct AdaptiveRecord {
    pub settings: AdaptiveSettings,
    pub choices: Vec<AdaptiveChoice>,
}

impl AdaptiveRecord {
    /// The pose ids chosen in `round`, in the order chosen.
    pub fn round_ids(&self, round: usize) -> Vec<u32> {
        self.choices.iter().filter(|c| c.round == round).map(|c| c.pose_id).collect()
    }

    /// Rounds with at least one choice recorded.
    pub fn rounds_recorded(&self) -> usize {
        self.choices.iter().map(|c| c.round).max().unwrap_or(0)
    }

    /// Whether the choices can be this collection's: every pose is one of `plan`'s (`in_plan`;
    /// `plan` names what it tests, "the plan" on a resume, "the plan's grid" in verify), and
    /// every round recorded is one of the settings' rounds with the number of presses the budget
    /// gives it. What is wrong otherwise.
    pub fn check_choices(&self, plan: &str, in_plan: impl Fn(u32) -> bool) -> Result<(), String> {
        if let Some(c) = self.choices.iter().find(|c| !in_plan(c.pose_id)) {
            return Err(format!("pose {} (round {}) is not a pose of {plan}", c.pose_id, c.round));
        }
        let s = &self.settings;
        for round in 1..=self.rounds_recorded() {
            let (got, want) = (self.choices.iter().filter(|c| c.round == round).count(), round_size(s.budget, s.rounds, round));
            if got != want {
                return Err(format!("round {round} records {got} poses; a budget of {} over {} rounds presses {want}", s.budget, s.rounds));
            }
        }
        Ok(())
    }
}

/// How many poses round `round` (1-based) presses: the budget split evenly, the first rounds
/// taking one more each while a remainder is left.
pub fn round_size(budget: usize, rounds: usize, round: usize) -> usize {
    if rounds == 0 || round == 0 || round > rounds {
        return 0;
    }
    budget / rounds + usize::from(round <= budget % rounds)
}

/// Poses as points of the unit hypercube: each axis divided by the plan's range on it (an axis
/// of one value is 0 everywhere), so a step in yaw weighs as much as a step in x when both
/// axes have as many steps.
pub fn normalised(spec: &PlanSpec, poses: &[PlannedPose]) -> Vec<[f64; 4]> {
    let scale = |v: f64, a: &super::AxisRange| if a.max > a.min { (v - a.min) / (a.max - a.min) } else { 0.0 };
    poses
        .iter()
        .map(|p| {
            [
                scale(p.pose.x_mm, &spec.x_mm),
                scale(p.pose.y_mm, &spec.y_mm),
                scale(p.pose.z_mm, &spec.z_mm),
                scale(p.pose.yaw_deg, &spec.yaw_deg),
            ]
        })
        .collect()
}

/// Euclidean distance between two normalised poses.
pub fn distance(a: &[f64; 4], b: &[f64; 4]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<f64>().sqrt()
}

/// For every point, the distance to the nearest of `pressed` (indices into `points`);
/// infinite when none is pressed. O(points x log pressed): one k-d tree query each.
pub fn nearest_pressed(points: &[[f64; 4]], pressed: &[usize]) -> Vec<f64> {
    let tree = KdTree::new(pressed.iter().map(|&q| points[q]).collect());
    points.iter().map(|p| nearest_in(&tree, p)).collect()
}

/// The distance from `p` to the nearest point of `tree`; infinite when it has none. The same
/// number as [`distance`] to that point (the tree sums the same squares in the same order).
fn nearest_in(tree: &KdTree, p: &[f64; 4]) -> f64 {
    tree.nearest(p, 1, false).first().map_or(f64::INFINITY, |&(d2, _)| d2.sqrt())
}

/// The index of the largest finite-or-infinite value among `eligible`, ties to the lower pose
/// id; `None` when none is eligible.
fn best(eligible: impl Iterator<Item = usize>, value: impl Fn(usize) -> f64, ids: &[u32]) -> Option<usize> {
    eligible.fold(None, |best: Option<usize>, i| match best {
        Some(b) if value(b) > value(i) || (value(b) == value(i) && ids[b] < ids[i]) => Some(b),
        _ => Some(i),
    })
}

/// Round 1: `count` poses by greedy farthest-point sampling, starting from the pose `seed`
/// picks (when nothing is pressed yet). `pressed` are indices already pressed; `ids` the
/// poses' ids (for ties). Returns (index, distance to the nearest earlier pose) in pick order.
pub fn farthest_points(points: &[[f64; 4]], ids: &[u32], pressed: &[usize], count: usize, seed: u64) -> Vec<(usize, f64)> {
    let mut nearest = nearest_pressed(points, pressed);
    let mut taken = vec![false; points.len()];
    for &p in pressed {
        taken[p] = true;
    }
    let mut picks = Vec::new();
    while picks.len() < count {
        let pick = if picks.is_empty() && pressed.is_empty() {
            // A seeded start: the same seed picks the same first pose.
            let free: Vec<usize> = (0..points.len()).filter(|&i| !taken[i]).collect();
            if free.is_empty() {
                break;
            }
            use rand::{RngExt, SeedableRng};
            let k = rand_chacha::ChaCha8Rng::seed_from_u64(seed).random_range(0..free.len());
            Some(free[k])
        } else {
            best((0..points.len()).filter(|&i| !taken[i]), |i| nearest[i], ids)
        };
        let Some(i) = pick else { break };
        picks.push((i, nearest[i]));
        taken[i] = true;
        for (j, n) in nearest.iter_mut().enumerate() {
            *n = n.min(distance(&points[j], &points[i]));
        }
    }
    picks
}

/// How much each term of a later round's acquisition counts: how well the term predicted the
/// errors measured at the poses already pressed ([`term_weight`]), so that a term that does not
/// point at the poses the model gets wrong stops steering the presses. Made by
/// [`Weights::measured`], never all 0.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Weights {
    pub distance: f64,
    pub spread: f64,
    pub error: f64,
}

/// Fewest pressed poses the weights are measured on: with fewer, a correlation is mostly
/// noise, and a round weighs every term 1 ([`Weights::PRIOR`]).
pub const MIN_EVIDENCE: usize = 8;

impl Weights {
    /// The weights before [`MIN_EVIDENCE`] poses are pressed: every term counts 1.
    pub const PRIOR: Weights = Weights { distance: 1.0, spread: 1.0, error: 1.0 };

    /// The weights as measured, each clamped to [0, 1]; where none is above 0 (no term
    /// predicted the errors), the distance alone counts: the round fills space as round 1 does.
    pub fn measured(distance: f64, spread: f64, error: f64) -> Self {
        let w = |v: f64| if v.is_finite() { v.clamp(0.0, 1.0) } else { 0.0 };
        let (distance, spread, error) = (w(distance), w(spread), w(error));
        if distance + spread + error > 0.0 { Self { distance, spread, error } } else { Self { distance: 1.0, spread, error } }
    }
}

/// The weight of a term: the correlation (Pearson's r) of its `values` at the pressed poses
/// with the `errors` measured there, or 0 where that is negative, undefined (a constant) or
/// measured on fewer than [`MIN_EVIDENCE`] poses. 1 when the term ranks the pressed poses as
/// their errors do, 0 when it says nothing about them.
pub fn term_weight(values: &[f64], errors: &[f64]) -> f64 {
    let n = values.len().min(errors.len());
    if n < MIN_EVIDENCE {
        return 0.0;
    }
    let mean = |v: &[f64]| v[..n].iter().sum::<f64>() / n as f64;
    let (mv, me) = (mean(values), mean(errors));
    let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
    for (x, y) in values[..n].iter().zip(&errors[..n]) {
        sxy += (x - mv) * (y - me);
        sxx += (x - mv) * (x - mv);
        syy += (y - me) * (y - me);
    }
    let r = sxy / (sxx * syy).sqrt();
    if r.is_finite() { r.clamp(0.0, 1.0) } else { 0.0 }
}

/// The audit-error model: the errors measured at pressed poses (point, error), regressed to any
/// pose as the inverse-distance-weighted mean of the [`ERROR_NEIGHBOURS`] nearest (by squared
/// distance, ties to the pose measured first). Built once a round, O(measured log measured); a query is
/// O(log measured).
pub struct ErrorModel {
    tree: KdTree,
    errors: Vec<f64>,
}

impl ErrorModel {
    pub fn new(measured: &[([f64; 4], f64)]) -> Self {
        Self { tree: KdTree::new(measured.iter().map(|m| m.0).collect()), errors: measured.iter().map(|m| m.1).collect() }
    }

    /// The error regressed at `point`; `None` when nothing was measured.
    pub fn at(&self, point: &[f64; 4]) -> Option<f64> {
        self.weighted(self.tree.nearest(point, ERROR_NEIGHBOURS, false).into_iter())
    }

    /// The error regressed at measured pose `k` from the others (leave one out): how well the
    /// regression predicts a pose it has not seen. `None` when no other was measured.
    pub fn left_out(&self, k: usize) -> Option<f64> {
        let near = self.tree.nearest(self.tree.point(k as u32), ERROR_NEIGHBOURS + 1, false);
        self.weighted(near.into_iter().filter(|&(_, i)| i as usize != k).take(ERROR_NEIGHBOURS))
    }

    fn weighted(&self, near: impl Iterator<Item = (f64, u32)>) -> Option<f64> {
        // A small floor keeps a measured pose's own error from an infinite weight.
        let (sum_w, sum_we) = near.fold((0.0, 0.0), |(w, we), (d2, i)| {
            let weight = 1.0 / (d2.sqrt() + 1e-3);
            (w + weight, we + weight * self.errors[i as usize])
        });
        (sum_w > 0.0).then(|| sum_we / sum_w)
    }

    /// The weight of the regressed error ([`term_weight`] of each measured pose's left-out
    /// regression against its error).
    pub fn weight(&self) -> f64 {
        let left_out: Vec<f64> = (0..self.errors.len()).map(|k| self.left_out(k).unwrap_or(0.0)).collect();
        term_weight(&left_out, &self.errors)
    }

    /// The weight of the distance: [`term_weight`] of each measured pose's distance to the
    /// nearest other measured pose against its error (were the poses far from the others the
    /// ones the model got wrong?).
    pub fn distance_weight(&self) -> f64 {
        let apart: Vec<f64> = (0..self.errors.len())
            .map(|k| {
                let near = self.tree.nearest(self.tree.point(k as u32), 2, false);
                near.into_iter().find(|&(_, i)| i as usize != k).map_or(0.0, |(d2, _)| d2.sqrt())
            })
            .collect();
        term_weight(&apart, &self.errors)
    }
}

/// Scales each value to [0, 1] over the finite values of the set (the least 0, the most 1);
/// an infinite value counts 1, and a set whose finite values are all equal counts 0.
struct RangeScale(f64, f64);

impl RangeScale {
    fn over(values: impl Iterator<Item = f64>) -> Self {
        let (lo, hi) = values.filter(|x| x.is_finite()).fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| (lo.min(x), hi.max(x)));
        Self(lo, hi)
    }

    fn of(&self, v: f64) -> f64 {
        let Self(lo, hi) = *self;
        if v == f64::INFINITY {
            1.0
        } else if hi > lo && v.is_finite() {
            ((v - lo) / (hi - lo)).clamp(0.0, 1.0)
        } else {
            0.0
        }
    }
}

/// The unpressed poses a later round scores with the model: of every unpressed pose, the `m`
/// best by the terms that cost no model call, the distance and the regressed error, each
/// scaled over the unpressed poses and weighted by `weights` (ties to the farther, then to the
/// lower id), as indices. With no error model, or where neither term counts, the `m` farthest
/// from every pressed pose.
pub fn candidates_to_score(
    points: &[[f64; 4]],
    ids: &[u32],
    pressed: &[usize],
    errors: Option<(&ErrorModel, Weights)>,
    m: usize,
) -> Vec<usize> {
    let nearest = nearest_pressed(points, pressed);
    let mut taken = vec![false; points.len()];
    for &p in pressed {
        taken[p] = true;
    }
    let free: Vec<usize> = (0..points.len()).filter(|&i| !taken[i]).collect();
    let (wd, we) = match errors {
        Some((_, w)) if w.distance + w.error > 0.0 => (w.distance, w.error),
        _ => (1.0, 0.0),
    };
    let error: Vec<f64> = match errors {
        Some((model, _)) if we > 0.0 => free.iter().map(|&i| model.at(&points[i]).unwrap_or(0.0)).collect(),
        _ => vec![0.0; free.len()],
    };
    let (ds, es) = (RangeScale::over(free.iter().map(|&i| nearest[i])), RangeScale::over(error.iter().copied()));
    let cheap: Vec<f64> = free.iter().zip(&error).map(|(&i, &e)| wd * ds.of(nearest[i]) + we * es.of(e)).collect();
    let mut order: Vec<usize> = (0..free.len()).collect();
    order.sort_by(|&a, &b| {
        cheap[b].total_cmp(&cheap[a]).then(nearest[free[b]].total_cmp(&nearest[free[a]])).then(ids[free[a]].cmp(&ids[free[b]]))
    });
    order.truncate(m);
    order.into_iter().map(|k| free[k]).collect()
}

/// How many poses a round of `batch` presses scores with the model, of `free` unpressed ones.
pub fn scored_count(batch: usize, free: usize) -> usize {
    (batch * SCORED_PER_PICK).max(MIN_SCORED).min(free)
}

/// One scored pose of a later round: its index and the evidence measured for it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Scored {
    pub index: usize,
    /// The model's spread over seeds in the contact region; `None` when the round did not
    /// measure it (its weight was 0).
    pub spread: Option<f64>,
    /// The regressed audit error ([`ErrorModel::at`]).
    pub error: f64,
}

/// A later round: `count` of the `scored` poses, greedily by the acquisition (each term scaled
/// to [0, 1] over `scored`, the least 0 and the most 1, then averaged with `weights`), the
/// distance term updated after each pick so that, where the distance counts, a round spreads.
/// `pressed`: indices pressed before this round.
///
/// Scaled by the range, not divided by the largest: an error of 0.50 against 0.55 is a tenth
/// apart divided by the largest, while the distances of the same poses may be twice apart, so
/// the distance would decide every round, and a term that is the same everywhere would add
/// the same to every pose without saying so. Scaled by its range, each term ranks the poses
/// as strongly as the others; a term equal at every pose counts 0. Weighted by how well it
/// predicted the errors measured, a term that does not point at the model's mistakes (the
/// spread often does not, nor, once round 1 has covered the plan, the distance) does not pull
/// presses away from where they are.
pub fn acquisition_batch(
    points: &[[f64; 4]],
    ids: &[u32],
    pressed: &[usize],
    scored: &[Scored],
    weights: Weights,
    count: usize,
    round: usize,
) -> Vec<AdaptiveChoice> {
    let tree = KdTree::new(pressed.iter().map(|&q| points[q]).collect());
    let mut nearest: Vec<f64> = scored.iter().map(|s| nearest_in(&tree, &points[s.index])).collect();
    let spread_scale = RangeScale::over(scored.iter().filter_map(|s| s.spread));
    let error_scale = RangeScale::over(scored.iter().map(|s| s.error));
    let distance_scale = RangeScale::over(nearest.iter().copied());
    let w = Weights::measured(weights.distance, weights.spread, weights.error);
    let (wd, ws, we) = (w.distance, w.spread, w.error);
    let mut taken = vec![false; scored.len()];
    let mut choices = Vec::new();
    let scored_ids: Vec<u32> = scored.iter().map(|s| ids[s.index]).collect();
    while choices.len() < count {
        let score = |k: usize| {
            let s = &scored[k];
            let spread = s.spread.map_or(0.0, |v| spread_scale.of(v));
            (wd * distance_scale.of(nearest[k]) + ws * spread + we * error_scale.of(s.error)) / (wd + ws + we)
        };
        let Some(k) = best((0..scored.len()).filter(|&k| !taken[k]), score, &scored_ids) else { break };
        let s = scored[k];
        choices.push(AdaptiveChoice {
            pose_id: ids[s.index],
            round,
            reason: ChoiceReason::Acquisition,
            distance: nearest[k],
            spread: s.spread.map(|v| spread_scale.of(v)),
            error: Some(error_scale.of(s.error)),
            score: Some(score(k)),
            distance_weight: Some(wd),
            spread_weight: Some(ws),
            error_weight: Some(we),
        });
        taken[k] = true;
        for (j, n) in nearest.iter_mut().enumerate() {
            *n = n.min(distance(&points[scored[j].index], &points[s.index]));
        }
    }
    choices
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pose::Pose;

    /// Every term counting as much as the distance.
    const EVEN: Weights = Weights::PRIOR;

    fn line(n: u32) -> (Vec<[f64; 4]>, Vec<u32>) {
        ((0..n).map(|i| [i as f64 / (n - 1) as f64, 0.0, 0.0, 0.0]).collect(), (0..n).collect())
    }

    #[test]
    fn round_sizes_add_up_to_the_budget() {
        for (budget, rounds) in [(10, 3), (97, 4), (5, 5), (7, 1)] {
            let sizes: Vec<usize> = (1..=rounds).map(|r| round_size(budget, rounds, r)).collect();
            assert_eq!(sizes.iter().sum::<usize>(), budget, "{budget} over {rounds}: {sizes:?}");
            assert!(sizes.windows(2).all(|w| w[0] >= w[1] && w[0] - w[1] <= 1), "{sizes:?}");
        }
        assert_eq!(round_size(10, 3, 4), 0);
    }

    #[test]
    fn farthest_points_spread_over_a_line_and_repeat_with_the_seed() {
        let (points, ids) = line(11);
        let a = farthest_points(&points, &ids, &[], 3, 7);
        assert_eq!(a, farthest_points(&points, &ids, &[], 3, 7), "same seed, same picks");
        let picked: Vec<usize> = a.iter().map(|p| p.0).collect();
        // After any start, the second pick is the far end from it and the third lies between.
        let far = if picked[0] <= 5 { 10 } else { 0 };
        assert_eq!(picked[1], far, "{picked:?}");
        assert!(a[1].1 >= 0.5 && a[2].1 <= a[1].1, "{a:?}");
        // With presses, the farthest free pose is taken first.
        let b = farthest_points(&points, &ids, &[0], 1, 7);
        assert_eq!(b[0].0, 10);
    }

    #[test]
    fn acquisition_prefers_spread_error_and_distance_and_spreads_a_batch() {
        let (points, ids) = line(11);
        let pressed = [0, 10];
        // Poses 4, 5 and 6 are equally far from a press; 6 has the largest spread and error.
        let scored: Vec<Scored> = [4, 5, 6]
            .iter()
            .map(|&i| Scored { index: i, spread: Some(if i == 6 { 1.0 } else { 0.1 }), error: if i == 6 { 0.5 } else { 0.1 } })
            .collect();
        let batch = acquisition_batch(&points, &ids, &pressed, &scored, EVEN, 2, 2);
        assert_eq!(batch[0].pose_id, 6, "{batch:?}");
        // Its neighbour 5 is now close to a pick: the second pick is 4.
        assert_eq!(batch[1].pose_id, 4, "{batch:?}");
        assert!(batch.iter().all(|c| c.round == 2 && c.reason == ChoiceReason::Acquisition));
        assert!(batch[0].score > batch[1].score);
    }

    /// Each term ranks by its range over the scored poses: two terms ahead by little (spread
    /// 0.52 against 0.50, error 0.55 against 0.50) outweigh one ahead by more (distance 0.5
    /// against 0.4). Divided by their largest, the two would count a few hundredths and the
    /// distance a fifth, and pose 5 would be picked.
    #[test]
    fn each_term_ranks_by_its_range_over_the_scored_poses() {
        let (points, ids) = line(11);
        let pressed = [0, 10];
        let scored = [Scored { index: 5, spread: Some(0.50), error: 0.50 }, Scored { index: 4, spread: Some(0.52), error: 0.55 }];
        let batch = acquisition_batch(&points, &ids, &pressed, &scored, EVEN, 2, 2);
        assert_eq!(batch[0].pose_id, 4, "{batch:?}");
        assert_eq!((batch[0].spread, batch[0].error), (Some(1.0), Some(1.0)), "{batch:?}");
        assert!((batch[0].distance - 0.4).abs() < 1e-12, "{batch:?}");
        assert_eq!((batch[1].spread, batch[1].error), (Some(0.0), Some(0.0)), "{batch:?}");
        // A term the same at every scored pose counts 0 everywhere.
        let same = [Scored { index: 5, spread: Some(0.3), error: 0.2 }, Scored { index: 4, spread: Some(0.3), error: 0.2 }];
        let batch = acquisition_batch(&points, &ids, &pressed, &same, EVEN, 1, 2);
        assert_eq!((batch[0].pose_id, batch[0].spread, batch[0].error, batch[0].score), (5, Some(0.0), Some(0.0), Some(1.0 / 3.0)));
    }

    #[test]
    fn regressed_error_follows_the_nearest_measures() {
        let measured = [([0.0, 0.0, 0.0, 0.0], 0.1), ([1.0, 0.0, 0.0, 0.0], 0.9)];
        let model = ErrorModel::new(&measured);
        let near_low = model.at(&[0.1, 0.0, 0.0, 0.0]).expect("measured");
        let near_high = model.at(&[0.9, 0.0, 0.0, 0.0]).expect("measured");
        assert!(near_low < 0.3 && near_high > 0.7, "{near_low} {near_high}");
        assert_eq!(ErrorModel::new(&[]).at(&[0.5, 0.0, 0.0, 0.0]), None);
        // Left out, each pose is regressed from the other alone.
        assert_eq!((model.left_out(0), model.left_out(1)), (Some(0.9), Some(0.1)));
        assert_eq!(ErrorModel::new(&measured[..1]).left_out(0), None);
    }

    /// A term's weight is its correlation with the measured errors, 0 when it points the other
    /// way, is constant or has too little evidence.
    #[test]
    fn a_term_weighs_as_well_as_it_predicted_the_measured_errors() {
        let errors = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8];
        let rising = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0];
        assert!((term_weight(&rising, &errors) - 1.0).abs() < 1e-12);
        let falling: Vec<f64> = rising.iter().rev().copied().collect();
        assert_eq!(term_weight(&falling, &errors), 0.0, "anti-correlated");
        assert_eq!(term_weight(&[2.0; 8], &errors), 0.0, "constant");
        assert_eq!(term_weight(&rising[..7], &errors[..7]), 0.0, "fewer than MIN_EVIDENCE");
        let w = term_weight(&[1.0, 3.0, 2.0, 4.0, 6.0, 5.0, 8.0, 7.0], &errors);
        assert!(w > 0.5 && w < 1.0, "{w}");
        // The regressed error of a smooth field predicts its left-out poses; of an alternating
        // one (each pose's neighbours the other way) it does not.
        let (points, _) = line(11);
        let smooth: Vec<([f64; 4], f64)> = points.iter().map(|p| (*p, p[0])).collect();
        assert!(ErrorModel::new(&smooth).weight() > 0.9, "{}", ErrorModel::new(&smooth).weight());
        let alternating: Vec<([f64; 4], f64)> = points.iter().enumerate().map(|(i, p)| (*p, (i % 2) as f64)).collect();
        assert_eq!(ErrorModel::new(&alternating).weight(), 0.0);
        // The distance weighs as well as isolation predicted the error: on a line pressed at
        // 0, 1, 2, 3 and 6, 8, 10 (apart by 0.1 and 0.2), errors that grow with the gap.
        let pressed = [0usize, 1, 2, 3, 6, 8, 10];
        let pressed: Vec<usize> = pressed.iter().copied().chain([5]).collect();
        let apart: Vec<([f64; 4], f64)> = pressed.iter().map(|&i| (points[i], if i >= 5 { 0.8 } else { 0.2 })).collect();
        assert!(ErrorModel::new(&apart).distance_weight() > 0.5, "{}", ErrorModel::new(&apart).distance_weight());
        let close: Vec<([f64; 4], f64)> = pressed.iter().map(|&i| (points[i], if i >= 5 { 0.2 } else { 0.8 })).collect();
        assert_eq!(ErrorModel::new(&close).distance_weight(), 0.0);
        // Weights never all 0: the distance then counts.
        assert_eq!(Weights::measured(0.0, 0.0, f64::NAN), Weights { distance: 1.0, spread: 0.0, error: 0.0 });
        assert_eq!(Weights::measured(-0.3, 0.2, 1.5), Weights { distance: 0.0, spread: 0.2, error: 1.0 });
    }

    /// A weight of 0 takes a term out of the score: the pose ahead only on the spread is not
    /// picked, and with the spread not measured the score is the distance's and the error's.
    #[test]
    fn a_term_of_weight_0_does_not_steer_the_round() {
        let (points, ids) = line(11);
        let pressed = [0, 10];
        let scored = [Scored { index: 5, spread: Some(0.1), error: 0.5 }, Scored { index: 4, spread: Some(0.9), error: 0.5 }];
        let unweighted = acquisition_batch(&points, &ids, &pressed, &scored, Weights { distance: 1.0, spread: 0.0, error: 1.0 }, 1, 2);
        assert_eq!(unweighted[0].pose_id, 5, "{unweighted:?}");
        assert_eq!((unweighted[0].spread_weight, unweighted[0].error_weight, unweighted[0].score), (Some(0.0), Some(1.0), Some(0.5)));
        // Where no term counts, the distance does: the farther pose, 5.
        let none = acquisition_batch(&points, &ids, &pressed, &scored, Weights { distance: 0.0, spread: 0.0, error: 0.0 }, 1, 2);
        assert_eq!((none[0].pose_id, none[0].distance_weight, none[0].score), (5, Some(1.0), Some(1.0)), "{none:?}");
        // Where the distance does not count, a round does not spread: the two poses of the
        // largest error are taken side by side.
        let side = [
            Scored { index: 3, spread: None, error: 0.9 },
            Scored { index: 4, spread: None, error: 0.9 },
            Scored { index: 7, spread: None, error: 0.1 },
        ];
        let errors_only = Weights { distance: 0.0, spread: 0.0, error: 1.0 };
        let ids_of = |b: Vec<AdaptiveChoice>| b.iter().map(|c| c.pose_id).collect::<Vec<_>>();
        assert_eq!(ids_of(acquisition_batch(&points, &ids, &pressed, &side, errors_only, 2, 2)), vec![3, 4]);
        assert_eq!(acquisition_batch(&points, &ids, &pressed, &scored, EVEN, 1, 2)[0].pose_id, 4);
        let unmeasured = [Scored { index: 4, spread: None, error: 0.9 }, Scored { index: 5, spread: None, error: 0.1 }];
        let batch = acquisition_batch(&points, &ids, &pressed, &unmeasured, Weights { distance: 1.0, spread: 0.0, error: 0.5 }, 1, 2);
        // Pose 4: distance 0.4 (scaled 0), error scaled 1: (0 + 0.5 x 1) / 1.5 = 1/3; pose 5:
        // distance 0.5 (scaled 1), error 0: 1 / 1.5 = 2/3.
        assert_eq!((batch[0].pose_id, batch[0].spread), (5, None));
        assert!((batch[0].score.expect("scored") - 2.0 / 3.0).abs() < 1e-12, "{batch:?}");
    }

    /// The k-d tree answers what a scan over every pressed pose answers, bit for bit, and the
    /// selected neighbours of the error what a stable sort of every measured pose by distance
    /// gives (ties, everywhere on a grid, to the pose measured first).
    #[test]
    fn tree_queries_match_the_scans_over_every_pressed_pose() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        // A 4-D grid of 5 x 5 x 3 x 4 steps: many equal distances.
        let points: Vec<[f64; 4]> =
            (0..300).map(|i| [(i % 5) as f64 / 4.0, (i / 5 % 5) as f64 / 4.0, (i / 25 % 3) as f64 / 2.0, (i / 75) as f64 / 3.0]).collect();
        for pressed_count in [0, 1, 7, 40, 150] {
            let mut pressed: Vec<usize> = (0..points.len()).collect();
            for i in (1..pressed.len()).rev() {
                pressed.swap(i, rng.random_range(0..=i));
            }
            pressed.truncate(pressed_count);
            let scan: Vec<f64> =
                points.iter().map(|p| pressed.iter().map(|&q| distance(p, &points[q])).fold(f64::INFINITY, f64::min)).collect();
            assert_eq!(nearest_pressed(&points, &pressed), scan, "{pressed_count} pressed");
            let measured: Vec<([f64; 4], f64)> = pressed.iter().map(|&q| (points[q], rng.random_range(0.0..1.0))).collect();
            for p in &points {
                // Nearest by squared distance (ties to the pose measured first), weighted by
                // the distance.
                let mut near: Vec<(f64, f64)> = measured.iter().map(|(m, e)| (super::super::kdtree::dist2(p, m), *e)).collect();
                near.sort_by(|a, b| a.0.total_cmp(&b.0));
                near.truncate(ERROR_NEIGHBOURS);
                let want = (!near.is_empty()).then(|| {
                    let (w, we) = near.iter().fold((0.0, 0.0), |(w, we), (d2, e)| {
                        let weight = 1.0 / (d2.sqrt() + 1e-3);
                        (w + weight, we + weight * e)
                    });
                    we / w
                });
                assert_eq!(ErrorModel::new(&measured).at(p), want, "{pressed_count} pressed, at {p:?}");
            }
        }
    }

    #[test]
    fn candidates_are_the_farthest_from_the_presses() {
        let (points, ids) = line(11);
        assert_eq!(candidates_to_score(&points, &ids, &[0, 10], None, 3), vec![5, 4, 6]);
        // The error, where it predicted, draws the candidates towards the poses near large
        // errors: pressed 0 (error 0.9) and 10 (0.1), the three farthest are 5, 4 and 6; with
        // the error weighing as much as the distance, 3 (nearer 0) takes 6's place.
        let measured: Vec<([f64; 4], f64)> = [(0, 0.9), (10, 0.1)].iter().map(|&(i, e)| (points[i], e)).collect();
        let model = ErrorModel::new(&measured);
        let w = |distance: f64, error: f64| Weights { distance, spread: 1.0, error };
        assert_eq!(candidates_to_score(&points, &ids, &[0, 10], Some((&model, w(1.0, 0.0))), 3), vec![5, 4, 6]);
        assert_eq!(candidates_to_score(&points, &ids, &[0, 10], Some((&model, w(1.0, 1.0))), 3), vec![5, 4, 3]);
        // The error alone: the poses nearest the large error; neither: the farthest.
        assert_eq!(candidates_to_score(&points, &ids, &[0, 10], Some((&model, w(0.0, 1.0))), 3), vec![1, 2, 3]);
        assert_eq!(candidates_to_score(&points, &ids, &[0, 10], Some((&model, w(0.0, 0.0))), 3), vec![5, 4, 6]);
        assert_eq!(scored_count(2, 9), 9);
        assert_eq!(scored_count(10, 100), 40);
    }

    #[test]
    fn choices_are_checked_against_the_plan_and_the_settings() {
        let settings = AdaptiveSettings { budget: 5, rounds: 2, seeds_per_pose: 2, model: "m".into(), model_sha256: "h".into(), steps: 1 };
        let pick = |pose_id: u32, round: usize| AdaptiveChoice {
            pose_id,
            round,
            reason: if round == 1 { ChoiceReason::SpaceFilling } else { ChoiceReason::Acquisition },
            distance: 1.0,
            spread: None,
            error: None,
            score: None,
            distance_weight: None,
            spread_weight: None,
            error_weight: None,
        };
        let plan = |id: u32| id < 10;
        let record = |choices: Vec<AdaptiveChoice>| AdaptiveRecord { settings: settings.clone(), choices };
        assert_eq!(record(vec![]).check_choices("the plan", plan), Ok(()));
        assert_eq!(record(vec![pick(1, 1), pick(2, 1), pick(3, 1)]).check_choices("the plan", plan), Ok(()));
        assert_eq!(record(vec![pick(1, 1), pick(2, 1), pick(3, 1), pick(4, 2), pick(5, 2)]).check_choices("the plan", plan), Ok(()));
        let refused = |choices: Vec<AdaptiveChoice>, says: &str| {
            let e = record(choices).check_choices("the plan", plan).expect_err("refused");
            assert!(e.contains(says), "{e}");
        };
        refused(vec![pick(1, 1), pick(12, 1), pick(3, 1)], "pose 12 (round 1) is not a pose of the plan");
        refused(vec![pick(1, 1), pick(2, 1)], "round 1 records 2 poses; a budget of 5 over 2 rounds presses 3");
        refused(vec![pick(1, 1), pick(2, 1), pick(3, 1), pick(4, 2), pick(5, 2), pick(6, 3)], "round 3 records 1 poses");
    }

    #[test]
    fn normalised_scales_each_axis_by_the_plan_range() {
        let spec = PlanSpec::default();
        let p = [PlannedPose { pose_id: 0, pose: Pose::new(spec.x_mm.max, spec.y_mm.min, 0.0, 0.0) }];
        let n = normalised(&spec, &p);
        assert_eq!(n[0][0], 1.0);
        assert_eq!(n[0][1], 0.0);
    }
}
