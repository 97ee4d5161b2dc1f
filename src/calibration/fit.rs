//! The robust point fit: sensor-frame mm to image px from correspondences.
//!
//! Input: [`FitPoint`]s (a contact's sensor-frame position in mm, the press depth, and where
//! it was detected in the image, px). Output: a [`Calibration`] of the module's model (centre,
//! rotation, one scale per axis, a negative y scale is a mirrored image; and the depth term)
//! plus a [`PointFit`] report.
//!
//! Stages:
//!
//! 1. Checks: every number finite, at least [`MIN_POINTS`] points, the mm points spread in
//!    two directions ([`FitError::AllAtOneSpot`], [`FitError::Collinear`]), the pixels not all
//!    at one spot. The conditioning reported is the ratio of the mm spread's principal axes
//!    (the condition number of the normalised design): 1 for a square pattern, large for a
//!    thin one.
//! 2. An affine least-squares fit on normalised coordinates (mean removed, divided by the RMS
//!    spread, so any magnitude that fits in an f64 stays well scaled), decomposed into
//!    rotation, x scale (kept positive) and y scale; what the model cannot express (shear) is
//!    reported as [`PointFit::shear`].
//! 3. Gauss-Newton (Levenberg damped) on the five model parameters with Huber weights
//!    (iteratively reweighted), starting from stage 2.
//! 4. The depth term ([`DepthTerm`]): when the points' press depths span at least
//!    [`FitOptions::min_depth_range_mm`] and the design conditions it (the standard error the
//!    term would have per px of detection noise, from the Gauss-Newton normal matrix, is at
//!    most [`FitOptions::max_depth_error_per_px`]), Gauss-Newton (Huber weighted, damped) on
//!    all six parameters from stage 3's result with the term at 0. Otherwise the term is
//!    left at 0 and the report says why. The scales and the depth term are nearly collinear
//!    when every press is at one depth (a deeper press looks like a larger scale), which is
//!    why a narrow depth range is refused rather than fitted.
//! 5. Outlier rejection: points further than `max(k * robust sigma, floor)` from the model are
//!    dropped and stages 2-4 rerun on the inliers (if enough remain and they are not
//!    degenerate).
//!
//! Whatever the input, the result is either an error or a calibration whose numbers are all
//! finite (checked last, so a numerically hopeless input is an error, never NaN).

// `!(a > b)` is deliberate here: a NaN must fail every check, which `a <= b` would not.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use super::{Calibration, FitPoint, FitRecord};

/// Fewest points the fit accepts (five parameters; three points in general position fix an
/// affine map, the extra constraints come from the model having no shear).
pub const MIN_POINTS: usize = 3;

/// Why a point set cannot be fitted.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FitError {
    #[error("{given} points given, at least {needed} are needed")]
    TooFewPoints { given: usize, needed: usize },
    #[error("point {index} is not finite: mm {mm:?}, px {px:?}")]
    NotFinite { index: usize, mm: [f64; 2], px: [f64; 2] },
    #[error("all points lie at one spot (spread {spread_mm:.3e} mm): move the indenter between presses")]
    AllAtOneSpot { spread_mm: f64 },
    #[error(
        "the points lie on a line (spread {minor_mm:.3e} mm across it, {major_mm:.3e} mm along it, condition {condition:.3e}): press off that line too"
    )]
    Collinear { major_mm: f64, minor_mm: f64, condition: f64 },
    #[error("all detections lie at one pixel spot (spread {spread_px:.3e} px): the contact was not seen moving")]
    PixelsAtOneSpot { spread_px: f64 },
    #[error("the fit did not give finite numbers (input too extreme)")]
    NonFiniteResult,
    #[error("after rejecting outliers only {inliers} of {given} points are left")]
    TooManyOutliers { inliers: usize, given: usize },
}

/// Settings of [`fit_points`].
#[derive(Debug, Clone, PartialEq)]
pub struct FitOptions {
    /// Huber threshold, px: residuals above it weigh less (linear instead of quadratic loss).
    pub huber_px: f64,
    /// Outliers: further than this many robust sigmas from the model...
    pub outlier_sigmas: f64,
    /// ...and further than this, px (so noise-free data does not reject good points).
    pub outlier_floor_px: f64,
    /// Smallest ratio of minor to major mm spread accepted (1/condition number).
    pub min_spread_ratio: f64,
    /// Smallest mm spread accepted, mm.
    pub min_spread_mm: f64,
    /// Image size written into the calibration, px.
    pub image_size: [u32; 2],
    /// Fit the depth term when the points condition it (stage 4); `false` leaves it 0.
    pub fit_depth: bool,
    /// Smallest spread of press depths (largest minus smallest) the depth term is fitted
    /// from, mm.
    pub min_depth_range_mm: f64,
    /// Largest standard error of the depth term per px of detection noise accepted, 1/mm per
    /// px (0.03: with the usual 0.3-0.5 px of detection noise the term is known to about
    /// ±0.01 per mm, a third of a pixel over the pattern's reach).
    pub max_depth_error_per_px: f64,
    /// Largest standard error of the fitted depth term accepted, 1/mm (from the fit's own
    /// residuals): a term the data do not pin down is left at 0 rather than stored.
    pub max_depth_std_error_per_mm: f64,
}

