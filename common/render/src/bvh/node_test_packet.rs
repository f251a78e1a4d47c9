//! A packet's 64 rays against a box, and its frustum against a wide node's eight children: the
//! node tests of the packet traversal (`traverse_packet`). Lanes are structure-of-arrays, so
//! each test runs one SIMD lane per ray (or per child), on inverse directions made finite as
//! for single rays (see `node_test_ray`), with compare-selects for `f32::min`/`max`.

use crate::bvh::node::{WideNode, EMPTY, WIDTH};
use crate::packet::{lane_mask, RayPacket, COMMON_ORIGIN, PACKET_RAYS};
use glam::Vec3;

/// The packet's rays in lanes: origins, inverse directions and current hit distances.
pub(super) struct Lanes<'a> {
    /// The shared origin, when there is one.
    pub(super) origin: Vec3,
    /// Per-lane origins, for packets without a common one (shadow rays).
    pub(super) org: &'a [[f32; PACKET_RAYS]; 3],
    /// Inverse directions with infinities made finite (see [`crate::bvh::node_test_ray::finite_inverse`]).
    pub(super) finite_inv: [[f32; PACKET_RAYS]; 3],
    /// Closest hit so far (at first the end of the ray's interval); -inf for lanes past the
    /// packet's end or with an empty interval, so they never enter a box.
    pub(super) t: [f32; PACKET_RAYS],
    /// Start of each ray's interval (0 unless cutting planes clip it).
    pub(super) t_min: [f32; PACKET_RAYS],
}

impl Lanes<'_> {
    #[inline(always)]
    pub(super) fn origin_of<const COMMON: bool>(&self, i: usize) -> [f32; 3] {
        if COMMON {
            self.origin.to_array()
        } else {
            [self.org[0][i], self.org[1][i], self.org[2][i]]
        }
    }

    #[inline(always)]
    pub(super) fn finite_inv_of(&self, i: usize) -> [f32; 3] {
        [
            self.finite_inv[0][i],
            self.finite_inv[1][i],
            self.finite_inv[2][i],
        ]
    }

    /// Whether lane `i` enters the box within its interval.
    #[inline(always)]
    pub(super) fn enters<const COMMON: bool>(&self, i: usize, min: Vec3, max: Vec3) -> bool {
        let (o, inv) = (self.origin_of::<COMMON>(i), self.finite_inv_of(i));
        let mut near = self.t_min[i];
        let mut far = self.t[i];
        for axis in 0..3 {
            let t0 = (min[axis] - o[axis]) * inv[axis];
            let t1 = (max[axis] - o[axis]) * inv[axis];
            near = fmax(near, fmin(t0, t1));
            far = fmin(far, fmax(t0, t1));
        }
        near <= far
    }

    /// Entry distance of every lane into the box, +inf where the lane misses it. `COMMON`:
    /// all lanes start at `origin` (the box offsets are then shared).
    #[inline(always)]
    pub(super) fn enter<const COMMON: bool>(
        &self,
        min: Vec3,
        max: Vec3,
        out: &mut [f32; PACKET_RAYS],
    ) -> bool {
        let shared_lo = min - self.origin;
        let shared_hi = max - self.origin;
        // Or-ed as a 32-bit mask per lane, not a `bool`: see `packet::LaneMask`.
        let mut any = 0;
        for i in 0..PACKET_RAYS {
            let (lo, hi) = if COMMON {
                (shared_lo, shared_hi)
            } else {
                let o = Vec3::new(self.org[0][i], self.org[1][i], self.org[2][i]);
                (min - o, max - o)
            };
            // Finite inverses keep NaN out (see `node_test_ray::enter_mask`), so compare-selects
            // stand in for `f32::min`/`max`, whose NaN handling costs three instructions each.
            let inv = [
                self.finite_inv[0][i],
                self.finite_inv[1][i],
                self.finite_inv[2][i],
            ];
            let (x0, x1) = (lo.x * inv[0], hi.x * inv[0]);
            let (y0, y1) = (lo.y * inv[1], hi.y * inv[1]);
            let (z0, z1) = (lo.z * inv[2], hi.z * inv[2]);
            let near = fmax(
                fmax(fmax(fmin(x0, x1), fmin(y0, y1)), fmin(z0, z1)),
                self.t_min[i],
            );
            let far = fmin(
                fmin(fmin(fmax(x0, x1), fmax(y0, y1)), fmax(z0, z1)),
                self.t[i],
            );
            let hit = near <= far;
            out[i] = if hit { near } else { f32::INFINITY };
            any |= lane_mask(hit);
        }
        any != 0
    }
}

