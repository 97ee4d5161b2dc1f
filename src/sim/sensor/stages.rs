//! The effect stages. Each works out what it needs once per frame (on the coarse cells, or on
//! the band of rows a contact reaches), then changes the frame one pixel row at a time, so the
//! renderer runs every stage on a row while that row is in cache. Only motion blur, which
//! moves pixels across rows, works on the whole frame.
//!
//! The frame buffer is RGB interleaved `f32` on the 8-bit scale (0..255, unclamped until the
//! end). Slowly varying quantities (skin indentation, glow) live on a coarse [`CellField`]
//! (one value per `cell` x `cell` pixels) and are sampled bilinearly, which keeps the wide
//! blurs cheap.

use crate::geometry::DepthMap;
use crate::imaging::{BoxBorder, RowBand, box_blur_repeated, luma};

/// A coarse scalar field over the image, one value per square cell of `cell_px` pixels.
#[derive(Debug, Clone)]
pub struct CellField {
    pub w: usize,
    pub h: usize,
    pub cell_px: usize,
    pub v: Vec<f32>,
}

impl CellField {
    /// Mean indentation, `max(height, 0)`, over each cell of an image of `depth.width` x
    /// `depth.height` (a NaN height counts as 0). Only `rows` can hold a positive height
    /// ([`near_rows`] of any gap gives them); the others count as 0.
    pub fn indentation(depth: &DepthMap, cell_px: usize, rows: std::ops::Range<usize>) -> Self {
        let (iw, ih) = (depth.width as usize, depth.height as usize);
        let cell_px = cell_px.max(1);
        let (w, h) = (iw.div_ceil(cell_px).max(1), ih.div_ceil(cell_px).max(1));
        let mut sum = vec![0.0f32; w * h];
        let lines = depth.height_mm.chunks_exact(iw.max(1)).take(ih).enumerate();
        for (y, row) in lines.skip(rows.start).take(rows.end.saturating_sub(rows.start)) {
            // A row without a positive height adds 0 to every cell: most rows of a contact.
            if !row.iter().fold(false, |any, &d| any | (d > 0.0)) {
                continue;
            }
            let sums = &mut sum[(y / cell_px) * w..(y / cell_px + 1) * w];
            for (s, chunk) in sums.iter_mut().zip(row.chunks(cell_px)) {
                *s += chunk.iter().map(|&d| d.max(0.0)).sum::<f32>();
            }
        }
        // Pixels per cell: whole cells, fewer along the right and bottom edges.
        let span = |k: usize, n: usize| n.min((k + 1) * cell_px).saturating_sub(k * cell_px);
        let v = sum
            .iter()
            .enumerate()
            .map(|(k, s)| match span(k % w, iw) * span(k / w, ih) {
                0 => 0.0,
                n => s / n as f32,
            })
            .collect();
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

    /// [`CellField::gradient_per_px`] at the centre of every cell, to `f(cx, cy, gradient)` in
    /// row order. One cell either way from a centre is the next centre, where bilinear sampling
    /// weighs that cell by exactly 1 (the centres' coordinates are exact in `f32`), so for a
    /// field of finite values the differences read the cells directly: the same gradients, up
    /// to the sign of a zero. A field holding an infinity or NaN is sampled as before, since
    /// there the weight-0 neighbour would leak into the sample.
    pub fn for_each_cell_gradient(&self, mut f: impl FnMut(usize, usize, [f32; 2])) {
        let c = self.cell_px as f32;
        if !self.v.iter().fold(true, |all, v| all & v.is_finite()) {
            for cy in 0..self.h {
                for cx in 0..self.w {
                    f(cx, cy, self.gradient_per_px((cx as f32 + 0.5) * c, (cy as f32 + 0.5) * c));
                }
            }
            return;
        }
        let w = self.w;
        let at = |x: usize, y: usize| self.v[y * w + x];
        for cy in 0..self.h {
            let (up, down) = (cy.saturating_sub(1), (cy + 1).min(self.h - 1));
            for cx in 0..w {
                let (left, right) = (cx.saturating_sub(1), (cx + 1).min(w - 1));
                f(cx, cy, [(at(right, cy) - at(left, cy)) / (2.0 * c), (at(cx, down) - at(cx, up)) / (2.0 * c)]);
            }
        }
    }

    /// Approximately Gaussian blur: `passes` separable box blurs of radius `radius_cells`,
    /// the edge cells repeated ([`BoxBorder::Replicate`]).
    pub fn blur(&mut self, radius_cells: usize, passes: usize) {
        box_blur_repeated(&mut self.v, self.w, self.h, radius_cells, passes, BoxBorder::Replicate);
    }

    /// Where each pixel column of a `width`-pixel row samples this field (the bilinear
    /// columns of [`CellField::sample`] at the pixel centres). Every field of one frame has the
    /// same cells, so one table serves them all.
    pub fn columns(&self, width: usize) -> Vec<CellColumn> {
        let c = self.cell_px as f32;
        (0..width)
            .map(|x| {
                let fx = ((x as f32 + 0.5) / c - 0.5).clamp(0.0, (self.w - 1) as f32);
                let x0 = fx as usize;
                CellColumn { x0, x1: (x0 + 1).min(self.w - 1), tx: fx - x0 as f32 }
            })
            .collect()
    }

    /// Calls `f(x, value)` for the pixels of row `y` in columns `start..end` (`cols` from
    /// [`CellField::columns`]) with the field sampled bilinearly, skipping the pixels whose four
    /// cells are all exactly `skip_value` (they would sample `skip_value`, for which `f` must do
    /// nothing).
    pub fn for_each_pixel_in_row(
        &self,
        cols: &[CellColumn],
        y: usize,
        skip_value: f32,
        span: (usize, usize),
        mut f: impl FnMut(usize, f32),
    ) {
        let Some(PixelRow { y0, y1, ty, first, last }) = self.pixel_row(cols, y, skip_value, span) else {
            return;
        };
        let (r0, r1) = (&self.v[y0 * self.w..(y0 + 1) * self.w], &self.v[y1 * self.w..(y1 + 1) * self.w]);
        for (x, c) in cols.iter().enumerate().take(last).skip(first) {
            let a = r0[c.x0] + (r0[c.x1] - r0[c.x0]) * c.tx;
            let b = r1[c.x0] + (r1[c.x1] - r1[c.x0]) * c.tx;
            f(x, a + (b - a) * ty);
        }
    }

    /// Where pixel row `y` lies between the cell rows, and which of its pixels in
    /// `start..end` have a cell that is not `skip_value` (the others sample exactly
    /// `skip_value`). `None` when none has.
    fn pixel_row(&self, cols: &[CellColumn], y: usize, skip_value: f32, (start, end): (usize, usize)) -> Option<PixelRow> {
        let fy = ((y as f32 + 0.5) / self.cell_px as f32 - 0.5).clamp(0.0, (self.h - 1) as f32);
        let y0 = fy as usize;
        let y1 = (y0 + 1).min(self.h - 1);
        let (r0, r1) = (&self.v[y0 * self.w..(y0 + 1) * self.w], &self.v[y1 * self.w..(y1 + 1) * self.w]);
        let live = |k: &usize| r0[*k] != skip_value || r1[*k] != skip_value;
        let (k0, k1) = ((0..self.w).find(live)?, (0..self.w).rev().find(live)?);
        let first = cols.partition_point(|c| c.x1 < k0).max(start);
        let last = cols.partition_point(|c| c.x0 <= k1).min(end);
        (first < last).then_some(PixelRow { y0, y1, ty: fy - y0 as f32, first, last })
    }
}

/// Pixel row `y` of a [`CellField`] ([`CellField::pixel_row`]): between cell rows `y0` and `y1`
/// with weight `ty` on the second; its pixels `first..last` are the ones to visit.
#[derive(Debug, Clone, Copy)]
struct PixelRow {
    y0: usize,
    y1: usize,
    ty: f32,
    first: usize,
    last: usize,
}

/// Where a pixel column samples a [`CellField`]: the cells either side and the weight of the
/// second.
#[derive(Debug, Clone, Copy)]
pub struct CellColumn {
    x0: usize,
    x1: usize,
    tx: f32,
}

/// A [`CellField`] sampled along pixel rows as [`CellField::for_each_pixel_in_row`] does, with
/// each cell row interpolated along x once a frame (a cell is several pixels high, and each
/// pixel row lies between two cell rows), so each pixel costs one interpolation between two
/// values in memory order.
#[derive(Debug, Default)]
pub struct RowSampler {
    /// Per cell row, its values interpolated at every pixel column, once worked out.
    along_x: Vec<f32>,
    done: Vec<bool>,
}

impl RowSampler {
    /// Forgets the rows kept (call it when the field changes).
    pub fn reset(&mut self) {
        self.done.clear();
    }