impl Default for FitOptions {
    fn default() -> Self {
        Self {
            huber_px: 1.5,
            outlier_sigmas: 4.0,
            outlier_floor_px: 3.0,
            min_spread_ratio: 1e-3,
            min_spread_mm: 1e-3,
            image_size: [512, 512],
            fit_depth: true,
            min_depth_range_mm: 0.3,
            max_depth_error_per_px: 0.03,
            max_depth_std_error_per_mm: 0.02,
        }
    }
}

/// What became of the depth term (stage 4 of the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DepthTerm {
    /// Fitted: the value, its standard error (from the residuals and the normal matrix), and
    /// the range of press depths it was fitted over.
    Fitted { per_mm: f64, std_error_per_mm: f64, depth_range_mm: [f64; 2] },
    /// Left at 0, and why.
    NotFitted(DepthRefusal),
}

/// Why the depth term was left at 0.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum DepthRefusal {
    #[error("depth fit disabled")]
    Disabled,
    #[error("press depths span only {range_mm:.2} mm (need {min_mm:.2} mm): press at two depths or more")]
    NarrowDepths { range_mm: f64, min_mm: f64 },
    #[error(
        "the pattern does not condition it: standard error {error_per_px:.3} /mm per px of noise (at most {max_per_px:.3}): press off-centre points at each depth"
    )]
    IllConditioned { error_per_px: f64, max_per_px: f64 },
    #[error("the fitted term {per_mm:.4} /mm is beyond ±{max:.2} /mm")]
    OutOfRange { per_mm: f64, max: f64 },
    #[error(
        "the fitted term {per_mm:+.4} /mm has a standard error of {std_error_per_mm:.4} /mm (at most {max:.4}): the residuals are too large to trust it"
    )]
    Uncertain { per_mm: f64, std_error_per_mm: f64, max: f64 },
}

impl std::fmt::Display for DepthTerm {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Fitted { per_mm, std_error_per_mm, depth_range_mm } => write!(
                f,
                "{per_mm:+.4} /mm (± {std_error_per_mm:.4}), fitted over press depths {:.2}..{:.2} mm",
                depth_range_mm[0], depth_range_mm[1]
            ),
            Self::NotFitted(why) => write!(f, "not fitted, left 0: {why}"),
        }
    }
}

/// What the fit found besides the calibration.
#[derive(Debug, Clone, PartialEq)]
pub struct PointFit {
    pub calibration: Calibration,
    /// Distance from the model per point, px (outliers included).
    pub residuals_px: Vec<f64>,
    /// Whether each point was kept.
    pub inlier: Vec<bool>,
    /// RMS of the inliers' residuals, px.
    pub rms_px: f64,
    /// The same in mm (divided by the mean absolute scale).
    pub rms_mm: f64,
    /// Largest inlier residual, px.
    pub max_px: f64,
    /// Condition number of the normalised mm design (1 = ideal).
    pub condition: f64,
    /// Shear of the unconstrained affine fit (cosine of the angle between its image axes):
    /// what the model without shear cannot express.
    pub shear: f64,
    /// The depth term, or why it was not fitted.
    pub depth: DepthTerm,
}

impl PointFit {
    /// `residual 0.21 px (0.025 mm)`.
    pub fn residual_line(&self) -> String {
        format!("residual {:.2} px ({:.3} mm)", self.rms_px, self.rms_mm)
    }
}