/// Bounds on the origins and inverse directions of a packet, for culling boxes no ray of it
/// can enter.
pub(super) struct Frustum {
    /// Per axis: smallest and largest inverse direction, when all rays agree in sign.
    inv: [(f32, f32); 3],
    /// Per axis: smallest and largest origin (one point for a common origin).
    org: [(f32, f32); 3],
    usable: bool,
}

impl Frustum {
    pub(super) fn of(packet: &mut RayPacket) -> Self {
        let n = packet.len();
        let common = packet.has(COMMON_ORIGIN).then_some(packet.origin);
        let org = std::array::from_fn(|axis| match common {
            Some(origin) => (origin[axis], origin[axis]),
            None => span(&packet.org[axis][..n]),
        });
        let inv = packet.inverse_directions();
        let mut usable = n > 0;
        let inv = std::array::from_fn(|axis| {
            let (lo, hi) = span(&inv[axis][..n]);
            // Mixed signs (or an axis-parallel ray) make the interval bounds meaningless.
            usable &= lo.is_finite() && hi.is_finite() && (lo > 0.0 || hi < 0.0);
            (lo, hi)
        });
        Frustum { inv, org, usable }
    }

    /// [`Frustum::misses`] for every child of a wide node at once (the same arithmetic, over
    /// the children's structure-of-arrays boxes, so it runs one child per SIMD lane). Empty
    /// slots count as missed.
    #[inline(always)]
    pub(super) fn misses_children(&self, node: &WideNode) -> [bool; WIDTH] {
        let empty: [bool; WIDTH] = std::array::from_fn(|k| node.count[k] == EMPTY);
        if !self.usable {
            return empty;
        }
        let mut near = [0.0f32; WIDTH];
        let mut far = [f32::INFINITY; WIDTH];
        for axis in 0..3 {
            let (lo, hi) = self.inv[axis];
            let (o_lo, o_hi) = self.org[axis];
            // Rays going + enter through the min slab, rays going - through the max slab.
            let (enter, exit) = if lo > 0.0 {
                (&node.lo[axis], &node.hi[axis])
            } else {
                (&node.hi[axis], &node.lo[axis])
            };
            // No NaN here (finite origins and inverse bounds, box corners finite or, in empty
            // slots, infinite), so compare-selects do what `f32::min`/`max` would.
            for k in 0..WIDTH {
                let (e0, e1) = (enter[k] - o_hi, enter[k] - o_lo);
                let (x0, x1) = (exit[k] - o_hi, exit[k] - o_lo);
                let entered = fmin(fmin(fmin(e0 * lo, e0 * hi), e1 * lo), e1 * hi);
                let exited = fmax(fmax(fmax(x0 * lo, x0 * hi), x1 * lo), x1 * hi);
                near[k] = fmax(near[k], entered);
                far[k] = fmin(far[k], exited);
            }
        }
        std::array::from_fn(|k| empty[k] | (near[k] > far[k]))
    }
}

/// The smaller of two floats that are not NaN, as one instruction.
#[inline(always)]
fn fmin(a: f32, b: f32) -> f32 {
    if a < b {
        a
    } else {
        b
    }
}

/// The larger of two floats that are not NaN, as one instruction.
#[inline(always)]
fn fmax(a: f32, b: f32) -> f32 {
    if a > b {
        a
    } else {
        b
    }
}

/// Smallest and largest of `values`.
fn span(values: &[f32]) -> (f32, f32) {
    // Sixteen running bounds, lane by lane, then folded: a compare-select per element
    // vectorizes where a fold through `f32::min` (a NaN-aware reduction) stays scalar.
    // NaNs are skipped either way.
    const LANES: usize = 16;
    let mut lo = [f32::INFINITY; LANES];
    let mut hi = [f32::NEG_INFINITY; LANES];
    let mut chunks = values.chunks_exact(LANES);
    for chunk in &mut chunks {
        for k in 0..LANES {
            lo[k] = if chunk[k] < lo[k] { chunk[k] } else { lo[k] };
            hi[k] = if chunk[k] > hi[k] { chunk[k] } else { hi[k] };
        }
    }
    for (k, &v) in chunks.remainder().iter().enumerate() {
        lo[k] = if v < lo[k] { v } else { lo[k] };
        hi[k] = if v > hi[k] { v } else { hi[k] };
    }
    // No running bound is a NaN, so compare-selects fold them too: `f32::min`, NaN-aware,
    // made each fold a chain of 16 four-instruction steps, most of this function's time.
    (
        lo.iter().fold(f32::INFINITY, |a, &b| fmin(a, b)),
        hi.iter().fold(f32::NEG_INFINITY, |a, &b| fmax(a, b)),
    )
}
