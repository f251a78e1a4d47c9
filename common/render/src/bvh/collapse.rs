//! The 8-wide tree that every ray walks, collapsed from the binary one obvhs builds. A binary
//! tree costs a dependent memory load per level; this one has about a third as many levels, and
//! one ray tests a node's eight boxes with a few 8-lane instructions (`node_test_ray`). Leaves
//! are the binary tree's own: the same triangle slots.
//!
//! Measured against a 4-wide collapse (1 thread, AVX2/AVX-512 builds; bunny and the 4.2M
//! knot): single shadow and AO rays 15-20 % faster, packets the same within noise, 3.9 bytes a
//! triangle more (its nodes are fuller at 4).

use crate::bvh::node::{set_child, BvhNode, WideNode, BLANK, WIDTH};

fn area(n: &BvhNode) -> f32 {
    let d = (n.max - n.min).max(glam::Vec3::ZERO);
    d.x * d.y + d.y * d.z + d.z * d.x
}

/// Collapses a binary BVH (children of inner node `i` at `first` and `first + 1`) into a
/// wide one: each wide node takes its binary node's children and keeps opening the largest
/// inner one among them until it has [`WIDTH`]. Deterministic, linear in the node count.
pub fn collapse(nodes: &[BvhNode]) -> Vec<WideNode> {
    let Some(root) = nodes.first() else {
        return Vec::new();
    };
    // Every 8-wide node opens at least one binary inner node, so this never grows: growing by
    // doubling copied the array and left the old copies resident (83 MB for a 49 MB tree).
    // The untouched rest of the reservation is never resident, and is given back below.
    let inner = nodes.iter().filter(|n| n.count == 0).count();
    let mut out = Vec::with_capacity(inner.max(1));
    out.push(BLANK);
    let mut stack: Vec<(u32, usize)> = Vec::new();
    if root.count > 0 {
        set_child(&mut out[0], 0, root, 0);
        return out;
    }
    stack.push((0, 0));
    while let Some((index, at)) = stack.pop() {
        let node = &nodes[index as usize];
        // The children so far, in a fixed array (no allocation per wide node).
        let mut children = [0u32; WIDTH];
        (children[0], children[1]) = (node.first, node.first + 1);
        let mut len = 2;
        while len < WIDTH {
            let widest = children[..len]
                .iter()
                .enumerate()
                .filter(|(_, &c)| nodes[c as usize].count == 0)
                .max_by(|a, b| area(&nodes[*a.1 as usize]).total_cmp(&area(&nodes[*b.1 as usize])))
                .map(|(k, _)| k);
            let Some(k) = widest else { break };
            // Child k opens into its two children, in its place.
            let first = nodes[children[k] as usize].first;
            children.copy_within(k + 1..len, k + 2);
            (children[k], children[k + 1]) = (first, first + 1);
            len += 1;
        }
        for (k, &c) in children[..len].iter().enumerate() {
            let child = &nodes[c as usize];
            if child.count > 0 {
                set_child(&mut out[at], k, child, child.first);
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
