//! obvhs' binary tree laid out again depth first, with the scene triangle of each new leaf
//! slot: on one thread for a small tree, split into subtrees laid out on every thread for a
//! large one, and the same array either way.
//!
//! Siblings stay side by side and every inner node's pair of children comes after it: the
//! pair, then the first child's subtree, then the second's. The collapse then fills its table
//! in backward sweeps of the array (`collapse::Plan`); walking obvhs' layout, where a node's
//! children lie anywhere, it missed the cache at every node (140 of the dragon's 560 ms build).
//! Leaf slots are numbered in the same depth-first order, so every subtree's triangles are one
//! run of slots (obvhs' order is not: 62 % of the dragon's subtrees were split) and the
//! collapse may make any small subtree one leaf.

use crate::bvh::node::BvhNode;
use rayon::prelude::*;

/// Trees of fewer nodes are laid out on one thread: splitting them costs more than it saves.
const PARALLEL_FROM: usize = 1 << 16;

/// How many levels below the root a large tree is split at: up to 2^6 pieces, enough for
/// uneven subtrees to share out over a few threads.
const SPLIT_LEVELS: u32 = 6;

/// `nodes` (obvhs' layout, the root first, `node_of` each one in ours) and the leaf slots'
/// triangles `order` laid out depth first: the new nodes and each new slot's triangle. The
/// peak holds the tree's nodes twice either way: obvhs' beside ours on one thread; split, the
/// pieces beside the array they are copied into, obvhs' freed before.
pub(super) fn depth_first<N: Sync>(
    nodes: Vec<N>,
    node_of: impl Fn(&N) -> BvhNode + Sync,
    order: Vec<u32>,
) -> (Vec<BvhNode>, Vec<u32>) {
    if nodes.len() < PARALLEL_FROM {
        one_thread(&nodes, node_of, &order)
    } else {
        split_depth_first(nodes, node_of, order, SPLIT_LEVELS)
    }
}

/// [`depth_first`] on this thread, straight into the array: no plan, no copy.
fn one_thread<N>(
    nodes: &[N],
    node_of: impl Fn(&N) -> BvhNode,
    order: &[u32],
) -> (Vec<BvhNode>, Vec<u32>) {
    let source = Source { nodes, node_of };
    below(source.at(0), &source, order)
}

/// [`depth_first`] split `levels` below the root (0: one piece, copied).
fn split_depth_first<N: Sync>(
    nodes: Vec<N>,
    node_of: impl Fn(&N) -> BvhNode + Sync,
    order: Vec<u32>,
    levels: u32,
) -> (Vec<BvhNode>, Vec<u32>) {
    let source = Source {
        nodes: &nodes,
        node_of,
    };
    let node_at = |i: usize| source.at(i);
    let mut root = node_at(0);
    let mut plan = Plan::default();
    plan.place(Placed::Root, root, levels, &node_at);
    let pieces: Vec<Piece> = plan
        .segments
        .par_iter()
        .map(|segment| segment.lay_out(&source, &order))
        .collect();
    drop(nodes);
    drop(order);
    let (mut laid, slots, node_offsets, slot_offsets) = assemble(&pieces);
    drop(pieces);
    for (placed, target) in plan.patches {
        let node = match placed {
            Placed::Root => &mut root,
            Placed::InPair { segment, which } => &mut laid[node_offsets[segment] + which],
        };
        node.first = if node.count > 0 {
            slot_offsets[target]
        } else {
            node_offsets[target] as u32
        };
    }
    laid[0] = root;
    (laid, slots)
}

/// obvhs' nodes, read as ours.
struct Source<'a, N, F> {
    nodes: &'a [N],
    node_of: F,
}

impl<N, F: Fn(&N) -> BvhNode> Source<'_, N, F> {
    fn at(&self, i: usize) -> BvhNode {
        (self.node_of)(&self.nodes[i])
    }

    /// Starts loading the pair of nodes from `i`.
    fn prefetch_pair(&self, i: usize) {
        if let Some(pair) = self.nodes.get(i..i + 2) {
            // Its first and last byte: a pair may straddle two cache lines.
            let (start, bytes) = (pair.as_ptr() as *const u8, size_of_val(pair));
            crate::bvh::memory::prefetch(start, 1);
            crate::bvh::memory::prefetch(start.wrapping_add(bytes - 1), 1);
        }
    }
}

/// Where a node above the split lies: the root, or one of a pair segment's two.
#[derive(Clone, Copy)]
enum Placed {
    Root,
    InPair { segment: usize, which: usize },
}

/// One run of the new layout, in order.
enum Segment {
    /// The two children of an inner node above the split (obvhs' index of the first).
    Pair(usize),
    /// The slots of a leaf above the split.
    Leaf { first: u32, count: u32 },
    /// Everything below an inner node at the split: its children's pair first.
    Below(BvhNode),
}

