//! Per-pixel statistics over a stack of frames: the median, the median over the frames a
//! mask leaves free, and the mean. Frames of another size than the first are left out.

use image::{Rgb, RgbImage};

/// Per-pixel, per-channel upper median of `frames` (element `n / 2` in order), at the first
/// frame's size.
pub fn median_image(frames: &[&RgbImage]) -> RgbImage {
    let (w, h) = frames.first().map(|f| f.dimensions()).unwrap_or((0, 0));
    let same: Vec<&RgbImage> = frames.iter().copied().filter(|f| f.dimensions() == (w, h)).collect();
    RgbImage::from_fn(w, h, |x, y| median_pixel(same.iter().copied(), x, y))
}

/// Per pixel, the upper median of the frames whose `excluded` mask (one per frame, row-major)
/// does not cover that pixel; of all frames where every mask covers it. The no-contact look of
/// a sensor from frames that each show a contact somewhere else.
pub fn median_image_excluding(frames: &[&RgbImage], excluded: &[Vec<bool>]) -> RgbImage {
    let (w, h) = frames.first().map(|f| f.dimensions()).unwrap_or((0, 0));
    let same: Vec<(&RgbImage, &Vec<bool>)> = frames.iter().copied().zip(excluded).filter(|(f, _)| f.dimensions() == (w, h)).collect();
    RgbImage::from_fn(w, h, |x, y| {
        let i = (y * w + x) as usize;
        let free = same.iter().filter(|(_, m)| !m.get(i).copied().unwrap_or(false)).map(|(f, _)| *f);
        if free.clone().next().is_some() { median_pixel(free, x, y) } else { median_pixel(same.iter().map(|(f, _)| *f), x, y) }
    })
}

/// Channel-wise upper median of pixel (x, y) over `frames` (black for none).
fn median_pixel<'a>(frames: impl Iterator<Item = &'a RgbImage> + Clone, x: u32, y: u32) -> Rgb<u8> {
    let mut px = [0u8; 3];
    for (k, out) in px.iter_mut().enumerate() {
        let mut v: Vec<u8> = frames.clone().map(|f| f.get_pixel(x, y).0[k]).collect();
        v.sort_unstable();
        *out = v.get(v.len() / 2).copied().unwrap_or(0);
    }
    Rgb(px)
}

/// The per-pixel mean of frames added one at a time (so a long stack need not be held in
/// memory), each channel rounded half up.
#[derive(Debug, Clone)]
pub struct MeanImage {
    width: u32,
    height: u32,
    sum: Vec<u64>,
    count: u64,
}

impl MeanImage {
    /// An empty mean of `width` x `height` frames.
    pub fn new(width: u32, height: u32) -> Self {
        Self { width, height, sum: vec![0; width as usize * height as usize * 3], count: 0 }
    }

    /// Adds a frame; a frame of another size is left out (returns `false`).
    pub fn add(&mut self, frame: &RgbImage) -> bool {
        if frame.dimensions() != (self.width, self.height) {
            return false;
        }
        for (s, &v) in self.sum.iter_mut().zip(frame.as_raw()) {
            *s += v as u64;
        }
        self.count += 1;
        true
    }

    /// Frames added.
    pub fn count(&self) -> u64 {
        self.count
    }

    /// The mean so far (`None` before the first frame). Rounded half up, `(sum + n / 2) / n`,
    /// which for sums of 8-bit values equals rounding the exact mean half away from zero.
    pub fn image(&self) -> Option<RgbImage> {
        let n = self.count;
        if n == 0 {
            return None;
        }
        let data = self.sum.iter().map(|&s| ((s + n / 2) / n) as u8).collect();
        RgbImage::from_raw(self.width, self.height, data)
    }
}

/// The per-pixel mean of `frames` at the first frame's size (see [`MeanImage`]); an empty
/// image for none.
pub fn mean_image(frames: &[&RgbImage]) -> RgbImage {
    let Some(first) = frames.first() else { return RgbImage::new(0, 0) };
    let mut mean = MeanImage::new(first.width(), first.height());
    for f in frames {
        mean.add(f);
    }
    mean.image().unwrap_or_else(|| RgbImage::new(0, 0))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flat(v: u8) -> RgbImage {
        RgbImage::from_pixel(2, 2, Rgb([v, v, v]))
    }

    #[test]
    fn median_is_the_upper_one_and_skips_other_sizes() {
        let frames = [flat(10), flat(30), flat(20), flat(40)];
        let refs: Vec<&RgbImage> = frames.iter().collect();
        assert_eq!(median_image(&refs).get_pixel(1, 1).0, [30; 3]);
        let odd = RgbImage::new(3, 3);
        assert_eq!(median_image(&[&frames[0], &odd]).get_pixel(0, 0).0, [10; 3]);
        assert_eq!(median_image(&[]).dimensions(), (0, 0));
    }

    #[test]
    fn excluded_pixels_take_the_free_frames() {
        let frames = [flat(10), flat(200), flat(20)];
        let refs: Vec<&RgbImage> = frames.iter().collect();
        // Frame 1 covers pixel 0; everyone covers pixel 3.
        let masks = vec![vec![false, false, false, true], vec![true, false, false, true], vec![false, false, false, true]];
        let out = median_image_excluding(&refs, &masks);
        assert_eq!(out.get_pixel(0, 0).0, [20; 3], "median of 10 and 20 (upper)");
        assert_eq!(out.get_pixel(1, 0).0, [20; 3], "median of all three");
        assert_eq!(out.get_pixel(1, 1).0, [20; 3], "all covered: median of all three");
    }

    #[test]
    fn mean_rounds_half_up_like_the_exact_mean() {
        assert_eq!(mean_image(&[&flat(10), &flat(21)]).get_pixel(1, 1).0, [16; 3]);
        assert_eq!(mean_image(&[]).dimensions(), (0, 0));
        // Integer rounding equals rounding the exact mean, for every sum of n 8-bit values.
        for n in 1u64..=12 {
            for sum in 0..=255 * n {
                let exact = (sum as f64 / n as f64).round() as u64;
                assert_eq!((sum + n / 2) / n, exact, "sum {sum} over {n}");
            }
        }
        let mut m = MeanImage::new(2, 2);
        assert!(m.image().is_none());
        assert!(!m.add(&RgbImage::new(3, 2)));
        assert!(m.add(&flat(7)));
        assert_eq!((m.count(), m.image().map(|i| i.get_pixel(0, 0).0)), (1, Some([7; 3])));
    }
}
