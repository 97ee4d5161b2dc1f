//! Statistics over the pairs: the per-method means of the table ([`MethodRow`]) and the model
//! against each baseline pose by pose ([`paired_comparisons`]: mean difference, a bootstrap
//! interval, a verdict, and the ceiling a perfect model would show).

use std::collections::BTreeMap;

use serde::Serialize;

use super::records::{Method, PairRecord};

fn mean(v: impl Iterator<Item = f64>) -> Option<f64> {
    let (sum, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x, n + 1));
    mean_of(sum, n)
}

fn mean_of(sum: f64, n: usize) -> Option<f64> {
    (n > 0 && !sum.is_nan()).then(|| sum / n as f64)
}

/// One row of the table: a method on one sensor's pairs. `None`: no data (shown `n/a`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MethodRow {
    pub sensor: String,
    pub method: Method,
    /// Pairs judged.
    pub n: usize,
    pub ssim: Option<f64>,
    /// Mean of the per-image PSNR, dB; infinite when some image is identical to its truth
    /// (written `null` in JSON, `inf` in the table).
    pub psnr_db: Option<f64>,
    pub mse: Option<f64>,
    /// Pairs whose true image has contact pixels (the contact columns average over these).
    pub n_contact: usize,
    pub contact_ssim: Option<f64>,
    pub contact_psnr_db: Option<f64>,
    pub contact_mse: Option<f64>,
    /// Mean distance between the contact centroid estimated from this method's image and the
    /// centroid of the contact the commanded pose gives the mesh, mm.
    pub position_err_mm: Option<f64>,
    /// Poses with a geometric contact, and of those, poses where this image gave an estimate.
    pub position_attempts: usize,
    pub position_found: usize,
    /// Mean angle between the estimated principal axis and the mesh contact's, degrees
    /// (mod 180, so at most 90), over poses whose mesh contact is not near-isotropic.
    pub yaw_err_deg: Option<f64>,
    pub yaw_attempts: usize,
    pub yaw_found: usize,
    /// The same two errors against the estimate from the true image of the same pose.
    pub position_vs_true_mm: Option<f64>,
    pub yaw_vs_true_deg: Option<f64>,
}

impl MethodRow {
    /// The table row of `method` on `sensor`: the means over its per-pair `records`.
    pub fn from_records(sensor: &str, method: Method, records: &[&PairRecord]) -> Self {
        let over = |f: fn(&PairRecord) -> Option<f64>| mean(records.iter().filter_map(|r| f(r)));
        let count = |f: fn(&PairRecord) -> bool| records.iter().filter(|r| f(r)).count();
        MethodRow {
            sensor: sensor.to_string(),
            method,
            n: count(|r| r.ssim.is_some()),
            ssim: over(|r| r.ssim),
            psnr_db: over(|r| r.psnr_db),
            mse: over(|r| r.mse),
            n_contact: count(|r| r.contact_ssim.is_some()),
            contact_ssim: over(|r| r.contact_ssim),
            contact_psnr_db: over(|r| r.contact_psnr_db),
            contact_mse: over(|r| r.contact_mse),
            position_err_mm: over(|r| r.position_err_mm),
            position_attempts: count(|r| r.mesh_contact),
            position_found: count(|r| r.position_err_mm.is_some()),
            yaw_err_deg: over(|r| r.yaw_err_deg),
            yaw_attempts: count(|r| r.mesh_contact && r.yaw_observable),
            yaw_found: count(|r| r.yaw_err_deg.is_some()),
            position_vs_true_mm: over(|r| r.position_vs_true_mm),
            yaw_vs_true_deg: over(|r| r.yaw_vs_true_deg),
        }
    }
}

/// A figure the model is compared on, pair by pair.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Figure {
    ContactSsim,
    PositionErr,
    YawErr,
}

impl Figure {
    pub const ALL: [Figure; 3] = [Figure::ContactSsim, Figure::PositionErr, Figure::YawErr];

