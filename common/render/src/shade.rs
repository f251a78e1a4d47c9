//! What a hit looks like: lights and shadows, ambient occlusion, Phong highlights, mirrors and
//! transparency.
//!
//! Each part costs only where a material uses it: a material with no specular colour computes
//! no highlight, a scene with no mirror traces no reflected ray, and a scene with no transparent
//! material never enters the blending path (its [`PreparedScene::blends`] is false and the
//! transmitted-ray counter stays at zero). Reflected and transmitted rays are single rays; their
//! depth is bounded by [`MAX_DEPTH`].

use crate::bvh::node::Hit;
use crate::geometry::Ray;
use crate::packet::PacketHit;
use crate::prepared::{FrameView, PreparedScene, RayCounts};
use crate::sampling::{Hemisphere, PixelSeed};
use crate::scene::Material;
use crate::slot_colors::SlotColors;
use crate::surface_hit::{
    faces_light, hit_frame, iso_occludes, leaving_point, nearest_surface, towards_light,
    PrimaryHit, SurfaceHit,
};
use crate::tracer::Tracer;
use crate::volume::FrameTables;
use glam::Vec3;
use std::sync::Arc;
use tessera_model::cut::CutPlanes;

/// Bounces of reflection and transmission (together) after the primary hit.
pub const MAX_DEPTH: u32 = 6;

/// Shading of one pixel's rays: borrows the scene and the frame, counts the rays it traces.
pub struct Shader<'a, 't> {
    /// The scene being shaded: materials, lights, particles, volume.
    pub scene: &'a PreparedScene,
    /// The frame: its parameters, its lights and the seed of its samples.
    pub view: &'a FrameView,
    /// What shadow, AO, reflected and transmitted rays are traced with.
    pub tracer: &'a mut Tracer<'t>,
    /// Rays traced so far, by kind; the caller adds them up.
    pub counts: RayCounts,
    /// The pixel whose samples (ambient occlusion) are drawn.
    pub pixel: (u32, u32),
    /// Key of the first ambient-occlusion sample (non-zero for later supersamples).
    pub first_ao_key: u32,
    /// The next primary hit to shade, as its shadow packet found it (which of the first 64
    /// lights are blocked). Taken by that hit; other hits trace single shadow rays.
    pub primary: Option<PrimaryHit>,
}

/// The frame's transfer-function tables, if the scene's volume is drawn through one (it has a
/// volume, and the frame no iso-values).
pub fn volume_tables(scene: &PreparedScene, view: &FrameView) -> Option<Arc<FrameTables>> {
    let params = view.params.volume();
    let volume = scene.volume.as_ref()?;
    params.iso.is_empty().then(|| volume.tables(params))
}

/// `behind` (the colour at the ray's end, `interval.1`) seen through the volume in front of it.
#[inline]
pub fn through_volume(
    scene: &PreparedScene,
    tables: &FrameTables,
    (origin, dir): (Vec3, Vec3),
    interval: (f32, f32),
    behind: Vec3,
    tracer: &mut Tracer<'_>,
) -> Vec3 {
    let Some(volume) = &scene.volume else {
        return behind;
    };
    let [r, g, b, a] = volume.composite(tables, (origin, dir), interval, tracer);
    Vec3::new(r, g, b) + behind * (1.0 - a)
}

impl Shader<'_, '_> {
    fn cuts(&self) -> &CutPlanes {
        self.view.params.cuts()
    }

