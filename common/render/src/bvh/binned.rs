//! The binary tree the collapse starts from, built top-down by the surface area heuristic over
//! binned centroids (Wald 2007, "On fast construction of SAH-based bounding volume
//! hierarchies"), as Embree's builders do.
//!
//! It replaced obvhs' PLOC build for triangles, which on the Stanford dragon (871k triangles,
//! 2 threads) took 0.25 s at obvhs' fastest preset and 0.40 s at the one used, where Embree
//! builds its whole BVH8 in about 0.24 s; the tree it gave rays was no better (its reinsertion
//! pass changed primary and AO rays by under 2 %). obvhs still builds the particles' tree.
//!
//! Leaves take the triangles in depth-first order, so every subtree's slots are one run (what
//! the collapse needs), and a node's two children sit side by side. The same triangles give the
//! same tree on any number of threads: every choice depends on the triangles alone, and the two
//! halves of a large node, built in parallel, are joined in a fixed order.

use crate::bvh::node::BvhNode;
use glam::{Vec3, Vec3A};
use rayon::prelude::*;

/// Centroid bins per axis for a large node, and for one of fewer than [`FEW`] triangles,
/// where setting up 32 bins cost more than binning.
const BINS: usize = 32;
const FEW_BINS: usize = 8;
const FEW: usize = 256;

/// Every node of this many triangles or fewer is a leaf, as in Embree's BVH8 of four-triangle
/// leaves (the collapse joins leaves up to its own limit). Against leaves chosen by the
/// heuristic from one to four triangles, on the dragon: 576k binary nodes instead of 961k, the
/// build 0.31 s instead of 0.45 s, 13.9 bytes of wide nodes a triangle instead of 17.1, and
/// eye-light and AO rays 2-4 % faster (2 threads).
const MAX_LEAF: usize = 4;

/// Nodes of more triangles than this build their two halves in parallel; smaller ones are not
/// worth a task.
const PARALLEL_FROM: usize = 4096;

/// Nodes of more triangles than this are binned in parallel, in chunks of this many.
const PARALLEL_BINNING: usize = 1 << 16;

/// Below this depth every node is split at its median instead: a scene built to defeat the
/// heuristic (triangles at exponentially growing distances) cannot make the tree deeper than
/// this plus the median split's log2 of its size.
const HEURISTIC_DEPTH: u32 = 48;

/// Coordinates are clamped to this, so sums and areas of boxes stay free of NaN.
const FAR: f32 = 1e30;

/// One triangle's box as the build sees it (its scene index lives beside it, in `index`).
#[derive(Clone, Copy)]
pub(crate) struct Prim {
    lo: Vec3A,
    hi: Vec3A,
}

impl Prim {
    /// The box of `corners`. Non-finite coordinates are dropped or clamped: such a triangle is
    /// never hit, and only needs a box that keeps the build's arithmetic finite.
    pub(crate) fn new(corners: [Vec3; 3]) -> Self {
        let [a, b, c] = corners;
        // Scalar min and max ignore a NaN operand.
        let clean = |v: Vec3| Vec3A::from(v.to_array().map(finite_or_zero));
        Prim {
            lo: clean(a.min(b).min(c)),
            hi: clean(a.max(b).max(c)),
        }
    }

    /// Twice the box's centre: binning needs only the order, so the halving is skipped.
    #[inline(always)]
    fn centroid2(&self) -> Vec3A {
        self.lo + self.hi
    }
}

fn finite_or_zero(x: f32) -> f32 {
    if x.is_nan() {
        0.0
    } else {
        x.clamp(-FAR, FAR)
    }
}

/// A box; empty when inverted.
#[derive(Clone, Copy)]
struct Aabb {
    lo: Vec3A,
    hi: Vec3A,
}

impl Aabb {
    const EMPTY: Aabb = Aabb {
        lo: Vec3A::splat(f32::INFINITY),
        hi: Vec3A::splat(f32::NEG_INFINITY),
    };

    #[inline(always)]
    fn grow(&mut self, lo: Vec3A, hi: Vec3A) {
        self.lo = self.lo.min(lo);
        self.hi = self.hi.max(hi);
    }

