//! 64-ray packets in structure-of-arrays layout, as in Manta.
//!
//! Properties the whole packet shares are flags (a common origin, normalized directions), so
//! traversal can take the fast path they allow. Derived values (inverse directions) are
//! computed once, on first use, and flagged. Shading splits a packet into sub-packets of
//! consecutive rays with the same material: ranges of the packet, not copies.

use crate::PixelRays;
use glam::Vec3;
use std::ops::Range;
use tessera_model::cut::CutPlanes;

/// Rays in a packet: the most it holds (a packet of fewer uses lanes `0..len`).
pub const PACKET_RAYS: usize = 64;

/// A lane's flag as a mask the width of its `f32` (all ones or zero). Kept in `bool` arrays,
/// the flags cost the AVX2 build a pack to bytes at every store and a widening at every load
/// (AVX-512 has mask registers for that): 8 % of its eye-light frame on the dragon.
pub(crate) type LaneMask = u32;

/// The [`LaneMask`] of `flag`.
#[inline(always)]
pub(crate) fn lane_mask(flag: bool) -> LaneMask {
    LaneMask::from(flag).wrapping_neg()
}

/// Each lane's index, as a 32-bit lane: compared with `usize` indices, the AVX2 build
/// compared four lanes at a time.
pub(crate) const LANE_INDEX: [u32; PACKET_RAYS] = {
    let mut index = [0; PACKET_RAYS];
    let mut i = 0;
    while i < PACKET_RAYS {
        index[i] = i as u32;
        i += 1;
    }
    index
};

/// All rays start at [`RayPacket::origin`].
pub const COMMON_ORIGIN: u32 = 1;
/// All directions have unit length.
pub const NORMALIZED: u32 = 1 << 1;
/// `inv` holds the inverse directions.
pub const HAVE_INVERSE: u32 = 1 << 2;
/// Some rays are limited to an interval other than `[0, ∞)` (cutting planes).
pub const CLIPPED: u32 = 1 << 3;

/// Up to [`PACKET_RAYS`] rays in render coordinates, one array per axis, with the flags
/// ([`COMMON_ORIGIN`], [`NORMALIZED`], ...) of what they share.
pub struct RayPacket {
    len: usize,
    flags: u32,
    /// The shared origin when `COMMON_ORIGIN` is set.
    pub origin: Vec3,
    /// Per-ray origins (each equal to `origin` when `COMMON_ORIGIN` is set).
    pub org: [[f32; PACKET_RAYS]; 3],
    /// Per-ray directions, one array per axis; unit length when [`NORMALIZED`] is set.
    pub dir: [[f32; PACKET_RAYS]; 3],
    inv: [[f32; PACKET_RAYS]; 3],
    /// Per-ray interval searched for hits; `t_min > t_max` for a ray that can hit nothing.
    pub t_min: [f32; PACKET_RAYS],
    /// Per-ray end of the interval searched for hits (infinity unless clipped), in units of the
    /// ray's direction length.
    pub t_max: [f32; PACKET_RAYS],
}

impl RayPacket {
    /// Primary rays of the `w × h ≤ 8 × 8` pixel block at `(x0, y0)`, row-major.
    pub fn primary(rays: &PixelRays, x0: u32, y0: u32, w: u32, h: u32) -> Self {
        // One packet, returned on every path. (The compiler still copies `at_eye`'s packet
        // once, 1-2 % of an eye-light frame; marking these inline made the frame slower.)
        let mut p = Self::at_eye(rays, (w * h) as usize);
        if w == 8 {
            // A full-width block (all but the right edge of a tile): lane i is pixel
            // (i % 8, i / 8), and the directions come lane-wide, with the operations of
            // `PixelRays::direction_at` in its order, so the bits are the same.
            let lanes = p.len;
            let sx: [f32; PACKET_RAYS] = std::array::from_fn(|i| (x0 + (i % 8) as u32) as f32);
            let sy: [f32; PACKET_RAYS] = std::array::from_fn(|i| (y0 + (i / 8) as u32) as f32);
            rays.directions_soa(&sx[..lanes], &sy[..lanes], &mut p.dir);
        } else {
            p.aim_jittered(rays, (x0, y0, w), |_, _| (0.5, 0.5));
        }
        p
    }

