//! Noise schedulers: DDIM (exactly as diffusers' `DDIMScheduler`) and DPM-Solver++ 2M.
//!
//! Data flow: the package's `scheduler/scheduler_config.json` is deserialised into
//! [`SchedulerConfig`], which builds a [`NoiseSchedule`] (betas, `alphas_cumprod`) once. Per
//! image, a [`Scheduler`] is made for the requested step count; the pipeline asks it for the
//! timesteps and calls [`Scheduler::step`] with the model's output after each UNet call.
//!
//! Arithmetic follows diffusers: betas and `alphas_cumprod` are float32 (torch computes them in
//! float32), the timestep grid uses integer timesteps with the configured spacing and
//! `steps_offset`, and the step formulas are DDIM's (Song et al., eq. 12) with `eta` and
//! DPM-Solver++(2M) (Lu et al. 2022, multistep, midpoint form, `lower_order_final`,
//! final sigma zero) as diffusers' `DPMSolverMultistepScheduler` writes them.

use std::path::{Path, PathBuf};

use serde::Deserialize;

/// Why a scheduler could not be made.
#[derive(Debug, thiserror::Error)]
pub enum SchedulerError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: not a diffusers scheduler config: {source}")]
    Json { path: PathBuf, source: crate::untrusted::SyntaxError },
    #[error("scheduler config: {field} = {value:?} is not supported ({supported})")]
    Unsupported { field: &'static str, value: String, supported: &'static str },
    #[error("{steps} inference steps do not fit {sampler} over {train_steps} training timesteps (it takes 1..={max})")]
    BadStepCount { steps: usize, sampler: &'static str, train_steps: usize, max: usize },
    #[error("scheduler config: {field} = {value} is out of range")]
    OutOfRange { field: &'static str, value: f64 },
    #[error("scheduler config: {field} = {value} is not valid: must be {min} to {max} ({why})")]
    OutOfBounds { field: &'static str, value: u64, min: u64, max: u64, why: &'static str },
}

/// The fields of a diffusers scheduler config that rig uses, with diffusers' `DDIMScheduler`
/// defaults for the ones a config leaves out. Unknown keys (`_class_name`, `skip_prk_steps`,
/// ...) are ignored, as diffusers' `from_config` does.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(default)]
pub struct SchedulerConfig {
    pub num_train_timesteps: usize,
    pub beta_start: f64,
    pub beta_end: f64,
    /// `linear`, `scaled_linear` or `squaredcos_cap_v2`.
    pub beta_schedule: String,
    pub trained_betas: Option<Vec<f64>>,
    pub clip_sample: bool,
    pub clip_sample_range: f64,
    pub set_alpha_to_one: bool,
    pub steps_offset: i64,
    /// `epsilon`, `v_prediction` or `sample`.
    pub prediction_type: String,
    /// `leading`, `trailing` or `linspace`.
    pub timestep_spacing: String,
    pub thresholding: bool,
    pub rescale_betas_zero_snr: bool,
}

impl Default for SchedulerConfig {
    fn default() -> Self {
        Self {
            num_train_timesteps: 1000,
            beta_start: 0.0001,
            beta_end: 0.02,
            beta_schedule: "linear".to_string(),
            trained_betas: None,
            clip_sample: true,
            clip_sample_range: 1.0,
            set_alpha_to_one: true,
            steps_offset: 0,
            prediction_type: "epsilon".to_string(),
            timestep_spacing: "leading".to_string(),
            thresholding: false,
            rescale_betas_zero_snr: false,
        }
    }
}

impl SchedulerConfig {
    /// Reads `scheduler_config.json`.
    pub fn read(path: &Path) -> Result<Self, SchedulerError> {
        let text = crate::untrusted::read_text(path, crate::untrusted::MAX_CONFIG_BYTES)
            .map_err(|source| SchedulerError::Io { path: path.to_path_buf(), source })?;
        Self::from_json(&text).map_err(|e| SchedulerError::Json { path: path.to_path_buf(), source: json_syntax(&e) })
    }

    /// Parses the JSON text of a scheduler config.
    pub fn from_json(text: &str) -> Result<Self, serde_json::Error> {
        serde_json::from_str(text)
    }
}

/// The model's noise schedule: `alphas_cumprod[t]` for each training timestep `t`.
#[derive(Debug, Clone)]
pub struct NoiseSchedule {
    pub config: SchedulerConfig,
    pub alphas_cumprod: Vec<f32>,
    /// `alpha_prod` used after the last step (1 with `set_alpha_to_one`, else `alphas_cumprod[0]`).
    pub final_alpha_cumprod: f32,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Prediction {
    Epsilon,
    V,
    Sample,
}

/// Smallest usable cumulative alpha: its square root (1e-6) still divides a latent without
/// overflowing f32.
const MIN_ALPHA_PROD: f32 = 1e-12;

impl NoiseSchedule {
    /// Builds the schedule, rejecting options rig does not implement.
    pub fn new(config: SchedulerConfig) -> Result<Self, SchedulerError> {
        let n = config.num_train_timesteps;
        // Bounded before anything of size n is allocated: the betas and cumulative alphas hold
        // one value per timestep (1e12 would ask for 4 TB and abort).
        if !(2..=super::limits::MAX_TRAIN_TIMESTEPS).contains(&n) {
            return Err(SchedulerError::OutOfBounds {
                field: "num_train_timesteps",
                value: n as u64,
                min: 2,
                max: super::limits::MAX_TRAIN_TIMESTEPS as u64,
                why: "Stable Diffusion trains over 1000",
            });
        }
        // diffusers uses an offset of 0 or 1; one past the schedule would overflow the grid.
        if config.steps_offset < 0 || config.steps_offset as u64 >= n as u64 {
            return Err(SchedulerError::OutOfBounds {
                field: "steps_offset",
                value: config.steps_offset.unsigned_abs(),
                min: 0,
                max: n as u64 - 1,
                why: "an offset into the training timesteps; diffusers uses 0 or 1",
            });
        }
        if config.clip_sample && !(config.clip_sample_range.is_finite() && config.clip_sample_range > 0.0) {
            return Err(SchedulerError::OutOfRange { field: "clip_sample_range", value: config.clip_sample_range });
        }
        if config.thresholding {
            return Err(SchedulerError::Unsupported { field: "thresholding", value: "true".into(), supported: "false" });
        }
        if config.rescale_betas_zero_snr {
            return Err(SchedulerError::Unsupported { field: "rescale_betas_zero_snr", value: "true".into(), supported: "false" });
        }
        prediction(&config.prediction_type)?;
        if !["leading", "trailing", "linspace"].contains(&config.timestep_spacing.as_str()) {
            return Err(SchedulerError::Unsupported {
                field: "timestep_spacing",
                value: config.timestep_spacing.clone(),
                supported: "leading, trailing, linspace",
            });
        }
        let betas: Vec<f32> = if let Some(trained) = &config.trained_betas {
            if trained.len() != n {
                return Err(SchedulerError::OutOfRange { field: "trained_betas (length)", value: trained.len() as f64 });
            }
            trained.iter().map(|&b| b as f32).collect()
        } else {
            match config.beta_schedule.as_str() {
                "linear" => linspace_f32(config.beta_start, config.beta_end, n),
                // torch.linspace(beta_start**0.5, beta_end**0.5, n, dtype=float32) ** 2
                "scaled_linear" => linspace_f32(config.beta_start.sqrt(), config.beta_end.sqrt(), n).into_iter().map(|b| b * b).collect(),
                "squaredcos_cap_v2" => {
                    let alpha_bar = |t: f64| ((t + 0.008) / 1.008 * std::f64::consts::PI / 2.0).cos().powi(2);
                    (0..n)
                        .map(|i| {
                            let t1 = i as f64 / n as f64;
                            let t2 = (i + 1) as f64 / n as f64;
                            (1.0 - alpha_bar(t2) / alpha_bar(t1)).min(0.999) as f32
                        })
                        .collect()
                }
                other => {
                    return Err(SchedulerError::Unsupported {
                        field: "beta_schedule",
                        value: other.to_string(),
                        supported: "linear, scaled_linear, squaredcos_cap_v2",
                    });
                }
            }
        };
        // A beta outside (0, 1) (a NaN from a bad config included) makes alpha_prod NaN, zero or
        // negative, and every step then divides by its square root: refuse it here.
        if let Some(&b) = betas.iter().find(|b| !(b.is_finite() && **b > 0.0 && **b < 1.0)) {
            return Err(SchedulerError::OutOfRange { field: "betas", value: b as f64 });
        }
        let mut alphas_cumprod = Vec::with_capacity(n);
        let mut acc = 1.0f32;
        for b in &betas {
            acc *= 1.0 - b;
            alphas_cumprod.push(acc);
        }
        // The noisiest step divides by sqrt(alpha_prod); a product that underflowed to about 0
        // would turn it into Inf.
        if let Some(&last) = alphas_cumprod.last().filter(|a| **a < MIN_ALPHA_PROD) {
            return Err(SchedulerError::OutOfRange { field: "alphas_cumprod (last)", value: last as f64 });
        }
        let final_alpha_cumprod = if config.set_alpha_to_one { 1.0 } else { alphas_cumprod[0] };
        Ok(Self { config, alphas_cumprod, final_alpha_cumprod })
    }

    /// The most inference steps `kind` takes over this schedule: DDIM one per training
    /// timestep; DPM-Solver++ one fewer (its grid has `steps + 1` points).
    pub fn max_steps(&self, kind: SchedulerKind) -> usize {
        let n = self.config.num_train_timesteps;
        match kind {
            SchedulerKind::Ddim => n,
            SchedulerKind::DpmSolverPp2m => n.saturating_sub(1),
        }
    }

    /// Whether `kind` can take `steps` steps over this schedule.
    pub fn check_steps(&self, kind: SchedulerKind, steps: usize) -> Result<(), SchedulerError> {
        let max = self.max_steps(kind);
        if steps == 0 || steps > max {
            return Err(SchedulerError::BadStepCount { steps, sampler: kind.name(), train_steps: self.config.num_train_timesteps, max });
        }
        Ok(())
    }

    /// The inference timesteps for `steps` steps, as diffusers' `set_timesteps` makes them.
    pub fn timesteps(&self, steps: usize) -> Result<Vec<i64>, SchedulerError> {
        let n = self.config.num_train_timesteps;
        self.check_steps(SchedulerKind::Ddim, steps)?;
        let ts: Vec<i64> = match self.config.timestep_spacing.as_str() {
            "linspace" => {
                // np.linspace(0, n - 1, steps).round()[::-1]
                let last = (n - 1) as f64;
                (0..steps)
                    .rev()
                    .map(|i| {
                        let v = if steps == 1 { 0.0 } else { last * i as f64 / (steps - 1) as f64 };
                        v.round_ties_even() as i64
                    })
                    .collect()
            }
            "trailing" => {
                // np.round(np.arange(n, 0, -n / steps)) - 1
                let ratio = n as f64 / steps as f64;
                let mut out = Vec::with_capacity(steps);
                let mut t = n as f64;
                while t > 0.0 && out.len() < steps {
                    out.push(t.round_ties_even() as i64 - 1);
                    t -= ratio;
                }
                out
            }
            _ => {
                // leading: (np.arange(0, steps) * (n // steps)).round()[::-1] + steps_offset
                let ratio = (n / steps) as i64;
                (0..steps as i64).rev().map(|i| i * ratio + self.config.steps_offset).collect()
            }
        };
        Ok(ts)
    }

    /// The timesteps diffusers' `DPMSolverMultistepScheduler` uses for `steps` steps: its grid
    /// has `steps + 1` points with the last (t = 0 side) dropped, so with leading spacing it
    /// differs from DDIM's (4 steps: 801, 601, 401, 201 rather than 751, 501, 251, 1).
    pub fn dpm_timesteps(&self, steps: usize) -> Result<Vec<i64>, SchedulerError> {
        let n = self.config.num_train_timesteps;
        self.check_steps(SchedulerKind::DpmSolverPp2m, steps)?;
        let ts: Vec<i64> = match self.config.timestep_spacing.as_str() {
            "linspace" => {
                let last = (n - 1) as f64;
                (1..=steps).rev().map(|i| (last * i as f64 / steps as f64).round_ties_even() as i64).collect()
            }
            "trailing" => {
                let ratio = n as f64 / steps as f64;
                (0..steps).map(|i| (n as f64 - ratio * i as f64).round_ties_even() as i64 - 1).collect()
            }
            _ => {
                let ratio = (n / (steps + 1)) as i64;
                (1..=steps as i64).rev().map(|i| i * ratio + self.config.steps_offset).collect()
            }
        };
        Ok(ts)
    }

    /// `alphas_cumprod[t]`, or the final value for `t < 0`; clamps `t` past the end.
    pub fn alpha_prod(&self, t: i64) -> f32 {
        if t < 0 {
            self.final_alpha_cumprod
        } else {
            let i = (t as usize).min(self.alphas_cumprod.len() - 1);
            self.alphas_cumprod[i]
        }
    }
}

fn prediction(kind: &str) -> Result<Prediction, SchedulerError> {
    match kind {
        "epsilon" => Ok(Prediction::Epsilon),
        "v_prediction" => Ok(Prediction::V),
        "sample" => Ok(Prediction::Sample),
        other => Err(SchedulerError::Unsupported {
            field: "prediction_type",
            value: other.to_string(),
            supported: "epsilon, v_prediction, sample",
        }),
    }
}

/// torch.linspace(start, end, n, dtype=float32): evaluated in double, stored as float.
fn linspace_f32(start: f64, end: f64, n: usize) -> Vec<f32> {
    let step = (end - start) / (n - 1) as f64;
    // torch fills the first half from the start and the second half from the end.
    let half = n / 2;
    (0..n).map(|i| if i < half { start + step * i as f64 } else { end - step * (n - 1 - i) as f64 } as f32).collect()
}

pub use super::settings::SchedulerKind;

/// A JSON parse error as a [`SyntaxError`](crate::untrusted::SyntaxError): its line and column,
/// its reason without the values it quotes from the file.
pub(crate) fn json_syntax(e: &serde_json::Error) -> crate::untrusted::SyntaxError {
    let text = e.to_string();
    // serde_json appends " at line L column C"; the position is kept as numbers instead.
    let reason = text.rsplit_once(" at line ").map_or(text.as_str(), |(r, _)| r);
    crate::untrusted::SyntaxError::at(e.line(), e.column(), reason)
}

/// One image's sampler state for a fixed number of steps.
#[derive(Debug, Clone)]
pub struct Scheduler {
    kind: SchedulerKind,
    timesteps: Vec<i64>,
    /// `num_train_timesteps // steps`: diffusers' DDIM takes the previous timestep as
    /// `t - step_ratio` whatever the spacing.
    step_ratio: i64,
    eta: f32,
    prediction: Prediction,
    clip: Option<f32>,
    /// DPM-Solver++: the previous step's data prediction (x0) and its lambda.
    previous_x0: Option<(Vec<f32>, f64)>,
    step_index: usize,
}

impl Scheduler {
    /// A sampler of `kind` for `steps` steps with DDIM's `eta` (ignored by DPM-Solver++).
    pub fn new(schedule: &NoiseSchedule, kind: SchedulerKind, steps: usize, eta: f32) -> Result<Self, SchedulerError> {
        let timesteps = match kind {
            SchedulerKind::Ddim => schedule.timesteps(steps)?,
            SchedulerKind::DpmSolverPp2m => schedule.dpm_timesteps(steps)?,
        };
        if !eta.is_finite() || eta < 0.0 {
            return Err(SchedulerError::OutOfRange { field: "eta", value: eta as f64 });
        }
        Ok(Self {
            kind,
            timesteps,
            step_ratio: (schedule.config.num_train_timesteps / steps) as i64,
            eta,
            prediction: prediction(&schedule.config.prediction_type)?,
            clip: schedule.config.clip_sample.then_some(schedule.config.clip_sample_range as f32),
            previous_x0: None,
            step_index: 0,
        })
    }

    /// The timesteps, first (noisiest) first.
    pub fn timesteps(&self) -> &[i64] {
        &self.timesteps
    }

    /// True when [`step`](Self::step) needs fresh Gaussian noise (DDIM with `eta > 0`).
    pub fn needs_noise(&self) -> bool {
        self.kind == SchedulerKind::Ddim && self.eta > 0.0
    }

    /// Advances `sample` by one step given the model output at the current timestep. `noise`
    /// (standard normal, same length) is used only when [`needs_noise`](Self::needs_noise).
    pub fn step(&mut self, schedule: &NoiseSchedule, model_output: &[f32], sample: &[f32], noise: Option<&[f32]>) -> Vec<f32> {
        let i = self.step_index.min(self.timesteps.len() - 1);
        let t = self.timesteps[i];
        let out = match self.kind {
            SchedulerKind::Ddim => self.ddim_step(schedule, t, model_output, sample, noise),
            SchedulerKind::DpmSolverPp2m => self.dpm_step(schedule, i, model_output, sample),
        };
        self.step_index += 1;
        out
    }

    /// x0 and epsilon predictions from the model output (diffusers' `prediction_type`).
    fn predict(&self, alpha_prod_t: f32, model_output: &[f32], sample: &[f32]) -> (Vec<f32>, Vec<f32>) {
        let beta_prod_t = 1.0 - alpha_prod_t;
        let (sa, sb) = (alpha_prod_t.sqrt(), beta_prod_t.sqrt());
        let mut x0: Vec<f32>;
        let eps: Vec<f32>;
        match self.prediction {
            Prediction::Epsilon => {
                x0 = sample.iter().zip(model_output).map(|(&x, &e)| (x - sb * e) / sa).collect();
                eps = model_output.to_vec();
            }
            Prediction::V => {
                x0 = sample.iter().zip(model_output).map(|(&x, &v)| sa * x - sb * v).collect();
                eps = sample.iter().zip(model_output).map(|(&x, &v)| sa * v + sb * x).collect();
            }
            Prediction::Sample => {
                x0 = model_output.to_vec();
                eps = sample.iter().zip(model_output).map(|(&x, &p)| (x - sa * p) / sb).collect();
            }
        }
        if let Some(range) = self.clip.filter(|_| self.kind == SchedulerKind::Ddim) {
            // diffusers clips x0 only; epsilon stays as predicted (use_clipped_model_output
            // is off in the pipelines).
            x0.iter_mut().for_each(|v| *v = v.clamp(-range, range));
        }
        (x0, eps)
    }

    fn ddim_step(&self, schedule: &NoiseSchedule, t: i64, model_output: &[f32], sample: &[f32], noise: Option<&[f32]>) -> Vec<f32> {
        let prev_t = t - self.step_ratio;
        let alpha_prod_t = schedule.alpha_prod(t);
        let alpha_prod_prev = schedule.alpha_prod(prev_t);
        let beta_prod_t = 1.0 - alpha_prod_t;
        let beta_prod_prev = 1.0 - alpha_prod_prev;
        let (x0, eps) = self.predict(alpha_prod_t, model_output, sample);
        let variance = (beta_prod_prev / beta_prod_t) * (1.0 - alpha_prod_t / alpha_prod_prev);
        let std_dev_t = self.eta * variance.sqrt();
        let dir_coeff = (1.0 - alpha_prod_prev - std_dev_t * std_dev_t).max(0.0).sqrt();
        let x0_coeff = alpha_prod_prev.sqrt();
        let mut prev: Vec<f32> = x0.iter().zip(&eps).map(|(&p, &e)| x0_coeff * p + dir_coeff * e).collect();
        if self.eta > 0.0
            && let Some(noise) = noise
        {
            prev.iter_mut().zip(noise).for_each(|(v, &z)| *v += std_dev_t * z);
        }
        prev
    }

    fn dpm_step(&mut self, schedule: &NoiseSchedule, i: usize, model_output: &[f32], sample: &[f32]) -> Vec<f32> {
        let t = self.timesteps[i];
        let alpha_prod_t = schedule.alpha_prod(t);
        let (x0, _) = self.predict(alpha_prod_t, model_output, sample);
        let last = i + 1 == self.timesteps.len();
        // The next point on the grid; after the last step, sigma = 0 (diffusers'
        // final_sigmas_type "zero"), where the update is x0 itself.
        let (alpha_s, sigma_s) = if last {
            (1.0f64, 0.0f64)
        } else {
            let a = schedule.alpha_prod(self.timesteps[i + 1]) as f64;
            (a.sqrt(), (1.0 - a).sqrt())
        };
        let (alpha_t, sigma_t) = ((alpha_prod_t as f64).sqrt(), (1.0 - alpha_prod_t as f64).sqrt());
        let lambda_t = (alpha_t / sigma_t).ln();
        let out: Vec<f32> = if sigma_s == 0.0 {
            x0.clone()
        } else {
            let lambda_s = (alpha_s / sigma_s).ln();
            let h = lambda_s - lambda_t;
            let ratio = (sigma_s / sigma_t) as f32;
            let coeff = (alpha_s * (-(-h).exp_m1())) as f32; // alpha_s * (1 - e^{-h})
            // The first step has no history; the last one (to sigma 0) is first order in
            // diffusers (lower_order_final / final_sigmas_type "zero") and handled above.
            let second_order = !last;
            match (&self.previous_x0, second_order) {
                // The second-order term divides by the previous step's lambda change: a
                // repeated lambda (two timesteps clamped onto the last trained one, as with
                // 999 steps and steps_offset 1) would make it Inf, so such a step stays first
                // order.
                (Some((prev_x0, lambda_prev)), true) if lambda_t - lambda_prev > 0.0 && h > 0.0 => {
                    let h_prev = lambda_t - lambda_prev;
                    let r = h_prev / h;
                    let half_over_r = (0.5 / r) as f32;
                    sample.iter().zip(&x0).zip(prev_x0).map(|((&x, &d0), &dm)| ratio * x + coeff * (d0 + half_over_r * (d0 - dm))).collect()
                }
                _ => sample.iter().zip(&x0).map(|(&x, &d0)| ratio * x + coeff * d0).collect(),
            }
        };
        self.previous_x0 = Some((x0, lambda_t));
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Stable Diffusion 1.5's scheduler settings (the tiny package's too).
    fn sd15() -> NoiseSchedule {
        NoiseSchedule::new(
            SchedulerConfig::from_json(
                r#"{"_class_name": "DDIMScheduler", "beta_end": 0.012, "beta_schedule": "scaled_linear",
                    "beta_start": 0.00085, "clip_sample": false, "num_train_timesteps": 1000,
                    "set_alpha_to_one": false, "steps_offset": 1, "trained_betas": null, "skip_prk_steps": true}"#,
            )
            .unwrap(),
        )
        .unwrap()
    }

    fn close(a: f32, b: f64, tol: f64) -> bool {
        ((a as f64) - b).abs() <= tol * b.abs().max(1e-12)
    }

    // Expected values below were printed by diffusers 0.42.1 (DDIMScheduler /
    // DPMSolverMultistepScheduler.from_config of the same config) with torch 2.15.

    #[test]
    fn ddim_timesteps_match_diffusers() {
        let s = sd15();
        assert_eq!(s.timesteps(4).unwrap(), vec![751, 501, 251, 1]);
        let t50 = s.timesteps(50).unwrap();
        assert_eq!(t50.len(), 50);
        assert_eq!(&t50[..3], &[981, 961, 941]);
        assert_eq!(*t50.last().unwrap(), 1);
        assert!(t50.windows(2).all(|w| w[0] - w[1] == 20));
        let mut c = s.config.clone();
        c.timestep_spacing = "linspace".into();
        assert_eq!(NoiseSchedule::new(c.clone()).unwrap().timesteps(7).unwrap(), vec![999, 832, 666, 500, 333, 166, 0]);
        c.timestep_spacing = "trailing".into();
        assert_eq!(NoiseSchedule::new(c).unwrap().timesteps(7).unwrap(), vec![999, 856, 713, 570, 428, 285, 142]);
        assert!(matches!(s.timesteps(0), Err(SchedulerError::BadStepCount { .. })));
    }

    #[test]
    fn step_limits_are_the_ones_the_messages_name() {
        let s = sd15();
        assert_eq!(s.timesteps(1000).map(|t| t.len()).ok(), Some(1000));
        assert!(s.dpm_timesteps(999).is_ok());
        // DPM-Solver++ takes one step fewer than DDIM, and says so.
        let e = s.dpm_timesteps(1000).expect_err("1000 dpm++2m steps");
        assert!(e.to_string().contains("1..=999") && e.to_string().contains("dpm++2m"), "{e}");
        let e = s.timesteps(1001).expect_err("1001 ddim steps");
        assert!(e.to_string().contains("1..=1000") && e.to_string().contains("ddim"), "{e}");
        for kind in [SchedulerKind::Ddim, SchedulerKind::DpmSolverPp2m] {
            let max = s.max_steps(kind);
            assert!(s.check_steps(kind, max).is_ok() && s.check_steps(kind, max + 1).is_err() && s.check_steps(kind, 0).is_err());
        }
    }

    #[test]
    fn dpm_timesteps_match_diffusers() {
        let s = sd15();
        assert_eq!(s.dpm_timesteps(4).unwrap(), vec![801, 601, 401, 201]);
        let t20 = s.dpm_timesteps(20).unwrap();
        assert_eq!(&t20[..4], &[941, 894, 847, 800]);
        assert_eq!(*t20.last().unwrap(), 48);
        let mut c = s.config.clone();
        c.timestep_spacing = "linspace".into();
        assert_eq!(NoiseSchedule::new(c.clone()).unwrap().dpm_timesteps(7).unwrap(), vec![999, 856, 714, 571, 428, 285, 143]);
        c.timestep_spacing = "trailing".into();
        assert_eq!(NoiseSchedule::new(c).unwrap().dpm_timesteps(7).unwrap(), vec![999, 856, 713, 570, 428, 285, 142]);
    }

    #[test]
    fn alphas_cumprod_match_diffusers() {
        let s = sd15();
        for (i, want) in [
            (0, 0.9991499781608582),
            (1, 0.9982960224151611),
            (250, 0.67379230260849),
            (500, 0.27633246779441833),
            (751, 0.055718984454870224),
            (999, 0.00466009508818388),
        ] {
            // 1e-5 relative: torch's float32 cumprod accumulates in its own order; rig's
            // sequential product drifts by about 1e-6 relative over 1000 factors.
            assert!(close(s.alphas_cumprod[i], want, 1e-5), "alphas_cumprod[{i}] = {} want {want}", s.alphas_cumprod[i]);
        }
        assert_eq!(s.final_alpha_cumprod, s.alphas_cumprod[0]);
        let cos = NoiseSchedule::new(SchedulerConfig { beta_schedule: "squaredcos_cap_v2".into(), ..Default::default() }).unwrap();
        assert!(close(cos.alphas_cumprod[0], 0.9999586939811707, 1e-6));
        assert!(close(cos.alphas_cumprod[500], 0.4922850430011749, 1e-5));
        let lin = NoiseSchedule::new(SchedulerConfig::default()).unwrap();
        assert!(close(lin.alphas_cumprod[500], 0.07779665291309357, 1e-5));
        assert!(close(lin.alphas_cumprod[999], 4.035830352222547e-05, 1e-4));
        assert_eq!(lin.final_alpha_cumprod, 1.0);
    }

    #[test]
    fn ddim_step_matches_diffusers() {
        let s = sd15();
        let x = [0.5f32, -1.0, 2.0, 0.25];
        let e = [0.1f32, -0.2, 0.3, -0.4];
        let z = [1.0f32, 0.0, -1.0, 0.5];
        let check = |got: Vec<f32>, want: [f64; 4], what: &str| {
            for (g, w) in got.iter().zip(want) {
                assert!(close(*g, w, 1e-5), "{what}: got {got:?} want {want:?}");
            }
        };
        let mut sch = Scheduler::new(&s, SchedulerKind::Ddim, 4, 0.0).unwrap();
        check(sch.step(&s, &e, &x, None), [0.9800608158111572, -1.9601216316223145, 4.0509772300720215, 1.0783334970474243], "t=751");
        check(sch.step(&s, &e, &x, None), [0.7058361768722534, -1.4116723537445068, 2.899204730987549, 0.694288432598114], "t=501");
        sch.step(&s, &e, &x, None);
        check(sch.step(&s, &e, &x, None), [0.49899962544441223, -0.9979992508888245, 1.9972126483917236, 0.25496360659599304], "t=1");
        let mut eta = Scheduler::new(&s, SchedulerKind::Ddim, 4, 0.5).unwrap();
        assert!(eta.needs_noise());
        eta.step(&s, &e, &x, Some(&z));
        check(
            eta.step(&s, &e, &x, Some(&z)),
            [0.9581247568130493, -1.39934241771698, 2.622256278991699, 0.8481751680374146],
            "t=501 eta 0.5",
        );
    }

    #[test]
    fn rejects_what_it_does_not_implement() {
        let bad = |json: &str| NoiseSchedule::new(SchedulerConfig::from_json(json).unwrap()).unwrap_err();
        assert!(matches!(bad(r#"{"thresholding": true}"#), SchedulerError::Unsupported { field: "thresholding", .. }));
        assert!(matches!(bad(r#"{"beta_schedule": "sigmoid"}"#), SchedulerError::Unsupported { field: "beta_schedule", .. }));
        assert!(matches!(bad(r#"{"prediction_type": "flow"}"#), SchedulerError::Unsupported { .. }));
        // Sizes that would abort on allocation (1e12) or take gigabytes (3e8) are refused first.
        for n in ["1000000000000", "300000000", "10001", "1"] {
            let e = bad(&format!(r#"{{"num_train_timesteps": {n}}}"#));
            assert!(matches!(e, SchedulerError::OutOfBounds { field: "num_train_timesteps", .. }), "{n}: {e}");
            assert!(e.to_string().contains("2 to 10000"), "{e}");
        }
        // At the bound, with betas small enough that the last cumulative alpha stays usable.
        let longest = SchedulerConfig { num_train_timesteps: 10_000, beta_end: 0.002, ..Default::default() };
        assert_eq!(NoiseSchedule::new(longest).map(|s| s.max_steps(SchedulerKind::Ddim)).ok(), Some(10_000));
        // Values that would overflow the timestep grid or make clamp panic.
        assert!(matches!(bad(r#"{"steps_offset": 9000000000000000000}"#), SchedulerError::OutOfBounds { field: "steps_offset", .. }));
        assert!(matches!(bad(r#"{"steps_offset": -1}"#), SchedulerError::OutOfBounds { field: "steps_offset", .. }));
        assert!(matches!(bad(r#"{"clip_sample_range": -1.0}"#), SchedulerError::OutOfRange { field: "clip_sample_range", .. }));
        assert!(SchedulerConfig::from_json("{not json").is_err());
        assert!("euler".parse::<SchedulerKind>().is_err());
        assert_eq!("DPM++2M".parse::<SchedulerKind>().unwrap(), SchedulerKind::DpmSolverPp2m);
    }
}
