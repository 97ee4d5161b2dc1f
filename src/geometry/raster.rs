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
    if width == 0 || height == 0 || !object_pose.is_finite() {
        return DepthMap::empty(width, height);
    }
    // Keep the supersampled buffer bounded (MAX_SAMPLES f32s) whatever size is asked for.
    let mut ss = supersample.clamp(1, MAX_SUPERSAMPLE);
    while ss > 1 && (width as u64 * ss as u64) * (height as u64 * ss as u64) > MAX_SAMPLES {
        ss -= 1;
    }
    let (sw, sh) = (width * ss, height * ss);
    let fine = rasterise(mesh, object_pose, &calib.scaled_to(sw, sh), sw, sh);
    if ss == 1 {
        return fine;
    }
    downsample(&fine, width, height, ss)
}

/// [`render_depth`] with the size and supersampling in one value.
pub fn render_depth_with(mesh: &Mesh, object_pose: &Pose, calib: &Calibration, opts: &RasterOptions) -> DepthMap {
    render_depth(mesh, object_pose, calib, opts.width, opts.height, opts.supersample)
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

fn rasterise(mesh: &Mesh, object_pose: &Pose, calib: &Calibration, width: u32, height: u32) -> DepthMap {
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

fn downsample(fine: &DepthMap, width: u32, height: u32, ss: u32) -> DepthMap {
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
}
