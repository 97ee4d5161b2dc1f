//! The static look of each sensor kind, measured on the real images of
//! `real-sample/multidiffsense-example` (512x512) and scaled to other sizes by
//! `min(width, height) / 512`.
//!
//! Measured facts (see the guide, `docs/src/simulator.md`, "A measured static look"): the markers sit in concentric rings of
//! 1, 8, 16, 16, 32, 32, 32 (137 in all) with a 25.2 px pitch, ring 1 turned by 30 deg and the
//! others by 7.5 deg; pins are about 10 px across. The field of view is a circle of radius
//! about 250 px, dark (near black, slightly blue) outside. TacTip: light grey pins on a black
//! skin. ViTac and ViTacTip: a warm beige-to-brown skin, darker and greyer towards the rim;
//! ViTacTip adds dark markers on the same lattice.
//!
//! [`StaticLook`] precomputes everything that does not change between frames: the skin
//! background (illumination, concentric texture, specks), the vignetting gain and the rest
//! positions of the markers.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::SensorKind;

/// Reference image size the constants below were measured at, px.
pub const REFERENCE_SIZE_PX: f32 = 512.0;
/// Markers per ring, from the centre out (137 in all).
pub const RING_COUNTS: [usize; 7] = [1, 8, 16, 16, 32, 32, 32];
/// Radial pitch of the marker rings at 512x512, px.
pub const RING_PITCH_PX: f32 = 25.2;
/// Radius of the circular field of view at 512x512, px.
pub const FOV_RADIUS_PX: f32 = 250.0;
/// Strength of the vignetting: gain = 1 - a * (r / fov radius)^2.
pub const VIGNETTE_STRENGTH: f32 = 0.3;

/// Marker appearance.
#[derive(Debug, Clone, Copy)]
pub struct MarkerLook {
    /// Colour at the marker centre, 8-bit linear-ish RGB.
    pub rgb: [f32; 3],
    /// Opacity at the centre.
    pub opacity: f32,
    /// Radius at 512x512, px.
    pub radius_px: f32,
    /// Relative brightness change of the ring just outside the marker (negative: darker).
    pub halo: f32,
}

impl MarkerLook {
    /// How the markers are drawn at pixel scale `scale` (relative to 512x512).
    pub fn style(&self, scale: f32) -> super::stages::MarkerStyle {
        super::stages::MarkerStyle { rgb: self.rgb, opacity: self.opacity, radius_px: self.radius_px * scale, halo: self.halo }
    }
}

/// Appearance constants of one sensor kind.
#[derive(Debug, Clone)]
pub struct Look {
    /// Skin colour as seen through the vignetting, at fractions of the field-of-view radius.
    pub profile: Vec<(f32, [f32; 3])>,
    /// Amplitude of the concentric ring texture (relative).
    pub ring_texture: f32,
    /// Whitish translucent patches on the skin (dust, moulding marks): how many, and their
    /// brightness in 8-bit levels. The real see-through skins show a handful.
    pub patches: (usize, f32),
    /// Markers, if the sensor has them.
    pub markers: Option<MarkerLook>,
    /// Colour of the object seen through the skin when pressed, if the skin is transparent.
    pub object_rgb: Option<[f32; 3]>,
    /// Colour of the glow the pressed object scatters into the skin.
    pub glow_rgb: [f32; 3],
    /// Brightness change per unit slope of the skin under the sensor's light. The opaque
    /// TacTip skin is lit from inside and shades visibly; through a transparent skin one sees
    /// the object, which the skin's tilt barely darkens (the real ViTac and ViTacTip frames
    /// show no dark rim around a contact).
    pub shading_gain: f32,
}

