//! A leaf's triangles against all rays of a packet at once: the watertight test of
//! [`Ray::hit_triangle`], written lane by lane over structure-of-arrays with no branch and no
//! short-circuit, so that the compiler runs it 8 or 16 lanes wide. It applies when the rays
//! share their origin (primary rays) and their axis frame: then the triangle's corners relative
//! to the origin are the same for every lane and only the shear constants differ. The
//! operations and their order are the scalar test's, so each lane gets exactly the scalar
//! answer; the rare lane where an edge function is exactly zero (which the scalar test redoes
//! in f64) is handed back to it.

use crate::bvh::node::LeafTriangle;
use crate::geometry::Ray;
use crate::packet::{lane_mask, LaneMask, PACKET_RAYS};
use glam::Vec3;

/// Lanes computed together by [`ShearedLanes::hit`]: one AVX-512 vector, two AVX2 ones.
pub(crate) const GROUP: usize = 16;

/// Bit `g` set where a lane of group `g` (lanes `g·GROUP ..`) is active.
#[inline(always)]
pub(crate) fn active_groups(active: &[LaneMask; PACKET_RAYS]) -> u32 {
    let mut groups = 0;
    for (g, lanes) in active.chunks_exact(GROUP).enumerate() {
        groups |= u32::from(lanes.iter().fold(0, |a, &b| a | b) != 0) << g;
    }
    groups
}

/// The per-lane shear constants of a packet whose rays share one axis frame.
pub(crate) struct ShearedLanes {
    axes: [usize; 3],
    sx: [f32; PACKET_RAYS],
    sy: [f32; PACKET_RAYS],
    sz: [f32; PACKET_RAYS],
}

impl ShearedLanes {
    /// `None` if the first `n` directions (structure-of-arrays) do not all share the first
    /// one's axis frame. The frame and the shear constants are those [`Ray::new`] computes,
    /// with the same operations, so each lane's test is the scalar one; this runs over the
    /// lanes at once instead of building 64 rays.
    pub(crate) fn of_directions(dir: &[[f32; PACKET_RAYS]; 3], n: usize) -> Option<Self> {
        if n == 0 {
            return None;
        }
        let first = Ray::new(Vec3::ZERO, Vec3::new(dir[0][0], dir[1][0], dir[2][0]));
        let (axes, _) = first.shear_frame();
        let [kx, ky, kz] = axes;
        let negative = dir[kz][0] < 0.0;
        let mut same = true;
        for i in 0..n {
            let (x, y, z) = (dir[0][i].abs(), dir[1][i].abs(), dir[2][i].abs());
            let dominant = if (x >= y) & (x >= z) {
                0
            } else if y >= z {
                1
            } else {
                2
            };
            same &= (dominant == kz) & ((dir[kz][i] < 0.0) == negative);
        }
        if !same {
            return None;
        }
        let (dx, dy, dz) = (&dir[kx], &dir[ky], &dir[kz]);
        Some(ShearedLanes {
            axes,
            sx: std::array::from_fn(|i| dx[i] / dz[i]),
            sy: std::array::from_fn(|i| dy[i] / dz[i]),
            sz: std::array::from_fn(|i| 1.0 / dz[i]),
        })
    }

