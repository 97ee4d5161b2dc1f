//! The travel-minimising order of a plan's poses ([`Order::Optimised`](super::Order::Optimised)):
//! one method from 10 to 10^6 poses, O(n log n) time and O(n) memory.
//!
//! ```text
//! poses ──probe the cost──► metric (work-frame x, y, z, yaw, each scaled to seconds)
//!       ──group──► sites (poses the metric cannot tell apart: the same approach pose)
//!       ──k-d tree──► candidate neighbours per site (24 by the metric, the 10 cheapest by the real cost)
//!       ──► nearest-neighbour tour (through the candidates, else the tree's nearest live site)
//!       ──► 2-opt and Or-opt over the candidates, don't-look bits ──► open path ──► poses
//! ```
//!
//! **The real cost decides every move.** The cost closure (for `rig collect` the firmware
//! profile's joint-space motion time between approach poses,
//! [`FirmwareProfile::pose_cost_s`](crate::arm::profile::FirmwareProfile::pose_cost_s)) is
//! opaque, so the index needs a metric that approximates it: each axis is scaled by the cost of
//! a probe step along it from the plan's centre, in seconds per mm (or per degree). The metric
//! only proposes neighbours; their order, the tour's steps and every move's gain use the cost
//! itself. An axis whose probe costs nothing (z for the profile: every travel happens at the
//! approach height) is left out of the metric, and poses that differ only along such axes form
//! one *site*, visited in one go (zero travel between them); this also keeps a site's z
//! siblings out of its neighbour lists, where they would crowd out the real neighbours.
//!
//! **Why a k-d tree written here**, and not a crate such as `kiddo` or grid buckets: the
//! nearest-neighbour tour deletes every site it visits and asks for the nearest live one; late
//! in the tour the sites around the query are gone. A tree that counts the live points under
//! each node skips emptied subtrees ([`super::kdtree`], ~150 lines), where `kiddo`'s trees
//! (static, or with removal that leaves empty leaves to walk) and grid buckets (empty cells to
//! walk, at the end of the tour across most of the grid) both degrade towards a scan. The
//! tree is exact under its metric, needs no tuning to the grid's density (a sampled plan uses
//! 1 % of a grid as easily as all of it) and adds no dependency to rig's build.
//!
//! **Bounded moves.** The tour is an array with each site's position; a 2-opt move reverses the
//! shorter side of the cycle, and a move that would reverse more than [`MAX_REVERSAL`] sites
//! is skipped (it binds only above 2 x 50,000 sites; Or-opt moves segments of 1 to 3 sites and
//! repairs much of what such a skipped move would have). Don't-look bits (a queue of sites
//! whose neighbourhood changed) make the local search touch each site a few times, and the
//! number of examinations is bounded by [`MAX_EXAMINATIONS_PER_SITE`] per site. 2-opt assumes
//! the cost is symmetric, which holds for per-axis (per-joint) trapezoid models; the path is
//! opened at a zero-cost virtual site and read in its cheaper direction under the directed cost.
//!
//! [`reference`] is the algorithm this module replaced (nearest neighbour by a full scan
//! and 2-opt over exact 16-nearest lists from a full row per pose: quadratic time and memory),
//! kept as the tests' and the benchmark's yardstick.

use super::kdtree::{KdTree, Point};
use crate::pose::Pose;

/// Candidate neighbours kept per site, the cheapest under the real cost.
const CANDIDATES: usize = 10;
/// Neighbours taken from the index per site, before ranking them by the real cost.
const INDEX_NEIGHBOURS: usize = 24;
/// Live sites the tour's step asks the index for when every candidate is visited.
const NEAREST_LIVE: usize = 32;
/// Most sites one move may reverse (the shorter side of the cycle).
pub const MAX_REVERSAL: usize = 50_000;
/// Bound on the local search: at most this many examinations per site.
pub const MAX_EXAMINATIONS_PER_SITE: usize = 100;
/// Improvements smaller than this (seconds) do not count: float noise must not loop.
const EPS: f64 = 1e-12;
/// No candidate (padding of a list shorter than [`CANDIDATES`]).
const NONE: u32 = u32::MAX;

