//! The control image (MultiDiffSense's ControlNet hint) and the plain 16-bit depth PNG.
//!
//! MultiDiffSense conditions on the object's depth map rendered from the STL, inverted (near
//! is high), colour-mapped with viridis and scaled to [0, 1]. Our [`DepthMap`] already holds
//! heights (near the sensor = large), so the inversion is the identity here:
//!
//! ```text
//! t = (h - h_min) / (h_max - h_min)   over the pixels the object covers (t = 1 if flat)
//! t = 0                               where no object is (the far background)
//! rgb = viridis(t)                    matplotlib's table, RGB8; divide by 255 for the hint
//! ```
//!
//! The 16-bit depth PNG keeps absolute heights: `0` = background, otherwise
//! `round(32768 + 1000 * height_mm)` clamped to 1..=65535 (micrometres around mid-range, so
//! +-32 mm round-trips at 1 um). [`depth_from_png16`] inverts it.

use image::{ImageBuffer, Luma, RgbImage};

use super::DepthMap;

/// A 16-bit grey image.
pub type Depth16Image = ImageBuffer<Luma<u16>, Vec<u16>>;

/// Zero level of the 16-bit encoding.
const DEPTH16_ZERO: f64 = 32768.0;
/// Steps per mm of the 16-bit encoding (1 um).
const DEPTH16_PER_MM: f64 = 1000.0;

/// Per-pixel hint values in [0, 1] (row-major), before colour mapping; see the module docs.
pub fn control_values(depth: &DepthMap) -> Vec<f32> {
    let range = ControlRange::of(depth);
    depth.height_mm.iter().map(|&h| range.value(h)).collect()
}

/// The covered heights' span that [`control_values`] normalises by.
#[derive(Debug, Clone, Copy)]
struct ControlRange {
    lo: f32,
    span: f32,
}

impl ControlRange {
    fn of(depth: &DepthMap) -> Self {
        let w = (depth.width as usize).max(1);
        // Eight running extremes, one per lane, so the scan vectorises (the extremes of a set
        // do not depend on the order they are taken in).
        let (mut lo, mut hi) = ([f32::INFINITY; 8], [f32::NEG_INFINITY; 8]);
        let mut take = |heights: &[f32]| {
            for (k, &h) in heights.iter().enumerate() {
                let covered = h > DepthMap::BACKGROUND_MM && h.is_finite();
                let (l, u) = if covered { (h, h) } else { (f32::INFINITY, f32::NEG_INFINITY) };
                lo[k] = if l < lo[k] { l } else { lo[k] };
                hi[k] = if u > hi[k] { u } else { hi[k] };
            }
        };
        for row in depth.height_mm.chunks(w).filter(|row| any_covered(row)) {
            let mut groups = row.chunks_exact(8);
            groups.by_ref().for_each(&mut take);
            take(groups.remainder());
        }
        let lo = lo.into_iter().fold(f32::INFINITY, f32::min);
        let hi = hi.into_iter().fold(f32::NEG_INFINITY, f32::max);
        Self { lo, span: hi - lo }
    }

    fn value(self, h: f32) -> f32 {
        if !(h > DepthMap::BACKGROUND_MM && h.is_finite()) {
            0.0
        } else if self.span > 1e-6 {
            ((h - self.lo) / self.span).clamp(0.0, 1.0)
        } else {
            1.0
        }
    }

    /// The viridis entry of height `h`: `viridis(self.value(h))`'s index, computed without
    /// branches so that a row of them vectorises. A covered height gives a finite value in
    /// [0, 1] (`h - lo` lies in `0..=span`), whose entry is `floor(256 t)` capped at 255; an
    /// uncovered one gives 0 and a flat object 255, as [`ControlRange::value`] does.
    fn index(self, h: f32) -> u8 {
        let covered = h > DepthMap::BACKGROUND_MM && h.is_finite();
        let t = ((h - self.lo) / self.span).clamp(0.0, 1.0);
        let graded = ((t * 256.0) as u32).min(255) as u8;
        if !covered {
            0
        } else if self.span > 1e-6 {
            graded
        } else {
            255
        }
    }
}

/// The control image: inverted, normalised depth through viridis, RGB8.
pub fn control_image(depth: &DepthMap) -> RgbImage {
    let range = ControlRange::of(depth);
    let (w, h) = (depth.width as usize, depth.height as usize);
    if w == 0 || depth.height_mm.len() != w * h {
        return RgbImage::new(depth.width, depth.height);
    }
    // Rows the object does not reach are the background colour throughout.
    let background: Vec<u8> = std::iter::repeat_n(viridis(0.0), w).flatten().collect();
    let mut indices = vec![0u8; w];
    let mut bytes = Vec::with_capacity(3 * w * h);
    for row in depth.height_mm.chunks_exact(w) {
        let start = bytes.len();
        bytes.extend_from_slice(&background);
        if !any_covered(row) {
            continue;
        }
        let first = row.iter().position(|&h| h > DepthMap::BACKGROUND_MM).unwrap_or(0);
        let last = row.iter().rposition(|&h| h > DepthMap::BACKGROUND_MM).unwrap_or(first);
        let (row, indices) = (&row[first..=last], &mut indices[first..=last]);
        for (i, &h) in indices.iter_mut().zip(row) {
            *i = range.index(h);
        }
        for (px, &i) in bytes[start + 3 * first..start + 3 * (last + 1)].chunks_exact_mut(3).zip(indices.iter()) {
            px.copy_from_slice(&VIRIDIS[i as usize]);
        }
    }
    // `bytes` holds exactly 3 * w * h values by construction.
    RgbImage::from_raw(depth.width, depth.height, bytes).unwrap_or_else(|| RgbImage::new(depth.width, depth.height))
}

