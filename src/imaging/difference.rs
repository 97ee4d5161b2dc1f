//! Luma, and how much an image changed from a reference.

use image::RgbImage;

/// Luma of an RGB pixel on the 8-bit scale (Rec. 601 weights), in `f32`.
pub fn luma(rgb: &[f32]) -> f32 {
    0.299 * rgb[0] + 0.587 * rgb[1] + 0.114 * rgb[2]
}

/// Luma of an 8-bit RGB pixel (Rec. 601 weights), in `f64`.
pub fn luma_f64(rgb: &[u8]) -> f64 {
    rgb[0] as f64 * 0.299 + rgb[1] as f64 * 0.587 + rgb[2] as f64 * 0.114
}

/// Per pixel, the largest of the three channel differences between `image` and `reference`,
/// 8-bit levels. Pixels past the shorter of the two are left out.
pub fn max_channel_difference(image: &RgbImage, reference: &RgbImage) -> Vec<f32> {
    image
        .as_raw()
        .chunks_exact(3)
        .zip(reference.as_raw().chunks_exact(3))
        .map(|(a, b)| (0..3).map(|k| (a[k] as i32 - b[k] as i32).unsigned_abs()).max().unwrap_or(0) as f32)
        .collect()
}

/// Per pixel, the sum of the three channel differences between `image` and `reference`
/// (0..=765). Pixels past the shorter of the two are left out.
pub fn summed_channel_difference(image: &RgbImage, reference: &RgbImage) -> Vec<u32> {
    image
        .as_raw()
        .chunks_exact(3)
        .zip(reference.as_raw().chunks_exact(3))
        .map(|(a, b)| (0..3).map(|k| (a[k] as i32 - b[k] as i32).unsigned_abs()).sum::<u32>())
        .collect()
}

/// The pixels whose [`summed_channel_difference`] from `reference` exceeds `threshold`.
pub fn difference_mask(image: &RgbImage, reference: &RgbImage, threshold: u32) -> Vec<bool> {
    summed_channel_difference(image, reference).into_iter().map(|d| d > threshold).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn differences_per_pixel() {
        let a = RgbImage::from_raw(2, 1, vec![10, 20, 30, 0, 0, 0]).unwrap();
        let b = RgbImage::from_raw(2, 1, vec![13, 10, 30, 0, 0, 255]).unwrap();
        assert_eq!(max_channel_difference(&a, &b), [10.0, 255.0]);
        assert_eq!(summed_channel_difference(&a, &b), [13, 255]);
        assert_eq!(difference_mask(&a, &b, 13), [false, true]);
        assert_eq!(luma(&[255.0, 255.0, 255.0]), 0.299 * 255.0 + 0.587 * 255.0 + 0.114 * 255.0);
        assert!((luma_f64(&[255, 255, 255]) - 255.0).abs() < 1e-9);
    }
}