/// Fits the model to `points` robustly (see the module docs). `method` goes into the
/// calibration's [`FitRecord`].
pub fn fit_points(points: &[FitPoint], options: &FitOptions, method: &str) -> Result<PointFit, FitError> {
    for (index, p) in points.iter().enumerate() {
        if !p.mm.iter().chain(p.px.iter()).all(|v| v.is_finite()) {
            return Err(FitError::NotFinite { index, mm: p.mm, px: p.px });
        }
    }
    if !points.iter().all(|p| p.depth_mm.is_finite()) {
        let index = points.iter().position(|p| !p.depth_mm.is_finite()).unwrap_or(0);
        return Err(FitError::NotFinite { index, mm: points[index].mm, px: points[index].px });
    }
    let all: Vec<usize> = (0..points.len()).collect();
    let (mut params, mut condition, mut shear) = fit_subset(points, &all, options)?;
    let mut depth;
    (params, depth) = fit_depth_term(points, &all, params, options);
    let mut residuals = residuals_of(&params, points);
    let mut inlier = vec![true; points.len()];

    // One round of outlier rejection, then a refit on what is left.
    let sigma = robust_sigma(&residuals);
    let limit = (options.outlier_sigmas * sigma).max(options.outlier_floor_px);
    let keep: Vec<usize> = all.iter().copied().filter(|&i| residuals[i] <= limit).collect();
    if keep.len() < points.len() {
        if keep.len() < MIN_POINTS.max(points.len() / 2) {
            return Err(FitError::TooManyOutliers { inliers: keep.len(), given: points.len() });
        }
        (params, condition, shear) = fit_subset(points, &keep, options)?;
        (params, depth) = fit_depth_term(points, &keep, params, options);
        residuals = residuals_of(&params, points);
        for (i, flag) in inlier.iter_mut().enumerate() {
            *flag = keep.contains(&i);
        }
    }

    let kept: Vec<f64> = residuals.iter().zip(&inlier).filter(|(_, k)| **k).map(|(r, _)| *r).collect();
    let rms_px = (kept.iter().map(|r| r * r).sum::<f64>() / kept.len().max(1) as f64).sqrt();
    let max_px = kept.iter().copied().fold(0.0, f64::max);
    let mean_scale = (params.sx.abs() + params.sy.abs()) / 2.0;
    let rms_mm = rms_px / mean_scale;
    let calibration = Calibration {
        centre_px: [params.cu, params.cv],
        scale_px_per_mm: [params.sx, params.sy],
        rotation_deg: crate::pose::wrap_deg(params.theta.to_degrees()),
        image_size: options.image_size,
        depth_scale_per_mm: params.k,
        fit: Some(FitRecord {
            method: method.to_string(),
            frames: Vec::new(),
            points: points.to_vec(),
            residuals_px: residuals.clone(),
            rms_px: Some(rms_px),
            iou: Vec::new(),
            notes: format!(
                "robust point fit: {} of {} points inliers, max {:.3} px, condition {:.2}, affine shear {:.4}; depth term {}",
                kept.len(),
                points.len(),
                max_px,
                condition,
                shear,
                depth
            ),
        }),
        pose_xy_correction: None,
    };
    let numbers = [rms_px, rms_mm, max_px, condition, shear, params.cu, params.cv, params.sx, params.sy, params.theta, params.k];
    if !numbers.iter().chain(residuals.iter()).all(|v| v.is_finite()) || params.sx.abs() < 1e-9 || params.sy.abs() < 1e-9 {
        return Err(FitError::NonFiniteResult);
    }
    Ok(PointFit { calibration, residuals_px: residuals, inlier, rms_px, rms_mm, max_px, condition, shear, depth })
}

/// The model parameters: centre (px), rotation (rad), scales (px/mm), depth term (1/mm).
#[derive(Debug, Clone, Copy)]
struct Params {
    cu: f64,
    cv: f64,
    theta: f64,
    sx: f64,
    sy: f64,
    k: f64,
}

impl Params {
    /// The map at press depth 0 (stages 2-3 fit this one, on normalised coordinates).
    fn apply(&self, mm: [f64; 2]) -> [f64; 2] {
        self.apply_at(mm, 0.0)
    }

    fn apply_at(&self, mm: [f64; 2], depth_mm: f64) -> [f64; 2] {
        let (s, c) = self.theta.sin_cos();
        let f = 1.0 + self.k * depth_mm;
        let (a, b) = (f * self.sx * mm[0], f * self.sy * mm[1]);
        [self.cu + c * a - s * b, self.cv + s * a + c * b]
    }

    /// Derivatives of the model's (u, v) at a point by (cu, cv, theta, sx, sy, k).
    fn jacobian(&self, mm: [f64; 2], depth_mm: f64) -> ([f64; 6], [f64; 6]) {
        let (s, c) = self.theta.sin_cos();
        let f = 1.0 + self.k * depth_mm;
        let (a, b) = (f * self.sx * mm[0], f * self.sy * mm[1]);
        let (ka, kb) = (depth_mm * self.sx * mm[0], depth_mm * self.sy * mm[1]);
        (
            [1.0, 0.0, -s * a - c * b, c * f * mm[0], -s * f * mm[1], c * ka - s * kb],
            [0.0, 1.0, c * a - s * b, s * f * mm[0], c * f * mm[1], s * ka + c * kb],
        )
    }
}