    /// The pixels of row `y` in `span` that [`CellField::for_each_pixel_in_row`] visits, and
    /// how to sample them ([`SampledRow`]). `None` when no pixel is visited.
    #[inline(always)]
    pub fn row<'a>(
        &'a mut self,
        field: &CellField,
        cols: &[CellColumn],
        y: usize,
        skip_value: f32,
        span: (usize, usize),
    ) -> Option<SampledRow<'a>> {
        let PixelRow { y0, y1, ty, first, last } = field.pixel_row(cols, y, skip_value, span)?;
        let n = cols.len();
        if self.done.is_empty() {
            self.done.resize(field.h, false);
            self.along_x.resize(field.h * n, 0.0);
        }
        for cy in [y0, y1] {
            if !self.done[cy] {
                let r = &field.v[cy * field.w..(cy + 1) * field.w];
                for (v, c) in self.along_x[cy * n..(cy + 1) * n].iter_mut().zip(cols) {
                    *v = r[c.x0] + (r[c.x1] - r[c.x0]) * c.tx;
                }
                self.done[cy] = true;
            }
        }
        let (top, bottom) = (&self.along_x[y0 * n..(y0 + 1) * n], &self.along_x[y1 * n..(y1 + 1) * n]);
        Some(SampledRow { first, last, ty, top, bottom })
    }
}

