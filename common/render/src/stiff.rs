//! Stiff cases of any scene: the scene moved far from the origin, its units changed, its
//! volume's values scaled, each rendered and compared with the plain picture. What `tessera-master
//! bench stiff` runs on a user's data, and the stiff-case tests on made-up data.
//!
//! A transformed scene is made from the loaded one in world coordinates, in f64, and placed in
//! a render frame again the way loaders place it ([`RenderFromWorld::centred_on`]); the camera
//! is moved with it, in f64, as the master moves one.
//!
//! ```
//! use glam::DVec3;
//! use tessera_model::params::RenderParams;
//! use tessera_render::scene::{knot_scene, Scene};
//! use tessera_render::stiff::{agreement, picture, transformed, Transform, View};
//!
//! let scene = knot_scene(48, 6);
//! let view = View::of(&scene);
//! let plain = picture(&scene, &view, RenderParams::interactive(), (32, 24));
//! let far = Transform::Offset(1e6);
//! let moved = transformed(&scene, far).unwrap();
//! let seen = picture(&moved, &view.transformed(far), RenderParams::interactive(), (32, 24));
//! let agreed = agreement(&plain, &seen, far);
//! assert!(agreed.pixels > 0.99 && agreed.depth < 1e-4 * view.size);
//! ```

use crate::aov::primary_aovs;
use crate::scene::particles::Particle;
use crate::scene::Scene;
use crate::{orbit_of, render_wall, FrameView, PreparedScene};
use glam::{DVec3, Vec3};
use tessera_model::camera::Camera;
use tessera_model::local_origin::RenderFromWorld;
use tessera_model::params::RenderParams;
use tessera_model::volume_params::{IsoValues, TransferDomain, TransferFunction, TransferPoint};
use tessera_model::wall::{TileGrid, WallSpec};

/// A change of a scene that must not change its picture.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Transform {
    /// Every world point moved by this much along each axis.
    Offset(f64),
    /// Units changed: every length multiplied by this.
    Extent(f64),
    /// The volume's values, iso-values and data-domain transfer points multiplied by this.
    Values(f32),
}

impl std::fmt::Display for Transform {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Transform::Offset(d) => write!(f, "offset {d:e}"),
            Transform::Extent(s) => write!(f, "extent ×{s:e}"),
            Transform::Values(s) => write!(f, "values ×{s:e}"),
        }
    }
}

/// Where the camera looks from and at, in world coordinates, and the scene's size there.
#[derive(Clone, Copy, Debug)]
pub struct View {
    /// The eye.
    pub eye: DVec3,
    /// The point looked at.
    pub target: DVec3,
    /// The scene's diagonal: what depth errors are measured against.
    pub size: f64,
}

impl View {
    /// The view of frame 0 of the orbit `local` starts with, in world coordinates.
    pub fn of(scene: &Scene) -> View {
        let bounds = scene.bounds();
        let camera = orbit_of(&bounds, 40.0)
            .expect("an orbit of finite bounds")
            .camera_for_frame(0);
        let frame = scene.render_from_world;
        View {
            eye: frame.world_point(camera.eye()),
            target: frame.world_point(camera.target()),
            size: (bounds.diagonal().length() as f64).max(1e-30),
        }
    }

    /// The same view of the scene after `t`.
    pub fn transformed(&self, t: Transform) -> View {
        let point = |p: DVec3| match t {
            Transform::Offset(d) => p + DVec3::splat(d),
            Transform::Extent(s) => p * s,
            Transform::Values(_) => p,
        };
        let scale = if let Transform::Extent(s) = t { s } else { 1.0 };
        View {
            eye: point(self.eye),
            target: point(self.target),
            size: self.size * scale,
        }
    }
}

/// `scene` after `t`, placed in a render frame anew; None for a change of values of a scene
/// without a volume.
pub fn transformed(scene: &Scene, t: Transform) -> Option<Scene> {
    match t {
        Transform::Offset(d) => Some(moved_and_scaled(scene, 1.0, DVec3::splat(d))),
        Transform::Extent(s) => Some(moved_and_scaled(scene, s, DVec3::ZERO)),
        Transform::Values(s) => {
            let volume = scene.volume.as_ref()?.scaled(1.0, [0.0; 3], s);
            let (positions, particles) = (scene.positions.clone(), scene.particles.clone());
            let parts = (positions, particles, Some(volume));
            Some(with_parts(scene, parts, scene.render_from_world))
        }
    }
}

/// `scene` with every world point `p` at `p · extent + offset`, placed in a render frame anew.
pub fn moved_and_scaled(scene: &Scene, extent: f64, offset: DVec3) -> Scene {
    let old = scene.render_from_world;
    let world = |p: Vec3| old.world_point(p) * extent + offset;
    let mut extent_of: Vec<DVec3> = scene.positions.iter().map(|&p| world(p)).collect();
    extent_of.extend(scene.particles.iter().map(|p| world(p.center)));
    let volume = scene
        .volume
        .as_ref()
        .map(|v| v.scaled(extent, offset.to_array(), 1.0));
    if let Some(v) = &volume {
        extent_of.extend(v.world_corners().map(DVec3::from_array));
    }
    let frame = RenderFromWorld::centred_on(&extent_of);
    let positions = scene.positions.iter().map(|&p| frame.point(world(p)));
    let particles = scene.particles.iter().map(|p| Particle {
        center: frame.point(world(p.center)),
        radius: (p.radius as f64 * extent) as f32,
        attribute: p.attribute,
    });
    with_parts(
        scene,
        (positions.collect(), particles.collect(), volume),
        frame,
    )
}