/// The segments of the new layout, and each node above the split with the segment its
/// children or slots begin.
#[derive(Default)]
struct Plan {
    segments: Vec<Segment>,
    patches: Vec<(Placed, usize)>,
}

impl Plan {
    /// Plans what lies below `node`, already placed at `placed`, split `levels` further down.
    fn place(
        &mut self,
        placed: Placed,
        node: BvhNode,
        levels: u32,
        node_at: &impl Fn(usize) -> BvhNode,
    ) {
        self.patches.push((placed, self.segments.len()));
        if node.count > 0 {
            let (first, count) = (node.first, node.count);
            self.segments.push(Segment::Leaf { first, count });
        } else if levels == 0 {
            self.segments.push(Segment::Below(node));
        } else {
            let segment = self.segments.len();
            let children = node.first as usize;
            self.segments.push(Segment::Pair(children));
            for which in 0..2 {
                let child = node_at(children + which);
                self.place(
                    Placed::InPair { segment, which },
                    child,
                    levels - 1,
                    node_at,
                );
            }
        }
    }
}

/// A segment laid out: its nodes and slots. A `Below`'s are `relative`: its first node is the
/// node above it, placed already and not copied, and the others point within the piece and to
/// its own slots.
struct Piece {
    nodes: Vec<BvhNode>,
    slots: Vec<u32>,
    relative: bool,
}

impl Piece {
    /// The nodes this piece puts in the array.
    fn own_nodes(&self) -> &[BvhNode] {
        &self.nodes[self.relative as usize..]
    }
}

impl Segment {
    fn lay_out<N, F: Fn(&N) -> BvhNode>(&self, source: &Source<N, F>, order: &[u32]) -> Piece {
        match *self {
            Segment::Pair(children) => Piece {
                nodes: vec![source.at(children), source.at(children + 1)],
                slots: Vec::new(),
                relative: false,
            },
            Segment::Leaf { first, count } => Piece {
                nodes: Vec::new(),
                slots: order[first as usize..(first + count) as usize].to_vec(),
                relative: false,
            },
            Segment::Below(node) => {
                let (nodes, slots) = below(node, source, order);
                Piece {
                    nodes,
                    slots,
                    relative: true,
                }
            }
        }
    }
}

/// `node` at index 0 and everything below it laid out depth first, on this thread; leaf slots
/// numbered from 0.
fn below<N, F: Fn(&N) -> BvhNode>(
    node: BvhNode,
    source: &Source<N, F>,
    order: &[u32],
) -> (Vec<BvhNode>, Vec<u32>) {
    let mut nodes = vec![node];
    let mut renumbered = Vec::new();
    // Nodes of ours still to lay out below, in depth-first order; until then `first` is the
    // children's index in obvhs' layout (or the leaf's first slot in `order`).
    let mut stack = vec![0usize];
    while let Some(at) = stack.pop() {
        let children_to = nodes.len();
        let node = &mut nodes[at];
        if node.count > 0 {
            let slots = node.first as usize..(node.first + node.count) as usize;
            node.first = renumbered.len() as u32;
            renumbered.extend_from_slice(&order[slots]);
            continue;
        }
        let children_from = node.first as usize;
        node.first = children_to as u32;
        let pair = [source.at(children_from), source.at(children_from + 1)];
        // The first child's pair is read next and the second's after the first's subtree:
        // asked for now, obvhs' scattered nodes are in cache by then.
        for child in pair.iter().filter(|c| c.count == 0) {
            source.prefetch_pair(child.first as usize);
        }
        nodes.extend(pair);
        // The second child pushed first, so the first is laid out and numbered first.
        stack.extend([children_to + 1, children_to]);
    }
    (nodes, renumbered)
}

