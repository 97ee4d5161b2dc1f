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
        BoxBorder::Replicate => TMP.with(|tmp| {
            // The intermediate plane is reused from call to call on this thread.
            let mut tmp = tmp.borrow_mut();
            tmp.clear();
            tmp.resize(width * height, 0.0);
            for _ in 0..passes {
                replicating_line_pass(buf, &mut tmp, width, height, r, true);
                replicating_line_pass(&tmp, buf, width, height, r, false);
            }
        }),
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

thread_local! {
    static TMP: std::cell::RefCell<Vec<f32>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// One box pass along rows (`horizontal`) or columns with replicated edges: a running sum per
/// line, `acc += src[in] - src[out]`. The column pass walks the rows once with one running sum
/// per column, so it reads memory in order and vectorises; each column's sums are the same
/// operations in the same order as walking the column itself.
///
/// A line that is all zeros stays all zeros (its running sum never leaves 0), so such rows, and
/// the columns left and right of every non-zero value, are written as zeros without summing: a
/// contact map that covers a small part of the image costs only that part.
fn replicating_line_pass(src: &[f32], dst: &mut [f32], w: usize, h: usize, r: usize, horizontal: bool) {
    let norm = 1.0 / (2 * r + 1) as f32;
    if horizontal {
        let n = w;
        for (s, d) in src.chunks_exact(w).zip(dst.chunks_exact_mut(w)).take(h) {
            if s.iter().fold(true, |zero, &v| zero & (v == 0.0)) {
                d.fill(0.0);
                continue;
            }
            // Running sum with clamped edges.
            let mut acc = 0.0f32;
            for k in 0..=2 * r {
                acc += s[(k as isize - r as isize).clamp(0, n as isize - 1) as usize];
            }
            for (i, out) in d.iter_mut().enumerate() {
                *out = acc * norm;
                let leaving = i.saturating_sub(r);
                let entering = (i + r + 1).min(n - 1);
                acc += s[entering] - s[leaving];
            }
        }
        return;
    }
    let n = h;
    // The columns holding a non-zero value; the others are zeros in and out.
    let (mut c0, mut c1) = (w, 0);
    for line in src.chunks_exact(w).take(h) {
        if line.iter().fold(true, |zero, &v| zero & (v == 0.0)) {
            continue;
        }
        if let (Some(first), Some(last)) = (line.iter().position(|&v| v != 0.0), line.iter().rposition(|&v| v != 0.0)) {
            (c0, c1) = (c0.min(first), c1.max(last + 1));
        }
    }
    if c0 >= c1 {
        dst[..w * h].fill(0.0);
        return;
    }
    let row = |i: usize| &src[i * w + c0..i * w + c1];
    let mut acc = vec![0.0f32; c1 - c0];
    for k in 0..=2 * r {
        for (a, &v) in acc.iter_mut().zip(row((k as isize - r as isize).clamp(0, n as isize - 1) as usize)) {
            *a += v;
        }
    }
    for i in 0..n {
        let (leaving, entering) = (row(i.saturating_sub(r)), row((i + r + 1).min(n - 1)));
        let line = &mut dst[i * w..(i + 1) * w];
        line[..c0].fill(0.0);
        line[c1..].fill(0.0);
        for (((out, a), &inn), &out_v) in line[c0..c1].iter_mut().zip(acc.iter_mut()).zip(entering).zip(leaving) {
            *out = *a * norm;
            *a += inn - out_v;
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

    /// The line-by-line running sum the passes implement, walking each column on its own.
    fn line_pass_by_lines(src: &[f32], w: usize, h: usize, r: usize, horizontal: bool) -> Vec<f32> {
        let (n, lines) = if horizontal { (w, h) } else { (h, w) };
        let at = |line: usize, i: usize| if horizontal { line * w + i } else { i * w + line };
        let norm = 1.0 / (2 * r + 1) as f32;
        let mut dst = vec![0.0f32; w * h];
        for line in 0..lines {
            let mut acc = 0.0f32;
            for k in 0..=2 * r {
                acc += src[at(line, (k as isize - r as isize).clamp(0, n as isize - 1) as usize)];
            }
            for i in 0..n {
                dst[at(line, i)] = acc * norm;
                let out = (i as isize - r as isize).clamp(0, n as isize - 1) as usize;
                acc += src[at(line, (i + r + 1).min(n - 1))] - src[at(line, out)];
            }
        }
        dst
    }

    #[test]
    fn passes_equal_the_line_by_line_running_sum_bit_for_bit() {
        let mut seed = 0x2545_f491u32;
        for (w, h, r) in [(1, 1, 1), (7, 5, 2), (5, 9, 6), (64, 48, 3), (33, 17, 1)] {
            let src: Vec<f32> = (0..w * h)
                .map(|_| {
                    seed ^= seed << 13;
                    seed ^= seed >> 17;
                    seed ^= seed << 5;
                    (seed % 1000) as f32 * 0.37 - 90.0
                })
                .collect();
            // Zero rows at the top and zero columns at the right (the skipped lines), and
            // an all-zero plane.
            let mut banded = src.clone();
            for (i, v) in banded.iter_mut().enumerate() {
                if i / w < h / 3 || i % w >= 2 * w / 3 {
                    *v = 0.0;
                }
            }
            for (src, horizontal) in [(&src, true), (&src, false), (&banded, true), (&banded, false)] {
                let mut dst = vec![-1.0f32; w * h];
                replicating_line_pass(src, &mut dst, w, h, r, horizontal);
                assert_eq!(dst, line_pass_by_lines(src, w, h, r, horizontal), "{w}x{h} r {r} horizontal {horizontal}");
            }
            let zero = vec![0.0f32; w * h];
            for horizontal in [true, false] {
                let mut dst = vec![7.0f32; w * h];
                replicating_line_pass(&zero, &mut dst, w, h, r, horizontal);
                assert_eq!(dst, zero);
            }
        }
    }
}
