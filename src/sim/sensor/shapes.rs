//! Simple analytic depth maps for tests, benchmarks and look-matching, in the sensor frame:
//! the image centre is the sensor axis, x right and y down, `px_per_mm` pixels per mm.
//! (Real collections get their depth maps from `geometry`'s rasteriser.)

use crate::geometry::DepthMap;

/// A straight edge: the half-plane on one side of a line is an object surface pressed
/// `indent_mm` into the skin, the other side is background. The line passes `offset_mm` from
/// the centre along its normal, which points at `angle_deg` (image frame) into the object.
pub fn straight_edge(width: u32, height: u32, px_per_mm: f32, offset_mm: f32, angle_deg: f32, indent_mm: f32) -> DepthMap {
    let (s, c) = angle_deg.to_radians().sin_cos();
    fill(width, height, px_per_mm, |x_mm, y_mm| if x_mm * c + y_mm * s >= offset_mm { Some(indent_mm) } else { None })
}

/// A flat-topped bar (the MultiDiffSense object 1 seen from above): `length_mm` x `width_mm`,
/// centred at (`x_mm`, `y_mm`), long axis at `angle_deg`, pressed `indent_mm` into the skin.
#[allow(clippy::too_many_arguments)]
pub fn bar(
    width: u32,
    height: u32,
    px_per_mm: f32,
    x_mm: f32,
    y_mm: f32,
    angle_deg: f32,
    length_mm: f32,
    width_mm: f32,
    indent_mm: f32,
) -> DepthMap {
    let (s, c) = angle_deg.to_radians().sin_cos();
    fill(width, height, px_per_mm, |px, py| {
        let (dx, dy) = (px - x_mm, py - y_mm);
        let (u, v) = (dx * c + dy * s, -dx * s + dy * c);
        (u.abs() <= length_mm / 2.0 && v.abs() <= width_mm / 2.0).then_some(indent_mm)
    })
}

/// A sphere of `radius_mm` centred over (`x_mm`, `y_mm`) pressed `indent_mm` into the skin:
/// height `indent_mm - (R - sqrt(R^2 - r^2))` inside its silhouette.
pub fn sphere(width: u32, height: u32, px_per_mm: f32, x_mm: f32, y_mm: f32, radius_mm: f32, indent_mm: f32) -> DepthMap {
    fill(width, height, px_per_mm, |px, py| {
        let r2 = (px - x_mm).powi(2) + (py - y_mm).powi(2);
        (r2 < radius_mm * radius_mm).then(|| indent_mm - (radius_mm - (radius_mm * radius_mm - r2).sqrt()))
    })
}

fn fill(width: u32, height: u32, px_per_mm: f32, f: impl Fn(f32, f32) -> Option<f32>) -> DepthMap {
    let mut d = DepthMap::empty(width, height);
    let (cx, cy) = (width as f32 / 2.0, height as f32 / 2.0);
    for y in 0..height {
        for x in 0..width {
            let x_mm = (x as f32 + 0.5 - cx) / px_per_mm;
            let y_mm = (y as f32 + 0.5 - cy) / px_per_mm;
            if let Some(v) = f(x_mm, y_mm) {
                d.height_mm[(y * width + x) as usize] = v;
            }
        }
    }
    d
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shapes_cover_what_they_should() {
        let e = straight_edge(100, 100, 10.0, 1.0, 0.0, 0.5);
        assert_eq!(e.get(99, 50), Some(0.5));
        assert_eq!(e.get(50, 50), Some(DepthMap::BACKGROUND_MM));
        let s = sphere(100, 100, 10.0, 0.0, 0.0, 3.0, 1.0);
        assert!((s.max_indentation_mm() - 1.0).abs() < 0.01);
        assert_eq!(s.get(0, 0), Some(DepthMap::BACKGROUND_MM));
        let b = bar(100, 100, 10.0, 0.0, 0.0, 90.0, 8.0, 2.0, 0.7);
        assert_eq!(b.get(50, 85), Some(0.7));
        assert_eq!(b.get(85, 50), Some(DepthMap::BACKGROUND_MM));
    }
}
