//! An 8-wide BVH, collapsed from the binary one, that every ray walks (single rays here, packets
//! in `accel_packet`): each node holds up to eight children's boxes in structure-of-arrays
//! form, so one ray tests all of them with a few 8-lane instructions (AVX2, chosen at run time;
//! two 4-lane halves on baseline SSE). A binary tree costs a dependent memory load per level;
//! this one has about a third as many levels. Leaves are the binary tree's own: the same
//! triangle slots.
//!
//! Measured against a 4-wide collapse (1 thread, AVX2/AVX-512 builds; bunny and the 4.2M
//! knot): single shadow and AO rays 15-20 % faster, packets the same within noise, 3.9 bytes a
//! triangle more (its nodes are fuller at 4).
//!
//! Closest hits are order-independent: of two hits at the same distance the lower slot wins,
//! so this traversal and the packet traversal agree bit for bit.

use crate::bvh::memory::{ChildPrefetch, TreeMemory};
use crate::bvh::tree::BvhNode;
use crate::geometry::Ray;

/// Children per node.
pub const WIDTH: usize = 8;

/// One node: up to [`WIDTH`] children, each an inner node (`count == 0`, `child` its index), a leaf
/// (`count` triangles from slot `child`) or empty (`count == EMPTY`).
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C, align(64))]
pub struct WideNode {
    /// Per axis, the children's box minima.
    pub lo: [[f32; WIDTH]; 3],
    pub hi: [[f32; WIDTH]; 3],
    pub child: [u32; WIDTH],
    pub count: [u32; WIDTH],
}

/// `count` of a child slot that holds nothing.
pub const EMPTY: u32 = u32::MAX;

const BLANK: WideNode = WideNode {
    lo: [[f32::INFINITY; WIDTH]; 3],
    hi: [[f32::NEG_INFINITY; WIDTH]; 3],
    child: [0; WIDTH],
    count: [EMPTY; WIDTH],
};

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

fn set_child(node: &mut WideNode, k: usize, child: &BvhNode, target: u32) {
    for axis in 0..3 {
        node.lo[axis][k] = child.min[axis];
        node.hi[axis][k] = child.max[axis];
    }
    node.child[k] = target;
    node.count[k] = child.count;
}

/// Entry distances into the children's boxes before `t_far`; +inf where the ray misses
/// (or the slot is empty). `inv` must be finite (see [`finite_inverse`]), so that no slab
/// distance is a NaN.
#[inline(always)]
pub(crate) fn enter_wide(
    node: &WideNode,
    origin: [f32; 3],
    inv: [f32; 3],
    t_far: f32,
) -> [f32; WIDTH] {
    let (near, entered) = enter_mask(node, origin, inv, t_far);
    std::array::from_fn(|k| {
        if entered >> k & 1 == 1 {
            near[k]
        } else {
            f32::INFINITY
        }
    })
}

/// A test of one ray against a wide node's children: (node, origin, finite inverse
/// direction, `t_far`) to the children's entry distances and, as bits, which of them it
/// enters ([`enter_mask`], or its AVX2 build [`enter_mask_avx2`]). Traversals take it as a
/// parameter so that one traversal serves every SIMD build.
pub(crate) trait NodeTest:
    Fn(&WideNode, [f32; 3], [f32; 3], f32) -> ([f32; WIDTH], u32)
{
}

impl<F: Fn(&WideNode, [f32; 3], [f32; 3], f32) -> ([f32; WIDTH], u32)> NodeTest for F {}

/// The children's entry distances, and as bits (child k is bit k) which of them the ray
/// enters before `t_far`. `inv` must be finite (see [`finite_inverse`]): then no slab
/// distance is a NaN (box corners are finite or, in empty slots, infinite, and `inv` is
/// never 0), so plain compare-selects do what `f32::min`/`max` would, without their NaN
/// handling, which tripled the instructions of this loop.
#[inline(always)]
pub(crate) fn enter_mask(
    node: &WideNode,
    origin: [f32; 3],
    inv: [f32; 3],
    t_far: f32,
) -> ([f32; WIDTH], u32) {
    let mut near = [0f32; WIDTH];
    let mut far = [t_far; WIDTH];
    for axis in 0..3 {
        for k in 0..WIDTH {
            let t0 = (node.lo[axis][k] - origin[axis]) * inv[axis];
            let t1 = (node.hi[axis][k] - origin[axis]) * inv[axis];
            let (lo, hi) = if t0 < t1 { (t0, t1) } else { (t1, t0) };
            near[k] = if lo > near[k] { lo } else { near[k] };
            far[k] = if hi < far[k] { hi } else { far[k] };
        }
    }
    let mut entered = 0u32;
    for k in 0..WIDTH {
        entered |= (((near[k] <= far[k]) & (node.count[k] != EMPTY)) as u32) << k;
    }
    (near, entered)
}

