//! Grey morphology of scalar maps (dilation = running maximum, erosion = running minimum,
//! closing) and square dilation of masks. Windows are `(2r + 1)` squares clamped at the
//! borders, applied rows then columns.

/// In-place grey dilation: every value becomes the largest in its window.
pub fn dilate_values(buf: &mut [f32], width: usize, height: usize, r: usize) {
    running_extreme(buf, width, height, r, true);
}

/// In-place grey erosion: every value becomes the smallest in its window.
pub fn erode_values(buf: &mut [f32], width: usize, height: usize, r: usize) {
    running_extreme(buf, width, height, r, false);
}

/// In-place closing (dilation, then erosion): fills dips narrower than the window (dark
/// markers in a brightening blend) and keeps wider shapes.
pub fn close_values(buf: &mut [f32], width: usize, height: usize, r: usize) {
    dilate_values(buf, width, height, r);
    erode_values(buf, width, height, r);
}

/// Running maximum (`max = true`) or minimum over the window.
fn running_extreme(buf: &mut [f32], w: usize, h: usize, r: usize, max: bool) {
    if r == 0 || buf.len() < w * h {
        return;
    }
    let pick = |a: f32, b: f32| if max { a.max(b) } else { a.min(b) };
    let mut line = Vec::new();
    let mut pass = |buf: &mut [f32], n: usize, count: usize, index: &dyn Fn(usize, usize) -> usize| {
        for k in 0..count {
            line.clear();
            line.extend((0..n).map(|i| buf[index(k, i)]));
            for i in 0..n {
                let (lo, hi) = (i.saturating_sub(r), (i + r + 1).min(n));
                buf[index(k, i)] = line[lo..hi].iter().copied().fold(line[i], pick);
            }
        }
    };
    pass(buf, w, h, &|row, i| row * w + i);
    pass(buf, h, w, &|col, i| i * w + col);
}

/// Square dilation of a `width` x `height` mask by `r` pixels: a pixel is set when any pixel
/// of its window is. A mask of another length comes back unchanged.
pub fn dilate_mask(mask: &[bool], width: usize, height: usize, r: usize) -> Vec<bool> {
    let (w, h) = (width, height);
    if mask.len() != w * h || w == 0 || h == 0 {
        return mask.to_vec();
    }
    let mut rows = vec![false; mask.len()];
    for y in 0..h {
        for x in 0..w {
            let (lo, hi) = (x.saturating_sub(r), (x + r).min(w - 1));
            rows[y * w + x] = mask[y * w + lo..=y * w + hi].iter().any(|&m| m);
        }
    }
    let mut out = vec![false; mask.len()];
    for y in 0..h {
        let (lo, hi) = (y.saturating_sub(r), (y + r).min(h - 1));
        for x in 0..w {
            out[y * w + x] = (lo..=hi).any(|yy| rows[yy * w + x]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn closing_fills_a_narrow_dip_and_keeps_a_wide_one() {
        let mut narrow = vec![5.0, 5.0, 0.0, 5.0, 5.0];
        close_values(&mut narrow, 5, 1, 1);
        assert_eq!(narrow, [5.0; 5]);
        let mut wide = vec![5.0, 0.0, 0.0, 0.0, 0.0, 0.0, 5.0];
        close_values(&mut wide, 7, 1, 1);
        assert_eq!(wide, [5.0, 0.0, 0.0, 0.0, 0.0, 0.0, 5.0]);
    }

    #[test]
    fn mask_dilation_is_a_square() {
        let mut mask = vec![false; 7 * 7];
        mask[3 * 7 + 3] = true;
        let out = dilate_mask(&mask, 7, 7, 2);
        assert_eq!(out.iter().filter(|&&m| m).count(), 25);
        assert!(out[7 + 1] && out[5 * 7 + 5] && !out[0]);
        assert_eq!(dilate_mask(&mask, 7, 7, 0), mask);
        assert_eq!(dilate_mask(&mask[..5], 7, 7, 1), mask[..5].to_vec());
    }
}
