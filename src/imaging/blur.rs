//! Box blur of a scalar map: the mean over a `(2r + 1)`-square window, rows then columns. A
//! few passes approximate a Gaussian (three passes of radius `r` spread a point by
//! `sqrt(r (r + 1))`).
//!
//! With the edge values repeated ([`BoxBorder::Replicate`]) the map is blurred as a
//! [`RowBand`]: the zero rows above what is not zero and the run of equal rows below it are not
//! summed, since the running sums give zeros above and stop changing below; the values are the
//! whole map's.

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
        BoxBorder::Replicate => BANDS.with(|bands| {
            // The bands are reused from call to call on this thread.
            let (band, scratch) = &mut *bands.borrow_mut();
            band.load(&buf[..width * height], width, height);
            band.blur_replicate(r, passes, scratch);
            band.store(&mut buf[..width * height]);
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
    static BANDS: std::cell::RefCell<(RowBand, RowBand)> = std::cell::RefCell::new(Default::default());
}

/// One replicating box pass of radius `r` along each `n`-value line of `src`, into `dst`: `d[i]`
/// is the mean of the line over `i - r ..= i + r` with its end values repeated, as a running
/// sum (`acc += s[in] - s[out]`), at the cost of the lines' non-zero parts. An all-zero line is
/// written as zeros. Left of a line's first non-zero value by more than `r` its sums are 0;
/// right of its last by more than `r` they no longer change (each step adds and removes a
/// zero): those parts are filled, not summed. A line's running sum is a chain of dependent
/// additions, so eight lines are summed in lockstep, over the span any of them needs, each with
/// exactly its own operations.
fn replicate_lines(src: &[f32], dst: &mut [f32], n: usize, r: usize) {
    if n == 0 {
        return;
    }
    let lines = src.len().min(dst.len()) / n;
    let mut busy = Vec::with_capacity(lines);
    for (k, (s, d)) in src.chunks_exact(n).zip(dst.chunks_exact_mut(n)).take(lines).enumerate() {
        if let (Some(first), Some(last)) = (s.iter().position(|&v| v != 0.0), s.iter().rposition(|&v| v != 0.0)) {
            busy.push((k, first, last));
        } else {
            d.fill(0.0);
        }
    }
    let mut groups = busy.chunks_exact(8);
    for group in groups.by_ref() {
        let group: &[(usize, usize, usize); 8] = group.try_into().unwrap_or_else(|_| unreachable!("chunks of eight"));
        sum_lines(src, dst, n, r, group);
    }
    for line in groups.remainder() {
        sum_lines(src, dst, n, r, &[*line]);
    }
}

/// The running sums of `K` lines (`(index, first non-zero, last non-zero)`) of `src` into
/// `dst` (see [`replicate_lines`]).
fn sum_lines<const K: usize>(src: &[f32], dst: &mut [f32], n: usize, r: usize, group: &[(usize, usize, usize); K]) {
    let norm = 1.0 / (2 * r + 1) as f32;
    let first = group.iter().map(|g| g.1).min().unwrap_or(0);
    let last = group.iter().map(|g| g.2).max().unwrap_or(0);
    // Sums up to `start` are 0 (their windows hold zeros only); from `end` on they are constant.
    let start = first.saturating_sub(r + 1);
    let end = (last + r + 1).min(n - 1);
    let lines: [&[f32]; K] = std::array::from_fn(|l| &src[group[l].0 * n..(group[l].0 + 1) * n]);
    let mut acc = [0.0f32; K];
    if start == 0 {
        for k in 0..=2 * r {
            let at = (k as isize - r as isize).clamp(0, n as isize - 1) as usize;
            for (a, line) in acc.iter_mut().zip(&lines) {
                *a += line[at];
            }
        }
    }
    // Output rows are written through one line at a time (they may be any rows of `dst`).
    let mut outs = [0usize; K];
    for (o, g) in outs.iter_mut().zip(group) {
        *o = g.0 * n;
        dst[*o..*o + start].fill(0.0);
    }
    for i in start..=end {
        let (leaving, entering) = (i.saturating_sub(r), (i + r + 1).min(n - 1));
        for ((a, line), &o) in acc.iter_mut().zip(&lines).zip(&outs) {
            dst[o + i] = *a * norm;
            *a += line[entering] - line[leaving];
        }
    }
    for &o in &outs {
        let settled = dst[o + end];
        dst[o + end + 1..o + n].fill(settled);
    }
}

/// The columns `[first, last + 1)` outside which every row of `rows` is zero, or `None` when all
/// are zero.
fn nonzero_columns<'a>(rows: impl Iterator<Item = &'a [f32]>) -> Option<(usize, usize)> {
    let (mut c0, mut c1) = (usize::MAX, 0);
    for line in rows {
        // Most rows are zero: find out without an early exit (vectorised) first.
        if line.iter().fold(true, |zero, &v| zero & (v == 0.0)) {
            continue;
        }
        if let (Some(first), Some(last)) = (line.iter().position(|&v| v != 0.0), line.iter().rposition(|&v| v != 0.0)) {
            (c0, c1) = (c0.min(first), c1.max(last + 1));
        }
    }
    (c0 < c1).then_some((c0, c1))
}

