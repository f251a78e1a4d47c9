//! Coherent traversal of the 8-wide BVH by whole 64-ray packets.
//!
//! For packets with a common origin (primary rays), every child is first tested against the
//! packet's frustum (interval arithmetic over its directions), which drops whole subtrees with
//! one test; a packet whose frustum misses the root's children stops before any per-lane
//! set-up. Inner nodes then test single rays from the first active one until one enters
//! (Wald's "first hit" traversal), which orders the eight children; leaves test all 64 lanes'
//! boxes at once in structure-of-arrays form (`node_test_packet`), and then each triangle
//! against the lanes that enter, 16 lanes at a time (`leaf_packet`), for packets with one
//! origin. Children are prefetched as they are pushed. Closest-hit packets without a common
//! origin fall back to single rays (`traverse_ray`). Shadow packets (`occluded_lanes`) start at
//! many points: they are culled by a frustum built from the box of their origins and stop each
//! ray at its first hit.
//!
//! The SIMD width is chosen at run time (`isa`): an AVX-512 or AVX2 build of the same code runs
//! where the CPU has it, the baseline SSE2 build elsewhere. All give bit-identical results,
//! because Rust never fuses a multiply and an add into an FMA on its own, so every node of a
//! wall renders the same pixels whatever its CPU.

use crate::bvh::leaf_packet::{self, ShearedLanes};
use crate::bvh::leaf_ray;
use crate::bvh::memory::TreeMemory;
use crate::bvh::node::{Hit, WIDTH};
use crate::bvh::node_test_packet::{Frustum, Lanes};
use crate::bvh::node_test_ray::{enter_wide, finite, BoxRay};
use crate::bvh::traverse_ray;
use crate::bvh::tree::Accel;
use crate::geometry::Ray;
use crate::isa::{isa_builds, Build, Isa};
use crate::packet::{lane_mask, PacketHit, RayPacket, COMMON_ORIGIN, LANE_INDEX, PACKET_RAYS};
use glam::Vec3;
use std::ops::Range;

impl Accel {
    /// Closest hits of a whole packet (see the module documentation), on the widest SIMD
    /// build this CPU runs.
    pub fn closest_hits(
        &self,
        packet: &mut RayPacket,
        hits: &mut [PacketHit; PACKET_RAYS],
        stack: &mut Vec<u32>,
    ) {
        closest_hits_on(Isa::best(), &mut self.resident(), packet, hits, stack);
    }

    /// [`Accel::closest_hits`] on the build `isa` (the portable one if the CPU lacks it).
    pub fn closest_hits_on(
        &self,
        isa: Isa,
        packet: &mut RayPacket,
        hits: &mut [PacketHit; PACKET_RAYS],
        stack: &mut Vec<u32>,
    ) {
        closest_hits_on(isa, &mut self.resident(), packet, hits, stack);
    }

    /// Which rays of the packet hit a triangle within their interval, as bits (ray i is bit
    /// i): shadow rays, which stop at the first hit. Rays need no common origin; the answer is
    /// the same as [`Accel::occluded`] ray by ray.
    pub fn occluded_lanes(&self, packet: &mut RayPacket, stack: &mut Vec<u32>) -> u64 {
        occluded_lanes_on(Isa::best(), &mut self.resident(), packet, stack)
    }

    /// [`Accel::occluded_lanes`] on the build `isa` (the portable one if the CPU lacks it).
    pub fn occluded_lanes_on(&self, isa: Isa, packet: &mut RayPacket, stack: &mut Vec<u32>) -> u64 {
        occluded_lanes_on(isa, &mut self.resident(), packet, stack)
    }
}

isa_builds! {
    /// [`Accel::closest_hits`] of the tree in `mem`, on the build `isa` (the portable one if
    /// the CPU lacks it).
    pub fn closest_hits_on<M: TreeMemory>(
        mem: &mut M,
        packet: &mut RayPacket,
        hits: &mut [PacketHit; PACKET_RAYS],
        stack: &mut Vec<u32>,
    ) = closest_hits_kernel on [Avx2, Avx512];
}

/// [`closest_hits_on`] on one build: the same code in each, which the build's target features
/// let the compiler run 8 or 16 lanes wide.
#[inline(always)]
fn closest_hits_kernel<M: TreeMemory>(
    build: impl Build,
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
            *hit = traverse_ray::closest_hit(mem, &ray, interval, stack)
                .map_or(PacketHit::MISS, |h| PacketHit::new(h.t, h.slot));
        }
        return;
    }
    traverse_packet::<M, true, false>(build, mem, packet, hits, stack);
}

