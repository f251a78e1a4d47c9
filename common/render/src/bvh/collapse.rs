//! The 8-wide tree that every ray walks, collapsed from the binary one obvhs builds. A binary
//! tree costs a dependent memory load per level; this one has about a third as many levels, and
//! one ray tests a node's eight boxes with a few 8-lane instructions (`node_test_ray`).
//!
//! The collapse chooses, by the surface area heuristic, which binary subtrees become one leaf
//! and which inner nodes a wide node takes as its children: the dynamic programme of Ylitie,
//! Karras and Laine (2017, "Efficient incoherent ray traversal on GPUs through compressed wide
//! BVHs", §3.1). Per binary node it keeps the cost of the subtree as at most 1..=8 roots, so a
//! wide node is as full, and a leaf as large, as pays. obvhs leaves most scanned triangles in
//! leaves of one (its SAH stops there); a greedy collapse of that tree gave the Stanford dragon
//! 212,284 wide nodes, a third of them with only two children, and leaves of 1.18 triangles.
//!
//! Leaves only ever join binary subtrees whose triangle slots form one run, so the slots, and
//! with them which triangle wins a tie, are the binary tree's: every pixel stays the same.

use crate::bvh::node::{set_child, BvhNode, WideNode, BLANK, WIDTH};
use rayon::prelude::*;

/// Cost of visiting a wide node, relative to [`TRIANGLE_COST`], per unit of box area.
const NODE_COST: f32 = 1.0;

/// Cost of testing one triangle of a leaf. Leaves of 2 or more are tested 8 at a time
/// (`leaf_ray`) and packets test every triangle across their rays, so a triangle costs well
/// under a node. At 0.08 against 0.3 (leaves of 4.5 triangles on the dragon instead of 2.0,
/// 37,882 wide nodes instead of 68,874), 1 thread: primary rays 8 % faster on the dragon and
/// 6 % on the CT bone, eye-light frames 7 % and 4 %, AO rays 2-4 %, the bunny's the same;
/// 0.15 and 0.04 were no better.
const TRIANGLE_COST: f32 = 0.08;

/// Cost of entering a leaf at all (a stack entry, the loop over its triangles): without it the
/// programme keeps the binary tree's leaves of one, since a wide node's eight boxes cost what
/// two do. On the dragon, against none: 68,870 wide nodes instead of 81,513 and leaves of 2.0
/// triangles instead of 1.6; primary rays 88-90 against 81-83 Mrays/s, AO the same (2 threads).
const LEAF_COST: f32 = 1.0;

/// The most triangles one leaf the collapse makes may hold (the binary tree's own leaves may
/// hold more and stay as they are).
const LEAF_LIMIT: u32 = 8;

/// What the wide tree's shape depends on beyond the binary tree: a cached wide tree made with
/// other costs is built again rather than loaded.
pub(crate) const COSTS_KEY: [f32; 4] = [NODE_COST, TRIANGLE_COST, LEAF_COST, LEAF_LIMIT as f32];

/// A count of [`Span`] for a subtree whose slots are not one run.
const NOT_CONTIGUOUS: u32 = u32::MAX;

/// What the programme chose for one binary node and a number of roots.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Choice {
    /// One root: the whole subtree as one leaf.
    Leaf,
    /// One root: a wide node whose children are the subtree as 8 roots of its children.
    Inner,
    /// As many roots as one fewer allows.
    Fewer,
    /// This many roots to the first child, the rest to the second.
    Split(u8),
}

/// A subtree's leaf slots: the first and how many.
type Span = (u32, u32);

fn area(n: &BvhNode) -> f32 {
    let d = (n.max - n.min).max(glam::Vec3::ZERO);
    d.x * d.y + d.y * d.z + d.z * d.x
}

/// Collapses a binary BVH (children of inner node `i` at `first` and `first + 1`, laid out
/// depth first as `layout::depth_first` does) into a wide one, the root first and every wide
/// node before its children. Deterministic, linear in the node count.
pub fn collapse(nodes: &[BvhNode]) -> Vec<WideNode> {
    collapse_with(nodes, PARALLEL_FROM)
}

