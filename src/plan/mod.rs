//! Pose plans: which contact poses a collection visits, and in which order.
//!
//! Data flow: a [`PlanSpec`] (read from TOML or built from CLI flags) is validated once, then
//! [`PlanSpec::grid`] enumerates the regular grid of work-frame poses it spans, each with a
//! stable `pose_id`, and [`PlanSpec::build`] samples `n_poses` of them ([`Sampling`]) and
//! orders them ([`Order`]) into a [`Plan`], reporting the total motion time before and after
//! ordering under the arm's motion-time model (passed in as a cost function).
//!
//! # Stable pose ids
//!
//! The grid is the Cartesian product of four axes, each `min, min + step, ..., <= max`
//! (`n_x, n_y, n_z, n_yaw` values; `max` itself is included when `max - min` is a whole
//! number of steps). A grid point with axis indices `(ix, iy, iz, iyaw)` has the mixed-radix
//! index
//!
//! ```text
//! pose_id = ((ix * n_y + iy) * n_z + iz) * n_yaw + iyaw
//! ```
//!
//! so x is the most significant digit and yaw the least. The id depends only on the ranges
//! and steps, never on sampling, seed or order: a later `rig synth --fill-missing` recomputes
//! the grid from the manifest's plan and knows exactly which ids were not collected.
//!
//! # Ordering
//!
//! [`Order::Optimised`] is one method from 10 to 10^6 poses, O(n log n) in time and O(n) in
//! memory (`order`): candidate neighbours from a k-d tree over the poses under a metric that
//! approximates the motion-time model, a nearest-neighbour path through it, then 2-opt and
//! Or-opt moves over the candidates with the model itself deciding every move (the path is
//! open: it is closed through a zero-cost virtual node so the cyclic moves apply). 2-opt
//! assumes the cost is symmetric, which holds for trapezoidal per-axis motion models; the
//! reported totals always use the directed cost. [`reference_order`] is the quadratic
//! algorithm it replaced, kept as the yardstick of tests and benchmarks.
//!
//! A collection orders its plan once and keeps the order with each dataset
//! ([`crate::dataset::order`]); resuming reads it back instead of ordering again.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use rand::seq::SliceRandom;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::pose::Pose;

pub mod adaptive;
mod kdtree;
mod order;
#[allow(unused_imports, reason = "the fuzz targets compile this module into a binary, where the library's re-export has no user")]
pub use order::{MAX_EXAMINATIONS_PER_SITE, MAX_REVERSAL};

/// Largest grid rig enumerates. Filling a dataset and sampling a plan hold a list of grid
/// poses (40 bytes each), so this bounds what a plan, or a dataset's manifest, can make rig
/// allocate: 1 000 000 points is 40 MB, and over a hundred times the default grid (7865).
pub const MAX_GRID_POINTS: u64 = 1_000_000;

/// One axis of the grid: values `min, min + step, ...` up to and including `max`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AxisRange {
    pub min: f64,
    pub max: f64,
    pub step: f64,
}

impl AxisRange {
    pub const fn new(min: f64, max: f64, step: f64) -> Self {
        Self { min, max, step }
    }

    /// Number of grid values on this axis (assumes a validated range).
    pub fn count(&self) -> u64 {
        // The small slack keeps `max` when (max - min) / step is whole but not exact in f64.
        ((self.max - self.min) / self.step + 1e-9).floor() as u64 + 1
    }

    /// The `i`-th value, rounded to 1e-9 so steps like 0.1 do not print as 0.30000000000000004.
    pub fn value(&self, i: u64) -> f64 {
        let v = self.min + i as f64 * self.step;
        (v * 1e9).round() / 1e9
    }
}

/// Error parsing an axis written `min:max:step`, a sampling or an order name.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PlanParseError {
    #[error("an axis range is written min:max:step (e.g. -5:5:1); got {text:?}")]
    Axis { text: String },
    #[error("unknown {what} {text:?}; expected one of {expected}")]
    Name { what: &'static str, text: String, expected: &'static str },
}

impl std::str::FromStr for AxisRange {
    type Err = PlanParseError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let err = || PlanParseError::Axis { text: s.to_string() };
        let parts: Vec<f64> = s.split(':').map(|p| p.trim().parse::<f64>()).collect::<Result<_, _>>().map_err(|_| err())?;
        match parts[..] {
            [min, max, step] => Ok(AxisRange::new(min, max, step)),
            _ => Err(err()),
        }
    }
}

impl std::str::FromStr for Sampling {
    type Err = PlanParseError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "full" => Ok(Sampling::Full),
            "random" => Ok(Sampling::Random),
            "lhs" | "latin-hypercube" => Ok(Sampling::Lhs),
            _ => Err(PlanParseError::Name { what: "sampling", text: s.to_string(), expected: "full, random, lhs" }),
        }
    }
}