isa_builds! {
    /// [`Accel::occluded_lanes`] of the tree in `mem`, on the build `isa` (the portable one if
    /// the CPU lacks it).
    pub fn occluded_lanes_on<M: TreeMemory>(
        mem: &mut M,
        packet: &mut RayPacket,
        stack: &mut Vec<u32>,
    ) -> u64 = occluded_lanes_kernel on [Avx2, Avx512];
}

/// [`occluded_lanes_on`] on one build.
#[inline(always)]
fn occluded_lanes_kernel<M: TreeMemory>(
    build: impl Build,
    mem: &mut M,
    packet: &mut RayPacket,
    stack: &mut Vec<u32>,
) -> u64 {
    let mut hits = [PacketHit::MISS; PACKET_RAYS];
    if packet.has(COMMON_ORIGIN) {
        traverse_packet::<M, true, true>(build, mem, packet, &mut hits, stack)
    } else {
        traverse_packet::<M, false, true>(build, mem, packet, &mut hits, stack)
    }
}

/// The packet traversal. `COMMON`: the rays share `packet.origin`, which allows frustum
/// culling. `ANY`: stop each ray at its first hit and return the rays that hit as bits;
/// otherwise fill `hits` with the closest hits.
#[inline(always)]
fn traverse_packet<M: TreeMemory, const COMMON: bool, const ANY: bool>(
    build: impl Build,
    mem: &mut M,
    packet: &mut RayPacket,
    hits: &mut [PacketHit; PACKET_RAYS],
    stack: &mut Vec<u32>,
) -> u64 {
    let n = packet.len();
    if mem.is_empty() || n == 0 {
        return 0;
    }
    let frustum = Frustum::of(packet);
    // Most packets of a view miss the whole scene (the sky around an object): they stop
    // here, before any per-lane set-up.
    let root_culled = frustum.misses_children(mem.node(0));
    if root_culled.iter().all(|&c| c) {
        return 0;
    }
    let inv = *packet.inverse_directions();
    let mut walk = PacketWalk::new::<COMMON, ANY>(packet, inv);
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
            if walk.leaf::<M, COMMON, ANY>(
                build,
                mem,
                first as usize,
                (min, max),
                child..child + count,
            ) {
                break;
            }
            continue;
        }
        walk.inner::<M, COMMON>(mem, &frustum, stack, first as usize, (min, max), child);
    }
    if !ANY {
        walk.write_hits(hits);
    }
    walk.blocked
}

/// One packet's walk down the tree: its lanes, and what they have found so far.
struct PacketWalk<'a> {
    packet: &'a RayPacket,
    n: usize,
    lanes: Lanes<'a>,
    /// Rays for the scalar triangle test, made for the lanes that need one.
    rays: LazyRays,
    /// Each lane's entry distance into the box last tested.
    entry: [f32; PACKET_RAYS],
    /// The closest hit's slot per lane (u32::MAX: none yet), written to `hits` at the end.
    best_slot: [u32; PACKET_RAYS],
    /// Only closest-hit packets with one origin test leaves lane-wide (`leaf_packet`).
    sheared: Option<ShearedLanes>,
    /// Rays with a hit, as bits, for shadow packets.
    blocked: u64,
    /// Every ray of the packet, as bits.
    all: u64,
}

impl<'a> PacketWalk<'a> {
    /// The walk of `packet`, whose inverse directions are `inv`.
    #[inline(always)]
    fn new<const COMMON: bool, const ANY: bool>(
        packet: &'a RayPacket,
        inv: [[f32; PACKET_RAYS]; 3],
    ) -> Self {
        let n = packet.len();
        let lanes = Lanes {
            origin: packet.origin,
            org: &packet.org,
            finite_inv: inv.map(|axis| axis.map(finite)),
            t: std::array::from_fn(|i| {
                if i < n && packet.t_min[i] <= packet.t_max[i] {
                    packet.t_max[i]
                } else {
                    f32::NEG_INFINITY
                }
            }),
            t_min: packet.t_min,
        };
        PacketWalk {
            packet,
            n,
            lanes,
            rays: LazyRays::new(n),
            entry: [0f32; PACKET_RAYS],
            best_slot: [u32::MAX; PACKET_RAYS],
            sheared: if COMMON && !ANY {
                ShearedLanes::of_directions(&packet.dir, n)
            } else {
                None
            },
            blocked: 0,
            all: if n == PACKET_RAYS {
                u64::MAX
            } else {
                (1 << n) - 1
            },
        }
    }

