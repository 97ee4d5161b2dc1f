//! Box blur of a scalar map: the mean over a `(2r + 1)`-square window, rows then columns. A
//! few passes approximate a Gaussian (three passes of radius `r` spread a point by
//! `sqrt(r (r + 1))`).

/// What the window does where it reaches past the map's edge. The two differ near the edges
/// and in their rounding; each caller keeps its own so its numbers stay what they were.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BoxBorder {
    /// The mean over the part of the window inside the map (the window shrinks at the edge),
    /// from `f64` prefix sums. Calibration (detection, contact fit) and eval's contact
    /// estimator use it.
    Shrink,
    /// The edge value repeated, so every window holds `2r + 1` samples, from an `f32` running
    /// sum. The sensor simulator's fields use it.
    Replicate,
}

/// In-place box blur of radius `r` of a `width` x `height` map. Radius 0, an empty map or a
/// buffer shorter than the map leave it as it is.
pub fn box_blur(buf: &mut [f32], width: usize, height: usize, r: usize, border: BoxBorder) {
    box_blur_repeated(buf, width, height, r, 1, border);
}

/// [`box_blur`] applied `passes` times.
pub fn box_blur_repeated(buf: &mut [f32], width: usize, height: usize, r: usize, passes: usize, border: BoxBorder) {
    if r == 0 || width == 0 || height == 0 || buf.len() < width * height {
        return;
    }
    match border {
        BoxBorder::Shrink => {
            for _ in 0..passes {
                shrinking_pass(buf, width, height, r);
            }
        }
        BoxBorder::Replicate => {
            let mut tmp = vec![0.0f32; buf.len()];
            for _ in 0..passes {
                replicating_line_pass(buf, &mut tmp, width, height, r, true);
                replicating_line_pass(&tmp, buf, width, height, r, false);
            }
        }
    }
}

/// One blur with the shrinking window, rows then columns.
fn shrinking_pass(buf: &mut [f32], w: usize, h: usize, r: usize) {
    let mut line = Vec::new();
    let mut prefix = Vec::new();
    let mut pass = |buf: &mut [f32], n: usize, count: usize, index: &dyn Fn(usize, usize) -> usize| {
        for k in 0..count {
            line.clear();
            line.extend((0..n).map(|i| buf[index(k, i)] as f64));
            prefix.clear();
            prefix.push(0.0);
            let mut acc = 0.0;
            for v in &line {
                acc += v;
                prefix.push(acc);
            }
            for i in 0..n {
                let lo = i.saturating_sub(r);
                let hi = (i + r + 1).min(n);
                buf[index(k, i)] = ((prefix[hi] - prefix[lo]) / (hi - lo) as f64) as f32;
            }
        }
    };
    pass(buf, w, h, &|row, i| row * w + i);
    pass(buf, h, w, &|col, i| i * w + col);
}

/// One direction of the replicating blur, from `src` into `dst`.
fn replicating_line_pass(src: &[f32], dst: &mut [f32], w: usize, h: usize, r: usize, horizontal: bool) {
    let (n, lines) = if horizontal { (w, h) } else { (h, w) };
    let at = |line: usize, i: usize| if horizontal { line * w + i } else { i * w + line };
    let norm = 1.0 / (2 * r + 1) as f32;
    for line in 0..lines {
        // Running sum with clamped edges.
        let mut acc = 0.0f32;
        for k in 0..=2 * r {
            let i = (k as isize - r as isize).clamp(0, n as isize - 1) as usize;
            acc += src[at(line, i)];
        }
        for i in 0..n {
            dst[at(line, i)] = acc * norm;
            let out = (i as isize - r as isize).clamp(0, n as isize - 1) as usize;
            let inn = (i + r + 1).min(n - 1);
            acc += src[at(line, inn)] - src[at(line, out)];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn both_borders_keep_a_flat_field_and_differ_at_the_edge() {
        for border in [BoxBorder::Shrink, BoxBorder::Replicate] {
            let mut flat = vec![3.0f32; 12 * 7];
            box_blur_repeated(&mut flat, 12, 7, 2, 3, border);
            assert!(flat.iter().all(|v| (v - 3.0).abs() < 1e-5), "{border:?}");
        }
        // A step at the left edge: the shrinking window averages only what is inside.
        let step: Vec<f32> = (0..5).map(|x| if x == 0 { 10.0 } else { 0.0 }).collect();
        let (mut shrink, mut replicate) = (step.clone(), step);
        box_blur(&mut shrink, 5, 1, 1, BoxBorder::Shrink);
        box_blur(&mut replicate, 5, 1, 1, BoxBorder::Replicate);
        assert_eq!(shrink[0], 5.0);
        assert!((replicate[0] - 20.0 / 3.0).abs() < 1e-5, "{}", replicate[0]);
    }

    #[test]
    fn radius_zero_and_empty_maps_are_left_alone() {
        let mut v = vec![1.0, 5.0, 2.0];
        box_blur(&mut v, 3, 1, 0, BoxBorder::Shrink);
        assert_eq!(v, [1.0, 5.0, 2.0]);
        let mut empty: Vec<f32> = Vec::new();
        box_blur(&mut empty, 0, 4, 2, BoxBorder::Replicate);
        box_blur(&mut v, 4, 4, 1, BoxBorder::Shrink);
        assert_eq!(v, [1.0, 5.0, 2.0], "a buffer shorter than the map is left alone");
    }
}