type Cost<'a> = &'a dyn Fn(&Pose, &Pose) -> f64;

/// A travel-minimising order of `poses`: a permutation of their indices.
pub(crate) fn optimise(poses: &[Pose], cost: Cost<'_>) -> Vec<u32> {
    if poses.len() < 3 {
        return (0..poses.len() as u32).collect();
    }
    let scale = axis_scales(poses, cost);
    let sites = Sites::group(poses, &scale);
    let n = sites.len();
    let path: Vec<u32> = if n < 3 {
        (0..n as u32).collect()
    } else {
        let points: Vec<Point> = (0..n).map(|s| metric_point(&sites.pose(poses, s as u32), &scale)).collect();
        let mut tree = KdTree::new(points);
        let d = |a: u32, b: u32| -> f64 {
            if a as usize >= n || b as usize >= n { 0.0 } else { cost(&sites.pose(poses, a), &sites.pose(poses, b)) }
        };
        let candidates = Candidates::build(&tree, n, &d);
        let first = nearest_neighbour_tour(&mut tree, &candidates, poses, &sites, cost, &d);
        let mut tour = Tour::new(first, n as u32);
        improve(&mut tour, &candidates, &d);
        tour.open_path()
    };
    let forward: Vec<u32> = path.iter().flat_map(|&s| sites.members(s).iter().copied()).collect();
    cheaper_direction(forward, poses, cost)
}

/// `path` (indices into `poses`) or its reverse, whichever costs less under the directed cost.
fn cheaper_direction(path: Vec<u32>, poses: &[Pose], cost: Cost<'_>) -> Vec<u32> {
    let total = |mut steps: Box<dyn Iterator<Item = &u32> + '_>| -> f64 {
        let Some(&first) = steps.next() else { return 0.0 };
        steps.fold((0.0, first), |(sum, prev), &next| (sum + cost(&poses[prev as usize], &poses[next as usize]), next)).0
    };
    if total(Box::new(path.iter().rev())) < total(Box::new(path.iter())) {
        let mut backward = path;
        backward.reverse();
        backward
    } else {
        path
    }
}

/// Seconds per unit (mm or degree) along each axis `[x, y, z, yaw]`: the mean of the cost
/// of a step of an eighth of the plan's extent out of its centre and back, less the cost of
/// staying put (a per-pose constant). 0 for an axis the cost ignores or the plan does not span.
fn axis_scales(poses: &[Pose], cost: Cost<'_>) -> [f64; 4] {
    let coords = |p: &Pose| [p.x_mm, p.y_mm, p.z_mm, p.yaw_deg];
    let (mut lo, mut hi) = ([f64::INFINITY; 4], [f64::NEG_INFINITY; 4]);
    for p in poses {
        let c = coords(p);
        for a in 0..4 {
            lo[a] = lo[a].min(c[a]);
            hi[a] = hi[a].max(c[a]);
        }
    }
    let mid: Vec<f64> = (0..4).map(|a| (lo[a] + hi[a]) / 2.0).collect();
    let centre = Pose::new(mid[0], mid[1], mid[2], mid[3]);
    let still = cost(&centre, &centre);
    let mut scale = [0.0; 4];
    for a in 0..4 {
        let extent = hi[a] - lo[a];
        if !(extent > 0.0 && extent.is_finite()) {
            continue;
        }
        let step = extent / 8.0;
        let mut c = coords(&centre);
        c[a] += step;
        let moved = Pose::new(c[0], c[1], c[2], c[3]);
        let t = (cost(&centre, &moved) + cost(&moved, &centre)) / 2.0 - still;
        if t.is_finite() && t > 0.0 {
            scale[a] = t / step;
        }
    }
    if scale.iter().all(|&s| s == 0.0) {
        // A cost that ignores every probe (constant, or broken): every spanned axis counts,
        // each over its own extent.
        for a in 0..4 {
            let extent = hi[a] - lo[a];
            if extent > 0.0 && extent.is_finite() {
                scale[a] = 1.0 / extent;
            }
        }
    }
    scale
}

