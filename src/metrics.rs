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
//!
//! **How SSIM is computed.** One pass over the image in bands of [`BAND_ROWS`] output rows,
//! the bands in parallel (rayon). Within a band each input row is read once, straight from the
//! 8-bit pixels: its five quantities (x, y, x², y², xy) are filtered horizontally into a ring
//! of the last 11 rows, and each output row is the vertical filter over that ring, folded at
//! once into the SSIM map's sum. The 11-tap kernel is symmetric, so each tap pair costs one
//! multiply. Buffers live in a per-thread scratch that only grows, so a steady stream of
//! same-size pairs allocates nothing. The loops are written to vectorise, and on x86-64 a copy
//! compiled for AVX2 runs where the CPU has it. The arithmetic is f64: the variances are
//! differences of second moments up to 255² = 65025 whose f32 rounding (about 0.004) is not
//! small against C2 = 58.5, so f32 would move SSIM by about 1e-4, past the 1e-6 agreement with
//! scikit-image this module keeps. The bands are fixed (not one per thread), so the result is
//! the same on any number of threads; [`ssim_reference`] is the straightforward implementation
//! it replaced, kept as the tests' oracle and the benchmark's baseline.

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
    ssim_pixels(a.as_raw(), b.as_raw(), 3, a.dimensions(), b.dimensions(), None)
}

/// Mean SSIM of two RGB images over the masked pixels.
pub fn ssim_masked(a: &RgbImage, b: &RgbImage, mask: &[bool]) -> Result<f64, MetricsError> {
    ssim_pixels(a.as_raw(), b.as_raw(), 3, a.dimensions(), b.dimensions(), Some(mask))
}

/// Mean SSIM of two grey images.
pub fn ssim_gray(a: &GrayImage, b: &GrayImage) -> Result<f64, MetricsError> {
    ssim_pixels(a.as_raw(), b.as_raw(), 1, a.dimensions(), b.dimensions(), None)
}

/// Mean SSIM of two grey images over the masked pixels.
pub fn ssim_gray_masked(a: &GrayImage, b: &GrayImage, mask: &[bool]) -> Result<f64, MetricsError> {
    ssim_pixels(a.as_raw(), b.as_raw(), 1, a.dimensions(), b.dimensions(), Some(mask))
}

/// [`ssim`] as rig computed it before the banded implementation: whole-plane f64 buffers per
/// channel and a plain separable filter. The same definition; kept as the oracle the tests
/// compare the fast path with and as the baseline `benches/ssim_vs_skimage.rs` times.
pub fn ssim_reference(a: &RgbImage, b: &RgbImage) -> Result<f64, MetricsError> {
    ssim_planes(&rgb_planes(a), &rgb_planes(b), a.dimensions(), b.dimensions(), None)
}

