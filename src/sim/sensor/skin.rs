//! The elastomer skin: how a press deforms it, and how the deformation shows.
//!
//! A [`SkinModel`] holds the few numbers of one sensor kind's skin. The stages read them:
//!
//! - `contact_deformation` (the indentation): the skin conforms to the object where it
//!   presses, and around the footprint it is dragged in by the superposition of the dent
//!   under a smoothing kernel (as Taxim superposes the gel's response to each pressed point,
//!   and TACTO and FOTS smooth the penetration depth): `w = max(dent, gain * G(spread) * dent)`.
//!   The superposition is linear in the dent, so a deeper press pulls the skin in further and
//!   over a wider field;
//! - `marker_displacement`: pins slide outward, down the slope of the smoothed dent, by
//!   `lateral_mm` per unit slope; the slope grows with the depth of the press, so the travel
//!   does too (up to `max_travel_mm`, a guard against absurd slopes);
//! - `see_through`: the object shows through a transparent skin more the harder it presses
//!   (`visibility = touch + (1 - touch) * (1 - exp(-depth / clear_mm))` where it touches), its
//!   outline is softened further the deeper the press (`edge_mm_per_mm`), and the glow it
//!   scatters into the skin follows the deformed skin (`1 - exp(-w / glow_mm)`).
//!
//! The values of [`SkinModel::of`] were fitted on the real frames 1-5 of the MultiDiffSense
//! example with `rig compare-real --fit-skin` (the guide, `docs/src/simulator.md`, gives the
//! fit, its residuals and a leave-one-out cross-validation). TacTip's are from an earlier
//! search; today's lands on other values that score the same (0.498 against 0.497: the optimum
//! is flat), and the committed ones were kept.

use crate::sensor::SensorKind;

/// The skin of one sensor kind (lengths in mm of the sensor's surface).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SkinModel {
    /// Reach of the elastic spread around the contact (the kernel's radius), mm.
    pub spread_mm: f32,
    /// Height of the spread relative to the smoothed dent: how much of the dent's volume the
    /// skin around it follows.
    pub spread_gain: f32,
    /// Pin travel per unit slope of the smoothed dent, mm.
    pub lateral_mm: f32,
    /// Longest pin travel, mm.
    pub max_travel_mm: f32,
    /// Visibility of the object through the skin where it first touches (0..1).
    pub touch_visibility: f32,
    /// Indentation over which the object's visibility rises towards 1, mm.
    pub clear_mm: f32,
    /// Deformation at which the glow's source reaches `1 - 1/e`, mm.
    pub glow_mm: f32,
    /// Softening of the object's outline per mm of the press's depth, mm.
    pub edge_mm_per_mm: f32,
}

/// One parameter of the skin, for fitting: its name, how to read and write it, the range a fit
/// may search and where the search starts (fixed, so that a fit gives the same answer whatever
/// the committed skin is).
#[derive(Debug, Clone, Copy)]
pub struct SkinParameter {
    pub name: &'static str,
    pub min: f32,
    pub max: f32,
    pub start: f32,
    get: fn(&SkinModel) -> f32,
    set: fn(&mut SkinModel, f32),
}

impl SkinParameter {
    /// The parameter's value in `skin`.
    pub fn get(&self, skin: &SkinModel) -> f32 {
        (self.get)(skin)
    }
    /// Sets the parameter in `skin`, clamped to its range.
    pub fn set(&self, skin: &mut SkinModel, value: f32) {
        (self.set)(skin, if value.is_finite() { value.clamp(self.min, self.max) } else { self.min })
    }
}

macro_rules! parameter {
    ($field:ident, $min:expr, $max:expr, $start:expr) => {
        SkinParameter { name: stringify!($field), min: $min, max: $max, start: $start, get: |s| s.$field, set: |s, v| s.$field = v }
    };
}

