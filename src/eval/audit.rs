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
use super::statistics::bootstrap_mean_interval;
use crate::dataset::{AuditFigure, read_rows};
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
}
