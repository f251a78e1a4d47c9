//! The 8-wide tree written block by block (Ize et al. §4.1): each block holds a subtree in
//! breadth-first order, so a traversal that enters a block walks a few levels before it needs
//! another; the subtrees hanging off a block's last level start the following blocks, depth
//! first, with no gap between subtrees. A node's inner children stay adjacent, so one fetch
//! usually brings all of them.
//!
//! Only where nodes sit changes, never the tree: the same boxes, children and leaves, so a
//! traversal visits the same leaves in the same order and returns the same hits.

use crate::bvh::node::{WideNode, WIDTH};
use std::collections::VecDeque;

/// The inner children of `node`, in child order.
fn inner_children(node: &WideNode) -> Vec<u32> {
    (0..WIDTH)
        .filter(|&k| node.count[k] == 0)
        .map(|k| node.child[k])
        .collect()
}

/// `wide` with its nodes reordered for blocks of `per_block` nodes (see the module doc); the
/// root stays node 0 and every inner child index is rewritten. Where the collapse's own order
/// (depth first, a node's inner children adjacent) changes blocks less on the paths down, it
/// is kept: on a knot of 38k nodes it did at 8, 16 and 32 nodes a block (27,613 changes
/// against 29,253 at 32, the default block's), and the block order won from 64 up (18,087
/// against 23,737).
pub fn reorder_for_blocks(wide: &[WideNode], per_block: usize) -> Vec<WideNode> {
    let reordered = block_ordered(wide, per_block);
    if path_switches(&reordered, per_block) < path_switches(wide, per_block) {
        reordered
    } else {
        wide.to_vec()
    }
}

/// Block changes along every root-to-leaf path, summed: what a traversal pays in block
/// lookups on its way down.
fn path_switches(wide: &[WideNode], per_block: usize) -> usize {
    let mut total = 0;
    let mut stack = Vec::new();
    if !wide.is_empty() {
        stack.push((0u32, 0usize));
    }
    while let Some((n, switches)) = stack.pop() {
        let node = &wide[n as usize];
        for k in 0..WIDTH {
            match node.count[k] {
                crate::bvh::node::EMPTY => {}
                0 => {
                    let c = node.child[k];
                    let crossed = (c as usize / per_block != n as usize / per_block) as usize;
                    stack.push((c, switches + crossed));
                }
                _ => total += switches,
            }
        }
    }
    total
}

/// `wide` in [`block_order`].
fn block_ordered(wide: &[WideNode], per_block: usize) -> Vec<WideNode> {
    let order = block_order(wide, per_block.max(WIDTH));
    let mut new_index = vec![u32::MAX; wide.len()];
    for (new, &old) in order.iter().enumerate() {
        new_index[old as usize] = new as u32;
    }
    order
        .iter()
        .map(|&old| {
            let mut node = wide[old as usize];
            for k in 0..WIDTH {
                if node.count[k] == 0 {
                    node.child[k] = new_index[node.child[k] as usize];
                }
            }
            node
        })
        .collect()
}

/// The old index of each node in its new place.
fn block_order(wide: &[WideNode], per_block: usize) -> Vec<u32> {
    let mut order: Vec<u32> = Vec::with_capacity(wide.len());
    if wide.is_empty() {
        return order;
    }
    // Sibling groups that start a subtree of their own, the next on top.
    let mut pending: Vec<Vec<u32>> = vec![vec![0]];
    while let Some(group) = pending.pop() {
        // The subtree fills what is left of the current block; where that is less than its
        // first group, it goes on into the next block (no gap is left: a gap is memory on
        // every node that holds the block, a straddling group one more fetch now and then).
        let mut room = per_block - order.len() % per_block;
        if room < group.len() {
            room += per_block;
        }
        let mut level = VecDeque::from([group]);
        let mut below = Vec::new();
        while let Some(g) = level.pop_front() {
            if g.len() > room {
                below.push(g);
                continue;
            }
            room -= g.len();
            for &n in &g {
                let children = inner_children(&wide[n as usize]);
                if !children.is_empty() {
                    level.push_back(children);
                }
            }
            order.extend(g);
        }
        pending.extend(below.into_iter().rev());
    }
    order
}

/// Whether `a` and `b` are the same tree (same boxes, counts and leaves, children matched
/// through the two orders): what a reorder must keep.
#[cfg(test)]
fn same_tree(a: &[WideNode], b: &[WideNode]) -> bool {
    let mut stack = vec![(0u32, 0u32)];
    let mut seen = 0;
    while let Some((x, y)) = stack.pop() {
        seen += 1;
        let (p, q) = (&a[x as usize], &b[y as usize]);
        if p.lo != q.lo || p.hi != q.hi || p.count != q.count {
            return false;
        }
        for k in 0..WIDTH {
            match p.count[k] {
                crate::bvh::node::EMPTY => {}
                0 => stack.push((p.child[k], q.child[k])),
                _ if p.child[k] != q.child[k] => return false,
                _ => {}
            }
        }
    }
    seen == a.len() && a.len() == b.len()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bvh::Accel;
    use crate::scene::knot_scene;

    #[test]
    fn the_reordered_tree_is_the_same_tree_with_siblings_adjacent() {
        let accel = Accel::build(&knot_scene(300, 24));
        for per_block in [8, 32, 128] {
            let wide = block_ordered(&accel.wide, per_block);
            assert!(same_tree(&accel.wide, &wide), "{per_block} a block");
            for node in &wide {
                let siblings = inner_children(node);
                assert!(
                    siblings.windows(2).all(|w| w[1] == w[0] + 1),
                    "siblings adjacent: {siblings:?}"
                );
            }
        }
    }

    /// The layout kept changes blocks no more often than either candidate, and where blocks
    /// are large the block order is what is kept: a block holding a subtree is what pays.
    #[test]
    fn a_block_holds_a_subtree_so_paths_down_the_tree_change_blocks_less() {
        let accel = Accel::build(&knot_scene(600, 32));
        for per_block in [8, 16, 32, 64, 128, 256] {
            let own = path_switches(&accel.wide, per_block);
            let blocks = path_switches(&block_ordered(&accel.wide, per_block), per_block);
            let kept = path_switches(&reorder_for_blocks(&accel.wide, per_block), per_block);
            eprintln!("{per_block} a block: {own} block changes own order, {blocks} block order");
            assert_eq!(kept, own.min(blocks), "{per_block} a block");
            if per_block >= 128 {
                assert!(blocks < own, "{per_block} a block: {blocks} against {own}");
            }
        }
    }
}