    /// A packet of `len` rays from the eye with no directions yet.
    fn at_eye(rays: &PixelRays, len: usize) -> Self {
        RayPacket {
            len,
            flags: COMMON_ORIGIN | NORMALIZED,
            origin: rays.eye,
            org: [
                [rays.eye.x; PACKET_RAYS],
                [rays.eye.y; PACKET_RAYS],
                [rays.eye.z; PACKET_RAYS],
            ],
            dir: [[0.0; PACKET_RAYS]; 3],
            inv: [[0.0; PACKET_RAYS]; 3],
            t_min: [0.0; PACKET_RAYS],
            t_max: [f32::INFINITY; PACKET_RAYS],
        }
    }

    /// Primary rays through the points `jitter(x, y)` of each pixel of the block.
    pub fn primary_jittered(
        rays: &PixelRays,
        x0: u32,
        y0: u32,
        w: u32,
        h: u32,
        jitter: impl FnMut(u32, u32) -> (f32, f32),
    ) -> Self {
        let mut p = Self::at_eye(rays, (w * h) as usize);
        p.aim_jittered(rays, (x0, y0, w), jitter);
        p
    }

    /// Points lane i at `jitter(x, y)` of pixel `(x, y)`, the i-th of the block `w` wide from
    /// `(x0, y0)`, row-major.
    fn aim_jittered(
        &mut self,
        rays: &PixelRays,
        (x0, y0, w): (u32, u32, u32),
        mut jitter: impl FnMut(u32, u32) -> (f32, f32),
    ) {
        for i in 0..self.len {
            let (x, y) = (x0 + i as u32 % w, y0 + i as u32 / w);
            let (jx, jy) = jitter(x, y);
            let d = rays.direction_at(x, y, jx, jy);
            for axis in 0..3 {
                self.dir[axis][i] = d[axis];
            }
        }
    }

    /// Rays with their own origins (shadow and ambient-occlusion packets).
    pub fn from_rays(rays: impl IntoIterator<Item = (Vec3, Vec3)>) -> Self {
        let mut p = RayPacket {
            len: 0,
            flags: 0,
            origin: Vec3::ZERO,
            org: [[0.0; PACKET_RAYS]; 3],
            dir: [[0.0; PACKET_RAYS]; 3],
            inv: [[0.0; PACKET_RAYS]; 3],
            t_min: [0.0; PACKET_RAYS],
            t_max: [f32::INFINITY; PACKET_RAYS],
        };
        for (o, d) in rays.into_iter().take(PACKET_RAYS) {
            for axis in 0..3 {
                p.org[axis][p.len] = o[axis];
                p.dir[axis][p.len] = d[axis];
            }
            p.len += 1;
        }
        p
    }

    /// Rays from one `origin` in `directions` (unit length), each searched up to `t_max`: the
    /// ambient-occlusion rays of one hit, which the packet traversal's common-origin tests
    /// serve.
    pub fn from_origin(
        origin: Vec3,
        directions: impl IntoIterator<Item = Vec3>,
        t_max: f32,
    ) -> Self {
        let mut p = Self::from_rays(directions.into_iter().map(|d| (origin, d)));
        p.flags = COMMON_ORIGIN | NORMALIZED;
        p.origin = origin;
        p.t_max = [t_max; PACKET_RAYS];
        p
    }

    /// Limits every ray to the part of it that the cutting planes keep.
    pub fn clip(&mut self, cuts: &CutPlanes) {
        if cuts.is_empty() {
            return;
        }
        for i in 0..self.len {
            (self.t_min[i], self.t_max[i]) = cuts.interval(self.ray_origin(i), self.direction(i));
        }
        self.flags |= CLIPPED;
    }

    /// How many lanes hold rays (`0..len`); the rest are unused.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the packet holds no ray.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Whether `flag` (one of [`COMMON_ORIGIN`], [`NORMALIZED`], ...) is set.
    pub fn has(&self, flag: u32) -> bool {
        self.flags & flag != 0
    }

    /// The direction of ray `i`.
    pub fn direction(&self, i: usize) -> Vec3 {
        Vec3::new(self.dir[0][i], self.dir[1][i], self.dir[2][i])
    }