/// `scene` with new vertices, particles and volume in the frame `frame`, the rest copied.
/// Field by field: `..scene.clone()` would copy the replaced parts (a volume of gigabytes, on
/// a user's data) only to drop them.
fn with_parts(
    scene: &Scene,
    (positions, particles, volume): (Vec<Vec3>, Vec<Particle>, Option<crate::volume::Volume>),
    frame: RenderFromWorld,
) -> Scene {
    Scene {
        positions,
        triangles: scene.triangles.clone(),
        triangle_material: scene.triangle_material.clone(),
        materials: scene.materials.clone(),
        material_names: scene.material_names.clone(),
        colors: scene.colors.clone(),
        lights: scene.lights.clone(),
        particles,
        volume,
        series: scene.series.clone(),
        render_from_world: frame,
        up: scene.up,
    }
}

/// `params` for the scene after `t`: lengths scaled with an extent, values with values.
pub fn transformed_params(params: RenderParams, t: Transform) -> RenderParams {
    let mut spec = params.spec();
    match t {
        Transform::Offset(_) => {}
        // The ambient-occlusion range is a share of the scene's size already.
        Transform::Extent(s) => spec.volume.step = (spec.volume.step as f64 * s) as f32,
        Transform::Values(s) => {
            let iso: Vec<f32> = spec.volume.iso.as_slice().iter().map(|v| v * s).collect();
            spec.volume.iso = IsoValues::new(&iso).expect("as many iso-values as before");
            let tf = spec.volume.transfer;
            if tf.domain() == TransferDomain::Data {
                let points: Vec<TransferPoint> = tf
                    .points()
                    .iter()
                    .map(|p| TransferPoint {
                        value: p.value * s,
                        ..*p
                    })
                    .collect();
                spec.volume.transfer =
                    TransferFunction::new(TransferDomain::Data, &points).expect("scaled points");
            }
        }
    }
    spec.build().expect("the knobs of a valid set, scaled")
}

/// A picture: 8-bit colour and the depth of each pixel.
pub struct Picture {
    /// Width and height.
    pub size: (u32, u32),
    /// RGB, three bytes a pixel, rows from the top.
    pub rgb: Vec<u8>,
    /// Distance along each primary ray to what it hit; +inf for nothing.
    pub depth: Vec<f32>,
}

/// Renders `scene` as one screen of `size` pixels from `view`, moved into the scene's render
/// frame in f64.
pub fn picture(scene: &Scene, view: &View, params: RenderParams, size: (u32, u32)) -> Picture {
    let frame = scene.render_from_world;
    let (eye, target) = (frame.point(view.eye), frame.point(view.target));
    let camera = Camera::new(eye, target, Vec3::Y, 40.0).expect("a camera of a finite view");
    let prepared = PreparedScene::new(scene);
    let wall = WallSpec::grid(1, 1, size.0, size.1).tile_size(16).build();
    let grid = TileGrid::new(wall.expect("a one-screen wall"));
    let view = FrameView::new(0, &camera, params, size.0, size.1);
    Picture {
        size,
        rgb: render_wall(&prepared, &view, &grid).rgb,
        depth: primary_aovs(&prepared, &view, &grid).depth,
    }
}

/// How far a transformed scene's picture agrees with the plain one.
#[derive(Clone, Copy, Debug)]
pub struct Agreement {
    /// Share of pixels within two levels (of 255) on every channel.
    pub pixels: f64,
    /// Largest depth difference where both pictures hit something, in the plain scene's
    /// units.
    pub depth: f64,
    /// Pixels where one picture hits something and the other does not.
    pub coverage: usize,
}

/// How `seen` (of the scene after `t`) agrees with `plain`; depths are compared in the plain
/// scene's units.
pub fn agreement(plain: &Picture, seen: &Picture, t: Transform) -> Agreement {
    let scale = if let Transform::Extent(s) = t { s } else { 1.0 };
    let same = plain.rgb.chunks(3).zip(seen.rgb.chunks(3));
    let same = same.filter(|(p, q)| p.iter().zip(*q).all(|(x, y)| x.abs_diff(*y) <= 2));
    let both = plain.depth.iter().zip(&seen.depth);
    let depth = both
        .clone()
        .filter(|(a, b)| a.is_finite() && b.is_finite())
        .map(|(a, b)| (*a as f64 - *b as f64 / scale).abs())
        .fold(0.0, f64::max);
    let pixels = (plain.size.0 * plain.size.1).max(1) as f64;
    Agreement {
        pixels: same.count() as f64 / pixels,
        depth,
        coverage: both.filter(|(a, b)| a.is_finite() != b.is_finite()).count(),
    }
}

/// The changes `bench stiff` tries: offsets to 10⁷, units from 10⁻⁶ to 10⁶, and for a
/// volume values from 10⁻³⁰ to 10³⁰.
pub fn cases(scene: &Scene) -> Vec<Transform> {
    let mut cases: Vec<Transform> = [3, 5, 6, 7]
        .map(|k| Transform::Offset(10f64.powi(k)))
        .into();
    cases.extend([-6, -3, 3, 6].map(|k| Transform::Extent(10f64.powi(k))));
    if scene.volume.is_some() {
        cases.extend([-30, -20, -10, 10, 20, 30].map(|k| Transform::Values(10f32.powi(k))));
    }
    cases
}