/// [`enter_mask`] in AVX2 intrinsics, the same operations (`vminps`/`vmaxps` are the
/// compare-selects there, with no NaN about): the compiler, left to itself, packed that loop
/// into 4-lane halves for single rays, and AO rays ran 15 % slower than with `f32::min`.
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
pub(crate) unsafe fn enter_mask_avx2(
    node: &WideNode,
    origin: [f32; 3],
    inv: [f32; 3],
    t_far: f32,
) -> ([f32; WIDTH], u32) {
    use std::arch::x86_64::*;
    let mut near = _mm256_setzero_ps();
    let mut far = _mm256_set1_ps(t_far);
    for axis in 0..3 {
        let o = _mm256_set1_ps(origin[axis]);
        let iv = _mm256_set1_ps(inv[axis]);
        // SAFETY: each array holds WIDTH = 8 floats; unaligned loads need no alignment.
        let (lo, hi) = unsafe {
            (
                _mm256_loadu_ps(node.lo[axis].as_ptr()),
                _mm256_loadu_ps(node.hi[axis].as_ptr()),
            )
        };
        let t0 = _mm256_mul_ps(_mm256_sub_ps(lo, o), iv);
        let t1 = _mm256_mul_ps(_mm256_sub_ps(hi, o), iv);
        near = _mm256_max_ps(_mm256_min_ps(t0, t1), near);
        far = _mm256_min_ps(_mm256_max_ps(t0, t1), far);
    }
    let entered = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(near, far)) as u32;
    // SAFETY: `count` holds 8 u32s.
    let count = unsafe { _mm256_loadu_si256(node.count.as_ptr() as *const __m256i) };
    let empty = _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpeq_epi32(
        count,
        _mm256_set1_epi32(EMPTY as i32),
    ))) as u32;
    let mut out = [0f32; WIDTH];
    // SAFETY: `out` holds 8 floats.
    unsafe { _mm256_storeu_ps(out.as_mut_ptr(), near) };
    (out, entered & !empty)
}

/// The ray's inverse direction with an infinite component (a direction parallel to an axis)
/// made the largest finite value of its sign: then an origin exactly on a slab plane gives
/// 0 · MAX = 0 where 0 · inf would give NaN, and the box is entered, as it should be.
pub(crate) fn finite_inverse(ray: &Ray) -> [f32; 3] {
    ray.inv_dir.to_array().map(finite)
}

/// An inverse direction component with an infinity made the largest finite value of its sign.
#[inline(always)]
pub(crate) fn finite(v: f32) -> f32 {
    if v.is_infinite() {
        f32::MAX.copysign(v)
    } else {
        v
    }
}

/// Asks the CPU to start loading what child `k` of `node` points to: its 8-wide node in
/// `nodes`, or its leaf's first items (`leaves`: where the leaf items start and the bytes of
/// one). On a mesh of millions of triangles these loads miss every cache; issued while the
/// nearer siblings are traversed, they took the 4.2M knot's primary rays from 13.1 to 14.6
/// Mrays/s (1 thread, AVX-512).
#[inline(always)]
pub(crate) fn prefetch_child(
    nodes: &[WideNode],
    (leaves, item_bytes): (*const u8, usize),
    node: &WideNode,
    k: usize,
) {
    let (child, count) = (node.child[k] as usize, node.count[k]);
    let (start, bytes) = if count == 0 {
        (
            nodes.as_ptr().wrapping_add(child) as *const u8,
            std::mem::size_of::<WideNode>(),
        )
    } else {
        (
            leaves.wrapping_add(child * item_bytes),
            count as usize * item_bytes,
        )
    };
    prefetch(start, bytes.min(PREFETCH_BYTES));
}