fn residuals_of(p: &Params, points: &[FitPoint]) -> Vec<f64> {
    points
        .iter()
        .map(|q| {
            let m = p.apply_at(q.mm, q.depth_mm);
            (m[0] - q.px[0]).hypot(m[1] - q.px[1])
        })
        .collect()
}

/// Stage 4: the depth term on the points `idx`, from the depth-free fit `start`. Returns the
/// parameters to use (`start` unchanged when the term is not fitted) and what happened.
fn fit_depth_term(points: &[FitPoint], idx: &[usize], start: Params, options: &FitOptions) -> (Params, DepthTerm) {
    if !options.fit_depth {
        return (start, DepthTerm::NotFitted(DepthRefusal::Disabled));
    }
    let depths = idx.iter().map(|&i| points[i].depth_mm);
    let (lo, hi) = depths.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), d| (lo.min(d), hi.max(d)));
    let range_mm = hi - lo;
    if !(range_mm >= options.min_depth_range_mm) {
        let range_mm = if range_mm.is_finite() { range_mm } else { 0.0 };
        return (start, DepthTerm::NotFitted(DepthRefusal::NarrowDepths { range_mm, min_mm: options.min_depth_range_mm }));
    }
    let normal = |p: &Params, weighted: bool| {
        let mut h = [[0.0; 6]; 6];
        let mut g = [0.0; 6];
        for &i in idx {
            let q = &points[i];
            let m = p.apply_at(q.mm, q.depth_mm);
            let (ru, rv) = (m[0] - q.px[0], m[1] - q.px[1]);
            let r = ru.hypot(rv);
            let w = if !weighted || r <= options.huber_px { 1.0 } else { options.huber_px / r };
            let (ju, jv) = p.jacobian(q.mm, q.depth_mm);
            for a in 0..6 {
                g[a] += w * (ju[a] * ru + jv[a] * rv);
                for b in 0..6 {
                    h[a][b] += w * (ju[a] * ju[b] + jv[a] * jv[b]);
                }
            }
        }
        (h, g)
    };
    // Conditioning: the term's variance per unit noise is the (k, k) element of the inverse
    // normal matrix, i.e. 1 / |the k column's part that the other five cannot absorb|^2.
    let (h0, _) = normal(&start, false);
    let mut unit = [0.0; 6];
    unit[5] = 1.0;
    let variance = solve::<6>(h0, unit).map_or(f64::INFINITY, |x| x[5]);
    let error_per_px = if variance > 0.0 { variance.sqrt() } else { f64::INFINITY };
    if !(error_per_px <= options.max_depth_error_per_px) {
        let error_per_px = if error_per_px.is_finite() { error_per_px } else { f64::MAX };
        return (start, DepthTerm::NotFitted(DepthRefusal::IllConditioned { error_per_px, max_per_px: options.max_depth_error_per_px }));
    }
    let cost = |p: &Params| -> f64 {
        idx.iter()
            .map(|&i| {
                let q = &points[i];
                let m = p.apply_at(q.mm, q.depth_mm);
                let r = (m[0] - q.px[0]).hypot(m[1] - q.px[1]);
                let hb = options.huber_px;
                if r <= hb { r * r / 2.0 } else { hb * (r - hb / 2.0) }
            })
            .sum()
    };
    let p = levenberg_marquardt::<6>(
        start,
        |p| normal(p, true),
        cost,
        |p, d| Params { cu: p.cu - d[0], cv: p.cv - d[1], theta: p.theta - d[2], sx: p.sx - d[3], sy: p.sy - d[4], k: p.k - d[5] },
    );
    if !(p.k.abs() <= super::MAX_DEPTH_SCALE_PER_MM) {
        let per_mm = if p.k.is_finite() { p.k } else { f64::MAX };
        return (start, DepthTerm::NotFitted(DepthRefusal::OutOfRange { per_mm, max: super::MAX_DEPTH_SCALE_PER_MM }));
    }
    // Noise estimate: the residuals' RMS with the six fitted parameters' degrees of freedom.
    let sum_sq: f64 = residuals_of(&p, points).iter().enumerate().filter(|(i, _)| idx.contains(i)).map(|(_, r)| r * r).sum();
    let dof = (2 * idx.len()).saturating_sub(6).max(1) as f64;
    let (h1, _) = normal(&p, false);
    let variance = solve::<6>(h1, unit).map_or(variance, |x| x[5]).max(0.0);
    let std_error_per_mm = (sum_sq / dof).sqrt() * variance.sqrt();
    if !(std_error_per_mm <= options.max_depth_std_error_per_mm) {
        let std_error_per_mm = if std_error_per_mm.is_finite() { std_error_per_mm } else { f64::MAX };
        return (
            start,
            DepthTerm::NotFitted(DepthRefusal::Uncertain { per_mm: p.k, std_error_per_mm, max: options.max_depth_std_error_per_mm }),
        );
    }
    (p, DepthTerm::Fitted { per_mm: p.k, std_error_per_mm, depth_range_mm: [lo, hi] })
}

