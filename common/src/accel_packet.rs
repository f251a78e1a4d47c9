//! Coherent traversal of the BVH by whole 64-ray packets.
//!
//! For packets with a common origin (primary rays), every node is first tested against the
//! packet's frustum (interval arithmetic over its directions), which drops whole subtrees with
//! one test; inner nodes then test single rays from the first active one until one enters
//! (Wald's "first hit" traversal), and leaves test all 64 lanes at once in structure-of-arrays
//! form, which the compiler turns into 8-wide SIMD, so that only the lanes whose rays enter a
//! leaf test its triangles. Packets that lose coherence (no common origin) fall back to single
//! rays.
//!
//! The SIMD width is chosen at run time: an AVX2 build of the same code runs where the CPU has
//! it, the baseline SSE2 build elsewhere. Both give bit-identical results, because Rust never
//! fuses a multiply and an add into an FMA on its own, so every node of a wall renders the same
//! pixels whatever its CPU.

use crate::accel::Accel;
use crate::geometry::Ray;
use crate::render::packet::{PacketHit, RayPacket, COMMON_ORIGIN, PACKET_RAYS};
use glam::Vec3;

/// The packet's rays in lanes: shared origin, inverse directions and current hit distances.
struct Lanes {
    origin: Vec3,
    inv: [[f32; PACKET_RAYS]; 3],
    /// Closest hit so far (at first the end of the ray's interval); -inf for lanes past the
    /// packet's end or with an empty interval, so they never enter a box.
    t: [f32; PACKET_RAYS],
    /// Start of each ray's interval (0 unless cutting planes clip it).
    t_min: [f32; PACKET_RAYS],
}

impl Lanes {
    /// Entry distance of every lane into the box, +inf where the lane misses it.
    #[inline(always)]
    fn enter(&self, min: Vec3, max: Vec3, out: &mut [f32; PACKET_RAYS]) -> bool {
        let lo = [
            min.x - self.origin.x,
            min.y - self.origin.y,
            min.z - self.origin.z,
        ];
        let hi = [
            max.x - self.origin.x,
            max.y - self.origin.y,
            max.z - self.origin.z,
        ];
        let mut any = false;
        for i in 0..PACKET_RAYS {
            let (x0, x1) = (lo[0] * self.inv[0][i], hi[0] * self.inv[0][i]);
            let (y0, y1) = (lo[1] * self.inv[1][i], hi[1] * self.inv[1][i]);
            let (z0, z1) = (lo[2] * self.inv[2][i], hi[2] * self.inv[2][i]);
            let near = x0
                .min(x1)
                .max(y0.min(y1))
                .max(z0.min(z1))
                .max(self.t_min[i]);
            let far = x0.max(x1).min(y0.max(y1)).min(z0.max(z1)).min(self.t[i]);
            let hit = near <= far;
            out[i] = if hit { near } else { f32::INFINITY };
            any |= hit;
        }
        any
    }
}

