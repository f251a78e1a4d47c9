//! The colours of each leaf slot's triangle beyond its material: texture coordinates and
//! vertex colours at its corners, in leaf order like [`crate::slot_materials`], so a hit's slot
//! finds them without the map back to scene triangles (which render nodes drop).
//!
//! A scene without textures or vertex colours has none of this: its prepared scene holds
//! `None`, and shading checks that one `Option` per hit.

use crate::bvh::node::LeafTriangle;
use crate::scene::texture::{decode, Texture};
use crate::scene::{Material, Scene};
use glam::{Vec2, Vec3};

/// Texture coordinates and vertex colours of every leaf slot's corners, and the textures.
pub(crate) struct SlotColors {
    /// Each slot's corners' texture coordinates (its leaf triangle's a, b, c); empty when no
    /// material has a texture.
    uvs: Vec<[Vec2; 3]>,
    /// Each slot's corners' colours; empty when the scene has none.
    vertex: Vec<[[u8; 3]; 3]>,
    textures: Vec<Texture>,
}

/// Grazing hits are filtered as if seen at this cosine at most: a pixel's footprint grows as
/// 1/cos, and without a bound an edge-on triangle would take its 1×1 level.
const MIN_COS: f32 = 0.125;

impl SlotColors {
    /// What `scene`'s slots (`scene_index`: the scene triangle of each) need; `None` when
    /// every triangle is drawn in its material's colour alone.
    pub(crate) fn of(scene: &Scene, scene_index: &[u32]) -> Option<SlotColors> {
        let colors = &scene.colors;
        let textured =
            !colors.uvs.is_empty() && scene.materials.iter().any(|m| m.texture.is_some());
        if !textured && colors.vertex.is_empty() {
            return None;
        }
        let corners = |slot: &u32| scene.triangles[*slot as usize].map(|v| v as usize);
        let uvs = match textured {
            true => scene_index
                .iter()
                .map(|s| corners(s).map(|v| colors.uvs[v]))
                .collect(),
            false => Vec::new(),
        };
        let vertex = scene_index
            .iter()
            .take(if colors.vertex.is_empty() {
                0
            } else {
                usize::MAX
            })
            .map(|s| corners(s).map(|v| colors.vertex[v]))
            .collect();
        Some(SlotColors {
            uvs,
            vertex,
            textures: if textured {
                colors.textures.clone()
            } else {
                Vec::new()
            },
        })
    }

    /// Bytes held (for memory reports; textures counted once).
    pub(crate) fn bytes(&self) -> usize {
        std::mem::size_of_val(&self.uvs[..])
            + std::mem::size_of_val(&self.vertex[..])
            + self
                .textures
                .iter()
                .map(Texture::texel_bytes)
                .sum::<usize>()
    }

    /// The diffuse colour at `point` on the triangle of `slot` (`tri`, its corners): the
    /// material's albedo, times its texture, times the vertex colours, each where there is
    /// one. `footprint` is how wide, in render units, one pixel is at the hit seen square on
    /// (the texture's level follows from it and `cos`, the angle between the ray and the
    /// surface).
    pub(crate) fn albedo(
        &self,
        slot: u32,
        material: &Material,
        tri: &LeafTriangle,
        point: Vec3,
        (footprint, cos): (f32, f32),
    ) -> Vec3 {
        let weights = barycentric(tri, point);
        let mut albedo = material.albedo;
        if let (Some(t), Some(uv)) = (material.texture, self.uvs.get(slot as usize)) {
            let texture = &self.textures[t as usize];
            let at = uv[0] * weights[0] + uv[1] * weights[1] + uv[2] * weights[2];
            let texels = texels_across(texture, uv, tri) * footprint / cos.abs().max(MIN_COS);
            albedo *= texture.sample(at, texture.level_for(texels));
        }
        if let Some(corners) = self.vertex.get(slot as usize) {
            let c = |k: usize| Vec3::from_array(corners[k].map(decode)) * weights[k];
            albedo *= c(0) + c(1) + c(2);
        }
        albedo
    }
}

