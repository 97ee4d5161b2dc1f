//! The scoring half of `rig audit`: synthesised images of a dataset against the images the rig
//! captured again at the same poses (the audit dataset, `audit/<object>/<sensor>/` beside the
//! dataset's rows).
//!
//! [`score_audit`] runs [`super::evaluate`] with the audit dataset as the real side and the
//! audited dataset as the synthetic side (its captured rows are the collected set the
//! baselines draw on), so every figure, interval and comparison of `rig eval` comes along.
//! Beside rig's figures (SSIM and PSNR on raw RGB, over the frame and over the contact region)
//! it computes MultiDiffSense's own definition ([`mds_ssim_psnr`]: both images turned grey
//! with Rec. 601 luma, each stretched from its own min to its own max onto 0..255, then SSIM
//! and PSNR of the two), and gives every figure's mean a 95% bootstrap interval
//! ([`bootstrap_mean_interval`]). [`worst_poses_panel`] draws the poses of lowest contact SSIM
//! side by side (synthesised | captured).

use std::path::Path;

use image::{GrayImage, Luma, RgbImage};
use serde::Serialize;

use super::error::EvalError;
use super::pairing::load_at;
use super::records::{Method, PairRecord};
use super::report::EvalReport;
use super::run::{EvalOptions, evaluate};
use super::statistics::{Figure, PairedComparison, Verdict, bootstrap_mean_interval};
use crate::dataset::{AuditFigure, SynthesisInfo, read_rows};
use crate::imaging::luma_f64;
use crate::metrics::{MetricsError, psnr, ssim_gray};

/// One audited pose: the synthesised image against the captured one.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AuditPose {
    pub pose_id: u32,
    pub x_mm: f64,
    pub y_mm: f64,
    pub z_mm: f64,
    pub yaw_deg: f64,
    /// rig's figures, on raw RGB ([`PairRecord`] of the model).
    pub ssim: Option<f64>,
    pub psnr_db: Option<f64>,
    pub contact_ssim: Option<f64>,
    pub contact_psnr_db: Option<f64>,
    /// MultiDiffSense's figures: grey, min-max scaled ([`mds_ssim_psnr`]).
    pub mds_ssim: Option<f64>,
    pub mds_psnr_db: Option<f64>,
    /// Pose recoverability of the synthesised image ([`PairRecord::position_err_mm`]).
    pub position_err_mm: Option<f64>,
    pub yaw_err_deg: Option<f64>,
}

/// The audit's figures: per pose, in total (mean and 95% interval), and `rig eval`'s report.
#[derive(Debug, Clone)]
pub struct AuditScores {
    /// In pose-id order.
    pub poses: Vec<AuditPose>,
    /// `rig eval` on the audited poses (baselines, paired comparisons).
    pub eval: EvalReport,
}

/// The grey image of `rgb` (Rec. 601 luma), stretched from its own min to its own max onto
/// 0..=255 (a flat image stays flat, at 0).
pub fn grey_min_max(rgb: &RgbImage) -> GrayImage {
    let luma: Vec<f64> = rgb.as_raw().chunks_exact(3).map(luma_f64).collect();
    let (lo, hi) = luma.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| (lo.min(v), hi.max(v)));
    let span = hi - lo;
    let scaled = luma.iter().map(|&v| if span > 0.0 { ((v - lo) / span * 255.0).round() as u8 } else { 0 });
    let mut out = GrayImage::new(rgb.width(), rgb.height());
    for (px, v) in out.pixels_mut().zip(scaled) {
        *px = Luma([v]);
    }
    out
}

/// SSIM and PSNR (dB) as MultiDiffSense defines them: both images grey and min-max scaled
/// ([`grey_min_max`]), data range 255.
pub fn mds_ssim_psnr(a: &RgbImage, b: &RgbImage) -> Result<(f64, f64), MetricsError> {
    let (ga, gb) = (grey_min_max(a), grey_min_max(b));
    let ssim = ssim_gray(&ga, &gb)?;
    // PSNR of the grey images: the same grey value in all three channels has the grey MSE.
    let rgb = |g: &GrayImage| RgbImage::from_fn(g.width(), g.height(), |x, y| image::Rgb([g.get_pixel(x, y).0[0]; 3]));
    let psnr_db = psnr(&rgb(&ga), &rgb(&gb))?;
    Ok((ssim, psnr_db))
}

