//! One ray against a leaf's triangles several at a time: the watertight test of
//! [`Ray::hit_triangle`] with one triangle per lane, so that a 16-triangle leaf of a
//! multi-million-triangle mesh costs two 8-lane passes instead of sixteen scalar tests. The
//! operations and their order are the scalar test's, so every lane gets exactly the scalar
//! answer; a lane where an edge function is exactly zero (which the scalar test redoes in f64)
//! is handed back to it. Single rays (shadow, ambient-occlusion, reflected) use this; packets
//! test one triangle across their rays instead (`leaf_packet`).

use crate::bvh::node::LeafTriangle;
use crate::geometry::Ray;

/// Triangles tested together: one AVX2 vector.
const LANES: usize = 8;

/// Leaves smaller than this are tested one triangle at a time: gathering the corners into lanes
/// costs more than it saves on a few.
const WIDE_FROM: usize = 2;

/// A leaf chunk's answers for one ray.
struct ChunkHits {
    /// Distance of each lane's hit; meaningful where `hit` is set.
    t: [f32; LANES],
    hit: [bool; LANES],
    /// Lanes the scalar test must decide.
    redo: [bool; LANES],
}

/// Tests the ray against up to [`LANES`] triangles (lanes past `tris.len()` repeat the last
/// one, so they agree with it).
#[inline(always)]
fn test_chunk(ray: &Ray, tris: &[LeafTriangle], t_min: f32, t_max: f32) -> ChunkHits {
    let ([kx, ky, kz], shear) = ray.shear_frame();
    let (sx, sy, sz) = (shear.x, shear.y, shear.z);
    let o = ray.origin;
    let last = tris.len() - 1;
    let mut corner = [[[0f32; LANES]; 3]; 3];
    for j in 0..LANES {
        let tri = &tris[j.min(last)];
        for (k, p) in [tri.a, tri.b, tri.c].into_iter().enumerate() {
            let p = p - o;
            corner[k][0][j] = p[kx];
            corner[k][1][j] = p[ky];
            corner[k][2][j] = p[kz];
        }
    }
    let [a, b, c] = corner;
    let mut out = ChunkHits {
        t: [0.0; LANES],
        hit: [false; LANES],
        redo: [false; LANES],
    };
    for j in 0..LANES {
        let ax = a[0][j] - sx * a[2][j];
        let ay = a[1][j] - sy * a[2][j];
        let bx = b[0][j] - sx * b[2][j];
        let by = b[1][j] - sy * b[2][j];
        let cx = c[0][j] - sx * c[2][j];
        let cy = c[1][j] - sy * c[2][j];
        let u = cx * by - cy * bx;
        let v = ax * cy - ay * cx;
        let w = bx * ay - by * ax;
        let edge = (u == 0.0) | (v == 0.0) | (w == 0.0);
        let outside = ((u < 0.0) | (v < 0.0) | (w < 0.0)) & ((u > 0.0) | (v > 0.0) | (w > 0.0));
        let det = u + v + w;
        let t = (u * (sz * a[2][j]) + v * (sz * b[2][j]) + w * (sz * c[2][j])) / det;
        out.t[j] = t;
        out.hit[j] = !edge & !outside & (det != 0.0) & (t > t_min) & (t < t_max);
        out.redo[j] = edge;
    }
    out
}

/// Whether the ray hits any of `tris` within `(t_min, t_max)`: the same answer as
/// [`Ray::hit_triangle`] on each.
#[inline(always)]
pub(crate) fn any_hit(ray: &Ray, tris: &[LeafTriangle], t_min: f32, t_max: f32) -> bool {
    if tris.len() < WIDE_FROM {
        return tris.iter().any(|tri| {
            ray.hit_triangle(tri.a, tri.b, tri.c, t_min, t_max)
                .is_some()
        });
    }
    for chunk in tris.chunks(LANES) {
        let hits = test_chunk(ray, chunk, t_min, t_max);
        if hits.hit.iter().fold(false, |a, &h| a | h) {
            return true;
        }
        for (j, tri) in chunk.iter().enumerate() {
            if hits.redo[j]
                && ray
                    .hit_triangle(tri.a, tri.b, tri.c, t_min, t_max)
                    .is_some()
            {
                return true;
            }
        }
    }
    false
}