/// 1.4826 x the median absolute residual (residuals are already non-negative distances).
fn robust_sigma(residuals: &[f64]) -> f64 {
    let mut r = residuals.to_vec();
    r.sort_by(f64::total_cmp);
    let median = if r.is_empty() { 0.0 } else { r[r.len() / 2] };
    1.4826 * median
}

/// Normalisation of a point cloud: mean and RMS distance from it.
struct Norm {
    mean: [f64; 2],
    scale: f64,
}

/// Mean, and principal spreads (major, minor standard deviations) of 2-D points. Computed on
/// points pre-divided by their largest magnitude so squares cannot overflow.
fn spread(pts: &[[f64; 2]]) -> (Norm, f64, f64) {
    let big = pts.iter().flat_map(|p| p.iter()).fold(0.0f64, |m, v| m.max(v.abs()));
    let k = if big > 0.0 { big } else { 1.0 };
    let n = pts.len() as f64;
    let mean_k = [pts.iter().map(|p| p[0] / k).sum::<f64>() / n, pts.iter().map(|p| p[1] / k).sum::<f64>() / n];
    let (mut sxx, mut syy, mut sxy) = (0.0, 0.0, 0.0);
    for p in pts {
        let (dx, dy) = (p[0] / k - mean_k[0], p[1] / k - mean_k[1]);
        sxx += dx * dx;
        syy += dy * dy;
        sxy += dx * dy;
    }
    let (sxx, syy, sxy) = (sxx / n, syy / n, sxy / n);
    let half_trace = (sxx + syy) / 2.0;
    let disc = (((sxx - syy) / 2.0).powi(2) + sxy * sxy).sqrt();
    let major = (half_trace + disc).max(0.0).sqrt() * k;
    let minor = (half_trace - disc).max(0.0).sqrt() * k;
    let rms = (sxx + syy).max(0.0).sqrt() * k;
    (Norm { mean: [mean_k[0] * k, mean_k[1] * k], scale: if rms > 0.0 { rms } else { 1.0 } }, major, minor)
}

