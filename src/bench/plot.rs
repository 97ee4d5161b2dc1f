//! Accuracy-against-time scatter plots, written as SVG with `plotters` (built without default
//! features: the SVG backend and the line and point series only).
//!
//! A [`Plot`] holds named series of `(x, y)` points, each point with an optional label drawn
//! beside it (e.g. `20 steps`). Points with a non-finite coordinate are left out. The axes
//! span the finite points with a margin.

use std::path::Path;

use plotters::prelude::*;

use super::error::BenchError;

/// One series: a name for the legend, points and their labels.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Series {
    pub name: String,
    pub points: Vec<[f64; 2]>,
    /// One label per point (empty strings draw nothing); may be shorter than `points`.
    pub labels: Vec<String>,
}

/// A scatter plot, points of a series joined in order when `lines` is set.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Plot {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub series: Vec<Series>,
    pub lines: bool,
}

/// Range of the finite values with 8 % of margin on each side (a unit range around a
/// single value; `0..1` when there is none).
pub fn padded_range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = values.filter(|v| v.is_finite()).fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| (lo.min(v), hi.max(v)));
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    let span = hi - lo;
    let pad = if span > 0.0 { span * 0.08 } else { lo.abs().max(1.0) * 0.5 };
    (lo - pad, hi + pad)
}

/// Writes `plot` to `path` as an 860 x 520 SVG.
pub fn write_svg(plot: &Plot, path: &Path) -> Result<(), BenchError> {
    draw(plot, path).map_err(|reason| BenchError::Plot { path: path.to_path_buf(), reason })
}

fn draw(plot: &Plot, path: &Path) -> Result<(), String> {
    let finite = |p: &&[f64; 2]| p[0].is_finite() && p[1].is_finite();
    let all: Vec<[f64; 2]> = plot.series.iter().flat_map(|s| s.points.iter().filter(finite).copied()).collect();
    let (x0, x1) = padded_range(all.iter().map(|p| p[0]));
    let (y0, y1) = padded_range(all.iter().map(|p| p[1]));
    let root = SVGBackend::new(path, (860, 520)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let mut chart = ChartBuilder::on(&root)
        .caption(&plot.title, ("sans-serif", 26))
        .margin(16)
        .x_label_area_size(46)
        .y_label_area_size(70)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(|e| e.to_string())?;
    chart
        .configure_mesh()
        .x_desc(plot.x_label.as_str())
        .y_desc(plot.y_label.as_str())
        .axis_desc_style(("sans-serif", 18))
        .label_style(("sans-serif", 15))
        .light_line_style(WHITE.mix(0.0))
        .draw()
        .map_err(|e| e.to_string())?;
    for (i, s) in plot.series.iter().enumerate() {
        let colour = Palette99::pick(i).to_rgba();
        let pts: Vec<(f64, f64)> = s.points.iter().filter(finite).map(|p| (p[0], p[1])).collect();
        if plot.lines && pts.len() > 1 {
            chart.draw_series(LineSeries::new(pts.clone(), colour.stroke_width(2))).map_err(|e| e.to_string())?;
        }
        let labelled: Vec<((f64, f64), String)> = s
            .points
            .iter()
            .enumerate()
            .filter(|(_, p)| finite(p))
            .map(|(k, p)| ((p[0], p[1]), s.labels.get(k).cloned().unwrap_or_default()))
            .collect();
        chart
            .draw_series(labelled.into_iter().map(|(c, label)| {
                EmptyElement::at(c) + Circle::new((0, 0), 4, colour.filled()) + Text::new(label, (6, -16), ("sans-serif", 15))
            }))
            .map_err(|e| e.to_string())?
            .label(s.name.as_str())
            .legend(move |(x, y)| Circle::new((x + 8, y), 4, colour.filled()));
    }
    if plot.series.iter().any(|s| !s.name.is_empty()) {
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", 15))
            .position(SeriesLabelPosition::UpperRight)
            .draw()
            .map_err(|e| e.to_string())?;
    }
    root.present().map_err(|e| e.to_string())?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn range_pads_and_ignores_nan() {
        let (lo, hi) = padded_range([1.0, f64::NAN, 3.0].into_iter());
        assert!((lo - 0.84).abs() < 1e-9 && (hi - 3.16).abs() < 1e-9, "{lo} {hi}");
        assert_eq!(padded_range(std::iter::empty()), (0.0, 1.0));
        let (lo, hi) = padded_range([2.0].into_iter());
        assert!(lo < 2.0 && hi > 2.0);
    }
}
