//! The depth rasteriser: the object as the sensor sees it at a pose.
//!
//! Conventions (the contract every user of [`render_depth`] relies on):
//!
//! - The object's **reference point** is the mesh origin's x/y at the height of the mesh's top
//!   (its largest z). For the library objects (features centred on the origin) that is the
//!   middle of the top face; for the real straight edge it is the middle of the ridge.
//! - `object_pose` is the sensor relative to that point, in the work frame: `x_mm`/`y_mm` move
//!   the sensor centre away from the reference point, `z_mm` is the indentation (positive: the
//!   skin plane lies `z_mm` below the object's top), `yaw_deg` turns the sensor about z, so the
//!   object appears turned by `-yaw_deg` in the sensor frame.
//! - Projection is orthographic along -z through a [`Calibration`] (sensor-frame mm to px),
//!   scaled to the requested image size. Each pixel holds the highest surface over its centre
//!   minus the skin plane ([`DepthMap::height_mm`]); pixels no triangle covers hold
//!   [`DepthMap::BACKGROUND_MM`].
//!
//! It is a scan-converting triangle rasteriser with a z-buffer (each triangle visits only the
//! pixels of its bounding box), so cost grows with covered pixels, not pixels x triangles.
//! Supersampling renders `s x s` samples per pixel and averages the covered ones; a pixel is
//! background when fewer than half its samples hit the object.

use glam::{DAffine2, DMat2, DVec2};

use super::DepthMap;
use super::stl::Mesh;
use crate::calibration::model::Calibration;
use crate::pose::Pose;

/// Image size and supersampling of a depth render.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RasterOptions {
    pub width: u32,
    pub height: u32,
    /// Samples per pixel along each axis (1 = none). Values above 8 are clamped to 8.
    pub supersample: u32,
}

impl Default for RasterOptions {
    fn default() -> Self {
        Self { width: 512, height: 512, supersample: 1 }
    }
}

/// Largest supersampling factor accepted (64 samples per pixel).
pub const MAX_SUPERSAMPLE: u32 = 8;
/// Most samples a supersampled render may hold (256 MiB of f32); the factor is lowered to fit.
pub const MAX_SAMPLES: u64 = 1 << 26;

/// Renders `mesh` under the sensor at `object_pose` (see the module docs) into a
/// `width x height` depth map, `calib` scaled to that size, with `supersample`^2 samples per
/// pixel (0 is treated as 1; lowered so the samples stay within [`MAX_SAMPLES`]). A pose with a
/// non-finite component renders nothing.
pub fn render_depth(mesh: &Mesh, object_pose: &Pose, calib: &Calibration, width: u32, height: u32, supersample: u32) -> DepthMap {
    let mut out = DepthMap::empty(0, 0);
    render_depth_into(&PreparedMesh::new(mesh), object_pose, calib, width, height, supersample, &mut RasterScratch::default(), &mut out);
    out
}

/// A mesh ready to be rendered: the triangles that can show from above (walls, whose normal is
/// nearly horizontal, project to slivers whose interpolated heights are ill-conditioned; the
/// faces around them already cover those pixels) and the mesh's top.
/// [`PreparedMesh::for_many_renders`] also sorts them and stores the vertices they share once.
#[derive(Debug, Clone)]
pub struct PreparedMesh {
    /// The corners of the kept triangles.
    vertices: Vec<glam::Vec3>,
    /// Each kept triangle as three indices into `vertices`.
    triangles: Vec<[u32; 3]>,
    top_z_mm: f32,
}

impl PreparedMesh {
    /// `mesh` without its walls, in its own order, each triangle with its own three corners
    /// (cheap to build: what a single render wants).
    pub fn new(mesh: &Mesh) -> Self {
        let kept = mesh.triangles.iter().filter(|tri| {
            let n = (tri[1] - tri[0]).cross(tri[2] - tri[0]);
            n.z.abs() > 1e-4 * n.length()
        });
        let vertices: Vec<glam::Vec3> = kept.flatten().copied().collect();
        // `Mesh` bounds its triangles far below 2^32 / 3.
        let triangles = (0..vertices.len() as u32 / 3).map(|t| [3 * t, 3 * t + 1, 3 * t + 2]).collect();
        Self { vertices, triangles, top_z_mm: mesh.top_z_mm() }
    }

    /// `mesh` prepared to be drawn many times (the control maps of a dataset, a simulated
    /// sensor's frames): [`PreparedMesh::new`], sorted top down, with each vertex the triangles
    /// share stored once, so that a render projects it once. The renders are the same.
    pub fn for_many_renders(mesh: &Mesh) -> Self {
        Self::new(mesh).sorted_top_down().with_shared_vertices()
    }

    /// The same triangles, each vertex they share (equal bits) stored once.
    fn with_shared_vertices(self) -> Self {
        let mut index = std::collections::HashMap::new();
        let mut vertices = Vec::new();
        let triangles = self
            .triangles
            .iter()
            .map(|tri| {
                tri.map(|i| {
                    let v = self.vertices[i as usize];
                    *index.entry(v.to_array().map(f32::to_bits)).or_insert_with(|| {
                        vertices.push(v);
                        // At most as many as the corners, which fit in u32.
                        (vertices.len() - 1) as u32
                    })
                })
            })
            .collect();
        Self { vertices, triangles, top_z_mm: self.top_z_mm }
    }

    /// Orders the triangles by their highest vertex, top first. The result of a render does not
    /// depend on the order, but the rasteriser skips a triangle that lies under what it has
    /// already drawn, so a mesh drawn many times is worth sorting once.
    pub fn sorted_top_down(mut self) -> Self {
        let v = &self.vertices;
        let top = |t: &[u32; 3]| v[t[0] as usize].z.max(v[t[1] as usize].z).max(v[t[2] as usize].z);
        self.triangles.sort_by(|a, b| top(b).total_cmp(&top(a)));
        self
    }