/// [`ssim_masked`] as [`ssim_reference`] computes it.
pub fn ssim_masked_reference(a: &RgbImage, b: &RgbImage, mask: &[bool]) -> Result<f64, MetricsError> {
    ssim_planes(&rgb_planes(a), &rgb_planes(b), a.dimensions(), b.dimensions(), Some(mask))
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

/// Output rows per band of the banded SSIM (see the module docs): fixed, so the sum's order,
/// and so the result to the last bit, does not depend on the number of threads.
pub const BAND_ROWS: usize = 64;

/// The Gaussian window's taps as the banded filter uses them: the centre, then the five
/// pairs from the outside in (`PAIRS[t]` weighs taps `t` and `10 - t`).
#[derive(Clone, Copy)]
struct Taps {
    centre: f64,
    pairs: [f64; PAD],
}

impl Taps {
    fn new() -> Self {
        let k = gaussian_window();
        let mut pairs = [0.0; PAD];
        pairs.copy_from_slice(&k[..PAD]);
        Self { centre: k[PAD], pairs }
    }
}

/// One band's buffers: the five quantities of an input row, the ring of the last [`WIN`]
/// horizontally filtered rows, the vertical filter of an output row, and the SSIM of its pixels.
#[derive(Default)]
struct Scratch {
    line: Vec<f64>,
    ring: Vec<f64>,
    vert: Vec<f64>,
    map: Vec<f64>,
}

impl Scratch {
    /// Sized for rows of `w` pixels; grows only.
    fn fit(&mut self, w: usize) {
        let ow = w - 2 * PAD;
        for (buf, len) in [(&mut self.line, 5 * w), (&mut self.ring, WIN * 5 * ow), (&mut self.vert, 5 * ow), (&mut self.map, ow)] {
            if buf.len() < len {
                buf.resize(len, 0.0);
            }
        }
    }
}

thread_local! {
    static SCRATCH: std::cell::RefCell<Scratch> = std::cell::RefCell::new(Scratch::default());
}

/// What a band needs to know of the images.
#[derive(Clone, Copy)]
struct Images<'a> {
    a: &'a [u8],
    b: &'a [u8],
    /// Interleaved channels per pixel (3 for RGB, 1 for grey).
    channels: usize,
    w: usize,
    mask: Option<&'a [bool]>,
    taps: Taps,
    c1: f64,
    c2: f64,
}

fn ssim_pixels(
    a: &[u8],
    b: &[u8],
    channels: usize,
    a_dim: (u32, u32),
    b_dim: (u32, u32),
    mask: Option<&[bool]>,
) -> Result<f64, MetricsError> {
    use rayon::prelude::*;
    check_sizes(a_dim, b_dim, mask)?;
    let (w, h) = (a_dim.0 as usize, a_dim.1 as usize);
    if w < WIN || h < WIN {
        return Err(MetricsError::TooSmall { width: a_dim.0, height: a_dim.1, min: WIN as u32 });
    }
    let n = w * h * channels;
    if a.len() != n || b.len() != n {
        return Err(MetricsError::SizeMismatch { a_width: a_dim.0, a_height: a_dim.1, b_width: b_dim.0, b_height: b_dim.1 });
    }
    let images = Images { a, b, channels, w, mask, taps: Taps::new(), c1: (K1 * DATA_RANGE).powi(2), c2: (K2 * DATA_RANGE).powi(2) };
    let oh = h - 2 * PAD;
    let bands = oh.div_ceil(BAND_ROWS);
    let band = |i: usize| -> (f64, usize) {
        let rows = i * BAND_ROWS..((i + 1) * BAND_ROWS).min(oh);
        SCRATCH.with(|s| {
            let mut s = s.borrow_mut();
            s.fit(w);
            (0..channels).fold((0.0, 0), |(t, c), ch| {
                let (bt, bc) = band_sum(&images, ch, rows.clone(), &mut s);
                (t + bt, c + bc)
            })
        })
    };
    // Each band's sum lands in its own slot; the slots are added in order, so the result does
    // not depend on how rayon shared the bands out.
    const SLOTS: usize = 64;
    let (mut total, mut count) = (0.0, 0usize);
    for first in (0..bands).step_by(SLOTS) {
        let mut parts = [(0.0f64, 0usize); SLOTS];
        let n = SLOTS.min(bands - first);
        parts[..n].par_iter_mut().enumerate().for_each(|(i, p)| *p = band(first + i));
        for (t, c) in &parts[..n] {
            total += t;
            count += c;
        }
    }
    if count == 0 {
        return Err(MetricsError::EmptyMask);
    }
    Ok(total / count as f64)
}

/// The sum of one channel's SSIM map over output rows `rows` (and how many pixels it holds).
fn band_sum(images: &Images, channel: usize, rows: std::ops::Range<usize>, s: &mut Scratch) -> (f64, usize) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2, checked just above.
        return unsafe { band_sum_avx2(images, channel, rows, s) };
    }
    band_sum_body(images, channel, rows, s)
}