    #[inline(always)]
    fn join(&self, other: &Aabb) -> Aabb {
        Aabb {
            lo: self.lo.min(other.lo),
            hi: self.hi.max(other.hi),
        }
    }

    /// Half the surface area; zero for an empty box.
    #[inline(always)]
    fn half_area(&self) -> f32 {
        let d = (self.hi - self.lo).max(Vec3A::ZERO);
        d.x * d.y + d.y * d.z + d.z * d.x
    }
}

/// A node's triangles as the heuristic needs them: their box and their centroids' box.
#[derive(Clone, Copy)]
struct Span {
    bounds: Aabb,
    centroids: Aabb,
}

impl Span {
    const EMPTY: Span = Span {
        bounds: Aabb::EMPTY,
        centroids: Aabb::EMPTY,
    };

    #[inline(always)]
    fn add(&mut self, p: &Prim) {
        self.bounds.grow(p.lo, p.hi);
        let c = p.centroid2();
        self.centroids.grow(c, c);
    }

    fn of(prims: &[Prim]) -> Span {
        let mut span = Span::EMPTY;
        prims.iter().for_each(|p| span.add(p));
        span
    }
}

/// Where the heuristic splits a node: triangles whose centroid falls in bins `..=last_left`
/// of `axis` go left.
#[derive(Clone, Copy)]
struct Split {
    axis: usize,
    last_left: usize,
    /// Sum over both sides of half area times triangles.
    cost: f32,
}

/// One bin of one axis: the box of its triangles and how many.
#[derive(Clone, Copy)]
struct Bin {
    bounds: Aabb,
    count: u32,
}

impl Bin {
    const EMPTY: Bin = Bin {
        bounds: Aabb::EMPTY,
        count: 0,
    };
}

/// The binning of one node into `B` bins per axis: the centroids' origin and bins per unit.
struct Binning<const B: usize> {
    origin: Vec3A,
    scale: Vec3A,
}

impl<const B: usize> Binning<B> {
    fn new(centroids: &Aabb) -> Self {
        let extent = centroids.hi - centroids.lo;
        // A flat axis puts everything in bin 0, which no split separates.
        let scale = Vec3A::from(extent.to_array().map(|e| {
            if e > 0.0 && e.is_finite() {
                B as f32 * (1.0 - 1e-5) / e
            } else {
                0.0
            }
        }));
        Binning {
            origin: centroids.lo,
            scale,
        }
    }

    /// Where centroid `c2` falls, in bins, on each axis: from 0 to `B - 1` (the centroids are
    /// finite and none lies below the origin, their minimum).
    #[inline(always)]
    fn position(&self, c2: Vec3A) -> Vec3A {
        ((c2 - self.origin) * self.scale).min(Vec3A::splat((B - 1) as f32))
    }

    /// The bins of centroid `c2` on the three axes.
    #[inline(always)]
    fn bins(&self, c2: Vec3A) -> [usize; 3] {
        truncate(self.position(c2))
    }

    /// Bins `prims` (in parallel chunks for a large node: the bins' boxes and counts are
    /// the same whichever way they are summed).
    fn fill(&self, prims: &[Prim]) -> [[Bin; B]; 3] {
        if prims.len() > PARALLEL_BINNING {
            return (prims.par_chunks(PARALLEL_BINNING))
                .map(|chunk| self.fill(chunk))
                .reduce(|| [[Bin::EMPTY; B]; 3], |a, b| merge(&a, &b));
        }
        let mut bins = [[Bin::EMPTY; B]; 3];
        for p in prims {
            for (axis, b) in self.bins(p.centroid2()).into_iter().enumerate() {
                let bin = &mut bins[axis][b];
                bin.bounds.grow(p.lo, p.hi);
                bin.count += 1;
            }
        }
        bins
    }