    /// Colour seen along a secondary ray (reflected or transmitted) at bounce `depth`.
    fn trace(&mut self, origin: Vec3, dir: Vec3, depth: u32) -> Vec3 {
        let ray = Ray::new(origin, dir);
        let interval = self.cuts().interval(origin, dir);
        if interval.0 > interval.1 {
            return background(dir);
        }
        let triangle = self
            .tracer
            .closest_hit(&ray, interval.0, interval.1)
            .map_or(PacketHit::MISS, |h| PacketHit::new(h.t, h.slot));
        let nearest = nearest_surface(
            self.scene,
            self.view,
            (origin, dir),
            interval,
            triangle,
            self.tracer,
        );
        let color = match nearest {
            None => background(dir),
            Some(hit) => {
                let material = self.scene.material_of(hit, self.view);
                self.shade(origin, dir, hit, &material, depth)
            }
        };
        match volume_tables(self.scene, self.view) {
            Some(tables) => {
                let t_hit = nearest.map_or(interval.1, |h| h.t());
                through_volume(
                    self.scene,
                    &tables,
                    (origin, dir),
                    (interval.0, t_hit),
                    color,
                    self.tracer,
                )
            }
            None => color,
        }
    }

    /// Whether anything kept by the cutting planes (triangles, or particles within the crop
    /// range) blocks the ray before `t_max`.
    fn blocked(&mut self, ray: &Ray, t_max: f32) -> bool {
        let (t_min, t_cut) = self.cuts().interval(ray.origin, ray.dir);
        let t_max = t_max.min(t_cut);
        if t_min > t_max {
            return false;
        }
        let scene = self.scene;
        self.tracer.occluded(ray, t_min, t_max)
            || scene.spheres.as_ref().is_some_and(|s| {
                let crop = self.view.params.crop();
                self.tracer.sphere_occluded(s, (ray, t_min, t_max), crop)
            })
            || iso_occludes(scene, self.view, ray, (t_min, t_max), self.tracer)
    }

    /// Colour of `hit` seen from `origin` along `dir`, `material` being its material (a
    /// particle's is its colour-mapped attribute).
    pub fn shade(
        &mut self,
        origin: Vec3,
        dir: Vec3,
        hit: SurfaceHit,
        material: &Material,
        depth: u32,
    ) -> Vec3 {
        let known = if depth == 0 {
            self.primary.take()
        } else {
            None
        };
        let (point, normal, start) = match known {
            Some(p) => (p.point, p.normal, p.start),
            None => {
                let (point, normal) = hit_frame(self.scene, self.tracer, origin, dir, hit);
                // Where shadow, AO and reflected rays leave; a hit that sends none (an
                // eyelight view) skips the offset, a tenth of its shading.
                let params = &self.view.params;
                let sends = !params.eye_light()
                    && (params.shadows() || params.ao_samples() > 0 || material.is_mirror());
                let start = if sends {
                    leaving_point(self.scene, hit, point, normal)
                } else {
                    point
                };
                (point, normal, start)
            }
        };
        let painted;
        let material = match (&self.scene.colors, hit) {
            (Some(colors), SurfaceHit::Triangle(h)) => {
                painted = Material {
                    albedo: self.painted_albedo(colors, h, material, (point, dir, normal)),
                    ..*material
                };
                &painted
            }
            _ => material,
        };
        if self.view.params.eye_light() {
            return eye_light(dir, normal, material.albedo);
        }
        let mut color = self.local(
            dir,
            point,
            normal,
            start,
            material,
            known.map(|p| p.blocked),
        );
        if material.is_mirror() && depth < MAX_DEPTH {
            self.counts.reflected += 1;
            let reflected = dir - 2.0 * dir.dot(normal) * normal;
            let seen = self.trace(start, reflected.normalize_or_zero(), depth + 1);
            color = color * (1.0 - material.mirror) + seen * material.mirror;
        }
        if material.is_transparent() && depth < MAX_DEPTH {
            self.counts.transmitted += 1;
            // An iso-surface is found again from the volume's index space: leave it as far.
            let behind = leaving_point(self.scene, hit, point, -normal);
            // Tinted glass: what lies behind is filtered by the surface's colour.
            let tint = Vec3::ONE.lerp(material.albedo, material.opacity);
            let seen = self.trace(behind, dir, depth + 1) * tint;
            color = color * material.opacity + seen * (1.0 - material.opacity);
        }
        color
    }