/// A pixel row of a [`CellField`] ([`RowSampler::row`]): the pixels `first..last` are visited,
/// and pixel `x`'s value is `top[x] + (bottom[x] - top[x]) * ty`.
#[derive(Debug)]
pub struct SampledRow<'a> {
    pub first: usize,
    pub last: usize,
    pub ty: f32,
    pub top: &'a [f32],
    pub bottom: &'a [f32],
}

#[inline(always)]
fn smoothstep(e0: f32, e1: f32, x: f32) -> f32 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Contact deformation, the indentation of the elastomer skin: it conforms to the object where
/// it presses and is dragged in around the footprint. The field becomes the larger of the dent
/// and `gain` times its blur over `spread_px` (the superposition of every pressed cell's
/// response under one smoothing kernel, [`super::SkinModel`]): linear in the dent, so a deeper
/// press drags the skin in further and over a wider field.
pub fn contact_deformation(indent: &mut CellField, spread_px: f32, gain: f32) {
    let raw = indent.v.clone();
    // Three box passes of radius r approximate a Gaussian of sigma ~ r.
    let r = (spread_px / indent.cell_px as f32).round().max(1.0) as usize;
    indent.blur(r, 3);
    // The blur spreads the dent and lowers its peak; the skin still conforms to the object where
    // it touches, and the spread keeps a share of the total dent volume around it.
    for (v, &o) in indent.v.iter_mut().zip(&raw) {
        *v = o.max(*v * gain);
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
    smooth.for_each_cell_gradient(|cx, cy, g| {
        let (mut dx, mut dy) = (-k * g[0], -k * g[1]);
        let len = (dx * dx + dy * dy).sqrt();
        if len > cap_px && len > 0.0 {
            (dx, dy) = (dx * cap_px / len, dy * cap_px / len);
        }
        ux.v[cy * indent.w + cx] = dx;
        uy.v[cy * indent.w + cx] = dy;
    });
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

/// Skin displacement of a measured image, row `y` of it: everything printed on or seen in the
/// skin (pins, texture) moves with it, so the image is resampled backwards along the
/// displacement, `out(p) = src(p - u(p))`, bilinearly from `src` (the undisplaced frame).
/// Pixels moved by less than a hundredth of a pixel are left as they are.
#[inline(always)]
pub fn warp_skin_row(row: &mut [f32], y: usize, src: &[f32], width: usize, height: usize, displacement: &[CellField; 2]) {
    if src.len() != width * height * 3 || row.len() != width * 3 || width == 0 || y >= height {
        return;
    }
    let at = |x: usize, y: usize, c: usize| src[(y * width + x) * 3 + c];
    let py = y as f32 + 0.5;
    for x in 0..width {
        let px = x as f32 + 0.5;
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
            row[x * 3 + c] = a + (b - a) * ty;
        }
    }
}

/// How markers are drawn: discs with soft edges and a halo ring.
#[derive(Debug, Clone, Copy)]
pub struct MarkerStyle {
    pub rgb: [f32; 3],
    pub opacity: f32,
    pub radius_px: f32,
    /// Relative brightness change of the ring just outside the marker.
    pub halo: f32,
}

/// Draws `markers` on a whole `width` x `height` frame.
pub fn draw_markers(buf: &mut [f32], width: usize, height: usize, markers: &[[f32; 2]], style: &MarkerStyle) {
    let mut rows = MarkerRows::new(markers, width, height, *style);
    for (y, row) in buf.chunks_exact_mut(width * 3).take(height).enumerate() {
        rows.draw(row, y);
    }
}

/// Markers drawn row by row: each marker's pixel box, and as the rows go down, the markers whose
/// box reaches the row, in marker order (a pixel two markers reach gets them in that order, as
/// when they are drawn one after the other).
#[derive(Debug)]
pub struct MarkerRows<'a> {
    markers: &'a [[f32; 2]],
    style: MarkerStyle,
    /// Per marker, `[x0, x1, y0, y1)`.
    boxes: Vec<[usize; 4]>,
    /// Marker indices by first row.
    by_top: Vec<usize>,
    next: usize,
    active: Vec<usize>,
    width: usize,
    /// One marker's weights along the current row: halo gain, cover and fall-off.
    weights: Vec<[f32; 3]>,
}