/// [`band_sum_body`] compiled for AVX2 (4 f64 lanes where SSE2 has 2).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn band_sum_avx2(images: &Images, channel: usize, rows: std::ops::Range<usize>, s: &mut Scratch) -> (f64, usize) {
    band_sum_body(images, channel, rows, s)
}

#[inline(always)]
fn band_sum_body(images: &Images, channel: usize, rows: std::ops::Range<usize>, s: &mut Scratch) -> (f64, usize) {
    let w = images.w;
    let ow = w - 2 * PAD;
    let Scratch { line, ring, vert, map } = s;
    let (line, ring, vert, map) = (&mut line[..5 * w], &mut ring[..WIN * 5 * ow], &mut vert[..5 * ow], &mut map[..ow]);
    let slot = |r: usize| (r % WIN) * 5 * ow;
    // The first output row needs input rows start..start + WIN; each later one, one more.
    for r in rows.start..rows.start + WIN - 1 {
        horizontal_row(images, channel, r, line, &mut ring[slot(r)..slot(r) + 5 * ow]);
    }
    let (mut total, mut count) = (0.0, 0usize);
    for oy in rows {
        let r = oy + WIN - 1;
        horizontal_row(images, channel, r, line, &mut ring[slot(r)..slot(r) + 5 * ow]);
        for q in 0..5 {
            let row = |t: usize| &ring[slot(oy + t) + q * ow..slot(oy + t) + (q + 1) * ow];
            symmetric_filter(
                images.taps,
                [row(0), row(1), row(2), row(3), row(4), row(5), row(6), row(7), row(8), row(9), row(10)],
                &mut vert[q * ow..(q + 1) * ow],
            );
        }
        ssim_row(&vert[..], ow, images.c1, images.c2, map);
        match images.mask {
            None => {
                total += sum_lanes(map);
                count += ow;
            }
            Some(m) => {
                let m = &m[(oy + PAD) * w + PAD..(oy + PAD) * w + PAD + ow];
                for (v, keep) in map.iter().zip(m) {
                    if *keep {
                        total += v;
                        count += 1;
                    }
                }
            }
        }
    }
    (total, count)
}

/// Input row `r` of one channel: its five quantities, filtered horizontally into `out` (five
/// runs of `w - 10`).
#[inline(always)]
fn horizontal_row(images: &Images, channel: usize, r: usize, line: &mut [f64], out: &mut [f64]) {
    let w = images.w;
    let ow = w - 2 * PAD;
    let step = images.channels;
    let start = r * w * step;
    let (a, b) = (&images.a[start..start + w * step], &images.b[start..start + w * step]);
    let (x, rest) = line.split_at_mut(w);
    let (y, rest) = rest.split_at_mut(w);
    let (xx, rest) = rest.split_at_mut(w);
    let (yy, xy) = rest.split_at_mut(w);
    for i in 0..w {
        let (p, q) = (f64::from(a[i * step + channel]), f64::from(b[i * step + channel]));
        x[i] = p;
        y[i] = q;
        xx[i] = p * p;
        yy[i] = q * q;
        xy[i] = p * q;
    }
    for (k, src) in [&*x, &*y, &*xx, &*yy, &*xy].into_iter().enumerate() {
        let shifted = |t: usize| &src[t..t + ow];
        symmetric_filter(
            images.taps,
            [
                shifted(0),
                shifted(1),
                shifted(2),
                shifted(3),
                shifted(4),
                shifted(5),
                shifted(6),
                shifted(7),
                shifted(8),
                shifted(9),
                shifted(10),
            ],
            &mut out[k * ow..(k + 1) * ow],
        );
    }
}

