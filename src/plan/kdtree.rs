//! A static k-d tree over the sites of a plan, with deletion by marking: the spatial index
//! the order optimiser ([`super::order`]) takes its candidate neighbours and its
//! nearest-neighbour tour from.
//!
//! The points are built once (median splits on the widest side, O(n log n)); a query finds
//! the `k` nearest points under squared Euclidean distance, either among all points or only
//! among those not yet [`remove`](KdTree::remove)d. Every node counts the points still live
//! below it and a query skips a node whose count is zero, so the nearest-neighbour tour's
//! query late in the tour, when the points around it are visited, stays O(log n) instead of
//! walking emptied leaves (Bentley's semidynamic k-d tree, 1990). Memory is O(n): the
//! points, one permutation, one node per about [`LEAF`] / 2 points.

/// Points per leaf at most.
const LEAF: usize = 8;

/// A point of the index: four coordinates (an axis the metric ignores is 0 everywhere).
pub(crate) type Point = [f64; 4];

#[derive(Debug, Clone)]
struct Node {
    /// The node's points are `perm[lo..hi]`.
    lo: u32,
    hi: u32,
    /// Children (`u32::MAX` for a leaf) and parent (`u32::MAX` for the root).
    left: u32,
    right: u32,
    parent: u32,
    /// Points below not removed yet.
    live: u32,
    /// Bounding box of the node's points.
    min: Point,
    max: Point,
}

/// The index. Items are the positions of the points in the slice it was built from.
#[derive(Debug, Clone)]
pub(crate) struct KdTree {
    points: Vec<Point>,
    perm: Vec<u32>,
    nodes: Vec<Node>,
    /// The leaf holding each item.
    leaf_of: Vec<u32>,
    alive: Vec<bool>,
}

/// Squared Euclidean distance.
pub(crate) fn dist2(a: &Point, b: &Point) -> f64 {
    (0..4).map(|i| (a[i] - b[i]) * (a[i] - b[i])).sum()
}

/// Squared distance from `q` to the box `[min, max]` (0 inside it).
fn box_dist2(q: &Point, min: &Point, max: &Point) -> f64 {
    (0..4)
        .map(|i| {
            let d = if q[i] < min[i] {
                min[i] - q[i]
            } else if q[i] > max[i] {
                q[i] - max[i]
            } else {
                0.0
            };
            d * d
        })
        .sum()
}

/// The `k` best `(distance², item)` found so far, sorted nearest first (ties: lower item).
struct Best {
    k: usize,
    found: Vec<(f64, u32)>,
}

impl Best {
    fn new(k: usize) -> Self {
        Self { k, found: Vec::with_capacity(k + 1) }
    }

    /// Distance a new point must beat to enter.
    fn bound(&self) -> f64 {
        if self.found.len() < self.k { f64::INFINITY } else { self.found[self.k - 1].0 }
    }

    fn offer(&mut self, d: f64, item: u32) {
        if self.k == 0 || d > self.bound() {
            return;
        }
        let at = self.found.partition_point(|&(fd, fi)| fd < d || (fd == d && fi < item));
        self.found.insert(at, (d, item));
        self.found.truncate(self.k);
    }
}

impl KdTree {
    /// Builds the index over `points` (all live). Items are indices into `points`.
    pub(crate) fn new(points: Vec<Point>) -> Self {
        let n = points.len();
        let mut tree = Self {
            perm: (0..n as u32).collect(),
            nodes: Vec::with_capacity(2 * n / LEAF + 2),
            leaf_of: vec![u32::MAX; n],
            alive: vec![true; n],
            points,
        };
        if n > 0 {
            tree.build(0, n, u32::MAX);
        }
        tree
    }

    fn build(&mut self, lo: usize, hi: usize, parent: u32) -> u32 {
        let (mut min, mut max) = ([f64::INFINITY; 4], [f64::NEG_INFINITY; 4]);
        for &i in &self.perm[lo..hi] {
            let p = &self.points[i as usize];
            for d in 0..4 {
                min[d] = min[d].min(p[d]);
                max[d] = max[d].max(p[d]);
            }
        }
        let id = self.nodes.len() as u32;
        self.nodes.push(Node { lo: lo as u32, hi: hi as u32, left: u32::MAX, right: u32::MAX, parent, live: (hi - lo) as u32, min, max });
        let dim = (0..4).max_by(|&a, &b| (max[a] - min[a]).total_cmp(&(max[b] - min[b]))).unwrap_or(0);
        if hi - lo <= LEAF || max[dim] <= min[dim] {
            for &i in &self.perm[lo..hi] {
                self.leaf_of[i as usize] = id;
            }
            return id;
        }
        let mid = lo + (hi - lo) / 2;
        let points = &self.points;
        self.perm[lo..hi]
            .select_nth_unstable_by(mid - lo, |&a, &b| points[a as usize][dim].total_cmp(&points[b as usize][dim]).then(a.cmp(&b)));
        let left = self.build(lo, mid, id);
        let right = self.build(mid, hi, id);
        self.nodes[id as usize].left = left;
        self.nodes[id as usize].right = right;
        id
    }