impl<'a> MarkerRows<'a> {
    /// `markers` drawn in `style` on rows of a `width` x `height` frame.
    pub fn new(markers: &'a [[f32; 2]], width: usize, height: usize, style: MarkerStyle) -> Self {
        let reach = style.radius_px + halo_width(style.radius_px) + 1.0;
        let span = |c: f32, n: usize| [(c - reach).floor().max(0.0) as usize, ((c + reach).ceil().max(0.0) as usize).min(n)];
        let boxes: Vec<[usize; 4]> = markers
            .iter()
            .map(|m| {
                let ([x0, x1], [y0, y1]) = (span(m[0], width), span(m[1], height));
                [x0, x1, y0, y1]
            })
            .collect();
        let mut by_top: Vec<usize> = (0..markers.len()).collect();
        by_top.sort_by_key(|&k| boxes[k][2]);
        Self { markers, style, boxes, by_top, next: 0, active: Vec::new(), width, weights: Vec::new() }
    }

    /// Draws the markers that reach row `y` (rows must come in increasing order) on `row`.
    #[inline(always)]
    pub fn draw(&mut self, row: &mut [f32], y: usize) {
        let mut added = false;
        while let Some(&k) = self.by_top.get(self.next).filter(|&&k| self.boxes[k][2] <= y) {
            self.active.push(k);
            self.next += 1;
            added = true;
        }
        let boxes = &self.boxes;
        self.active.retain(|&k| boxes[k][3] > y);
        if added {
            self.active.sort_unstable();
        }
        let MarkerRows { markers, style, active, boxes, weights, width, .. } = self;
        let halo_w = halo_width(style.radius_px);
        let r = style.radius_px;
        for &k in active.iter() {
            let (m, [x0, x1, ..]) = (markers[k], boxes[k]);
            let x1 = x1.min(*width).max(x0);
            // The marker's weights along the row first (a loop the compiler vectorises), then
            // the blend: the same operations per pixel as drawing it pixel by pixel.
            weights.clear();
            weights.resize(x1 - x0, [0.0; 3]);
            let dy = y as f32 + 0.5 - m[1];
            for (k, w) in weights.iter_mut().enumerate() {
                // Pixel columns are far below 2^24: as i32 they convert exactly, and vectorise.
                let dx = ((x0 + k) as i32) as f32 + 0.5 - m[0];
                let d = (dx * dx + dy * dy).sqrt();
                let cover = smoothstep(r + 0.8, r - 0.8, d) * style.opacity;
                let ring = smoothstep(r + halo_w + 0.5, r + 0.5, d) - cover;
                let fall = 1.0 - 0.12 * (d / r).min(1.0).powi(2);
                *w = [1.0 + style.halo * ring.max(0.0), cover, fall];
            }
            for (px, &[gain, cover, fall]) in row[3 * x0..3 * x1].chunks_exact_mut(3).zip(weights.iter()) {
                for (v, &rgb) in px.iter_mut().zip(&style.rgb) {
                    let p = *v * gain;
                    *v = p + (rgb * fall - p) * cover;
                }
            }
        }
    }
}