impl std::str::FromStr for Order {
    type Err = PlanParseError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "as-sampled" => Ok(Order::AsSampled),
            "random" => Ok(Order::Random),
            "optimised" | "optimized" => Ok(Order::Optimised),
            _ => Err(PlanParseError::Name { what: "order", text: s.to_string(), expected: "as-sampled, random, optimised" }),
        }
    }
}

/// How the poses of a plan are drawn from the grid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Sampling {
    /// Every grid point (`n_poses` must be absent).
    Full,
    /// `n_poses` distinct grid points, uniformly at random.
    Random,
    /// `n_poses` distinct grid points by Latin hypercube: each axis's range is cut into
    /// `n_poses` equal strata and each stratum is used exactly once per axis; points that land
    /// on an already chosen grid point move to the nearest free one.
    Lhs,
}

/// The order in which the sampled poses are visited.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Order {
    /// The sampler's order (grid order for `full`).
    AsSampled,
    /// A seeded shuffle.
    Random,
    /// Nearest neighbour plus 2-opt over the motion-time model.
    Optimised,
}

impl std::fmt::Display for Sampling {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Sampling::Full => "full",
            Sampling::Random => "random",
            Sampling::Lhs => "lhs",
        })
    }
}

impl std::fmt::Display for Order {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Order::AsSampled => "as-sampled",
            Order::Random => "random",
            Order::Optimised => "optimised",
        })
    }
}

/// A plan as written in a TOML file (see `plans/default.toml`). Poses are in the work frame:
/// x, y offsets from the contact point, z extra indentation, yaw relative to the frame's yaw.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlanSpec {
    pub x_mm: AxisRange,
    pub y_mm: AxisRange,
    pub z_mm: AxisRange,
    pub yaw_deg: AxisRange,
    pub sampling: Sampling,
    /// How many poses to sample; required for `random` and `lhs`, absent for `full`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub n_poses: Option<usize>,
    /// Seed of the sampler and of the random order.
    #[serde(default)]
    pub seed: u64,
    pub order: Order,
}

impl Default for PlanSpec {
    /// The MultiDiffSense ranges (x, y in [-5, 5] mm, z in [-1, 1] mm, yaw in [-90, 90] deg) on
    /// a 1 mm / 0.5 mm / 15 deg grid (7865 points), 500 poses by Latin hypercube, optimised order.
    fn default() -> Self {
        Self {
            x_mm: AxisRange::new(-5.0, 5.0, 1.0),
            y_mm: AxisRange::new(-5.0, 5.0, 1.0),
            z_mm: AxisRange::new(-1.0, 1.0, 0.5),
            yaw_deg: AxisRange::new(-90.0, 90.0, 15.0),
            sampling: Sampling::Lhs,
            n_poses: Some(500),
            seed: 0,
            order: Order::Optimised,
        }
    }
}