/// Scores the synthesised rows of `dataset` against the captured rows of the audit dataset
/// `audit_dataset` (same object and sensor), every image at `size_px` square.
pub fn score_audit(dataset: &Path, audit_dataset: &Path, size_px: u32) -> Result<AuditScores, EvalError> {
    let options = EvalOptions::at_size(size_px, "synthesised poses collected again (rig audit)");
    let eval = evaluate(audit_dataset, dataset, &[], &options)?;
    let wrap = |dir: &Path| {
        let dir = dir.to_path_buf();
        move |source| EvalError::Dataset { dir, source }
    };
    let synthetic = read_rows(dataset).map_err(wrap(dataset))?;
    let captured = read_rows(audit_dataset).map_err(wrap(audit_dataset))?;
    let mut poses = Vec::new();
    for r in eval.pairs.iter().filter(|p| p.method == Method::Model.label()) {
        let (mut mds_ssim, mut mds_psnr_db) = (None, None);
        let synth_row = synthetic.iter().find(|s| s.pose_id == r.pose_id && s.source == crate::dataset::Source::Synthetic);
        let real_row = captured.iter().find(|s| s.pose_id == r.pose_id && s.source.is_captured());
        if let (Some(s), Some(c)) = (synth_row, real_row) {
            let a = load_at(dataset, &s.image, size_px)?;
            let b = load_at(audit_dataset, &c.image, size_px)?;
            if let Ok((ssim, psnr_db)) = mds_ssim_psnr(&b, &a) {
                mds_ssim = Some(ssim);
                mds_psnr_db = Some(psnr_db);
            }
        }
        poses.push(pose_of(r, mds_ssim, mds_psnr_db));
    }
    poses.sort_by_key(|p| p.pose_id);
    Ok(AuditScores { poses, eval })
}

fn pose_of(r: &PairRecord, mds_ssim: Option<f64>, mds_psnr_db: Option<f64>) -> AuditPose {
    AuditPose {
        pose_id: r.pose_id,
        x_mm: r.x_mm,
        y_mm: r.y_mm,
        z_mm: r.z_mm,
        yaw_deg: r.yaw_deg,
        ssim: r.ssim,
        psnr_db: r.psnr_db,
        contact_ssim: r.contact_ssim,
        contact_psnr_db: r.contact_psnr_db,
        mds_ssim,
        mds_psnr_db,
        position_err_mm: r.position_err_mm,
        yaw_err_deg: r.yaw_err_deg,
    }
}

/// The mean of `values` (the finite ones) with its 95% bootstrap interval; `None` when none is
/// finite.
pub fn figure(values: impl Iterator<Item = Option<f64>>) -> Option<AuditFigure> {
    let v: Vec<f64> = values.flatten().filter(|x| x.is_finite()).collect();
    bootstrap_mean_interval(&v).map(|(mean, interval95)| AuditFigure { n: v.len(), mean, interval95 })
}

impl AuditScores {
    /// Contact-region SSIM on RGB, in total.
    pub fn contact_ssim(&self) -> Option<AuditFigure> {
        figure(self.poses.iter().map(|p| p.contact_ssim))
    }

    /// The totals table, one line per figure: (name, figure, decimals).
    pub fn totals(&self) -> Vec<(&'static str, Option<AuditFigure>, usize)> {
        let f = |get: fn(&AuditPose) -> Option<f64>| figure(self.poses.iter().map(get));
        vec![
            ("SSIM (RGB, frame)", f(|p| p.ssim), 3),
            ("PSNR dB (RGB, frame)", f(|p| p.psnr_db), 2),
            ("contact SSIM (RGB)", f(|p| p.contact_ssim), 3),
            ("contact PSNR dB (RGB)", f(|p| p.contact_psnr_db), 2),
            ("SSIM (grey, min-max; MultiDiffSense)", f(|p| p.mds_ssim), 3),
            ("PSNR dB (grey, min-max; MultiDiffSense)", f(|p| p.mds_psnr_db), 2),
            ("position error mm", f(|p| p.position_err_mm), 2),
            ("yaw error deg", f(|p| p.yaw_err_deg), 2),
        ]
    }

