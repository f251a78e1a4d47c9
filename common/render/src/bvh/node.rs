//! The formats the tree is stored in: the binary node obvhs' tree is flattened into (what the
//! cache stores), the 8-wide node every traversal walks, the leaf triangle, and the hit a search
//! returns. Everything else in `bvh` reads these; this file reads nothing of `bvh`.

use glam::Vec3;

/// One BVH node. Inner nodes have `count == 0` and children at `first` and `first + 1`;
/// leaves hold triangles `first .. first + count` of [`crate::bvh::Accel::triangles`].
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct BvhNode {
    /// Lower corner of the node's box, in render coordinates.
    pub min: Vec3,
    /// Upper corner of the node's box.
    pub max: Vec3,
    /// An inner node's first child (its index in the node array), or a leaf's first triangle slot.
    pub first: u32,
    /// Triangles in a leaf; 0 for an inner node.
    pub count: u32,
}

impl From<&obvhs::bvh2::node::Bvh2Node> for BvhNode {
    fn from(n: &obvhs::bvh2::node::Bvh2Node) -> Self {
        BvhNode {
            min: n.aabb().min.into(),
            max: n.aabb().max.into(),
            first: n.first_index,
            count: n.prim_count,
        }
    }
}

/// A triangle's corners, stored in leaf order.
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct LeafTriangle {
    /// First corner, in render coordinates.
    pub a: Vec3,
    /// Second corner.
    pub b: Vec3,
    /// Third corner.
    pub c: Vec3,
}

/// The closest hit found by [`crate::bvh::Accel::closest_hit`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Distance along the ray to the hit, in units of the ray's direction.
    pub t: f32,
    /// Index into [`crate::bvh::Accel::triangles`] (leaf order).
    pub slot: u32,
}

impl Hit {
    /// Whether a hit at `t` on `slot` beats `best`: nearer, or as near on a lower slot.
    #[inline(always)]
    pub(crate) fn closer(t: f32, slot: u32, best: Option<Hit>) -> bool {
        best.is_none_or(|b| t < b.t || (t == b.t && slot < b.slot))
    }
}

/// Children per node.
pub const WIDTH: usize = 8;

/// One node: up to [`WIDTH`] children, each an inner node (`count == 0`, `child` its index), a leaf
/// (`count` triangles from slot `child`) or empty (`count == EMPTY`).
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C, align(64))]
pub struct WideNode {
    /// Per axis, the children's box minima.
    pub lo: [[f32; WIDTH]; 3],
    /// Per axis, the children's box maxima (minus infinity for an empty slot).
    pub hi: [[f32; WIDTH]; 3],
    /// Per child, the index of an inner child's wide node, or a leaf's first triangle slot.
    pub child: [u32; WIDTH],
    /// Per child, its leaf's triangle count; 0 for an inner child, [`EMPTY`] for no child.
    pub count: [u32; WIDTH],
}

/// `count` of a child slot that holds nothing.
pub const EMPTY: u32 = u32::MAX;

/// A wide node whose every slot is empty, with boxes no ray enters.
pub(crate) const BLANK: WideNode = WideNode {
    lo: [[f32::INFINITY; WIDTH]; 3],
    hi: [[f32::NEG_INFINITY; WIDTH]; 3],
    child: [0; WIDTH],
    count: [EMPTY; WIDTH],
};

/// Makes slot `k` of `node` the binary node `child`, found at `target` (a wide node's index for
/// an inner node, the first triangle slot for a leaf).
pub(crate) fn set_child(node: &mut WideNode, k: usize, child: &BvhNode, target: u32) {
    for axis in 0..3 {
        node.lo[axis][k] = child.min[axis];
        node.hi[axis][k] = child.max[axis];
    }
    node.child[k] = target;
    node.count[k] = child.count;
}
