//! The effect stages, each a separate function over the frame buffer.
//!
//! The frame buffer is RGB interleaved `f32` on the 8-bit scale (0..255, unclamped until the
//! end). Slowly varying quantities (skin indentation, glow) live on a coarse [`CellField`]
//! (one value per `cell` x `cell` pixels) and are sampled bilinearly, which keeps the wide
//! blurs cheap.

use crate::geometry::DepthMap;
use crate::imaging::{BoxBorder, box_blur_repeated, luma};

/// A coarse scalar field over the image, one value per square cell of `cell_px` pixels.
#[derive(Debug, Clone)]
pub struct CellField {
    pub w: usize,
    pub h: usize,
    pub cell_px: usize,
    pub v: Vec<f32>,
}

impl CellField {
    /// Mean of `f(depth)` over each cell of an image of `depth.width` x `depth.height`.
    pub fn from_depth(depth: &DepthMap, cell_px: usize, f: impl Fn(f32) -> f32) -> Self {
        let (iw, ih) = (depth.width as usize, depth.height as usize);
        let cell_px = cell_px.max(1);
        let (w, h) = (iw.div_ceil(cell_px).max(1), ih.div_ceil(cell_px).max(1));
        let mut sum = vec![0.0f32; w * h];
        let mut n = vec![0u32; w * h];
        for y in 0..ih {
            let row = &depth.height_mm[y * iw..(y + 1) * iw];
            let cy = y / cell_px;
            for (cx, chunk) in row.chunks(cell_px).enumerate() {
                let k = cy * w + cx;
                sum[k] += chunk.iter().map(|&d| f(d)).sum::<f32>();
                n[k] += chunk.len() as u32;
            }
        }
        let v = sum.iter().zip(&n).map(|(s, &c)| if c > 0 { s / c as f32 } else { 0.0 }).collect();
        Self { w, h, cell_px, v }
    }

    /// Largest value.
    pub fn max(&self) -> f32 {
        self.v.iter().copied().fold(0.0, f32::max)
    }

    /// Bilinear sample at pixel coordinates (cell centres at `(i + 0.5) * cell_px`).
    pub fn sample(&self, x_px: f32, y_px: f32) -> f32 {
        let c = self.cell_px as f32;
        let fx = (x_px / c - 0.5).clamp(0.0, (self.w - 1) as f32);
        let fy = (y_px / c - 0.5).clamp(0.0, (self.h - 1) as f32);
        let (x0, y0) = (fx as usize, fy as usize);
        let (x1, y1) = ((x0 + 1).min(self.w - 1), (y0 + 1).min(self.h - 1));
        let (tx, ty) = (fx - x0 as f32, fy - y0 as f32);
        let a = self.v[y0 * self.w + x0] * (1.0 - tx) + self.v[y0 * self.w + x1] * tx;
        let b = self.v[y1 * self.w + x0] * (1.0 - tx) + self.v[y1 * self.w + x1] * tx;
        a * (1.0 - ty) + b * ty
    }

    /// Gradient in field units per pixel, by central differences one cell apart.
    pub fn gradient_per_px(&self, x_px: f32, y_px: f32) -> [f32; 2] {
        let c = self.cell_px as f32;
        [
            (self.sample(x_px + c, y_px) - self.sample(x_px - c, y_px)) / (2.0 * c),
            (self.sample(x_px, y_px + c) - self.sample(x_px, y_px - c)) / (2.0 * c),
        ]
    }

    /// Approximately Gaussian blur: `passes` separable box blurs of radius `radius_cells`,
    /// the edge cells repeated ([`BoxBorder::Replicate`]).
    pub fn blur(&mut self, radius_cells: usize, passes: usize) {
        box_blur_repeated(&mut self.v, self.w, self.h, radius_cells, passes, BoxBorder::Replicate);
    }