    /// The totals with their intervals, as printed and at the top of `report.md`.
    pub fn totals_markdown(&self) -> String {
        let mut s = String::from("| figure | n | mean | 95% interval |\n|---|---:|---:|---|\n");
        for (name, fig, k) in self.totals() {
            match fig {
                Some(f) => s += &format!("| {name} | {} | {:.k$} | [{:.k$}, {:.k$}] |\n", f.n, f.mean, f.interval95[0], f.interval95[1]),
                None => s += &format!("| {name} | 0 | n/a | n/a |\n"),
            }
        }
        s
    }

    /// The per-pose table.
    pub fn poses_markdown(&self) -> String {
        let cell = |v: Option<f64>, k: usize| match v {
            Some(x) if x.is_infinite() => "inf".to_string(),
            Some(x) if x.is_finite() => format!("{x:.k$}"),
            _ => "n/a".to_string(),
        };
        let mut s = String::from(
            "| pose_id | x mm | y mm | z mm | yaw deg | SSIM | PSNR dB | contact SSIM | contact PSNR dB | MDS SSIM | MDS PSNR dB | pos err mm | yaw err deg |\n\
             |---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
        );
        for p in &self.poses {
            s += &format!(
                "| {} | {:.2} | {:.2} | {:.2} | {:.1} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
                p.pose_id,
                p.x_mm,
                p.y_mm,
                p.z_mm,
                p.yaw_deg,
                cell(p.ssim, 3),
                cell(p.psnr_db, 2),
                cell(p.contact_ssim, 3),
                cell(p.contact_psnr_db, 2),
                cell(p.mds_ssim, 3),
                cell(p.mds_psnr_db, 2),
                cell(p.position_err_mm, 2),
                cell(p.yaw_err_deg, 2),
            );
        }
        s
    }

    /// The `count` poses of lowest contact SSIM (a pose without one counts as worst), worst
    /// first.
    pub fn worst(&self, count: usize) -> Vec<&AuditPose> {
        let mut v: Vec<&AuditPose> = self.poses.iter().collect();
        v.sort_by(|a, b| a.contact_ssim.unwrap_or(f64::NEG_INFINITY).total_cmp(&b.contact_ssim.unwrap_or(f64::NEG_INFINITY)));
        v.truncate(count);
        v
    }
}

/// Where the fill stands against one baseline over the audited poses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Standing {
    /// Better on every figure both have.
    Beats,
    /// Worse on every figure both have.
    LosesTo,
    /// Better on some, worse or no different on others.
    Mixed,
    /// No figure to compare.
    Unknown,
}

impl Standing {
    fn verb(self) -> &'static str {
        match self {
            Standing::Beats => "beats",
            Standing::LosesTo => "loses to",
            Standing::Mixed => "does not clearly beat",
            Standing::Unknown => "cannot be compared with",
        }
    }
}

/// The fill against `baseline` on contact SSIM and position error: each paired comparison's
/// verdict where it has one (at least [`super::MIN_PAIRS_FOR_VERDICT`] pairs), else the sign of
/// the difference of the means.
pub fn standing(comparisons: &[PairedComparison], baseline: Method) -> Standing {
    let signs: Vec<i8> = comparisons
        .iter()
        .filter(|c| c.baseline == baseline && c.figure != Figure::YawErr)
        .map(|c| match c.verdict {
            Verdict::ModelBetter => 1,
            Verdict::ModelWorse => -1,
            Verdict::NoDifferenceShown => 0,
            Verdict::TooFewPairs => {
                let better = if c.figure.higher_is_better() { c.difference > 0.0 } else { c.difference < 0.0 };
                let worse = if c.figure.higher_is_better() { c.difference < 0.0 } else { c.difference > 0.0 };
                i8::from(better) - i8::from(worse)
            }
        })
        .collect();
    if signs.is_empty() {
        Standing::Unknown
    } else if signs.iter().all(|&s| s > 0) {
        Standing::Beats
    } else if signs.iter().all(|&s| s < 0) {
        Standing::LosesTo
    } else {
        Standing::Mixed
    }
}

