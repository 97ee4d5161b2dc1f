//! The LeRobot export's statistics (`meta/stats.json` and each episode's `stats/<key>/<stat>`
//! columns): min, max, mean, std, count and the quantiles [`QUANTILES`] of every numeric and
//! image feature, exact.
//!
//! A vector feature's stats are computed from its values over a set of frames ([`VecStats`]),
//! gathered once the set is known: the export holds a small record per pose from which every
//! numeric feature follows, so no value is kept while frames are written. An image feature's
//! stats come from a 256-bin histogram per channel ([`ImageStats`]): exact for 8-bit pixels,
//! constant in size, merged across episodes by adding counts.

use std::collections::BTreeMap;

use serde_json::{Value, json};

/// The quantiles in the stats, as LeRobot names them (`q01` is the 1 % quantile).
pub const QUANTILES: [(&str, f64); 5] = [("q01", 0.01), ("q10", 0.10), ("q50", 0.50), ("q90", 0.90), ("q99", 0.99)];

/// `stat -> per-component values`, LeRobot's stat names in order (min, max, mean, std, q01..q99).
pub(super) type StatTable = Vec<(String, Vec<f64>)>;

/// One feature's stats over some frames.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct FeatureStats {
    pub table: StatTable,
    /// Frames counted.
    pub count: u64,
    /// An image feature: its stats are per channel, shaped `[3, 1, 1]`.
    pub image: bool,
}

/// Every feature's stats over some frames, by feature key.
pub(super) type StatsByFeature = BTreeMap<String, FeatureStats>;

/// Exact statistics of a vector feature over a set of frames.
#[derive(Debug, Clone, Default)]
pub(super) struct VecStats {
    /// Values by component.
    dims: Vec<Vec<f64>>,
}

impl VecStats {
    pub fn new(dims: usize) -> Self {
        Self { dims: vec![Vec::new(); dims] }
    }
    pub fn push(&mut self, values: &[f64]) {
        for (d, v) in self.dims.iter_mut().zip(values) {
            d.push(*v);
        }
    }
    pub fn count(&self) -> usize {
        self.dims.first().map_or(0, Vec::len)
    }
    /// The stats, consuming the values (each component is sorted in place).
    pub fn into_stats(mut self) -> FeatureStats {
        let count = self.count() as u64;
        for d in &mut self.dims {
            d.sort_by(f64::total_cmp);
        }
        let sorted = &self.dims;
        let per = |f: &dyn Fn(&[f64]) -> f64| sorted.iter().map(|d| f(d)).collect::<Vec<f64>>();
        let mut table = vec![
            ("min".to_string(), per(&|d| d.first().copied().unwrap_or(0.0))),
            ("max".to_string(), per(&|d| d.last().copied().unwrap_or(0.0))),
            ("mean".to_string(), per(&|d| mean_std(d).0)),
            ("std".to_string(), per(&|d| mean_std(d).1)),
        ];
        for (name, q) in QUANTILES {
            table.push((name.to_string(), per(&|d| quantile_sorted(d, q))));
        }
        FeatureStats { table, count, image: false }
    }
}

/// Mean and population standard deviation (numpy's default, ddof = 0).
fn mean_std(values: &[f64]) -> (f64, f64) {
    if values.is_empty() {
        return (0.0, 0.0);
    }
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let var = values.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / n;
    (mean, var.sqrt())
}

/// The `q` quantile of sorted values, numpy's default (linear) method.
fn quantile_sorted(sorted: &[f64], q: f64) -> f64 {
    let Some(last) = sorted.len().checked_sub(1) else { return 0.0 };
    let pos = q * last as f64;
    let lo = pos.floor() as usize;
    let hi = (lo + 1).min(last);
    let frac = pos - lo as f64;
    sorted[lo] + (sorted[hi] - sorted[lo]) * frac
}

/// Exact per-channel statistics of 8-bit RGB images (a histogram per channel).
#[derive(Debug, Clone)]
pub(super) struct ImageStats {
    hist: [[u64; 256]; 3],
    images: u64,
}

impl Default for ImageStats {
    fn default() -> Self {
        Self { hist: [[0; 256]; 3], images: 0 }
    }
}

impl ImageStats {
    pub fn push(&mut self, image: &image::RgbImage) {
        for px in image.pixels() {
            for c in 0..3 {
                self.hist[c][usize::from(px.0[c])] += 1;
            }
        }
        self.images += 1;
    }
    pub fn merge(&mut self, other: &ImageStats) {
        for c in 0..3 {
            for v in 0..256 {
                self.hist[c][v] += other.hist[c][v];
            }
        }
        self.images += other.images;
    }
    /// The stats, per channel on [0, 1].
    pub fn stats(&self) -> FeatureStats {
        let per = |f: &dyn Fn(&[u64; 256]) -> f64| self.hist.iter().map(|h| f(h) / 255.0).collect::<Vec<f64>>();
        let mut table = vec![
            ("min".to_string(), per(&|h| h.iter().position(|&n| n > 0).unwrap_or(0) as f64)),
            ("max".to_string(), per(&|h| h.iter().rposition(|&n| n > 0).unwrap_or(0) as f64)),
            ("mean".to_string(), per(&|h| hist_mean_std(h).0)),
            ("std".to_string(), per(&|h| hist_mean_std(h).1)),
        ];
        for (name, q) in QUANTILES {
            table.push((name.to_string(), per(&|h| hist_quantile(h, q))));
        }
        FeatureStats { table, count: self.images, image: true }
    }
}