/// [`collapse`], the table filled in two halves at once for subtrees of `parallel_from` binary
/// nodes or more (see `Table::sweep`): the tree is the same for any `parallel_from`.
pub(crate) fn collapse_with(nodes: &[BvhNode], parallel_from: usize) -> Vec<WideNode> {
    let Some(root) = nodes.first() else {
        return Vec::new();
    };
    let mut out = vec![BLANK];
    if root.count > 0 {
        set_child(&mut out[0], 0, root, root.first);
        return out;
    }
    let plan = Plan::new(nodes, parallel_from);
    let mut stack = vec![(0u32, 0usize)];
    let mut roots = Vec::with_capacity(WIDTH);
    while let Some((index, at)) = stack.pop() {
        roots.clear();
        plan.roots_of_children(index, &mut roots);
        for (k, &c) in roots.iter().enumerate() {
            let child = &nodes[c as usize];
            if let Some((first, count)) = plan.leaf(c) {
                let leaf = BvhNode {
                    first,
                    count,
                    ..*child
                };
                set_child(&mut out[at], k, &leaf, first);
            } else {
                let next = out.len();
                out.push(BLANK);
                set_child(&mut out[at], k, child, next as u32);
                stack.push((c, next));
            }
        }
    }
    out.shrink_to_fit();
    out
}

/// The programme's table: per binary node and number of roots, the choice.
struct Plan<'a> {
    nodes: &'a [BvhNode],
    spans: Vec<Span>,
    /// Per node, the choice for 1..=8 roots, then the split of a wide node's children.
    choices: Vec<[Choice; WIDTH + 1]>,
}

impl<'a> Plan<'a> {
    /// Fills the table children first, in backward sweeps of the depth-first layout: there
    /// every node's pair of children comes after it, the pair before the first child's subtree
    /// and that before the second's. A subtree's costs are needed only until its parent's are
    /// known, so they live on a stack as deep as the tree, not in a table: a table of them was
    /// 32 bytes a binary node, about 55 a triangle, during the build. Sweeping a pair leaves its
    /// first node's costs on top of its second's, where their parent finds them. The two
    /// subtrees below a node are two runs of the layout, so large ones are swept on two
    /// threads ([`Table::sweep`]) from `parallel_from` nodes on; the table is the same.
    fn new(nodes: &'a [BvhNode], parallel_from: usize) -> Self {
        // Filled (and faulted in) on every thread, 26 bytes a binary node: the dragon's build
        // at 2 threads 2.86 -> 2.92 Mtris/s, medians of 5 alternated.
        let mut spans = Vec::with_capacity(nodes.len());
        spans.par_extend(rayon::iter::repeat_n((0, NOT_CONTIGUOUS), nodes.len()));
        let mut choices = Vec::with_capacity(nodes.len());
        choices.par_extend(rayon::iter::repeat_n(
            [Choice::Leaf; WIDTH + 1],
            nodes.len(),
        ));
        let mut table = Table {
            nodes,
            parallel_from,
            base: 0,
            spans: &mut spans,
            choices: &mut choices,
        };
        let mut costs: Vec<[f32; WIDTH]> = Vec::new();
        if nodes.len() > 1 {
            table.sweep(1, nodes.len(), &mut costs);
        }
        table.settle(0, &mut costs);
        Plan {
            nodes,
            spans,
            choices,
        }
    }

    /// The slots of binary node `c` if the plan makes it a leaf.
    fn leaf(&self, c: u32) -> Option<Span> {
        let leaf =
            self.nodes[c as usize].count > 0 || matches!(self.choices[c as usize][0], Choice::Leaf);
        leaf.then_some(self.spans[c as usize])
    }

    /// Appends the roots that inner node `index`'s children become as a wide node's children.
    fn roots_of_children(&self, index: u32, out: &mut Vec<u32>) {
        let Choice::Split(k) = self.choices[index as usize][WIDTH] else {
            unreachable!("an inner node keeps its wide split")
        };
        self.split(index, k as usize, WIDTH, out);
    }

    /// Appends the roots of inner node `index`'s children: `k` of the first, the rest of the
    /// `roots` of the second.
    fn split(&self, index: u32, k: usize, roots: usize, out: &mut Vec<u32>) {
        let first = self.nodes[index as usize].first;
        self.roots_of(first, k, out);
        self.roots_of(first + 1, roots - k, out);
    }

    /// Appends the roots binary node `c` becomes as at most `roots` of them.
    fn roots_of(&self, c: u32, roots: usize, out: &mut Vec<u32>) {
        let mut count = roots;
        loop {
            match self.choices[c as usize][count - 1] {
                _ if self.nodes[c as usize].count > 0 || count == 1 => return out.push(c),
                Choice::Fewer => count -= 1,
                Choice::Split(k) => return self.split(c, k as usize, count, out),
                Choice::Leaf | Choice::Inner => return out.push(c),
            }
        }
    }
}