/// Width of the halo ring around a marker of `radius_px`, px.
fn halo_width(radius_px: f32) -> f32 {
    (radius_px * 0.35).max(1.0)
}

/// See-through: the object under a transparent skin, bright where it presses, faint where a
/// small gap is left, with the glow it scatters into the skin. This is row `y` of it: first the
/// glow (`glow` is 0..1 on cells), then the object itself with its visibility `vis` (the row of
/// [`visibility`], `None` where it is zero).
///
/// The object is seen through about a millimetre of elastomer, which scatters: its outline is
/// softened (see [`visibility`]). `transmit`, for a measured look, is the share of light that
/// whatever sits in front of the object in the skin (markers, dust) lets through, per pixel
/// ([`transmit_row`]): dark pins stay visible over the object as they do on the real sensors.
/// Outside the field of view (`fov_row` 0, and outside `span`) glow and object add nothing.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub fn see_through_row(
    row: &mut [f32],
    y: usize,
    glow: &CellField,
    cols: &[CellColumn],
    sampler: &mut RowSampler,
    vis: Option<&[f32]>,
    fov_row: &[f32],
    span: (usize, usize),
    object_rgb: [f32; 3],
    glow_rgb: [f32; 3],
    transmit: Option<&[f32]>,
) {
    let t_at = |x: usize| transmit.map_or(1.0, |t| t[x]);
    let glow_strength = 0.75;
    if let Some(SampledRow { first, last, ty, top, bottom }) = sampler.row(glow, cols, y, 0.0, span) {
        let pixels =
            row[3 * first..3 * last].chunks_exact_mut(3).zip(&top[first..last]).zip(&bottom[first..last]).zip(&fov_row[first..last]);
        match transmit {
            // Without a measured look every pixel lets all light through (t = 1): the same
            // blend, in a loop the compiler vectorises.
            None => {
                for (((p, &a), &b), &fov) in pixels {
                    let g = a + (b - a) * ty;
                    let alpha = (g * glow_strength * fov).min(1.0);
                    for c in 0..3 {
                        p[c] += (glow_rgb[c] - p[c]) * alpha;
                    }
                }
            }
            Some(t) => {
                for ((((p, &a), &b), &fov), &t) in pixels.zip(&t[first..last]) {
                    let g = a + (b - a) * ty;
                    let alpha = (g * glow_strength * fov).min(1.0);
                    for c in 0..3 {
                        p[c] += (glow_rgb[c] * t - p[c]) * alpha;
                    }
                }
            }
        }
    }
    let Some(vis) = vis else { return };
    // The pixels the object shows through: visibility above 0 (or NaN, which is not below).
    let shows = |v: &f32| v.is_nan() || *v > 0.0;
    let (start, end) = (span.0, span.1.min(vis.len()));
    let (Some(first), Some(last)) = (vis[start.min(end)..end].iter().position(shows), vis[start.min(end)..end].iter().rposition(shows))
    else {
        return;
    };
    let (first, last) = (start + first, start + last + 1);
    // Branch-free: a pixel that does not show keeps its value (the blend's result is dropped).
    let pixels = row[3 * first..3 * last].chunks_exact_mut(3).zip(&vis[first..last]).zip(&fov_row[first..last]);
    for (x, ((p, &v), &fov)) in (first..).zip(pixels) {
        let a = v * v * 0.97 * fov;
        let t = t_at(x);
        let seen = shows(&v);
        for c in 0..3 {
            let blended = p[c] + (object_rgb[c] * (0.8 + 0.2 * v) * t - p[c]) * a;
            p[c] = if seen { blended } else { p[c] };
        }
    }
}