    /// Triangles kept.
    pub fn len(&self) -> usize {
        self.triangles.len()
    }

    /// True when no triangle can show from above.
    pub fn is_empty(&self) -> bool {
        self.triangles.is_empty()
    }
}

/// [`render_depth`] with the size and supersampling in one value.
pub fn render_depth_with(mesh: &Mesh, object_pose: &Pose, calib: &Calibration, opts: &RasterOptions) -> DepthMap {
    render_depth(mesh, object_pose, calib, opts.width, opts.height, opts.supersample)
}

/// The buffers a depth render reuses from call to call: the projected triangles and the
/// supersampled samples. A renderer that draws many poses through one scratch (one per
/// thread) allocates nothing once the buffers have grown to the largest render.
#[derive(Debug, Default)]
pub struct RasterScratch {
    vertices: Vec<(DVec2, f64)>,
    triangles: Vec<Projected>,
    samples: Vec<f32>,
}

/// One triangle projected to sample space, with its sample bounding box (inclusive).
#[derive(Debug, Clone, Copy)]
struct Projected {
    a: DVec2,
    b: DVec2,
    c: DVec2,
    z: [f64; 3],
    inv_area: f64,
    i0: usize,
    i1: usize,
    j0: usize,
    j1: usize,
}

/// A rectangle of samples, inclusive bounds.
#[derive(Debug, Clone, Copy)]
struct Region {
    i0: usize,
    i1: usize,
    j0: usize,
    j1: usize,
}

/// [`render_depth`] into `out` (resized to `width x height`), with the buffers of `scratch`.
///
/// Only the samples under the projected object's bounding box are cleared, rasterised and
/// averaged; the rest of `out` is background. The result equals [`render_depth`]'s bit for bit.
#[allow(clippy::too_many_arguments)]
pub fn render_depth_into(
    mesh: &PreparedMesh,
    object_pose: &Pose,
    calib: &Calibration,
    width: u32,
    height: u32,
    supersample: u32,
    scratch: &mut RasterScratch,
    out: &mut DepthMap,
) {
    out.width = width;
    out.height = height;
    out.height_mm.clear();
    out.height_mm.resize(width as usize * height as usize, DepthMap::BACKGROUND_MM);
    if width == 0 || height == 0 || !object_pose.is_finite() {
        return;
    }
    // Keep the supersampled buffer bounded (MAX_SAMPLES f32s) whatever size is asked for.
    let mut ss = supersample.clamp(1, MAX_SUPERSAMPLE);
    while ss > 1 && (width as u64 * ss as u64) * (height as u64 * ss as u64) > MAX_SAMPLES {
        ss -= 1;
    }
    let (sw, sh) = (width * ss, height * ss);
    let RasterScratch { vertices, triangles, samples } = scratch;
    let Some(covered) = project(mesh, object_pose, &calib.scaled_to(sw, sh), sw as usize, sh as usize, vertices, triangles) else {
        return;
    };
    if ss == 1 {
        let all = Region { i0: 0, i1: width as usize - 1, j0: 0, j1: height as usize - 1 };
        rasterise(triangles, &mut out.height_mm, all);
        return;
    }
    // The covered samples, widened to whole output pixels.
    let ss = ss as usize;
    let (x0, x1, y0, y1) = (covered.i0 / ss, covered.i1 / ss, covered.j0 / ss, covered.j1 / ss);
    let region = Region { i0: x0 * ss, i1: (x1 + 1) * ss - 1, j0: y0 * ss, j1: (y1 + 1) * ss - 1 };
    let (rw, rh) = (region.i1 - region.i0 + 1, region.j1 - region.j0 + 1);
    samples.clear();
    samples.resize(rw * rh, DepthMap::BACKGROUND_MM);
    rasterise(triangles, samples, region);
    let w = width as usize;
    for (y, block) in (y0..=y1).zip(samples.chunks_exact(ss * rw)) {
        downsample_row(block, rw, ss, &mut out.height_mm[y * w + x0..=y * w + x1]);
    }
}

/// Averages each `ss x ss` block of samples (`block` holds `ss` rows of `rw` samples) into the
/// pixel below it in `out`: the mean of its covered samples, or background when fewer than half
/// are covered. Compiled for AVX2 where the CPU has it (the same operations, more lanes).
fn downsample_row(block: &[f32], rw: usize, ss: usize, out: &mut [f32]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2, checked just above.
        return unsafe { downsample_row_avx2(block, rw, ss, out) };
    }
    downsample_row_body(block, rw, ss, out);
}

/// [`downsample_row_body`] compiled for AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn downsample_row_avx2(block: &[f32], rw: usize, ss: usize, out: &mut [f32]) {
    downsample_row_body(block, rw, ss, out);
}

#[inline(always)]
fn downsample_row_body(block: &[f32], rw: usize, ss: usize, out: &mut [f32]) {
    let need = (ss * ss).div_ceil(2);
    // Branch-free: an uncovered sample adds 0.0, which leaves the sum as it was (it starts at
    // +0.0 and so never becomes -0.0), and counts 0.
    let add = |sum: f64, n: usize, v: f32| {
        let hit = v > DepthMap::BACKGROUND_MM;
        (sum + if hit { v as f64 } else { 0.0 }, n + hit as usize)
    };
    let mean = |cell: f32, sum: f64, n: usize| if n >= need { (sum / n as f64) as f32 } else { cell };
    if ss == 2 {
        // The common case, unrolled so that the compiler vectorises across pixels.
        let (top, bottom) = block.split_at(rw);
        for ((cell, a), b) in out.iter_mut().zip(top.chunks_exact(2)).zip(bottom.chunks_exact(2)) {
            let (sum, n) = add(0.0, 0, a[0]);
            let (sum, n) = add(sum, n, a[1]);
            let (sum, n) = add(sum, n, b[0]);
            let (sum, n) = add(sum, n, b[1]);
            *cell = mean(*cell, sum, n);
        }
        return;
    }
    for (x, cell) in out.iter_mut().enumerate() {
        let (mut sum, mut n) = (0.0f64, 0usize);
        for dy in 0..ss {
            let start = dy * rw + x * ss;
            for &v in &block[start..start + ss] {
                (sum, n) = add(sum, n, v);
            }
        }
        *cell = mean(*cell, sum, n);
    }
}