fn hist_mean_std(h: &[u64; 256]) -> (f64, f64) {
    let n: u64 = h.iter().sum();
    if n == 0 {
        return (0.0, 0.0);
    }
    let mean = h.iter().enumerate().map(|(v, &c)| v as f64 * c as f64).sum::<f64>() / n as f64;
    let var = h.iter().enumerate().map(|(v, &c)| (v as f64 - mean).powi(2) * c as f64).sum::<f64>() / n as f64;
    (mean, var.sqrt())
}

/// The value at 0-based rank `k` of the histogram's sorted values.
fn hist_rank(h: &[u64; 256], k: u64) -> f64 {
    let mut seen = 0u64;
    for (v, &c) in h.iter().enumerate() {
        seen += c;
        if seen > k {
            return v as f64;
        }
    }
    255.0
}

/// The `q` quantile of the histogram's values, numpy's linear method (as on the sorted pixels).
fn hist_quantile(h: &[u64; 256], q: f64) -> f64 {
    let n: u64 = h.iter().sum();
    let Some(last) = n.checked_sub(1) else { return 0.0 };
    let pos = q * last as f64;
    let lo = pos.floor() as u64;
    let hi = (lo + 1).min(last);
    let (a, b) = (hist_rank(h, lo), hist_rank(h, hi));
    a + (b - a) * (pos - lo as f64)
}

/// `feature -> stat -> value` as `meta/stats.json` holds it: vectors as lists, image stats as
/// [3][1][1], `count` as a one-element list.
pub(super) fn stats_json(stats: &StatsByFeature) -> Value {
    let mut out = serde_json::Map::new();
    for (key, s) in stats {
        let mut m = serde_json::Map::new();
        for (stat, values) in &s.table {
            let value = if s.image { json!(values.iter().map(|x| vec![vec![*x]]).collect::<Vec<_>>()) } else { json!(values) };
            m.insert(stat.clone(), value);
        }
        m.insert("count".into(), json!([s.count]));
        out.insert(key.clone(), Value::Object(m));
    }
    Value::Object(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_follow_numpys_linear_method() {
        let v = [1.0, 2.0, 3.0, 4.0, 10.0];
        // numpy.quantile([1, 2, 3, 4, 10], [0.01, 0.5, 0.9, 0.99]) = 1.04, 3.0, 7.6, 9.76
        assert!((quantile_sorted(&v, 0.01) - 1.04).abs() < 1e-12);
        assert_eq!(quantile_sorted(&v, 0.5), 3.0);
        assert!((quantile_sorted(&v, 0.9) - 7.6).abs() < 1e-12);
        assert!((quantile_sorted(&v, 0.99) - 9.76).abs() < 1e-12);
        assert_eq!(quantile_sorted(&[], 0.5), 0.0);
    }

    #[test]
    fn histogram_stats_equal_the_stats_of_the_pixels() {
        let values: Vec<u8> = vec![0, 3, 3, 7, 200, 255, 17, 17, 17, 90];
        let mut h = [0u64; 256];
        for &v in &values {
            h[usize::from(v)] += 1;
        }
        let mut sorted: Vec<f64> = values.iter().map(|&v| f64::from(v)).collect();
        sorted.sort_by(f64::total_cmp);
        for (_, q) in QUANTILES {
            assert!((hist_quantile(&h, q) - quantile_sorted(&sorted, q)).abs() < 1e-9, "q {q}");
        }
        let (m, s) = mean_std(&sorted);
        let (hm, hs) = hist_mean_std(&h);
        assert!((m - hm).abs() < 1e-9 && (s - hs).abs() < 1e-9);
    }

    #[test]
    fn image_stats_are_per_channel_on_the_unit_interval() {
        let mut img = image::RgbImage::new(2, 1);
        img.put_pixel(0, 0, image::Rgb([0, 255, 51]));
        img.put_pixel(1, 0, image::Rgb([255, 255, 153]));
        let mut st = ImageStats::default();
        st.push(&img);
        let s = st.stats();
        assert_eq!(s.count, 1);
        let t: BTreeMap<String, Vec<f64>> = s.table.into_iter().collect();
        assert_eq!(t["min"], vec![0.0, 1.0, 0.2]);
        assert_eq!(t["max"], vec![1.0, 1.0, 0.6]);
        assert!((t["mean"][0] - 0.5).abs() < 1e-12 && (t["mean"][2] - 0.4).abs() < 1e-12);
        assert!((t["std"][0] - 0.5).abs() < 1e-12 && t["std"][1] == 0.0);
    }

    #[test]
    fn merged_histograms_are_the_histogram_of_all_images() {
        let a = image::RgbImage::from_fn(3, 2, |x, y| image::Rgb([(x * 40) as u8, (y * 90) as u8, 7]));
        let b = image::RgbImage::from_fn(2, 2, |x, y| image::Rgb([200, (x + y) as u8, 250]));
        let (mut one, mut sa, mut sb) = (ImageStats::default(), ImageStats::default(), ImageStats::default());
        one.push(&a);
        one.push(&b);
        sa.push(&a);
        sb.push(&b);
        sa.merge(&sb);
        assert_eq!(sa.stats(), one.stats());
        assert_eq!(sa.stats().count, 2);
    }
}