/// Subtrees below this many binary nodes are swept on one thread.
const PARALLEL_FROM: usize = 1 << 16;

/// The part of the programme's table from binary node `base` on: what one sweep writes.
struct Table<'t> {
    nodes: &'t [BvhNode],
    /// Subtrees of this many nodes or more are swept in two halves at once.
    parallel_from: usize,
    base: usize,
    spans: &'t mut [Span],
    choices: &'t mut [[Choice; WIDTH + 1]],
}

impl Table<'_> {
    /// Fills the table for the nodes `pair..end`: the subtree below a node whose children are
    /// at `pair` and `pair + 1`, laid out depth first. Leaves the pair's costs on `costs`, the
    /// first node's on top. Large subtrees sweep their two halves on two threads.
    fn sweep(&mut self, pair: usize, end: usize, costs: &mut Vec<[f32; WIDTH]>) {
        if end - pair < self.parallel_from {
            let mut at = end;
            while at > pair {
                at -= 2;
                let first = self.settle(at, costs);
                let second = self.settle(at + 1, costs);
                costs.extend([second, first]);
            }
            return;
        }
        // The first child's subtree, then the second's: the second's starts at its pair.
        let second = &self.nodes[pair + 1];
        let middle = if second.count > 0 {
            end
        } else {
            second.first as usize
        };
        let (mut first_costs, mut second_costs) = (Vec::new(), Vec::new());
        {
            let (mut below_first, mut below_second) = self.split(pair + 2, middle);
            rayon::join(
                || {
                    if middle > pair + 2 {
                        below_first.sweep(pair + 2, middle, &mut first_costs);
                    }
                },
                || {
                    if end > middle {
                        below_second.sweep(middle, end, &mut second_costs);
                    }
                },
            );
        }
        let first = self.settle(pair, &mut first_costs);
        let second = self.settle(pair + 1, &mut second_costs);
        costs.extend([second, first]);
    }

    /// The table from node `from` to `middle`, and from `middle` on.
    fn split(&mut self, from: usize, middle: usize) -> (Table<'_>, Table<'_>) {
        let at = from - self.base;
        let (spans, choices) = (&mut self.spans[at..], &mut self.choices[at..]);
        let (first_spans, second_spans) = spans.split_at_mut(middle - from);
        let (first_choices, second_choices) = choices.split_at_mut(middle - from);
        let table = |base, spans, choices| Table {
            nodes: self.nodes,
            parallel_from: self.parallel_from,
            base,
            spans,
            choices,
        };
        (
            table(from, first_spans, first_choices),
            table(middle, second_spans, second_choices),
        )
    }

    /// Node `i`'s costs as 1..=8 roots, and its table entry; an inner node's children's
    /// costs are popped off `costs`, the first child's on top.
    fn settle(&mut self, i: usize, costs: &mut Vec<[f32; WIDTH]>) -> [f32; WIDTH] {
        let n = &self.nodes[i];
        let at = i - self.base;
        if n.count > 0 {
            self.spans[at] = (n.first, n.count);
            return [area(n) * (LEAF_COST + n.count as f32 * TRIANGLE_COST); WIDTH];
        }
        let (l, r) = (
            n.first as usize - self.base,
            n.first as usize + 1 - self.base,
        );
        self.spans[at] = join(self.spans[l], self.spans[r]);
        let left = costs.pop().expect("the first child's costs");
        let right = costs.pop().expect("the second child's costs");
        let (cost, choice) = node_costs(area(n), self.spans[at], &left, &right);
        self.choices[at] = choice;
        cost
    }
}

/// Per number of roots, the cheapest split of them between two children (the cost, and the
/// first child's share: the smallest of the cheapest), where the children's costs stop falling
/// at `a` and `b` roots. More roots than `a + b` split no cheaper than `a + b` do, so those
/// rows are left infinite (the choice for them is `Fewer` either way), and a first child given
/// more than `a` is never cheaper, nor first, than given `a`: neither is tried (most nodes lie
/// near the leaves, where `a + b` is 2 or 3), except the 8 roots' split, which a wide node
/// keeps. The node's costs and choices are the same as from trying every split.
fn splits(left: &[f32; WIDTH], right: &[f32; WIDTH]) -> [(f32, u8); WIDTH] {
    let (a, b) = (falls_until(left), falls_until(right));
    let mut split = [(f32::INFINITY, 0u8); WIDTH];
    for roots in (2..=WIDTH).filter(|&r| r <= a + b || r == WIDTH) {
        for k in 1..roots.min(a + 1) {
            let c = left[k - 1] + right[roots - k - 1];
            if c < split[roots - 1].0 {
                split[roots - 1] = (c, k as u8);
            }
        }
    }
    split
}

