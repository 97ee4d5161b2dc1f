//! Image similarity: SSIM, PSNR and MSE, over the whole image or a masked region.
//!
//! SSIM follows Wang et al. (2004) as `skimage.metrics.structural_similarity(...,
//! gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=255)` computes it:
//! 11 x 11 Gaussian window (sigma 1.5, truncated at 3.5 sigma), K1 = 0.01, K2 = 0.03, the mean
//! of the SSIM map over the pixels at least 5 px from the border (where the window fits). RGB
//! images are the mean over the three channels. With the constants C1, C2 > 0 it is finite on
//! flat images (two identical flat images score exactly 1).
//!
//! Masked variants take one `bool` per pixel (row-major) and average only where it is true
//! (for SSIM: over window centres inside the mask and away from the border). PSNR of identical
//! images is `f64::INFINITY`.

use image::{GrayImage, RgbImage};

/// Window half-width: `int(3.5 * 1.5 + 0.5)` as skimage computes it.
const PAD: usize = 5;
const WIN: usize = 2 * PAD + 1;
const SIGMA: f64 = 1.5;
const DATA_RANGE: f64 = 255.0;
const K1: f64 = 0.01;
const K2: f64 = 0.03;

/// Why a metric cannot be computed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MetricsError {
    #[error("images differ in size: {a_width}x{a_height} vs {b_width}x{b_height}")]
    SizeMismatch { a_width: u32, a_height: u32, b_width: u32, b_height: u32 },
    #[error("mask has {got} entries, the image {expected} pixels")]
    MaskSize { expected: usize, got: usize },
    #[error("image {width}x{height} is smaller than the {min}x{min} SSIM window")]
    TooSmall { width: u32, height: u32, min: u32 },
    #[error("the mask selects no pixel where the metric is defined")]
    EmptyMask,
}

/// Mean SSIM of two RGB images (mean over channels).
pub fn ssim(a: &RgbImage, b: &RgbImage) -> Result<f64, MetricsError> {
    ssim_planes(&rgb_planes(a), &rgb_planes(b), a.dimensions(), b.dimensions(), None)
}

/// Mean SSIM of two RGB images over the masked pixels.
pub fn ssim_masked(a: &RgbImage, b: &RgbImage, mask: &[bool]) -> Result<f64, MetricsError> {
    ssim_planes(&rgb_planes(a), &rgb_planes(b), a.dimensions(), b.dimensions(), Some(mask))
}

/// Mean SSIM of two grey images.
pub fn ssim_gray(a: &GrayImage, b: &GrayImage) -> Result<f64, MetricsError> {
    ssim_planes(&[gray_plane(a)], &[gray_plane(b)], a.dimensions(), b.dimensions(), None)
}

/// Mean SSIM of two grey images over the masked pixels.
pub fn ssim_gray_masked(a: &GrayImage, b: &GrayImage, mask: &[bool]) -> Result<f64, MetricsError> {
    ssim_planes(&[gray_plane(a)], &[gray_plane(b)], a.dimensions(), b.dimensions(), Some(mask))
}

/// Mean squared error over all channels, in 8-bit units squared.
pub fn mse(a: &RgbImage, b: &RgbImage) -> Result<f64, MetricsError> {
    mse_impl(a, b, None)
}

/// Mean squared error over the masked pixels.
pub fn mse_masked(a: &RgbImage, b: &RgbImage, mask: &[bool]) -> Result<f64, MetricsError> {
    mse_impl(a, b, Some(mask))
}

/// Peak signal-to-noise ratio, dB (peak 255); infinite for identical images.
pub fn psnr(a: &RgbImage, b: &RgbImage) -> Result<f64, MetricsError> {
    mse(a, b).map(psnr_from_mse)
}

/// PSNR over the masked pixels, dB.
pub fn psnr_masked(a: &RgbImage, b: &RgbImage, mask: &[bool]) -> Result<f64, MetricsError> {
    mse_masked(a, b, mask).map(psnr_from_mse)
}

fn psnr_from_mse(mse: f64) -> f64 {
    if mse <= 0.0 { f64::INFINITY } else { 10.0 * (DATA_RANGE * DATA_RANGE / mse).log10() }
}