    /// The albedo at a triangle hit of a scene with textures or vertex colours. The texture's
    /// level follows from how wide a pixel is at the hit: the distance along this ray times
    /// the angle between neighbouring pixels of the frame's one image (a viewport's pixels
    /// are about as wide). After a mirror or through glass only this ray's own length counts,
    /// which is sharper than the whole path's footprint would be, never blurrier.
    fn painted_albedo(
        &mut self,
        colors: &SlotColors,
        hit: Hit,
        material: &Material,
        (point, dir, normal): (Vec3, Vec3, Vec3),
    ) -> Vec3 {
        let (x, y) = self.pixel;
        let rays = &self.view.rays;
        let pixel_angle =
            (rays.direction_at(x, y, 1.5, 0.5) - rays.direction_at(x, y, 0.5, 0.5)).length();
        let footprint = hit.t * pixel_angle;
        let tri = self.tracer.triangle(hit.slot);
        let cos = normal.dot(dir);
        colors.albedo(hit.slot, material, &tri, point, (footprint, cos))
    }

    /// Light reflected at the surface itself: headlight, lights with shadows, ambient term and
    /// Phong highlights.
    fn local(
        &mut self,
        dir: Vec3,
        point: Vec3,
        normal: Vec3,
        start: Vec3,
        material: &Material,
        known_shadows: Option<u64>,
    ) -> Vec3 {
        let headlight = (-normal.dot(dir)).max(0.0);
        let glossy = material.has_specular();
        let mut highlight = 0.0;
        if glossy {
            // The headlight sits at the eye, so its mirror direction makes the angle
            // 2·cos²−1 with the view direction.
            let r_dot_v = (2.0 * headlight * headlight - 1.0).max(0.0);
            highlight += 0.35 * phong_lobe(r_dot_v, material.shininess);
        }
        let mut direct = 0.0;
        for (k, light) in self.view.lights(self.scene).iter().enumerate() {
            let (towards, reach, intensity) = towards_light(light, point);
            let Some(cos) = faces_light(normal, towards) else {
                continue;
            };
            if self.view.params.shadows() {
                self.counts.shadow += 1;
                let blocked = match known_shadows {
                    Some(bits) if k < 64 => bits >> k & 1 == 1,
                    _ => self.blocked(&Ray::new(start, towards), reach),
                };
                if blocked {
                    continue;
                }
            }
            direct += cos * intensity;
            if glossy {
                let mirrored = 2.0 * cos * normal - towards;
                let r_dot_v = mirrored.dot(-dir).max(0.0);
                highlight += intensity * phong_lobe(r_dot_v, material.shininess);
            }
        }
        let ambient = if self.view.params.ao_samples() > 0 {
            self.counts.ambient += self.view.params.ao_samples() as u64;
            0.3 * self.ambient_visibility(start, normal)
        } else {
            0.1
        };
        let diffuse = material.albedo * (ambient + 0.35 * headlight + direct);
        if glossy {
            diffuse + material.specular * highlight
        } else {
            diffuse
        }
    }

    /// Fraction of `ao_samples` cosine-weighted rays from `start` that escape within the AO
    /// range.
    pub fn ambient_visibility(&mut self, start: Vec3, normal: Vec3) -> f32 {
        let n = self.view.params.ao_samples();
        let reach = self.scene.diagonal * self.view.params.ao_range();
        let mut open = 0;
        let hemisphere = Hemisphere::around(normal);
        let seed = PixelSeed::new(self.view.frame, self.pixel.0, self.pixel.1);
        for sample in 0..n {
            let mut stream = seed.stream(self.first_ao_key + sample);
            let d = hemisphere.cosine_direction(&mut stream);
            if !self.blocked(&Ray::new(start, d), reach) {
                open += 1;
            }
        }
        open as f32 / n as f32
    }
}