    /// Tests `tri` (leaf slot `slot`) for every lane with `active` set, from the common
    /// `origin`, within `(t_min, t_max)`, and keeps it where it is closer than `best_t` /
    /// `best_slot` (ties to the lower slot). Sets `redo` for the lanes the scalar test must do
    /// instead, and returns whether there are any. Only the groups of [`GROUP`] lanes whose
    /// bit is set in `groups` (see [`active_groups`]) are computed: on a mesh of
    /// pixel-sized triangles a leaf is entered by a few neighbouring rays, which sit in one
    /// or two rows of the 8×8 packet.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn hit(
        &self,
        origin: Vec3,
        tri: &LeafTriangle,
        slot: u32,
        (active, groups): (&[LaneMask; PACKET_RAYS], u32),
        (t_min, t_max): (&[f32; PACKET_RAYS], &[f32; PACKET_RAYS]),
        best_t: &mut [f32; PACKET_RAYS],
        best_slot: &mut [u32; PACKET_RAYS],
        redo: &mut [LaneMask; PACKET_RAYS],
    ) -> bool {
        let [kx, ky, kz] = self.axes;
        let (a, b, c) = (tri.a - origin, tri.b - origin, tri.c - origin);
        let (a_x, a_y, a_z) = (a[kx], a[ky], a[kz]);
        let (b_x, b_y, b_z) = (b[kx], b[ky], b[kz]);
        let (c_x, c_y, c_z) = (c[kx], c[ky], c[kz]);
        let mut any_redo = 0;
        for group in 0..PACKET_RAYS / GROUP {
            if groups >> group & 1 == 0 {
                continue;
            }
            for i in group * GROUP..(group + 1) * GROUP {
                let (sx, sy, sz) = (self.sx[i], self.sy[i], self.sz[i]);
                let ax = a_x - sx * a_z;
                let ay = a_y - sy * a_z;
                let bx = b_x - sx * b_z;
                let by = b_y - sy * b_z;
                let cx = c_x - sx * c_z;
                let cy = c_y - sy * c_z;
                let u = cx * by - cy * bx;
                let v = ax * cy - ay * cx;
                let w = bx * ay - by * ax;
                let edge = (u == 0.0) | (v == 0.0) | (w == 0.0);
                let outside =
                    ((u < 0.0) | (v < 0.0) | (w < 0.0)) & ((u > 0.0) | (v > 0.0) | (w > 0.0));
                let det = u + v + w;
                let t = (u * (sz * a_z) + v * (sz * b_z) + w * (sz * c_z)) / det;
                let closer = (t < best_t[i]) | ((t == best_t[i]) & (slot < best_slot[i]));
                let live = active[i] != 0;
                let take = live
                    & !edge
                    & !outside
                    & (det != 0.0)
                    & (t > t_min[i])
                    & (t < t_max[i])
                    & closer;
                let again = live & edge;
                redo[i] = lane_mask(again);
                any_redo |= redo[i];
                best_t[i] = if take { t } else { best_t[i] };
                best_slot[i] = if take { slot } else { best_slot[i] };
            }
        }
        any_redo != 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every lane gets exactly the scalar answer, or is handed back: including rays through a
    /// triangle's edge and corner, where an edge function is exactly zero.
    #[test]
    fn each_lane_agrees_with_the_scalar_test() {
        let origin = Vec3::new(0.0, 0.0, -3.0);
        let tri = LeafTriangle {
            a: Vec3::new(-1.0, -1.0, 0.0),
            b: Vec3::new(1.0, -1.0, 0.0),
            c: Vec3::new(-1.0, 1.0, 0.0),
        };
        // An 8x8 grid over the triangle's box, so rows and columns cross its corners and its
        // axis-parallel edges exactly.
        let rays: [Ray; PACKET_RAYS] = std::array::from_fn(|i| {
            let (x, y) = ((i % 8) as f32 / 3.5 - 1.0, (i / 8) as f32 / 3.5 - 1.0);
            Ray::new(origin, Vec3::new(x, y, 0.0) - origin)
        });
        let dir = std::array::from_fn(|axis| std::array::from_fn(|i| rays[i].dir[axis]));
        let lanes = ShearedLanes::of_directions(&dir, PACKET_RAYS).expect("one axis frame");
        for (i, ray) in rays.iter().enumerate() {
            let (_, shear) = ray.shear_frame();
            assert_eq!(
                [lanes.sx[i], lanes.sy[i], lanes.sz[i]],
                shear.to_array(),
                "lane {i}"
            );
        }
        let (t_min, t_max) = ([0.0; PACKET_RAYS], [f32::INFINITY; PACKET_RAYS]);
        let mut best_t = [f32::INFINITY; PACKET_RAYS];
        let mut best_slot = [u32::MAX; PACKET_RAYS];
        let mut redo = [0; PACKET_RAYS];
        let active = [lane_mask(true); PACKET_RAYS];
        lanes.hit(
            origin,
            &tri,
            7,
            (&active, active_groups(&active)),
            (&t_min, &t_max),
            &mut best_t,
            &mut best_slot,
            &mut redo,
        );
        let mut handed_back = 0;
        for (i, ray) in rays.iter().enumerate() {
            let scalar = ray.hit_triangle(tri.a, tri.b, tri.c, 0.0, f32::INFINITY);
            if redo[i] != 0 {
                handed_back += 1;
                continue;
            }
            let wide = (best_slot[i] == 7).then_some(best_t[i]);
            assert_eq!(wide, scalar, "lane {i}");
        }
        assert!(handed_back > 0, "the grid must cross an edge exactly");
        assert!(best_slot.contains(&7), "and hit the triangle");
    }
}