    /// Tests the leaf of triangles `slots`, in the box `(min, max)`, against the lanes from
    /// `first` on; true when every ray of a shadow packet is blocked, and the walk is done.
    #[inline(always)]
    fn leaf<M: TreeMemory, const COMMON: bool, const ANY: bool>(
        &mut self,
        build: impl Build,
        mem: &mut M,
        first: usize,
        (min, max): (Vec3, Vec3),
        slots: Range<u32>,
    ) -> bool {
        if !self.lanes.enter::<COMMON>(min, max, &mut self.entry) {
            return false;
        }
        // Lane-wide even for one lane: only the groups of 16 lanes that hold an active
        // one are computed, and that beat the scalar test from 1 lane on (1 thread,
        // AVX-512; the 4.2M knot 12.3 against 11.2 Mrays/s when it took over from 4
        // lanes, the bunny 53.8 against 50.7).
        if self.sheared.is_some() {
            self.leaf_lane_wide(mem, first, slots);
            return false;
        }
        if ANY {
            self.leaf_any_ray_by_ray(build, mem, first, slots);
            return self.blocked == self.all;
        }
        self.leaf_ray_by_ray(mem, first, slots);
        false
    }

    /// [`PacketWalk::leaf`] one triangle at a time across the lanes (`leaf_packet`), the scalar
    /// test redoing the lanes it hands back.
    #[inline(always)]
    fn leaf_lane_wide<M: TreeMemory>(&mut self, mem: &mut M, first: usize, slots: Range<u32>) {
        let Some(sheared) = self.sheared.as_ref() else {
            return;
        };
        let (n, entry) = (self.n, &self.entry);
        let mut active = [0; PACKET_RAYS];
        let (from, to) = (first as u32, n as u32);
        for (i, lane) in active.iter_mut().enumerate() {
            let index = LANE_INDEX[i];
            *lane = lane_mask((index >= from) & (index < to) & (entry[i] != f32::INFINITY));
        }
        let (packet, origin) = (self.packet, self.lanes.origin);
        let mut redo = [0; PACKET_RAYS];
        let groups = leaf_packet::active_groups(&active);
        for slot in slots {
            let tri = mem.triangle(slot);
            let again = sheared.hit(
                origin,
                tri,
                slot,
                (&active, groups),
                (&self.lanes.t_min, &packet.t_max),
                &mut self.lanes.t,
                &mut self.best_slot,
                &mut redo,
            );
            if !again {
                continue;
            }
            for i in (0..n).filter(|&i| redo[i] != 0) {
                let hit = self.rays.get(i, origin, packet).hit_triangle(
                    tri.a,
                    tri.b,
                    tri.c,
                    self.lanes.t_min[i],
                    packet.t_max[i],
                );
                let best = Some(Hit {
                    t: self.lanes.t[i],
                    slot: self.best_slot[i],
                });
                if let Some(t) = hit.filter(|&t| Hit::closer(t, slot, best)) {
                    self.lanes.t[i] = t;
                    self.best_slot[i] = slot;
                }
            }
        }
    }

    /// [`PacketWalk::leaf`] for shadow rays, ray by ray: each entering lane against the leaf's
    /// triangles 8 at a time (`leaf_ray`, what single rays use), stopping at its first hit.
    /// One triangle at a time cost the full frame 8-16 % once the collapse made leaves of 4.5
    /// triangles instead of 2 (bunny and CT bone, 1 thread); 8 at a time it runs 7-9 % ahead
    /// of the smaller leaves.
    #[inline(always)]
    fn leaf_any_ray_by_ray<M: TreeMemory>(
        &mut self,
        build: impl Build,
        mem: &mut M,
        first: usize,
        slots: Range<u32>,
    ) {
        let (packet, origin) = (self.packet, self.lanes.origin);
        for i in first..self.n {
            if self.entry[i] == f32::INFINITY {
                continue;
            }
            let ray = self.rays.get(i, origin, packet);
            let (t_min, t_max) = (self.lanes.t_min[i], self.lanes.t[i]);
            let (mut at, mut hit) = (slots.start, false);
            while at < slots.end && !hit {
                let tris = mem.triangles(at..slots.end);
                hit = leaf_ray::any_hit(build, ray, tris, t_min, t_max);
                at += tris.len() as u32;
            }
            if hit {
                // Done with this ray: it enters no box from now on.
                self.blocked |= 1 << i;
                self.lanes.t[i] = f32::NEG_INFINITY;
            }
        }
    }

