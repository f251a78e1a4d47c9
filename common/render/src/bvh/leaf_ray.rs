//! One ray against a leaf's triangles several at a time: the watertight test of
//! [`Ray::hit_triangle`] with one triangle per lane, so that a 16-triangle leaf of a
//! multi-million-triangle mesh costs two 8-lane passes instead of sixteen scalar tests. The
//! operations and their order are the scalar test's, so every lane gets exactly the scalar
//! answer; a lane where an edge function is exactly zero (which the scalar test redoes in f64)
//! is handed back to it. Single rays (shadow, ambient-occlusion, reflected) use this; packets
//! test one triangle across their rays instead (`leaf_packet`).

use crate::bvh::node::LeafTriangle;
use crate::geometry::Ray;
use crate::isa::{Build, Isa};

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

/// Corners `[corner][axis][lane]` of up to [`LANES`] triangles, lanes past `tris.len()`
/// repeating the last one. The AVX2 build loads each triangle's first eight floats as one vector
/// and transposes them (a triangle is nine floats, so the loads stay inside it), and gathers the
/// ninth: scalar copies cost 18 memory operations a lane, and the vector loads that followed
/// them waited for eight separate stores each.
#[inline(always)]
fn gather_corners<B: Build>(_: B, tris: &[LeafTriangle]) -> [[[f32; LANES]; 3]; 3] {
    #[cfg(target_arch = "x86_64")]
    if B::ISA != Isa::Portable {
        // SAFETY: a `B` exists only where the CPU runs its build, and every build above
        // portable has AVX2.
        return unsafe { gather_corners_avx2(tris) };
    }
    let last = tris.len() - 1;
    let mut corner = [[[0f32; LANES]; 3]; 3];
    for j in 0..LANES {
        let tri = &tris[j.min(last)];
        for (k, p) in [tri.a, tri.b, tri.c].into_iter().enumerate() {
            corner[k][0][j] = p.x;
            corner[k][1][j] = p.y;
            corner[k][2][j] = p.z;
        }
    }
    corner
}

/// Per last lane of a chunk, each lane's triangle's first float: lane `j` reads triangle
/// `min(j, last)`. A table, since working it out took a tenth of the corners' gathering.
#[cfg(target_arch = "x86_64")]
const LANE_FLOATS: [[i32; LANES]; LANES] = {
    const FLOATS: usize = std::mem::size_of::<LeafTriangle>() / 4;
    let mut table = [[0; LANES]; LANES];
    let mut last = 0;
    while last < LANES {
        let mut j = 0;
        while j < LANES {
            let tri = if j < last { j } else { last };
            table[last][j] = (tri * FLOATS) as i32;
            j += 1;
        }
        last += 1;
    }
    table
};

/// [`gather_corners`] in AVX2: an 8×8 transpose of the triangles' first eight floats, and a
/// gather of the ninth.
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn gather_corners_avx2(tris: &[LeafTriangle]) -> [[[f32; LANES]; 3]; 3] {
    use std::arch::x86_64::*;
    let base = tris.as_ptr() as *const f32;
    let index = &LANE_FLOATS[tris.len() - 1];
    // SAFETY: every index is a triangle's first float, below `tris.len()` (the table's row
    // for `tris.len()` lanes); a triangle is 9 floats, so eight from its start stay inside
    // it, and its ninth is at offset 8.
    let (rows, ninth) = unsafe {
        let rows: [__m256; LANES] =
            std::array::from_fn(|j| _mm256_loadu_ps(base.add(index[j] as usize)));
        let vindex = _mm256_loadu_si256(index.as_ptr() as *const __m256i);
        (rows, _mm256_i32gather_ps::<4>(base.add(8), vindex))
    };
    let lo = |a, b| _mm256_unpacklo_ps(a, b);
    let hi = |a, b| _mm256_unpackhi_ps(a, b);
    let t = [
        lo(rows[0], rows[1]),
        hi(rows[0], rows[1]),
        lo(rows[2], rows[3]),
        hi(rows[2], rows[3]),
        lo(rows[4], rows[5]),
        hi(rows[4], rows[5]),
        lo(rows[6], rows[7]),
        hi(rows[6], rows[7]),
    ];
    let even = |a, b| _mm256_shuffle_ps::<0b01_00_01_00>(a, b);
    let odd = |a, b| _mm256_shuffle_ps::<0b11_10_11_10>(a, b);
    let u = [
        even(t[0], t[2]),
        odd(t[0], t[2]),
        even(t[1], t[3]),
        odd(t[1], t[3]),
        even(t[4], t[6]),
        odd(t[4], t[6]),
        even(t[5], t[7]),
        odd(t[5], t[7]),
    ];
    let column: [__m256; 8] = std::array::from_fn(|f| {
        if f < 4 {
            _mm256_permute2f128_ps::<0x20>(u[f], u[f + 4])
        } else {
            _mm256_permute2f128_ps::<0x31>(u[f - 4], u[f])
        }
    });
    let mut corner = [[[0f32; LANES]; 3]; 3];
    for f in 0..9 {
        let v = if f < 8 { column[f] } else { ninth };
        // SAFETY: each corner row holds LANES = 8 floats, the 32 bytes the store writes.
        unsafe { _mm256_storeu_ps(corner[f / 3][f % 3].as_mut_ptr(), v) };
    }
    corner
}

