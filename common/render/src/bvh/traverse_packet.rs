//! Coherent traversal of the 8-wide BVH by whole 64-ray packets.
//!
//! For packets with a common origin (primary rays), every child is first tested against the
//! packet's frustum (interval arithmetic over its directions), which drops whole subtrees with
//! one test; a packet whose frustum misses the root's children stops before any per-lane
//! set-up. Inner nodes then test single rays from the first active one until one enters
//! (Wald's "first hit" traversal), which orders the eight children; leaves test all 64 lanes'
//! boxes at once in structure-of-arrays form, and then each triangle against the lanes that
//! enter, 16 lanes at a time (`packet_leaf`), for packets with one origin. Children are
//! prefetched as they are pushed. Closest-hit packets without a common origin fall back to
//! single rays. Shadow packets (`occluded_lanes`) start at many points: they are culled by a
//! frustum built from the box of their origins and stop each ray at its first hit.
//!
//! Box tests run on inverse directions made finite (`traverse_ray::finite_inverse`), so no slab
//! distance is a NaN and plain compare-selects stand in for `f32::min`/`max`.
//!
//! The SIMD width is chosen at run time (`isa`): an AVX-512 or AVX2 build of the same code runs
//! where the CPU has it, the baseline SSE2 build elsewhere. All give bit-identical results,
//! because Rust never fuses a multiply and an add into an FMA on its own, so every node of a
//! wall renders the same pixels whatever its CPU.

use crate::bvh::leaf_packet::ShearedLanes;
use crate::bvh::memory::{ChildPrefetch, TreeMemory};
use crate::bvh::traverse_ray::{self, EMPTY, WIDTH};
use crate::bvh::tree::{Accel, Hit};
use crate::geometry::Ray;
use crate::isa::Isa;
use crate::packet::{PacketHit, RayPacket, COMMON_ORIGIN, PACKET_RAYS};
use glam::Vec3;

/// The packet's rays in lanes: origins, inverse directions and current hit distances.
struct Lanes<'a> {
    /// The shared origin, when there is one.
    origin: Vec3,
    /// Per-lane origins, for packets without a common one (shadow rays).
    org: &'a [[f32; PACKET_RAYS]; 3],
    /// Inverse directions with infinities made finite (see [`traverse_ray::finite_inverse`]).
    finite_inv: [[f32; PACKET_RAYS]; 3],
    /// Closest hit so far (at first the end of the ray's interval); -inf for lanes past the
    /// packet's end or with an empty interval, so they never enter a box.
    t: [f32; PACKET_RAYS],
    /// Start of each ray's interval (0 unless cutting planes clip it).
    t_min: [f32; PACKET_RAYS],
}

impl Lanes<'_> {
    #[inline(always)]
    fn origin_of<const COMMON: bool>(&self, i: usize) -> [f32; 3] {
        if COMMON {
            self.origin.to_array()
        } else {
            [self.org[0][i], self.org[1][i], self.org[2][i]]
        }
    }

    #[inline(always)]
    fn finite_inv_of(&self, i: usize) -> [f32; 3] {
        [
            self.finite_inv[0][i],
            self.finite_inv[1][i],
            self.finite_inv[2][i],
        ]
    }

    /// Whether lane `i` enters the box within its interval.
    #[inline(always)]
    fn enters<const COMMON: bool>(&self, i: usize, min: Vec3, max: Vec3) -> bool {
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
    fn enter<const COMMON: bool>(
        &self,
        min: Vec3,
        max: Vec3,
        out: &mut [f32; PACKET_RAYS],
    ) -> bool {
        let shared_lo = min - self.origin;
        let shared_hi = max - self.origin;
        let mut any = false;
        for i in 0..PACKET_RAYS {
            let (lo, hi) = if COMMON {
                (shared_lo, shared_hi)
            } else {
                let o = Vec3::new(self.org[0][i], self.org[1][i], self.org[2][i]);
                (min - o, max - o)
            };
            // Finite inverses keep NaN out (see `traverse_ray::enter_mask`), so compare-selects
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
            any |= hit;
        }
        any
    }
}