fn check_sizes(a: (u32, u32), b: (u32, u32), mask: Option<&[bool]>) -> Result<(), MetricsError> {
    if a != b {
        return Err(MetricsError::SizeMismatch { a_width: a.0, a_height: a.1, b_width: b.0, b_height: b.1 });
    }
    if let Some(m) = mask {
        let expected = a.0 as usize * a.1 as usize;
        if m.len() != expected {
            return Err(MetricsError::MaskSize { expected, got: m.len() });
        }
    }
    Ok(())
}

fn mse_impl(a: &RgbImage, b: &RgbImage, mask: Option<&[bool]>) -> Result<f64, MetricsError> {
    check_sizes(a.dimensions(), b.dimensions(), mask)?;
    let (mut sum, mut n) = (0.0f64, 0usize);
    for (i, (pa, pb)) in a.pixels().zip(b.pixels()).enumerate() {
        if mask.is_some_and(|m| !m[i]) {
            continue;
        }
        for k in 0..3 {
            let d = pa.0[k] as f64 - pb.0[k] as f64;
            sum += d * d;
        }
        n += 3;
    }
    if n == 0 {
        return Err(MetricsError::EmptyMask);
    }
    Ok(sum / n as f64)
}

fn rgb_planes(img: &RgbImage) -> Vec<Vec<f32>> {
    (0..3).map(|k| img.pixels().map(|p| p.0[k] as f32).collect()).collect()
}

fn gray_plane(img: &GrayImage) -> Vec<f32> {
    img.pixels().map(|p| p.0[0] as f32).collect()
}

fn gaussian_window() -> [f64; WIN] {
    let mut w = [0.0; WIN];
    for (i, v) in w.iter_mut().enumerate() {
        let x = i as f64 - PAD as f64;
        *v = (-x * x / (2.0 * SIGMA * SIGMA)).exp();
    }
    let s: f64 = w.iter().sum();
    w.map(|v| v / s)
}

/// Separable "valid" Gaussian filter: output is (w - 10) x (h - 10), output (x, y) is the
/// window centred on input (x + 5, y + 5).
fn filter_valid(src: &[f64], w: usize, h: usize, k: &[f64; WIN]) -> Vec<f64> {
    let (ow, oh) = (w - 2 * PAD, h - 2 * PAD);
    let mut tmp = vec![0.0; ow * h];
    for y in 0..h {
        let row = &src[y * w..(y + 1) * w];
        for x in 0..ow {
            tmp[y * ow + x] = k.iter().zip(&row[x..x + WIN]).map(|(a, b)| a * b).sum();
        }
    }
    let mut out = vec![0.0; ow * oh];
    for y in 0..oh {
        for x in 0..ow {
            out[y * ow + x] = (0..WIN).map(|t| k[t] * tmp[(y + t) * ow + x]).sum();
        }
    }
    out
}