fn metric_point(p: &Pose, scale: &[f64; 4]) -> Point {
    [p.x_mm * scale[0], p.y_mm * scale[1], p.z_mm * scale[2], p.yaw_deg * scale[3]]
}

/// Poses grouped by their position under the metric: poses that differ only along axes the
/// metric leaves out are one site. `order` holds pose indices site by site (each site's in
/// the input's order); site `s` is `order[start[s]..start[s + 1]]`.
struct Sites {
    order: Vec<u32>,
    start: Vec<u32>,
}

impl Sites {
    fn group(poses: &[Pose], scale: &[f64; 4]) -> Self {
        let key = |p: &Pose| -> [u64; 4] {
            let c = [p.x_mm, p.y_mm, p.z_mm, p.yaw_deg];
            // +0.0 folds -0.0 onto 0.0 so that the two are one position.
            std::array::from_fn(|a| if scale[a] > 0.0 { (c[a] + 0.0).to_bits() } else { 0 })
        };
        let mut order: Vec<u32> = (0..poses.len() as u32).collect();
        order.sort_by_key(|&i| (key(&poses[i as usize]), i));
        let mut start = Vec::new();
        for (k, &i) in order.iter().enumerate() {
            if k == 0 || key(&poses[i as usize]) != key(&poses[order[k - 1] as usize]) {
                start.push(k as u32);
            }
        }
        start.push(order.len() as u32);
        Self { order, start }
    }

    fn len(&self) -> usize {
        self.start.len() - 1
    }

    fn members(&self, s: u32) -> &[u32] {
        &self.order[self.start[s as usize] as usize..self.start[s as usize + 1] as usize]
    }

    /// The site's pose (its first member's: the others cost nothing to reach from it).
    fn pose(&self, poses: &[Pose], s: u32) -> Pose {
        poses[self.order[self.start[s as usize] as usize] as usize]
    }
}

/// Each site's [`CANDIDATES`] cheapest neighbours among its [`INDEX_NEIGHBOURS`] nearest
/// under the metric, cheapest first, with their cost (as `f32`: it only prunes; every gain is
/// recomputed in full precision).
struct Candidates {
    ids: Vec<u32>,
    cost_s: Vec<f32>,
}

impl Candidates {
    fn build(tree: &KdTree, n: usize, d: &dyn Fn(u32, u32) -> f64) -> Self {
        let mut ids = vec![NONE; n * CANDIDATES];
        let mut cost_s = vec![f32::INFINITY; n * CANDIDATES];
        let mut ranked: Vec<(f64, u32)> = Vec::with_capacity(INDEX_NEIGHBOURS + 1);
        for a in 0..n as u32 {
            ranked.clear();
            for (_, c) in tree.nearest(tree.point(a), INDEX_NEIGHBOURS + 1, false) {
                if c != a {
                    ranked.push((d(a, c), c));
                }
            }
            ranked.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
            for (k, &(t, c)) in ranked.iter().take(CANDIDATES).enumerate() {
                ids[a as usize * CANDIDATES + k] = c;
                cost_s[a as usize * CANDIDATES + k] = t as f32;
            }
        }
        Self { ids, cost_s }
    }

    /// `(neighbour, cost)` of site `a`, cheapest first (none for the virtual site).
    fn of(&self, a: u32) -> impl Iterator<Item = (u32, f64)> + '_ {
        let range = if (a as usize) < self.ids.len() / CANDIDATES { a as usize * CANDIDATES..(a as usize + 1) * CANDIDATES } else { 0..0 };
        self.ids[range.clone()].iter().zip(&self.cost_s[range]).take_while(|&(&c, _)| c != NONE).map(|(&c, &t)| (c, t as f64))
    }
}