impl Look {
    /// The measured look of `kind`.
    pub fn of(kind: SensorKind) -> Self {
        let outside = [[14.0, 19.0, 26.0], [10.0, 14.0, 20.0]];
        match kind {
            SensorKind::TacTip => Look {
                profile: vec![
                    (0.0, [9.0, 8.0, 9.0]),
                    (0.6, [9.0, 8.0, 9.0]),
                    (0.97, [8.0, 8.0, 8.0]),
                    (1.0, [10.0, 10.0, 11.0]),
                    (1.03, [8.0, 8.0, 9.0]),
                    (1.08, [8.0, 8.0, 9.0]),
                ],
                ring_texture: 0.25,
                patches: (0, 0.0),
                markers: Some(MarkerLook { rgb: [188.0, 198.0, 202.0], opacity: 1.0, radius_px: 5.0, halo: -0.5 }),
                object_rgb: None,
                glow_rgb: [0.0; 3],
                shading_gain: 0.3,
            },
            SensorKind::ViTac => Look {
                profile: vec![
                    (0.0, [168.0, 166.0, 158.0]),
                    (0.3, [150.0, 149.0, 142.0]),
                    (0.5, [146.0, 125.0, 99.0]),
                    (0.65, [120.0, 100.0, 77.0]),
                    (0.78, [104.0, 94.0, 76.0]),
                    (0.88, [90.0, 86.0, 74.0]),
                    (0.96, [74.0, 73.0, 62.0]),
                    (0.995, [60.0, 60.0, 54.0]),
                    (1.01, outside[0]),
                    (1.08, outside[1]),
                ],
                ring_texture: 0.025,
                patches: (6, 22.0),
                markers: None,
                object_rgb: Some([252.0, 254.0, 254.0]),
                glow_rgb: [240.0, 240.0, 234.0],
                shading_gain: 0.05,
            },
            SensorKind::ViTacTip => Look {
                profile: vec![
                    (0.0, [156.0, 155.0, 148.0]),
                    (0.3, [146.0, 142.0, 132.0]),
                    (0.5, [132.0, 116.0, 94.0]),
                    (0.65, [104.0, 92.0, 74.0]),
                    (0.78, [94.0, 85.0, 70.0]),
                    (0.88, [78.0, 76.0, 65.0]),
                    (0.96, [64.0, 64.0, 57.0]),
                    (0.995, [52.0, 52.0, 48.0]),
                    (1.01, outside[0]),
                    (1.08, outside[1]),
                ],
                ring_texture: 0.025,
                patches: (6, 22.0),
                markers: Some(MarkerLook { rgb: [38.0, 35.0, 37.0], opacity: 0.92, radius_px: 4.7, halo: 0.08 }),
                object_rgb: Some([235.0, 242.0, 240.0]),
                glow_rgb: [225.0, 228.0, 222.0],
                shading_gain: 0.05,
            },
        }
    }

    /// Skin colour at `rho` (fraction of the field-of-view radius), linear between the stops.
    pub fn profile_at(&self, rho: f32) -> [f32; 3] {
        let p = &self.profile;
        let Some(first) = p.first() else { return [0.0; 3] };
        if rho <= first.0 {
            return first.1;
        }
        for w in p.windows(2) {
            let ((r0, c0), (r1, c1)) = (w[0], w[1]);
            if rho <= r1 {
                let t = if r1 > r0 { (rho - r0) / (r1 - r0) } else { 1.0 };
                return [c0[0] + t * (c1[0] - c0[0]), c0[1] + t * (c1[1] - c0[1]), c0[2] + t * (c1[2] - c0[2])];
            }
        }
        p.last().map(|l| l.1).unwrap_or([0.0; 3])
    }
}

/// Vignetting gain at `rho` (fraction of the field-of-view radius).
pub fn vignette_gain(rho: f32) -> f32 {
    1.0 - VIGNETTE_STRENGTH * rho.min(1.1).powi(2)
}

/// Rest positions of the markers for an image of `width` x `height`, px (image x right, y down).
pub fn marker_lattice(width: u32, height: u32) -> Vec<[f32; 2]> {
    let s = scale(width, height);
    // The lattice centre sits slightly up-left of the image centre in the real images.
    let cx = width as f32 / 2.0 - 1.2 * s;
    let cy = height as f32 / 2.0 - 2.6 * s;
    let mut out = Vec::with_capacity(RING_COUNTS.iter().sum());
    for (ring, &count) in RING_COUNTS.iter().enumerate() {
        let r = ring as f32 * RING_PITCH_PX * s;
        let offset_deg = if ring == 1 { 30.0 } else { 7.5 };
        for k in 0..count {
            let a = (offset_deg + 360.0 * k as f32 / count as f32).to_radians();
            out.push([cx + r * a.cos(), cy + r * a.sin()]);
        }
    }
    out
}

/// Pixel scale relative to the 512x512 reference.
pub fn scale(width: u32, height: u32) -> f32 {
    width.min(height).max(1) as f32 / REFERENCE_SIZE_PX
}