/// Level-0 texels per render unit on the triangle: the square root of the ratio of its area
/// in texels to its area in space.
fn texels_across(texture: &Texture, uv: &[Vec2; 3], tri: &LeafTriangle) -> f32 {
    let (w, h) = texture.size();
    let uv_area = (uv[1] - uv[0]).perp_dot(uv[2] - uv[0]).abs() * (w as f32 * h as f32);
    let area = (tri.b - tri.a).cross(tri.c - tri.a).length();
    if area > 0.0 {
        (uv_area / area).sqrt()
    } else {
        0.0
    }
}

/// The weights of `tri`'s corners at `point` (on its plane), each clamped to 0..1 so that a
/// point rounded just outside does not extrapolate a colour.
fn barycentric(tri: &LeafTriangle, point: Vec3) -> [f32; 3] {
    let (e1, e2, w) = (tri.b - tri.a, tri.c - tri.a, point - tri.a);
    let (d11, d12, d22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
    let (w1, w2) = (w.dot(e1), w.dot(e2));
    let denom = d11 * d22 - d12 * d12;
    if denom.is_nan() || denom <= 0.0 {
        return [1.0, 0.0, 0.0];
    }
    let b = ((d22 * w1 - d12 * w2) / denom).clamp(0.0, 1.0);
    let c = ((d11 * w2 - d12 * w1) / denom).clamp(0.0, 1.0);
    [(1.0 - b - c).max(0.0), b, c]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn barycentric_weights_give_back_the_corners_and_the_centre() {
        let tri = LeafTriangle {
            a: Vec3::ZERO,
            b: Vec3::X * 2.0,
            c: Vec3::Y * 2.0,
        };
        assert_eq!(barycentric(&tri, Vec3::ZERO), [1.0, 0.0, 0.0]);
        assert_eq!(barycentric(&tri, Vec3::X * 2.0), [0.0, 1.0, 0.0]);
        assert_eq!(barycentric(&tri, Vec3::Y * 2.0), [0.0, 0.0, 1.0]);
        let mid = barycentric(&tri, Vec3::new(1.0, 1.0, 0.0));
        assert_eq!(mid, [0.0, 0.5, 0.5]);
    }

    #[test]
    fn a_texture_seen_from_afar_is_sampled_at_a_coarser_level() {
        // A 64×64 checker of single texels on a unit triangle pair: at one texel a pixel
        // the checker shows; at 64 texels a pixel it is its mean, grey.
        let texels = (0..64 * 64)
            .map(|i| {
                if (i % 64 + i / 64) % 2 == 0 {
                    [255; 3]
                } else {
                    [0; 3]
                }
            })
            .collect();
        let scene = Scene {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y],
            triangles: vec![[0, 1, 2]],
            triangle_material: vec![0],
            materials: vec![Material {
                texture: Some(0),
                ..Material::lambert(Vec3::ONE)
            }],
            colors: crate::scene::colors::SurfaceColors {
                uvs: vec![Vec2::ZERO, Vec2::X, Vec2::Y],
                textures: vec![Texture::new("checker", 64, 64, texels)],
                ..Default::default()
            },
            ..Scene::default()
        };
        let slots = SlotColors::of(&scene, &[0]).unwrap();
        let tri = LeafTriangle {
            a: Vec3::ZERO,
            b: Vec3::X,
            c: Vec3::Y,
        };
        // Texel (10, 10) is white, its centre at (10.5 / 64, 10.5 / 64).
        let point = Vec3::new(10.5 / 64.0, 10.5 / 64.0, 0.0);
        let near = slots.albedo(0, &scene.materials[0], &tri, point, (1.0 / 64.0, 1.0));
        assert!((near - Vec3::ONE).length() < 1e-5, "{near}");
        let far = slots.albedo(0, &scene.materials[0], &tri, point, (1.0, 1.0));
        assert!((far - Vec3::splat(0.5)).length() < 0.01, "{far}");
        // Grazing: the same distance blurs more.
        let grazing = slots.albedo(0, &scene.materials[0], &tri, point, (1.0 / 64.0, 0.2));
        assert!((grazing - Vec3::ONE).length() > 0.1, "{grazing}");
    }
}
