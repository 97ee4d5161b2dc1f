//! Control image: supersampling factor against edge error against milliseconds per map.
//!
//! Each library object is rendered at a few poses by [`render_depth`] with each factor and
//! with a high-factor reference (8 x 8 samples per pixel), and turned into the control image
//! the diffusion model is conditioned on ([`control_values`]). Supersampling only changes
//! pixels on the object's outline, so the error is measured there:
//!
//! - **edge band** ([`edge_band`]): pixels of the reference whose 3 x 3 neighbourhood holds
//!   both object and background, or a height step above [`EDGE_STEP_MM`] (inner edges);
//! - **edge error** ([`edge_error_levels`]): mean absolute difference of the control values
//!   over the band, in 8-bit levels of the hint (0..255; viridis index units);
//! - **footprint error**: pixels whose object/background state differs from the reference,
//!   as a share of the band.
//!
//! Time is the fastest of the renders of a map (depth render plus control image), ms.

use std::time::Instant;

use super::error::BenchError;
use super::knob::{BenchConfig, Knob};
use super::plot::{Plot, Series};
use super::table::{Column, KnobReport, Row, fastest, mean};
use crate::calibration::Calibration;
use crate::geometry::DepthMap;
use crate::geometry::control::{control_image, control_values};
use crate::geometry::objects::load_object;
use crate::geometry::raster::render_depth;
use crate::pose::Pose;

/// A height step between neighbours larger than this marks an inner edge, mm.
pub const EDGE_STEP_MM: f32 = 0.2;

fn covered(h: f32) -> bool {
    h > DepthMap::BACKGROUND_MM && h.is_finite()
}

/// The edge band of a depth map (see the module docs): one flag per pixel, row-major.
pub fn edge_band(depth: &DepthMap) -> Vec<bool> {
    let (w, h) = (depth.width as usize, depth.height as usize);
    let mut band = vec![false; w * h];
    for y in 0..h {
        for x in 0..w {
            let c = depth.height_mm[y * w + x];
            let mut edge = false;
            for (dx, dy) in [(-1i64, -1i64), (0, -1), (1, -1), (-1, 0), (1, 0), (-1, 1), (0, 1), (1, 1)] {
                let (nx, ny) = (x as i64 + dx, y as i64 + dy);
                if nx < 0 || ny < 0 || nx >= w as i64 || ny >= h as i64 {
                    continue;
                }
                let n = depth.height_mm[ny as usize * w + nx as usize];
                if covered(n) != covered(c) || (covered(n) && covered(c) && (n - c).abs() > EDGE_STEP_MM) {
                    edge = true;
                    break;
                }
            }
            band[y * w + x] = edge;
        }
    }
    band
}

/// Mean absolute difference of the control values of `map` and `reference` over `band`, in
/// 8-bit levels; NaN when the band is empty or the sizes differ.
pub fn edge_error_levels(map: &DepthMap, reference: &DepthMap, band: &[bool]) -> f64 {
    let (a, b) = (control_values(map), control_values(reference));
    if a.len() != b.len() || band.len() != a.len() {
        return f64::NAN;
    }
    let diffs: Vec<f64> = a.iter().zip(&b).zip(band).filter(|(_, on)| **on).map(|((x, y), _)| ((x - y).abs() * 255.0) as f64).collect();
    mean(&diffs)
}

/// Share of the band's pixels whose object/background state differs from the reference.
pub fn footprint_error(map: &DepthMap, reference: &DepthMap, band: &[bool]) -> f64 {
    let n_band = band.iter().filter(|b| **b).count();
    if n_band == 0 || map.height_mm.len() != reference.height_mm.len() {
        return f64::NAN;
    }
    let wrong = map.height_mm.iter().zip(&reference.height_mm).filter(|(a, b)| covered(**a) != covered(**b)).count();
    wrong as f64 / n_band as f64
}

/// Poses the objects are rendered at: off-centre, turned, pressed 1 mm.
pub fn poses(n: usize) -> Vec<Pose> {
    [Pose::new(0.8, -0.6, 1.0, 25.0), Pose::new(-1.7, 1.1, 0.5, -40.0), Pose::new(2.3, 2.0, 1.5, 70.0), Pose::new(0.0, 0.0, 1.0, 0.0)]
        .into_iter()
        .cycle()
        .take(n)
        .collect()
}

