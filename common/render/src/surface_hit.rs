//! What a ray hit and the geometry there: the surface ([`SurfaceHit`]: a triangle, a particle or
//! an iso-surface), its point and normal, where rays leaving it start, the way to each light, and
//! a primary hit as its shadow packet saw it ([`PrimaryHit`]). Shading (`shade`) and the shadow
//! packets (`shadow_packet`) both work from these, and neither uses the other.

use crate::bvh::node::Hit;
use crate::geometry::{triangle_normal, Ray};
use crate::packet::PacketHit;
use crate::prepared::{FrameView, PreparedScene};
use crate::scene::particles::Particle;
use crate::scene::Light;
use crate::tracer::Tracer;
use glam::Vec3;

/// Surface point and the normal facing the viewer for a hit.
#[inline]
pub fn surface(tracer: &mut Tracer<'_>, origin: Vec3, dir: Vec3, hit: Hit) -> (Vec3, Vec3) {
    let tri = tracer.triangle(hit.slot);
    let mut normal = triangle_normal(tri.a, tri.b, tri.c).normalize_or_zero();
    if normal.dot(dir) > 0.0 {
        normal = -normal;
    }
    (origin + dir * hit.t, normal)
}

/// Where secondary rays start: the hit point pushed off the surface along the normal, by a few
/// hundred ULPs of each coordinate (Wächter and Binder, Ray Tracing Gems ch. 6). An ULP offset
/// grows with the coordinates, so it neither causes acne far from the origin nor leaves a gap
/// near it; close to the origin, where ULPs vanish, a step proportional to the scene's size
/// takes over so that scenes at 1e-6 scale work too.
pub fn offset_origin(point: Vec3, normal: Vec3, scene_diagonal: f32) -> Vec3 {
    const INT_SCALE: f32 = 256.0;
    let near_origin = scene_diagonal * (1.0 / 32.0);
    let float_step = scene_diagonal * (1.0 / 65536.0);
    let mut out = [0f32; 3];
    for axis in 0..3 {
        let p = point[axis];
        let n = normal[axis];
        out[axis] = if p.abs() < near_origin {
            p + float_step * n
        } else {
            let ulps = (INT_SCALE * n) as i32;
            let ulps = if p < 0.0 { -ulps } else { ulps };
            f32::from_bits((p.to_bits() as i32).wrapping_add(ulps) as u32)
        };
    }
    Vec3::from_array(out)
}

/// The shading key of particles: no scene has this many materials (loaders stop at 65535).
pub const PARTICLE_KEY: u16 = u16::MAX;
/// The shading key of a volume's first iso-surface; the others count down from it.
pub const ISO_KEY: u16 = u16::MAX - 1;

/// What a ray hit first.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SurfaceHit {
    /// A triangle of the BVH, by leaf slot.
    Triangle(Hit),
    /// A particle.
    Sphere {
        /// Distance along the ray, in units of its direction.
        t: f32,
        /// Index of the sphere in the sphere BVH's order
        /// ([`crate::spheres::SphereAccel::spheres`]).
        slot: u32,
        /// The sphere, as the trace read it (particles in shared memory are not at hand).
        sphere: Particle,
    },
    /// A volume's direct iso-surface: `surface` indexes the frame's iso-values.
    Iso {
        /// Distance along the ray, in units of its direction.
        t: f32,
        /// Which iso-value: its index in the frame's volume parameters (`VolumeParams::iso`).
        surface: u8,
    },
}

impl SurfaceHit {
    /// The surface a packet's triangle hit is, if it hit one.
    #[inline]
    pub fn of_triangle(hit: PacketHit) -> Option<SurfaceHit> {
        hit.slot()
            .map(|slot| SurfaceHit::Triangle(Hit { t: hit.t, slot }))
    }

    /// Distance along the ray to the hit, in units of its direction, whatever was hit.
    pub fn t(&self) -> f32 {
        match *self {
            SurfaceHit::Triangle(h) => h.t,
            SurfaceHit::Sphere { t, .. } | SurfaceHit::Iso { t, .. } => t,
        }
    }

    /// Index of the primitive in the scene: triangles first, then particles.
    ///
    /// # Panics
    /// On a scene slimmed for rendering ([`PreparedScene::slim_for_rendering`]).
    pub fn scene_primitive(&self, scene: &PreparedScene) -> u64 {
        match *self {
            SurfaceHit::Triangle(h) => *scene
                .accel
                .scene_index
                .get(h.slot as usize)
                .expect("AOVs need the scene index, which render nodes drop")
                as u64,
            SurfaceHit::Sphere { slot, .. } => {
                let index = scene.spheres().scene_index.get(slot as usize);
                let index = index.expect(
                    "AOVs need the particles' scene index, which shared memory does not hold",
                );
                scene.accel.triangles.len() as u64 + *index as u64
            }
            // After the triangles and particles, one index per iso-value.
            SurfaceHit::Iso { surface, .. } => {
                let spheres = scene.spheres.as_ref().map_or(0, |s| s.len());
                (scene.accel.triangles.len() + spheres) as u64 + surface as u64
            }
        }
    }

    /// The material index that shading groups rays by: a triangle's own, or one past the
    /// scene's materials for particles (whose colour comes from their attribute).
    pub fn material_key(&self, scene: &PreparedScene) -> u16 {
        match *self {
            SurfaceHit::Triangle(h) => scene.slot_material.of(h.slot),
            SurfaceHit::Sphere { .. } => PARTICLE_KEY,
            SurfaceHit::Iso { surface, .. } => ISO_KEY - surface as u16,
        }
    }
}