    /// Calls `f(x, y, value)` for every pixel of a `width` x `height` image with the field
    /// sampled bilinearly, skipping the pixels whose four cells are all exactly `skip_value`
    /// (they would sample `skip_value`, for which `f` must do nothing).
    pub fn for_each_pixel(&self, width: usize, height: usize, skip_value: f32, f: impl FnMut(usize, f32)) {
        self.for_each_pixel_within(width, height, skip_value, |_| (0, width), f);
    }

    /// [`CellField::for_each_pixel`] over the columns `span(y)` (`[start, end)`) of each row `y`
    /// only.
    pub fn for_each_pixel_within(
        &self,
        width: usize,
        height: usize,
        skip_value: f32,
        span: impl Fn(usize) -> (usize, usize),
        mut f: impl FnMut(usize, f32),
    ) {
        let c = self.cell_px as f32;
        let cols: Vec<(usize, usize, f32)> = (0..width)
            .map(|x| {
                let fx = ((x as f32 + 0.5) / c - 0.5).clamp(0.0, (self.w - 1) as f32);
                let x0 = fx as usize;
                (x0, (x0 + 1).min(self.w - 1), fx - x0 as f32)
            })
            .collect();
        for y in 0..height {
            let fy = ((y as f32 + 0.5) / c - 0.5).clamp(0.0, (self.h - 1) as f32);
            let y0 = fy as usize;
            let y1 = (y0 + 1).min(self.h - 1);
            let ty = fy - y0 as f32;
            let (r0, r1) = (&self.v[y0 * self.w..(y0 + 1) * self.w], &self.v[y1 * self.w..(y1 + 1) * self.w]);
            // The cells of these two rows that are not `skip_value`; a pixel between two
            // cells outside them samples exactly `skip_value`.
            let live = |k: &usize| r0[*k] != skip_value || r1[*k] != skip_value;
            let (Some(k0), Some(k1)) = ((0..self.w).find(live), (0..self.w).rev().find(live)) else {
                continue;
            };
            let (start, end) = span(y);
            let first = cols.partition_point(|&(_, x1, _)| x1 < k0).max(start);
            let last = cols.partition_point(|&(x0, _, _)| x0 <= k1).min(end);
            for (x, &(x0, x1, tx)) in cols.iter().enumerate().take(last).skip(first) {
                let a = r0[x0] + (r0[x1] - r0[x0]) * tx;
                let b = r1[x0] + (r1[x1] - r1[x0]) * tx;
                f(y * width + x, a + (b - a) * ty);
            }
        }
    }
}

fn smoothstep(e0: f32, e1: f32, x: f32) -> f32 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Contact deformation: the skin is dragged in around the footprint of the object. The
/// indentation field becomes the larger of itself and its blur over `spread_px`.
pub fn contact_deformation(indent: &mut CellField, spread_px: f32) {
    let raw = indent.v.clone();
    // Three box passes of radius r approximate a Gaussian of sigma ~ r.
    let r = (spread_px / indent.cell_px as f32).round().max(1.0) as usize;
    indent.blur(r, 3);
    // The blur spreads the dent and lowers its peak; the skin still conforms to the object where
    // it touches, and the spread keeps a share of the total dent volume around it.
    for (v, &o) in indent.v.iter_mut().zip(&raw) {
        *v = o.max(*v * 1.6);
    }
}