/// The affine map from object-frame x/y (mm) to pixels for a pose and calibration (the pose's
/// x/y pass through [`Calibration::effective_offset_mm`] first). The scales are those at the
/// pose's press depth `z_mm` ([`Calibration::scale_at_depth`]): a calibration with a depth
/// term shows a deeper press larger about the sensor centre.
pub fn object_to_pixel(object_pose: &Pose, calib: &Calibration) -> DAffine2 {
    let (s, c) = calib.rotation_deg.to_radians().sin_cos();
    let [sx, sy] = calib.scale_at_depth(object_pose.z_mm);
    let rot_scale = DMat2::from_cols(DVec2::new(c, s), DVec2::new(-s, c)) * DMat2::from_diagonal(DVec2::new(sx, sy));
    DAffine2::from_translation(DVec2::from_array(calib.centre_px))
        * DAffine2::from_mat2(rot_scale)
        * DAffine2::from_angle(-object_pose.yaw_deg.to_radians())
        * DAffine2::from_translation(-DVec2::from(calib.effective_offset_mm(object_pose.x_mm, object_pose.y_mm)))
}

/// Projects the triangles that can cover a sample centre of a `width x height` image into
/// `out` (each shared vertex once, into `vertices`), and returns the bounding box of their
/// samples (`None` when none can).
fn project(
    mesh: &PreparedMesh,
    object_pose: &Pose,
    calib: &Calibration,
    width: usize,
    height: usize,
    vertices: &mut Vec<(DVec2, f64)>,
    out: &mut Vec<Projected>,
) -> Option<Region> {
    out.clear();
    let to_px = object_to_pixel(object_pose, calib);
    // Height of a vertex above the skin plane: the plane lies z_mm below the object's top.
    let plane_z = mesh.top_z_mm as f64 - object_pose.z_mm;
    vertices.clear();
    vertices.extend(mesh.vertices.iter().map(|v| (to_px.transform_point2(DVec2::new(v.x as f64, v.y as f64)), v.z as f64 - plane_z)));
    let mut covered = Region { i0: usize::MAX, i1: 0, j0: usize::MAX, j1: 0 };
    for tri in &mesh.triangles {
        // The indices were made by `PreparedMesh::new` from this vertex list.
        let p = tri.map(|i| vertices[i as usize]);
        let (a, b, c) = (p[0].0, p[1].0, p[2].0);
        let area = (b - a).perp_dot(c - a);
        // Walls seen edge-on and degenerate triangles cover no pixel centre reliably: skip.
        if !area.is_finite() || area.abs() < 1e-12 {
            continue;
        }
        let min = a.min(b).min(c);
        let max = a.max(b).max(c);
        // Pixel (i, j) is sampled at its centre (i + 0.5, j + 0.5).
        let i0 = ceil(min.x - 0.5).max(0.0);
        let j0 = ceil(min.y - 0.5).max(0.0);
        let i1 = floor(max.x - 0.5).min(width as f64 - 1.0);
        let j1 = floor(max.y - 0.5).min(height as f64 - 1.0);
        if i0 > i1 || j0 > j1 {
            continue;
        }
        let t = Projected {
            a,
            b,
            c,
            z: [p[0].1, p[1].1, p[2].1],
            inv_area: 1.0 / area,
            i0: i0 as usize,
            i1: i1 as usize,
            j0: j0 as usize,
            j1: j1 as usize,
        };
        covered = Region { i0: covered.i0.min(t.i0), i1: covered.i1.max(t.i1), j0: covered.j0.min(t.j0), j1: covered.j1.max(t.j1) };
        out.push(t);
    }
    (!out.is_empty()).then_some(covered)
}

/// `x.ceil()` without a libm call (x86-64's baseline has no rounding instruction); equal to it
/// for every finite `x` below 2^52 in magnitude, which is all the rasteriser asks (it clamps
/// the result to the image, and the casts saturate beyond that).
fn ceil(x: f64) -> f64 {
    let t = x as i64 as f64;
    if t < x { t + 1.0 } else { t }
}

/// `x.floor()`, as [`ceil`].
fn floor(x: f64) -> f64 {
    let t = x as i64 as f64;
    if t > x { t - 1.0 } else { t }
}

/// Z-buffers `triangles` into `buf`, which holds the samples of `region` row by row (every
/// triangle lies inside it). Two shortcuts keep it to the samples a triangle can change, and
/// neither changes a result (the z-buffer keeps each sample's maximum, whatever the order):
///
/// - a triangle whose highest possible interpolated height does not exceed any sample under its
///   bounding box is skipped (meshes sorted top down, [`PreparedMesh::sorted_top_down`], hide
///   most of their underside this way);
/// - each row visits only the span where the edge functions can pass, found from their values
///   at the row's ends and widened by two samples plus their rounding, and tests those samples
///   exactly as before.
///
/// On a CPU with AVX2 the samples of a row are tested four at a time ([`row_avx2`]), with the
/// same operations in the same order as the scalar test ([`row_scalar`]).
fn rasterise(triangles: &[Projected], buf: &mut [f32], region: Region) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2, checked just above.
        return unsafe { rasterise_avx2(triangles, buf, region) };
    }
    rasterise_body(triangles, buf, region, |edges, x0, buf, start, len| row_scalar(edges, x0, &mut buf[start..start + len]));
}