/// The nearest hit among `tris` (leaf slots from `first`) that beats `best` (nearer, or as
/// near on a lower slot), within `(t_min, t_max)`: what testing them one by one with
/// [`Ray::hit_triangle`] and [`crate::bvh::node::Hit::closer`] keeps.
#[inline(always)]
pub(crate) fn closest_hit(
    ray: &Ray,
    tris: &[LeafTriangle],
    first: u32,
    (t_min, t_max): (f32, f32),
    mut best: Option<crate::bvh::node::Hit>,
) -> Option<crate::bvh::node::Hit> {
    use crate::bvh::node::Hit;
    if tris.len() < WIDE_FROM {
        for (j, tri) in tris.iter().enumerate() {
            let slot = first + j as u32;
            let t = ray.hit_triangle(tri.a, tri.b, tri.c, t_min, t_max);
            if let Some(t) = t.filter(|&t| Hit::closer(t, slot, best)) {
                best = Some(Hit { t, slot });
            }
        }
        return best;
    }
    for (c, chunk) in tris.chunks(LANES).enumerate() {
        let hits = test_chunk(ray, chunk, t_min, t_max);
        let base = first + (c * LANES) as u32;
        for (j, tri) in chunk.iter().enumerate() {
            let slot = base + j as u32;
            let t = if hits.redo[j] {
                ray.hit_triangle(tri.a, tri.b, tri.c, t_min, t_max)
            } else {
                hits.hit[j].then_some(hits.t[j])
            };
            if let Some(t) = t.filter(|&t| Hit::closer(t, slot, best)) {
                best = Some(Hit { t, slot });
            }
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bvh::node::Hit;
    use glam::Vec3;

    /// Rays through a fan of triangles, including their shared edges and corners (where an
    /// edge function is exactly zero): every answer is the scalar test's.
    #[test]
    fn agrees_with_the_scalar_test_triangle_by_triangle() {
        let tris: Vec<LeafTriangle> = (0..13)
            .map(|k| {
                let angle = |k: f32| k * 0.45;
                let z = k as f32 * 0.01;
                LeafTriangle {
                    a: Vec3::new(0.0, 0.0, z),
                    b: Vec3::new(angle(k as f32).cos(), angle(k as f32).sin(), z),
                    c: Vec3::new(angle(k as f32 + 1.0).cos(), angle(k as f32 + 1.0).sin(), z),
                }
            })
            .collect();
        let mut checked = 0;
        for y in -8..=8 {
            for x in -8..=8 {
                let origin = Vec3::new(x as f32 / 8.0, y as f32 / 8.0, -2.0);
                for dir in [
                    Vec3::Z,
                    Vec3::new(0.1, -0.05, 1.0),
                    Vec3::new(-0.0, 0.0, -1.0),
                ] {
                    let ray = Ray::new(origin, dir);
                    for (t_min, t_max) in [(0.0, f32::INFINITY), (0.0, 2.05), (2.03, 9.0)] {
                        let mut scalar: Option<Hit> = None;
                        for (slot, tri) in tris.iter().enumerate() {
                            let slot = slot as u32 + 100;
                            if let Some(t) = ray.hit_triangle(tri.a, tri.b, tri.c, t_min, t_max) {
                                if Hit::closer(t, slot, scalar) {
                                    scalar = Some(Hit { t, slot });
                                }
                            }
                        }
                        let wide = closest_hit(&ray, &tris, 100, (t_min, t_max), None);
                        assert_eq!(wide, scalar, "ray {origin} {dir} in ({t_min}, {t_max})");
                        assert_eq!(
                            any_hit(&ray, &tris, t_min, t_max),
                            scalar.is_some(),
                            "ray {origin} {dir}"
                        );
                        checked += scalar.is_some() as u32;
                    }
                }
            }
        }
        assert!(checked > 100, "the rays must hit the fan ({checked} hits)");
    }
}