/// The vertical running sums of a replicating box pass of radius `r` over a plane of `n` rows
/// (`row(i)`: row `i`, `None` for a row of zeros), over the columns `c0..c1` only: `emit(i,
/// sums)` for every output row `i` in `first..=last`, with its window sums (the pass writes
/// `sums * norm`). `first` is 0 (the window starts with the top row repeated) or a row whose
/// window, `first - r ..= first + r`, holds only zero rows, so its sums are 0.
fn vertical_sums<'a>(
    n: usize,
    r: usize,
    (c0, c1): (usize, usize),
    row: impl Fn(usize) -> Option<&'a [f32]>,
    first: usize,
    last: usize,
    mut emit: impl FnMut(usize, &[f32]),
) {
    let zero = vec![0.0f32; c1 - c0];
    let at = |i: usize| row(i).map_or(&zero[..], |line| &line[c0..c1]);
    let mut acc = vec![0.0f32; c1 - c0];
    if first == 0 {
        for k in 0..=2 * r {
            for (a, &v) in acc.iter_mut().zip(at((k as isize - r as isize).clamp(0, n as isize - 1) as usize)) {
                *a += v;
            }
        }
    }
    for i in first..=last {
        emit(i, &acc);
        if i == last {
            break;
        }
        let (leaving, entering) = (at(i.saturating_sub(r)), at((i + r + 1).min(n - 1)));
        for ((a, &inn), &out) in acc.iter_mut().zip(entering).zip(leaving) {
            *a += inn - out;
        }
    }
}

/// A `width` x `height` scalar map held as a band of rows: the rows above `top` are zero, the
/// rows `top..bottom` are stored, and every row from `bottom` on equals one stored tail row.
/// A contact touches a band of rows; [`RowBand::blur_replicate`] blurs it at the cost of that
/// band, with exactly the values [`box_blur_repeated`] gives the whole map
/// ([`BoxBorder::Replicate`]): below the band its running sums stop changing, so every row
/// there is the same (the tail; zero up to the rounding residue the sums leave).
#[derive(Debug, Clone, Default)]
pub struct RowBand {
    width: usize,
    height: usize,
    top: usize,
    bottom: usize,
    rows: Vec<f32>,
    /// `width` values, or empty for a tail of zeros.
    tail: Vec<f32>,
}

impl RowBand {
    /// Makes this the `width` x `height` map that is zero outside the rows `top..top + count`
    /// (cut to the map), and returns those rows, zeroed, for the caller to fill. The buffers are
    /// reused.
    pub fn reset(&mut self, width: usize, height: usize, top: usize, count: usize) -> &mut [f32] {
        let top = top.min(height);
        let count = count.min(height - top);
        (self.width, self.height, self.top, self.bottom) = (width, height, top, top + count);
        self.tail.clear();
        self.rows.clear();
        self.rows.resize(count * width, 0.0);
        &mut self.rows
    }

