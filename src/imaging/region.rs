//! Connected regions of a scalar map, and the overlap of masks.

/// The 4-connected pixels of a `width` x `height` map whose value exceeds `threshold`,
/// reachable from `start` (always included), in the order a depth-first fill visits them
/// (neighbours left, right, up, down). Marks each in `seen` and does not enter a pixel already
/// marked, so one `seen` can be shared by fills from several starts. An out-of-range `start`
/// or short buffers give no pixel.
pub fn flood_fill(values: &[f32], width: usize, height: usize, start: usize, threshold: f64, seen: &mut [bool]) -> Vec<usize> {
    let (w, h) = (width, height);
    let n = w * h;
    if start >= n || values.len() < n || seen.len() < n {
        return Vec::new();
    }
    let mut region = Vec::new();
    let mut stack = vec![start];
    seen[start] = true;
    while let Some(i) = stack.pop() {
        region.push(i);
        let (x, y) = (i % w, i / w);
        let neighbours = [(x > 0).then(|| i - 1), (x + 1 < w).then(|| i + 1), (y > 0).then(|| i - w), (y + 1 < h).then(|| i + w)];
        for j in neighbours.into_iter().flatten() {
            if !seen[j] && values[j] as f64 > threshold {
                seen[j] = true;
                stack.push(j);
            }
        }
    }
    region
}

/// Intersection over union of two masks (0 when both are empty).
pub fn iou(a: &[bool], b: &[bool]) -> f64 {
    let inter = a.iter().zip(b).filter(|(x, y)| **x && **y).count();
    let union = a.iter().zip(b).filter(|(x, y)| **x || **y).count();
    if union == 0 { 0.0 } else { inter as f64 / union as f64 }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fill_stays_in_its_region_and_shares_seen() {
        #[rustfmt::skip]
        let v = [
            5.0, 5.0, 0.0, 5.0,
            0.0, 5.0, 0.0, 5.0,
        ];
        let mut seen = vec![false; 8];
        let mut left = flood_fill(&v, 4, 2, 0, 1.0, &mut seen);
        left.sort_unstable();
        assert_eq!(left, [0, 1, 5]);
        assert!(flood_fill(&v, 4, 2, 9, 1.0, &mut seen).is_empty());
        let right = flood_fill(&v, 4, 2, 3, 1.0, &mut seen);
        assert_eq!(right, [3, 7]);
        assert!(seen[5] && !seen[2]);
    }

    #[test]
    fn iou_of_masks() {
        assert_eq!(iou(&[true, true, false], &[true, false, false]), 0.5);
        assert_eq!(iou(&[false, false], &[false, false]), 0.0);
    }
}
