//! The report: [`EvalReport`], its Markdown table, JSON and per-pair CSV.

use std::collections::BTreeMap;

use serde::Serialize;

use super::contact::ContactEstimator;
use super::records::{EvalCounts, Method, PairRecord};
use super::statistics::{MIN_PAIRS_FOR_VERDICT, MethodRow, PairedComparison, Verdict, comparison_summary};

/// The result of [`super::evaluate`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EvalReport {
    pub label: String,
    pub size_px: u32,
    pub mask_threshold: f64,
    pub mask_dilate_px: u32,
    pub counts: EvalCounts,
    pub rows: Vec<MethodRow>,
    /// The contact estimator each sensor's images were judged by.
    pub estimators: BTreeMap<String, ContactEstimator>,
    /// The model against each baseline, pair by pair ([`super::paired_comparisons`]).
    pub comparisons: Vec<PairedComparison>,
    /// Every method on every pair, in the order judged (not in the JSON: see [`Self::write_pairs_csv`]).
    #[serde(skip)]
    pub pairs: Vec<PairRecord>,
}

fn cell(v: Option<f64>, decimals: usize) -> String {
    match v {
        Some(x) if x.is_infinite() => "inf".to_string(),
        Some(x) if x.is_finite() => format!("{x:.decimals$}"),
        _ => "n/a".to_string(),
    }
}

/// A recoverability cell: the mean, with `(found/attempts)` when some images gave no estimate.
fn found_cell(v: Option<f64>, found: usize, attempts: usize) -> String {
    let base = cell(v, 2);
    if attempts > 0 && found < attempts { format!("{base} ({found}/{attempts})") } else { base }
}