/// The audit's verdict, one line: where the fill stands against the pose-blind and the
/// nearest-neighbour baselines (contact SSIM, position error, over the poses both have), how
/// sure that is, and, unless it beats both, the likely cause: the upscale the manifest's
/// `[synthesis]` records, else the model itself.
pub fn verdict_line(comparisons: &[PairedComparison], synthesis: Option<&SynthesisInfo>) -> String {
    let (pb, nn) = (standing(comparisons, Method::PoseBlind), standing(comparisons, Method::NearestNeighbour));
    if pb == Standing::Unknown && nn == Standing::Unknown {
        return "verdict: none: no audited pose has a contact SSIM or a position error to set against the baselines".to_string();
    }
    let mut s = if pb == nn {
        format!("verdict: the fill {} both baselines", pb.verb())
    } else {
        format!("verdict: the fill {} the pose-blind baseline and {} the nearest neighbour", pb.verb(), nn.verb())
    };
    let find = |b: Method, f: Figure| comparisons.iter().find(|c| c.baseline == b && c.figure == f);
    let mut figures = Vec::new();
    for (figure, name, unit, k) in [(Figure::ContactSsim, "contact SSIM", "", 3), (Figure::PositionErr, "position error", " mm", 2)] {
        let (p, n) = (find(Method::PoseBlind, figure), find(Method::NearestNeighbour, figure));
        let Some(model) = p.or(n).map(|c| c.model_mean) else { continue };
        let other = |c: Option<&PairedComparison>, label: &str| c.map(|c| format!("{:.k$}{unit} {label}", c.baseline_mean));
        let others: Vec<String> = [other(p, "pose-blind"), other(n, "nearest neighbour")].into_iter().flatten().collect();
        figures.push(format!("{name} {model:.k$}{unit} against {}", others.join(" and ")));
    }
    let n = comparisons.iter().filter(|c| c.figure != Figure::YawErr).map(|c| c.n).max().unwrap_or(0);
    let sure = if comparisons.iter().any(|c| c.figure != Figure::YawErr && c.verdict == Verdict::TooFewPairs) {
        format!("{n} poses: means only, a 95% verdict needs {}", super::MIN_PAIRS_FOR_VERDICT)
    } else {
        format!("{n} poses, 95% intervals")
    };
    if !figures.is_empty() {
        s += &format!(" ({}; {sure})", figures.join("; "));
    }
    if pb == Standing::Beats && nn == Standing::Beats {
        s += ": worth training on by this measure.";
        return s;
    }
    s += &match synthesis {
        Some(info) if info.upscales() => format!(
            ". Likely cause: the fill upscales {} from the model's {} px to the frames' {} px, which blurs what the model drew \
             (`rig synth --poses-of` and `rig eval` judge the model at its own size; a model trained at {} px needs no upscale).",
            info.upscale_text(),
            info.model_resolution_px[0],
            info.image_resolution_px[0],
            info.image_resolution_px[0]
        ),
        Some(info) => format!(
            ". Likely cause: the model ({}) itself: its images are written at its own {} px, not resampled.",
            info.model, info.model_resolution_px[0]
        ),
        None => ". Cause unknown: the manifest does not record the model's resolution (filled before rig recorded it; \
                 a fill now records it under [synthesis])."
            .to_string(),
    };
    s
}