/// The nearest-neighbour tour of the sites, from the one nearest (by the cost) to the
/// work-frame origin, where a collection starts: each step goes to the cheapest unvisited
/// candidate, or, when every candidate is visited, to the cheapest of the index's
/// [`NEAREST_LIVE`] nearest unvisited sites. Removes every site from `tree`.
fn nearest_neighbour_tour(
    tree: &mut KdTree,
    candidates: &Candidates,
    poses: &[Pose],
    sites: &Sites,
    cost: Cost<'_>,
    d: &dyn Fn(u32, u32) -> f64,
) -> Vec<u32> {
    let n = sites.len();
    let origin = Pose::default();
    let start =
        (0..n as u32).min_by(|&a, &b| cost(&origin, &sites.pose(poses, a)).total_cmp(&cost(&origin, &sites.pose(poses, b)))).unwrap_or(0);
    let mut visited = vec![false; n];
    let mut tour = Vec::with_capacity(n);
    let mut cur = start;
    loop {
        visited[cur as usize] = true;
        tree.remove(cur);
        tour.push(cur);
        if tree.live() == 0 {
            break;
        }
        let next = candidates.of(cur).find(|&(c, _)| !visited[c as usize]).map(|(c, _)| c).unwrap_or_else(|| {
            let point = *tree.point(cur);
            tree.nearest(&point, NEAREST_LIVE, true)
                .into_iter()
                .map(|(_, c)| (d(cur, c), c))
                .min_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)))
                .map(|(_, c)| c)
                .unwrap_or(cur)
        });
        if next == cur {
            break; // unreachable while live sites remain; never loop on it
        }
        cur = next;
    }
    tour
}

/// A cyclic tour as an array and each site's position in it. The last site (`virt`) is the
/// virtual one that closes the open path at zero cost.
struct Tour {
    order: Vec<u32>,
    pos: Vec<u32>,
    virt: u32,
}

impl Tour {
    fn new(path: Vec<u32>, virt: u32) -> Self {
        let mut order = path;
        order.push(virt);
        let mut pos = vec![0u32; order.len()];
        for (i, &s) in order.iter().enumerate() {
            pos[s as usize] = i as u32;
        }
        Self { order, pos, virt }
    }

    fn m(&self) -> usize {
        self.order.len()
    }

    fn succ(&self, x: u32) -> u32 {
        self.order[(self.pos[x as usize] as usize + 1) % self.m()]
    }

    fn pred(&self, x: u32) -> u32 {
        self.order[(self.pos[x as usize] as usize + self.m() - 1) % self.m()]
    }

    fn next(&self, x: u32, forward: bool) -> u32 {
        if forward { self.succ(x) } else { self.pred(x) }
    }

    /// Sites on the path from `x` to `y` in direction `forward`, both included.
    fn span(&self, x: u32, y: u32, forward: bool) -> usize {
        let (px, py, m) = (self.pos[x as usize] as usize, self.pos[y as usize] as usize, self.m());
        (if forward { py + m - px } else { px + m - py }) % m + 1
    }

    /// Sites a reversal of that path moves: the shorter side of the cycle.
    fn reversal_cost(&self, x: u32, y: u32, forward: bool) -> usize {
        let s = self.span(x, y, forward);
        s.min(self.m() - s)
    }

    /// Reverses the forward path `x ..= y`, or its complement when that is shorter (the same
    /// cycle, read the other way).
    fn reverse(&mut self, x: u32, y: u32) {
        let m = self.m();
        let len = self.span(x, y, true);
        let (mut i, mut j, len) = if 2 * len <= m {
            (self.pos[x as usize] as usize, self.pos[y as usize] as usize, len)
        } else {
            (self.pos[self.succ(y) as usize] as usize, self.pos[self.pred(x) as usize] as usize, m - len)
        };
        for _ in 0..len / 2 {
            self.order.swap(i, j);
            self.pos[self.order[i] as usize] = i as u32;
            self.pos[self.order[j] as usize] = j as u32;
            i = (i + 1) % m;
            j = (j + m - 1) % m;
        }
    }

    /// The 2-opt move that replaces edges `{a, b}` and `{c, d}` by `{a, c}` and `{b, d}`, where
    /// `b` follows `a` and `d` follows `c` in the same direction.
    fn two_opt(&mut self, a: u32, b: u32, c: u32, d: u32) {
        if self.succ(a) == b { self.reverse(b, c) } else { self.reverse(a, d) }
    }

