//! What `rig eval --downstream`'s table cannot show by itself: how little a small test set or a
//! single seed says, and which pose components the images cannot show at all.
//!
//! [`ambiguous_components`] looks for them in the data: captured rows whose images are
//! identical (the same pixels at the regressor's input size) while their labels differ in a
//! component. No regressor can tell such rows apart, so that component's scores measure a
//! guess (a sphere's yaw: every yaw gives the same image; a plan spanning 180° of yaw on an
//! object with a two-fold symmetry: two labels for one image). [`warnings`] turns these and
//! the test set's size into the lines the report ends with.

use std::collections::HashMap;
use std::hash::{Hash, Hasher};

/// Fewer held-out rows than this: the report warns that its figures move with the draw.
pub const FEW_TEST_ROWS: usize = 30;

/// One component the images cannot show: rows with identical images and different labels.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Ambiguity {
    /// The component's name ([`crate::eval::downstream::COMPONENTS`]).
    pub component: &'static str,
    /// Captured rows whose image some row with another value of the component shares.
    pub rows: usize,
    /// Captured rows looked at.
    pub of: usize,
    /// Two such rows' pose ids, as an example.
    pub example: (u32, u32),
}

/// The components of `rows` (pose id, label with one value per component of `names`, image
/// pixels) whose labels differ between rows with identical images. Rows are grouped by a hash of their
/// pixels, then compared exactly, so a hash collision joins nothing.
pub fn ambiguous_components<const N: usize>(rows: &[(u32, [f32; N], &[f32])], names: [&'static str; N]) -> Vec<Ambiguity> {
    let mut by_hash: HashMap<u64, Vec<usize>> = HashMap::new();
    for (i, (_, _, pixels)) in rows.iter().enumerate() {
        let mut h = std::collections::hash_map::DefaultHasher::new();
        for p in *pixels {
            p.to_bits().hash(&mut h);
        }
        by_hash.entry(h.finish()).or_default().push(i);
    }
    let mut found: Vec<Option<Ambiguity>> = vec![None; N];
    let mut counted = vec![vec![false; rows.len()]; N];
    for group in by_hash.values().filter(|g| g.len() > 1) {
        for (k, &a) in group.iter().enumerate() {
            for &b in &group[k + 1..] {
                if rows[a].2 != rows[b].2 {
                    continue;
                }
                for (c, slot) in found.iter_mut().enumerate() {
                    // Labels are commanded poses: equal ones are equal to well within this.
                    if (rows[a].1[c] - rows[b].1[c]).abs() <= 1e-3 {
                        continue;
                    }
                    let entry = slot.get_or_insert(Ambiguity {
                        component: names[c],
                        rows: 0,
                        of: rows.len(),
                        example: (rows[a].0.min(rows[b].0), rows[a].0.max(rows[b].0)),
                    });
                    for i in [a, b] {
                        if !counted[c][i] {
                            counted[c][i] = true;
                            entry.rows += 1;
                        }
                    }
                }
            }
        }
    }
    found.into_iter().flatten().collect()
}

/// A table cell over the seeds from their `(mean, sd)`: `mean ± sd`, or the mean alone from
/// one seed (a spread of one value is not 0, it is unknown).
pub fn spread_cell(s: Option<(f64, f64)>, digits: usize, seeds: usize) -> String {
    match s {
        Some((mean, sd)) if seeds > 1 => format!("{:.*} ± {:.*}", digits, mean, digits, sd),
        Some((mean, _)) => format!("{:.*}", digits, mean),
        None => "n/a".into(),
    }
}

/// The sentence on the seeds under the regressor line.
pub fn seeds_sentence(seeds: u32, first: u64) -> String {
    if seeds > 1 {
        format!("Mean ± sd over {seeds} seeds (from {first}).")
    } else {
        format!("One seed ({first}): no spread is shown; --seeds 3 or more gives one.")
    }
}

/// The warnings a report ends with: a test set under [`FEW_TEST_ROWS`] rows, and each
/// component the images cannot show ([`ambiguous_components`]), for each sensor's label, test
/// rows and ambiguities.
pub fn warnings<'a>(sensors: impl IntoIterator<Item = (String, usize, &'a [Ambiguity])>) -> Vec<String> {
    let mut out = Vec::new();
    for (sensor, test_rows, ambiguous) in sensors {
        if test_rows < FEW_TEST_ROWS {
            out.push(format!(
                "warning: {sensor}: {} test rows: MAE and R² from under {FEW_TEST_ROWS} rows move a lot with which rows are drawn \
                 (try another --seed); collect more poses before reading a difference between the sets",
                test_rows
            ));
        }
        for a in ambiguous {
            out.push(format!(
                "warning: {sensor}: {}: {} of {} captured rows share an identical image with a row of another {} \
                 (e.g. pose_id {} and {}): the images cannot show it (a symmetric object, or a plan spanning a symmetry), \
                 so its scores measure a guess, not the fill",
                a.component, a.rows, a.of, a.component, a.example.0, a.example.1
            ));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    const NAMES: [&str; 3] = ["X", "Z", "yaw"];

    #[test]
    fn identical_images_under_different_labels_make_a_component_ambiguous() {
        let (disc, ring, other) = (vec![0.5f32; 12], vec![0.25f32; 12], vec![0.75f32; 12]);
        // A sphere: poses 1 and 2 differ only in yaw and give one image; pose 3 is elsewhere.
        let rows = [(1, [0.0, -1.0, 0.0], &disc[..]), (2, [0.0, -1.0, 90.0], &disc[..]), (3, [2.0, -1.5, 0.0], &ring[..])];
        let found = ambiguous_components(&rows, NAMES);
        assert_eq!(found, vec![Ambiguity { component: "yaw", rows: 2, of: 3, example: (1, 2) }]);
        // The same image at the same label twice (a resumed duplicate) is no ambiguity.
        let same = [(1, [0.0, -1.0, 0.0], &disc[..]), (2, [0.0, -1.0, 0.0], &disc[..]), (3, [1.0, -1.0, 0.0], &other[..])];
        assert!(ambiguous_components(&same, NAMES).is_empty());
        // X and yaw both, counted per row once.
        let both = [
            (5, [0.0, -1.0, 0.0], &disc[..]),
            (6, [1.0, -1.0, 45.0], &disc[..]),
            (7, [2.0, -1.0, 45.0], &disc[..]),
            (8, [0.0, 0.0, 0.0], &ring[..]),
        ];
        let found = ambiguous_components(&both, NAMES);
        assert_eq!(found.iter().map(|a| (a.component, a.rows)).collect::<Vec<_>>(), vec![("X", 3), ("yaw", 3)]);
    }

    #[test]
    fn one_seed_shows_no_spread() {
        assert_eq!(spread_cell(Some((0.1234, 0.0)), 3, 1), "0.123");
        assert_eq!(spread_cell(Some((0.1234, 0.02)), 3, 3), "0.123 ± 0.020");
        assert_eq!(spread_cell(None, 3, 3), "n/a");
        assert!(seeds_sentence(1, 1).starts_with("One seed (1): no spread"));
        assert_eq!(seeds_sentence(3, 1), "Mean ± sd over 3 seeds (from 1).");
    }
}
