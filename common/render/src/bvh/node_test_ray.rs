//! One ray against a wide node's eight children at once: their boxes in structure-of-arrays
//! form, tested with a few 8-lane instructions (AVX2, chosen at run time; two 4-lane halves on
//! baseline SSE). Box tests run on inverse directions made finite ([`finite_inverse`]), so no
//! slab distance is a NaN, and order distances by their bits as integers (see [`enter_mask`]);
//! the packet traversal's node tests (`node_test_packet`) rely on the same finite inverses.

use crate::bvh::node::{WideNode, WIDTH};
use crate::geometry::Ray;

/// A ray as the node tests read it: its origin, its finite inverse direction (see
/// [`finite_inverse`]), where its interval starts and, per axis, where in a [`WideNode`]
/// (viewed as floats) the children's planes it crosses first and last begin: the minima where
/// it moves up the axis, else the maxima. Choosing by sign does what a min/max of the two slab distances would, at half the
/// operations: `(p - o) · inv` keeps the order of the planes, or reverses it (rounding is
/// monotonic), and `inv` is never 0. An empty slot (minima +inf, maxima -inf) comes out entered
/// at +inf and left at -inf, so no ray enters it. The choice is made once per ray: made per
/// node, it cost a compare and two conditional moves per axis, and spilled registers.
#[derive(Clone, Copy, Debug)]
pub(crate) struct BoxRay {
    /// The ray's origin.
    pub origin: [f32; 3],
    /// Its finite inverse direction.
    pub inv: [f32; 3],
    /// Per axis, the float offset in the node of the planes crossed first.
    near: [usize; 3],
    /// Per axis, the float offset of the planes crossed last.
    far: [usize; 3],
    /// Boxes the ray leaves before this distance are not entered: nothing in them can be hit
    /// in its interval. Never below 0.
    t_near: f32,
}

/// Floats in a [`WideNode`].
const NODE_FLOATS: usize = std::mem::size_of::<WideNode>() / 4;

impl BoxRay {
    /// The node tests' view of `ray`, whose interval starts at `t_min`. A ray that starts
    /// beyond its origin (Embree's ambient-occlusion rays start at 0.001) skips the boxes it
    /// leaves before then, which a near bound of 0 entered to test their triangles for
    /// nothing: AO rays from t = 0.001 ran 3.8 -> 5.4 Mrays/s on the dragon.
    pub(crate) fn new(ray: &Ray, t_min: f32) -> Self {
        let mut boxes = BoxRay::from_parts(ray.origin.to_array(), finite_inverse(ray));
        // +0 at least, never -0: the node tests order distances by their bits, where -0 is
        // the lowest of all (see `enter_mask`).
        boxes.t_near = if t_min > 0.0 { t_min } else { 0.0 };
        boxes
    }

    /// The node tests' view of a ray from `origin` with finite inverse direction `inv`.
    #[inline(always)]
    pub(crate) fn from_parts(origin: [f32; 3], inv: [f32; 3]) -> Self {
        let (lo, hi) = (|axis| axis * WIDTH, |axis| (3 + axis) * WIDTH);
        let down = |axis: usize| inv[axis].is_sign_negative();
        BoxRay {
            origin,
            inv,
            near: std::array::from_fn(|a| if down(a) { hi(a) } else { lo(a) }),
            far: std::array::from_fn(|a| if down(a) { lo(a) } else { hi(a) }),
            t_near: 0.0,
        }
    }
}

/// Entry distances into the children's boxes before `t_far`; +inf where the ray misses
/// (or the slot is empty).
#[inline(always)]
pub(crate) fn enter_wide(node: &WideNode, ray: &BoxRay, t_far: f32) -> [f32; WIDTH] {
    let (near, entered) = enter_mask(node, ray, t_far);
    std::array::from_fn(|k| {
        if entered >> k & 1 == 1 {
            near[k]
        } else {
            f32::INFINITY
        }
    })
}

/// A test of one ray against a wide node's children: (node, ray, `t_far`) to the children's
/// entry distances and, as bits, which of them it enters ([`enter_mask`], or its AVX2 build
/// [`enter_mask_avx2`]). Traversals take it as a parameter so that one traversal serves every
/// SIMD build.
pub(crate) trait NodeTest: Fn(&WideNode, &BoxRay, f32) -> ([f32; WIDTH], u32) {}

impl<F: Fn(&WideNode, &BoxRay, f32) -> ([f32; WIDTH], u32)> NodeTest for F {}