impl Accel {
    /// Closest hits of a whole packet (see the module documentation).
    pub fn closest_hits(
        &self,
        packet: &mut RayPacket,
        hits: &mut [PacketHit; PACKET_RAYS],
        stack: &mut Vec<u32>,
    ) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2, checked just above.
            unsafe { self.closest_hits_avx2(packet, hits, stack) };
            return;
        }
        self.closest_hits_portable(packet, hits, stack);
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn closest_hits_avx2(
        &self,
        packet: &mut RayPacket,
        hits: &mut [PacketHit; PACKET_RAYS],
        stack: &mut Vec<u32>,
    ) {
        self.closest_hits_generic(packet, hits, stack);
    }

    /// The baseline build of the traversal, also used to check that the SIMD builds agree.
    pub fn closest_hits_portable(
        &self,
        packet: &mut RayPacket,
        hits: &mut [PacketHit; PACKET_RAYS],
        stack: &mut Vec<u32>,
    ) {
        self.closest_hits_generic(packet, hits, stack);
    }

    #[inline(always)]
    fn closest_hits_generic(
        &self,
        packet: &mut RayPacket,
        hits: &mut [PacketHit; PACKET_RAYS],
        stack: &mut Vec<u32>,
    ) {
        let n = packet.len();
        hits[..n].fill(PacketHit::MISS);
        if !packet.has(COMMON_ORIGIN) {
            for (i, hit) in hits.iter_mut().enumerate().take(n) {
                let ray = Ray::new(packet.ray_origin(i), packet.direction(i));
                *hit = self
                    .closest_hit(&ray, packet.t_min[i], packet.t_max[i], stack)
                    .map_or(PacketHit::MISS, |h| PacketHit::new(h.t, h.slot));
            }
            return;
        }
        if self.nodes.is_empty() || n == 0 {
            return;
        }
        let origin = packet.origin;
        let frustum = Frustum::of(packet);
        let rays: [Ray; PACKET_RAYS] =
            std::array::from_fn(|i| Ray::new(origin, packet.direction(i.min(n - 1))));
        let mut lanes = Lanes {
            origin,
            inv: *packet.inverse_directions(),
            t: std::array::from_fn(|i| {
                if i < n && packet.t_min[i] <= packet.t_max[i] {
                    packet.t_max[i]
                } else {
                    f32::NEG_INFINITY
                }
            }),
            t_min: packet.t_min,
        };
        let mut entry = [0f32; PACKET_RAYS];
        // Stack entries are pairs (first active lane, node): lanes before the first active one
        // missed an ancestor's box, so they miss every box below it.
        stack.clear();
        stack.extend([0, 0]);
        while let (Some(index), Some(first)) = (stack.pop(), stack.pop()) {
            let node = &self.nodes[index as usize];
            if frustum.misses(node.min, node.max, origin, f32::INFINITY) {
                continue;
            }
            if node.count > 0 {
                if !lanes.enter(node.min, node.max, &mut entry) {
                    continue;
                }
                for i in first as usize..n {
                    if entry[i] == f32::INFINITY {
                        continue;
                    }
                    for slot in node.first..node.first + node.count {
                        let tri = &self.triangles[slot as usize];
                        if let Some(t) =
                            rays[i].hit_triangle(tri.a, tri.b, tri.c, lanes.t_min[i], lanes.t[i])
                        {
                            lanes.t[i] = t;
                            hits[i] = PacketHit::new(t, slot);
                        }
                    }
                }
                continue;
            }
            // Inner nodes test single rays, from the first active one on, until one enters
            // (Wald's "first hit" packet traversal): for coherent rays that is the first one,
            // so a node costs one ray's box test instead of 64.
            let Some(active) = (first as usize..n)
                .find(|&i| rays[i].box_entry(node.min, node.max, lanes.t[i]) < f32::INFINITY)
            else {
                continue;
            };
            let (l, r) = (node.first, node.first + 1);
            let (ln, rn) = (&self.nodes[l as usize], &self.nodes[r as usize]);
            let tl = rays[active].box_entry(ln.min, ln.max, f32::INFINITY);
            let tr = rays[active].box_entry(rn.min, rn.max, f32::INFINITY);
            let active = active as u32;
            if tl <= tr {
                stack.extend([active, r, active, l]);
            } else {
                stack.extend([active, l, active, r]);
            }
        }
    }
}

/// Bounds on the inverse directions of a packet, for culling boxes no ray of it can enter.
struct Frustum {
    /// Per axis: smallest and largest inverse direction, when all rays agree in sign.
    inv: [(f32, f32); 3],
    usable: bool,
}

impl Frustum {
    fn of(packet: &mut RayPacket) -> Self {
        let n = packet.len();
        let inv = packet.inverse_directions();
        let mut bounds = [(0.0, 0.0); 3];
        let mut usable = n > 0;
        for axis in 0..3 {
            let lanes = &inv[axis][..n];
            let lo = lanes.iter().fold(f32::INFINITY, |a, &b| a.min(b));
            let hi = lanes.iter().fold(f32::NEG_INFINITY, |a, &b| a.max(b));
            // Mixed signs (or an axis-parallel ray) make the interval bounds meaningless.
            usable &= lo.is_finite() && hi.is_finite() && (lo > 0.0 || hi < 0.0);
            bounds[axis] = (lo, hi);
        }
        Frustum {
            inv: bounds,
            usable,
        }
    }

    /// True when no ray of the packet can enter the box before `t_max`.
    fn misses(&self, min: Vec3, max: Vec3, origin: Vec3, t_max: f32) -> bool {
        if !self.usable {
            return false;
        }
        let mut near = 0.0f32;
        let mut far = t_max;
        for axis in 0..3 {
            let (lo, hi) = self.inv[axis];
            let (a, b) = (min[axis] - origin[axis], max[axis] - origin[axis]);
            // Rays going + enter through the min slab, rays going - through the max slab.
            let (enter, exit) = if lo > 0.0 { (a, b) } else { (b, a) };
            near = near.max((enter * lo).min(enter * hi));
            far = far.min((exit * lo).max(exit * hi));
        }
        near > far
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::{Camera, CameraMode, CutPlanes};
    use crate::scene::knot_scene;

    #[test]
    fn packet_traversal_finds_what_single_rays_find_on_every_simd_path() {
        let scene = knot_scene(256, 32);
        let accel = Accel::build(&scene);
        let mut stack = accel.new_stack();
        let orbit = CameraMode::orbit_of(&scene.bounds());
        for frame in [0u64, 40, 95, 200] {
            let camera: Camera = orbit.camera_for_frame(frame);
            let rays = camera.rays_for(96, 64);
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
                let mut portable = [PacketHit::MISS; PACKET_RAYS];
                accel.closest_hits(&mut packet, &mut fast, &mut stack);
                accel.closest_hits_portable(&mut packet, &mut portable, &mut stack);
                assert_eq!(fast, portable, "SIMD paths disagree (frame {frame})");
                for i in 0..packet.len() {
                    let ray = Ray::new(camera.eye, packet.direction(i));
                    let (t_min, t_max) = cuts.interval(camera.eye, packet.direction(i));
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
}