/// One row per pose of `worst`: the synthesised image (from `dataset`) beside the captured one
/// (from `audit_dataset`), each at `size_px` square. `None` when `worst` is empty.
pub fn worst_poses_panel(dataset: &Path, audit_dataset: &Path, worst: &[&AuditPose], size_px: u32) -> Result<Option<RgbImage>, EvalError> {
    if worst.is_empty() {
        return Ok(None);
    }
    let image_of = |dir: &Path, synthetic: bool, pose_id: u32| -> Result<RgbImage, EvalError> {
        let rows = read_rows(dir).map_err(|source| EvalError::Dataset { dir: dir.to_path_buf(), source })?;
        let row = rows.iter().find(|r| r.pose_id == pose_id && (r.source == crate::dataset::Source::Synthetic) == synthetic);
        match row {
            Some(r) => load_at(dir, &r.image, size_px),
            None => Ok(RgbImage::new(size_px, size_px)),
        }
    };
    let mut out = RgbImage::new(2 * size_px, worst.len() as u32 * size_px);
    for (k, p) in worst.iter().enumerate() {
        let y = (k as u32 * size_px) as i64;
        image::imageops::replace(&mut out, &image_of(dataset, true, p.pose_id)?, 0, y);
        image::imageops::replace(&mut out, &image_of(audit_dataset, false, p.pose_id)?, size_px as i64, y);
    }
    Ok(Some(out))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::test_images::disc;

    #[test]
    fn min_max_scaling_makes_a_dimmer_copy_score_as_the_same_image() {
        let a = disc(64, 30.0, 32.0, 12.0, 9.0);
        // The same picture at half the brightness and lifted: raw RGB sees a different image,
        // MultiDiffSense's grey min-max definition sees the same one.
        let dim = RgbImage::from_fn(64, 64, |x, y| {
            let v = a.get_pixel(x, y).0[0] / 2 + 40;
            image::Rgb([v, v, v])
        });
        let (ssim, psnr_db) = mds_ssim_psnr(&a, &dim).expect("scores");
        assert!((ssim - 1.0).abs() < 1e-9, "{ssim}");
        assert!(psnr_db.is_infinite(), "{psnr_db}");
        let raw = crate::metrics::ssim(&a, &dim).expect("ssim");
        assert!(raw < 0.9, "raw RGB SSIM {raw} should see the change");
        // A moved disc is a different image under both.
        let moved = disc(64, 40.0, 32.0, 12.0, 9.0);
        let (ssim_moved, _) = mds_ssim_psnr(&a, &moved).expect("scores");
        assert!(ssim_moved < 0.9, "{ssim_moved}");
    }

    #[test]
    fn a_flat_image_scales_to_zero_not_nan() {
        let flat = RgbImage::from_pixel(32, 32, image::Rgb([90, 90, 90]));
        let g = grey_min_max(&flat);
        assert!(g.pixels().all(|p| p.0[0] == 0));
        let (ssim, _) = mds_ssim_psnr(&flat, &flat).expect("scores");
        assert!(ssim.is_finite());
    }

    #[test]
    fn worst_puts_missing_contact_ssim_first_then_the_lowest() {
        let pose = |id, c| AuditPose {
            pose_id: id,
            x_mm: 0.0,
            y_mm: 0.0,
            z_mm: 0.0,
            yaw_deg: 0.0,
            ssim: None,
            psnr_db: None,
            contact_ssim: c,
            contact_psnr_db: None,
            mds_ssim: None,
            mds_psnr_db: None,
            position_err_mm: None,
            yaw_err_deg: None,
        };
        let scores = AuditScores {
            poses: vec![pose(1, Some(0.9)), pose(2, Some(0.2)), pose(3, None), pose(4, Some(0.5))],
            eval: EvalReport {
                label: "t".into(),
                size_px: 64,
                mask_threshold: 10.0,
                mask_dilate_px: 1,
                counts: Default::default(),
                rows: Vec::new(),
                estimators: Default::default(),
                comparisons: Vec::new(),
                pairs: Vec::new(),
            },
        };
        let ids: Vec<u32> = scores.worst(3).iter().map(|p| p.pose_id).collect();
        assert_eq!(ids, vec![3, 2, 4]);
        let total = scores.contact_ssim().expect("figure");
        assert_eq!(total.n, 3);
        assert!((total.mean - (0.9 + 0.2 + 0.5) / 3.0).abs() < 1e-12);
        assert!(total.interval95[0] <= total.mean && total.mean <= total.interval95[1]);
    }

    fn comparison(baseline: Method, figure: Figure, model: f64, other: f64, n: usize, verdict: Verdict) -> PairedComparison {
        PairedComparison {
            sensor: "tactip".into(),
            baseline,
            figure,
            n,
            model_mean: model,
            baseline_mean: other,
            difference: model - other,
            interval95: [model - other - 0.01, model - other + 0.01],
            verdict,
            true_image: None,
        }
    }

    #[test]
    fn the_verdict_names_both_baselines_and_the_upscale_as_the_likely_cause() {
        use Method::{NearestNeighbour as Nn, PoseBlind as Pb};
        // The demo's TacTip audit: both baselines beat the fill, 9 poses (too few for intervals).
        let few = Verdict::TooFewPairs;
        let losing = [
            comparison(Pb, Figure::ContactSsim, 0.939, 0.959, 7, few),
            comparison(Nn, Figure::ContactSsim, 0.939, 0.973, 7, few),
            comparison(Pb, Figure::PositionErr, 3.09, 2.5, 9, few),
            comparison(Nn, Figure::PositionErr, 3.09, 0.32, 9, few),
            // Yaw is left out: a sphere's yaw is not observable.
            comparison(Nn, Figure::YawErr, 0.1, 9.0, 9, few),
        ];
        let upscaled = SynthesisInfo {
            model: "default".into(),
            model_dir: "models/default".into(),
            model_resolution_px: [128, 128],
            image_resolution_px: [512, 512],
        };
        let line = verdict_line(&losing, Some(&upscaled));
        assert!(line.starts_with("verdict: the fill loses to both baselines"), "{line}");
        assert!(line.contains("contact SSIM 0.939 against 0.959 pose-blind and 0.973 nearest neighbour"), "{line}");
        assert!(line.contains("position error 3.09 mm against 2.50 mm pose-blind and 0.32 mm nearest neighbour"), "{line}");
        assert!(line.contains("9 poses: means only, a 95% verdict needs 10"), "{line}");
        assert!(line.contains("Likely cause: the fill upscales 4x from the model's 128 px to the frames' 512 px"), "{line}");
        assert_eq!(line.lines().count(), 1);
        // Without the record, the cause is unknown; at the model's own size, the model is.
        assert!(verdict_line(&losing, None).contains("Cause unknown"), "{}", verdict_line(&losing, None));
        let native = SynthesisInfo { image_resolution_px: [128, 128], ..upscaled.clone() };
        assert!(verdict_line(&losing, Some(&native)).contains("Likely cause: the model (default) itself"));

        // A fill better on both figures against both, with enough pairs: no cause to name.
        let better = Verdict::ModelBetter;
        let winning = [
            comparison(Pb, Figure::ContactSsim, 0.99, 0.95, 40, better),
            comparison(Nn, Figure::ContactSsim, 0.99, 0.97, 40, better),
            comparison(Pb, Figure::PositionErr, 0.3, 2.0, 40, better),
            comparison(Nn, Figure::PositionErr, 0.3, 0.5, 40, better),
        ];
        let line = verdict_line(&winning, Some(&upscaled));
        assert!(line.starts_with("verdict: the fill beats both baselines"), "{line}");
        assert!(line.contains("40 poses, 95% intervals") && line.ends_with("worth training on by this measure."), "{line}");
        assert!(!line.contains("cause"), "{line}");
        // Mixed: better than pose-blind, no difference shown against the nearest neighbour.
        let mut mixed = winning.clone();
        mixed[1].verdict = Verdict::NoDifferenceShown;
        let line = verdict_line(&mixed, Some(&upscaled));
        assert!(
            line.starts_with("verdict: the fill beats the pose-blind baseline and does not clearly beat the nearest neighbour"),
            "{line}"
        );
        assert!(line.contains("Likely cause: the fill upscales 4x"), "{line}");
        assert!(verdict_line(&[], None).starts_with("verdict: none: "), "{}", verdict_line(&[], None));
    }
}