/// The leaf triangles as the prefetcher sees them: where they start and how big one is.
pub(crate) fn leaf_bytes(triangles: &[crate::bvh::tree::LeafTriangle]) -> (*const u8, usize) {
    (
        triangles.as_ptr() as *const u8,
        std::mem::size_of::<crate::bvh::tree::LeafTriangle>(),
    )
}

/// At most this much of a child is prefetched: a node's boxes, or a leaf's first seven
/// triangles (prefetching whole 16-triangle leaves was no faster).
const PREFETCH_BYTES: usize = 256;

/// Prefetches the cache lines of `bytes` bytes from `start` (a hint: it never faults, so
/// the range need not be valid).
#[inline(always)]
fn prefetch(start: *const u8, bytes: usize) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        let mut offset = 0;
        while offset < bytes {
            // SAFETY: a prefetch is only a hint: it reads nothing the program sees and never
            // faults, whatever the address.
            unsafe { _mm_prefetch::<_MM_HINT_T0>(start.wrapping_add(offset) as *const i8) };
            offset += 64;
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (start, bytes);
}

/// Visits the leaves whose boxes `ray` enters before `t_far` (nearer children first when
/// `ORDERED`: closest hits want that, any-hit rays do not); `visit` gets the memory and a
/// leaf's slots, may shrink `t_far`, and returns `true` to stop.
#[inline(always)]
pub(crate) fn traverse_wide<const ORDERED: bool, M: TreeMemory>(
    mem: &mut M,
    enter: impl NodeTest,
    ray: &Ray,
    stack: &mut Vec<u32>,
    t_far: &mut f32,
    mut visit: impl FnMut(&mut M, std::ops::Range<u32>, &mut f32) -> bool,
) {
    stack.clear();
    if mem.is_empty() {
        return;
    }
    let origin = ray.origin.to_array();
    let inv = finite_inverse(ray);
    if !ORDERED {
        traverse_unordered(mem, enter, (origin, inv), stack, t_far, visit);
        return;
    }
    let hints = mem.prefetcher();
    // Entries are (child, count) pairs: count 0 is an inner node.
    stack.extend([0, 0]);
    while let (Some(count), Some(child)) = (stack.pop(), stack.pop()) {
        if count > 0 {
            if visit(mem, child..child + count, t_far) {
                return;
            }
            continue;
        }
        let node = mem.node(child);
        let (t, mut entered) = enter(node, origin, inv, *t_far);
        // The entered children, nearest first (an insertion sort of at most WIDTH).
        let mut order = [0usize; WIDTH];
        let mut n = 0;
        while entered != 0 {
            let k = entered.trailing_zeros() as usize;
            entered &= entered - 1;
            let mut j = n;
            while j > 0 && t[order[j - 1]] > t[k] {
                order[j] = order[j - 1];
                j -= 1;
            }
            order[j] = k;
            n += 1;
        }
        for &k in order[..n].iter().rev() {
            hints.prefetch_child(node, k);
            stack.extend([node.child[k], node.count[k]]);
        }
    }
}