/// Lateral skin displacement, px, per cell: down the gradient of the indentation smoothed
/// over half of `spread_px` (away from the indenter), `lateral_mm` of travel per unit slope, at most
/// `max_travel_mm`. The skin surface moves smoothly even where the object's outline is sharp:
/// taking the slope of the unsmoothed dent would throw pins at its edges across the image.
pub fn displacement_field(
    indent: &CellField,
    spread_px: f32,
    rigid_px: f32,
    px_per_mm: f32,
    lateral_mm: f32,
    max_travel_mm: f32,
) -> [CellField; 2] {
    let mut smooth = indent.clone();
    smooth.blur((0.5 * spread_px / indent.cell_px as f32).round().max(1.0) as usize, 3);
    let (mut ux, mut uy) = (indent.clone(), indent.clone());
    let c = indent.cell_px as f32;
    // g is mm of indentation per px; the slope in mm/mm is g * px_per_mm, the travel in px is
    // slope * lateral_mm * px_per_mm.
    let k = lateral_mm * px_per_mm * px_per_mm;
    let cap_px = max_travel_mm * px_per_mm;
    for cy in 0..indent.h {
        for cx in 0..indent.w {
            let g = smooth.gradient_per_px((cx as f32 + 0.5) * c, (cy as f32 + 0.5) * c);
            let (mut dx, mut dy) = (-k * g[0], -k * g[1]);
            let len = (dx * dx + dy * dy).sqrt();
            if len > cap_px && len > 0.0 {
                (dx, dy) = (dx * cap_px / len, dy * cap_px / len);
            }
            ux.v[cy * indent.w + cx] = dx;
            uy.v[cy * indent.w + cx] = dy;
        }
    }
    // Pins are rigid: each moves as a whole with the skin around it, so the field is averaged
    // over `rigid_px` (about half a pin pitch). Without this, a pin straddling the middle of
    // an edge-like dent is torn in two; with it, pins right under the object stay put.
    for f in [&mut ux, &mut uy] {
        f.blur((rigid_px / c).round() as usize, 2);
    }
    [ux, uy]
}

/// Marker displacement: each marker moves by the skin displacement at its rest position
/// (see [`displacement_field`]).
pub fn marker_displacement(markers: &mut [[f32; 2]], displacement: &[CellField; 2]) {
    for m in markers.iter_mut() {
        let (dx, dy) = (displacement[0].sample(m[0], m[1]), displacement[1].sample(m[0], m[1]));
        m[0] += dx;
        m[1] += dy;
    }
}

/// Skin displacement of a measured image: everything printed on or seen in the skin (pins,
/// texture) moves with it, so the image is resampled backwards along the displacement,
/// `out(p) = src(p - u(p))`, bilinearly. Pixels moved by less than a hundredth of a pixel are
/// left as they are.
pub fn warp_skin(buf: &mut [f32], width: usize, height: usize, displacement: &[CellField; 2]) {
    if buf.len() != width * height * 3 || width == 0 || height == 0 {
        return;
    }
    let src = buf.to_vec();
    let at = |x: usize, y: usize, c: usize| src[(y * width + x) * 3 + c];
    for y in 0..height {
        for x in 0..width {
            let (px, py) = (x as f32 + 0.5, y as f32 + 0.5);
            let (dx, dy) = (displacement[0].sample(px, py), displacement[1].sample(px, py));
            if dx.abs() < 0.01 && dy.abs() < 0.01 {
                continue;
            }
            let fx = (px - dx - 0.5).clamp(0.0, (width - 1) as f32);
            let fy = (py - dy - 0.5).clamp(0.0, (height - 1) as f32);
            let (x0, y0) = (fx as usize, fy as usize);
            let (x1, y1) = ((x0 + 1).min(width - 1), (y0 + 1).min(height - 1));
            let (tx, ty) = (fx - x0 as f32, fy - y0 as f32);
            for c in 0..3 {
                let a = at(x0, y0, c) + (at(x1, y0, c) - at(x0, y0, c)) * tx;
                let b = at(x0, y1, c) + (at(x1, y1, c) - at(x0, y1, c)) * tx;
                buf[(y * width + x) * 3 + c] = a + (b - a) * ty;
            }
        }
    }
}

