//! The ranges rig accepts for sampling settings and image sizes, checked before anything is
//! allocated or loaded, by every front end (`rig synth`, `rig synth one`, daemon jobs).
//!
//! | setting | range | why |
//! |---|---|---|
//! | guidance | 1 to 30 | 1 is unguided (the conditional half only); classifier-free guidance extrapolates `uncond + g (cond - uncond)`, and past about 30 the latents leave the range the decoder was trained on (saturated noise), as with every Stable Diffusion UI's cap |
//! | eta | 0 to 1 | DDIM's eta scales its noise between deterministic DDIM (0) and DDPM-like sampling (1); above 1 the formula's `1 - alpha_prev - sigma^2` goes negative |
//! | conditioning scale | 0 to 2 | multiplies the ControlNet residuals: 0 ignores the hint, 1 is as trained; past 2 they swamp the UNet's own features (ControlNet UIs cap the weight at 2) |
//! | width, height | 1 to 2048 px, multiples of the package's size multiple | memory grows with the area (2048 x 2048 is 16 times SD 1.5's native area); the multiple is the VAE factor times 2 per UNet downsample ([`super::onnx_graph`]) |
//! | batch | 1 to 16 | each image of a batch holds its latents and control hint twice under guidance |
//! | supersample | 1 to 8 | the depth render holds `supersample^2` samples per pixel |
//! | steps | 1 to the sampler's limit, at most [`MAX_STEPS`] | DDIM takes one per training timestep, DPM-Solver++ one fewer ([`super::scheduler::NoiseSchedule::max_steps`]) |
//! | training timesteps (`num_train_timesteps` in `scheduler_config.json`) | 2 to [`MAX_TRAIN_TIMESTEPS`] | the schedule holds one beta and one cumulative alpha per timestep; Stable Diffusion uses 1000, and 10000 is ten times any published diffusers scheduler, so a package cannot make rig allocate gigabytes before its first step |
//! | package `sampling_steps` (`model.toml`) | 1 to [`MAX_STEPS`] | a step count no schedule rig accepts can take is refused when the package is read |
//!
//! The checks stand alone (their error is [`BadSetting`], which becomes
//! [`super::SynthError::BadRequest`]), so the daemon's request validation can be fuzzed without
//! the rest of rig.

/// A setting outside its range.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{field} = {value} is not valid: {reason}")]
pub struct BadSetting {
    pub field: &'static str,
    pub value: String,
    pub reason: String,
}

/// Largest width or height of a synthesised image, px.
pub const MAX_SIDE_PX: u32 = 2048;
/// Classifier-free guidance scale range.
pub const GUIDANCE: (f32, f32) = (1.0, 30.0);
/// DDIM eta range.
pub const ETA: (f32, f32) = (0.0, 1.0);
/// ControlNet conditioning scale range.
pub const CONDITIONING_SCALE: (f32, f32) = (0.0, 2.0);
/// Largest batch (images per model call).
pub const MAX_BATCH: usize = 16;
/// Largest supersampling factor of the control image's depth render.
pub const MAX_SUPERSAMPLE: u32 = 8;
/// Most training timesteps a scheduler config may declare (`num_train_timesteps`): bounds the
/// schedule's arrays before they are allocated.
pub const MAX_TRAIN_TIMESTEPS: usize = 10_000;
/// Most sampling steps of one image: no sampler takes more steps than training timesteps.
pub const MAX_STEPS: usize = MAX_TRAIN_TIMESTEPS;

fn in_range(field: &'static str, value: f32, (lo, hi): (f32, f32), why: &str) -> Result<(), BadSetting> {
    if value.is_finite() && (lo..=hi).contains(&value) {
        Ok(())
    } else {
        Err(BadSetting { field, value: value.to_string(), reason: format!("must be a number from {lo} to {hi} ({why})") })
    }
}

/// Guidance in [`GUIDANCE`].
pub fn check_guidance(guidance: f32) -> Result<(), BadSetting> {
    in_range("guidance", guidance, GUIDANCE, "1: unguided; larger values push the image away from the decoder's range")
}

/// Eta in [`ETA`].
pub fn check_eta(eta: f32) -> Result<(), BadSetting> {
    in_range("eta", eta, ETA, "0: deterministic DDIM, 1: DDPM-like noise")
}

/// Conditioning scale in [`CONDITIONING_SCALE`].
pub fn check_conditioning_scale(scale: f32) -> Result<(), BadSetting> {
    in_range("conditioning_scale", scale, CONDITIONING_SCALE, "0 ignores the depth hint, 1 is as trained")
}

/// Batch in 1..=[`MAX_BATCH`].
pub fn check_batch(batch: usize) -> Result<(), BadSetting> {
    if (1..=MAX_BATCH).contains(&batch) {
        Ok(())
    } else {
        Err(BadSetting { field: "batch", value: batch.to_string(), reason: format!("must be 1 to {MAX_BATCH} images per model call") })
    }
}