    /// The path the cycle holds, opened at the virtual site.
    fn open_path(&self) -> Vec<u32> {
        let at = self.pos[self.virt as usize] as usize;
        (1..self.m()).map(|k| self.order[(at + k) % self.m()]).collect()
    }
}

/// Local search to a 2-opt and Or-opt optimum over the candidate lists, with don't-look bits:
/// a queue of sites to examine, starting with all of them; a site whose examination finds no
/// improving move leaves the queue, and the ends of every edge a move changes come back.
fn improve(tour: &mut Tour, candidates: &Candidates, d: &dyn Fn(u32, u32) -> f64) {
    let n = tour.virt as usize;
    let mut queue: std::collections::VecDeque<u32> = tour.order.iter().copied().filter(|&s| s != tour.virt).collect();
    let mut queued = vec![true; n + 1];
    queued[n] = false;
    let mut budget = MAX_EXAMINATIONS_PER_SITE.saturating_mul(n);
    while let Some(a) = queue.pop_front() {
        queued[a as usize] = false;
        if budget == 0 {
            break;
        }
        budget -= 1;
        let touched = two_opt_move(tour, candidates, d, a).or_else(|| or_opt_move(tour, candidates, d, a));
        for s in touched.into_iter().flatten() {
            if s != tour.virt && !std::mem::replace(&mut queued[s as usize], true) {
                queue.push_back(s);
            }
        }
    }
}

/// Applies the first improving 2-opt move with a new edge from `a` to a candidate; returns
/// the sites whose edges changed.
fn two_opt_move(tour: &mut Tour, candidates: &Candidates, d: &dyn Fn(u32, u32) -> f64, a: u32) -> Option<[u32; 6]> {
    for forward in [true, false] {
        let b = tour.next(a, forward);
        let d_ab = d(a, b);
        for (c, d_ac_pruning) in candidates.of(a) {
            if d_ab - d_ac_pruning <= EPS {
                break; // cheapest first: no later candidate gains
            }
            let dd = tour.next(c, forward);
            if c == b || dd == a {
                continue;
            }
            let delta = d(a, c) + d(b, dd) - d_ab - d(c, dd);
            if delta >= -EPS {
                continue;
            }
            let reversed = if forward { tour.reversal_cost(b, c, true) } else { tour.reversal_cost(a, dd, true) };
            if reversed > MAX_REVERSAL {
                continue;
            }
            tour.two_opt(a, b, c, dd);
            return Some([a, b, c, dd, a, a]);
        }
    }
    None
}

/// Applies the first improving Or-opt move of a segment of 1 to 3 sites starting at `a`
/// (either way along the tour) to an edge at one of its ends' candidates, the segment kept or
/// reversed; returns the sites whose edges changed.
fn or_opt_move(tour: &mut Tour, candidates: &Candidates, d: &dyn Fn(u32, u32) -> f64, a: u32) -> Option<[u32; 6]> {
    if tour.m() < 8 {
        return None;
    }
    for forward in [true, false] {
        let mut seg = [a; 3];
        for len in 1..=3 {
            if len > 1 {
                seg[len - 1] = tour.next(seg[len - 2], forward);
            }
            let e = seg[len - 1];
            if e == tour.virt {
                break;
            }
            let (p, nx) = (tour.next(a, !forward), tour.next(e, forward));
            let removal_gain = d(p, a) + d(e, nx) - d(p, nx);
            if removal_gain <= EPS {
                continue;
            }
            let in_seg = |x: u32| seg[..len].contains(&x);
            // A candidate of `a` becomes `a`'s new neighbour; one of `e`, `e`'s.
            let ends: &[(u32, u32)] = if len == 1 { &[(a, a)] } else { &[(a, e), (e, a)] };
            for &(end, other) in ends {
                for (c, d_c_pruning) in candidates.of(end) {
                    if d_c_pruning >= removal_gain - EPS {
                        break;
                    }
                    if in_seg(c) {
                        continue;
                    }
                    for c2 in [tour.next(c, forward), tour.next(c, !forward)] {
                        if in_seg(c2) {
                            continue;
                        }
                        let added = d(c, end) + d(other, c2) - d(c, c2);
                        if removal_gain - added <= EPS {
                            continue;
                        }
                        // (u, v): the insertion edge, v after u in the segment's direction.
                        let (u, v) = if tour.next(c, forward) == c2 { (c, c2) } else { (c2, c) };
                        // Next to the segment, the move is a 2-opt move: left to that search.
                        if u == nx || v == p {
                            continue;
                        }
                        let reach = tour.span(a, u, forward);
                        if reach.min(tour.m() - reach) > MAX_REVERSAL {
                            continue;
                        }
                        // p [a..e] nx .. u v  ──►  p nx .. u [e..a] v  (two 2-opt moves)
                        tour.two_opt(p, a, u, v);
                        tour.two_opt(p, u, nx, e);
                        // ... u [a..e] v when `a` is to neighbour `u`: reverse the segment.
                        let a_next_to_u = (end == a && c == u) || (end == e && c == v);
                        if a_next_to_u {
                            tour.two_opt(u, e, a, v);
                        }
                        return Some([p, a, e, nx, u, v]);
                    }
                }
            }
        }
    }
    None
}