    /// The name in the table.
    pub fn label(&self) -> &'static str {
        match self {
            Figure::ContactSsim => "contact SSIM",
            Figure::PositionErr => "pos err mm",
            Figure::YawErr => "yaw err deg",
        }
    }

    fn of(&self, p: &PairRecord) -> Option<f64> {
        match self {
            Figure::ContactSsim => p.contact_ssim,
            Figure::PositionErr => p.position_err_mm,
            Figure::YawErr => p.yaw_err_deg,
        }
        .filter(|v| v.is_finite())
    }

    /// Whether a larger value is better (SSIM) or worse (errors).
    pub fn higher_is_better(&self) -> bool {
        matches!(self, Figure::ContactSsim)
    }

    pub(super) fn decimals(&self) -> usize {
        match self {
            Figure::ContactSsim => 4,
            Figure::PositionErr => 3,
            Figure::YawErr => 2,
        }
    }
}

/// What a paired comparison shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Verdict {
    /// The 95% interval of the mean difference lies wholly on the model's better side.
    ModelBetter,
    /// ... wholly on its worse side.
    ModelWorse,
    /// The interval holds 0: no difference shown.
    NoDifferenceShown,
    /// Fewer than [`MIN_PAIRS_FOR_VERDICT`] pairs with the figure on both sides.
    TooFewPairs,
}

impl Verdict {
    pub fn label(&self) -> &'static str {
        match self {
            Verdict::ModelBetter => "model better",
            Verdict::ModelWorse => "model worse",
            Verdict::NoDifferenceShown => "no difference shown",
            Verdict::TooFewPairs => "too few pairs",
        }
    }
}

/// Bootstrap resamples behind each interval.
pub const BOOTSTRAP_RESAMPLES: usize = 4000;

/// Fewer pairs than this get no verdict.
pub const MIN_PAIRS_FOR_VERDICT: usize = 10;

/// The model against one baseline on one figure of one sensor, over the pairs where both have
/// that figure (so a method that finds no contact on a hard pose is not averaged over easier
/// poses than the other).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PairedComparison {
    pub sensor: String,
    pub baseline: Method,
    pub figure: Figure,
    /// Pairs where both have the figure.
    pub n: usize,
    pub model_mean: f64,
    pub baseline_mean: f64,
    /// Mean of (model - baseline) over the n pairs.
    pub difference: f64,
    /// 95% percentile-bootstrap interval of that mean ([`BOOTSTRAP_RESAMPLES`] resamples of the
    /// pairs, a fixed seed: the same data gives the same interval).
    pub interval95: [f64; 2],
    pub verdict: Verdict,
    /// What a perfect model would show against the same baseline: the true image in the
    /// model's place ([`Ceiling`]). `None` where no pair has the figure on both sides.
    pub true_image: Option<Ceiling>,
}

/// The true image against a baseline on one figure, as if it were the model: the best any model
/// can show on this test set. Its pose errors are measured like any method's; its contact SSIM
/// is 1 (the image against itself) wherever the baseline has one. Where even this comparison
/// shows no difference, the baseline sits at the estimator's floor and no model can beat it
/// here: "no difference shown" is then the best verdict there is.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Ceiling {
    /// Pairs where the true image and the baseline both have the figure.
    pub n: usize,
    pub true_mean: f64,
    pub baseline_mean: f64,
    /// Mean of (true image - baseline), and its 95% bootstrap interval.
    pub difference: f64,
    pub interval95: [f64; 2],
    /// [`Verdict::ModelBetter`]: the true image beats the baseline, so a model can too.
    pub verdict: Verdict,
}

impl Ceiling {
    /// Whether a model can show that it beats the baseline on this figure here.
    pub fn winnable(&self) -> bool {
        self.verdict == Verdict::ModelBetter
    }
}

/// Mean of `d` and its 95% percentile-bootstrap interval (resampling the entries, fixed seed).
pub fn bootstrap_mean_interval(d: &[f64]) -> Option<(f64, [f64; 2])> {
    use rand::{RngExt, SeedableRng};
    if d.is_empty() || d.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let n = d.len();
    let mean = d.iter().sum::<f64>() / n as f64;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x9a1_4ed);
    let mut means: Vec<f64> = (0..BOOTSTRAP_RESAMPLES).map(|_| (0..n).map(|_| d[rng.random_range(0..n)]).sum::<f64>() / n as f64).collect();
    means.sort_by(f64::total_cmp);
    let lo = means[(BOOTSTRAP_RESAMPLES as f64 * 0.025) as usize];
    let hi = means[((BOOTSTRAP_RESAMPLES as f64 * 0.975).ceil() as usize - 1).min(BOOTSTRAP_RESAMPLES - 1)];
    Some((mean, [lo, hi]))
}