    /// The cheapest split by the heuristic, if any bin boundary has triangles on both sides.
    fn best_split(&self, prims: &[Prim]) -> Option<Split> {
        let bins = self.fill(prims);
        let mut best: Option<Split> = None;
        for (axis, bins) in bins.iter().enumerate() {
            let mut right = [f32::NAN; B];
            let (mut acc, mut count) = (Aabb::EMPTY, 0u32);
            for b in (1..B).rev() {
                acc = acc.join(&bins[b].bounds);
                count += bins[b].count;
                if count > 0 {
                    right[b] = acc.half_area() * count as f32;
                }
            }
            let (mut acc, mut count) = (Aabb::EMPTY, 0u32);
            for last_left in 0..B - 1 {
                acc = acc.join(&bins[last_left].bounds);
                count += bins[last_left].count;
                let cost = acc.half_area() * count as f32 + right[last_left + 1];
                // An empty side costs NaN; ties keep the first split found.
                if count > 0 && !cost.is_nan() && best.is_none_or(|b| cost < b.cost) {
                    best = Some(Split {
                        axis,
                        last_left,
                        cost,
                    });
                }
            }
        }
        best
    }

    /// Moves the triangles left of `split` before the others (and their indices with them),
    /// measuring both sides as it goes.
    fn partition(&self, prims: &mut [Prim], index: &mut [u32], split: Split) -> Halves {
        let (mut left, mut right) = (Span::EMPTY, Span::EMPTY);
        let (mut i, mut j) = (0, prims.len());
        // Bin `last_left` or lower is a position below the next bin's start.
        let bound = (split.last_left + 1) as f32;
        while i < j {
            if self.position(prims[i].centroid2())[split.axis] < bound {
                left.add(&prims[i]);
                i += 1;
            } else {
                j -= 1;
                prims.swap(i, j);
                index.swap(i, j);
                right.add(&prims[j]);
            }
        }
        (i, left, right)
    }
}

/// The lanes of `v`, in `0..2^31`, truncated to integers (`as` adds a range check per lane,
/// which cost a third of the binning).
#[inline(always)]
fn truncate(v: Vec3A) -> [usize; 3] {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{__m128i, _mm_cvttps_epi32};
        // SAFETY: SSE2 is part of every x86_64 CPU.
        let truncated = unsafe { _mm_cvttps_epi32(v.into()) };
        let lanes = bytemuck::cast::<__m128i, [i32; 4]>(truncated);
        [lanes[0] as usize, lanes[1] as usize, lanes[2] as usize]
    }
    #[cfg(not(target_arch = "x86_64"))]
    v.to_array().map(|x| x as usize)
}

fn merge<const B: usize>(a: &[[Bin; B]; 3], b: &[[Bin; B]; 3]) -> [[Bin; B]; 3] {
    std::array::from_fn(|axis| {
        std::array::from_fn(|k| Bin {
            bounds: a[axis][k].bounds.join(&b[axis][k].bounds),
            count: a[axis][k].count + b[axis][k].count,
        })
    })
}

/// Where a node was split and the two sides' spans.
type Halves = (usize, Span, Span);

/// Builds the binary tree over `prims`, reordering them and `index` (each triangle's scene
/// index) into leaf order. Returns the nodes, the root first and a node's children side by
/// side, and the tree's depth.
pub(crate) fn build(prims: &mut [Prim], index: &mut [u32]) -> (Vec<BvhNode>, usize) {
    if prims.is_empty() {
        return (Vec::new(), 0);
    }
    let span = Span::of(prims);
    let (nodes, depth) = subtree(prims, index, 0, span, 0);
    (nodes, depth as usize)
}

/// The subtree over `prims`, whose first slot is `first_slot`, as its own array (root at 0).
fn subtree(
    prims: &mut [Prim],
    index: &mut [u32],
    first_slot: u32,
    span: Span,
    depth: u32,
) -> (Vec<BvhNode>, u32) {
    let mut out = vec![node(&span, first_slot, 0)];
    let deepest = grow(prims, index, first_slot, span, depth, 0, &mut out);
    (out, deepest)
}

/// A node over `span`: a leaf of `count` triangles from slot `first`, or (`count` 0) an inner
/// node whose children are at `first` and `first + 1`.
fn node(span: &Span, first: u32, count: usize) -> BvhNode {
    BvhNode {
        min: span.bounds.lo.into(),
        max: span.bounds.hi.into(),
        first,
        count: count as u32,
    }
}