/// Tests the ray against up to [`LANES`] triangles (lanes past `tris.len()` repeat the last
/// one, so they agree with it).
#[inline(always)]
fn test_chunk<B: Build>(
    build: B,
    ray: &Ray,
    tris: &[LeafTriangle],
    t_min: f32,
    t_max: f32,
) -> ChunkHits {
    let ([kx, ky, kz], shear) = ray.shear_frame();
    let (sx, sy, sz) = (shear.x, shear.y, shear.z);
    let o = ray.origin.to_array();
    // Corners in world axis order: the shear frame's order is chosen by which array the lanes
    // read below. Permuting each corner as it was gathered cost a branch per coordinate (the
    // axis is known only at run time), 70 instructions a lane.
    let corner = gather_corners(build, tris);
    // Relative to the origin, on the shear frame's axes: what `(p - o)[k]` gives.
    // (Loops, not `array::map`: that was left a call, compiled without AVX2.)
    let mut rel = [[[0f32; LANES]; 3]; 3];
    for k in 0..3 {
        for (i, axis) in [kx, ky, kz].into_iter().enumerate() {
            for j in 0..LANES {
                rel[k][i][j] = corner[k][axis][j] - o[axis];
            }
        }
    }
    let [a, b, c] = rel;
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
pub(crate) fn any_hit<B: Build>(
    build: B,
    ray: &Ray,
    tris: &[LeafTriangle],
    t_min: f32,
    t_max: f32,
) -> bool {
    if tris.len() < WIDE_FROM {
        // A plain loop: `Iter::any` was left a call, compiled without AVX2.
        for tri in tris {
            if ray
                .hit_triangle(tri.a, tri.b, tri.c, t_min, t_max)
                .is_some()
            {
                return true;
            }
        }
        return false;
    }
    for chunk in tris.chunks(LANES) {
        let hits = test_chunk(build, ray, chunk, t_min, t_max);
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
pub(crate) fn closest_hit<B: Build>(
    build: B,
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
        let hits = test_chunk(build, ray, chunk, t_min, t_max);
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
    use crate::isa::build::Portable;
    use glam::Vec3;

    /// The AVX2 build, where the CPU has it.
    #[cfg(target_arch = "x86_64")]
    fn avx2() -> Option<crate::isa::build::Avx2> {
        // SAFETY: made only once the CPU is known to have AVX2.
        std::arch::is_x86_feature_detected!("avx2")
            .then(|| unsafe { crate::isa::build::Avx2::new_unchecked() })
    }

    /// The transposing gather gives the portable corners, lane for lane, for every chunk
    /// length (lanes past the length repeating the last triangle), at the start and the very
    /// end of the triangle array (where a load of eight floats must not run past it).
    #[test]
    #[cfg(target_arch = "x86_64")]
    fn the_avx2_gather_gives_the_portable_corners() {
        let Some(avx2) = avx2() else { return };
        let tris: Vec<LeafTriangle> = (0..11)
            .map(|i| {
                let f = |k: usize| (i * 9 + k) as f32 + 0.5;
                LeafTriangle {
                    a: Vec3::new(f(0), f(1), f(2)),
                    b: Vec3::new(f(3), f(4), f(5)),
                    c: Vec3::new(f(6), f(7), f(8)),
                }
            })
            .collect();
        for len in 1..=LANES {
            for chunk in [&tris[..len], &tris[tris.len() - len..]] {
                let portable = gather_corners(Portable, chunk);
                assert_eq!(gather_corners(avx2, chunk), portable, "{len} triangles");
                let last = &chunk[len - 1];
                assert_eq!(portable[2][2][LANES - 1], last.c.z, "{len} triangles");
                assert_eq!(portable[0][1][0], chunk[0].a.y, "{len} triangles");
            }
        }
    }

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
                        let interval = (t_min, t_max);
                        let wide = closest_hit(Portable, &ray, &tris, 100, interval, None);
                        assert_eq!(wide, scalar, "ray {origin} {dir} in ({t_min}, {t_max})");
                        let any = any_hit(Portable, &ray, &tris, t_min, t_max);
                        assert_eq!(any, scalar.is_some(), "ray {origin} {dir}");
                        #[cfg(target_arch = "x86_64")]
                        if let Some(avx2) = avx2() {
                            let wide = closest_hit(avx2, &ray, &tris, 100, interval, None);
                            assert_eq!(wide, scalar, "AVX2: ray {origin} {dir}");
                            let any = any_hit(avx2, &ray, &tris, t_min, t_max);
                            assert_eq!(any, scalar.is_some(), "AVX2: ray {origin} {dir}");
                        }
                        checked += scalar.is_some() as u32;
                    }
                }
            }
        }
        assert!(checked > 100, "the rays must hit the fan ({checked} hits)");
    }
}