/// Every parameter of [`SkinModel`], with the range a fit searches and its start.
pub const SKIN_PARAMETERS: [SkinParameter; 8] = [
    parameter!(spread_mm, 0.25, 6.0, 2.0),
    parameter!(spread_gain, 0.0, 5.0, 1.6),
    parameter!(lateral_mm, 0.0, 3.0, 0.15),
    parameter!(max_travel_mm, 0.05, 2.0, 1.0),
    parameter!(touch_visibility, 0.0, 1.0, 0.5),
    parameter!(clear_mm, 0.02, 5.0, 0.5),
    parameter!(glow_mm, 0.02, 5.0, 0.3),
    parameter!(edge_mm_per_mm, 0.0, 0.5, 0.05),
];

impl SkinModel {
    /// The fitted skin of `kind` (see the module docs).
    pub fn of(kind: SensorKind) -> Self {
        // What the see-through kinds do not fit, they share with TacTip's fit (the spread) or
        // keep from the search's start (ViTacTip's edge, which its fit held at 0.05).
        let shared = SkinModel {
            spread_mm: 4.875,
            spread_gain: 3.0,
            lateral_mm: 0.9,
            max_travel_mm: 1.0,
            touch_visibility: 0.5,
            clear_mm: 0.5,
            glow_mm: 1.5,
            edge_mm_per_mm: 0.05,
        };
        match kind {
            SensorKind::TacTip => shared,
            SensorKind::ViTac => SkinModel { spread_gain: 5.0, clear_mm: 0.02, glow_mm: 5.0, edge_mm_per_mm: 0.016, ..shared },
            SensorKind::ViTacTip => SkinModel { spread_gain: 5.0, lateral_mm: 1.359, clear_mm: 0.876, glow_mm: 5.0, ..shared },
        }
    }

    /// The parameters a fit for `kind` searches: the ones that matter most for what that kind
    /// shows (the opaque TacTip has no see-through; ViTac has no pins; five frames do not
    /// pin down more than a few). The others keep the values of [`SkinModel::of`]:
    /// `max_travel_mm` is a guard, `touch_visibility` is not seen apart from `clear_mm` on
    /// presses of 1-2.5 mm, the see-through kinds share TacTip's spread, and ViTacTip's edge
    /// stays at the search's start.
    pub fn fitted_parameters(kind: SensorKind) -> Vec<SkinParameter> {
        let names: &[&str] = match kind {
            SensorKind::TacTip => &["spread_mm", "spread_gain", "lateral_mm"],
            SensorKind::ViTac => &["spread_gain", "clear_mm", "glow_mm", "edge_mm_per_mm"],
            SensorKind::ViTacTip => &["spread_gain", "lateral_mm", "clear_mm", "glow_mm"],
        };
        SKIN_PARAMETERS.into_iter().filter(|p| names.contains(&p.name)).collect()
    }

    /// The same skin with every parameter brought into its range (a non-finite value becomes
    /// the range's low end).
    pub fn clamped(mut self) -> Self {
        for p in SKIN_PARAMETERS {
            let v = p.get(&self);
            p.set(&mut self, v);
        }
        self
    }

    /// Visibility of the object through the skin at a height `d_mm` above the undeformed skin
    /// (`d_mm > 0`: pressed that deep), given its visibility `gap_visibility` from the gap
    /// alone (0..1, 1 where it touches).
    #[inline(always)]
    pub fn visibility(&self, gap_visibility: f32, d_mm: f32) -> f32 {
        let pressed = 1.0 - (-(d_mm.max(0.0)) / self.clear_mm).exp();
        gap_visibility * (self.touch_visibility + (1.0 - self.touch_visibility) * pressed)
    }

    /// The glow's source (0..1) where the skin is deformed by `w_mm`.
    #[inline(always)]
    pub fn glow_source(&self, w_mm: f32) -> f32 {
        1.0 - (-(w_mm.max(0.0)) / self.glow_mm).exp()
    }
}