/// Combines a packet's triangle hit with the particles, when the scene has any; `interval` is
/// the part of the ray the cutting planes keep. The sphere test's ray (a division per axis) is
/// only set up when there are spheres.
pub fn nearest_surface(
    scene: &PreparedScene,
    view: &FrameView,
    (origin, dir): (Vec3, Vec3),
    interval: (f32, f32),
    triangle: PacketHit,
    tracer: &mut Tracer<'_>,
) -> Option<SurfaceHit> {
    let mut nearest = SurfaceHit::of_triangle(triangle);
    if let Some(spheres) = &scene.spheres {
        let t_max = triangle.t.min(interval.1);
        let ray = (&Ray::new(origin, dir), interval.0, t_max);
        if let Some((t, slot, sphere)) = tracer.sphere_hit(spheres, ray, view.params.crop()) {
            nearest = Some(SurfaceHit::Sphere { t, slot, sphere });
        }
    }
    if let Some(volume) = &scene.volume {
        let t_max = nearest.map_or(interval.1, |h| h.t().min(interval.1));
        let iso = view.params.volume().iso.as_slice();
        if let Some((t, surface)) = volume.iso_hit(iso, (origin, dir), (interval.0, t_max), tracer)
        {
            nearest = Some(SurfaceHit::Iso { t, surface });
        }
    }
    nearest
}

/// Surface point and the normal facing the viewer, for a triangle or particle hit.
#[inline]
pub fn hit_frame(
    scene: &PreparedScene,
    tracer: &mut Tracer<'_>,
    origin: Vec3,
    dir: Vec3,
    hit: SurfaceHit,
) -> (Vec3, Vec3) {
    match hit {
        SurfaceHit::Triangle(h) => surface(tracer, origin, dir, h),
        SurfaceHit::Sphere { t, sphere: s, .. } => {
            let p = origin + dir * t;
            let mut n = ((p - s.center) / s.radius).normalize_or_zero();
            if n.dot(dir) > 0.0 {
                n = -n;
            }
            (p, n)
        }
        SurfaceHit::Iso { t, .. } => {
            let p = origin + dir * t;
            let volume = scene.volume.as_ref().expect("an iso hit implies a volume");
            let mut n = volume.normal_at(p, -dir, tracer);
            if n.dot(dir) > 0.0 {
                n = -n;
            }
            (p, n)
        }
    }
}

/// Where rays leaving `hit` at `point` start. An iso-surface is found again from the volume's
/// index space, whose rounding is larger than a few ULPs of the render coordinates: its rays
/// start a thousandth of a voxel off the surface.
pub fn leaving_point(scene: &PreparedScene, hit: SurfaceHit, point: Vec3, normal: Vec3) -> Vec3 {
    let start = offset_origin(point, normal, scene.diagonal);
    match (hit, &scene.volume) {
        (SurfaceHit::Iso { .. }, Some(volume)) => {
            let off = point + normal * (volume.reference_step() * 1e-3);
            if (off - point).length_squared() > (start - point).length_squared() {
                off
            } else {
                start
            }
        }
        _ => start,
    }
}

/// Whether a volume's opaque iso-surface blocks `ray` within `interval` (never, in a frame
/// without iso-values). Translucent ones cast no shadow: they are there to show what lies
/// inside them, which their shadow would darken.
pub fn iso_occludes(
    scene: &PreparedScene,
    view: &FrameView,
    ray: &Ray,
    interval: (f32, f32),
    tracer: &mut Tracer<'_>,
) -> bool {
    let volume_params = view.params.volume();
    let all = volume_params.iso.as_slice();
    let mut opaque = [0.0; tessera_model::volume_params::MAX_ISO_VALUES];
    let mut count = 0;
    for (i, &value) in all.iter().enumerate() {
        if volume_params.iso_look(i).1 >= 1.0 {
            opaque[count] = value;
            count += 1;
        }
    }
    let iso = &opaque[..count];
    scene.volume.as_ref().is_some_and(|v| {
        !iso.is_empty()
            && v.iso_hit(iso, (ray.origin, ray.dir), interval, tracer)
                .is_some()
    })
}

/// Direction towards `light` from `point`, how far the light is, and its intensity there.
pub fn towards_light(light: &Light, point: Vec3) -> (Vec3, f32, f32) {
    match *light {
        Light::Directional { towards, intensity } => (towards, f32::INFINITY, intensity),
        Light::Point {
            position,
            intensity,
        } => {
            let d = position - point;
            let dist2 = d.length_squared();
            (d / dist2.sqrt(), dist2.sqrt(), intensity / dist2.max(1e-30))
        }
    }
}

/// Whether a shadow ray leaves towards the light at all: the light is in front of the surface.
pub fn faces_light(normal: Vec3, towards: Vec3) -> Option<f32> {
    let cos = normal.dot(towards);
    (cos > 0.0 && cos.is_finite()).then_some(cos)
}

/// Lights whose shadows are traced as packets; further lights use single rays.
pub const PACKET_LIGHTS: usize = 64;

/// A primary hit as the shadow packets saw it, handed on to shading so it is not worked out
/// twice.
#[derive(Clone, Copy, Debug)]
pub struct PrimaryHit {
    pub point: Vec3,
    /// Facing the viewer.
    pub normal: Vec3,
    /// Where rays leaving the surface start (see [`offset_origin`]).
    pub start: Vec3,
    /// Bit k set when light k (of the first [`PACKET_LIGHTS`]) is blocked. A light the surface
    /// faces away from has no shadow ray, and its bit is unused.
    pub blocked: u64,
}