/// [`rasterise_body`] compiled for AVX2, with the four-lane row test.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn rasterise_avx2(triangles: &[Projected], buf: &mut [f32], region: Region) {
    // SAFETY (of the closure's call): this function runs only where AVX2 was detected.
    rasterise_body(triangles, buf, region, |edges, x0, buf, start, len| unsafe { row_avx2(edges, x0, buf, start, len) });
}

/// The edge test of one triangle along one sample row, in the form both row tests use:
/// barycentric weights from edge functions, normalised by the signed area so both windings
/// work, `w_a = (row_a - cb_y * (x - b_x)) * inv_area` (and `w_b` likewise about `c`), where
/// `row_a = cb_x * (py - b_y)`: `(c - b).perp_dot(q - b) * inv_area` term by term.
#[derive(Debug, Clone, Copy)]
struct RowEdges {
    row_a: f64,
    cb_y: f64,
    b_x: f64,
    row_b: f64,
    ac_y: f64,
    c_x: f64,
    inv_area: f64,
    z: [f64; 3],
}

impl RowEdges {
    fn new(t: &Projected, py: f64) -> Self {
        let (a, b, c) = (t.a, t.b, t.c);
        let (cb, ac) = (c - b, a - c);
        Self {
            row_a: cb.x * (py - b.y),
            cb_y: cb.y,
            b_x: b.x,
            row_b: ac.x * (py - c.y),
            ac_y: ac.y,
            c_x: c.x,
            inv_area: t.inv_area,
            z: t.z,
        }
    }

    /// The three weights at sample column `x` (its centre is `x + 0.5`).
    #[inline(always)]
    fn weights(&self, qx: f64) -> [f64; 3] {
        let wa = (self.row_a - self.cb_y * (qx - self.b_x)) * self.inv_area;
        let wb = (self.row_b - self.ac_y * (qx - self.c_x)) * self.inv_area;
        [wa, wb, 1.0 - wa - wb]
    }
}

/// Tolerance of the edge test: a sample on an edge, up to rounding, is inside.
const EDGE_EPS: f64 = -1e-9;

#[inline(always)]
fn rasterise_body(triangles: &[Projected], buf: &mut [f32], region: Region, row_test: impl Fn(&RowEdges, usize, &mut [f32], usize, usize)) {
    let stride = region.i1 - region.i0 + 1;
    for t in triangles {
        if hidden(t, buf, stride, region) {
            continue;
        }
        for j in t.j0..=t.j1 {
            let py = j as f64 + 0.5;
            let edges = RowEdges::new(t, py);
            let Some((lo, hi)) = row_span(t, |x| edges.weights(x)) else {
                continue;
            };
            let start = (j - region.j0) * stride;
            row_test(&edges, lo, buf, start + lo - region.i0, hi - lo + 1);
        }
    }
}

/// The edge and depth test of the samples `row` (columns `x0..`): each sample inside the
/// triangle takes the interpolated height when that is higher. Branch-free, so the compiler
/// can test two samples at a time; a NaN weight fails the test, as it did as
/// `w < EPS || ...` followed by `z > cell`.
#[inline(always)]
fn row_scalar(e: &RowEdges, x0: usize, row: &mut [f32]) {
    let [za, zb, zc] = e.z;
    for (k, cell) in row.iter_mut().enumerate() {
        let [wa, wb, wc] = e.weights((x0 + k) as f64 + 0.5);
        let inside = (wa >= EDGE_EPS) & (wb >= EDGE_EPS) & (wc >= EDGE_EPS);
        let z = (wa * za + wb * zb + wc * zc) as f32;
        *cell = if inside & (z > *cell) { z } else { *cell };
    }
}