/// Errors reading or validating a plan.
#[derive(Debug, thiserror::Error)]
pub enum PlanError {
    #[error("plan axis {axis}: {field} is not a finite number ({value})")]
    NotFinite { axis: &'static str, field: &'static str, value: f64 },
    #[error("plan axis {axis}: empty range, min {min} > max {max}")]
    EmptyRange { axis: &'static str, min: f64, max: f64 },
    #[error("plan axis {axis}: step must be positive, got {step}")]
    BadStep { axis: &'static str, step: f64 },
    #[error("plan grid has {points} points, more than the {max} rig enumerates; use larger steps")]
    GridTooLarge { points: u128, max: u64 },
    #[error("plan asks for {requested} poses but the grid has only {grid} points")]
    TooManyPoses { requested: usize, grid: u64 },
    #[error("plan sampling `{sampling}` needs n_poses")]
    MissingCount { sampling: Sampling },
    #[error("plan sampling `full` takes every grid point; remove n_poses ({n_poses})")]
    CountWithFull { n_poses: usize },
    #[error("plan asks for 0 poses")]
    ZeroPoses,
    #[error("cannot read plan {path}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("plan {path} is not a valid plan")]
    Parse {
        path: PathBuf,
        #[source]
        source: crate::untrusted::SyntaxError,
    },
}

/// The dotted name of the key set on 1-based `line` of a TOML `text` (`x_mm.step` inside
/// `[x_mm]`), when the key and its table are plain names (letters, digits, `_`, `-`, at most
/// 64 characters): a typo's own name, without echoing anything else the file holds.
fn key_on_line(text: &str, line: usize) -> Option<String> {
    let plain = |s: &str| {
        let s = s.trim();
        (!s.is_empty() && s.len() <= 64 && s.chars().all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')).then(|| s.to_string())
    };
    let lines: Vec<&str> = text.lines().collect();
    let here = lines.get(line.checked_sub(1)?)?;
    let key = plain(here.split_once('=')?.0)?;
    let table = lines[..line - 1]
        .iter()
        .rev()
        .find_map(|l| l.trim().strip_prefix('[').and_then(|l| l.split_once(']')).map(|(name, _)| plain(name)))
        .flatten();
    Some(match table {
        Some(table) => format!("{table}.{key}"),
        None => key,
    })
}

/// One pose of a plan: its stable grid id and its work-frame pose.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PlannedPose {
    pub pose_id: u32,
    pub pose: Pose,
}

/// A sampled and ordered plan, with the total motion time (sum of the cost between
/// consecutive poses) of the sampler's order and of the final order.
#[derive(Debug, Clone, PartialEq)]
pub struct Plan {
    pub poses: Vec<PlannedPose>,
    pub motion_time_before_s: f64,
    pub motion_time_after_s: f64,
}

impl PlanSpec {
    /// Reads and validates a TOML plan file.
    pub fn load(path: &Path) -> Result<Self, PlanError> {
        let text = crate::untrusted::read_text(path, crate::untrusted::MAX_CONFIG_BYTES)
            .map_err(|source| PlanError::Io { path: path.to_path_buf(), source })?;
        let spec = Self::from_toml_str(&text).map_err(|e| {
            let mut source = crate::untrusted::SyntaxError::from_toml(&e, &text);
            // Name the key the error is on (`x_mm.stp`, `samplng`): a plan's own schema words,
            // never a value from the file.
            if let Some(key) = key_on_line(&text, source.line) {
                source.reason = format!("{} (key `{key}`)", source.reason);
            }
            PlanError::Parse { path: path.to_path_buf(), source }
        })?;
        spec.validate()?;
        Ok(spec)
    }

    /// Parses TOML without validating.
    pub fn from_toml_str(text: &str) -> Result<Self, toml::de::Error> {
        toml::from_str(text)
    }

    fn axes(&self) -> [(&'static str, &AxisRange); 4] {
        [("x_mm", &self.x_mm), ("y_mm", &self.y_mm), ("z_mm", &self.z_mm), ("yaw_deg", &self.yaw_deg)]
    }

    /// Checks ranges, steps, grid size and the pose count.
    pub fn validate(&self) -> Result<(), PlanError> {
        let mut points: u128 = 1;
        for (axis, r) in self.axes() {
            for (field, value) in [("min", r.min), ("max", r.max), ("step", r.step)] {
                if !value.is_finite() {
                    return Err(PlanError::NotFinite { axis, field, value });
                }
            }
            if r.min > r.max {
                return Err(PlanError::EmptyRange { axis, min: r.min, max: r.max });
            }
            if r.step <= 0.0 {
                return Err(PlanError::BadStep { axis, step: r.step });
            }
            let per_axis = ((r.max - r.min) / r.step + 1e-9).floor();
            if per_axis >= MAX_GRID_POINTS as f64 {
                return Err(PlanError::GridTooLarge { points: u128::MAX, max: MAX_GRID_POINTS });
            }
            points *= per_axis as u128 + 1;
        }
        if points > MAX_GRID_POINTS as u128 {
            return Err(PlanError::GridTooLarge { points, max: MAX_GRID_POINTS });
        }
        let grid = points as u64;
        match (self.sampling, self.n_poses) {
            (Sampling::Full, Some(n_poses)) => Err(PlanError::CountWithFull { n_poses }),
            (Sampling::Full, None) => Ok(()),
            (sampling, None) => Err(PlanError::MissingCount { sampling }),
            (_, Some(0)) => Err(PlanError::ZeroPoses),
            (_, Some(n)) if n as u64 > grid => Err(PlanError::TooManyPoses { requested: n, grid }),
            (_, Some(_)) => Ok(()),
        }
    }

    /// Values per axis `[n_x, n_y, n_z, n_yaw]` (assumes a validated spec).
    pub fn axis_counts(&self) -> [u64; 4] {
        [self.x_mm.count(), self.y_mm.count(), self.z_mm.count(), self.yaw_deg.count()]
    }

    /// Number of grid points (assumes a validated spec).
    pub fn grid_len(&self) -> u64 {
        self.axis_counts().iter().product()
    }

    /// How many poses [`build`](Self::build) returns.
    pub fn planned_len(&self) -> u64 {
        match self.sampling {
            Sampling::Full => self.grid_len(),
            _ => self.n_poses.unwrap_or(0) as u64,
        }
    }

    fn indices_of(&self, pose_id: u32) -> [u64; 4] {
        let [_, ny, nz, nyaw] = self.axis_counts();
        let mut rest = pose_id as u64;
        let iyaw = rest % nyaw;
        rest /= nyaw;
        let iz = rest % nz;
        rest /= nz;
        let iy = rest % ny;
        let ix = rest / ny;
        [ix, iy, iz, iyaw]
    }

    fn id_of(&self, idx: [u64; 4]) -> u32 {
        let [_, ny, nz, nyaw] = self.axis_counts();
        (((idx[0] * ny + idx[1]) * nz + idx[2]) * nyaw + idx[3]) as u32
    }

    /// The work-frame pose of a grid id, `None` outside the grid.
    pub fn pose_of(&self, pose_id: u32) -> Option<Pose> {
        if pose_id as u64 >= self.grid_len() {
            return None;
        }
        let [ix, iy, iz, iyaw] = self.indices_of(pose_id);
        Some(Pose::new(self.x_mm.value(ix), self.y_mm.value(iy), self.z_mm.value(iz), self.yaw_deg.value(iyaw)))
    }

    /// The grid id of a pose lying on the grid (within `tol` of a grid value on every axis,
    /// in the axis's own unit); `None` when it is off the grid.
    pub fn pose_id_of(&self, pose: &Pose, tol: f64) -> Option<u32> {
        let comps = [pose.x_mm, pose.y_mm, pose.z_mm, pose.yaw_deg];
        let mut idx = [0u64; 4];
        for (k, (_, r)) in self.axes().into_iter().enumerate() {
            let f = (comps[k] - r.min) / r.step;
            if !f.is_finite() {
                return None;
            }
            let i = f.round();
            if i < 0.0 || i >= r.count() as f64 || (r.value(i as u64) - comps[k]).abs() > tol {
                return None;
            }
            idx[k] = i as u64;
        }
        Some(self.id_of(idx))
    }

    /// Every grid point in `pose_id` order (assumes a validated spec).
    pub fn grid(&self) -> Vec<PlannedPose> {
        (0..self.grid_len() as u32).filter_map(|pose_id| self.pose_of(pose_id).map(|pose| PlannedPose { pose_id, pose })).collect()
    }

    /// Validates, samples and orders. `cost(a, b)` is the motion time in seconds from pose `a`
    /// to pose `b` (work frame), e.g. the firmware profile's motion-time model.
    pub fn build(&self, cost: &dyn Fn(&Pose, &Pose) -> f64) -> Result<Plan, PlanError> {
        let sampled = self.sample()?;
        Ok(self.order_sampled(sampled, cost))
    }

    /// Validates and samples: the plan's poses in the sampler's order, not ordered yet. O(n)
    /// (and one flag per grid point for Latin hypercube sampling).
    pub fn sample(&self) -> Result<Vec<PlannedPose>, PlanError> {
        self.validate()?;
        Ok(self.sample_ids().into_iter().filter_map(|pose_id| self.pose_of(pose_id).map(|pose| PlannedPose { pose_id, pose })).collect())
    }

    /// Orders [`sample`](Self::sample)'s poses as the spec's `order` says.
    pub fn order_sampled(&self, sampled: Vec<PlannedPose>, cost: &dyn Fn(&Pose, &Pose) -> f64) -> Plan {
        order_poses(sampled, self.order, self.seed, cost)
    }

    fn sample_ids(&self) -> Vec<u32> {
        let grid = self.grid_len();
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed);
        match self.sampling {
            Sampling::Full => (0..grid as u32).collect(),
            Sampling::Random => {
                let n = self.n_poses.unwrap_or(0);
                rand::seq::index::sample(&mut rng, grid as usize, n).into_iter().map(|i| i as u32).collect()
            }
            Sampling::Lhs => self.sample_lhs(&mut rng),
        }
    }

    fn sample_lhs(&self, rng: &mut ChaCha8Rng) -> Vec<u32> {
        let n = self.n_poses.unwrap_or(0);
        let counts = self.axis_counts();
        // One stratum permutation per axis; point k takes stratum perm[a][k] on axis a.
        let mut strata: Vec<Vec<usize>> = Vec::with_capacity(4);
        for _ in 0..4 {
            let mut perm: Vec<usize> = (0..n).collect();
            perm.shuffle(rng);
            strata.push(perm);
        }
        let mut used = vec![false; self.grid_len() as usize];
        let mut ids = Vec::with_capacity(n);
        for k in 0..n {
            let mut idx = [0u64; 4];
            for (a, perm) in strata.iter().enumerate() {
                let u = (perm[k] as f64 + rng.random::<f64>()) / n as f64;
                idx[a] = ((u * counts[a] as f64).floor() as u64).min(counts[a] - 1);
            }
            let mut id = self.id_of(idx);
            if used[id as usize] {
                id = self.nearest_free(idx, &used);
            }
            used[id as usize] = true;
            ids.push(id);
        }
        ids
    }

    /// A free grid point near `idx`: the nearest (index space normalised by the axis counts,
    /// ties to the lowest id) within the box of half-width [`LHS_LOCAL_RADIUS`] grid steps, or
    /// the nearest in the whole grid when that box is full. Only collisions call it.
    fn nearest_free(&self, idx: [u64; 4], used: &[bool]) -> u32 {
        let counts = self.axis_counts();
        let dist = |other: [u64; 4]| -> f64 { (0..4).map(|a| ((other[a] as f64 - idx[a] as f64) / counts[a] as f64).powi(2)).sum() };
        let mut best = (f64::INFINITY, u32::MAX);
        let consider = |other: [u64; 4], best: &mut (f64, u32)| {
            let id = self.id_of(other);
            if !used[id as usize] {
                let d = dist(other);
                if d < best.0 || (d == best.0 && id < best.1) {
                    *best = (d, id);
                }
            }
        };
        let r = LHS_LOCAL_RADIUS;
        let lo: Vec<u64> = (0..4).map(|a| idx[a].saturating_sub(r)).collect();
        let hi: Vec<u64> = (0..4).map(|a| (idx[a] + r).min(counts[a] - 1)).collect();
        for i0 in lo[0]..=hi[0] {
            for i1 in lo[1]..=hi[1] {
                for i2 in lo[2]..=hi[2] {
                    for i3 in lo[3]..=hi[3] {
                        consider([i0, i1, i2, i3], &mut best);
                    }
                }
            }
        }
        if best.1 == u32::MAX {
            for id in (0..used.len()).filter(|&id| !used[id]) {
                consider(self.indices_of(id as u32), &mut best);
            }
        }
        best.1
    }
}

/// Half-width, in grid steps, of the box searched first for a free point after an LHS
/// collision (a 7^4 box: cheap, and almost always holds one).
const LHS_LOCAL_RADIUS: u64 = 3;

fn derived_seed(seed: u64, stream: u64) -> u64 {
    seed ^ stream.wrapping_mul(0x9E37_79B9_7F4A_7C15)
}

/// Total motion time of visiting `poses` in order (sum over consecutive pairs), seconds.
pub fn path_cost(poses: &[PlannedPose], cost: &dyn Fn(&Pose, &Pose) -> f64) -> f64 {
    poses.windows(2).map(|w| cost(&w[0].pose, &w[1].pose)).sum()
}

/// `sampled` (a sampler's poses) in `order`; `seed` is the plan's (it seeds the random order).
pub fn order_poses(sampled: Vec<PlannedPose>, order: Order, seed: u64, cost: &dyn Fn(&Pose, &Pose) -> f64) -> Plan {
    let motion_time_before_s = path_cost(&sampled, cost);
    let poses = match order {
        Order::AsSampled => sampled,
        Order::Random => {
            let mut rng = ChaCha8Rng::seed_from_u64(derived_seed(seed, 1));
            let mut v = sampled;
            v.shuffle(&mut rng);
            v
        }
        Order::Optimised => {
            let ordered = permuted(&sampled, order::optimise(&plain_poses(&sampled), cost));
            // Never hand back a worse order than the sampler's (possible only with
            // strongly asymmetric costs, which 2-opt does not model).
            if path_cost(&ordered, cost) <= motion_time_before_s { ordered } else { sampled }
        }
    };
    let motion_time_after_s = path_cost(&poses, cost);
    Plan { poses, motion_time_before_s, motion_time_after_s }
}

/// The order `order` replaced: nearest neighbour by a full scan and 2-opt over exact 16-nearest
/// lists, quadratic in time and memory. The yardstick of tests and benchmarks
/// (`cargo bench --bench plan_order`); no command of rig uses it.
pub fn reference_order(poses: &[PlannedPose], cost: &dyn Fn(&Pose, &Pose) -> f64) -> Vec<PlannedPose> {
    permuted(poses, order::reference(&plain_poses(poses), cost))
}

fn plain_poses(poses: &[PlannedPose]) -> Vec<Pose> {
    poses.iter().map(|p| p.pose).collect()
}

/// `poses` in the order of `permutation` (indices into `poses`).
fn permuted(poses: &[PlannedPose], permutation: Vec<u32>) -> Vec<PlannedPose> {
    permutation.into_iter().map(|i| poses[i as usize]).collect()
}

/// Why a kept order (a list of pose ids) is not an order of a plan's poses.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum OrderMismatch {
    #[error("it lists {kept} poses, the plan has {planned}")]
    Count { kept: usize, planned: usize },
    #[error("it lists pose {pose_id}, which is not one of the plan's")]
    NotPlanned { pose_id: u32 },
    #[error("it lists pose {pose_id} twice")]
    Repeated { pose_id: u32 },
}

/// `sampled` (a sampler's poses) in the order of `ids`, which must list every one of them
/// exactly once: a kept order read back instead of ordering again. O(n log n), no cost
/// evaluated but the two totals' (O(n)).
pub fn in_kept_order(sampled: Vec<PlannedPose>, ids: &[u32], cost: &dyn Fn(&Pose, &Pose) -> f64) -> Result<Plan, OrderMismatch> {
    if ids.len() != sampled.len() {
        return Err(OrderMismatch::Count { kept: ids.len(), planned: sampled.len() });
    }
    let mut by_id: Vec<(u32, u32)> = sampled.iter().enumerate().map(|(i, p)| (p.pose_id, i as u32)).collect();
    by_id.sort_unstable();
    let mut taken = vec![false; sampled.len()];
    let mut poses = Vec::with_capacity(sampled.len());
    for &pose_id in ids {
        let at = by_id.binary_search_by_key(&pose_id, |&(id, _)| id).map_err(|_| OrderMismatch::NotPlanned { pose_id })?;
        let i = by_id[at].1 as usize;
        if std::mem::replace(&mut taken[i], true) {
            return Err(OrderMismatch::Repeated { pose_id });
        }
        poses.push(sampled[i]);
    }
    let motion_time_before_s = path_cost(&sampled, cost);
    let motion_time_after_s = path_cost(&poses, cost);
    Ok(Plan { poses, motion_time_before_s, motion_time_after_s })
}

/// A simple motion-time model: every axis moves at once with a trapezoidal velocity profile,
/// the slowest axis sets the travel time, and each pose adds a constant for the descent,
/// press and retract. Stand-in for the firmware profile's model in `rig plan show`, tests and
/// benchmarks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrapezoidMotionModel {
    pub speed_mm_s: f64,
    pub accel_mm_s2: f64,
    pub yaw_speed_deg_s: f64,
    pub yaw_accel_deg_s2: f64,
    /// Time per pose for approach-descend-press-retract, s (order-independent).
    pub per_pose_s: f64,
}