/// Supersampling in 1..=[`MAX_SUPERSAMPLE`].
pub fn check_supersample(supersample: u32) -> Result<(), BadSetting> {
    if (1..=MAX_SUPERSAMPLE).contains(&supersample) {
        Ok(())
    } else {
        Err(BadSetting {
            field: "supersample",
            value: supersample.to_string(),
            reason: format!("must be 1 to {MAX_SUPERSAMPLE} samples per pixel side"),
        })
    }
}

/// An image size: each side 1..=[`MAX_SIDE_PX`] and a multiple of `multiple` (the package's
/// [`size multiple`](super::Pipeline::size_multiple)).
pub fn check_size(field: &'static str, (width, height): (u32, u32), multiple: u32) -> Result<(), BadSetting> {
    let value = format!("{width}x{height}");
    if width == 0 || height == 0 || width > MAX_SIDE_PX || height > MAX_SIDE_PX {
        return Err(BadSetting { field, value, reason: format!("width and height must be 1 to {MAX_SIDE_PX} px") });
    }
    if multiple > 0 && (!width.is_multiple_of(multiple) || !height.is_multiple_of(multiple)) {
        return Err(BadSetting {
            field,
            value,
            reason: format!(
                "width and height must be multiples of {multiple} px for this model package (its VAE factor times 2 per UNet \
                 downsample), e.g. {}x{}",
                round_to(width, multiple),
                round_to(height, multiple)
            ),
        });
    }
    Ok(())
}

/// A step count, when given: 1 to [`MAX_STEPS`] (the package's schedule may allow fewer).
pub fn check_steps(steps: Option<usize>) -> Result<(), BadSetting> {
    match steps {
        Some(n) if n == 0 || n > MAX_STEPS => Err(BadSetting {
            field: "steps",
            value: n.to_string(),
            reason: format!("must be 1 to {MAX_STEPS} (and at most the package's training timesteps)"),
        }),
        _ => Ok(()),
    }
}

/// The checks of a fill's settings that need no package: steps at least 1 (their upper
/// bound depends on the package's schedule), guidance, eta, conditioning scale, batch and
/// supersampling in range. `None`: left to the package, whose value is checked when it is read.
pub fn check_fill_settings(
    steps: Option<usize>,
    guidance: Option<f32>,
    eta: Option<f32>,
    conditioning_scale: f32,
    batch: usize,
    supersample: u32,
) -> Result<(), BadSetting> {
    check_steps(steps)?;
    if let Some(g) = guidance {
        check_guidance(g)?;
    }
    if let Some(eta) = eta {
        check_eta(eta)?;
    }
    check_conditioning_scale(conditioning_scale)?;
    check_batch(batch)?;
    check_supersample(supersample)
}

fn round_to(v: u32, multiple: u32) -> u32 {
    ((v + multiple / 2) / multiple).max(1) * multiple
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_refuse_what_means_nothing() {
        for g in [1.0, 9.0, 30.0] {
            assert!(check_guidance(g).is_ok(), "{g}");
        }
        for g in [0.5, 31.0, 1e30, f32::NAN, f32::INFINITY, -1.0] {
            let e = check_guidance(g).expect_err("out of range");
            assert!(e.to_string().contains("from 1 to 30"), "{e}");
        }
        assert!(check_eta(0.0).is_ok() && check_eta(1.0).is_ok());
        assert!(check_eta(1e30).is_err() && check_eta(-0.1).is_err() && check_eta(f32::NAN).is_err());
        assert!(check_conditioning_scale(0.0).is_ok() && check_conditioning_scale(2.0).is_ok());
        assert!(check_conditioning_scale(2.5).is_err());
        assert!(check_batch(0).is_err() && check_batch(16).is_ok() && check_batch(17).is_err());
        assert!(check_supersample(0).is_err() && check_supersample(8).is_ok() && check_supersample(9).is_err());
        assert!(check_steps(None).is_ok() && check_steps(Some(1)).is_ok() && check_steps(Some(MAX_STEPS)).is_ok());
        for bad in [0, MAX_STEPS + 1, 40_000_000] {
            assert!(check_steps(Some(bad)).expect_err("out of range").to_string().contains("1 to 10000"), "{bad}");
        }
    }

    #[test]
    fn sizes_are_bounded_and_multiples() {
        assert!(check_size("size", (64, 64), 16).is_ok());
        assert!(check_size("size", (48, 32), 16).is_ok());
        let e = check_size("size", (72, 72), 16).expect_err("72 is not a multiple of 16");
        assert!(e.to_string().contains("multiples of 16") && e.to_string().contains("80x80"), "{e}");
        assert!(check_size("size", (100_000, 100_000), 8).expect_err("huge").to_string().contains("1 to 2048"));
        assert!(check_size("size", (0, 64), 8).is_err());
        assert!(check_size("size", (4096, 64), 8).is_err());
    }
}