impl PreparedScene {
    /// The material a hit is shaded with in frame `view` (a particle whose attribute is
    /// missing takes the frame's missing-data colour, else `MISSING_COLOR`).
    pub fn material_of(&self, hit: SurfaceHit, view: &FrameView) -> Material {
        match hit {
            SurfaceHit::Triangle(h) => self.materials[self.slot_material.of(h.slot) as usize],
            SurfaceHit::Sphere { sphere: s, .. } => {
                if s.attribute.is_nan() {
                    let color = view.params.volume().missing_color;
                    return Material::lambert(color.map_or(MISSING_COLOR, Vec3::from_array));
                }
                let (lo, hi) = self.attribute_range;
                // In f64: the span of attributes near ±f32::MAX is past f32's range.
                let x = if hi > lo {
                    ((s.attribute as f64 - lo as f64) / (hi as f64 - lo as f64)) as f32
                } else {
                    0.5
                };
                Material::lambert(Vec3::from_array(view.params.colormap().eval(x)))
            }
            SurfaceHit::Iso { surface, .. } => {
                let (color, opacity) = view.params.volume().iso_look(surface as usize);
                Material::transparent(Vec3::from_array(color), opacity)
            }
        }
    }
}

/// A hit lit by the eye light alone, as Embree's viewer shades: |N·D| times the base colour.
/// The absolute value makes the side the normal faces irrelevant, so the fast path of
/// triangle-only packets (`frame`) need not flip it and gets the same bits.
#[inline(always)]
pub fn eye_light(dir: Vec3, normal: Vec3, albedo: Vec3) -> Vec3 {
    albedo * normal.dot(dir).abs()
}

/// The colour of a particle whose attribute is missing (NaN in its file): a neutral grey, a
/// colour the viridis map never gives.
pub const MISSING_COLOR: Vec3 = Vec3::splat(0.5);

/// `cos^shininess` with the exponent rounded to an integer: `powi` is a chain of multiplies,
/// the same bits on every CPU, where `powf` comes from the C library, which may pick an FMA
/// variant on some CPUs and not others.
fn phong_lobe(cos: f32, shininess: f32) -> f32 {
    cos.powi(shininess.round().clamp(1.0, 10_000.0) as i32)
}

/// The linear colour of a ray that hits nothing: a vertical gradient by the direction's y (unit
/// length), dark blue below, light blue above.
#[inline]
pub fn background(dir: Vec3) -> Vec3 {
    let t = 0.5 + 0.5 * dir.y;
    BACKDROP[0].lerp(BACKDROP[1], t)
}

/// The backdrop straight down and straight up, which [`background`] blends (and the eye
/// light's SIMD kernel, `lanes`, channel by channel).
pub(crate) const BACKDROP: [Vec3; 2] = [Vec3::new(0.05, 0.06, 0.09), Vec3::new(0.32, 0.42, 0.62)];

/// Linear to 8-bit with a gamma of 2 (a square root is exact in IEEE arithmetic, so it is the
/// same on every CPU, unlike `powf`). Non-finite values come out black, never as garbage.
pub fn encode_srgb_ish(color: Vec3) -> [u8; 3] {
    color.to_array().map(encode_channel)
}

/// One channel of [`encode_srgb_ish`], written without branches so that loops over many
/// channels vectorize.
#[inline(always)]
pub fn encode_channel(c: f32) -> u8 {
    // Clamped to 0..=1, and a non-finite channel to 0 (NaN fails both compares): written as
    // the compares and selects SIMD has, so that the loop vectorizes.
    let linear = if c > 0.0 && c < f32::INFINITY {
        c.min(1.0)
    } else {
        0.0
    };
    let encoded = linear.sqrt() * 255.0 + 0.5;
    // SAFETY: `encoded` is in 0.5..=255.5, well inside `i32`. The saturating `as` conversion
    // `to_int_unchecked` avoids does not vectorize: SSE and AVX convert without saturating.
    unsafe { encoded.to_int_unchecked::<i32>() as u8 }
}