impl Accel {
    /// Closest hits of a whole packet (see the module documentation), on the widest SIMD
    /// build this CPU runs.
    pub fn closest_hits(
        &self,
        packet: &mut RayPacket,
        hits: &mut [PacketHit; PACKET_RAYS],
        stack: &mut Vec<u32>,
    ) {
        closest_hits_on(&mut self.resident(), Isa::best(), packet, hits, stack);
    }

    /// [`Accel::closest_hits`] on the build `isa` (the portable one if the CPU lacks it).
    pub fn closest_hits_on(
        &self,
        isa: Isa,
        packet: &mut RayPacket,
        hits: &mut [PacketHit; PACKET_RAYS],
        stack: &mut Vec<u32>,
    ) {
        closest_hits_on(&mut self.resident(), isa, packet, hits, stack);
    }

    /// Which rays of the packet hit a triangle within their interval, as bits (ray i is bit
    /// i): shadow rays, which stop at the first hit. Rays need no common origin; the answer is
    /// the same as [`Accel::occluded`] ray by ray.
    pub fn occluded_lanes(&self, packet: &mut RayPacket, stack: &mut Vec<u32>) -> u64 {
        occluded_lanes_on(&mut self.resident(), Isa::best(), packet, stack)
    }

    /// [`Accel::occluded_lanes`] on the build `isa` (the portable one if the CPU lacks it).
    pub fn occluded_lanes_on(&self, isa: Isa, packet: &mut RayPacket, stack: &mut Vec<u32>) -> u64 {
        occluded_lanes_on(&mut self.resident(), isa, packet, stack)
    }
}