/// Draws disc markers with soft edges and a halo ring.
#[allow(clippy::too_many_arguments)]
pub fn draw_markers(
    buf: &mut [f32],
    width: usize,
    height: usize,
    markers: &[[f32; 2]],
    rgb: [f32; 3],
    opacity: f32,
    radius_px: f32,
    halo: f32,
) {
    let halo_w = (radius_px * 0.35).max(1.0);
    let reach = radius_px + halo_w + 1.0;
    for m in markers {
        let (x0, x1) = ((m[0] - reach).floor().max(0.0) as usize, ((m[0] + reach).ceil().max(0.0) as usize).min(width));
        let (y0, y1) = ((m[1] - reach).floor().max(0.0) as usize, ((m[1] + reach).ceil().max(0.0) as usize).min(height));
        for y in y0..y1 {
            for x in x0..x1 {
                let (dx, dy) = (x as f32 + 0.5 - m[0], y as f32 + 0.5 - m[1]);
                let d = (dx * dx + dy * dy).sqrt();
                let i = (y * width + x) * 3;
                let cover = smoothstep(radius_px + 0.8, radius_px - 0.8, d) * opacity;
                let ring = smoothstep(radius_px + halo_w + 0.5, radius_px + 0.5, d) - cover;
                let fall = 1.0 - 0.12 * (d / radius_px).min(1.0).powi(2);
                for c in 0..3 {
                    let p = buf[i + c] * (1.0 + halo * ring.max(0.0));
                    buf[i + c] = p + (rgb[c] * fall - p) * cover;
                }
            }
        }
    }
}

/// See-through: the object under a transparent skin, bright where it presses, faint where a
/// small gap is left, with the glow it scatters into the skin (`glow` is 0..1 on cells).
///
/// The object is seen through about a millimetre of elastomer, which scatters: its outline is
/// softened over `edge_blur_px`. `skin_lum`, when given, is the skin's luminance smoothed over
/// a few marker widths (a measured look): whatever sits in front of the object in the skin
/// (markers, dust) keeps its share `lum / skin_lum` of the light, so dark pins stay visible
/// over the object as they do on the real sensors.
#[allow(clippy::too_many_arguments)]
pub fn see_through(
    buf: &mut [f32],
    depth: &DepthMap,
    fov: &[f32],
    fov_span: &[(usize, usize)],
    object_rgb: [f32; 3],
    glow_rgb: [f32; 3],
    glow: &CellField,
    gap_mm: f32,
    edge_blur_px: f32,
    skin_lum: Option<&[f32]>,
) {
    let (w, h) = (depth.width as usize, depth.height as usize);
    let transmit: Option<Vec<f32>> = skin_lum
        .filter(|l| l.len() == w * h)
        .map(|l| buf.chunks_exact(3).zip(l).map(|(p, &s)| if s > 1.0 { (luma(p) / s).clamp(0.0, 1.0) } else { 1.0 }).collect());
    let t_at = |i: usize| transmit.as_ref().map(|t| t[i]).unwrap_or(1.0);
    let glow_strength = 0.75;
    // Outside the field of view (`fov` 0) glow and object add nothing (their weight is 0).
    let span = |y: usize| fov_span.get(y).copied().unwrap_or((0, w));
    glow.for_each_pixel_within(w, h, 0.0, span, |i, g| {
        let a = (g * glow_strength * fov[i]).min(1.0);
        let t = t_at(i);
        for c in 0..3 {
            let p = &mut buf[i * 3 + c];
            *p += (glow_rgb[c] * t - *p) * a;
        }
    });
    // Visibility of the object per pixel, then softened by the scattering of the skin.
    VIS.with(|vis| {
        let mut vis = vis.borrow_mut();
        let mut field = CellField { w, h, cell_px: 1, v: std::mem::take(&mut *vis) };
        // Visibility is 0 wherever the object is farther than the gap: fill, then compute
        // only the rows and columns of the nearer pixels.
        field.v.clear();
        field.v.resize(w * h, 0.0);
        // A NaN height goes through `smoothstep`, as it always has.
        let near = |d: f32| d > -gap_mm || d.is_nan();
        let mut any = false;
        for (row, out) in depth.height_mm.chunks_exact(w.max(1)).zip(field.v.chunks_exact_mut(w.max(1))) {
            // Most rows hold no near pixel: find out without an early exit (vectorised).
            if !row.iter().fold(false, |any, &d| any | near(d)) {
                continue;
            }
            let (Some(first), Some(last)) = (row.iter().position(|&d| near(d)), row.iter().rposition(|&d| near(d))) else {
                continue;
            };
            for (v, &d) in out[first..=last].iter_mut().zip(&row[first..=last]) {
                *v = if near(d) { smoothstep(-gap_mm, 0.0, d) } else { 0.0 };
                any |= *v != 0.0;
            }
        }
        if any {
            field.blur(edge_blur_px.round().max(0.0) as usize, 2);
            for (y, row) in field.v.chunks_exact(w).enumerate() {
                if row.iter().fold(true, |none, &v| none & (v <= 0.0)) {
                    continue;
                }
                let (start, end) = span(y);
                for (x, &v) in row.iter().enumerate().take(end).skip(start) {
                    if v <= 0.0 {
                        continue;
                    }
                    let i = y * w + x;
                    let a = v * v * 0.97 * fov[i];
                    let t = t_at(i);
                    for c in 0..3 {
                        let p = &mut buf[i * 3 + c];
                        *p += (object_rgb[c] * (0.8 + 0.2 * v) * t - *p) * a;
                    }
                }
            }
        }
        *vis = field.v;
    });
}

