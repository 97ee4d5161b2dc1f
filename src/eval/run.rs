//! [`evaluate`]: the run. Reads the three sides, pairs real and synthetic datasets by object
//! and sensor and their rows by commanded pose, drops the poses the collected set has, judges
//! every pair ([`super::judge`]) and sums the records up into the report.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use super::baselines::Collected;
use super::contact::ContactEstimator;
use super::error::EvalError;
use super::judge::{DatasetJudge, JudgeSettings};
use super::pairing::{Sides, describe, pair_rows};
use super::records::{EvalCounts, Method, PairRecord};
use super::report::EvalReport;
use super::statistics::{MethodRow, paired_comparisons};
use crate::dataset::Source;

/// Smallest `size_px`: the SSIM window.
pub const MIN_SIZE_PX: u32 = 11;

/// Settings of an evaluation.
#[derive(Debug, Clone, PartialEq)]
pub struct EvalOptions {
    /// Every image is resized to `size_px` x `size_px` before it is measured.
    pub size_px: u32,
    /// What the test set is (e.g. "unseen poses"); the table's heading.
    pub label: String,
    /// A pixel belongs to the contact region when the true image's change from the reference
    /// (largest channel difference, 3 x 3 box mean) exceeds this, grey levels.
    pub mask_threshold: f64,
    /// The region is then dilated by this many pixels (square).
    pub mask_dilate_px: u32,
    /// Only these objects of the real and synthetic sides (empty: all). The collected set is
    /// not filtered: baselines may use any object of the sensor.
    pub objects: Vec<String>,
    /// The contact estimator for every sensor (None: each sensor's own,
    /// [`ContactEstimator::for_sensor`]).
    pub estimator: Option<ContactEstimator>,
}

impl EvalOptions {
    /// Defaults at a size: threshold 10 levels, dilation `size / 64` px (2 px at 128).
    pub fn at_size(size_px: u32, label: &str) -> Self {
        Self {
            size_px,
            label: label.to_string(),
            mask_threshold: 10.0,
            mask_dilate_px: (size_px / 64).max(1),
            objects: Vec::new(),
            estimator: None,
        }
    }
}

impl Default for EvalOptions {
    fn default() -> Self {
        Self::at_size(128, "test set")
    }
}

/// At most this many unpaired poses are named in the counts.
const UNPAIRED_EXAMPLES: usize = 5;

/// Runs the evaluation (see the module docs). `collected` empty: the real rows of the
/// synthetic datasets are the collected set.
pub fn evaluate(real_root: &Path, synthetic_root: &Path, collected: &[PathBuf], options: &EvalOptions) -> Result<EvalReport, EvalError> {
    let size = options.size_px;
    if size < MIN_SIZE_PX {
        return Err(EvalError::BadSize { size_px: size, min: MIN_SIZE_PX });
    }
    let sides = Sides::load(real_root, synthetic_root, collected, &options.objects)?;
    let collected = Collected::load(&sides.collected, size)?;
    let mut counts = EvalCounts {
        real_datasets: sides.real.len(),
        synthetic_datasets: sides.synthetic.len(),
        collected_images: collected.images,
        ..EvalCounts::default()
    };
    let mut pairs: Vec<PairRecord> = Vec::new();
    let mut estimators = BTreeMap::new();
    let matched = judge_datasets(&sides, &collected, options, &mut counts, &mut pairs, &mut estimators)?;
    if counts.pairs == 0 {
        return Err(EvalError::NoPairs {
            real_datasets: sides.real.len(),
            synthetic_datasets: sides.synthetic.len(),
            matched_datasets: matched,
            unpaired_real: counts.unpaired_real,
            unpaired_synthetic: counts.unpaired_synthetic,
            dropped_seen: counts.dropped_seen,
        });
    }
    let rows = method_rows(&pairs, &collected, &mut counts);
    Ok(EvalReport {
        label: options.label.clone(),
        size_px: size,
        mask_threshold: options.mask_threshold,
        mask_dilate_px: options.mask_dilate_px,
        counts,
        rows,
        estimators,
        comparisons: paired_comparisons(&pairs),
        pairs,
    })
}

/// Judges every real dataset against its synthetic twin dataset (same object and sensor),
/// counting the datasets and rows without a counterpart; returns how many datasets matched.
fn judge_datasets(
    sides: &Sides,
    collected: &Collected,
    options: &EvalOptions,
    counts: &mut EvalCounts,
    pairs: &mut Vec<PairRecord>,
    estimators: &mut BTreeMap<String, ContactEstimator>,
) -> Result<usize, EvalError> {
    for (key, s) in &sides.synthetic {
        if !sides.real.contains_key(key) {
            counts.unmatched_datasets.push(format!("synthetic {} ({}/{})", s.dir.display(), key.0, key.1));
            counts.unpaired_synthetic += s.rows_of(Source::Synthetic).count();
        }
    }
    let mut matched = 0usize;
    for (key, r) in &sides.real {
        let (object, sensor) = key;
        let Some(s) = sides.synthetic.get(key) else {
            counts.unmatched_datasets.push(format!("real {} ({object}/{sensor})", r.dir.display()));
            counts.unpaired_real += r.captured_rows().count();
            continue;
        };
        matched += 1;
        let estimator = options.estimator.unwrap_or_else(|| ContactEstimator::for_sensor(sensor));
        let settings = JudgeSettings {
            size_px: options.size_px,
            mask_threshold: options.mask_threshold,
            mask_dilate_px: options.mask_dilate_px,
            estimator,
        };
        let judge = DatasetJudge::new(key, r, s, collected, settings, counts)?;
        estimators.insert(sensor.clone(), estimator);
        let rows = pair_rows(r, s);
        for row in &rows.unpaired_real {
            counts.unpaired_real += 1;
            if counts.unpaired_examples.len() < UNPAIRED_EXAMPLES {
                counts.unpaired_examples.push(describe(object, sensor, "real", row));
            }
        }
        for (row, twin) in &rows.twins {
            if judge.seen(&row.commanded()) {
                counts.dropped_seen += 1;
                continue;
            }
            judge.judge(row, twin, counts, pairs)?;
        }
        for t in &rows.unpaired_synthetic {
            counts.unpaired_synthetic += 1;
            if counts.unpaired_examples.len() < UNPAIRED_EXAMPLES {
                counts.unpaired_examples.push(describe(object, sensor, "synthetic", t));
            }
        }
    }
    Ok(matched)
}

/// The table: one row per sensor judged and method, in sensor then [`Method::ALL`] order;
/// notes the sensors without a collected image (their baselines are `n/a`).
fn method_rows(pairs: &[PairRecord], collected: &Collected, counts: &mut EvalCounts) -> Vec<MethodRow> {
    let sensors: BTreeSet<&str> = pairs.iter().map(|p| p.sensor.as_str()).collect();
    let mut rows = Vec::new();
    for sensor in sensors {
        if collected.by_sensor.get(sensor).is_none_or(|c| c.mean.is_none()) {
            counts.sensors_without_baseline.push(sensor.to_string());
        }
        for method in Method::ALL {
            let records: Vec<&PairRecord> = pairs.iter().filter(|p| p.sensor == sensor && p.method == method.label()).collect();
            rows.push(MethodRow::from_records(sensor, method, &records));
        }
    }
    rows
}