/// [`traverse_wide`] for rays that any hit ends: children in no order (the order buys little
/// when the first hit stops the ray, and costs a sort per node: AO rays a few per cent faster
/// without it on the bunny). One entered child is descended into at once instead of going
/// through the stack.
#[inline(always)]
fn traverse_unordered<M: TreeMemory>(
    mem: &mut M,
    enter: impl NodeTest,
    (origin, inv): ([f32; 3], [f32; 3]),
    stack: &mut Vec<u32>,
    t_far: &mut f32,
    mut visit: impl FnMut(&mut M, std::ops::Range<u32>, &mut f32) -> bool,
) {
    let hints = mem.prefetcher();
    // (child, count): count 0 is an inner node.
    let (mut child, mut count) = (0u32, 0u32);
    loop {
        if count > 0 {
            if visit(mem, child..child + count, t_far) {
                return;
            }
        } else {
            let node = mem.node(child);
            let (_, mut entered) = enter(node, origin, inv, *t_far);
            if entered != 0 {
                let next = (u32::BITS - 1 - entered.leading_zeros()) as usize;
                entered &= !(1 << next);
                while entered != 0 {
                    let k = entered.trailing_zeros() as usize;
                    entered &= entered - 1;
                    hints.prefetch_child(node, k);
                    stack.extend([node.child[k], node.count[k]]);
                }
                (child, count) = (node.child[next], node.count[next]);
                continue;
            }
        }
        match (stack.pop(), stack.pop()) {
            (Some(c), Some(ch)) => (child, count) = (ch, c),
            _ => return,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bvh::tree::Accel;
    use crate::scene::knot_scene;
    use glam::Vec3;

    #[test]
    fn every_leaf_appears_once_in_the_collapsed_tree() {
        let accel = Accel::build(&knot_scene(120, 16));
        let wide = collapse(&accel.nodes);
        let mut slots: Vec<u32> = wide
            .iter()
            .flat_map(|n| {
                (0..WIDTH)
                    .filter(|&k| n.count[k] != EMPTY && n.count[k] > 0)
                    .flat_map(move |k| n.child[k]..n.child[k] + n.count[k])
            })
            .collect();
        slots.sort_unstable();
        assert_eq!(slots, (0..accel.triangles.len() as u32).collect::<Vec<_>>());
        // About a third as many nodes as the binary tree has inner nodes, or fewer.
        let inner = accel.nodes.iter().filter(|n| n.count == 0).count();
        assert!(
            wide.len() * 2 < inner,
            "{} wide nodes for {inner} inner ones",
            wide.len()
        );
    }

    /// The AVX2 node test gives the portable one's mask and entry distances, on a collapsed
    /// tree's real nodes (with empty slots) and rays from inside and outside, some parallel
    /// to an axis.
    #[test]
    #[cfg(target_arch = "x86_64")]
    fn the_avx2_node_test_is_the_portable_one() {
        if !std::arch::is_x86_feature_detected!("avx2") {
            return;
        }
        let accel = Accel::build(&knot_scene(64, 8));
        let mut seen = 0u32;
        for (n, node) in accel.wide.iter().enumerate() {
            for r in 0..12 {
                let f = (n * 12 + r) as f32;
                let origin = Vec3::new((f * 0.37).sin() * 3.0, (f * 0.11).cos() * 2.0, 0.5);
                let k = r % WIDTH;
                let centre = Vec3::new(
                    node.lo[0][k] + node.hi[0][k],
                    node.lo[1][k] + node.hi[1][k],
                    node.lo[2][k] + node.hi[2][k],
                ) * 0.5;
                let dir = match r % 4 {
                    0 => Vec3::X,
                    1 if node.count[k] != EMPTY => centre - origin,
                    _ => Vec3::new((f * 0.7).cos(), (f * 1.3).sin(), (f * 0.3).cos() - 0.2),
                };
                let ray = Ray::new(origin, dir);
                let (o, inv) = (origin.to_array(), finite_inverse(&ray));
                let t_far = if r % 3 == 0 { f32::INFINITY } else { 1.5 };
                let portable = enter_mask(node, o, inv, t_far);
                // SAFETY: the CPU has AVX2, checked above.
                let avx2 = unsafe { enter_mask_avx2(node, o, inv, t_far) };
                assert_eq!(avx2.1, portable.1, "node {n} ray {r}");
                for k in (0..WIDTH).filter(|k| portable.1 >> k & 1 == 1) {
                    assert_eq!(avx2.0[k], portable.0[k], "node {n} ray {r} child {k}");
                }
                seen += portable.1.count_ones();
            }
        }
        assert!(seen > 100, "the rays must enter some boxes ({seen})");
    }

    #[test]
    fn a_ray_on_a_slab_plane_parallel_to_it_still_enters() {
        let mut node = BLANK;
        set_child(
            &mut node,
            0,
            &BvhNode {
                min: Vec3::ZERO,
                max: Vec3::ONE,
                first: 0,
                count: 1,
            },
            0,
        );
        // Origin on the x = 0 plane, moving along y: (0 - 0) * inf is NaN on x.
        let ray = Ray::new(Vec3::new(0.0, -1.0, 0.5), Vec3::Y);
        let t = enter_wide(
            &node,
            ray.origin.to_array(),
            finite_inverse(&ray),
            f32::INFINITY,
        );
        assert_eq!(t[0], 1.0);
        assert!(t[1..].iter().all(|t| *t == f32::INFINITY));
    }
}
