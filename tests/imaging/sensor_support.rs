//! Helpers shared by the sensor tests: a spot detector that measures markers the same way on
//! real and simulated images, and access to the real sample data.

#![allow(dead_code)]

use std::path::PathBuf;

/// A detected spot: centroid (px) and area (px).
#[derive(Debug, Clone, Copy)]
pub struct Spot {
    pub x: f32,
    pub y: f32,
    pub area: f32,
}

fn lum(img: &image::RgbImage, x: u32, y: u32) -> f32 {
    let p = img.get_pixel(x, y);
    (p[0] as f32 + p[1] as f32 + p[2] as f32) / 3.0
}

/// Spots brighter (or darker, for `dark`) than their neighbourhood by `contrast` levels,
/// 4-connected, with an area between `min_area` and `max_area`.
pub fn spots(img: &image::RgbImage, dark: bool, contrast: f32, min_area: f32, max_area: f32) -> Vec<Spot> {
    let (w, h) = img.dimensions();
    let r = 8i32;
    let mut mask = vec![false; (w * h) as usize];
    for y in 0..h {
        for x in 0..w {
            let (mut s, mut n) = (0.0, 0.0);
            for dy in (-r..=r).step_by(4) {
                for dx in (-r..=r).step_by(4) {
                    let (xx, yy) = (x as i32 + dx, y as i32 + dy);
                    if xx >= 0 && yy >= 0 && xx < w as i32 && yy < h as i32 {
                        s += lum(img, xx as u32, yy as u32);
                        n += 1.0;
                    }
                }
            }
            let (m, v) = (s / n, lum(img, x, y));
            mask[(y * w + x) as usize] = if dark { v < m - contrast } else { v > m + contrast };
        }
    }
    let mut seen = vec![false; mask.len()];
    let mut out = Vec::new();
    for i in 0..mask.len() {
        if !mask[i] || seen[i] {
            continue;
        }
        seen[i] = true;
        let mut stack = vec![i];
        let (mut sx, mut sy, mut n) = (0.0f64, 0.0f64, 0.0f64);
        while let Some(j) = stack.pop() {
            let (x, y) = ((j as u32 % w) as i32, (j as u32 / w) as i32);
            sx += x as f64;
            sy += y as f64;
            n += 1.0;
            for (dx, dy) in [(1, 0), (-1, 0), (0, 1), (0, -1)] {
                let (xx, yy) = (x + dx, y + dy);
                if xx >= 0 && yy >= 0 && xx < w as i32 && yy < h as i32 {
                    let k = (yy as u32 * w + xx as u32) as usize;
                    if mask[k] && !seen[k] {
                        seen[k] = true;
                        stack.push(k);
                    }
                }
            }
        }
        let area = n as f32;
        if area >= min_area && area <= max_area {
            out.push(Spot { x: (sx / n) as f32, y: (sy / n) as f32, area });
        }
    }
    out
}

/// Spots within `radius` px of the image centre.
pub fn central(spots: Vec<Spot>, w: u32, h: u32, radius: f32) -> Vec<Spot> {
    let (cx, cy) = (w as f32 / 2.0, h as f32 / 2.0);
    spots.into_iter().filter(|s| ((s.x - cx).powi(2) + (s.y - cy).powi(2)).sqrt() < radius).collect()
}

/// Radii of the spots about their own centroid, sorted.
pub fn radii(spots: &[Spot]) -> Vec<f32> {
    let n = spots.len().max(1) as f32;
    let mx = spots.iter().map(|s| s.x).sum::<f32>() / n;
    let my = spots.iter().map(|s| s.y).sum::<f32>() / n;
    let mut r: Vec<f32> = spots.iter().map(|s| ((s.x - mx).powi(2) + (s.y - my).powi(2)).sqrt()).collect();
    r.sort_by(|a, b| a.total_cmp(b));
    r
}

/// Mean colour of the pixels whose distance from the centre lies in `[r0, r1)` px.
pub fn ring_mean(img: &image::RgbImage, r0: f32, r1: f32) -> [f32; 3] {
    let (w, h) = img.dimensions();
    let (cx, cy) = (w as f32 / 2.0, h as f32 / 2.0);
    let (mut s, mut n) = ([0.0f64; 3], 0.0f64);
    for (x, y, p) in img.enumerate_pixels() {
        let r = ((x as f32 + 0.5 - cx).powi(2) + (y as f32 + 0.5 - cy).powi(2)).sqrt();
        if r >= r0 && r < r1 {
            for c in 0..3 {
                s[c] += p[c] as f64;
            }
            n += 1.0;
        }
    }
    [(s[0] / n) as f32, (s[1] / n) as f32, (s[2] / n) as f32]
}

/// The real sample folder (`$RIG_SHARED/real-sample/multidiffsense-example/tactile/1`,
/// `RIG_SHARED` defaulting to `../shared` from the repository root).
pub fn real_dir() -> PathBuf {
    let shared = std::env::var("RIG_SHARED").unwrap_or_else(|_| "../shared".to_string());
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let shared = if PathBuf::from(&shared).is_absolute() { PathBuf::from(shared) } else { root.join(shared) };
    shared.join("real-sample/multidiffsense-example/tactile/1")
}

/// A real image, `<Sensor>/target/1_<Sensor>_<i>.png`.
pub fn real_image(label: &str, i: u32) -> image::RgbImage {
    let p = real_dir().join(format!("{label}/target/1_{label}_{i}.png"));
    image::open(&p)
        .unwrap_or_else(|e| panic!("real sample {} not readable ({e}); set RIG_SHARED to the shared folder", p.display()))
        .to_rgb8()
}