/// The precomputed, frame-independent part of a sensor image (megabytes: no `Debug`).
#[derive(Clone)]
pub struct StaticLook {
    /// Skin background before vignetting, RGB interleaved, 8-bit scale as f32.
    pub background: Vec<f32>,
    /// Vignetting gain per pixel.
    pub vignette: Vec<f32>,
    /// 1 inside the field of view, 0 outside, soft at the rim.
    pub fov: Vec<f32>,
    /// Per row, the columns `[start, end)` outside which `fov` is 0.
    pub fov_span: Vec<(usize, usize)>,
    /// Marker rest positions, px.
    pub markers: Vec<[f32; 2]>,
    /// The no-contact frame before vignetting and noise: background plus markers at rest.
    pub rest_frame: Vec<f32>,
    /// True when the background is a measured no-contact frame of a real sensor (see
    /// [`StaticLook::from_reference`]): its pins are in the image already, so contact moves
    /// them by warping the skin instead of drawing the lattice.
    pub measured: bool,
    /// For a measured look: the skin's luminance smoothed over a few marker widths, per pixel
    /// (what the skin looks like without its pins); see-through uses it to keep pins in front
    /// of the object.
    pub skin_lum: Option<Vec<f32>>,
}

impl StaticLook {
    /// Builds the static look of `look` at `width` x `height`; `seed` places the specks.
    pub fn build(look: &Look, width: u32, height: u32, seed: u64) -> Self {
        let (w, h) = (width as usize, height as usize);
        let s = scale(width, height);
        let (cx, cy) = (width as f32 / 2.0, height as f32 / 2.0);
        let fov_r = FOV_RADIUS_PX * s;
        let ring_period = 7.0 * s;
        let mut background = vec![0.0f32; w * h * 3];
        let mut vignette = vec![1.0f32; w * h];
        let mut fov = vec![0.0f32; w * h];
        for y in 0..h {
            for x in 0..w {
                let (dx, dy) = (x as f32 + 0.5 - cx, y as f32 + 0.5 - cy);
                let r = (dx * dx + dy * dy).sqrt();
                let rho = r / fov_r;
                let g = vignette_gain(rho);
                let base = look.profile_at(rho);
                // Concentric texture of the moulded skin and the tube, strongest at the rim.
                let tex = 1.0 + look.ring_texture * (0.3 + 0.7 * rho.min(1.0)) * (r / ring_period * std::f32::consts::TAU).sin();
                let i = y * w + x;
                for c in 0..3 {
                    background[i * 3 + c] = base[c] * tex / g;
                }
                vignette[i] = g;
                fov[i] = ((fov_r - r) / (1.5 * s)).clamp(0.0, 1.0);
            }
        }
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5eed_5bec);
        // Patches: soft whitish blobs of 12..30 px (at 512) between a fifth and nine tenths of
        // the radius.
        let (count, level) = look.patches;
        for _ in 0..count {
            let rho: f32 = 0.2 + 0.7 * rng.random::<f32>();
            let a: f32 = rng.random::<f32>() * std::f32::consts::TAU;
            let radius = (12.0 + 18.0 * rng.random::<f32>()) * s;
            let gain = level * (0.5 + 0.5 * rng.random::<f32>());
            let (px, py) = (cx + rho * fov_r * a.cos(), cy + rho * fov_r * a.sin());
            let reach = 2.0 * radius;
            let (x0, x1) = ((px - reach).max(0.0) as usize, ((px + reach).max(0.0) as usize).min(w));
            let (y0, y1) = ((py - reach).max(0.0) as usize, ((py + reach).max(0.0) as usize).min(h));
            for y in y0..y1 {
                for x in x0..x1 {
                    let d2 = ((x as f32 + 0.5 - px).powi(2) + (y as f32 + 0.5 - py).powi(2)) / (radius * radius);
                    let i = y * w + x;
                    let add = gain * (-d2).exp() / vignette[i].max(0.1);
                    for c in 0..3 {
                        background[i * 3 + c] += add;
                    }
                }
            }
        }
        // Dust and scratches: short bright streaks, mostly towards the rim, as in the real images.
        for k in 0..40 {
            // Two thirds on the tube rim, the rest scattered over the skin.
            let rho: f32 = if k % 3 == 0 { 0.2 + 0.75 * rng.random::<f32>() } else { 0.97 + 0.12 * rng.random::<f32>() };
            let a: f32 = rng.random::<f32>() * std::f32::consts::TAU;
            let len = (2.0 + 8.0 * rng.random::<f32>()) * s;
            let dir: f32 = rng.random::<f32>() * std::f32::consts::TAU;
            let gain = if rho < 0.97 { 15.0 + 35.0 * rng.random::<f32>() } else { 40.0 + 120.0 * rng.random::<f32>() };
            let (x0, y0) = (cx + rho * fov_r * a.cos(), cy + rho * fov_r * a.sin());
            let steps = len.ceil() as usize + 1;
            for k in 0..steps {
                let t = k as f32 / steps as f32 * len;
                let (px, py) = (x0 + t * dir.cos(), y0 + t * dir.sin());
                if px < 0.0 || py < 0.0 || px >= width as f32 || py >= height as f32 {
                    continue;
                }
                let i = py as usize * w + px as usize;
                let g = vignette[i].max(0.1);
                for c in 0..3 {
                    background[i * 3 + c] = (background[i * 3 + c] + gain / g).min(255.0 / g);
                }
            }
        }
        let markers = marker_lattice(width, height);
        let mut rest_frame = background.clone();
        if let Some(m) = look.markers {
            super::stages::draw_markers(&mut rest_frame, w, h, &markers, &m.style(s));
        }
        let fov_span = fov
            .chunks_exact(w.max(1))
            .map(|row| match (row.iter().position(|&f| f != 0.0), row.iter().rposition(|&f| f != 0.0)) {
                (Some(first), Some(last)) => (first, last + 1),
                _ => (0, 0),
            })
            .collect();
        Self { background, vignette, fov, fov_span, markers, rest_frame, measured: false, skin_lum: None }
    }

    /// The static look taken from a measured no-contact frame of one real sensor
    /// (`reference`: RGB interleaved, 8-bit, `width` x `height`): the skin, its illumination,
    /// the pins at rest, the tube and the dust are what that sensor shows, and the effect stages
    /// add the contact on top. A real rig captures such a frame at start-up anyway (tactile
    /// pipelines subtract it); this is the honest way to look like one particular sensor
    /// rather than like the average of its kind. The frame already holds the sensor's vignetting,
    /// so the vignetting gain becomes 1; the field of view stays the modelled circle (it only
    /// limits where see-through applies). Returns `None` when the buffer does
    /// not hold `width * height * 3` bytes.
    pub fn from_reference(look: &Look, reference: &[u8], width: u32, height: u32, seed: u64) -> Option<Self> {
        let n = width as usize * height as usize;
        if reference.len() != n * 3 {
            return None;
        }
        let mut out = Self::build(look, width, height, seed);
        // The measured frame holds the sensor's own fall-off: the vignetting stage has nothing
        // left to add.
        out.vignette.fill(1.0);
        out.background = reference.iter().map(|&v| v as f32).collect();
        out.rest_frame = out.background.clone();
        out.measured = true;
        // Smoothing over about three pin pitches leaves the skin without its pins; a pin's
        // luminance over it is the share of light the pin lets through.
        let s = scale(width, height);
        let mut lum = super::stages::CellField {
            w: width as usize,
            h: height as usize,
            cell_px: 1,
            v: out.background.chunks_exact(3).map(crate::imaging::luma).collect(),
        };
        lum.blur((RING_PITCH_PX * s).round().max(1.0) as usize, 3);
        out.skin_lum = Some(lum.v);
        Some(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lattice_has_the_measured_rings() {
        let m = marker_lattice(512, 512);
        assert_eq!(m.len(), 137);
        let outer = m.iter().map(|p| ((p[0] - 254.8).powi(2) + (p[1] - 253.4).powi(2)).sqrt()).fold(0.0, f32::max);
        assert!((outer - 151.2).abs() < 1.0, "outer ring at {outer}");
        assert_eq!(marker_lattice(640, 480).len(), 137);
    }

    #[test]
    fn profile_interpolates_and_clamps() {
        let l = Look::of(SensorKind::ViTac);
        assert_eq!(l.profile_at(-1.0), l.profile[0].1);
        assert_eq!(l.profile_at(9.0), l.profile.last().unwrap().1);
        let mid = l.profile_at(0.2);
        assert!(mid[0] < 168.0 && mid[0] > 152.0);
    }
}