/// Stages 1-3 on the points `idx`; returns the parameters, the condition number and the shear.
fn fit_subset(points: &[FitPoint], idx: &[usize], options: &FitOptions) -> Result<(Params, f64, f64), FitError> {
    if idx.len() < MIN_POINTS {
        return Err(FitError::TooFewPoints { given: idx.len(), needed: MIN_POINTS });
    }
    let mm: Vec<[f64; 2]> = idx.iter().map(|&i| points[i].mm).collect();
    let px: Vec<[f64; 2]> = idx.iter().map(|&i| points[i].px).collect();
    let (nm, major, minor) = spread(&mm);
    if !(major > options.min_spread_mm) {
        return Err(FitError::AllAtOneSpot { spread_mm: major });
    }
    let condition = major / minor.max(f64::MIN_POSITIVE);
    if !(minor > options.min_spread_ratio * major) || !(minor > options.min_spread_mm * 1e-3) {
        return Err(FitError::Collinear { major_mm: major, minor_mm: minor, condition });
    }
    let (np, pmajor, _) = spread(&px);
    if !(pmajor > 1e-9 * np.mean[0].abs().max(np.mean[1].abs()).max(1.0)) {
        return Err(FitError::PixelsAtOneSpot { spread_px: pmajor });
    }
    // Normalised coordinates: x' = (x - mean) / scale.
    let xs: Vec<[f64; 2]> = mm.iter().map(|p| [(p[0] - nm.mean[0]) / nm.scale, (p[1] - nm.mean[1]) / nm.scale]).collect();
    let us: Vec<[f64; 2]> = px.iter().map(|p| [(p[0] - np.mean[0]) / np.scale, (p[1] - np.mean[1]) / np.scale]).collect();

    // Stage 2: affine u = a x + b y + t (normalised), per output coordinate.
    let mut ata = [[0.0; 3]; 3];
    let mut atu = [[0.0; 3]; 2];
    for (x, u) in xs.iter().zip(&us) {
        let row = [x[0], x[1], 1.0];
        for r in 0..3 {
            for c in 0..3 {
                ata[r][c] += row[r] * row[c];
            }
            atu[0][r] += row[r] * u[0];
            atu[1][r] += row[r] * u[1];
        }
    }
    let su = solve::<3>(ata, atu[0]).ok_or(FitError::Collinear { major_mm: major, minor_mm: minor, condition })?;
    let sv = solve::<3>(ata, atu[1]).ok_or(FitError::Collinear { major_mm: major, minor_mm: minor, condition })?;
    // A = [[su0, su1], [sv0, sv1]]: columns are the images of the x and y axes.
    let col0 = [su[0], sv[0]];
    let col1 = [su[1], sv[1]];
    let theta = col0[1].atan2(col0[0]);
    let (s, c) = theta.sin_cos();
    let sx = col0[0].hypot(col0[1]);
    let sy = -s * col1[0] + c * col1[1];
    let shear_raw = c * col1[0] + s * col1[1];
    let shear = shear_raw / col1[0].hypot(col1[1]).max(f64::MIN_POSITIVE);
    // Normalised model: u' = t + R diag(sx, sy) x'; start from the affine translation.
    let start = Params { cu: su[2], cv: sv[2], theta, sx, sy, k: 0.0 };

    // Stage 3: damped Gauss-Newton with Huber weights.
    let huber = options.huber_px / np.scale;
    let cost = |p: &Params| -> f64 {
        xs.iter()
            .zip(&us)
            .map(|(x, u)| {
                let m = p.apply(*x);
                let r = (m[0] - u[0]).hypot(m[1] - u[1]);
                if r <= huber { r * r / 2.0 } else { huber * (r - huber / 2.0) }
            })
            .sum()
    };
    let normal = |p: &Params| {
        let (s, c) = p.theta.sin_cos();
        let mut h = [[0.0; 5]; 5];
        let mut g = [0.0; 5];
        for (x, u) in xs.iter().zip(&us) {
            let m = p.apply(*x);
            let (ru, rv) = (m[0] - u[0], m[1] - u[1]);
            let r = ru.hypot(rv);
            let w = if r <= huber { 1.0 } else { huber / r };
            let ju = [1.0, 0.0, -s * p.sx * x[0] - c * p.sy * x[1], c * x[0], -s * x[1]];
            let jv = [0.0, 1.0, c * p.sx * x[0] - s * p.sy * x[1], s * x[0], c * x[1]];
            for a in 0..5 {
                g[a] += w * (ju[a] * ru + jv[a] * rv);
                for b in 0..5 {
                    h[a][b] += w * (ju[a] * ju[b] + jv[a] * jv[b]);
                }
            }
        }
        (h, g)
    };
    let p = levenberg_marquardt::<5>(start, normal, cost, |p, d| Params {
        cu: p.cu - d[0],
        cv: p.cv - d[1],
        theta: p.theta - d[2],
        sx: p.sx - d[3],
        sy: p.sy - d[4],
        k: 0.0,
    });
    // Back to pixels: u = np.mean + np.scale * (t + R diag(sx, sy) (x - nm.mean) / nm.scale).
    let k = np.scale / nm.scale;
    let (sx, sy) = (p.sx * k, p.sy * k);
    let (mut theta, mut sx, mut sy) = (p.theta, sx, sy);
    if sx < 0.0 {
        // Same map: R(theta + pi) diag(-sx, -sy); keep the x scale positive.
        theta += std::f64::consts::PI;
        sx = -sx;
        sy = -sy;
    }
    let (s, c) = theta.sin_cos();
    let (a, b) = (sx * nm.mean[0], sy * nm.mean[1]);
    let cu = np.mean[0] + np.scale * p.cu - (c * a - s * b);
    let cv = np.mean[1] + np.scale * p.cv - (s * a + c * b);
    Ok((Params { cu, cv, theta, sx, sy, k: 0.0 }, condition, shear))
}

