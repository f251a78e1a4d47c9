//! The built-in scenes: a (2,3) torus knot drawn as a bumpy tube, over a checkered floor, and
//! the same knot in a gallery of materials.
//!
//! It is generated, not shipped, so a fresh clone has something worth looking at on a wall, and
//! its triangle count is a parameter so benchmarks can scale it up to millions.

use super::{default_light, Material, Scene};
use glam::Vec3;
use std::f32::consts::TAU;

const MAJOR_RADIUS: f32 = 2.0;
const MINOR_RADIUS: f32 = 0.8;
const TUBE_RADIUS: f32 = 0.3;
const FLOOR_CELLS: u32 = 16;
const FLOOR_HALF_SIZE: f32 = 6.0;

/// The knot with `segments` rings of `sides` quads each (2 × segments × sides triangles), plus a
/// floor of `FLOOR_CELLS²` checkered quads.
pub fn knot_scene(segments: u32, sides: u32) -> Scene {
    let segments = segments.max(3);
    let sides = sides.max(3);
    let mut positions = Vec::with_capacity((segments * sides) as usize + 1024);
    let mut triangles = Vec::with_capacity((2 * segments * sides) as usize + 1024);
    let mut triangle_material = Vec::with_capacity(triangles.capacity());

    for i in 0..segments {
        let t = i as f32 / segments as f32 * TAU;
        let (center, tangent, normal) = knot_frame(t);
        let binormal = tangent.cross(normal);
        for j in 0..sides {
            let phi = j as f32 / sides as f32 * TAU;
            let bump = 1.0 + 0.12 * (6.0 * phi).sin() * (40.0 * t).sin();
            let offset = (normal * phi.cos() + binormal * phi.sin()) * TUBE_RADIUS * bump;
            positions.push(center + offset);
        }
    }
    let vertex = |i: u32, j: u32| (i % segments) * sides + (j % sides);
    for i in 0..segments {
        for j in 0..sides {
            let (a, b) = (vertex(i, j), vertex(i + 1, j));
            let (c, d) = (vertex(i + 1, j + 1), vertex(i, j + 1));
            triangles.push([a, b, c]);
            triangles.push([a, c, d]);
            triangle_material.extend([0, 0]);
        }
    }

    let floor_y = -(MINOR_RADIUS + TUBE_RADIUS * 1.6);
    let cell = 2.0 * FLOOR_HALF_SIZE / FLOOR_CELLS as f32;
    for row in 0..FLOOR_CELLS {
        for col in 0..FLOOR_CELLS {
            let x0 = -FLOOR_HALF_SIZE + col as f32 * cell;
            let z0 = -FLOOR_HALF_SIZE + row as f32 * cell;
            let base = positions.len() as u32;
            positions.extend([
                Vec3::new(x0, floor_y, z0),
                Vec3::new(x0, floor_y, z0 + cell),
                Vec3::new(x0 + cell, floor_y, z0 + cell),
                Vec3::new(x0 + cell, floor_y, z0),
            ]);
            triangles.push([base, base + 1, base + 2]);
            triangles.push([base, base + 2, base + 3]);
            let material = 1 + ((row + col) % 2) as u16;
            triangle_material.extend([material, material]);
        }
    }

    Scene {
        positions,
        triangles,
        triangle_material,
        materials: vec![
            Material::lambert(Vec3::new(0.9, 0.42, 0.25)),
            Material::lambert(Vec3::new(0.78, 0.78, 0.76)),
            Material::lambert(Vec3::new(0.32, 0.36, 0.42)),
        ],
        material_names: vec!["knot".into(), "light floor".into(), "dark floor".into()],
        colors: Default::default(),
        lights: vec![default_light()],
        particles: Vec::new(),
        volume: None,
        series: Vec::new(),
        render_from_world: Default::default(),
        up: None,
    }
}

/// The knot (glossy) in front of a mirror wall, seen through a pane of tinted glass, lit by the
/// sun and a point light: every material and light kind in one small scene.
pub fn gallery_scene() -> Scene {
    let mut scene = knot_scene(256, 32);
    scene.materials[0] = Material::phong(Vec3::new(0.85, 0.35, 0.2), Vec3::splat(0.6), 40.0);
    let mirror = scene.materials.len() as u16;
    scene
        .materials
        .push(Material::mirror(Vec3::new(0.9, 0.92, 0.95), 0.85));
    scene.material_names.push("mirror wall".into());
    let glass = mirror + 1;
    scene
        .materials
        .push(Material::transparent(Vec3::new(0.3, 0.7, 0.9), 0.35));
    scene.material_names.push("glass pane".into());
    let floor_y = -(MINOR_RADIUS + TUBE_RADIUS * 1.6);
    let s = FLOOR_HALF_SIZE;
    add_quad(
        &mut scene,
        [
            Vec3::new(-s, floor_y, -s),
            Vec3::new(s, floor_y, -s),
            Vec3::new(s, floor_y + 5.0, -s),
            Vec3::new(-s, floor_y + 5.0, -s),
        ],
        mirror,
    );
    add_quad(
        &mut scene,
        [
            Vec3::new(-1.5, floor_y, 3.4),
            Vec3::new(1.5, floor_y, 3.4),
            Vec3::new(1.5, floor_y + 2.2, 3.4),
            Vec3::new(-1.5, floor_y + 2.2, 3.4),
        ],
        glass,
    );
    scene.lights.push(crate::scene::Light::Point {
        position: Vec3::new(3.0, 3.5, 3.0),
        intensity: 6.0,
    });
    scene
}

fn add_quad(scene: &mut Scene, corners: [Vec3; 4], material: u16) {
    let base = scene.positions.len() as u32;
    scene.positions.extend(corners);
    scene.triangles.push([base, base + 1, base + 2]);
    scene.triangles.push([base, base + 2, base + 3]);
    scene.triangle_material.extend([material, material]);
}

/// Point, unit tangent and unit normal of the knot at parameter `t`. The normal points away
/// from the torus' core circle, which is never parallel to the tangent, so the tube needs no
/// parallel transport and closes without a seam.
fn knot_frame(t: f32) -> (Vec3, Vec3, Vec3) {
    let point = |t: f32| {
        let (p, q) = (2.0 * t, 3.0 * t);
        let ring = MAJOR_RADIUS + MINOR_RADIUS * q.cos();
        Vec3::new(ring * p.cos(), MINOR_RADIUS * q.sin(), ring * p.sin())
    };
    let h = 1e-3;
    let center = point(t);
    let tangent = (point(t + h) - point(t - h)).normalize();
    let core = Vec3::new((2.0 * t).cos(), 0.0, (2.0 * t).sin()) * MAJOR_RADIUS;
    let away = center - core;
    let normal = (away - tangent * away.dot(tangent)).normalize();
    (center, tangent, normal)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_knot_has_a_few_hundred_thousand_valid_triangles() {
        let scene = knot_scene(1536, 128);
        assert!(
            scene.triangles.len() >= 300_000,
            "{}",
            scene.triangles.len()
        );
        scene.validate("knot").unwrap();
        assert_eq!(scene.triangles.len(), scene.triangle_material.len());
        let bounds = scene.bounds();
        assert!(bounds.diagonal().length() > 10.0);
        assert!(!scene.has_transparency());
    }

    #[test]
    fn gallery_has_every_material_kind() {
        let scene = gallery_scene();
        scene.validate("gallery").unwrap();
        assert!(scene.has_transparency());
        assert!(scene.materials.iter().any(Material::is_mirror));
        assert!(scene.materials.iter().any(Material::has_specular));
    }
}
