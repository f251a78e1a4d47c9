//! Rays, boxes and the watertight ray–triangle test.
//!
//! The triangle test is the one of Woop, Benthin and Wald (JCGT 2013): the ray is sheared so it
//! runs along +z, and the edge functions are evaluated in 2D. A point on a shared edge gets the
//! same edge-function value from both triangles, so rays through edges and vertices of a closed
//! mesh never slip through; exact zeros fall back to double precision.

use glam::Vec3;

/// A ray with the per-ray values the triangle and box tests need, computed once.
#[derive(Clone, Copy, Debug)]
pub struct Ray {
    /// Where the ray starts, in render coordinates.
    pub origin: Vec3,
    /// The direction, not necessarily of unit length: distances along the ray are in its units.
    pub dir: Vec3,
    /// `1 / dir` per axis (infinite for a zero component), for the box test.
    pub inv_dir: Vec3,
    /// Index of the dominant axis of `dir` (the one the ray is sheared onto).
    kz: usize,
    kx: usize,
    ky: usize,
    shear: Vec3,
}

impl Ray {
    /// `dir` need not be normalized but must be finite and non-zero.
    pub fn new(origin: Vec3, dir: Vec3) -> Self {
        let abs = dir.abs();
        let kz = if abs.x >= abs.y && abs.x >= abs.z {
            0
        } else if abs.y >= abs.z {
            1
        } else {
            2
        };
        let mut kx = (kz + 1) % 3;
        let mut ky = (kx + 1) % 3;
        // Keep the winding independent of the sign of the dominant axis.
        if dir[kz] < 0.0 {
            std::mem::swap(&mut kx, &mut ky);
        }
        let shear = Vec3::new(dir[kx] / dir[kz], dir[ky] / dir[kz], 1.0 / dir[kz]);
        Ray {
            origin,
            dir,
            inv_dir: dir.recip(),
            kz,
            kx,
            ky,
            shear,
        }
    }

    /// The axes the watertight test works in (x, y, then the dominant z) and its shear
    /// constants, for testing many rays against one triangle at once (`bvh::leaf_packet`).
    pub(crate) fn shear_frame(&self) -> ([usize; 3], Vec3) {
        ([self.kx, self.ky, self.kz], self.shear)
    }

    /// The point at distance `t` along the ray (in units of `dir`).
    pub fn at(&self, t: f32) -> Vec3 {
        self.origin + self.dir * t
    }

    /// Distance along the ray to the entry of the box `[min, max]`, or `f32::INFINITY` if the
    /// ray misses it or enters after `t_max`.
    #[inline(always)]
    pub fn box_entry(&self, min: Vec3, max: Vec3, t_max: f32) -> f32 {
        let t0 = (min - self.origin) * self.inv_dir;
        let t1 = (max - self.origin) * self.inv_dir;
        // min/max ignore a NaN operand (0 * inf on a slab plane), which keeps the test conservative.
        let t_near = t0.min(t1).max_element().max(0.0);
        let t_far = t0.max(t1).min_element().min(t_max);
        if t_near <= t_far {
            t_near
        } else {
            f32::INFINITY
        }
    }

    /// Watertight intersection with triangle `(a, b, c)`: the distance along the ray (in units of
    /// `dir`) if the ray hits it within `(t_min, t_max)`, else `None`. Both sides are hit.
    #[inline(always)]
    pub fn hit_triangle(&self, a: Vec3, b: Vec3, c: Vec3, t_min: f32, t_max: f32) -> Option<f32> {
        let (kx, ky, kz) = (self.kx, self.ky, self.kz);
        let (sx, sy, sz) = (self.shear.x, self.shear.y, self.shear.z);
        let a = a - self.origin;
        let b = b - self.origin;
        let c = c - self.origin;
        let ax = a[kx] - sx * a[kz];
        let ay = a[ky] - sy * a[kz];
        let bx = b[kx] - sx * b[kz];
        let by = b[ky] - sy * b[kz];
        let cx = c[kx] - sx * c[kz];
        let cy = c[ky] - sy * c[kz];
        let mut u = cx * by - cy * bx;
        let mut v = ax * cy - ay * cx;
        let mut w = bx * ay - by * ax;
        if u == 0.0 || v == 0.0 || w == 0.0 {
            u = (cx as f64 * by as f64 - cy as f64 * bx as f64) as f32;
            v = (ax as f64 * cy as f64 - ay as f64 * cx as f64) as f32;
            w = (bx as f64 * ay as f64 - by as f64 * ax as f64) as f32;
        }
        if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
            return None;
        }
        let det = u + v + w;
        if det == 0.0 {
            return None;
        }
        let az = sz * a[kz];
        let bz = sz * b[kz];
        let cz = sz * c[kz];
        let t_scaled = u * az + v * bz + w * cz;
        let t = t_scaled / det;
        if t > t_min && t < t_max {
            Some(t)
        } else {
            None
        }
    }
}