impl EvalReport {
    /// The Markdown table with its heading and counts.
    pub fn to_markdown(&self) -> String {
        let c = &self.counts;
        let mut s = format!("### rig eval: {} ({} px)\n\n", self.label, self.size_px);
        s += &format!(
            "{} pairs from {} real and {} synthetic datasets; {} collected images for the baselines. \
             Dropped as seen in the collected set: {}. Without a twin: {} real, {} synthetic poses. \
             No contact pixels (left out of the contact columns): {}. Yaw not observable (contact near-isotropic or within the estimator's blur, left out of the yaw columns): {}. \
             No mesh contact (left out of the pose-error columns): {}.\n",
            c.pairs,
            c.real_datasets,
            c.synthetic_datasets,
            c.collected_images,
            c.dropped_seen,
            c.unpaired_real,
            c.unpaired_synthetic,
            c.no_contact_pixels,
            c.yaw_unobservable,
            c.no_geometric_contact
        );
        if !self.estimators.is_empty() {
            let each: Vec<String> = self
                .estimators
                .iter()
                .map(|(sensor, e)| format!("{sensor} blur size/{}, region {}", e.blur_divisor, e.region_fraction))
                .collect();
            s += &format!("Contact estimator: {}.\n", each.join("; "));
        }
        if !c.unpaired_examples.is_empty() {
            s += &format!("Unpaired, e.g.: {}.\n", c.unpaired_examples.join("; "));
        }
        if !c.unmatched_datasets.is_empty() {
            s += &format!("Datasets without a counterpart: {}.\n", c.unmatched_datasets.join("; "));
        }
        if !c.default_calibration_for.is_empty() {
            s += &format!(
                "Calibration file not found, default calibration used (pose errors approximate) for: {}.\n",
                c.default_calibration_for.join(", ")
            );
        }
        if !c.sensors_without_baseline.is_empty() {
            s += &format!("No collected images (baselines n/a) for: {}.\n", c.sensors_without_baseline.join(", "));
        }
        s += "\n| sensor | method | n | SSIM | PSNR dB | MSE | contact SSIM | contact PSNR dB | contact MSE | pos err mm | yaw err deg | pos vs true mm | yaw vs true deg |\n";
        s += "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n";
        for r in &self.rows {
            let image_cols = if r.method == Method::TrueImage {
                ["n/a".to_string(), "n/a".to_string(), "n/a".to_string(), "n/a".to_string(), "n/a".to_string(), "n/a".to_string()]
            } else {
                [
                    cell(r.ssim, 3),
                    cell(r.psnr_db, 2),
                    cell(r.mse, 1),
                    cell(r.contact_ssim, 3),
                    cell(r.contact_psnr_db, 2),
                    cell(r.contact_mse, 1),
                ]
            };
            let n = if r.method == Method::TrueImage { r.position_attempts } else { r.n };
            s += &format!(
                "| {} | {} | {} | {} | {} | {} | {} | {} |\n",
                r.sensor,
                r.method.label(),
                n,
                image_cols.join(" | "),
                found_cell(r.position_err_mm, r.position_found, r.position_attempts),
                found_cell(r.yaw_err_deg, r.yaw_found, r.yaw_attempts),
                cell(r.position_vs_true_mm, 2),
                cell(r.yaw_vs_true_deg, 2),
            );
        }
        if !self.comparisons.is_empty() {
            s += &format!(
                "\nThe model against each baseline, pose by pose: only poses where both have the figure; difference = model - baseline, \
                 its mean with a 95% bootstrap interval; a verdict where the interval excludes 0 (and n >= {MIN_PAIRS_FOR_VERDICT}). \
                 The last two columns put the true image in the model's place (its contact SSIM is 1), over the poses where it and the baseline \
                 have the figure: the best any model can show. \"no\": not even the true image beats the baseline here (the baseline is at the \
                 estimator's floor), so \"no difference shown\" is the best verdict a model can get.\n\n"
            );
            s += "| sensor | baseline | figure | n | model | baseline | difference | 95% interval | verdict | true image - baseline | can a model win |\n";
            s += "|---|---|---|---:|---:|---:|---:|---|---|---|---|\n";
            for c in &self.comparisons {
                let k = c.figure.decimals();
                let (ceiling, winnable) = match &c.true_image {
                    Some(t) => (
                        format!("{:+.k$} [{:+.k$}, {:+.k$}]", t.difference, t.interval95[0], t.interval95[1]),
                        match t.verdict {
                            Verdict::TooFewPairs => "too few pairs",
                            _ if t.winnable() => "yes",
                            _ => "no",
                        },
                    ),
                    None => ("n/a".to_string(), "n/a"),
                };
                s += &format!(
                    "| {} | {} | {} | {} | {:.k$} | {:.k$} | {:+.k$} | [{:+.k$}, {:+.k$}] | {} | {ceiling} | {winnable} |\n",
                    c.sensor,
                    c.baseline.label(),
                    c.figure.label(),
                    c.n,
                    c.model_mean,
                    c.baseline_mean,
                    c.difference,
                    c.interval95[0],
                    c.interval95[1],
                    c.verdict.label(),
                );
            }
            s += &comparison_summary(&self.comparisons);
        }
        s
    }

    /// The report as pretty JSON (non-finite numbers become `null`).
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).unwrap_or_else(|e| format!("{{\"error\": \"{e}\"}}"))
    }

    /// Writes [`Self::pairs`] as CSV (a header, then one line per method and pair; an empty
    /// field is a figure not measured for that pair).
    pub fn write_pairs_csv(&self, out: impl std::io::Write) -> Result<(), csv::Error> {
        let mut w = csv::Writer::from_writer(out);
        for p in &self.pairs {
            w.serialize(p)?;
        }
        w.flush()?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_says_na_not_nan() {
        let row = MethodRow::from_records("vitac", Method::Model, &[]);
        let report = EvalReport {
            label: "t".into(),
            size_px: 64,
            mask_threshold: 10.0,
            mask_dilate_px: 1,
            counts: EvalCounts::default(),
            rows: vec![row],
            estimators: BTreeMap::new(),
            comparisons: Vec::new(),
            pairs: Vec::new(),
        };
        let md = report.to_markdown();
        assert!(md.contains("n/a") && !md.contains("NaN"), "{md}");
        assert!(report.to_json().contains("\"ssim\": null"));
    }
}