fn ssim_planes(a: &[Vec<f32>], b: &[Vec<f32>], a_dim: (u32, u32), b_dim: (u32, u32), mask: Option<&[bool]>) -> Result<f64, MetricsError> {
    check_sizes(a_dim, b_dim, mask)?;
    let (w, h) = (a_dim.0 as usize, a_dim.1 as usize);
    if w < WIN || h < WIN {
        return Err(MetricsError::TooSmall { width: a_dim.0, height: a_dim.1, min: WIN as u32 });
    }
    let k = gaussian_window();
    let c1 = (K1 * DATA_RANGE).powi(2);
    let c2 = (K2 * DATA_RANGE).powi(2);
    let (ow, oh) = (w - 2 * PAD, h - 2 * PAD);
    let mut total = 0.0;
    let mut count = 0usize;
    for (pa, pb) in a.iter().zip(b) {
        let x: Vec<f64> = pa.iter().map(|&v| v as f64).collect();
        let y: Vec<f64> = pb.iter().map(|&v| v as f64).collect();
        let xx: Vec<f64> = x.iter().map(|v| v * v).collect();
        let yy: Vec<f64> = y.iter().map(|v| v * v).collect();
        let xy: Vec<f64> = x.iter().zip(&y).map(|(p, q)| p * q).collect();
        let (ux, uy) = (filter_valid(&x, w, h, &k), filter_valid(&y, w, h, &k));
        let (uxx, uyy, uxy) = (filter_valid(&xx, w, h, &k), filter_valid(&yy, w, h, &k), filter_valid(&xy, w, h, &k));
        for oy in 0..oh {
            for ox in 0..ow {
                if let Some(m) = mask
                    && !m[(oy + PAD) * w + ox + PAD]
                {
                    continue;
                }
                let i = oy * ow + ox;
                let (mx, my) = (ux[i], uy[i]);
                let vx = uxx[i] - mx * mx;
                let vy = uyy[i] - my * my;
                let cxy = uxy[i] - mx * my;
                let s = ((2.0 * mx * my + c1) * (2.0 * cxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2));
                total += s;
                count += 1;
            }
        }
    }
    if count == 0 {
        return Err(MetricsError::EmptyMask);
    }
    Ok(total / count as f64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::{Luma, Rgb};

    fn noise(w: u32, h: u32, seed: u32) -> RgbImage {
        let mut s = seed.wrapping_mul(2_654_435_761).max(1);
        RgbImage::from_fn(w, h, |_, _| {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            Rgb([(s & 255) as u8, ((s >> 8) & 255) as u8, ((s >> 16) & 255) as u8])
        })
    }

    #[test]
    fn identical_is_one_and_flat_is_finite() {
        let a = noise(32, 24, 1);
        assert!((ssim(&a, &a).unwrap() - 1.0).abs() < 1e-12);
        let flat0 = RgbImage::from_pixel(20, 20, Rgb([0, 0, 0]));
        let flat1 = RgbImage::from_pixel(20, 20, Rgb([255, 255, 255]));
        let s = ssim(&flat0, &flat1).unwrap();
        assert!(s.is_finite() && s < 0.01, "{s}");
        assert_eq!(ssim(&flat0, &flat0).unwrap(), 1.0);
        assert_eq!(psnr(&a, &a).unwrap(), f64::INFINITY);
    }

    #[test]
    fn noise_lowers_ssim_and_psnr() {
        let a = noise(40, 40, 1);
        let b = noise(40, 40, 2);
        let s = ssim(&a, &b).unwrap();
        assert!(s.abs() < 0.1, "independent noise SSIM {s}");
        let mut c = a.clone();
        for p in c.pixels_mut().step_by(7) {
            p.0[0] = p.0[0].wrapping_add(40);
        }
        let sc = ssim(&a, &c).unwrap();
        assert!(sc > s && sc < 1.0);
        assert!(psnr(&a, &c).unwrap() > psnr(&a, &b).unwrap());
    }

    #[test]
    fn mse_by_hand_and_mask() {
        let a = RgbImage::from_pixel(2, 1, Rgb([10, 10, 10]));
        let mut b = a.clone();
        b.put_pixel(1, 0, Rgb([13, 10, 10]));
        assert!((mse(&a, &b).unwrap() - 9.0 / 6.0).abs() < 1e-12);
        assert_eq!(mse_masked(&a, &b, &[true, false]).unwrap(), 0.0);
        assert_eq!(mse_masked(&a, &b, &[false, false]), Err(MetricsError::EmptyMask));
        assert!(matches!(mse_masked(&a, &b, &[true]), Err(MetricsError::MaskSize { .. })));
    }

    #[test]
    fn masked_ssim_sees_only_the_region() {
        let a = noise(40, 40, 3);
        let mut b = a.clone();
        // Damage the right half only.
        for y in 0..40 {
            for x in 20..40 {
                b.put_pixel(x, y, Rgb([0, 0, 0]));
            }
        }
        let left: Vec<bool> = (0..40 * 40).map(|i| i % 40 < 12).collect();
        assert!((ssim_masked(&a, &b, &left).unwrap() - 1.0).abs() < 1e-12);
        assert!(ssim(&a, &b).unwrap() < 0.9);
        let g = GrayImage::from_pixel(11, 11, Luma([7]));
        assert_eq!(ssim_gray(&g, &g).unwrap(), 1.0);
        assert!(matches!(ssim_gray(&GrayImage::new(5, 5), &GrayImage::new(5, 5)), Err(MetricsError::TooSmall { .. })));
    }
}