/// One side against another over the pairs where both have a value: (n, means, mean
/// difference, its interval, verdict from the first side's point of view).
struct Paired {
    n: usize,
    means: [f64; 2],
    difference: f64,
    interval95: [f64; 2],
    verdict: Verdict,
}

fn paired(values: &[(f64, f64)], figure: Figure) -> Option<Paired> {
    let d: Vec<f64> = values.iter().map(|(x, y)| x - y).collect();
    let (difference, interval95) = bootstrap_mean_interval(&d)?;
    let n = d.len();
    let verdict = if n < MIN_PAIRS_FOR_VERDICT {
        Verdict::TooFewPairs
    } else if interval95[0] > 0.0 || interval95[1] < 0.0 {
        let first_higher = interval95[0] > 0.0;
        if first_higher == figure.higher_is_better() { Verdict::ModelBetter } else { Verdict::ModelWorse }
    } else {
        Verdict::NoDifferenceShown
    };
    let mean = |f: fn(&(f64, f64)) -> f64| values.iter().map(f).sum::<f64>() / n as f64;
    Some(Paired { n, means: [mean(|v| v.0), mean(|v| v.1)], difference, interval95, verdict })
}

/// The model against pose-blind and nearest-neighbour on every [`Figure`], per sensor, each
/// with its [`Ceiling`].
pub fn paired_comparisons(pairs: &[PairRecord]) -> Vec<PairedComparison> {
    // (sensor, pair) -> method -> record
    let mut by_pair: BTreeMap<(&str, usize), BTreeMap<&str, &PairRecord>> = BTreeMap::new();
    for p in pairs {
        by_pair.entry((p.sensor.as_str(), p.pair)).or_default().insert(p.method, p);
    }
    let sensors: Vec<&str> = {
        let mut v: Vec<&str> = by_pair.keys().map(|(s, _)| *s).collect();
        v.dedup();
        v
    };
    let mut out = Vec::new();
    for sensor in sensors {
        for baseline in [Method::PoseBlind, Method::NearestNeighbour] {
            for figure in Figure::ALL {
                let (mut model, mut truth) = (Vec::new(), Vec::new());
                for methods in by_pair.range((sensor, 0)..=(sensor, usize::MAX)).map(|(_, v)| v) {
                    let get = |method: Method| methods.get(method.label()).and_then(|p| figure.of(p));
                    let Some(b) = get(baseline) else { continue };
                    if let Some(m) = get(Method::Model) {
                        model.push((m, b));
                    }
                    let t = match figure {
                        // The true image against itself; pairs without contact pixels have no
                        // contact SSIM for the baseline either.
                        Figure::ContactSsim => Some(1.0),
                        Figure::PositionErr | Figure::YawErr => get(Method::TrueImage),
                    };
                    if let Some(t) = t {
                        truth.push((t, b));
                    }
                }
                let Some(m) = paired(&model, figure) else { continue };
                let true_image = paired(&truth, figure).map(|t| Ceiling {
                    n: t.n,
                    true_mean: t.means[0],
                    baseline_mean: t.means[1],
                    difference: t.difference,
                    interval95: t.interval95,
                    verdict: t.verdict,
                });
                out.push(PairedComparison {
                    sensor: sensor.to_string(),
                    baseline,
                    figure,
                    n: m.n,
                    model_mean: m.means[0],
                    baseline_mean: m.means[1],
                    difference: m.difference,
                    interval95: m.interval95,
                    verdict: m.verdict,
                    true_image,
                });
            }
        }
    }
    out
}