    /// The point of `item`.
    pub(crate) fn point(&self, item: u32) -> &Point {
        &self.points[item as usize]
    }

    /// Points not removed.
    pub(crate) fn live(&self) -> usize {
        self.nodes.first().map_or(0, |n| n.live as usize)
    }

    /// Marks `item` removed: later live-only queries skip it. Removing twice does nothing.
    pub(crate) fn remove(&mut self, item: u32) {
        if !std::mem::replace(&mut self.alive[item as usize], false) {
            return;
        }
        let mut node = self.leaf_of[item as usize];
        while node != u32::MAX {
            let n = &mut self.nodes[node as usize];
            n.live -= 1;
            node = n.parent;
        }
    }

    /// The `k` items nearest to `q`, nearest first, as `(distance², item)`; only live ones
    /// when `live_only`. Ties go to the lower item, so the answer is deterministic.
    pub(crate) fn nearest(&self, q: &Point, k: usize, live_only: bool) -> Vec<(f64, u32)> {
        let mut best = Best::new(k);
        if !self.nodes.is_empty() && k > 0 {
            self.search(0, q, live_only, &mut best);
        }
        best.found
    }

    fn search(&self, node: u32, q: &Point, live_only: bool, best: &mut Best) {
        let n = &self.nodes[node as usize];
        if (live_only && n.live == 0) || box_dist2(q, &n.min, &n.max) > best.bound() {
            return;
        }
        if n.left == u32::MAX {
            for &i in &self.perm[n.lo as usize..n.hi as usize] {
                if !live_only || self.alive[i as usize] {
                    best.offer(dist2(q, &self.points[i as usize]), i);
                }
            }
            return;
        }
        // The nearer child first: its points tighten the bound that prunes the other.
        let (l, r) = (&self.nodes[n.left as usize], &self.nodes[n.right as usize]);
        let (first, second) =
            if box_dist2(q, &l.min, &l.max) <= box_dist2(q, &r.min, &r.max) { (n.left, n.right) } else { (n.right, n.left) };
        self.search(first, q, live_only, best);
        self.search(second, q, live_only, best);
    }
}

#[cfg(test)]
mod tests {
    use rand::{RngExt, SeedableRng};

    use super::*;

    fn brute(points: &[Point], q: &Point, k: usize, alive: &[bool]) -> Vec<(f64, u32)> {
        let mut v: Vec<(f64, u32)> = points.iter().enumerate().filter(|(i, _)| alive[*i]).map(|(i, p)| (dist2(q, p), i as u32)).collect();
        v.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        v.truncate(k);
        v
    }

    /// Every query equals a brute-force scan, before and after removals, on random points and
    /// on a grid with many ties.
    #[test]
    fn queries_match_a_scan() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
        let random: Vec<Point> = (0..700).map(|_| [rng.random::<f64>(), rng.random::<f64>() * 3.0, 0.0, rng.random::<f64>()]).collect();
        let grid: Vec<Point> = (0..600).map(|i| [(i % 10) as f64, ((i / 10) % 6) as f64, 0.0, (i / 60) as f64]).collect();
        for points in [random, grid] {
            let mut tree = KdTree::new(points.clone());
            let mut alive = vec![true; points.len()];
            for round in 0..4 {
                for _ in 0..50 {
                    let q = [rng.random::<f64>() * 10.0, rng.random::<f64>() * 6.0, 0.0, rng.random::<f64>() * 10.0];
                    for k in [1, 5, 12] {
                        assert_eq!(tree.nearest(&q, k, true), brute(&points, &q, k, &alive), "round {round} k {k}");
                        assert_eq!(tree.nearest(&q, k, false), brute(&points, &q, k, &vec![true; points.len()]));
                    }
                }
                for _ in 0..points.len() / 5 {
                    let i = rng.random_range(0..points.len());
                    tree.remove(i as u32);
                    alive[i] = false;
                }
                assert_eq!(tree.live(), alive.iter().filter(|&&a| a).count());
            }
        }
    }

    #[test]
    fn empty_and_all_removed() {
        let tree = KdTree::new(Vec::new());
        assert!(tree.nearest(&[0.0; 4], 3, true).is_empty());
        let mut tree = KdTree::new(vec![[1.0, 0.0, 0.0, 0.0]; 20]);
        for i in 0..20 {
            tree.remove(i);
        }
        assert_eq!(tree.live(), 0);
        assert!(tree.nearest(&[0.0; 4], 3, true).is_empty());
        assert_eq!(tree.nearest(&[0.0; 4], 2, false), vec![(1.0, 0), (1.0, 1)]);
    }
}