/// Fills node `at` of `out` with the subtree over `prims`; returns the deepest level reached.
fn grow(
    prims: &mut [Prim],
    index: &mut [u32],
    first_slot: u32,
    span: Span,
    depth: u32,
    at: usize,
    out: &mut Vec<BvhNode>,
) -> u32 {
    let n = prims.len();
    let Some((mid, left, right)) = divide(prims, index, &span, depth) else {
        out[at] = node(&span, first_slot, n);
        return depth;
    };
    let (lower, upper) = prims.split_at_mut(mid);
    let (lower_index, upper_index) = index.split_at_mut(mid);
    let right_slot = first_slot + mid as u32;
    if n > PARALLEL_FROM {
        let ((l, ld), (r, rd)) = rayon::join(
            || subtree(lower, lower_index, first_slot, left, depth + 1),
            || subtree(upper, upper_index, right_slot, right, depth + 1),
        );
        append_children(out, at, l, r);
        return ld.max(rd);
    }
    let children = out.len();
    out[at] = node(&span, children as u32, 0);
    out.extend([node(&left, 0, 0), node(&right, 0, 0)]);
    let ld = grow(
        lower,
        lower_index,
        first_slot,
        left,
        depth + 1,
        children,
        out,
    );
    let rd = grow(
        upper,
        upper_index,
        right_slot,
        right,
        depth + 1,
        children + 1,
        out,
    );
    ld.max(rd)
}

/// Makes `left` and `right` (each with its root at 0) the children of node `at` of `out`.
fn append_children(out: &mut Vec<BvhNode>, at: usize, left: Vec<BvhNode>, right: Vec<BvhNode>) {
    let children = out.len();
    out[at].first = children as u32;
    out[at].count = 0;
    // A subtree's node k > 0 lands at base + k - 1; its root at `children` or `children + 1`.
    let left_base = children + 2;
    let right_base = left_base + left.len() - 1;
    let moved = |node: &BvhNode, base: usize| {
        let mut node = *node;
        if node.count == 0 {
            node.first = (base + node.first as usize - 1) as u32;
        }
        node
    };
    out.reserve(left.len() + right.len());
    out.push(moved(&left[0], left_base));
    out.push(moved(&right[0], right_base));
    out.extend(left[1..].iter().map(|n| moved(n, left_base)));
    out.extend(right[1..].iter().map(|n| moved(n, right_base)));
}

/// Splits `prims` in two (reordering them and `index`) where the heuristic says, or at the
/// median when it finds no split or the tree is too deep; `None` when they make a leaf.
fn divide(prims: &mut [Prim], index: &mut [u32], span: &Span, depth: u32) -> Option<Halves> {
    if prims.len() < FEW {
        divide_in::<FEW_BINS>(prims, index, span, depth)
    } else {
        divide_in::<BINS>(prims, index, span, depth)
    }
}

fn divide_in<const B: usize>(
    prims: &mut [Prim],
    index: &mut [u32],
    span: &Span,
    depth: u32,
) -> Option<Halves> {
    if prims.len() <= MAX_LEAF {
        return None;
    }
    let binning = Binning::<B>::new(&span.centroids);
    let split = (depth < HEURISTIC_DEPTH)
        .then(|| binning.best_split(prims))
        .flatten();
    match split {
        Some(split) => Some(binning.partition(prims, index, split)),
        None => Some(median(prims, index, span)),
    }
}