/// [`row_scalar`] on the `len` samples of `buf` from `start` (columns `x0..`), four at a time:
/// the same operations on four lanes (no fused multiply-add, which would round differently).
/// A group of four that runs past the row reads the samples after it and writes them back
/// unchanged (its extra lanes never take a height); only at the end of `buf` are the extra
/// lanes masked off instead (masked stores are slow on some CPUs).
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn row_avx2(e: &RowEdges, x0: usize, buf: &mut [f32], start: usize, len: usize) {
    use std::arch::x86_64::*;
    assert!(start + len <= buf.len(), "row inside the buffer");
    let [za, zb, zc] = e.z.map(|z| _mm256_set1_pd(z));
    let (row_a, cb_y, b_x) = (_mm256_set1_pd(e.row_a), _mm256_set1_pd(e.cb_y), _mm256_set1_pd(e.b_x));
    let (row_b, ac_y, c_x) = (_mm256_set1_pd(e.row_b), _mm256_set1_pd(e.ac_y), _mm256_set1_pd(e.c_x));
    let (inv, one, eps, half) = (_mm256_set1_pd(e.inv_area), _mm256_set1_pd(1.0), _mm256_set1_pd(EDGE_EPS), _mm256_set1_pd(0.5));
    let lanes = _mm256_set_pd(3.0, 2.0, 1.0, 0.0);
    let lane_index = _mm_set_epi32(3, 2, 1, 0);
    for g in (0..len).step_by(4) {
        // (x0 + k) as f64 + 0.5 per lane: integers and halves well below 2^52 add exactly.
        let qx = _mm256_add_pd(_mm256_add_pd(_mm256_set1_pd((x0 + g) as f64), lanes), half);
        let wa = _mm256_mul_pd(_mm256_sub_pd(row_a, _mm256_mul_pd(cb_y, _mm256_sub_pd(qx, b_x))), inv);
        let wb = _mm256_mul_pd(_mm256_sub_pd(row_b, _mm256_mul_pd(ac_y, _mm256_sub_pd(qx, c_x))), inv);
        let wc = _mm256_sub_pd(_mm256_sub_pd(one, wa), wb);
        let inside = _mm256_and_pd(
            _mm256_and_pd(_mm256_cmp_pd::<_CMP_GE_OQ>(wa, eps), _mm256_cmp_pd::<_CMP_GE_OQ>(wb, eps)),
            _mm256_cmp_pd::<_CMP_GE_OQ>(wc, eps),
        );
        let z = _mm256_cvtpd_ps(_mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(wa, za), _mm256_mul_pd(wb, zb)), _mm256_mul_pd(wc, zc)));
        // The 64-bit lane masks as 32-bit ones: the low half of each.
        let (lo, hi) = (_mm256_castpd256_pd128(inside), _mm256_extractf128_pd::<1>(inside));
        let inside = _mm_shuffle_ps::<0b10_00_10_00>(_mm_castpd_ps(lo), _mm_castpd_ps(hi));
        let in_row = _mm_castsi128_ps(_mm_cmplt_epi32(lane_index, _mm_set1_epi32((len - g) as i32)));
        // A lane that may not draw offers -inf; `max(offer, cell)` is `offer > cell ? offer :
        // cell` (MAXPS returns its second operand when either is NaN), the scalar test's choice.
        let offer = _mm_blendv_ps(_mm_set1_ps(f32::NEG_INFINITY), z, _mm_and_ps(inside, in_row));
        let at = start + g;
        if at + 4 <= buf.len() {
            // SAFETY: the four f32s from `at` lie inside `buf`, checked just above.
            let old = unsafe { _mm_loadu_ps(buf.as_ptr().add(at)) };
            // SAFETY: as the load; lanes that do not take a height are written back as read.
            unsafe { _mm_storeu_ps(buf.as_mut_ptr().add(at), _mm_max_ps(offer, old)) };
        } else {
            let valid = _mm_castps_si128(in_row);
            // SAFETY: the mask selects the lanes of the row, which lie inside `buf` (asserted).
            let old = unsafe { _mm_maskload_ps(buf.as_ptr().add(at), valid) };
            // SAFETY: as the load; only lanes of the row are written.
            unsafe { _mm_maskstore_ps(buf.as_mut_ptr().add(at), valid, _mm_max_ps(offer, old)) };
        }
    }
}

/// True when no sample under `t`'s bounding box can rise: each already holds at least the
/// highest height the triangle can interpolate (its top vertex, plus the weights' tolerance and
/// rounding), so the exact test would reject every sample. The samples are compared with the
/// least `f32` at or above that bar, which for an `f32` sample is the same test as comparing
/// it, widened, with the bar itself.
fn hidden(t: &Projected, buf: &[f32], stride: usize, region: Region) -> bool {
    let [za, zb, zc] = t.z;
    let (top, bottom) = (za.max(zb).max(zc), za.min(zb).min(zc));
    let bar = top + 1e-6 * (1.0 + top.abs() + (top - bottom));
    if !bar.is_finite() {
        return false;
    }
    let narrow = bar as f32;
    let bar32 = if (narrow as f64) < bar { narrow.next_up() } else { narrow };
    (t.j0..=t.j1).all(|j| {
        let start = (j - region.j0) * stride + (t.i0 - region.i0);
        // No early exit within a row: the compiler compares eight samples at a time.
        buf[start..start + (t.i1 - t.i0 + 1)].iter().fold(true, |all, &v| all & (v >= bar32))
    })
}

/// The samples of row `py` inside `t`'s bounding box that can pass the edge test: each weight
/// is linear along the row, so its crossing of the tolerance is found from its values at the
/// box's two ends, then widened by two samples and its rounding (a weight that barely changes
/// along the row narrows nothing). `None` when no sample can pass.
fn row_span(t: &Projected, weights: impl Fn(f64) -> [f64; 3]) -> Option<(usize, usize)> {
    // A narrow box is cheaper to test whole than to narrow.
    if t.i1 - t.i0 < 8 {
        return Some((t.i0, t.i1));
    }
    let n = (t.i1 - t.i0) as f64;
    let (first, last) = (weights(t.i0 as f64 + 0.5), weights(t.i1 as f64 + 0.5));
    let (mut lo, mut hi) = (0.0f64, n);
    for (v0, v1) in first.into_iter().zip(last) {
        let per_sample = (v1 - v0) / n;
        let slack = 2.0 + 1e-12 * (1.0 + v0.abs() + v1.abs()) / per_sample.abs();
        if !slack.is_finite() || slack > n {
            continue;
        }
        let crossing = (EDGE_EPS - v0) / per_sample;
        if per_sample > 0.0 {
            lo = lo.max(crossing - slack);
        } else {
            hi = hi.min(crossing + slack);
        }
    }
    let (lo, hi) = (ceil(lo.max(0.0)), floor(hi.min(n)));
    (lo <= hi).then(|| (t.i0 + lo as usize, t.i0 + hi as usize))
}

/// The straightforward renderer [`render_depth`] replaced: a fresh full-size sample buffer per
/// call, every triangle's whole bounding box tested sample by sample, every sample averaged. It
/// is the tests' oracle (the results are equal bit for bit) and `rig bench`'s "previous code".
#[doc(hidden)]
pub fn render_depth_reference(mesh: &Mesh, object_pose: &Pose, calib: &Calibration, width: u32, height: u32, supersample: u32) -> DepthMap {
    if width == 0 || height == 0 || !object_pose.is_finite() {
        return DepthMap::empty(width, height);
    }
    // Keep the supersampled buffer bounded (MAX_SAMPLES f32s) whatever size is asked for.
    let mut ss = supersample.clamp(1, MAX_SUPERSAMPLE);
    while ss > 1 && (width as u64 * ss as u64) * (height as u64 * ss as u64) > MAX_SAMPLES {
        ss -= 1;
    }
    let (sw, sh) = (width * ss, height * ss);
    let fine = rasterise_reference(mesh, object_pose, &calib.scaled_to(sw, sh), sw, sh);
    if ss == 1 {
        return fine;
    }
    downsample_reference(&fine, width, height, ss)
}