/// For a measured look: the share of light each pixel of `row` keeps over the skin's smoothed
/// luminance `skin_lum` (its pins and dust darker than the skin), into `out`.
#[inline(always)]
pub fn transmit_row(row: &[f32], skin_lum: &[f32], out: &mut Vec<f32>) {
    out.clear();
    out.extend(row.chunks_exact(3).zip(skin_lum).map(|(p, &s)| if s > 1.0 { (luma(p) / s).clamp(0.0, 1.0) } else { 1.0 }));
}

/// The visibility of the object through the skin per pixel, into `band`: where it presses,
/// rising with the local depth of the press ([`super::SkinModel::visibility`]), falling to 0
/// at `gap_mm` below the skin, blurred over `edge_blur_px` by the scattering of the skin (two
/// box passes with the edge repeated). Only the rows near the object are worked on
/// ([`RowBand`]). False when the object is nowhere near the skin (then `band` holds nothing of
/// use). `band` and `scratch` are buffers reused from frame to frame.
pub fn visibility(
    depth: &DepthMap,
    gap_mm: f32,
    edge_blur_px: f32,
    skin: &super::SkinModel,
    near_rows: std::ops::Range<usize>,
    band: &mut RowBand,
    scratch: &mut RowBand,
) -> bool {
    let (w, h) = (depth.width as usize, depth.height as usize);
    if w == 0 || depth.height_mm.len() != w * h || near_rows.is_empty() {
        return false;
    }
    let near = |d: f32| is_near(d, gap_mm);
    let lines = || depth.height_mm.chunks_exact(w);
    let top = near_rows.start;
    let rows = band.reset(w, h, top, near_rows.len());
    let mut any = false;
    for (row, out) in lines().skip(top).zip(rows.chunks_exact_mut(w)) {
        let (Some(first), Some(last)) = (row.iter().position(|&d| near(d)), row.iter().rposition(|&d| near(d))) else {
            continue;
        };
        for (v, &d) in out[first..=last].iter_mut().zip(&row[first..=last]) {
            *v = if near(d) { skin.visibility(smoothstep(-gap_mm, 0.0, d), d) } else { 0.0 };
            any |= *v != 0.0;
        }
    }
    if any {
        band.blur_replicate(edge_blur_px.round().max(0.0) as usize, 2, scratch);
    }
    any
}

/// True for a height less than `gap_mm` below the skin (a NaN height too: it goes through the
/// stages as it always has).
fn is_near(d: f32, gap_mm: f32) -> bool {
    d > -gap_mm || d.is_nan()
}

/// The rows of `depth` holding a height less than `gap_mm` (at least 0) below the skin, as
/// `first..last + 1` (empty when there is none): every positive height lies in them. The one
/// scan of the whole depth map a frame makes.
pub fn near_rows(depth: &DepthMap, gap_mm: f32) -> std::ops::Range<usize> {
    let w = depth.width as usize;
    if w == 0 || depth.height_mm.len() != w * depth.height as usize {
        return 0..0;
    }
    // Most rows hold no near pixel: find out without an early exit (vectorised).
    let has_near = |row: &[f32]| row.iter().fold(false, |any, &d| any | is_near(d, gap_mm));
    let mut lines = depth.height_mm.chunks_exact(w);
    match (lines.position(has_near), lines.rposition(has_near)) {
        (Some(first), Some(last)) => first..first + last + 2,
        (Some(first), None) => first..first + 1,
        _ => 0..0,
    }
}

/// Shading: brightness follows the slope of the skin towards the light. The factor per cell
/// (added to 1) from `indent` (mm); `px_per_mm` converts its gradient to a slope.
pub fn shading_factor(indent: &CellField, px_per_mm: f32, light: [f32; 2], gain: f32) -> CellField {
    let mut factor = indent.clone();
    indent.for_each_cell_gradient(|cx, cy, g| {
        let slope = [g[0] * px_per_mm, g[1] * px_per_mm];
        factor.v[cy * indent.w + cx] = (gain * (slope[0] * light[0] + slope[1] * light[1])).clamp(-0.3, 0.3);
    });
    factor
}

/// Shading of row `y`: each pixel times one plus the factor sampled there.
#[inline(always)]
pub fn shade_row(row: &mut [f32], y: usize, factor: &CellField, cols: &[CellColumn]) {
    factor.for_each_pixel_in_row(cols, y, 0.0, (0, cols.len()), |x, f| {
        let k = 1.0 + f;
        for ch in 0..3 {
            row[x * 3 + ch] *= k;
        }
    });
}