/// The order this module replaced: nearest neighbour by a full scan from the pose nearest the
/// origin, then 2-opt over each pose's exact 16 nearest poses under the cost (a full row of
/// costs per pose), to a local optimum. Quadratic in time and memory; the yardstick of the
/// tests and of `cargo bench --bench plan_order`, not used by rig's commands. A permutation of
/// the indices of `poses`.
pub(crate) fn reference(poses: &[Pose], cost: Cost<'_>) -> Vec<u32> {
    const NEIGHBOURS: usize = 16;
    let n = poses.len();
    if n < 3 {
        return (0..n as u32).collect();
    }
    let virt = n;
    let d = |a: usize, b: usize| -> f64 { if a == virt || b == virt { 0.0 } else { cost(&poses[a], &poses[b]) } };

    let origin = Pose::default();
    let start = (0..n).min_by(|&a, &b| cost(&origin, &poses[a]).total_cmp(&cost(&origin, &poses[b]))).unwrap_or(0);
    let mut visited = vec![false; n];
    let mut tour = Vec::with_capacity(n + 1);
    tour.push(virt);
    let mut cur = start;
    visited[cur] = true;
    tour.push(cur);
    for _ in 1..n {
        let next = (0..n).filter(|&j| !visited[j]).min_by(|&a, &b| d(cur, a).total_cmp(&d(cur, b))).unwrap_or(cur);
        visited[next] = true;
        tour.push(next);
        cur = next;
    }

    let k = NEIGHBOURS.min(n - 1);
    let knn: Vec<Vec<(f64, usize)>> = (0..n)
        .map(|a| {
            let mut v: Vec<(f64, usize)> = (0..n).filter(|&b| b != a).map(|b| (d(a, b), b)).collect();
            if k < v.len() {
                v.select_nth_unstable_by(k, |x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
                v.truncate(k);
            }
            v.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
            v
        })
        .collect();

    let m = n + 1;
    let mut pos = vec![0usize; m];
    for (i, &node) in tour.iter().enumerate() {
        pos[node] = i;
    }
    let succ = |tour: &[usize], pos: &[usize], x: usize| tour[(pos[x] + 1) % m];
    let pred = |tour: &[usize], pos: &[usize], x: usize| tour[(pos[x] + m - 1) % m];
    let mut improved = true;
    let mut passes = 0;
    while improved && passes < 1000 {
        improved = false;
        passes += 1;
        for a in 0..n {
            for forward in [true, false] {
                let b = if forward { succ(&tour, &pos, a) } else { pred(&tour, &pos, a) };
                let d_ab = d(a, b);
                for &(d_ac, c) in &knn[a] {
                    if d_ab - d_ac <= EPS {
                        break;
                    }
                    let dd = if forward { succ(&tour, &pos, c) } else { pred(&tour, &pos, c) };
                    if dd == a || c == b {
                        continue;
                    }
                    let delta = d_ac + d(b, dd) - d_ab - d(c, dd);
                    if delta < -EPS {
                        let (i, j) = if forward { (pos[a], pos[c]) } else { (pos[b], pos[dd]) };
                        let (lo, hi) = if i < j { (i + 1, j) } else { (j + 1, i) };
                        tour[lo..=hi].reverse();
                        for (p, &node) in tour.iter().enumerate().take(hi + 1).skip(lo) {
                            pos[node] = p;
                        }
                        improved = true;
                        break;
                    }
                }
            }
        }
    }

    let at = pos[virt];
    let path: Vec<u32> = (1..m).map(|s| tour[(at + s) % m] as u32).collect();
    cheaper_direction(path, poses, cost)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::{AxisRange, Order, PlanSpec, PlannedPose, Sampling, TrapezoidMotionModel, path_cost};

    /// [`super::optimise`] on planned poses.
    fn optimise(poses: &[PlannedPose], cost: Cost<'_>) -> Vec<PlannedPose> {
        let plain: Vec<Pose> = poses.iter().map(|p| p.pose).collect();
        super::optimise(&plain, cost).into_iter().map(|i| poses[i as usize]).collect()
    }

    fn reference_order(poses: &[PlannedPose], cost: Cost<'_>) -> Vec<PlannedPose> {
        crate::plan::reference_order(poses, cost)
    }

    /// `rig collect`'s cost: the default firmware profile between approach poses.
    fn profile_cost() -> impl Fn(&Pose, &Pose) -> f64 {
        let profile = crate::arm::profile::FirmwareProfile::default_mg400();
        let work_frame = crate::pose::WorkFrame::default();
        move |a: &Pose, b: &Pose| profile.pose_cost_s(&work_frame, a, b)
    }

    fn trapezoid_cost() -> impl Fn(&Pose, &Pose) -> f64 {
        let m = TrapezoidMotionModel::default();
        move |a: &Pose, b: &Pose| m.time_s(a, b)
    }

    /// The 100 x 100 x 10 x 10 grid of the scale figures (`plans/lab-scale.toml`, Latin
    /// hypercube), `n_poses` of it in the sampler's order.
    fn lab_grid(n_poses: usize, seed: u64) -> PlanSpec {
        let file = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("plans/lab-scale.toml");
        let spec = PlanSpec::load(&file).expect("plans/lab-scale.toml");
        PlanSpec { n_poses: Some(n_poses), seed, order: Order::AsSampled, ..spec }
    }

    fn sampled(spec: &PlanSpec, cost: &dyn Fn(&Pose, &Pose) -> f64) -> Vec<PlannedPose> {
        spec.build(cost).expect("valid plan").poses
    }

    fn assert_permutation(ordered: &[PlannedPose], of: &[PlannedPose]) {
        let key = |v: &[PlannedPose]| {
            let mut ids: Vec<u32> = v.iter().map(|p| p.pose_id).collect();
            ids.sort_unstable();
            ids
        };
        assert_eq!(key(ordered), key(of), "not a permutation");
        for p in ordered {
            assert!(of.contains(p), "pose changed: {p:?}");
        }
    }

    /// Every size and shape of input comes back as a permutation of itself: tiny plans, one
    /// site (z only: zero travel between every pair), a line, duplicates of one position.
    #[test]
    fn every_order_is_a_permutation() {
        let cost = profile_cost();
        let trapezoid = trapezoid_cost();
        let line: Vec<PlannedPose> =
            (0..40).map(|i| PlannedPose { pose_id: i, pose: Pose::new(i as f64 * 0.25 - 5.0, 0.0, 0.0, 0.0) }).collect();
        let z_only: Vec<PlannedPose> =
            (0..9).map(|i| PlannedPose { pose_id: i, pose: Pose::new(1.0, 1.0, i as f64 * 0.25 - 1.0, 15.0) }).collect();
        let twins: Vec<PlannedPose> = (0..30)
            .map(|i| PlannedPose { pose_id: i, pose: Pose::new((i % 3) as f64, ((i / 3) % 2) as f64, (i / 6) as f64 * 0.5 - 1.0, 0.0) })
            .collect();
        for poses in [line, z_only, twins] {
            for n in [0, 1, 2, 3, 4, 5, 7, 9, poses.len()] {
                let part = &poses[..n.min(poses.len())];
                for c in [&cost as &dyn Fn(&Pose, &Pose) -> f64, &trapezoid] {
                    let ordered = optimise(part, c);
                    assert_permutation(&ordered, part);
                }
            }
        }
        for n in [10, 100, 2000] {
            let poses = sampled(&lab_grid(n, 3), &cost);
            assert_permutation(&optimise(&poses, &cost), &poses);
        }
    }

    /// Poses the cost cannot tell apart (z, with the profile's approach-height travel) are
    /// visited one after the other.
    #[test]
    fn a_site_is_visited_in_one_go() {
        let cost = profile_cost();
        let spec = PlanSpec { sampling: Sampling::Full, n_poses: None, ..lab_grid(1, 0) };
        let spec = PlanSpec { x_mm: AxisRange::new(-2.0, 2.0, 1.0), y_mm: AxisRange::new(-2.0, 2.0, 1.0), ..spec };
        let ordered = optimise(&sampled(&spec, &cost), &cost);
        let mut seen = std::collections::BTreeSet::new();
        let mut last = None;
        for p in &ordered {
            let site = (p.pose.x_mm.to_bits(), p.pose.y_mm.to_bits(), p.pose.yaw_deg.to_bits());
            if last != Some(site) {
                assert!(seen.insert(site), "site {site:?} visited twice");
                last = Some(site);
            }
        }
        assert_eq!(seen.len(), 5 * 5 * 10);
    }

    /// At 1,000 poses the route is within 2 % of the order this module replaced, under the
    /// firmware profile's model (default grid, Latin hypercube, two seeds) and under the
    /// trapezoid stand-in (the 100 x 100 x 10 x 10 grid). The 5,000-pose comparison is in
    /// `cargo bench --bench plan_order` (the reference takes minutes there in a test build).
    #[test]
    fn route_within_2_percent_of_the_reference_at_1000_poses() {
        let cost = profile_cost();
        let trapezoid = trapezoid_cost();
        type Cost<'a> = &'a dyn Fn(&Pose, &Pose) -> f64;
        let cases: [(&str, PlanSpec, Cost); 3] = [
            ("profile, default grid, seed 0", PlanSpec { n_poses: Some(1000), order: Order::AsSampled, ..PlanSpec::default() }, &cost),
            (
                "profile, default grid, seed 1",
                PlanSpec { n_poses: Some(1000), seed: 1, order: Order::AsSampled, ..PlanSpec::default() },
                &cost,
            ),
            ("trapezoid, lab grid", lab_grid(1000, 0), &trapezoid),
        ];
        for (label, spec, c) in cases {
            let poses = sampled(&spec, c);
            let new = path_cost(&optimise(&poses, c), c);
            let reference = path_cost(&reference_order(&poses, c), c);
            assert!(new <= 1.02 * reference, "{label}: {new:.2} s against the reference's {reference:.2} s");
            assert!(new < 0.5 * path_cost(&poses, c), "{label}: {new:.2} s is not much better than as sampled");
        }
    }

    /// No cliff: the route per pose does not jump from one size to the next. 10,000 to 10,001
    /// poses is where the serpentine sweep used to take over (173.8 s to 585.6 s, 3.4x).
    #[test]
    fn no_cliff_at_10001_poses() {
        let cost = profile_cost();
        let at = |n: usize| PlanSpec { order: Order::Optimised, ..lab_grid(n, 0) }.build(&cost).expect("valid plan").motion_time_after_s;
        let (below, above) = (at(10_000), at(10_001));
        assert!(above <= 1.2 * below && below <= 1.2 * above, "10,000 poses: {below:.1} s, 10,001: {above:.1} s");
    }
}