fn rasterise_reference(mesh: &Mesh, object_pose: &Pose, calib: &Calibration, width: u32, height: u32) -> DepthMap {
    let mut map = DepthMap::empty(width, height);
    let to_px = object_to_pixel(object_pose, calib);
    // Height of a vertex above the skin plane: the plane lies z_mm below the object's top.
    let plane_z = mesh.top_z_mm() as f64 - object_pose.z_mm;
    let (w, h) = (width as usize, height as usize);
    for tri in &mesh.triangles {
        // Walls (normal nearly horizontal) project to slivers whose interpolated heights are
        // ill-conditioned; the faces around them already cover those pixels.
        let n = (tri[1] - tri[0]).cross(tri[2] - tri[0]);
        if n.z.abs() <= 1e-4 * n.length() {
            continue;
        }
        let p = tri.map(|v| {
            let uv = to_px.transform_point2(DVec2::new(v.x as f64, v.y as f64));
            (uv, v.z as f64 - plane_z)
        });
        let (a, b, c) = (p[0].0, p[1].0, p[2].0);
        let area = (b - a).perp_dot(c - a);
        // Walls seen edge-on and degenerate triangles cover no pixel centre reliably: skip.
        if !area.is_finite() || area.abs() < 1e-12 {
            continue;
        }
        let min = a.min(b).min(c);
        let max = a.max(b).max(c);
        // Pixel (i, j) is sampled at its centre (i + 0.5, j + 0.5).
        let i0 = (min.x - 0.5).ceil().max(0.0);
        let j0 = (min.y - 0.5).ceil().max(0.0);
        let i1 = (max.x - 0.5).floor().min(w as f64 - 1.0);
        let j1 = (max.y - 0.5).floor().min(h as f64 - 1.0);
        if i0 > i1 || j0 > j1 {
            continue;
        }
        let inv_area = 1.0 / area;
        let (za, zb, zc) = (p[0].1, p[1].1, p[2].1);
        for j in j0 as usize..=j1 as usize {
            let py = j as f64 + 0.5;
            let row = &mut map.height_mm[j * w..(j + 1) * w];
            for (i, cell) in row.iter_mut().enumerate().take(i1 as usize + 1).skip(i0 as usize) {
                let q = DVec2::new(i as f64 + 0.5, py);
                // Barycentric weights from edge functions, normalised by the signed area so
                // both windings work.
                let wa = (c - b).perp_dot(q - b) * inv_area;
                let wb = (a - c).perp_dot(q - c) * inv_area;
                let wc = 1.0 - wa - wb;
                const EPS: f64 = -1e-9;
                if wa < EPS || wb < EPS || wc < EPS {
                    continue;
                }
                let z = (wa * za + wb * zb + wc * zc) as f32;
                if z > *cell {
                    *cell = z;
                }
            }
        }
    }
    map
}

