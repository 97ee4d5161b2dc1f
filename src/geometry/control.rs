//! The control image (MultiDiffSense's ControlNet hint) and the plain 16-bit depth PNG.
//!
//! MultiDiffSense conditions on the object's depth map rendered from the STL, inverted (near
//! is high), colour-mapped with viridis and scaled to [0, 1]. Our [`DepthMap`] already holds
//! heights (near the sensor = large), so the inversion is the identity here:
//!
//! ```text
//! t = (h - h_min) / (h_max - h_min)   over the pixels the object covers (t = 1 if flat)
//! t = 0                               where no object is (the far background)
//! rgb = viridis(t)                    as RGB8; divide by 255 for the [0, 1] hint tensor
//! ```
//!
//! The 16-bit depth PNG keeps absolute heights: `0` = background, otherwise
//! `round(32768 + 1000 * height_mm)` clamped to 1..=65535 (micrometres around mid-range, so
//! +-32 mm round-trips at 1 um). [`depth_from_png16`] inverts it.

use image::{ImageBuffer, Luma, Rgb, RgbImage};

use super::DepthMap;

/// A 16-bit grey image.
pub type Depth16Image = ImageBuffer<Luma<u16>, Vec<u16>>;

/// Zero level of the 16-bit encoding.
const DEPTH16_ZERO: f64 = 32768.0;
/// Steps per mm of the 16-bit encoding (1 um).
const DEPTH16_PER_MM: f64 = 1000.0;

/// Per-pixel hint values in [0, 1] (row-major), before colour mapping; see the module docs.
pub fn control_values(depth: &DepthMap) -> Vec<f32> {
    let covered = depth.height_mm.iter().copied().filter(|&h| h > DepthMap::BACKGROUND_MM && h.is_finite());
    let (lo, hi) = covered.fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), h| (lo.min(h), hi.max(h)));
    let span = hi - lo;
    depth
        .height_mm
        .iter()
        .map(|&h| {
            if !(h > DepthMap::BACKGROUND_MM && h.is_finite()) {
                0.0
            } else if span > 1e-6 {
                ((h - lo) / span).clamp(0.0, 1.0)
            } else {
                1.0
            }
        })
        .collect()
}

/// The control image: inverted, normalised depth through viridis, RGB8.
pub fn control_image(depth: &DepthMap) -> RgbImage {
    let values = control_values(depth);
    let mut img = RgbImage::new(depth.width, depth.height);
    for (px, t) in img.pixels_mut().zip(values) {
        *px = Rgb(viridis(t));
    }
    img
}

/// The plain 16-bit depth image (see the module docs for the encoding).
pub fn depth_png16(depth: &DepthMap) -> Depth16Image {
    let mut img = Depth16Image::new(depth.width, depth.height);
    for (px, &h) in img.pixels_mut().zip(&depth.height_mm) {
        px.0[0] = if h > DepthMap::BACKGROUND_MM && h.is_finite() {
            (DEPTH16_ZERO + DEPTH16_PER_MM * h as f64).round().clamp(1.0, 65535.0) as u16
        } else {
            0
        };
    }
    img
}

/// Decodes a 16-bit depth image written by [`depth_png16`].
pub fn depth_from_png16(img: &Depth16Image) -> DepthMap {
    let height_mm = img
        .pixels()
        .map(|p| if p.0[0] == 0 { DepthMap::BACKGROUND_MM } else { ((p.0[0] as f64 - DEPTH16_ZERO) / DEPTH16_PER_MM) as f32 })
        .collect();
    DepthMap { width: img.width(), height: img.height(), height_mm }
}

/// Matplotlib's viridis at `t` in [0, 1] (clamped), RGB8.
///
/// A degree-6 polynomial fit of the matplotlib table (after Matt Zucker's public fit); it stays
/// within about 1% of the table, below what the diffusion model's hint encoder resolves.
pub fn viridis(t: f32) -> [u8; 3] {
    const C: [[f64; 3]; 7] = [
        [0.277_727_327_223_417_7, 0.005_407_344_544_966_578, 0.334_099_805_335_306_1],
        [0.105_093_043_108_577_4, 1.404_613_529_898_575, 1.384_590_162_594_685],
        [-0.330_861_828_725_556_3, 0.214_847_559_468_213, 0.095_095_163_028_236_59],
        [-4.634_230_498_983_486, -5.799_100_973_351_585, -19.332_440_956_279_87],
        [6.228_269_936_347_081, 14.179_933_366_805_09, 56.690_552_600_681_05],
        [4.776_384_997_670_288, -13.745_145_377_746_01, -65.353_032_633_372_34],
        [-5.435_455_855_934_631, 4.645_852_612_178_535, 26.312_435_249_583_2],
    ];
    let t = if t.is_finite() { t.clamp(0.0, 1.0) as f64 } else { 0.0 };
    let mut rgb = [0u8; 3];
    for (k, out) in rgb.iter_mut().enumerate() {
        let v = C.iter().rev().fold(0.0, |acc, c| acc * t + c[k]);
        *out = (v.clamp(0.0, 1.0) * 255.0).round() as u8;
    }
    rgb
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn viridis_endpoints_match_matplotlib() {
        // matplotlib: viridis(0) = (68, 1, 84), viridis(1) = (253, 231, 37), viridis(0.5) = (33, 145, 140).
        let close = |a: [u8; 3], b: [u8; 3]| a.iter().zip(b).all(|(x, y)| (*x as i32 - y as i32).abs() <= 4);
        assert!(close(viridis(0.0), [68, 1, 84]), "{:?}", viridis(0.0));
        assert!(close(viridis(1.0), [253, 231, 37]), "{:?}", viridis(1.0));
        assert!(close(viridis(0.5), [33, 145, 140]), "{:?}", viridis(0.5));
    }

    #[test]
    fn control_normalises_and_background_is_zero() {
        let mut d = DepthMap::empty(3, 1);
        d.height_mm[1] = -2.0;
        d.height_mm[2] = 1.0;
        assert_eq!(control_values(&d), vec![0.0, 0.0, 1.0]);
        let img = control_image(&d);
        assert_eq!(img.get_pixel(2, 0).0, viridis(1.0));
    }

    #[test]
    fn depth16_round_trip() {
        let mut d = DepthMap::empty(4, 1);
        d.height_mm[1] = 1.234;
        d.height_mm[2] = -7.5;
        d.height_mm[3] = 0.0;
        let back = depth_from_png16(&depth_png16(&d));
        for (a, b) in d.height_mm.iter().zip(&back.height_mm) {
            assert!((a - b).abs() < 1e-3, "{a} {b}");
        }
    }
}
