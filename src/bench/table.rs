//! A knob's measurements as a table ([`KnobReport`]), and the summaries the knobs share.

use super::knob::Knob;
use super::plot::Plot;

/// How a table column is printed.
#[derive(Debug, Clone, PartialEq)]
pub struct Column {
    pub name: String,
    /// Digits after the decimal point.
    pub decimals: usize,
}

impl Column {
    pub fn new(name: &str, decimals: usize) -> Self {
        Self { name: name.to_string(), decimals }
    }
}

/// One table row: a label and one number per [`Column`] (NaN prints as `n/a`).
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    pub label: String,
    pub values: Vec<f64>,
}

/// The measurements of one knob.
#[derive(Debug, Clone, PartialEq)]
pub struct KnobReport {
    pub knob: Knob,
    pub title: String,
    /// Header of the label column.
    pub label_column: String,
    pub columns: Vec<Column>,
    pub rows: Vec<Row>,
    /// Markdown lines: what was measured, how, and what to read from it.
    pub notes: Vec<String>,
    pub plot: Plot,
}

impl KnobReport {
    /// The table as Markdown.
    pub fn markdown_table(&self) -> String {
        let mut out = format!("| {} |", self.label_column);
        for c in &self.columns {
            out.push_str(&format!(" {} |", c.name));
        }
        out.push_str("\n|---|");
        for _ in &self.columns {
            out.push_str("---:|");
        }
        out.push('\n');
        for row in &self.rows {
            out.push_str(&format!("| {} |", row.label));
            for (c, v) in self.columns.iter().zip(&row.values) {
                if v.is_finite() {
                    out.push_str(&format!(" {:.*} |", c.decimals, v));
                } else {
                    out.push_str(" n/a |");
                }
            }
            out.push('\n');
        }
        out
    }
}

/// Mean of a slice (NaN when empty).
pub(crate) fn mean(v: &[f64]) -> f64 {
    if v.is_empty() { f64::NAN } else { v.iter().sum::<f64>() / v.len() as f64 }
}

/// Smallest value of a slice (NaN when empty): the timing least disturbed by other load.
pub(crate) fn fastest(v: &[f64]) -> f64 {
    v.iter().copied().fold(f64::NAN, f64::min)
}