fn downsample_reference(fine: &DepthMap, width: u32, height: u32, ss: u32) -> DepthMap {
    let mut out = DepthMap::empty(width, height);
    let fw = fine.width as usize;
    let ss = ss as usize;
    let need = (ss * ss).div_ceil(2);
    for y in 0..height as usize {
        for x in 0..width as usize {
            let (mut sum, mut n) = (0.0f64, 0usize);
            for dy in 0..ss {
                let row = (y * ss + dy) * fw;
                for dx in 0..ss {
                    let v = fine.height_mm[row + x * ss + dx];
                    if v > DepthMap::BACKGROUND_MM {
                        sum += v as f64;
                        n += 1;
                    }
                }
            }
            if n >= need {
                out.height_mm[y * width as usize + x] = (sum / n as f64) as f32;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::shapes::box_mesh;
    use glam::Vec3;

    #[test]
    fn flat_top_box_has_indentation_height_and_footprint() {
        // 4 x 2 mm top face, 10 px/mm: 40 x 20 px at the centre.
        let mesh = box_mesh(Vec3::new(-2.0, -1.0, 0.0), Vec3::new(2.0, 1.0, 5.0));
        let calib = Calibration { scale_px_per_mm: [10.0, 10.0], ..Calibration::default_for(100, 100) };
        let d = render_depth(&mesh, &Pose::new(0.0, 0.0, 1.5, 0.0), &calib, 100, 100, 1);
        let covered = d.height_mm.iter().filter(|&&v| v > DepthMap::BACKGROUND_MM).count();
        assert_eq!(covered, 40 * 20);
        assert!((d.get(50, 50).unwrap() - 1.5).abs() < 1e-5);
        assert_eq!(d.get(50, 35), Some(DepthMap::BACKGROUND_MM));
    }

    #[test]
    fn yaw_90_turns_the_footprint() {
        let mesh = box_mesh(Vec3::new(-2.0, -1.0, 0.0), Vec3::new(2.0, 1.0, 5.0));
        let calib = Calibration { scale_px_per_mm: [10.0, 10.0], ..Calibration::default_for(100, 100) };
        let d = render_depth(&mesh, &Pose::new(0.0, 0.0, 1.0, 90.0), &calib, 100, 100, 1);
        // Long side now along the rows.
        assert!(d.get(50, 30).unwrap() > 0.0 && d.get(30, 50) == Some(DepthMap::BACKGROUND_MM));
    }

    #[test]
    fn non_finite_pose_renders_nothing_and_huge_supersampling_is_bounded() {
        let mesh = box_mesh(Vec3::new(-2.0, -1.0, 0.0), Vec3::new(2.0, 1.0, 5.0));
        let calib = Calibration::default_for(64, 64);
        let d = render_depth(&mesh, &Pose::new(f64::NAN, 0.0, 1.0, 0.0), &calib, 64, 64, 1);
        assert_eq!(d, DepthMap::empty(64, 64));
        // 4096^2 at 8x8 would be 1 G samples; it renders at a lower factor instead.
        let big = render_depth(&mesh, &Pose::new(0.0, 0.0, 1.0, 0.0), &Calibration::default_for(4096, 4096), 4096, 4096, 8);
        assert!((big.max_indentation_mm() - 1.0).abs() < 1e-4);
    }

    #[test]
    fn a_depth_term_renders_a_deeper_press_larger_by_its_factor() {
        // 4 x 2 mm top face at 10 px/mm and +5 % per mm: 1.1 x larger at 2 mm than at 0 mm
        // (44 x 22 px), 1.2 x at 4 mm (48 x 24 px); without the term both are 40 x 20 px.
        let mesh = box_mesh(Vec3::new(-2.0, -1.0, 0.0), Vec3::new(2.0, 1.0, 5.0));
        let flat = Calibration { scale_px_per_mm: [10.0, 10.0], ..Calibration::default_for(100, 100) };
        let deep = Calibration { depth_scale_per_mm: 0.05, ..flat.clone() };
        let covered = |calib: &Calibration, z_mm: f64| {
            let d = render_depth(&mesh, &Pose::new(0.0, 0.0, z_mm, 0.0), calib, 100, 100, 1);
            d.height_mm.iter().filter(|&&v| v > DepthMap::BACKGROUND_MM).count()
        };
        assert_eq!(covered(&flat, 2.0), 40 * 20);
        assert_eq!(covered(&flat, 4.0), 40 * 20);
        assert_eq!(covered(&deep, 2.0), 44 * 22);
        assert_eq!(covered(&deep, 4.0), 48 * 24);
        // An offset object moves away from the centre by the same factor: 1 mm -> 11 px.
        let shifted = render_depth(&mesh, &Pose::new(-1.0, 0.0, 2.0, 0.0), &deep, 100, 100, 1);
        let cols: Vec<u32> = (0..100u32).filter(|&x| shifted.get(x, 50).is_some_and(|v| v > DepthMap::BACKGROUND_MM)).collect();
        let mid = (cols[0] + cols[cols.len() - 1] + 1) as f64 / 2.0;
        assert!((mid - (50.0 + 11.0)).abs() < 0.51, "{mid}");
    }

    #[test]
    fn supersampling_keeps_heights() {
        let mesh = box_mesh(Vec3::new(-2.0, -1.0, 0.0), Vec3::new(2.0, 1.0, 5.0));
        let calib = Calibration::default_for(64, 64);
        let d = render_depth(&mesh, &Pose::new(0.3, 0.1, 0.7, 10.0), &calib, 64, 64, 4);
        assert!((d.max_indentation_mm() - 0.7).abs() < 1e-4);
    }

    /// The library objects at poses across the workspace, sizes and supersampling factors,
    /// through one reused scratch and a mesh sorted top down: equal to the straightforward
    /// renderer bit for bit.
    #[test]
    fn library_objects_render_exactly_as_the_reference_renderer() {
        let mut scratch = RasterScratch::default();
        let mut out = DepthMap::empty(0, 0);
        for name in crate::geometry::shapes::OBJECT_NAMES {
            let mesh = crate::geometry::shapes::object_mesh(name).expect("library object");
            let prepared = PreparedMesh::for_many_renders(&mesh);
            for (k, (w, h, ss)) in [(96u32, 80u32, 1u32), (64, 64, 2), (50, 70, 3)].into_iter().enumerate() {
                let calib = Calibration::default_for(w, h);
                for pose in [Pose::new(0.0, 0.0, 1.0, 0.0), Pose::new(-3.5, 2.0, 2.5, 37.0 + k as f64), Pose::new(9.0, -1.0, -0.5, -120.0)]
                {
                    render_depth_into(&prepared, &pose, &calib, w, h, ss, &mut scratch, &mut out);
                    assert_eq!(out, render_depth_reference(&mesh, &pose, &calib, w, h, ss), "{name} {w}x{h} ss {ss} {pose:?}");
                }
            }
        }
    }

    /// A prepared mesh stores each shared vertex once and keeps every triangle's corners.
    #[test]
    fn prepared_mesh_shares_vertices() {
        let mesh = crate::geometry::shapes::object_mesh("sphere").expect("library object");
        let prepared = PreparedMesh::for_many_renders(&mesh);
        // A closed mesh has about half as many vertices as triangles (not three per triangle).
        assert!(prepared.vertices.len() * 5 < prepared.triangles.len() * 3, "{} vertices", prepared.vertices.len());
        let kept: Vec<[Vec3; 3]> = prepared.triangles.iter().map(|t| t.map(|i| prepared.vertices[i as usize])).collect();
        let walls = mesh.triangles.len() - kept.len();
        assert!(kept.iter().all(|t| mesh.triangles.contains(t)) && walls < mesh.triangles.len() / 100, "{walls} walls");
    }

    /// Samples compared with the `f32` bar pass exactly when, widened, they reach the `f64` bar.
    #[test]
    fn the_hidden_test_bar_in_f32_is_the_f64_test() {
        let t = |z: [f64; 3]| Projected { a: DVec2::ZERO, b: DVec2::X, c: DVec2::Y, z, inv_area: 1.0, i0: 0, i1: 0, j0: 0, j1: 0 };
        let region = Region { i0: 0, i1: 0, j0: 0, j1: 0 };
        for z in [[0.1f64, 0.2, 0.3], [1.0 / 3.0, 0.0, -2.0], [-5e-7, -1e-3, -0.5], [1e30, 0.0, 0.0], [0.0; 3]] {
            let top = z[0].max(z[1]).max(z[2]);
            let bar = top + 1e-6 * (1.0 + top.abs() + (top - z[0].min(z[1]).min(z[2])));
            let near = bar as f32;
            for v in [near.next_down(), near, near.next_up(), f32::NAN, f32::INFINITY, DepthMap::BACKGROUND_MM] {
                assert_eq!(hidden(&t(z), &[v], 1, region), v as f64 >= bar, "{z:?} {v}");
            }
        }
    }

    /// Triangles through the scalar row test and through the AVX2 one (where the CPU has it)
    /// leave the same samples, including rows that end at the buffer's last sample.
    #[test]
    fn the_avx2_row_test_equals_the_scalar_one() {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            let mut seed = 0x9e37_79b9_u64;
            let mut next = || {
                seed = crate::sim::sensor::stages::mix64(seed);
                (seed >> 11) as f64 / (1u64 << 53) as f64
            };
            for _ in 0..200 {
                let (w, h) = (1 + (next() * 40.0) as usize, 1 + (next() * 30.0) as usize);
                let mut triangles = Vec::new();
                for _ in 0..12 {
                    let mut p = || DVec2::new(next() * (w as f64 + 4.0) - 2.0, next() * (h as f64 + 4.0) - 2.0);
                    let (a, b, c) = (p(), p(), p());
                    let area = (b - a).perp_dot(c - a);
                    let (min, max) = (a.min(b).min(c), a.max(b).max(c));
                    let (i0, j0) = (ceil(min.x - 0.5).max(0.0), ceil(min.y - 0.5).max(0.0));
                    let (i1, j1) = (floor(max.x - 0.5).min(w as f64 - 1.0), floor(max.y - 0.5).min(h as f64 - 1.0));
                    if area.abs() < 1e-12 || i0 > i1 || j0 > j1 {
                        continue;
                    }
                    let z = [next() * 4.0 - 2.0, next() * 4.0 - 2.0, next() * 4.0 - 2.0];
                    let (i0, i1, j0, j1) = (i0 as usize, i1 as usize, j0 as usize, j1 as usize);
                    triangles.push(Projected { a, b, c, z, inv_area: 1.0 / area, i0, i1, j0, j1 });
                }
                let region = Region { i0: 0, i1: w - 1, j0: 0, j1: h - 1 };
                let mut scalar = vec![DepthMap::BACKGROUND_MM; w * h];
                rasterise_body(&triangles, &mut scalar, region, |e, x0, buf, start, len| row_scalar(e, x0, &mut buf[start..start + len]));
                let mut wide = vec![DepthMap::BACKGROUND_MM; w * h];
                rasterise(&triangles, &mut wide, region);
                assert_eq!(wide, scalar, "{w}x{h}");
            }
        }
    }

    /// The downsampling of 2 x 2 blocks (unrolled) and of other factors, compiled either way,
    /// equals the straightforward average of the covered samples.
    #[test]
    fn downsampling_equals_the_straightforward_average() {
        let mut seed = 7u64;
        for ss in 1..4usize {
            let (w, rw) = (9, 9 * ss);
            let block: Vec<f32> = (0..ss * rw)
                .map(|_| {
                    seed = crate::sim::sensor::stages::mix64(seed);
                    if seed.is_multiple_of(3) { DepthMap::BACKGROUND_MM } else { (seed % 1000) as f32 / 7.0 - 60.0 }
                })
                .collect();
            let expected: Vec<f32> = (0..w)
                .map(|x| {
                    let hits: Vec<f32> =
                        (0..ss * ss).map(|k| block[(k / ss) * rw + x * ss + k % ss]).filter(|&v| v > DepthMap::BACKGROUND_MM).collect();
                    if hits.len() >= (ss * ss).div_ceil(2) {
                        (hits.iter().map(|&v| v as f64).sum::<f64>() / hits.len() as f64) as f32
                    } else {
                        -1.0
                    }
                })
                .collect();
            let (mut fast, mut plain) = (vec![-1.0f32; w], vec![-1.0f32; w]);
            downsample_row(&block, rw, ss, &mut fast);
            downsample_row_body(&block, rw, ss, &mut plain);
            assert_eq!(fast, expected, "ss {ss}");
            assert_eq!(plain, expected, "ss {ss}");
        }
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(64))]
        /// Random triangle soups (slivers, both windings, overlaps, triangles off the image)
        /// render exactly as the straightforward renderer does.
        #[test]
        fn random_meshes_render_exactly_as_the_reference_renderer(
            coords in proptest::collection::vec(-12.0f32..12.0, 9..180),
            pose in (-4.0f64..4.0, -4.0f64..4.0, -2.0f64..3.0, -180.0f64..180.0),
            size in (1u32..70, 1u32..70),
            ss in 1u32..4,
        ) {
            let triangles: Vec<[Vec3; 3]> = coords
                .chunks_exact(9)
                .map(|c| [Vec3::new(c[0], c[1], c[2] * 0.3), Vec3::new(c[3], c[4], c[5] * 0.3), Vec3::new(c[6], c[7], c[8] * 0.3)])
                .collect();
            let mesh = Mesh::new(triangles);
            let pose = Pose::new(pose.0, pose.1, pose.2, pose.3);
            let calib = Calibration::default_for(size.0, size.1);
            let expected = render_depth_reference(&mesh, &pose, &calib, size.0, size.1, ss);
            proptest::prop_assert_eq!(&render_depth(&mesh, &pose, &calib, size.0, size.1, ss), &expected);
            let mut out = DepthMap::empty(3, 3);
            render_depth_into(&PreparedMesh::for_many_renders(&mesh), &pose, &calib, size.0, size.1, ss, &mut RasterScratch::default(), &mut out);
            proptest::prop_assert_eq!(&out, &expected);
        }
    }
}