thread_local! {
    /// The see-through visibility plane, reused from frame to frame on this thread.
    static VIS: std::cell::RefCell<Vec<f32>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Shading: brightness follows the slope of the skin towards the light. `indent` is in mm,
/// `px_per_mm` converts its gradient to a slope.
pub fn shading(buf: &mut [f32], width: usize, height: usize, indent: &CellField, px_per_mm: f32, light: [f32; 2], gain: f32) {
    // Precompute the shading factor per cell, then sample it per pixel.
    let c = indent.cell_px as f32;
    let mut factor = indent.clone();
    for cy in 0..indent.h {
        for cx in 0..indent.w {
            let g = indent.gradient_per_px((cx as f32 + 0.5) * c, (cy as f32 + 0.5) * c);
            let slope = [g[0] * px_per_mm, g[1] * px_per_mm];
            factor.v[cy * indent.w + cx] = (gain * (slope[0] * light[0] + slope[1] * light[1])).clamp(-0.3, 0.3);
        }
    }
    factor.for_each_pixel(width, height, 0.0, |i, f| {
        let k = 1.0 + f;
        for ch in 0..3 {
            buf[i * 3 + ch] *= k;
        }
    });
}

/// Motion blur: the mean of the image shifted along `direction_rad` over `length_px`.
pub fn motion_blur(buf: &mut Vec<f32>, width: usize, height: usize, length_px: f32, direction_rad: f32) {
    if length_px.is_nan() || length_px < 0.5 || width == 0 || height == 0 {
        return;
    }
    let taps = (length_px.ceil() as usize + 1).clamp(2, 64);
    let (s, c) = direction_rad.sin_cos();
    let mut out = vec![0.0f32; buf.len()];
    let norm = 1.0 / taps as f32;
    for k in 0..taps {
        let t = (k as f32 / (taps - 1) as f32 - 0.5) * length_px;
        let (dx, dy) = ((t * c).round() as isize, (t * s).round() as isize);
        for y in 0..height {
            let sy = (y as isize + dy).clamp(0, height as isize - 1) as usize;
            let src = &buf[sy * width * 3..(sy + 1) * width * 3];
            let dst = &mut out[y * width * 3..(y + 1) * width * 3];
            // Interior columns read a contiguous shifted slice; only the edges clamp.
            let lo = (-dx).clamp(0, width as isize) as usize;
            let hi = (width as isize - dx).clamp(lo as isize, width as isize) as usize;
            for x in (0..lo).chain(hi..width) {
                let sx = (x as isize + dx).clamp(0, width as isize - 1) as usize;
                for ch in 0..3 {
                    dst[x * 3 + ch] += src[sx * 3 + ch] * norm;
                }
            }
            if hi > lo {
                // Here 0 <= lo + dx and hi + dx <= width.
                let shift = (lo as isize + dx) as usize;
                let (d, s) = (&mut dst[lo * 3..hi * 3], &src[shift * 3..(shift + hi - lo) * 3]);
                for (o, i) in d.iter_mut().zip(s) {
                    *o += i * norm;
                }
            }
        }
    }
    *buf = out;
}

/// Changes from the no-contact frame below this many 8-bit levels do not widen the region
/// that motion blur processes.
pub const BLUR_IGNORE_LEVELS: f32 = 0.5;

/// Motion blur of the contact only: the camera and the skin move with the arm, so only what
/// the contact changes (the object seen through, displaced markers, shading) streaks. The
/// change from `rest` (the no-contact frame before vignetting) is blurred and added back;
/// only the box around the change (grown by the streak) is touched. Changes under
/// [`BLUR_IGNORE_LEVELS`] (the far tails of the glow) do not widen the box: they are too faint
/// to streak visibly.
pub fn contact_motion_blur(buf: &mut [f32], rest: &[f32], width: usize, height: usize, length_px: f32, direction_rad: f32) {
    if length_px.is_nan() || length_px < 0.5 || rest.len() != buf.len() || buf.len() != width * height * 3 {
        return;
    }
    // Bounding box of the change.
    let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0usize, 0usize);
    for y in 0..height {
        let row = y * width * 3..(y + 1) * width * 3;
        let (b, r) = (&buf[row.clone()], &rest[row]);
        let changed = |(b, r): (&f32, &f32)| (b - r).abs() > BLUR_IGNORE_LEVELS;
        // Most rows are unchanged: find out without an early exit (vectorised) first.
        if !b.iter().zip(r).fold(false, |any, p| any | changed(p)) {
            continue;
        }
        let first = b.iter().zip(r).position(changed);
        if let Some(f) = first {
            let last = b.iter().zip(r).rposition(changed).unwrap_or(f);
            (x0, x1) = (x0.min(f / 3), x1.max(last / 3));
            (y0, y1) = (y0.min(y), y.max(y1));
        }
    }
    if x0 > x1 {
        return;
    }
    let m = (length_px / 2.0).ceil() as usize + 1;
    let (x0, y0, x1, y1) = (x0.saturating_sub(m), y0.saturating_sub(m), (x1 + m + 1).min(width), (y1 + m + 1).min(height));
    let (cw, ch) = (x1 - x0, y1 - y0);
    let mut delta = vec![0.0f32; cw * ch * 3];
    for y in 0..ch {
        let src = ((y0 + y) * width + x0) * 3..((y0 + y) * width + x1) * 3;
        for ((d, b), r) in delta[y * cw * 3..(y + 1) * cw * 3].iter_mut().zip(&buf[src.clone()]).zip(&rest[src]) {
            *d = b - r;
        }
    }
    // The box has a margin of zero change at least half a streak wide wherever it is inside
    // the image, so clamping at its edges reads the same as clamping at the image's.
    motion_blur(&mut delta, cw, ch, length_px, direction_rad);
    for y in 0..ch {
        let dst = ((y0 + y) * width + x0) * 3..((y0 + y) * width + x1) * 3;
        for ((b, d), r) in buf[dst.clone()].iter_mut().zip(&delta[y * cw * 3..(y + 1) * cw * 3]).zip(&rest[dst]) {
            *b = r + d;
        }
    }
}