/// The children's entry distances, and as bits (child k is bit k) which of them the ray
/// enters before `t_far`. The inverse direction is finite (see [`finite_inverse`]), so no slab
/// distance is a NaN (box corners are finite or, in empty slots, infinite, and `inv` is never
/// 0).
///
/// Distances are ordered by their bits read as signed integers, as Embree's node test does:
/// an integer max or min takes one cycle where a float one takes four, and they are the
/// chain every node visit waits on (AO rays 5 % and single shadow rays 7 % faster on the
/// dragon). That order is the float order among distances of +0 and above, and puts every
/// negative one (and -0) below +0. Entry distances are a max with the ray's `t_near`, which is
/// +0 or more, so they come out exactly as a float max would give them. Exit distances below
/// +0 may come out as another negative than the float min: either way the box is left before
/// it is entered and is not entered. The one difference from float compares: a box the ray
/// leaves at exactly -0 (an origin on its far plane) is not entered, where `0 <= -0` would
/// enter it; nothing in it lies beyond the ray's start, and hits must lie beyond `t_min`.
#[inline(always)]
pub(crate) fn enter_mask(node: &WideNode, ray: &BoxRay, t_far: f32) -> ([f32; WIDTH], u32) {
    let floats: &[f32; NODE_FLOATS] = bytemuck::cast_ref(node);
    let plane = |at: usize| -> &[f32] { &floats[at..at + WIDTH] };
    let bits = |t: f32| t.to_bits() as i32;
    // Integer max and min are exact and associative: the AVX2 build's trees give the same.
    let mut enter = [bits(ray.t_near); WIDTH];
    let mut leave = [bits(t_far); WIDTH];
    for axis in 0..3 {
        let (near_plane, far_plane) = (plane(ray.near[axis]), plane(ray.far[axis]));
        let (o, inv) = (ray.origin[axis], ray.inv[axis]);
        for k in 0..WIDTH {
            enter[k] = enter[k].max(bits((near_plane[k] - o) * inv));
            leave[k] = leave[k].min(bits((far_plane[k] - o) * inv));
        }
    }
    let mut entered = 0u32;
    for k in 0..WIDTH {
        entered |= ((enter[k] <= leave[k]) as u32) << k;
    }
    let near = enter.map(|t| f32::from_bits(t as u32));
    (near, entered)
}

/// [`enter_mask`] in AVX2 intrinsics, the same operations (`vpmaxsd`/`vpminsd` on the
/// distances' bits, as trees of two levels): the compiler, left to itself, packed that loop
/// into 4-lane halves for single rays, and AO rays ran 15 % slower than with `f32::min`.
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
pub(crate) unsafe fn enter_mask_avx2(
    node: &WideNode,
    ray: &BoxRay,
    t_far: f32,
) -> ([f32; WIDTH], u32) {
    use std::arch::x86_64::*;
    let floats = node as *const WideNode as *const f32;
    let slab = |axis: usize| {
        let o = _mm256_set1_ps(ray.origin[axis]);
        let iv = _mm256_set1_ps(ray.inv[axis]);
        // SAFETY: `BoxRay::from_parts` makes every offset the start of one of the node's six
        // plane arrays of WIDTH = 8 floats; unaligned loads need no alignment.
        let (lo, hi) = unsafe {
            (
                _mm256_loadu_ps(floats.add(ray.near[axis])),
                _mm256_loadu_ps(floats.add(ray.far[axis])),
            )
        };
        (
            _mm256_castps_si256(_mm256_mul_ps(_mm256_sub_ps(lo, o), iv)),
            _mm256_castps_si256(_mm256_mul_ps(_mm256_sub_ps(hi, o), iv)),
        )
    };
    let ((nx, fx), (ny, fy), (nz, fz)) = (slab(0), slab(1), slab(2));
    let t_near = _mm256_castps_si256(_mm256_set1_ps(ray.t_near));
    let t_far = _mm256_castps_si256(_mm256_set1_ps(t_far));
    let near = _mm256_max_epi32(_mm256_max_epi32(nx, ny), _mm256_max_epi32(nz, t_near));
    let far = _mm256_min_epi32(_mm256_min_epi32(fx, fy), _mm256_min_epi32(fz, t_far));
    let gt = _mm256_cmpgt_epi32(near, far);
    let entered = !(_mm256_movemask_ps(_mm256_castsi256_ps(gt)) as u32) & 0xff;
    let near = _mm256_castsi256_ps(near);
    let mut out = [0f32; WIDTH];
    // SAFETY: `out` holds 8 floats, the 32 bytes the store writes, unaligned.
    unsafe { _mm256_storeu_ps(out.as_mut_ptr(), near) };
    (out, entered)
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bvh::node::{set_child, BvhNode, BLANK};
    use glam::Vec3;

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
        let t = enter_wide(&node, &BoxRay::new(&ray, 0.0), f32::INFINITY);
        assert_eq!(t[0], 1.0);
        assert!(t[1..].iter().all(|t| *t == f32::INFINITY));
    }
}