    /// The origin of ray `i`.
    pub fn ray_origin(&self, i: usize) -> Vec3 {
        Vec3::new(self.org[0][i], self.org[1][i], self.org[2][i])
    }

    /// Inverse directions, computed on first use.
    pub fn inverse_directions(&mut self) -> &[[f32; PACKET_RAYS]; 3] {
        if !self.has(HAVE_INVERSE) {
            for axis in 0..3 {
                for i in 0..PACKET_RAYS {
                    self.inv[axis][i] = 1.0 / self.dir[axis][i];
                }
            }
            self.flags |= HAVE_INVERSE;
        }
        &self.inv
    }
}

/// The closest hit of one ray of a packet.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PacketHit {
    /// Distance along the ray to the hit, in units of its direction's length; infinity for a miss.
    pub t: f32,
    slot: u32,
}

impl PacketHit {
    /// No hit: `t` infinite and no slot.
    pub const MISS: PacketHit = PacketHit {
        t: f32::INFINITY,
        slot: u32::MAX,
    };

    /// A hit at `t` of the triangle in leaf slot `slot` (`u32::MAX` is read as no triangle).
    pub fn new(t: f32, slot: u32) -> Self {
        PacketHit { t, slot }
    }

    /// Leaf slot of the triangle hit, if any.
    pub fn slot(&self) -> Option<u32> {
        (self.slot != u32::MAX).then_some(self.slot)
    }
}

/// Splits `keys` into maximal runs of equal consecutive keys: the sub-packets of rays that share
/// a material, as ranges into the packet (no allocation: it runs once per packet).
pub fn runs_by<K: PartialEq + Copy>(keys: &[K]) -> impl Iterator<Item = (K, Range<usize>)> + '_ {
    let mut start = 0;
    std::iter::from_fn(move || {
        let &key = keys.get(start)?;
        let len = keys[start..].iter().take_while(|&&k| k == key).count();
        let run = start..start + len;
        start += len;
        Some((key, run))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_model::camera::Camera;

    #[test]
    fn primary_packets_share_origin_and_compute_inverses_once() {
        let camera = Camera::new(Vec3::new(1.0, 2.0, 3.0), Vec3::ZERO, Vec3::Y, 60.0).unwrap();
        let rays = PixelRays::new(&camera, 64, 48);
        let mut p = RayPacket::primary(&rays, 8, 16, 8, 5);
        assert_eq!(p.len(), 40);
        assert!(p.has(COMMON_ORIGIN) && p.has(NORMALIZED) && !p.has(HAVE_INVERSE));
        assert_eq!(p.direction(9), rays.direction(9, 17));
        let inv_x = p.inverse_directions()[0][9];
        assert!(p.has(HAVE_INVERSE));
        assert_eq!(inv_x, 1.0 / rays.direction(9, 17).x);
    }

    #[test]
    fn full_width_blocks_get_the_directions_of_single_pixels_bit_for_bit() {
        let camera = Camera::new(Vec3::new(0.3, 2.0, 7.0), Vec3::ONE, Vec3::Y, 35.0).unwrap();
        let rays = PixelRays::new(&camera, 1920, 1080);
        for (x0, y0, h) in [(0, 0, 8), (1912, 1072, 8), (640, 360, 3)] {
            let p = RayPacket::primary(&rays, x0, y0, 8, h);
            let slow = RayPacket::primary_jittered(&rays, x0, y0, 8, h, |_, _| (0.5, 0.5));
            assert_eq!(p.len(), (8 * h) as usize);
            for i in 0..p.len() {
                let d = rays.direction(x0 + i as u32 % 8, y0 + i as u32 / 8);
                assert_eq!(p.direction(i).to_array(), d.to_array(), "lane {i}");
                assert_eq!(slow.direction(i).to_array(), d.to_array(), "lane {i}");
            }
        }
    }

    #[test]
    fn runs_split_by_material_without_gaps() {
        let runs: Vec<_> = runs_by(&[2u16, 2, 5, 5, 5, 2, 7]).collect();
        assert_eq!(runs, vec![(2, 0..2), (5, 2..5), (2, 5..6), (7, 6..7)]);
        assert!(runs_by::<u16>(&[]).next().is_none());
    }
}