impl Default for TrapezoidMotionModel {
    /// 100 mm/s, 1000 mm/s^2, 180 deg/s, 720 deg/s^2; 0.4 s per pose (two 10 mm moves).
    fn default() -> Self {
        Self { speed_mm_s: 100.0, accel_mm_s2: 1000.0, yaw_speed_deg_s: 180.0, yaw_accel_deg_s2: 720.0, per_pose_s: 0.4 }
    }
}

fn trapezoid_s(dist: f64, v: f64, a: f64) -> f64 {
    let dist = dist.abs();
    if dist * a < v * v { 2.0 * (dist / a).sqrt() } else { dist / v + v / a }
}

impl TrapezoidMotionModel {
    /// Time from `from` to `to` (work frame) including the per-pose constant, s.
    pub fn time_s(&self, from: &Pose, to: &Pose) -> f64 {
        let lin = [to.x_mm - from.x_mm, to.y_mm - from.y_mm, to.z_mm - from.z_mm]
            .into_iter()
            .map(|dx| trapezoid_s(dx, self.speed_mm_s, self.accel_mm_s2))
            .fold(0.0, f64::max);
        // Raw difference, not wrapped: the wrist turns through the angle, joint limits forbid
        // the short way round.
        let yaw = trapezoid_s(to.yaw_deg - from.yaw_deg, self.yaw_speed_deg_s, self.yaw_accel_deg_s2);
        self.per_pose_s + lin.max(yaw)
    }
}