    /// [`PacketWalk::leaf`] for closest hits ray by ray, each entering lane against every
    /// triangle.
    #[inline(always)]
    fn leaf_ray_by_ray<M: TreeMemory>(&mut self, mem: &mut M, first: usize, slots: Range<u32>) {
        let (packet, origin) = (self.packet, self.lanes.origin);
        for i in first..self.n {
            if self.entry[i] == f32::INFINITY {
                continue;
            }
            let ray = self.rays.get(i, origin, packet);
            for slot in slots.clone() {
                let tri = mem.triangle(slot);
                let lanes = &mut self.lanes;
                let (t_min, t_max) = (lanes.t_min[i], packet.t_max[i]);
                if let Some(t) = ray.hit_triangle(tri.a, tri.b, tri.c, t_min, t_max) {
                    // Closest hits accept a tie on a lower slot too (see `Hit::closer`),
                    // so they agree with the single-ray traversal of the 8-wide tree.
                    let best = Some(Hit {
                        t: lanes.t[i],
                        slot: self.best_slot[i],
                    });
                    if Hit::closer(t, slot, best) {
                        lanes.t[i] = t;
                        self.best_slot[i] = slot;
                    }
                }
            }
        }
    }

    /// Pushes the children of inner node `child` (in the box `(min, max)`) that the frustum
    /// keeps, if a lane from `first` on enters the box.
    #[inline(always)]
    fn inner<M: TreeMemory, const COMMON: bool>(
        &mut self,
        mem: &mut M,
        frustum: &Frustum,
        stack: &mut Vec<u32>,
        first: usize,
        (min, max): (Vec3, Vec3),
        child: u32,
    ) {
        // Inner nodes test the first active ray alone (Wald's "first hit" packet
        // traversal): for coherent rays it usually enters, and the node costs one ray's
        // box test. If it misses, all lanes are tested at once, which is cheaper than
        // trying them one by one when none enters (a frequent case for 8-wide siblings).
        let lanes = &self.lanes;
        let active = if lanes.enters::<COMMON>(first, min, max) {
            first
        } else if lanes.enter::<COMMON>(min, max, &mut self.entry) {
            match (first + 1..self.n).find(|&i| self.entry[i] < f32::INFINITY) {
                Some(i) => i,
                None => return,
            }
        } else {
            return;
        };
        // Every child the frustum keeps is pushed: other lanes may enter what the active
        // ray misses. Those it misses (or enters beyond its closest hit) go deepest; those
        // it enters on top, nearest last, in an insertion sort of the few (1-3 typically)
        // it enters.
        let node = mem.node(child);
        let ray = BoxRay::from_parts(
            lanes.origin_of::<COMMON>(active),
            lanes.finite_inv_of(active),
        );
        let t = enter_wide(node, &ray, f32::INFINITY);
        let culled = frustum.misses_children(node);
        // The node's children as it names them: the node is not read again once the hints
        // below go out through the memory.
        let (children, counts) = (node.child, node.count);
        stack.reserve(3 * WIDTH);
        let mut entered = [0usize; WIDTH];
        let mut n_entered = 0;
        for k in 0..WIDTH {
            if culled[k] {
                continue;
            }
            if t[k] == f32::INFINITY {
                mem.prefetch(children[k], counts[k]);
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
            mem.prefetch(children[k], counts[k]);
            stack.extend([active as u32, child, k as u32]);
        }
    }

    /// The closest hits found, into `hits` (which the caller has filled with misses).
    #[inline(always)]
    fn write_hits(&self, hits: &mut [PacketHit; PACKET_RAYS]) {
        for i in 0..self.n {
            if self.best_slot[i] != u32::MAX {
                hits[i] = PacketHit::new(self.lanes.t[i], self.best_slot[i]);
            }
        }
    }
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::knot_scene;
    use crate::{orbit_of, PixelRays};
    use tessera_model::camera::Camera;
    use tessera_model::cut::CutPlanes;

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