/// Renders every object at every pose with each factor; one row per factor.
pub fn measure(config: &BenchConfig) -> Result<KnobReport, BenchError> {
    let px = config.image_px;
    let calib = Calibration::default_for(px, px);
    let reps = 3;
    let mut meshes = Vec::new();
    for name in &config.control_objects {
        meshes.push((name.clone(), load_object(name)?));
    }
    let cases: Vec<(usize, Pose)> = (0..meshes.len()).flat_map(|m| poses(config.control_poses).into_iter().map(move |p| (m, p))).collect();
    if cases.is_empty() {
        return Err(BenchError::Empty { knob: Knob::Control, reason: "no objects or poses" });
    }
    let references: Vec<DepthMap> =
        cases.iter().map(|(m, p)| render_depth(&meshes[*m].1, p, &calib, px, px, config.control_reference_supersample)).collect();
    let bands: Vec<Vec<bool>> = references.iter().map(edge_band).collect();
    let mut factors = config.control_supersample.clone();
    factors.push(config.control_reference_supersample);
    let mut rows = Vec::new();
    let mut series = Series { name: format!("{} objects x {} poses, {px} px", meshes.len(), config.control_poses), ..Default::default() };
    for &ss in &factors {
        let (mut errors, mut footprints, mut times) = (Vec::new(), Vec::new(), Vec::new());
        for (((m, pose), reference), band) in cases.iter().zip(&references).zip(&bands) {
            let mut map = None;
            let mut t_case = Vec::new();
            for _ in 0..reps {
                let t = Instant::now();
                let d = render_depth(&meshes[*m].1, pose, &calib, px, px, ss);
                std::hint::black_box(control_image(&d));
                t_case.push(t.elapsed().as_secs_f64() * 1e3);
                map = Some(d);
            }
            times.push(fastest(&t_case));
            if let Some(d) = map {
                errors.push(edge_error_levels(&d, reference, band));
                footprints.push(footprint_error(&d, reference, band));
            }
        }
        let (err, foot, ms) = (mean(&errors), mean(&footprints), mean(&times));
        let label = if ss == config.control_reference_supersample { format!("{ss}x{ss} (reference)") } else { format!("{ss}x{ss}") };
        rows.push(Row { label, values: vec![ss as f64, err, 100.0 * foot, ms] });
        series.points.push([ms, err]);
        series.labels.push(format!("{ss}x"));
    }
    let band_px = mean(&bands.iter().map(|b| b.iter().filter(|x| **x).count() as f64).collect::<Vec<_>>());
    Ok(KnobReport {
        knob: Knob::Control,
        title: "Control image: supersampling".into(),
        label_column: "samples per pixel".into(),
        columns: vec![
            Column::new("factor", 0),
            Column::new("edge error [levels]", 2),
            Column::new("footprint error [% of band]", 2),
            Column::new("ms per map", 2),
        ],
        rows,
        notes: vec![
            format!(
                "Objects {} at {} poses each, {px} x {px} px, default calibration. Reference: {r}x{r} samples per pixel.",
                config.control_objects.join(", "),
                config.control_poses,
                r = config.control_reference_supersample
            ),
            format!(
                "Edge error = mean |control value - reference| over the reference's edge band (pixels whose 3x3 neighbourhood \
                 holds object and background, or a step over {EDGE_STEP_MM} mm; {band_px:.0} px per map on average), in 8-bit \
                 levels of the viridis hint. Footprint error = pixels whose object/background state differs from the \
                 reference, in % of the band. ms per map = depth render + control image, fastest of {reps}, mean over the maps."
            ),
        ],
        plot: Plot {
            title: "Control image: edge error against time".into(),
            x_label: "ms per map".into(),
            y_label: "edge error [8-bit levels]".into(),
            series: vec![series],
            lines: true,
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square(w: u32, x0: usize, x1: usize, height_mm: f32) -> DepthMap {
        let mut d = DepthMap::empty(w, w);
        for y in x0..x1 {
            for x in x0..x1 {
                d.height_mm[y * w as usize + x] = height_mm;
            }
        }
        d
    }

    #[test]
    fn band_is_the_outline_of_a_square() {
        let d = square(10, 3, 7, 1.0);
        let band = edge_band(&d);
        // Inside: the 2 x 2 core has only covered neighbours; outside: everything at distance >= 2.
        assert!(!band[5 * 10 + 5] && !band[4 * 10 + 4]);
        assert!(band[3 * 10 + 3] && band[2 * 10 + 2] && band[7 * 10 + 5]);
        assert!(!band[0] && !band[9 * 10 + 9]);
        // 6 x 6 ring around the square minus the 2 x 2 core.
        assert_eq!(band.iter().filter(|b| **b).count(), 36 - 4);
    }

    #[test]
    fn band_marks_inner_steps() {
        let mut d = square(10, 0, 10, 1.0);
        for y in 0..10 {
            for x in 5..10 {
                d.height_mm[y * 10 + x] = 2.0;
            }
        }
        let band = edge_band(&d);
        assert!(band[3 * 10 + 4] && band[3 * 10 + 5] && !band[3 * 10 + 2]);
    }

    #[test]
    fn edge_error_is_zero_for_the_reference_and_grows_with_a_shift() {
        let reference = square(12, 3, 8, 1.0);
        let band = edge_band(&reference);
        assert_eq!(edge_error_levels(&reference, &reference, &band), 0.0);
        assert_eq!(footprint_error(&reference, &reference, &band), 0.0);
        let shifted = square(12, 4, 9, 1.0);
        let e = edge_error_levels(&shifted, &reference, &band);
        // Flat tops map to control value 1 and background to 0: each changed pixel costs 255.
        let changed = reference.height_mm.iter().zip(&shifted.height_mm).filter(|(a, b)| covered(**a) != covered(**b)).count();
        let n_band = band.iter().filter(|b| **b).count();
        assert!((e - 255.0 * changed as f64 / n_band as f64).abs() < 1e-6, "{e}");
        assert!((footprint_error(&shifted, &reference, &band) - changed as f64 / n_band as f64).abs() < 1e-12);
        assert!(edge_error_levels(&DepthMap::empty(3, 3), &reference, &band).is_nan());
    }
}