/// The pieces put one after another behind a root slot, on every thread, their own indices
/// made the array's; with each piece's first node and first slot.
fn assemble(pieces: &[Piece]) -> (Vec<BvhNode>, Vec<u32>, Vec<usize>, Vec<u32>) {
    let mut node_offsets = Vec::with_capacity(pieces.len());
    let mut slot_offsets = Vec::with_capacity(pieces.len());
    let (mut node_total, mut slot_total) = (1usize, 0usize);
    for piece in pieces {
        node_offsets.push(node_total);
        slot_offsets.push(slot_total as u32);
        node_total += piece.own_nodes().len();
        slot_total += piece.slots.len();
    }
    let mut nodes: Vec<BvhNode> = bytemuck::zeroed_vec(node_total);
    let mut slots = vec![0u32; slot_total];
    let mut jobs = Vec::with_capacity(pieces.len());
    let (mut node_rest, mut slot_rest) = (&mut nodes[1..], &mut slots[..]);
    for (i, piece) in pieces.iter().enumerate() {
        let (node_part, n) = std::mem::take(&mut node_rest).split_at_mut(piece.own_nodes().len());
        let (slot_part, s) = std::mem::take(&mut slot_rest).split_at_mut(piece.slots.len());
        (node_rest, slot_rest) = (n, s);
        jobs.push((
            piece,
            node_part,
            slot_part,
            node_offsets[i],
            slot_offsets[i],
        ));
    }
    jobs.into_par_iter()
        .for_each(|(piece, node_part, slot_part, node_at, slot_at)| {
            slot_part.copy_from_slice(&piece.slots);
            for (to, from) in node_part.iter_mut().zip(piece.own_nodes()) {
                *to = *from;
                if piece.relative {
                    // Index 0 of the piece is the node above it, not copied.
                    to.first += if to.count > 0 {
                        slot_at
                    } else {
                        node_at as u32 - 1
                    };
                }
            }
        });
    (nodes, slots, node_offsets, slot_offsets)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::knot_scene;
    use obvhs::bvh2::builder::build_bvh2_from_tris;
    use std::time::Duration;

    /// The depth-first layout is the same tree: node for node the same boxes and the same
    /// triangles under each leaf; every node's children come after it; each subtree's slots
    /// are one run.
    #[test]
    fn the_depth_first_layout_is_the_same_tree_in_order() {
        let tris = crate::bvh::build::obvhs_triangles(&knot_scene(96, 16));
        let preset = crate::bvh::tree::Accel::preset(tris.len());
        let bvh = build_bvh2_from_tris(&tris, preset, &mut Duration::default());
        let old: Vec<BvhNode> = bvh.nodes.iter().map(BvhNode::from).collect();
        let (new, order) = depth_first(old.clone(), |n| *n, bvh.primitive_indices.clone());
        assert_eq!(new.len(), old.len());
        // (old index, new index); returns the new subtree's slots.
        fn walk(old: &[BvhNode], new: &[BvhNode], o: usize, n: usize) -> (u32, u32) {
            let (a, b) = (&old[o], &new[n]);
            assert_eq!((a.min, a.max, a.count), (b.min, b.max, b.count), "node {n}");
            if b.count > 0 {
                return (b.first, b.count);
            }
            assert!(b.first as usize > n, "node {n}'s children come after it");
            let (f, o) = (b.first as usize, a.first as usize);
            let (first, second) = (walk(old, new, o, f), walk(old, new, o + 1, f + 1));
            assert_eq!(first.0 + first.1, second.0, "node {n}'s slots are one run");
            (first.0, first.1 + second.1)
        }
        assert_eq!(walk(&old, &new, 0, 0), (0, tris.len() as u32));
        // Each leaf holds the triangles it held: compare as sets per leaf via the old order.
        let mut leaves = (Vec::new(), Vec::new());
        for (nodes, slots, out) in [
            (&old, &bvh.primitive_indices, &mut leaves.0),
            (&new, &order, &mut leaves.1),
        ] {
            for node in nodes.iter().filter(|n| n.count > 0) {
                let range = node.first as usize..(node.first + node.count) as usize;
                out.push((node.min.to_array().map(f32::to_bits), slots[range].to_vec()));
            }
            out.sort();
        }
        assert_eq!(leaves.0, leaves.1);
    }

    /// Split at any depth, on any number of threads, the layout is the one-thread one, bit
    /// for bit; also where the split passes leaves (a shallow root leaf, a lopsided tree).
    #[test]
    fn a_split_layout_is_the_one_thread_layout() {
        for scene in [knot_scene(96, 16), knot_scene(3, 3)] {
            let tris = crate::bvh::build::obvhs_triangles(&scene);
            let preset = crate::bvh::tree::Accel::preset(tris.len());
            let bvh = build_bvh2_from_tris(&tris, preset, &mut Duration::default());
            let old: Vec<BvhNode> = bvh.nodes.iter().map(BvhNode::from).collect();
            let order = bvh.primitive_indices.clone();
            let serial = one_thread(&old, |n| *n, &order);
            for levels in [0, 1, 2, 5, SPLIT_LEVELS, 40] {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(levels as usize % 3 + 1)
                    .build()
                    .unwrap();
                let split =
                    pool.install(|| split_depth_first(old.clone(), |n| *n, order.clone(), levels));
                assert_eq!(
                    bytemuck::cast_slice::<_, u8>(&split.0),
                    bytemuck::cast_slice::<_, u8>(&serial.0),
                    "{} nodes split {levels} levels down",
                    old.len()
                );
                assert_eq!(split.1, serial.1, "slots split {levels} levels down");
            }
        }
    }
}