impl PlanSpec {
    /// Grid points whose id is not in `done`, in `pose_id` order: what
    /// `rig synth --fill-missing` has to produce (assumes a validated spec).
    pub fn missing(&self, done: &BTreeSet<u32>) -> Vec<PlannedPose> {
        self.grid().into_iter().filter(|p| !done.contains(&p.pose_id)).collect()
    }
}

/// Shard `index` of `count` (0-based): every `count`-th pose starting at position `index`, so
/// shards are disjoint, cover all poses, and differ in size by at most one. Empty when
/// `index >= count`.
pub fn shard(poses: &[PlannedPose], index: usize, count: usize) -> Vec<PlannedPose> {
    if count == 0 || index >= count {
        return Vec::new();
    }
    poses.iter().skip(index).step_by(count).copied().collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn model() -> impl Fn(&Pose, &Pose) -> f64 {
        let m = TrapezoidMotionModel::default();
        move |a: &Pose, b: &Pose| m.time_s(a, b)
    }

    /// A typo in a plan file names the key it is on (its table too), never the value.
    #[test]
    fn plan_typos_name_their_key() {
        let dir = tempfile::tempdir().expect("temp dir");
        let good = "sampling = \"full\"\norder = \"optimised\"\n[x_mm]\nmin = 0\nmax = 1\nstep = 1\n[y_mm]\nmin = 0\nmax = 1\nstep = 1\n\
                    [z_mm]\nmin = 0\nmax = 1\nstep = 1\n[yaw_deg]\nmin = 0\nmax = 1\nstep = 1\n";
        let path = dir.path().join("plan.toml");
        std::fs::write(&path, good).expect("write");
        PlanSpec::load(&path).expect("the plan without typos loads");
        for (typo, key, hidden) in [
            (good.replace("sampling = \"full\"", "samplng = \"full\""), "`samplng`", "\"full\""),
            (good.replace("sampling = \"full\"", "sampling = \"randm-secret\""), "`sampling`", "randm-secret"),
            (good.replacen("step = 1\n[y_mm]", "stp = 1\n[y_mm]", 1), "`x_mm.stp`", "stp = 1"),
        ] {
            std::fs::write(&path, &typo).expect("write");
            let err = PlanSpec::load(&path).expect_err("a typo");
            let text = format!("{err}: {}", std::error::Error::source(&err).map(|s| s.to_string()).unwrap_or_default());
            assert!(text.contains(&format!("(key {key})")), "{key} not named: {text}");
            assert!(!text.contains(hidden), "the file's value was echoed: {text}");
        }
    }

    #[test]
    fn default_grid_size_and_ids() {
        let s = PlanSpec::default();
        s.validate().unwrap();
        assert_eq!(s.axis_counts(), [11, 11, 5, 13]);
        assert_eq!(s.grid_len(), 7865);
        let g = s.grid();
        assert_eq!(g[0].pose, Pose::new(-5.0, -5.0, -1.0, -90.0));
        assert_eq!(g[1].pose, Pose::new(-5.0, -5.0, -1.0, -75.0));
        assert_eq!(g[13].pose, Pose::new(-5.0, -5.0, -0.5, -90.0));
        assert_eq!(g[7864].pose, Pose::new(5.0, 5.0, 1.0, 90.0));
        for p in &g {
            assert_eq!(s.pose_id_of(&p.pose, 1e-6), Some(p.pose_id));
        }
        assert_eq!(s.pose_id_of(&Pose::new(0.5, 0.0, 0.0, 0.0), 1e-6), None);
    }

    #[test]
    fn validation_errors() {
        let mut s = PlanSpec::default();
        s.x_mm.step = 0.0;
        assert!(matches!(s.validate(), Err(PlanError::BadStep { axis: "x_mm", .. })));
        let mut s = PlanSpec::default();
        s.yaw_deg.min = f64::NAN;
        assert!(matches!(s.validate(), Err(PlanError::NotFinite { axis: "yaw_deg", field: "min", .. })));
        let s = PlanSpec { z_mm: AxisRange::new(1.0, -1.0, 0.5), ..PlanSpec::default() };
        assert!(matches!(s.validate(), Err(PlanError::EmptyRange { axis: "z_mm", .. })));
        let s = PlanSpec { n_poses: Some(7866), ..PlanSpec::default() };
        assert!(matches!(s.validate(), Err(PlanError::TooManyPoses { requested: 7866, grid: 7865 })));
        let s = PlanSpec { sampling: Sampling::Full, ..PlanSpec::default() };
        assert!(matches!(s.validate(), Err(PlanError::CountWithFull { .. })));
        let s = PlanSpec { n_poses: None, ..PlanSpec::default() };
        assert!(matches!(s.validate(), Err(PlanError::MissingCount { sampling: Sampling::Lhs })));
        let mut s = PlanSpec::default();
        s.x_mm.step = 1e-9;
        assert!(matches!(s.validate(), Err(PlanError::GridTooLarge { .. })));
        // The cap is on the product of the axes, and says what it is.
        let mut s = PlanSpec { sampling: Sampling::Full, n_poses: None, ..PlanSpec::default() };
        (s.x_mm.step, s.y_mm.step) = (0.01, 0.01);
        let e = s.validate().expect_err("over the cap");
        assert!(matches!(e, PlanError::GridTooLarge { max: MAX_GRID_POINTS, .. }), "{e}");
        assert!(e.to_string().contains("1000000"), "{e}");
    }

    #[test]
    fn optimised_order_is_a_permutation_and_not_worse() {
        let cost = model();
        for sampling in [Sampling::Random, Sampling::Lhs] {
            let s = PlanSpec { sampling, n_poses: Some(120), seed: 3, ..PlanSpec::default() };
            let plan = s.build(&cost).unwrap();
            let mut ids: Vec<u32> = plan.poses.iter().map(|p| p.pose_id).collect();
            assert_eq!(ids.len(), 120);
            ids.sort();
            ids.dedup();
            assert_eq!(ids.len(), 120, "duplicated pose ids");
            assert!(plan.motion_time_after_s < plan.motion_time_before_s);
            assert!((path_cost(&plan.poses, &cost) - plan.motion_time_after_s).abs() < 1e-9);
        }
    }

    /// A kept order is read back as it is, and refused when it is not an order of the plan's
    /// poses: a missing or extra pose, one twice.
    #[test]
    fn kept_orders_are_checked_against_the_plan() {
        let cost = model();
        let spec = PlanSpec { n_poses: Some(30), seed: 2, ..PlanSpec::default() };
        let sampled = spec.sample().unwrap();
        let mut ids: Vec<u32> = sampled.iter().map(|p| p.pose_id).collect();
        ids.reverse();
        let plan = in_kept_order(sampled.clone(), &ids, &cost).unwrap();
        assert_eq!(plan.poses.iter().map(|p| p.pose_id).collect::<Vec<_>>(), ids);
        assert!((plan.motion_time_before_s - path_cost(&sampled, &cost)).abs() < 1e-12);
        assert!((plan.motion_time_after_s - path_cost(&plan.poses, &cost)).abs() < 1e-12);
        assert_eq!(in_kept_order(sampled.clone(), &ids[1..], &cost), Err(OrderMismatch::Count { kept: 29, planned: 30 }));
        let outside = (0..7865).find(|id| !ids.contains(id)).unwrap();
        let mut other = ids.clone();
        other[4] = outside;
        assert_eq!(in_kept_order(sampled.clone(), &other, &cost), Err(OrderMismatch::NotPlanned { pose_id: outside }));
        other[4] = ids[9];
        assert_eq!(in_kept_order(sampled, &other, &cost), Err(OrderMismatch::Repeated { pose_id: ids[9] }));
    }

    #[test]
    fn lhs_balances_every_axis() {
        // With n equal to the axis count, each axis value is drawn once per stratum, so before
        // collisions every value appears n / count times; collisions move few points.
        let s = PlanSpec {
            x_mm: AxisRange::new(0.0, 9.0, 1.0),
            y_mm: AxisRange::new(0.0, 9.0, 1.0),
            z_mm: AxisRange::new(0.0, 9.0, 1.0),
            yaw_deg: AxisRange::new(0.0, 90.0, 10.0),
            sampling: Sampling::Lhs,
            n_poses: Some(100),
            seed: 9,
            order: Order::AsSampled,
        };
        let plan = s.build(&model()).unwrap();
        let mut per_x = [0usize; 10];
        for p in &plan.poses {
            per_x[p.pose.x_mm as usize] += 1;
        }
        assert!(per_x.iter().all(|&c| (8..=12).contains(&c)), "{per_x:?}");
    }

    #[test]
    fn seeded_and_reproducible() {
        let cost = model();
        let a = PlanSpec { seed: 7, ..PlanSpec::default() }.build(&cost).unwrap();
        let b = PlanSpec { seed: 7, ..PlanSpec::default() }.build(&cost).unwrap();
        let c = PlanSpec { seed: 8, ..PlanSpec::default() }.build(&cost).unwrap();
        assert_eq!(a, b);
        assert_ne!(a.poses, c.poses);
    }

    #[test]
    fn missing_and_shards() {
        let s = PlanSpec::default();
        let done: BTreeSet<u32> = (0..7000).collect();
        let missing = s.missing(&done);
        assert_eq!(missing.len(), 865);
        assert_eq!(missing[0].pose_id, 7000);
        let shards: Vec<Vec<PlannedPose>> = (0..3).map(|i| shard(&missing, i, 3)).collect();
        assert_eq!(shards.iter().map(Vec::len).sum::<usize>(), 865);
        let mut ids: Vec<u32> = shards.iter().flatten().map(|p| p.pose_id).collect();
        ids.sort();
        assert_eq!(ids, missing.iter().map(|p| p.pose_id).collect::<Vec<_>>());
        assert!(shard(&missing, 3, 3).is_empty());
    }

    #[test]
    fn trapezoid_model() {
        let m = TrapezoidMotionModel { per_pose_s: 0.0, ..Default::default() };
        // 10 mm at 1000 mm/s^2 never reaches 100 mm/s: t = 2 sqrt(d / a) = 0.2 s.
        assert!((m.time_s(&Pose::default(), &Pose::new(10.0, 0.0, 0.0, 0.0)) - 0.2).abs() < 1e-9);
        // 180 deg: cruise, 180/180 + 180/720 = 1.25 s.
        assert!((m.time_s(&Pose::default(), &Pose::new(0.0, 0.0, 0.0, 180.0)) - 1.25).abs() < 1e-9);
    }
}