/// One line per baseline: how many comparisons the model wins, loses and ties, and of the
/// ties, which no model could win (see [`Ceiling`]).
pub fn comparison_summary(comparisons: &[PairedComparison]) -> String {
    let mut s = String::new();
    for baseline in [Method::PoseBlind, Method::NearestNeighbour] {
        let mine: Vec<&PairedComparison> = comparisons.iter().filter(|c| c.baseline == baseline).collect();
        if mine.is_empty() {
            continue;
        }
        let name = |c: &&PairedComparison| format!("{} {}", c.sensor, c.figure.label());
        let with = |v: Verdict| -> Vec<&PairedComparison> { mine.iter().copied().filter(|c| c.verdict == v).collect() };
        let list = |v: &[&PairedComparison]| v.iter().map(name).collect::<Vec<_>>().join(", ");
        let (better, worse, ties, few) =
            (with(Verdict::ModelBetter), with(Verdict::ModelWorse), with(Verdict::NoDifferenceShown), with(Verdict::TooFewPairs));
        let (winnable, floor): (Vec<_>, Vec<_>) = ties.iter().copied().partition(|c| c.true_image.as_ref().is_some_and(Ceiling::winnable));
        s += &format!("\nAgainst {}: model better on {} of {}", baseline.label(), better.len(), mine.len());
        if !worse.is_empty() {
            s += &format!("; worse on {} ({})", worse.len(), list(&worse));
        }
        if !ties.is_empty() {
            s += &format!("; no difference shown on {}", ties.len());
            let mut parts = Vec::new();
            if !floor.is_empty() {
                parts.push(format!("not winnable here, even the true image shows none: {}", list(&floor)));
            }
            if !winnable.is_empty() {
                parts.push(format!("winnable, the true image beats the baseline: {}", list(&winnable)));
            }
            s += &format!(" ({})", parts.join("; "));
        }
        if !few.is_empty() {
            s += &format!("; too few pairs on {}", few.len());
        }
        s += ".\n";
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(pair: usize, method: Method, contact_ssim: Option<f64>, position: Option<f64>, yaw: Option<f64>) -> PairRecord {
        PairRecord {
            pair,
            object: "edge".into(),
            sensor: "vitac".into(),
            pose_id: pair as u32,
            x_mm: 0.0,
            y_mm: 0.0,
            z_mm: 0.0,
            yaw_deg: 0.0,
            method: method.label(),
            ssim: contact_ssim,
            contact_ssim,
            position_err_mm: position,
            yaw_err_deg: yaw,
            position_vs_true_mm: None,
            yaw_vs_true_deg: None,
            psnr_db: None,
            mse: None,
            contact_psnr_db: None,
            contact_mse: None,
            mesh_contact: position.is_some(),
            yaw_observable: yaw.is_some(),
        }
    }

    #[test]
    fn bootstrap_interval_is_tight_on_constants_and_covers_the_mean() {
        let (m, ci) = bootstrap_mean_interval(&[0.25; 30]).expect("interval");
        assert_eq!((m, ci), (0.25, [0.25, 0.25]));
        // -1, +1 alternating: mean 0, an interval around it, narrower than the data's range.
        let d: Vec<f64> = (0..40).map(|i| if i % 2 == 0 { -1.0 } else { 1.0 }).collect();
        let (m, [lo, hi]) = bootstrap_mean_interval(&d).expect("interval");
        assert_eq!(m, 0.0);
        assert!(lo < 0.0 && hi > 0.0 && lo > -0.6 && hi < 0.6, "[{lo}, {hi}]");
        // The standard error of that mean is 1/sqrt(40) = 0.158: the 95% interval is about +-0.31.
        assert!((hi - lo - 2.0 * 1.96 / 40f64.sqrt()).abs() < 0.1, "[{lo}, {hi}]");
        assert_eq!(bootstrap_mean_interval(&d), bootstrap_mean_interval(&d), "same data, same interval");
        assert!(bootstrap_mean_interval(&[]).is_none());
        assert!(bootstrap_mean_interval(&[1.0, f64::NAN]).is_none());
    }

    #[test]
    fn paired_comparisons_give_verdicts_on_common_pairs_only() {
        let mut pairs = Vec::new();
        for i in 0..20 {
            let wobble = if i % 2 == 0 { 0.01 } else { -0.01 };
            // Model: contact SSIM 0.1 higher (better); position 0.5 mm lower (better); yaw
            // 1 deg higher (worse) except where the baseline found none.
            pairs.push(record(i, Method::Model, Some(0.9 + wobble), Some(0.5 + wobble), Some(2.0 + wobble)));
            pairs.push(record(i, Method::NearestNeighbour, Some(0.8), Some(1.0), (i < 15).then_some(1.0)));
            // Pose-blind: the same as the model up to noise of both signs.
            pairs.push(record(i, Method::PoseBlind, Some(0.9 - wobble), Some(0.5 - wobble), Some(2.0 - wobble)));
            pairs.push(record(i, Method::TrueImage, None, Some(0.4), Some(1.0)));
        }
        let c = paired_comparisons(&pairs);
        let find = |b: Method, f: Figure| c.iter().find(|x| x.baseline == b && x.figure == f).expect("comparison");
        let nn_ssim = find(Method::NearestNeighbour, Figure::ContactSsim);
        assert_eq!((nn_ssim.n, nn_ssim.verdict), (20, Verdict::ModelBetter), "{nn_ssim:?}");
        assert!((nn_ssim.difference - 0.1).abs() < 1e-12);
        assert_eq!(find(Method::NearestNeighbour, Figure::PositionErr).verdict, Verdict::ModelBetter);
        let nn_yaw = find(Method::NearestNeighbour, Figure::YawErr);
        assert_eq!((nn_yaw.n, nn_yaw.verdict), (15, Verdict::ModelWorse), "only the 15 pairs where both found a yaw: {nn_yaw:?}");
        // The ceilings: the true image in the model's place.
        let ceiling = |b: Method, f: Figure| find(b, f).true_image.clone().expect("ceiling");
        let ssim = ceiling(Method::NearestNeighbour, Figure::ContactSsim);
        assert_eq!((ssim.n, ssim.true_mean), (20, 1.0), "the true image's contact SSIM is 1: {ssim:?}");
        assert!((ssim.difference - 0.2).abs() < 1e-12 && ssim.winnable(), "{ssim:?}");
        let pos = ceiling(Method::NearestNeighbour, Figure::PositionErr);
        assert!((pos.difference + 0.6).abs() < 1e-12 && pos.winnable(), "true 0.4 mm against 1.0: {pos:?}");
        // The baseline's yaw is as good as the true image's: nobody can beat it, only match it.
        let yaw = ceiling(Method::NearestNeighbour, Figure::YawErr);
        assert_eq!((yaw.n, yaw.difference, yaw.verdict), (15, 0.0, Verdict::NoDifferenceShown), "{yaw:?}");
        assert!(!yaw.winnable());
        // Pose-blind's yaw (2.0) is beaten by the true image (1.0) but not by the model.
        let pb_yaw = find(Method::PoseBlind, Figure::YawErr);
        assert_eq!(pb_yaw.verdict, Verdict::NoDifferenceShown);
        assert!(pb_yaw.true_image.as_ref().is_some_and(Ceiling::winnable), "{pb_yaw:?}");
        for f in Figure::ALL {
            let pb = find(Method::PoseBlind, f);
            assert_eq!(pb.verdict, Verdict::NoDifferenceShown, "{pb:?}");
            assert!(pb.interval95[0] < 0.0 && pb.interval95[1] > 0.0, "{pb:?}");
        }
        let summary = comparison_summary(&c);
        assert!(summary.contains("Against nearest-neighbour: model better on 2 of 3; worse on 1 (vitac yaw err deg)."), "{summary}");
        assert!(
            summary.contains(
                "Against pose-blind: model better on 0 of 3; no difference shown on 3 (winnable, the true image beats the baseline: \
                 vitac contact SSIM, vitac pos err mm, vitac yaw err deg)."
            ),
            "{summary}"
        );
        // A tie the true image cannot break either is listed as not winnable.
        let mut floor = find(Method::NearestNeighbour, Figure::YawErr).clone();
        floor.verdict = Verdict::NoDifferenceShown;
        let summary = comparison_summary(&[floor]);
        assert!(
            summary.contains("no difference shown on 1 (not winnable here, even the true image shows none: vitac yaw err deg)"),
            "{summary}"
        );
        // Too few pairs: no verdict, whatever the difference.
        let few: Vec<PairRecord> = pairs.iter().filter(|p| p.pair < MIN_PAIRS_FOR_VERDICT - 1).cloned().collect();
        assert!(paired_comparisons(&few).iter().all(|x| x.verdict == Verdict::TooFewPairs));
        assert!(paired_comparisons(&[]).is_empty());
    }
}