/// Axis-aligned bounding box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bounds {
    /// The lower corner.
    pub min: Vec3,
    /// The upper corner; below `min` on some axis for an empty box.
    pub max: Vec3,
}

impl Bounds {
    /// The box around nothing (inverted, infinite): growing it by a point gives that point.
    pub const EMPTY: Bounds = Bounds {
        min: Vec3::splat(f32::INFINITY),
        max: Vec3::splat(f32::NEG_INFINITY),
    };

    /// Grows the box to hold `p`.
    pub fn grow(&mut self, p: Vec3) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }

    /// Whether the box holds no point (as [`Bounds::EMPTY`] does).
    pub fn is_empty(&self) -> bool {
        self.min.cmpgt(self.max).any()
    }

    /// The middle of the box.
    pub fn center(&self) -> Vec3 {
        (self.min + self.max) * 0.5
    }

    /// The vector from `min` to `max`: the box's extent along each axis.
    pub fn diagonal(&self) -> Vec3 {
        self.max - self.min
    }
}

/// Unnormalized geometric normal of a triangle (right-handed, counter-clockwise front).
pub fn triangle_normal(a: Vec3, b: Vec3, c: Vec3) -> Vec3 {
    (b - a).cross(c - a)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn hits_the_middle_and_reports_distance() {
        let ray = Ray::new(Vec3::new(0.2, 0.2, 5.0), Vec3::new(0.0, 0.0, -1.0));
        let t = ray.hit_triangle(Vec3::ZERO, Vec3::X, Vec3::Y, 0.0, f32::INFINITY);
        assert!((t.unwrap() - 5.0).abs() < 1e-5, "{t:?}");
    }

    #[test]
    fn misses_outside_and_behind() {
        let ray = Ray::new(Vec3::new(0.8, 0.8, 5.0), Vec3::new(0.0, 0.0, -1.0));
        assert_eq!(
            ray.hit_triangle(Vec3::ZERO, Vec3::X, Vec3::Y, 0.0, 1e30),
            None
        );
        let behind = Ray::new(Vec3::new(0.2, 0.2, 5.0), Vec3::new(0.0, 0.0, 1.0));
        assert_eq!(
            behind.hit_triangle(Vec3::ZERO, Vec3::X, Vec3::Y, 0.0, 1e30),
            None
        );
    }

    #[test]
    fn degenerate_triangle_is_never_hit() {
        let ray = Ray::new(Vec3::new(0.5, 0.0, 5.0), Vec3::new(0.0, 0.0, -1.0));
        assert_eq!(
            ray.hit_triangle(Vec3::ZERO, Vec3::X, Vec3::X * 2.0, 0.0, 1e30),
            None
        );
    }

    proptest! {
        /// A ray through any point of the shared diagonal of a quad hits at least one of its
        /// two triangles: no cracks along shared edges.
        #[test]
        fn shared_edge_has_no_crack(s in 0.0f32..=1.0, ox in -3.0f32..3.0, oy in -3.0f32..3.0) {
            let (a, b, c, d) = (Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y);
            let on_edge = a + (c - a) * s;
            let origin = Vec3::new(ox, oy, 2.0);
            let ray = Ray::new(origin, on_edge - origin);
            let first = ray.hit_triangle(a, b, c, 0.0, f32::INFINITY);
            let second = ray.hit_triangle(a, c, d, 0.0, f32::INFINITY);
            prop_assert!(first.is_some() || second.is_some());
        }

        #[test]
        fn box_entry_agrees_with_point_inside(px in -1.0f32..1.0, py in -1.0f32..1.0, pz in -1.0f32..1.0,
                                              dx in -1.0f32..1.0, dy in -1.0f32..1.0, dz in -1.0f32..1.0) {
            prop_assume!(Vec3::new(dx, dy, dz).length() > 1e-3);
            let ray = Ray::new(Vec3::new(px, py, pz), Vec3::new(dx, dy, dz));
            // The origin is inside the box, so the box is entered at t = 0.
            prop_assert_eq!(ray.box_entry(Vec3::splat(-1.0), Vec3::splat(1.0), f32::INFINITY), 0.0);
        }
    }
}