    /// Makes this the `width` x `height` map `plane` (row by row): its rows above the first
    /// non-zero one are not stored, nor the run of equal rows at its bottom beyond the first of
    /// them (kept as the tail). The buffers are reused.
    pub fn load(&mut self, plane: &[f32], width: usize, height: usize) {
        let zero = |row: &[f32]| row.iter().fold(true, |zero, &v| zero & (v == 0.0));
        let rows = || plane.chunks_exact(width.max(1)).take(height);
        let top = rows().position(|row| !zero(row)).unwrap_or(height);
        let mut bottom = height;
        if let Some(last) = rows().next_back() {
            // Equal values (`==`: NaN ends the run; zeros of either sign are equal).
            let same = |row: &[f32]| row.iter().zip(last).fold(true, |same, (a, b)| same & (a == b));
            bottom = rows().rposition(|row| !same(row)).map_or(0, |k| k + 1).max(top);
        }
        let stored = self.reset(width, height, top, bottom - top);
        stored.copy_from_slice(&plane[top * width..bottom * width]);
        if bottom < height && !zero(&plane[(height - 1) * width..height * width]) {
            self.tail.extend_from_slice(&plane[(height - 1) * width..height * width]);
        }
    }

    /// Writes the whole map into `plane`, row by row.
    pub fn store(&self, plane: &mut [f32]) {
        for (y, line) in plane.chunks_exact_mut(self.width.max(1)).take(self.height).enumerate() {
            match self.row(y) {
                Some(row) => line.copy_from_slice(row),
                None => line.fill(0.0),
            }
        }
    }

    /// Row `y`: `None` where it is all zeros (or outside the map).
    pub fn row(&self, y: usize) -> Option<&[f32]> {
        let w = self.width;
        if y < self.top || y >= self.height {
            None
        } else if y < self.bottom {
            Some(&self.rows[(y - self.top) * w..(y - self.top + 1) * w])
        } else {
            (!self.tail.is_empty()).then_some(&self.tail[..])
        }
    }

    /// The first row that may be non-zero.
    pub fn top(&self) -> usize {
        self.top
    }

    /// `passes` box blurs of radius `r` with the edge values repeated: the values
    /// [`box_blur_repeated`] with [`BoxBorder::Replicate`] gives the whole map, up to the sign of
    /// zeros. `scratch` holds the intermediate band (reused from call to call).
    pub fn blur_replicate(&mut self, r: usize, passes: usize, scratch: &mut RowBand) {
        if r == 0 || self.width == 0 || self.height == 0 {
            return;
        }
        for _ in 0..passes {
            self.horizontal_into(r, scratch);
            scratch.vertical_into(r, self);
        }
    }

    /// The row pass of every stored row and of the tail (every tail row gives the same line).
    fn horizontal_into(&self, r: usize, dst: &mut RowBand) {
        let w = self.width;
        dst.width = w;
        dst.height = self.height;
        dst.top = self.top;
        dst.bottom = self.bottom;
        dst.rows.clear();
        dst.rows.resize(self.rows.len(), 0.0);
        replicate_lines(&self.rows, &mut dst.rows, w, r);
        dst.tail.clear();
        if !self.tail.is_empty() {
            dst.tail.resize(w, 0.0);
            replicate_lines(&self.tail, &mut dst.tail, w, r);
        }
    }

    /// The column pass. Output row `i` sums input rows `i - r ..= i + r`, so the output band
    /// starts `r` rows higher, and from row `bottom + r` on its window holds tail rows only:
    /// each step adds and removes the same finite values, so the sums no longer change and
    /// that row is the new tail. (A tail with an infinite value would turn the sums to NaN
    /// from step to step: then every row is computed.)
    fn vertical_into(&self, r: usize, dst: &mut RowBand) {
        let (w, h) = (self.width, self.height);
        dst.width = w;
        dst.height = h;
        dst.rows.clear();
        dst.tail.clear();
        let has_tail = self.bottom < h && !self.tail.is_empty();
        let stored = self.rows.chunks_exact(w).chain(has_tail.then_some(&self.tail[..]));
        let Some((c0, c1)) = nonzero_columns(stored) else {
            (dst.top, dst.bottom) = (h, h);
            return;
        };
        let settles = !has_tail || self.tail.iter().all(|v| !v.is_infinite());
        let top = self.top.saturating_sub(r);
        let bottom = if settles { (self.bottom + r).min(h) } else { h };
        // Output rows above `top` are zero; the sums start from zero one row above it.
        let first = self.top.saturating_sub(r + 1);
        let last = bottom.min(h - 1);
        (dst.top, dst.bottom) = (top, bottom);
        dst.rows.resize((bottom - top) * w, 0.0);
        if bottom < h {
            dst.tail.resize(w, 0.0);
        }
        let norm = 1.0 / (2 * r + 1) as f32;
        let RowBand { rows, tail, .. } = dst;
        vertical_sums(
            h,
            r,
            (c0, c1),
            |i| self.row(i),
            first,
            last,
            |i, sums| {
                let line = if i < top {
                    return;
                } else if i < bottom {
                    &mut rows[(i - top) * w..(i - top + 1) * w]
                } else {
                    &mut tail[..]
                };
                for (out, a) in line[c0..c1].iter_mut().zip(sums) {
                    *out = a * norm;
                }
            },
        );
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

    /// Equal values, NaN equal to NaN (a NaN spreads through the running sums).
    fn same(a: &[f32], b: &[f32]) -> bool {
        a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x == y || (x.is_nan() && y.is_nan()))
    }

