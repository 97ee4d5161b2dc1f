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

/// A mesh ready to be rendered many times: the triangles that can show from above (walls,
/// whose normal is nearly horizontal, project to slivers whose interpolated heights are
/// ill-conditioned; the faces around them already cover those pixels) and the mesh's top.
#[derive(Debug, Clone)]
pub struct PreparedMesh {
    triangles: Vec<[glam::Vec3; 3]>,
    top_z_mm: f32,
}

impl PreparedMesh {
    /// `mesh` without its walls, in its own order.
    pub fn new(mesh: &Mesh) -> Self {
        let triangles = mesh
            .triangles
            .iter()
            .filter(|tri| {
                let n = (tri[1] - tri[0]).cross(tri[2] - tri[0]);
                n.z.abs() > 1e-4 * n.length()
            })
            .copied()
            .collect();
        Self { triangles, top_z_mm: mesh.top_z_mm() }
    }

    /// Orders the triangles by their highest vertex, top first. The result of a render does not
    /// depend on the order, but the rasteriser skips a triangle that lies under what it has
    /// already drawn, so a mesh drawn many times is worth sorting once.
    pub fn sorted_top_down(mut self) -> Self {
        let top = |t: &[glam::Vec3; 3]| t[0].z.max(t[1].z).max(t[2].z);
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
    let Some(covered) = project(mesh, object_pose, &calib.scaled_to(sw, sh), sw as usize, sh as usize, &mut scratch.triangles) else {
        return;
    };
    if ss == 1 {
        let all = Region { i0: 0, i1: width as usize - 1, j0: 0, j1: height as usize - 1 };
        rasterise(&scratch.triangles, &mut out.height_mm, all);
        return;
    }
    // The covered samples, widened to whole output pixels.
    let ss = ss as usize;
    let (x0, x1, y0, y1) = (covered.i0 / ss, covered.i1 / ss, covered.j0 / ss, covered.j1 / ss);
    let region = Region { i0: x0 * ss, i1: (x1 + 1) * ss - 1, j0: y0 * ss, j1: (y1 + 1) * ss - 1 };
    let (rw, rh) = (region.i1 - region.i0 + 1, region.j1 - region.j0 + 1);
    scratch.samples.clear();
    scratch.samples.resize(rw * rh, DepthMap::BACKGROUND_MM);
    rasterise(&scratch.triangles, &mut scratch.samples, region);
    let need = (ss * ss).div_ceil(2);
    let w = width as usize;
    for y in y0..=y1 {
        let row = &mut out.height_mm[y * w..(y + 1) * w];
        for (x, cell) in row.iter_mut().enumerate().take(x1 + 1).skip(x0) {
            let (mut sum, mut n) = (0.0f64, 0usize);
            for dy in 0..ss {
                let start = ((y - y0) * ss + dy) * rw + (x - x0) * ss;
                for &v in &scratch.samples[start..start + ss] {
                    if v > DepthMap::BACKGROUND_MM {
                        sum += v as f64;
                        n += 1;
                    }
                }
            }
            if n >= need {
                *cell = (sum / n as f64) as f32;
            }
        }
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
/// `out`, and returns the bounding box of their samples (`None` when none can).
fn project(
    mesh: &PreparedMesh,
    object_pose: &Pose,
    calib: &Calibration,
    width: usize,
    height: usize,
    out: &mut Vec<Projected>,
) -> Option<Region> {
    out.clear();
    let to_px = object_to_pixel(object_pose, calib);
    // Height of a vertex above the skin plane: the plane lies z_mm below the object's top.
    let plane_z = mesh.top_z_mm as f64 - object_pose.z_mm;
    let mut covered = Region { i0: usize::MAX, i1: 0, j0: usize::MAX, j1: 0 };
    for tri in &mesh.triangles {
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
///   bounding box is skipped (meshes sorted top down, [`Mesh::sort_top_down`], hide most of
///   their underside this way);
/// - each row visits only the span where the edge functions can pass, found from their values
///   at the row's ends and widened by two samples plus their rounding, and tests those samples
///   exactly as before.
fn rasterise(triangles: &[Projected], buf: &mut [f32], region: Region) {
    let stride = region.i1 - region.i0 + 1;
    const EPS: f64 = -1e-9;
    for t in triangles {
        let (a, b, c) = (t.a, t.b, t.c);
        let [za, zb, zc] = t.z;
        if hidden(t, buf, stride, region) {
            continue;
        }
        // Barycentric weights from edge functions, normalised by the signed area so both
        // windings work.
        let weights = |x: f64, py: f64| {
            let q = DVec2::new(x, py);
            let wa = (c - b).perp_dot(q - b) * t.inv_area;
            let wb = (a - c).perp_dot(q - c) * t.inv_area;
            [wa, wb, 1.0 - wa - wb]
        };
        for j in t.j0..=t.j1 {
            let py = j as f64 + 0.5;
            let Some((lo, hi)) = row_span(t, py, weights) else {
                continue;
            };
            let start = (j - region.j0) * stride;
            let row = &mut buf[start + lo - region.i0..=start + hi - region.i0];
            // Branch-free, so the compiler can test two samples at a time; a NaN weight fails
            // the test, as it did as `w < EPS || ...` followed by `z > cell`.
            for (k, cell) in row.iter_mut().enumerate() {
                let [wa, wb, wc] = weights((lo + k) as f64 + 0.5, py);
                let inside = (wa >= EPS) & (wb >= EPS) & (wc >= EPS);
                let z = (wa * za + wb * zb + wc * zc) as f32;
                *cell = if inside & (z > *cell) { z } else { *cell };
            }
        }
    }
}

/// True when no sample under `t`'s bounding box can rise: each already holds at least the
/// highest height the triangle can interpolate (its top vertex, plus the weights' tolerance and
/// rounding), so the exact test would reject every sample.
fn hidden(t: &Projected, buf: &[f32], stride: usize, region: Region) -> bool {
    let [za, zb, zc] = t.z;
    let (top, bottom) = (za.max(zb).max(zc), za.min(zb).min(zc));
    let bar = top + 1e-6 * (1.0 + top.abs() + (top - bottom));
    if !bar.is_finite() {
        return false;
    }
    (t.j0..=t.j1).all(|j| {
        let start = (j - region.j0) * stride + (t.i0 - region.i0);
        buf[start..start + (t.i1 - t.i0 + 1)].iter().all(|&v| v as f64 >= bar)
    })
}

/// The samples of row `py` inside `t`'s bounding box that can pass the edge test: each weight
/// is linear along the row, so its crossing of the tolerance is found from its values at the
/// box's two ends, then widened by two samples and its rounding (a weight that barely changes
/// along the row narrows nothing). `None` when no sample can pass.
fn row_span(t: &Projected, py: f64, weights: impl Fn(f64, f64) -> [f64; 3]) -> Option<(usize, usize)> {
    const EPS: f64 = -1e-9;
    // A narrow box is cheaper to test whole than to narrow.
    if t.i1 - t.i0 < 8 {
        return Some((t.i0, t.i1));
    }
    let n = (t.i1 - t.i0) as f64;
    let (first, last) = (weights(t.i0 as f64 + 0.5, py), weights(t.i1 as f64 + 0.5, py));
    let (mut lo, mut hi) = (0.0f64, n);
    for (v0, v1) in first.into_iter().zip(last) {
        let per_sample = (v1 - v0) / n;
        let slack = 2.0 + 1e-12 * (1.0 + v0.abs() + v1.abs()) / per_sample.abs();
        if !slack.is_finite() || slack > n {
            continue;
        }
        let crossing = (EPS - v0) / per_sample;
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
            let prepared = PreparedMesh::new(&mesh).sorted_top_down();
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
            render_depth_into(&PreparedMesh::new(&mesh).sorted_top_down(), &pose, &calib, size.0, size.1, ss, &mut RasterScratch::default(), &mut out);
            proptest::prop_assert_eq!(&out, &expected);
        }
    }
}