/// Vignetting: multiply by the precomputed radial gain.
pub fn vignetting(buf: &mut [f32], gain: &[f32]) {
    for (px, &g) in buf.chunks_exact_mut(3).zip(gain) {
        px[0] *= g;
        px[1] *= g;
        px[2] *= g;
    }
}

/// A 64-bit mixing function (splitmix64's finaliser): deterministic on every platform.
pub fn mix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Sensor noise: luminance noise with a read floor and a shot part growing with brightness,
/// plus a smaller independent part per channel. Deterministic in `key`.
pub fn noise(buf: &mut [f32], sigma_levels: f32, key: u64) {
    // The sum of four uniform bytes has mean 510 and standard deviation ~147.8: a cheap,
    // nearly Gaussian variate.
    const MEAN: f32 = 510.0;
    const INV_SD: f32 = 1.0 / 147.8;
    let base = mix64(key);
    for (i, px) in buf.chunks_exact_mut(3).enumerate() {
        let r = mix64(base ^ (i as u64).wrapping_mul(0x2545_f491_4f6c_dd1d));
        let b = r.to_le_bytes();
        let l = (b[0] as f32 + b[1] as f32 + b[2] as f32 + b[3] as f32 - MEAN) * INV_SD;
        let lum = (px[0] + px[1] + px[2]) * (1.0 / 765.0);
        let sd = sigma_levels * (0.6 + 0.8 * lum.max(0.0).sqrt());
        for c in 0..3 {
            let chroma = (b[4 + c] as f32 - 127.5) * (1.0 / 73.9);
            px[c] += sd * (l + 0.35 * chroma);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blur_keeps_the_mean_of_a_flat_field() {
        let mut f = CellField { w: 8, h: 6, cell_px: 4, v: vec![2.0; 48] };
        f.blur(3, 3);
        assert!(f.v.iter().all(|v| (v - 2.0).abs() < 1e-5));
    }

    #[test]
    fn motion_blur_spreads_a_point_along_the_direction() {
        let (w, h) = (21, 21);
        let mut buf = vec![0.0f32; w * h * 3];
        buf[(10 * w + 10) * 3] = 90.0;
        motion_blur(&mut buf, w, h, 8.0, 0.0);
        let row: Vec<f32> = (0..w).map(|x| buf[(10 * w + x) * 3]).collect();
        let lit = row.iter().filter(|&&v| v > 0.0).count();
        assert_eq!(lit, 9, "{row:?}");
        assert!(buf[(9 * w + 10) * 3] == 0.0);
        assert!((row.iter().sum::<f32>() - 90.0).abs() < 1e-3);
        // Streaks longer than the image only clamp at the edges.
        for (w, h) in [(1, 1), (3, 2), (5, 40)] {
            let mut b = vec![10.0f32; w * h * 3];
            motion_blur(&mut b, w, h, 60.0, 2.0);
            assert!(b.iter().all(|v| (v - 10.0).abs() < 1e-4));
        }
    }

    #[test]
    fn contact_blur_equals_blurring_the_whole_change() {
        let (w, h) = (40, 30);
        let rest: Vec<f32> = (0..w * h * 3).map(|i| (i % 17) as f32).collect();
        let mut buf = rest.clone();
        for (x, y) in [(3, 4), (20, 15), (21, 15), (38, 28)] {
            buf[(y * w + x) * 3 + 1] += 50.0;
        }
        for dir in [0.0f32, 0.7, 2.0, -1.9] {
            let mut delta: Vec<f32> = buf.iter().zip(&rest).map(|(b, r)| b - r).collect();
            motion_blur(&mut delta, w, h, 9.0, dir);
            let expected: Vec<f32> = rest.iter().zip(&delta).map(|(r, d)| r + d).collect();
            let mut got = buf.clone();
            contact_motion_blur(&mut got, &rest, w, h, 9.0, dir);
            assert!(got.iter().zip(&expected).all(|(a, b)| (a - b).abs() < 1e-3), "direction {dir}");
        }
    }

    #[test]
    fn noise_is_deterministic_and_zero_mean() {
        let mut a = vec![100.0f32; 3 * 10_000];
        let mut b = a.clone();
        noise(&mut a, 3.0, 7);
        noise(&mut b, 3.0, 7);
        assert_eq!(a, b);
        let mean = a.iter().sum::<f32>() / a.len() as f32;
        assert!((mean - 100.0).abs() < 0.2, "{mean}");
        let mut c = vec![100.0f32; 3 * 10_000];
        noise(&mut c, 3.0, 8);
        assert_ne!(a, c);
    }
}