    fn noise(seed: &mut u32, n: usize) -> Vec<f32> {
        (0..n)
            .map(|_| {
                *seed ^= *seed << 13;
                *seed ^= *seed >> 17;
                *seed ^= *seed << 5;
                (*seed % 1000) as f32 * 0.37 - 90.0
            })
            .collect()
    }

    /// Planes whose rows the band shortcuts reach: random; zero rows at the top, zero columns
    /// at the left and right and equal rows at the bottom (zero or not, finite, NaN or infinite); all
    /// zeros; one row.
    fn planes(w: usize, h: usize, seed: &mut u32) -> Vec<Vec<f32>> {
        let src = noise(seed, w * h);
        let mut out = vec![src.clone(), vec![0.0; w * h]];
        for tail in [0.0f32, 2.5, f32::NAN, f32::INFINITY] {
            let mut banded = src.clone();
            let last = noise(seed, w);
            for (i, v) in banded.iter_mut().enumerate() {
                let (x, y) = (i % w, i / w);
                if y < h / 3 || x >= 2 * w / 3 || x < w / 5 {
                    *v = 0.0;
                } else if y >= h - h / 3 {
                    *v = if x == w / 2 { tail } else { last[x] * 0.001 };
                }
            }
            out.push(banded);
        }
        out
    }

    /// A replicating blur pass through the band (rows then columns) gives what the line-by-line
    /// running sums give on the whole plane, for one pass and for several.
    #[test]
    fn banded_blur_equals_the_line_by_line_running_sums() {
        let mut seed = 0x2545_f491u32;
        for (w, h, r) in [(1, 1, 1), (7, 5, 2), (5, 9, 6), (64, 48, 3), (33, 17, 1), (40, 60, 4)] {
            for plane in planes(w, h, &mut seed) {
                for passes in [1, 3] {
                    let mut expected = plane.clone();
                    for _ in 0..passes {
                        let rows = line_pass_by_lines(&expected, w, h, r, true);
                        expected = line_pass_by_lines(&rows, w, h, r, false);
                    }
                    let mut got = plane.clone();
                    box_blur_repeated(&mut got, w, h, r, passes, BoxBorder::Replicate);
                    assert!(same(&got, &expected), "{w}x{h} r {r} passes {passes}:\n{got:?}\n{expected:?}");
                    let (mut band, mut scratch) = (RowBand::default(), RowBand::default());
                    band.load(&plane, w, h);
                    band.blur_replicate(r, passes, &mut scratch);
                    let rows: Vec<f32> = (0..h).flat_map(|y| band.row(y).map_or(vec![0.0; w], <[f32]>::to_vec)).collect();
                    assert!(same(&rows, &expected), "{w}x{h} r {r} passes {passes} by rows");
                }
            }
        }
    }

    /// The band stores only the rows between the zero rows above and the equal rows below.
    #[test]
    fn a_band_stores_what_is_not_zero_above_or_repeated_below() {
        let (w, h) = (4, 10);
        let mut plane = vec![0.0f32; w * h];
        for y in 3..10 {
            for x in 0..w {
                plane[y * w + x] = if y < 6 { (y * 10 + x) as f32 } else { x as f32 + 0.5 };
            }
        }
        let mut band = RowBand::default();
        band.load(&plane, w, h);
        assert_eq!((band.top(), band.bottom, band.rows.len()), (3, 6, 3 * w));
        assert_eq!(band.tail, vec![0.5, 1.5, 2.5, 3.5]);
        let mut back = vec![9.0f32; w * h];
        band.store(&mut back);
        assert_eq!(back, plane);
    }
}