/// Levenberg-Marquardt on N of the parameters: `normal(p)` is the (Huber-weighted) normal
/// matrix and gradient at `p`, `cost(p)` the robust cost, `step(p, d)` the parameters moved by
/// `-d`. A step is taken only when the cost does not rise; the damping falls 10x after an
/// accepted step and rises 10x after a refused or singular one. Ends when no step helps, a step
/// is negligible, or after 100 iterations.
fn levenberg_marquardt<const N: usize>(
    start: Params,
    normal: impl Fn(&Params) -> ([[f64; N]; N], [f64; N]),
    cost: impl Fn(&Params) -> f64,
    step: impl Fn(&Params, &[f64; N]) -> Params,
) -> Params {
    let mut p = start;
    let mut current = cost(&p);
    let mut lambda = 1e-6;
    for _ in 0..100 {
        let (h, g) = normal(&p);
        let mut improved = false;
        for _ in 0..10 {
            let mut hd = h;
            for (a, row) in hd.iter_mut().enumerate() {
                row[a] += lambda * (h[a][a] + 1e-12);
            }
            let Some(d) = solve::<N>(hd, g) else {
                lambda *= 10.0;
                continue;
            };
            let trial = step(&p, &d);
            let c2 = cost(&trial);
            if c2.is_finite() && c2 <= current {
                let small = d.iter().all(|x| x.abs() < 1e-13);
                p = trial;
                current = c2;
                lambda = (lambda / 10.0).max(1e-12);
                improved = !small;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    p
}

/// Solves `a x = b` by Gaussian elimination with partial pivoting; `None` when singular.
pub(crate) fn solve<const N: usize>(mut a: [[f64; N]; N], mut b: [f64; N]) -> Option<[f64; N]> {
    let norm = a.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
    if !(norm > 0.0) || !norm.is_finite() {
        return None;
    }
    for col in 0..N {
        let pivot = (col..N).max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))?;
        if !(a[pivot][col].abs() > 1e-14 * norm) {
            return None;
        }
        a.swap(col, pivot);
        b.swap(col, pivot);
        for row in col + 1..N {
            let f = a[row][col] / a[col][col];
            let pivot_row = a[col];
            for (v, p) in a[row].iter_mut().zip(pivot_row).skip(col) {
                *v -= f * p;
            }
            b[row] -= f * b[col];
        }
    }
    let mut x = [0.0; N];
    for row in (0..N).rev() {
        let mut acc = b[row];
        for k in row + 1..N {
            acc -= a[row][k] * x[k];
        }
        x[row] = acc / a[row][row];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn truth() -> Calibration {
        Calibration { centre_px: [262.3, 249.1], scale_px_per_mm: [11.7, -10.8], rotation_deg: 7.5, ..Calibration::default_for(512, 512) }
    }

    fn grid(c: &Calibration) -> Vec<FitPoint> {
        let mut v = Vec::new();
        for i in -2..=2 {
            for j in -2..=2 {
                let mm = [i as f64 * 2.0, j as f64 * 2.0];
                let (u, w) = c.mm_to_px(mm[0], mm[1]);
                v.push(FitPoint::new(mm, [u, w]));
            }
        }
        v
    }

    #[test]
    fn recovers_an_anisotropic_rotated_mirrored_map() {
        let t = truth();
        let fit = fit_points(&grid(&t), &FitOptions::default(), "test").unwrap();
        let c = &fit.calibration;
        assert!((c.centre_px[0] - 262.3).abs() < 1e-6 && (c.centre_px[1] - 249.1).abs() < 1e-6, "{c:?}");
        assert!((c.scale_px_per_mm[0] - 11.7).abs() < 1e-6 && (c.scale_px_per_mm[1] + 10.8).abs() < 1e-6, "{c:?}");
        assert!((c.rotation_deg - 7.5).abs() < 1e-6, "{c:?}");
        assert!(fit.rms_px < 1e-6 && fit.shear.abs() < 1e-9);
        assert!((fit.condition - 1.0).abs() < 1e-6);
    }

    /// The grid at 1.5 mm, and its corners, edge midpoints and centre at 1.0 and 2.0 mm.
    fn grid_at_depths(c: &Calibration) -> Vec<FitPoint> {
        let mut v: Vec<FitPoint> = grid(c)
            .into_iter()
            .map(|p| {
                let (u, w) = c.mm_to_px_at_depth(p.mm[0], p.mm[1], 1.5);
                FitPoint { mm: p.mm, px: [u, w], depth_mm: 1.5 }
            })
            .collect();
        for d in [1.0, 2.0] {
            for i in -1..=1 {
                for j in -1..=1 {
                    let mm = [i as f64 * 4.0, j as f64 * 4.0];
                    let (u, w) = c.mm_to_px_at_depth(mm[0], mm[1], d);
                    v.push(FitPoint { mm, px: [u, w], depth_mm: d });
                }
            }
        }
        v
    }

    #[test]
    fn recovers_the_depth_term() {
        let t = Calibration { depth_scale_per_mm: 0.04, ..truth() };
        let fit = fit_points(&grid_at_depths(&t), &FitOptions::default(), "test").unwrap();
        let c = &fit.calibration;
        assert!((c.depth_scale_per_mm - 0.04).abs() < 1e-6, "{c:?}");
        assert!((c.scale_px_per_mm[0] - 11.7).abs() < 1e-5 && (c.scale_px_per_mm[1] + 10.8).abs() < 1e-5, "{c:?}");
        assert!(fit.rms_px < 1e-6, "{}", fit.rms_px);
        let DepthTerm::Fitted { depth_range_mm, std_error_per_mm, .. } = fit.depth else { panic!("{:?}", fit.depth) };
        assert_eq!(depth_range_mm, [1.0, 2.0]);
        assert!(std_error_per_mm < 1e-6);
        // Without the depth fit the same points leave a residual (the corners at 1 and 2 mm).
        let flat = fit_points(&grid_at_depths(&t), &FitOptions { fit_depth: false, ..FitOptions::default() }, "t").unwrap();
        assert_eq!(flat.calibration.depth_scale_per_mm, 0.0);
        assert!(flat.rms_px > 0.3, "{}", flat.rms_px);
        assert_eq!(flat.depth, DepthTerm::NotFitted(DepthRefusal::Disabled));
    }

    #[test]
    fn refuses_the_depth_term_when_the_depths_do_not_condition_it() {
        let t = Calibration { depth_scale_per_mm: 0.04, ..truth() };
        // One depth: left at 0 (the scales absorb the factor), the fit itself still works.
        let one: Vec<FitPoint> = grid_at_depths(&t).into_iter().filter(|p| p.depth_mm == 1.5).collect();
        let fit = fit_points(&one, &FitOptions::default(), "t").unwrap();
        assert!(matches!(fit.depth, DepthTerm::NotFitted(DepthRefusal::NarrowDepths { range_mm: 0.0, .. })), "{:?}", fit.depth);
        assert_eq!(fit.calibration.depth_scale_per_mm, 0.0);
        assert!(fit.calibration.fit.unwrap().notes.contains("not fitted"));
        // Other depths only at the centre: no lever arm, the term is not conditioned.
        let mut centre_only: Vec<FitPoint> = one.clone();
        for d in [0.5, 2.5] {
            let (u, w) = t.mm_to_px_at_depth(0.0, 0.0, d);
            centre_only.push(FitPoint { mm: [0.0, 0.0], px: [u, w], depth_mm: d });
        }
        let fit = fit_points(&centre_only, &FitOptions::default(), "t").unwrap();
        assert!(matches!(fit.depth, DepthTerm::NotFitted(DepthRefusal::IllConditioned { .. })), "{:?}", fit.depth);
        assert_eq!(fit.calibration.depth_scale_per_mm, 0.0);
        // Depths that would condition it, but detections too noisy to pin it down.
        let mut noisy = grid_at_depths(&t);
        for (i, p) in noisy.iter_mut().enumerate() {
            p.px[0] += if i % 2 == 0 { 2.5 } else { -2.5 };
            p.px[1] += if i % 3 == 0 { 2.5 } else { -1.5 };
        }
        let fit = fit_points(&noisy, &FitOptions::default(), "t").unwrap();
        assert!(matches!(fit.depth, DepthTerm::NotFitted(DepthRefusal::Uncertain { .. })), "{:?}", fit.depth);
        assert_eq!(fit.calibration.depth_scale_per_mm, 0.0);
        let mut nan = one;
        nan[4].depth_mm = f64::NAN;
        assert!(matches!(fit_points(&nan, &FitOptions::default(), ""), Err(FitError::NotFinite { index: 4, .. })));
    }

    #[test]
    fn rejects_an_outlier() {
        let t = truth();
        let mut pts = grid(&t);
        pts[7].px[0] += 40.0;
        let fit = fit_points(&pts, &FitOptions::default(), "test").unwrap();
        assert!(!fit.inlier[7]);
        assert_eq!(fit.inlier.iter().filter(|k| **k).count(), pts.len() - 1);
        assert!(fit.rms_px < 1e-6, "{}", fit.rms_px);
        assert!(fit.residuals_px[7] > 39.0);
    }

    #[test]
    fn refuses_degenerate_sets() {
        let t = truth();
        let pts = grid(&t);
        assert!(matches!(fit_points(&pts[..2], &FitOptions::default(), ""), Err(FitError::TooFewPoints { given: 2, .. })));
        let line: Vec<FitPoint> = pts.iter().filter(|p| p.mm[1] == 0.0).copied().collect();
        assert!(matches!(fit_points(&line, &FitOptions::default(), ""), Err(FitError::Collinear { .. })));
        let spot = vec![pts[3]; 6];
        assert!(matches!(fit_points(&spot, &FitOptions::default(), ""), Err(FitError::AllAtOneSpot { .. })));
        let mut same_px = pts.clone();
        for p in &mut same_px {
            p.px = [10.0, 10.0];
        }
        assert!(matches!(fit_points(&same_px, &FitOptions::default(), ""), Err(FitError::PixelsAtOneSpot { .. })));
        let mut nan = pts;
        nan[2].mm[0] = f64::NAN;
        assert!(matches!(fit_points(&nan, &FitOptions::default(), ""), Err(FitError::NotFinite { index: 2, .. })));
    }
}