/// Whether any height of `row` is an object's (vectorised: no early exit).
fn any_covered(row: &[f32]) -> bool {
    row.iter().fold(false, |any, &h| any | (h > DepthMap::BACKGROUND_MM))
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

/// Matplotlib's viridis at `t` in [0, 1] (clamped; NaN is 0), RGB8.
///
/// Looks up matplotlib's 256-entry table the way matplotlib does for float input:
/// index `floor(t * 256)`, with `t = 1` mapped to the last entry.
pub fn viridis(t: f32) -> [u8; 3] {
    let t = if t.is_finite() { t.clamp(0.0, 1.0) } else { 0.0 };
    let index = ((t * 256.0) as usize).min(255);
    VIRIDIS[index]
}

/// matplotlib's `viridis` colours (matplotlib 3.11 `colormaps["viridis"].colors`, rounded to 8 bit).
#[rustfmt::skip]
const VIRIDIS: [[u8; 3]; 256] = [
    [68, 1, 84], [68, 2, 86], [69, 4, 87], [69, 5, 89], [70, 7, 90], [70, 8, 92], [70, 10, 93], [70, 11, 94],
    [71, 13, 96], [71, 14, 97], [71, 16, 99], [71, 17, 100], [71, 19, 101], [72, 20, 103], [72, 22, 104], [72, 23, 105],
    [72, 24, 106], [72, 26, 108], [72, 27, 109], [72, 28, 110], [72, 29, 111], [72, 31, 112], [72, 32, 113], [72, 33, 115],
    [72, 35, 116], [72, 36, 117], [72, 37, 118], [72, 38, 119], [72, 40, 120], [72, 41, 121], [71, 42, 122], [71, 44, 122],
    [71, 45, 123], [71, 46, 124], [71, 47, 125], [70, 48, 126], [70, 50, 126], [70, 51, 127], [70, 52, 128], [69, 53, 129],
    [69, 55, 129], [69, 56, 130], [68, 57, 131], [68, 58, 131], [68, 59, 132], [67, 61, 132], [67, 62, 133], [66, 63, 133],
    [66, 64, 134], [66, 65, 134], [65, 66, 135], [65, 68, 135], [64, 69, 136], [64, 70, 136], [63, 71, 136], [63, 72, 137],
    [62, 73, 137], [62, 74, 137], [62, 76, 138], [61, 77, 138], [61, 78, 138], [60, 79, 138], [60, 80, 139], [59, 81, 139],
    [59, 82, 139], [58, 83, 139], [58, 84, 140], [57, 85, 140], [57, 86, 140], [56, 88, 140], [56, 89, 140], [55, 90, 140],
    [55, 91, 141], [54, 92, 141], [54, 93, 141], [53, 94, 141], [53, 95, 141], [52, 96, 141], [52, 97, 141], [51, 98, 141],
    [51, 99, 141], [50, 100, 142], [50, 101, 142], [49, 102, 142], [49, 103, 142], [49, 104, 142], [48, 105, 142], [48, 106, 142],
    [47, 107, 142], [47, 108, 142], [46, 109, 142], [46, 110, 142], [46, 111, 142], [45, 112, 142], [45, 113, 142], [44, 113, 142],
    [44, 114, 142], [44, 115, 142], [43, 116, 142], [43, 117, 142], [42, 118, 142], [42, 119, 142], [42, 120, 142], [41, 121, 142],
    [41, 122, 142], [41, 123, 142], [40, 124, 142], [40, 125, 142], [39, 126, 142], [39, 127, 142], [39, 128, 142], [38, 129, 142],
    [38, 130, 142], [38, 130, 142], [37, 131, 142], [37, 132, 142], [37, 133, 142], [36, 134, 142], [36, 135, 142], [35, 136, 142],
    [35, 137, 142], [35, 138, 141], [34, 139, 141], [34, 140, 141], [34, 141, 141], [33, 142, 141], [33, 143, 141], [33, 144, 141],
    [33, 145, 140], [32, 146, 140], [32, 146, 140], [32, 147, 140], [31, 148, 140], [31, 149, 139], [31, 150, 139], [31, 151, 139],
    [31, 152, 139], [31, 153, 138], [31, 154, 138], [30, 155, 138], [30, 156, 137], [30, 157, 137], [31, 158, 137], [31, 159, 136],
    [31, 160, 136], [31, 161, 136], [31, 161, 135], [31, 162, 135], [32, 163, 134], [32, 164, 134], [33, 165, 133], [33, 166, 133],
    [34, 167, 133], [34, 168, 132], [35, 169, 131], [36, 170, 131], [37, 171, 130], [37, 172, 130], [38, 173, 129], [39, 173, 129],
    [40, 174, 128], [41, 175, 127], [42, 176, 127], [44, 177, 126], [45, 178, 125], [46, 179, 124], [47, 180, 124], [49, 181, 123],
    [50, 182, 122], [52, 182, 121], [53, 183, 121], [55, 184, 120], [56, 185, 119], [58, 186, 118], [59, 187, 117], [61, 188, 116],
    [63, 188, 115], [64, 189, 114], [66, 190, 113], [68, 191, 112], [70, 192, 111], [72, 193, 110], [74, 193, 109], [76, 194, 108],
    [78, 195, 107], [80, 196, 106], [82, 197, 105], [84, 197, 104], [86, 198, 103], [88, 199, 101], [90, 200, 100], [92, 200, 99],
    [94, 201, 98], [96, 202, 96], [99, 203, 95], [101, 203, 94], [103, 204, 92], [105, 205, 91], [108, 205, 90], [110, 206, 88],
    [112, 207, 87], [115, 208, 86], [117, 208, 84], [119, 209, 83], [122, 209, 81], [124, 210, 80], [127, 211, 78], [129, 211, 77],
    [132, 212, 75], [134, 213, 73], [137, 213, 72], [139, 214, 70], [142, 214, 69], [144, 215, 67], [147, 215, 65], [149, 216, 64],
    [152, 216, 62], [155, 217, 60], [157, 217, 59], [160, 218, 57], [162, 218, 55], [165, 219, 54], [168, 219, 52], [170, 220, 50],
    [173, 220, 48], [176, 221, 47], [178, 221, 45], [181, 222, 43], [184, 222, 41], [186, 222, 40], [189, 223, 38], [192, 223, 37],
    [194, 223, 35], [197, 224, 33], [200, 224, 32], [202, 225, 31], [205, 225, 29], [208, 225, 28], [210, 226, 27], [213, 226, 26],
    [216, 226, 25], [218, 227, 25], [221, 227, 24], [223, 227, 24], [226, 228, 24], [229, 228, 25], [231, 228, 25], [234, 229, 26],
    [236, 229, 27], [239, 229, 28], [241, 229, 29], [244, 230, 30], [246, 230, 32], [248, 230, 33], [251, 231, 35], [253, 231, 37],
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn viridis_matches_matplotlib() {
        // Values printed by matplotlib 3.11: (np.array(colormaps["viridis"](t)[:3]) * 255).round().
        assert_eq!(viridis(0.0), [68, 1, 84]);
        assert_eq!(viridis(0.25), [59, 82, 139]);
        assert_eq!(viridis(0.5), [33, 145, 140]);
        assert_eq!(viridis(0.75), [94, 201, 98]);
        assert_eq!(viridis(1.0), [253, 231, 37]);
        assert_eq!(viridis(f32::NAN), viridis(0.0));
        assert_eq!(viridis(7.0), viridis(1.0));
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

    /// The branch-free entry of a height is viridis's entry of its value, for covered and
    /// uncovered heights, graded and flat objects.
    #[test]
    fn the_branch_free_index_is_viridis_of_the_value() {
        let heights = [DepthMap::BACKGROUND_MM, -999.0, -3.0, -1.0, -0.0, 0.0, 1e-7, 0.3, 0.999_999, 1.0, 2.5, f32::NAN, f32::INFINITY];
        for (lo, span) in [(-1.0f32, 2.0f32), (0.0, 1e-7), (0.3, 0.0), (f32::INFINITY, f32::NEG_INFINITY), (-3.0, 5.5)] {
            let range = ControlRange { lo, span };
            for h in heights.into_iter().chain((0..1000).map(|k| lo + span * k as f32 / 999.0)) {
                assert_eq!(VIRIDIS[range.index(h) as usize], viridis(range.value(h)), "lo {lo} span {span} h {h}");
            }
        }
    }

    /// A map with rows the object does not reach, a flat top and non-finite heights: every
    /// pixel is viridis of its value.
    #[test]
    fn control_image_is_viridis_of_every_value() {
        let mut d = DepthMap::empty(13, 5);
        for (i, h) in d.height_mm.iter_mut().enumerate().filter(|(i, _)| i / 13 % 2 == 1) {
            *h = [0.5, -2.0, f32::NAN, 1.25, f32::INFINITY, -0.25][i % 6];
        }
        let values = control_values(&d);
        let img = control_image(&d);
        for (px, v) in img.pixels().zip(&values) {
            assert_eq!(px.0, viridis(*v));
        }
        let mut flat = DepthMap::empty(4, 2);
        flat.height_mm[5] = 0.7;
        flat.height_mm[6] = 0.7;
        assert_eq!(control_image(&flat).get_pixel(1, 1).0, viridis(1.0));
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