/// Splits at the median centroid on the widest axis (in index order where all are equal).
fn median(prims: &mut [Prim], index: &mut [u32], span: &Span) -> Halves {
    let extent = (span.centroids.hi - span.centroids.lo).to_array();
    let axis = (0..3)
        .filter(|&a| extent[a] > 0.0)
        .max_by(|&a, &b| extent[a].total_cmp(&extent[b]));
    let mid = prims.len() / 2;
    if let Some(axis) = axis {
        // Rare (a degenerate or adversarial node), so the pairs may be copied.
        let mut pairs: Vec<(Prim, u32)> =
            prims.iter().copied().zip(index.iter().copied()).collect();
        pairs.select_nth_unstable_by(mid, |(a, i), (b, j)| {
            (a.centroid2()[axis].total_cmp(&b.centroid2()[axis])).then(i.cmp(j))
        });
        for (k, (p, i)) in pairs.into_iter().enumerate() {
            (prims[k], index[k]) = (p, i);
        }
    }
    let (lower, upper) = prims.split_at(mid);
    (mid, Span::of(lower), Span::of(upper))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn prims(corners: &[[Vec3; 3]]) -> (Vec<Prim>, Vec<u32>) {
        let prims = corners.iter().map(|&c| Prim::new(c)).collect();
        (prims, (0..corners.len() as u32).collect())
    }

    fn tri_at(x: f32) -> [Vec3; 3] {
        [
            Vec3::new(x, 0.0, 0.0),
            Vec3::new(x + 0.5, 0.0, 0.0),
            Vec3::new(x, 0.5, 0.0),
        ]
    }

    /// Every node's box holds its children's (or its leaf's triangles'), children sit side
    /// by side after their parent, and every triangle is in exactly one leaf.
    fn check(nodes: &[BvhNode], (prims, index): &(Vec<Prim>, Vec<u32>)) {
        let mut seen = vec![false; prims.len()];
        let inside = |outer: &BvhNode, lo: Vec3A, hi: Vec3A| {
            let (lo, hi) = (Vec3::from(lo), Vec3::from(hi));
            outer.min.cmple(lo).all() && outer.max.cmpge(hi).all()
        };
        for (i, node) in nodes.iter().enumerate() {
            if node.count == 0 {
                let first = node.first as usize;
                assert!(first > i && first + 1 < nodes.len(), "node {i}");
                for c in [first, first + 1] {
                    assert!(
                        inside(node, nodes[c].min.into(), nodes[c].max.into()),
                        "node {i} child {c}"
                    );
                }
                continue;
            }
            assert!(node.count as usize <= MAX_LEAF);
            for slot in node.first..node.first + node.count {
                let p = &prims[slot as usize];
                assert!(inside(node, p.lo, p.hi), "leaf {i} slot {slot}");
                assert!(!std::mem::replace(
                    &mut seen[index[slot as usize] as usize],
                    true
                ));
            }
        }
        assert!(seen.iter().all(|&s| s), "every triangle in a leaf");
    }

    #[test]
    fn a_row_of_triangles_builds_a_sound_balanced_tree() {
        let mut all = prims(&(0..10_000).map(|i| tri_at(i as f32)).collect::<Vec<_>>());
        let (nodes, depth) = build(&mut all.0, &mut all.1);
        check(&nodes, &all);
        assert!(depth <= 20, "depth {depth} for 10k evenly spaced triangles");
    }

    #[test]
    fn copies_of_one_triangle_split_at_the_median() {
        let mut all = prims(&vec![tri_at(1.0); 5000]);
        let (nodes, depth) = build(&mut all.0, &mut all.1);
        check(&nodes, &all);
        assert!(depth <= 13, "depth {depth}");
    }

    /// Triangles at exponentially growing distances peel off one at a time by the heuristic;
    /// past its depth the median takes over, so the tree stays shallow enough to traverse.
    #[test]
    fn triangles_that_defeat_the_heuristic_still_give_a_bounded_depth() {
        let far: Vec<_> = (0..3000).map(|i| tri_at(1.02f32.powi(i))).collect();
        let mut all = prims(&far);
        let (nodes, depth) = build(&mut all.0, &mut all.1);
        check(&nodes, &all);
        assert!(depth as u32 <= HEURISTIC_DEPTH + 14, "depth {depth}");
    }

    #[test]
    fn nan_and_infinite_corners_neither_panic_nor_lose_a_triangle() {
        let mut corners: Vec<_> = (0..200).map(|i| tri_at(i as f32)).collect();
        corners[7][1].x = f32::NAN;
        corners[9] = [Vec3::splat(f32::INFINITY); 3];
        corners[11][2].y = f32::NEG_INFINITY;
        let mut all = prims(&corners);
        let (nodes, _) = build(&mut all.0, &mut all.1);
        let mut slots: Vec<u32> = (nodes.iter().filter(|n| n.count > 0))
            .flat_map(|n| n.first..n.first + n.count)
            .collect();
        slots.sort_unstable();
        assert_eq!(slots, (0..200).collect::<Vec<u32>>());
    }
}