/// `out[i] = centre * s[5][i] + sum over t < 5 of pairs[t] * (s[t][i] + s[10 - t][i])`: the
/// 11-tap window over eleven equally long runs.
#[inline(always)]
fn symmetric_filter(taps: Taps, s: [&[f64]; WIN], out: &mut [f64]) {
    let n = out.len();
    let s = s.map(|r| &r[..n]);
    let [p0, p1, p2, p3, p4] = taps.pairs;
    for i in 0..n {
        out[i] = taps.centre * s[5][i]
            + p0 * (s[0][i] + s[10][i])
            + p1 * (s[1][i] + s[9][i])
            + p2 * (s[2][i] + s[8][i])
            + p3 * (s[3][i] + s[7][i])
            + p4 * (s[4][i] + s[6][i]);
    }
}

/// The SSIM of each pixel of an output row from its filtered moments (`vert`: five runs of
/// `ow`: mean x, mean y, mean x², mean y², mean xy).
#[inline(always)]
fn ssim_row(vert: &[f64], ow: usize, c1: f64, c2: f64, map: &mut [f64]) {
    let (ux, uy, uxx, uyy, uxy) = (&vert[..ow], &vert[ow..2 * ow], &vert[2 * ow..3 * ow], &vert[3 * ow..4 * ow], &vert[4 * ow..5 * ow]);
    let map = &mut map[..ow];
    for i in 0..ow {
        let (mx, my) = (ux[i], uy[i]);
        let vx = uxx[i] - mx * mx;
        let vy = uyy[i] - my * my;
        let cxy = uxy[i] - mx * my;
        map[i] = ((2.0 * mx * my + c1) * (2.0 * cxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2));
    }
}

/// The sum of `v` in four interleaved partial sums (so it vectorises).
#[inline(always)]
fn sum_lanes(v: &[f64]) -> f64 {
    let mut acc = [0.0f64; 4];
    let chunks = v.chunks_exact(4);
    let tail: f64 = chunks.remainder().iter().sum();
    for c in chunks {
        for k in 0..4 {
            acc[k] += c[k];
        }
    }
    (acc[0] + acc[1]) + (acc[2] + acc[3]) + tail
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
    fn banded_ssim_equals_the_reference_implementation() {
        // Sizes around the band height and the window, masks on and off, RGB and grey.
        for (w, h, seed) in [(11, 11, 1), (12, 75, 2), (64, 64, 3), (100, 139, 4), (300, 140, 5)] {
            let a = noise(w, h, seed);
            let mut b = a.clone();
            for (i, p) in b.pixels_mut().enumerate() {
                if i % 5 < 2 {
                    p.0[(i / 5) % 3] = p.0[(i / 5) % 3].wrapping_add((i % 97) as u8);
                }
            }
            let fast = ssim(&a, &b).unwrap();
            let slow = ssim_reference(&a, &b).unwrap();
            assert!((fast - slow).abs() < 1e-12, "{w}x{h}: {fast} vs {slow}");
            let mask: Vec<bool> = (0..(w * h) as usize).map(|i| (i * 7919) % 13 < 6).collect();
            let (fm, sm) = (ssim_masked(&a, &b, &mask).unwrap(), ssim_masked_reference(&a, &b, &mask).unwrap());
            assert!((fm - sm).abs() < 1e-12, "{w}x{h} masked: {fm} vs {sm}");
            let (ga, gb) = (image::imageops::grayscale(&a), image::imageops::grayscale(&b));
            let gray_ref = ssim_planes(
                &[ga.pixels().map(|p| p.0[0] as f32).collect()],
                &[gb.pixels().map(|p| p.0[0] as f32).collect()],
                ga.dimensions(),
                gb.dimensions(),
                None,
            )
            .unwrap();
            assert!((ssim_gray(&ga, &gb).unwrap() - gray_ref).abs() < 1e-12);
        }
    }

    #[test]
    fn banded_ssim_is_the_same_on_one_thread_and_many() {
        let a = noise(200, 300, 7);
        let b = noise(200, 300, 8);
        let many = ssim(&a, &b).unwrap();
        let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap().install(|| ssim(&a, &b).unwrap());
        assert_eq!(one.to_bits(), many.to_bits());
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