/// The fewest roots at which `costs` (never rising with more roots) reach their last value:
/// from there on every entry equals it.
fn falls_until(costs: &[f32; WIDTH]) -> usize {
    let last = costs[WIDTH - 1];
    (1..WIDTH)
        .rev()
        .find(|&r| costs[r - 1] != last)
        .map_or(1, |r| r + 1)
}

/// An inner node's cost as at most 1..=8 roots, and the choices, from its children's.
fn node_costs(
    area: f32,
    span: Span,
    left: &[f32; WIDTH],
    right: &[f32; WIDTH],
) -> ([f32; WIDTH], [Choice; WIDTH + 1]) {
    choose(area, span, &splits(left, right))
}

/// [`node_costs`] from the cheapest splits of each number of roots.
fn choose(
    area: f32,
    span: Span,
    split: &[(f32, u8); WIDTH],
) -> ([f32; WIDTH], [Choice; WIDTH + 1]) {
    let mut cost = [f32::INFINITY; WIDTH];
    let mut choice = [Choice::Fewer; WIDTH + 1];
    let inner = area * NODE_COST + split[WIDTH - 1].0;
    choice[WIDTH] = Choice::Split(split[WIDTH - 1].1);
    let leaf = if span.1 != NOT_CONTIGUOUS && span.1 <= LEAF_LIMIT {
        area * (LEAF_COST + span.1 as f32 * TRIANGLE_COST)
    } else {
        f32::INFINITY
    };
    (cost[0], choice[0]) = if leaf <= inner {
        (leaf, Choice::Leaf)
    } else {
        (inner, Choice::Inner)
    };
    for roots in 2..=WIDTH {
        let (c, k) = split[roots - 1];
        (cost[roots - 1], choice[roots - 1]) = if c < cost[roots - 2] {
            (c, Choice::Split(k))
        } else {
            (cost[roots - 2], Choice::Fewer)
        };
    }
    (cost, choice)
}

/// The two children's slot runs as one, if they adjoin.
fn join(a: Span, b: Span) -> Span {
    let whole = a.1 != NOT_CONTIGUOUS && b.1 != NOT_CONTIGUOUS;
    match () {
        _ if whole && a.0 + a.1 == b.0 => (a.0, a.1 + b.1),
        _ if whole && b.0 + b.1 == a.0 => (b.0, a.1 + b.1),
        _ => (0, NOT_CONTIGUOUS),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every split tried, the reference `splits` must equal.
    fn every_split(left: &[f32; WIDTH], right: &[f32; WIDTH]) -> [(f32, u8); WIDTH] {
        let mut split = [(f32::INFINITY, 0u8); WIDTH];
        for roots in 2..=WIDTH {
            for k in 1..roots {
                let c = left[k - 1] + right[roots - k - 1];
                if c < split[roots - 1].0 {
                    split[roots - 1] = (c, k as u8);
                }
            }
        }
        split
    }

    /// Costs that never rise with more roots, with plateaus and ties as the programme makes
    /// them (a root more that buys nothing repeats the cost exactly), a leaf's flat ones too.
    fn costs(seed: &mut u64) -> [f32; WIDTH] {
        let mut next = || {
            *seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (*seed >> 33) as u32
        };
        let mut c = [(next() % 64) as f32 * 0.25 + 1.0; WIDTH];
        for r in 1..WIDTH {
            c[r] = match next() % 3 {
                0 => c[r - 1],
                _ => c[r - 1] - (next() % 4) as f32 * 0.25,
            };
        }
        c
    }

    #[test]
    fn splits_tried_only_where_they_can_win_choose_as_every_split_does() {
        let mut seed = 7;
        for _ in 0..20_000 {
            let (left, right) = (costs(&mut seed), costs(&mut seed));
            let area = (seed >> 40) as f32 * 1e-6;
            for span in [(0, 2), (0, 9), (0, NOT_CONTIGUOUS)] {
                let fast = node_costs(area, span, &left, &right);
                let every = choose(area, span, &every_split(&left, &right));
                assert_eq!(fast.1, every.1, "{left:?} {right:?}");
                assert_eq!(fast.0.map(f32::to_bits), every.0.map(f32::to_bits));
            }
        }
        let nan = [f32::NAN; WIDTH];
        assert_eq!(falls_until(&nan), WIDTH, "NaN costs try every split");
    }
}