/// [`Accel::closest_hits`] of the tree in `mem`, on the build `isa` (the portable one if the
/// CPU lacks it).
pub fn closest_hits_on<M: TreeMemory>(
    mem: &mut M,
    isa: Isa,
    packet: &mut RayPacket,
    hits: &mut [PacketHit; PACKET_RAYS],
    stack: &mut Vec<u32>,
) {
    #[cfg(target_arch = "x86_64")]
    if isa.is_available() {
        match isa {
            // SAFETY: the CPU has the features, checked just above.
            Isa::Avx512 => return unsafe { closest_hits_avx512(mem, packet, hits, stack) },
            Isa::Avx2 => return unsafe { closest_hits_avx2(mem, packet, hits, stack) },
            Isa::Portable => {}
        }
    }
    closest_hits_generic(mem, packet, hits, stack);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn closest_hits_avx2<M: TreeMemory>(
    mem: &mut M,
    packet: &mut RayPacket,
    hits: &mut [PacketHit; PACKET_RAYS],
    stack: &mut Vec<u32>,
) {
    closest_hits_generic(mem, packet, hits, stack);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512vl,avx512bw,avx512dq")]
unsafe fn closest_hits_avx512<M: TreeMemory>(
    mem: &mut M,
    packet: &mut RayPacket,
    hits: &mut [PacketHit; PACKET_RAYS],
    stack: &mut Vec<u32>,
) {
    closest_hits_generic(mem, packet, hits, stack);
}

#[inline(always)]
fn closest_hits_generic<M: TreeMemory>(
    mem: &mut M,
    packet: &mut RayPacket,
    hits: &mut [PacketHit; PACKET_RAYS],
    stack: &mut Vec<u32>,
) {
    let n = packet.len();
    hits[..n].fill(PacketHit::MISS);
    if !packet.has(COMMON_ORIGIN) {
        for (i, hit) in hits.iter_mut().enumerate().take(n) {
            let ray = Ray::new(packet.ray_origin(i), packet.direction(i));
            let interval = (packet.t_min[i], packet.t_max[i]);
            *hit = crate::bvh::tree::closest_hit(mem, &ray, interval, stack)
                .map_or(PacketHit::MISS, |h| PacketHit::new(h.t, h.slot));
        }
        return;
    }
    traverse_packet::<M, true, false>(mem, packet, hits, stack);
}

/// [`Accel::occluded_lanes`] of the tree in `mem`, on the build `isa`.
pub fn occluded_lanes_on<M: TreeMemory>(
    mem: &mut M,
    isa: Isa,
    packet: &mut RayPacket,
    stack: &mut Vec<u32>,
) -> u64 {
    #[cfg(target_arch = "x86_64")]
    if isa.is_available() {
        match isa {
            // SAFETY: the CPU has the features, checked just above.
            Isa::Avx512 => return unsafe { occluded_lanes_avx512(mem, packet, stack) },
            Isa::Avx2 => return unsafe { occluded_lanes_avx2(mem, packet, stack) },
            Isa::Portable => {}
        }
    }
    occluded_lanes_generic(mem, packet, stack)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn occluded_lanes_avx2<M: TreeMemory>(
    mem: &mut M,
    packet: &mut RayPacket,
    stack: &mut Vec<u32>,
) -> u64 {
    occluded_lanes_generic(mem, packet, stack)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512vl,avx512bw,avx512dq")]
unsafe fn occluded_lanes_avx512<M: TreeMemory>(
    mem: &mut M,
    packet: &mut RayPacket,
    stack: &mut Vec<u32>,
) -> u64 {
    occluded_lanes_generic(mem, packet, stack)
}

#[inline(always)]
fn occluded_lanes_generic<M: TreeMemory>(
    mem: &mut M,
    packet: &mut RayPacket,
    stack: &mut Vec<u32>,
) -> u64 {
    let mut hits = [PacketHit::MISS; PACKET_RAYS];
    if packet.has(COMMON_ORIGIN) {
        traverse_packet::<M, true, true>(mem, packet, &mut hits, stack)
    } else {
        traverse_packet::<M, false, true>(mem, packet, &mut hits, stack)
    }
}

/// The packet traversal. `COMMON`: the rays share `packet.origin`, which allows frustum
/// culling. `ANY`: stop each ray at its first hit and return the rays that hit as bits;
/// otherwise fill `hits` with the closest hits.
#[inline(always)]
fn traverse_packet<M: TreeMemory, const COMMON: bool, const ANY: bool>(
    mem: &mut M,
    packet: &mut RayPacket,
    hits: &mut [PacketHit; PACKET_RAYS],
    stack: &mut Vec<u32>,
) -> u64 {
    let n = packet.len();
    if mem.is_empty() || n == 0 {
        return 0;
    }
    let all: u64 = if n == PACKET_RAYS {
        u64::MAX
    } else {
        (1 << n) - 1
    };
    let mut blocked = 0u64;
    let origin = packet.origin;
    let frustum = Frustum::of(packet);
    // Most packets of a view miss the whole scene (the sky around an object): they stop
    // here, before any per-lane set-up.
    let root_culled = frustum.misses_children(mem.node(0));
    let hints = mem.prefetcher();
    if root_culled.iter().all(|&c| c) {
        return 0;
    }
    let inv = *packet.inverse_directions();
    let mut lanes = Lanes {
        origin,
        org: &packet.org,
        finite_inv: inv.map(|axis| axis.map(traverse_ray::finite)),
        t: std::array::from_fn(|i| {
            if i < n && packet.t_min[i] <= packet.t_max[i] {
                packet.t_max[i]
            } else {
                f32::NEG_INFINITY
            }
        }),
        t_min: packet.t_min,
    };
    // Rays for the scalar triangle test, made for the lanes that need one.
    let mut rays = LazyRays::new(n);
    let mut entry = [0f32; PACKET_RAYS];
    // The closest hit's slot per lane (u32::MAX: none yet), written to `hits` at the end.
    let mut best_slot = [u32::MAX; PACKET_RAYS];
    // Only closest-hit packets with one origin test leaves lane-wide (`packet_leaf`).
    let sheared = if COMMON && !ANY {
        ShearedLanes::of_directions(&packet.dir, n)
    } else {
        None
    };
    // Stack entries are triples (first active lane, 8-wide node, child slot): lanes before
    // the first active one missed an ancestor's box, so they miss every box below it. The
    // child's box and kind are read from its parent, where the 8-wide tree keeps them.
    stack.clear();
    for k in (0..WIDTH).rev() {
        if !root_culled[k] {
            stack.extend([0, 0, k as u32]);
        }
    }
    while let (Some(k), Some(parent), Some(first)) = (stack.pop(), stack.pop(), stack.pop()) {
        let parent = mem.node(parent);
        let k = k as usize;
        let (min, max) = (
            Vec3::new(parent.lo[0][k], parent.lo[1][k], parent.lo[2][k]),
            Vec3::new(parent.hi[0][k], parent.hi[1][k], parent.hi[2][k]),
        );
        // (The frustum culled it before it was pushed.)
        let (child, count) = (parent.child[k], parent.count[k]);
        if count > 0 {
            if !lanes.enter::<COMMON>(min, max, &mut entry) {
                continue;
            }
            let active: [bool; PACKET_RAYS] = std::array::from_fn(|i| {
                (i >= first as usize) & (i < n) & (entry[i] != f32::INFINITY)
            });
            // Lane-wide even for one lane: only the groups of 16 lanes that hold an active
            // one are computed, and that beat the scalar test from 1 lane on (1 thread,
            // AVX-512; the 4.2M knot 12.3 against 11.2 Mrays/s when it took over from 4
            // lanes, the bunny 53.8 against 50.7).
            if let Some(sheared) = sheared.as_ref() {
                let mut redo = [false; PACKET_RAYS];
                let groups = crate::bvh::leaf_packet::active_groups(&active);
                for slot in child..child + count {
                    let tri = mem.triangle(slot);
                    let again = sheared.hit(
                        origin,
                        tri,
                        slot,
                        (&active, groups),
                        (&lanes.t_min, &packet.t_max),
                        &mut lanes.t,
                        &mut best_slot,
                        &mut redo,
                    );
                    if !again {
                        continue;
                    }
                    for i in (0..n).filter(|&i| redo[i]) {
                        let hit = rays.get(i, origin, packet).hit_triangle(
                            tri.a,
                            tri.b,
                            tri.c,
                            lanes.t_min[i],
                            packet.t_max[i],
                        );
                        let best = Some(Hit {
                            t: lanes.t[i],
                            slot: best_slot[i],
                        });
                        if let Some(t) = hit.filter(|&t| Hit::closer(t, slot, best)) {
                            lanes.t[i] = t;
                            best_slot[i] = slot;
                        }
                    }
                }
                continue;
            }
            for i in first as usize..n {
                if entry[i] == f32::INFINITY {
                    continue;
                }
                let ray = rays.get(i, origin, packet);
                for slot in child..child + count {
                    let tri = mem.triangle(slot);
                    // Closest hits accept a tie on a lower slot too (see `Hit::closer`),
                    // so they agree with the single-ray traversal of the 8-wide tree.
                    let t_max = if ANY { lanes.t[i] } else { packet.t_max[i] };
                    if let Some(t) = ray.hit_triangle(tri.a, tri.b, tri.c, lanes.t_min[i], t_max) {
                        if ANY {
                            // Done with this ray: it enters no box from now on.
                            blocked |= 1 << i;
                            lanes.t[i] = f32::NEG_INFINITY;
                            break;
                        }
                        let best = Some(Hit {
                            t: lanes.t[i],
                            slot: best_slot[i],
                        });
                        if Hit::closer(t, slot, best) {
                            lanes.t[i] = t;
                            best_slot[i] = slot;
                        }
                    }
                }
            }
            if ANY && blocked == all {
                break;
            }
            continue;
        }
        // Inner nodes test the first active ray alone (Wald's "first hit" packet
        // traversal): for coherent rays it usually enters, and the node costs one ray's
        // box test. If it misses, all lanes are tested at once, which is cheaper than
        // trying them one by one when none enters (a frequent case for 8-wide siblings).
        let first = first as usize;
        let active = if lanes.enters::<COMMON>(first, min, max) {
            first
        } else if lanes.enter::<COMMON>(min, max, &mut entry) {
            match (first + 1..n).find(|&i| entry[i] < f32::INFINITY) {
                Some(i) => i,
                None => continue,
            }
        } else {
            continue;
        };
        // Every child the frustum keeps is pushed: other lanes may enter what the active
        // ray misses. Those it misses (or enters beyond its closest hit) go deepest; those
        // it enters on top, nearest last, in an insertion sort of the few (1-3 typically)
        // it enters.
        let node = mem.node(child);
        let t = traverse_ray::enter_wide(
            node,
            lanes.origin_of::<COMMON>(active),
            lanes.finite_inv_of(active),
            f32::INFINITY,
        );
        let culled = frustum.misses_children(node);
        stack.reserve(3 * WIDTH);
        let mut entered = [0usize; WIDTH];
        let mut n_entered = 0;
        for k in 0..WIDTH {
            if culled[k] {
                continue;
            }
            if t[k] == f32::INFINITY {
                hints.prefetch_child(node, k);
                stack.extend([active as u32, child, k as u32]);
                continue;
            }
            let mut j = n_entered;
            while j > 0 && t[entered[j - 1]] < t[k] {
                entered[j] = entered[j - 1];
                j -= 1;
            }
            entered[j] = k;
            n_entered += 1;
        }
        for &k in &entered[..n_entered] {
            hints.prefetch_child(node, k);
            stack.extend([active as u32, child, k as u32]);
        }
    }
    if !ANY {
        for i in 0..n {
            if best_slot[i] != u32::MAX {
                hits[i] = PacketHit::new(lanes.t[i], best_slot[i]);
            }
        }
    }
    blocked
}

/// The packet's rays as [`Ray`]s for the scalar triangle test, each made on first use: most
/// lanes of a primary packet never need one (their leaves are tested lane-wide), and making
/// all 64 up front cost an eighth of the traversal.
struct LazyRays {
    made: u64,
    rays: [std::mem::MaybeUninit<Ray>; PACKET_RAYS],
    len: usize,
}

impl LazyRays {
    fn new(len: usize) -> Self {
        LazyRays {
            made: 0,
            rays: [const { std::mem::MaybeUninit::uninit() }; PACKET_RAYS],
            len,
        }
    }

    /// Lane `i`'s ray (from `origin` if the packet has one origin, else its own).
    #[inline(always)]
    fn get(&mut self, i: usize, origin: Vec3, packet: &RayPacket) -> &Ray {
        assert!(
            i < self.len,
            "lane {i} is past the packet's {} rays",
            self.len
        );
        if self.made >> i & 1 == 0 {
            let o = if packet.has(COMMON_ORIGIN) {
                origin
            } else {
                packet.ray_origin(i)
            };
            self.rays[i].write(Ray::new(o, packet.direction(i)));
            self.made |= 1 << i;
        }
        // SAFETY: bit i of `made` is set only once `rays[i]` has been written, just above or
        // by an earlier call.
        unsafe { self.rays[i].assume_init_ref() }
    }
}

/// Bounds on the origins and inverse directions of a packet, for culling boxes no ray of it
/// can enter.
struct Frustum {
    /// Per axis: smallest and largest inverse direction, when all rays agree in sign.
    inv: [(f32, f32); 3],
    /// Per axis: smallest and largest origin (one point for a common origin).
    org: [(f32, f32); 3],
    usable: bool,
}

impl Frustum {
    fn of(packet: &mut RayPacket) -> Self {
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
    fn misses_children(&self, node: &traverse_ray::WideNode) -> [bool; WIDTH] {
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
    (
        lo.iter().fold(f32::INFINITY, |a, &b| a.min(b)),
        hi.iter().fold(f32::NEG_INFINITY, |a, &b| a.max(b)),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::knot_scene;
    use crate::{orbit_of, PixelRays};
    use tessera_wire::camera::Camera;
    use tessera_wire::cut::CutPlanes;

    #[test]
    fn packet_traversal_finds_what_single_rays_find_on_every_simd_path() {
        let scene = knot_scene(256, 32);
        let accel = Accel::build(&scene);
        let mut stack = accel.new_stack();
        let orbit = orbit_of(&scene.bounds(), 45.0).unwrap();
        for frame in [0u64, 40, 95, 200] {
            let camera: Camera = orbit.camera_for_frame(frame);
            let rays = PixelRays::new(&camera, 96, 64);
            let cuts = [
                CutPlanes::EMPTY,
                CutPlanes::new(&[(Vec3::new(0.2, 1.0, 0.1), 0.3), (-Vec3::Z, 1.0)]).unwrap(),
            ];
            for ((x0, y0, w, h), cuts) in
                [(0, 0, 8, 8), (40, 24, 8, 8), (88, 56, 8, 8), (48, 32, 5, 3)]
                    .into_iter()
                    .flat_map(|block| cuts.iter().map(move |c| (block, c)))
            {
                let mut packet = RayPacket::primary(&rays, x0, y0, w, h);
                packet.clip(cuts);
                let mut fast = [PacketHit::MISS; PACKET_RAYS];
                accel.closest_hits_on(Isa::Portable, &mut packet, &mut fast, &mut stack);
                for isa in Isa::available() {
                    let mut wide = [PacketHit::MISS; PACKET_RAYS];
                    accel.closest_hits_on(isa, &mut packet, &mut wide, &mut stack);
                    assert_eq!(wide, fast, "{isa:?} and portable disagree (frame {frame})");
                }
                for i in 0..packet.len() {
                    let ray = Ray::new(camera.eye(), packet.direction(i));
                    let (t_min, t_max) = cuts.interval(camera.eye(), packet.direction(i));
                    let single = accel.closest_hit(&ray, t_min, t_max, &mut stack);
                    assert_eq!(
                        fast[i].t,
                        single.map_or(f32::INFINITY, |h| h.t),
                        "frame {frame} ray {i}"
                    );
                }
            }
        }
    }

    #[test]
    fn shadow_packets_agree_with_single_shadow_rays_on_every_simd_path() {
        let scene = knot_scene(256, 32);
        let accel = Accel::build(&scene);
        let mut stack = accel.new_stack();
        let camera = orbit_of(&scene.bounds(), 45.0)
            .unwrap()
            .camera_for_frame(30);
        let rays = PixelRays::new(&camera, 96, 64);
        let light = Vec3::new(3.0, 4.0, 2.0);
        let mut blocked_somewhere = 0;
        for (x0, y0) in [(0, 0), (40, 24), (48, 32), (88, 56), (24, 40)] {
            // Shadow rays from where the primary rays hit, towards a point light (stopping
            // short of it) and towards a directional light (no end).
            let mut primary = RayPacket::primary(&rays, x0, y0, 8, 8);
            let mut hits = [PacketHit::MISS; PACKET_RAYS];
            accel.closest_hits(&mut primary, &mut hits, &mut stack);
            let starts: Vec<Vec3> = (0..primary.len())
                .map(|i| {
                    let t = if hits[i].t.is_finite() {
                        hits[i].t * 0.999
                    } else {
                        1.0
                    };
                    camera.eye() + primary.direction(i) * t
                })
                .collect();
            for point_light in [true, false] {
                let mut packet = RayPacket::from_rays(starts.iter().map(|&o| {
                    let towards = if point_light {
                        light - o
                    } else {
                        Vec3::new(0.3, 1.0, 0.2)
                    };
                    (o, towards.normalize())
                }));
                for (i, &o) in starts.iter().enumerate() {
                    packet.t_max[i] = if point_light {
                        (light - o).length()
                    } else {
                        f32::INFINITY
                    };
                }
                let fast = accel.occluded_lanes_on(Isa::Portable, &mut packet, &mut stack);
                for isa in Isa::available() {
                    let wide = accel.occluded_lanes_on(isa, &mut packet, &mut stack);
                    assert_eq!(wide, fast, "{isa:?} and portable disagree");
                }
                for (i, &o) in starts.iter().enumerate() {
                    let ray = Ray::new(o, packet.direction(i));
                    let single = accel.occluded(&ray, 0.0, packet.t_max[i], &mut stack);
                    assert_eq!(fast >> i & 1 == 1, single, "block ({x0}, {y0}) ray {i}");
                }
                blocked_somewhere += fast.count_ones();
            }
        }
        assert!(blocked_somewhere > 0, "the test must see some shadow");
    }
}