/// Motion blur: the mean of the image shifted along `direction_rad` over `length_px`.
pub fn motion_blur(buf: &mut Vec<f32>, width: usize, height: usize, length_px: f32, direction_rad: f32) {
    let mut out = Vec::new();
    if motion_blur_into(buf, &mut out, width, height, length_px, direction_rad) {
        *buf = out;
    }
}

/// [`motion_blur`] of `buf` into `out` (resized; its buffer reused). False, and `out` left as it
/// was, when there is nothing to blur.
fn motion_blur_into(buf: &[f32], out: &mut Vec<f32>, width: usize, height: usize, length_px: f32, direction_rad: f32) -> bool {
    if length_px.is_nan() || length_px < 0.5 || width == 0 || height == 0 || buf.len() < width * height * 3 {
        return false;
    }
    let taps = (length_px.ceil() as usize + 1).clamp(2, 64);
    let (s, c) = direction_rad.sin_cos();
    out.clear();
    out.resize(buf.len(), 0.0);
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
    true
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
/// `scratch` holds the change and its blur, reused from frame to frame.
pub fn contact_motion_blur(
    buf: &mut [f32],
    rest: &[f32],
    width: usize,
    height: usize,
    length_px: f32,
    direction_rad: f32,
    scratch: &mut [Vec<f32>; 2],
) {
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
    let [delta, blurred] = scratch;
    delta.clear();
    delta.resize(cw * ch * 3, 0.0);
    for y in 0..ch {
        let src = ((y0 + y) * width + x0) * 3..((y0 + y) * width + x1) * 3;
        for ((d, b), r) in delta[y * cw * 3..(y + 1) * cw * 3].iter_mut().zip(&buf[src.clone()]).zip(&rest[src]) {
            *d = b - r;
        }
    }
    // The box has a margin of zero change at least half a streak wide wherever it is inside
    // the image, so clamping at its edges reads the same as clamping at the image's.
    let delta = if motion_blur_into(delta, blurred, cw, ch, length_px, direction_rad) { blurred } else { delta };
    for y in 0..ch {
        let dst = ((y0 + y) * width + x0) * 3..((y0 + y) * width + x1) * 3;
        for ((b, d), r) in buf[dst.clone()].iter_mut().zip(&delta[y * cw * 3..(y + 1) * cw * 3]).zip(&rest[dst]) {
            *b = r + d;
        }
    }
}

/// Vignetting: multiply each pixel of `px` by its precomputed radial gain.
#[inline(always)]
pub fn vignetting(px: &mut [f32], gain: &[f32]) {
    for (p, &g) in px.chunks_exact_mut(3).zip(gain) {
        p[0] *= g;
        p[1] *= g;
        p[2] *= g;
    }
}

/// The 8-bit values of `px` into `out`: `(v + 0.5) as u8`, which rounds and saturates (NaN to
/// 0), written as a clamp to `[0, 255]` and a truncation so that it vectorises (the same bytes
/// for every `f32`).
#[inline(always)]
pub fn to_bytes(px: &[f32], out: &mut [u8]) {
    for (o, &v) in out.iter_mut().zip(px) {
        let x = v + 0.5;
        // Both comparisons are false for NaN, which becomes 0.
        let x = if x >= 0.0 { x } else { 0.0 };
        let x = if x <= 255.0 { x } else { 255.0 };
        // SAFETY: `x` lies in [0, 255], where the conversion is exact truncation.
        *o = unsafe { x.to_int_unchecked::<i32>() } as u8;
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
/// plus a smaller independent part per channel. Deterministic in `key` and each pixel's index
/// in the frame; `px` holds the pixels from index `first_pixel` on.
#[inline(always)]
pub fn noise(px: &mut [f32], first_pixel: usize, sigma_levels: f32, key: u64) {
    // The sum of four uniform bytes has mean 510 and standard deviation ~147.8: a cheap,
    // nearly Gaussian variate.
    const MEAN: f32 = 510.0;
    const INV_SD: f32 = 1.0 / 147.8;
    let base = mix64(key);
    for (k, px) in px.chunks_exact_mut(3).enumerate() {
        let i = first_pixel + k;
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

    fn values(seed: &mut u64, n: usize) -> Vec<f32> {
        (0..n)
            .map(|_| {
                *seed = mix64(*seed);
                (*seed % 2001) as f32 / 1000.0 - 1.0
            })
            .collect()
    }

    /// Gradients read from the neighbouring cells equal those sampled one cell either side of
    /// each centre, for cell sizes and field shapes of every kind, and a field holding a NaN or
    /// an infinity is sampled.
    #[test]
    fn cell_gradients_equal_the_sampled_ones() {
        let mut seed = 3u64;
        for (w, h, cell_px) in [(1, 1, 1), (5, 3, 4), (7, 9, 3), (16, 12, 5), (40, 30, 4), (3, 8, 7), (2, 2, 2)] {
            let mut fields = vec![CellField { w, h, cell_px, v: values(&mut seed, w * h) }];
            for odd in [f32::NAN, f32::INFINITY] {
                let mut f = fields[0].clone();
                f.v[(w * h) / 2] = odd;
                fields.push(f);
            }
            for f in &fields {
                let c = cell_px as f32;
                f.for_each_cell_gradient(|cx, cy, g| {
                    let expected = f.gradient_per_px((cx as f32 + 0.5) * c, (cy as f32 + 0.5) * c);
                    for k in 0..2 {
                        assert!(
                            g[k] == expected[k] || (g[k].is_nan() && expected[k].is_nan()),
                            "{w}x{h} cell {cell_px} ({cx}, {cy}): {g:?} {expected:?}"
                        );
                    }
                });
            }
        }
    }

    /// The indentation field equals the plain mean of `max(height, 0)` per cell over every row,
    /// given only the near rows, with NaN and negative heights and sizes that do not divide
    /// into cells.
    #[test]
    fn the_indentation_field_is_the_mean_positive_height_per_cell() {
        let mut seed = 11u64;
        for (w, h, cell_px) in [(13usize, 9usize, 4usize), (8, 8, 2), (17, 5, 3), (1, 1, 1), (30, 21, 5)] {
            let mut height_mm = values(&mut seed, w * h);
            for (i, v) in height_mm.iter_mut().enumerate() {
                if i % 7 == 0 {
                    *v = f32::NAN;
                } else if i / w < h / 3 {
                    *v = -2.0;
                }
            }
            let depth = DepthMap { width: w as u32, height: h as u32, height_mm };
            let (cw, ch) = (w.div_ceil(cell_px), h.div_ceil(cell_px));
            let mut expected = vec![0.0f32; cw * ch];
            let mut count = vec![0u32; cw * ch];
            for (y, row) in depth.height_mm.chunks(w).enumerate() {
                for (cx, chunk) in row.chunks(cell_px).enumerate() {
                    expected[(y / cell_px) * cw + cx] += chunk.iter().map(|&d| d.max(0.0)).sum::<f32>();
                    count[(y / cell_px) * cw + cx] += chunk.len() as u32;
                }
            }
            for (e, &n) in expected.iter_mut().zip(&count) {
                *e /= n as f32;
            }
            let got = CellField::indentation(&depth, cell_px, near_rows(&depth, 0.6));
            assert_eq!((got.w, got.h), (cw, ch));
            assert_eq!(got.v, expected, "{w}x{h} cell {cell_px}");
        }
    }

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
            contact_motion_blur(&mut got, &rest, w, h, 9.0, dir, &mut Default::default());
            assert!(got.iter().zip(&expected).all(|(a, b)| (a - b).abs() < 1e-3), "direction {dir}");
        }
    }

    #[test]
    fn noise_is_deterministic_and_zero_mean() {
        let mut a = vec![100.0f32; 3 * 10_000];
        let mut b = a.clone();
        noise(&mut a, 0, 3.0, 7);
        noise(&mut b[..3 * 4000], 0, 3.0, 7);
        noise(&mut b[3 * 4000..], 4000, 3.0, 7);
        assert_eq!(a, b);
        let mean = a.iter().sum::<f32>() / a.len() as f32;
        assert!((mean - 100.0).abs() < 0.2, "{mean}");
        let mut c = vec![100.0f32; 3 * 10_000];
        noise(&mut c, 0, 3.0, 8);
        assert_ne!(a, c);
    }
}
