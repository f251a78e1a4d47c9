//! The first renderer: primary rays, headlight Lambert shading and hard shadows from the scene's
//! directional light, traced in 8×8 packets that rayon threads take from a shared queue.
//!
//! Every pixel is a pure function of (scene, camera, params, pixel), so a tile is byte-identical
//! on whichever node renders it and the single-process reference equals the wall.

pub mod aov;
pub mod bench;
mod camera;
pub mod packet;
pub mod sampling;

pub use camera::{Camera, CameraError, CameraMode, PixelRays};

use crate::accel::{Accel, Hit};
use crate::geometry::{triangle_normal, Ray};
use crate::scene::Light;
use crate::scene::Scene;
use crate::spheres::{colormap, SphereAccel};
use crate::wall::Tile;
use glam::Vec3;
use packet::{PacketHit, RayPacket};
use rayon::prelude::*;
use sampling::{cosine_direction, SampleStream};
use serde::{Deserialize, Serialize};

/// Edge of a packet: tiles are traced as 8×8 = 64-ray packets.
pub const PACKET: u32 = 8;

/// Per-frame quality knobs, changed only at the frame barrier.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RenderParams {
    /// Trace shadow rays towards the lights.
    pub shadows: bool,
    /// Ambient-occlusion rays per hit (0: none traced).
    pub ao_samples: u32,
    /// Reach of ambient-occlusion rays, as a fraction of the scene's bounding-box diagonal.
    pub ao_range: f32,
    /// Only particles whose attribute lies in this range are drawn (and cast shadows).
    pub crop: Option<(f32, f32)>,
}

impl RenderParams {
    /// What the interactive wall renders by default: shadows, no ambient occlusion.
    pub const fn interactive() -> Self {
        RenderParams {
            shadows: true,
            ao_samples: 0,
            ao_range: 0.1,
            crop: None,
        }
    }

    /// A still worth waiting for: shadows and 16 ambient-occlusion rays per hit.
    pub const fn final_frame() -> Self {
        RenderParams {
            shadows: true,
            ao_samples: 16,
            ao_range: 0.1,
            crop: None,
        }
    }

    /// Every preset, for tests that must hold for all of them.
    pub const PRESETS: [RenderParams; 2] = [Self::interactive(), Self::final_frame()];
}

impl Default for RenderParams {
    fn default() -> Self {
        Self::interactive()
    }
}

/// A scene ready to trace: materials and lights from the scene, plus its BVH.
pub struct PreparedScene {
    pub accel: Accel,
    /// Material albedo of each leaf slot of `accel`.
    slot_albedo: Vec<Vec3>,
    lights: Vec<Light>,
    /// Length of the scene's bounding-box diagonal: the scale of offsets and AO reach.
    diagonal: f32,
    /// Particles, if the scene has any.
    pub spheres: Option<SphereAccel>,
    /// Attribute values mapped to the two ends of the colour map.
    attribute_range: (f32, f32),
}

impl PreparedScene {
    pub fn new(scene: &Scene) -> Self {
        Self::from_accel(scene, Accel::build(scene))
    }

    /// Uses an already built (e.g. cached) BVH of `scene`.
    pub fn from_accel(scene: &Scene, accel: Accel) -> Self {
        let slot_albedo = accel
            .scene_index
            .iter()
            .map(|&i| scene.materials[scene.triangle_material[i as usize] as usize].albedo)
            .collect();
        let range = scene
            .particles
            .iter()
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), p| {
                (lo.min(p.attribute), hi.max(p.attribute))
            });
        PreparedScene {
            diagonal: scene.bounds().diagonal().length(),
            accel,
            slot_albedo,
            lights: scene.lights.clone(),
            spheres: SphereAccel::build(&scene.particles),
            attribute_range: range,
        }
    }

    pub fn lights(&self) -> &[Light] {
        &self.lights
    }
}

/// What one frame is rendered with.
#[derive(Clone, Copy, Debug)]
pub struct FrameView {
    pub frame: u64,
    pub rays: PixelRays,
    pub params: RenderParams,
}

impl FrameView {
    pub fn new(
        frame: u64,
        camera: &Camera,
        params: RenderParams,
        wall_width: u32,
        wall_height: u32,
    ) -> Self {
        FrameView {
            frame,
            rays: camera.rays_for(wall_width, wall_height),
            params,
        }
    }
}

/// Rays traced, by kind.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct RayCounts {
    pub primary: u64,
    pub shadow: u64,
    pub ambient: u64,
}

impl RayCounts {
    pub fn total(&self) -> u64 {
        self.primary + self.shadow + self.ambient
    }

    fn add(self, other: RayCounts) -> RayCounts {
        RayCounts {
            primary: self.primary + other.primary,
            shadow: self.shadow + other.shadow,
            ambient: self.ambient + other.ambient,
        }
    }
}

/// Renders `tiles` as RGB8, row-major per tile, on the current rayon pool. All packets of all
/// tiles go into one parallel loop so that threads stay busy across tile boundaries.
///
/// Must not be called on a tokio worker thread: use `spawn_blocking`.
pub fn render_tiles(
    scene: &PreparedScene,
    view: &FrameView,
    tiles: &[Tile],
) -> (Vec<Vec<u8>>, RayCounts) {
    let packets: Vec<(usize, u32, u32)> = tiles
        .iter()
        .enumerate()
        .flat_map(|(i, t)| {
            (0..t.height.div_ceil(PACKET)).flat_map(move |py| {
                (0..t.width.div_ceil(PACKET)).map(move |px| (i, px * PACKET, py * PACKET))
            })
        })
        .collect();
    let traced: Vec<([u8; (PACKET * PACKET * 3) as usize], RayCounts)> = packets
        .par_iter()
        .map_init(
            || scene.accel.new_stack(),
            |stack, &(i, px, py)| trace_packet(scene, view, &tiles[i], px, py, stack),
        )
        .collect();
    let mut images: Vec<Vec<u8>> = tiles.iter().map(|t| vec![0; t.pixel_count() * 3]).collect();
    let mut counts = RayCounts::default();
    for (&(i, px, py), (pixels, c)) in packets.iter().zip(&traced) {
        counts = counts.add(*c);
        let tile = &tiles[i];
        let w = PACKET.min(tile.width - px) as usize;
        let h = PACKET.min(tile.height - py);
        for row in 0..h {
            let dst = (((py + row) * tile.width + px) * 3) as usize;
            let src = (row * PACKET * 3) as usize;
            images[i][dst..dst + w * 3].copy_from_slice(&pixels[src..src + w * 3]);
        }
    }
    (images, counts)
}

/// Traces the packet whose top-left corner is `(px, py)` inside `tile`; returns 8×8 RGB8 pixels
/// (pixels outside the tile left black) and the rays traced.
fn trace_packet(
    scene: &PreparedScene,
    view: &FrameView,
    tile: &Tile,
    px: u32,
    py: u32,
    stack: &mut Vec<u32>,
) -> ([u8; (PACKET * PACKET * 3) as usize], RayCounts) {
    let mut out = [0u8; (PACKET * PACKET * 3) as usize];
    let (x0, y0) = (tile.x + px, tile.y + py);
    let (w, h) = (PACKET.min(tile.width - px), PACKET.min(tile.height - py));
    let mut packet = RayPacket::primary(&view.rays, x0, y0, w, h);
    let mut hits = [PacketHit::MISS; 64];
    scene.accel.closest_hits(&mut packet, &mut hits, stack);
    let mut counts = RayCounts {
        primary: packet.len() as u64,
        ..RayCounts::default()
    };
    for i in 0..packet.len() {
        let (col, row) = (i as u32 % w, i as u32 / w);
        let dir = packet.direction(i);
        let color = match nearest_surface(scene, view, view.rays.eye, dir, hits[i], stack) {
            None => background(dir),
            Some(hit) => shade(
                scene,
                view,
                (x0 + col, y0 + row),
                view.rays.eye,
                dir,
                hit,
                stack,
                &mut counts,
            ),
        };
        let o = ((row * PACKET + col) * 3) as usize;
        out[o..o + 3].copy_from_slice(&encode_srgb_ish(color));
    }
    (out, counts)
}

/// Surface point and the normal facing the viewer for a hit.
pub fn surface(scene: &PreparedScene, origin: Vec3, dir: Vec3, hit: Hit) -> (Vec3, Vec3) {
    let tri = &scene.accel.triangles[hit.slot as usize];
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

/// What a primary ray hit first.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SurfaceHit {
    Triangle(Hit),
    Sphere { t: f32, slot: u32 },
}

/// Combines a packet's triangle hit with the particles, when the scene has any.
pub fn nearest_surface(
    scene: &PreparedScene,
    view: &FrameView,
    origin: Vec3,
    dir: Vec3,
    triangle: PacketHit,
    stack: &mut Vec<u32>,
) -> Option<SurfaceHit> {
    let mut nearest = triangle.slot().map(|slot| {
        SurfaceHit::Triangle(Hit {
            t: triangle.t,
            slot,
        })
    });
    if let Some(spheres) = &scene.spheres {
        if let Some((t, slot)) = spheres.closest_hit(
            &Ray::new(origin, dir),
            0.0,
            triangle.t,
            view.params.crop,
            stack,
        ) {
            nearest = Some(SurfaceHit::Sphere { t, slot });
        }
    }
    nearest
}

impl SurfaceHit {
    pub fn t(&self) -> f32 {
        match *self {
            SurfaceHit::Triangle(h) => h.t,
            SurfaceHit::Sphere { t, .. } => t,
        }
    }

    /// Index of the primitive in the scene: triangles first, then particles.
    pub fn scene_primitive(&self, scene: &PreparedScene) -> u64 {
        match *self {
            SurfaceHit::Triangle(h) => scene.accel.scene_index[h.slot as usize] as u64,
            SurfaceHit::Sphere { slot, .. } => {
                let spheres = scene
                    .spheres
                    .as_ref()
                    .expect("a sphere hit implies spheres");
                scene.accel.triangles.len() as u64 + spheres.scene_index[slot as usize] as u64
            }
        }
    }
}

/// Whether anything (triangles, or particles within the crop range) blocks the ray.
fn blocked(
    scene: &PreparedScene,
    view: &FrameView,
    ray: &Ray,
    t_max: f32,
    stack: &mut Vec<u32>,
) -> bool {
    scene.accel.occluded(ray, 0.0, t_max, stack)
        || scene
            .spheres
            .as_ref()
            .is_some_and(|s| s.occluded(ray, 0.0, t_max, view.params.crop, stack))
}

#[allow(clippy::too_many_arguments)]
fn shade(
    scene: &PreparedScene,
    view: &FrameView,
    pixel: (u32, u32),
    origin: Vec3,
    dir: Vec3,
    hit: SurfaceHit,
    stack: &mut Vec<u32>,
    counts: &mut RayCounts,
) -> Vec3 {
    let (point, normal, albedo) = match hit {
        SurfaceHit::Triangle(h) => {
            let (p, n) = surface(scene, origin, dir, h);
            (p, n, scene.slot_albedo[h.slot as usize])
        }
        SurfaceHit::Sphere { t, slot } => {
            let s = &scene
                .spheres
                .as_ref()
                .expect("a sphere hit implies spheres")
                .spheres[slot as usize];
            let p = origin + dir * t;
            let mut n = ((p - s.center) / s.radius).normalize_or_zero();
            if n.dot(dir) > 0.0 {
                n = -n;
            }
            let (lo, hi) = scene.attribute_range;
            let x = if hi > lo {
                (s.attribute - lo) / (hi - lo)
            } else {
                0.5
            };
            (p, n, colormap(x))
        }
    };
    let headlight = (-normal.dot(dir)).max(0.0);
    let start = offset_origin(point, normal, scene.diagonal);
    let mut direct = 0.0;
    for light in &scene.lights {
        let (towards, reach, intensity) = match *light {
            Light::Directional { towards, intensity } => (towards, f32::INFINITY, intensity),
            Light::Point {
                position,
                intensity,
            } => {
                let d = position - point;
                let dist2 = d.length_squared();
                (d / dist2.sqrt(), dist2.sqrt(), intensity / dist2.max(1e-30))
            }
        };
        let cos = normal.dot(towards);
        if cos <= 0.0 || !cos.is_finite() {
            continue;
        }
        if view.params.shadows {
            counts.shadow += 1;
            if blocked(scene, view, &Ray::new(start, towards), reach, stack) {
                continue;
            }
        }
        direct += cos * intensity;
    }
    let ambient = if view.params.ao_samples > 0 {
        let n = view.params.ao_samples;
        counts.ambient += n as u64;
        0.3 * ambient_visibility(scene, view, pixel, start, normal, stack)
    } else {
        0.1
    };
    albedo * (ambient + 0.35 * headlight + direct)
}

/// Fraction of `ao_samples` cosine-weighted rays from `start` that escape within the AO range.
pub fn ambient_visibility(
    scene: &PreparedScene,
    view: &FrameView,
    pixel: (u32, u32),
    start: Vec3,
    normal: Vec3,
    stack: &mut Vec<u32>,
) -> f32 {
    let n = view.params.ao_samples;
    let reach = scene.diagonal * view.params.ao_range;
    let mut open = 0;
    for sample in 0..n {
        let mut stream = SampleStream::new(view.frame, pixel.0, pixel.1, sample);
        let d = cosine_direction(normal, &mut stream);
        if !blocked(scene, view, &Ray::new(start, d), reach, stack) {
            open += 1;
        }
    }
    open as f32 / n as f32
}

pub fn background(dir: Vec3) -> Vec3 {
    let t = 0.5 + 0.5 * dir.y;
    Vec3::new(0.05, 0.06, 0.09).lerp(Vec3::new(0.32, 0.42, 0.62), t)
}

/// Linear to 8-bit with a gamma of 2 (a square root is exact in IEEE arithmetic, so it is the
/// same on every CPU, unlike `powf`). Non-finite values come out black, never as garbage.
pub fn encode_srgb_ish(color: Vec3) -> [u8; 3] {
    color.to_array().map(|c| {
        if c.is_finite() {
            (c.clamp(0.0, 1.0).sqrt() * 255.0 + 0.5) as u8
        } else {
            0
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::knot_scene;
    use crate::wall::{TileGrid, WallLayout};

    #[test]
    fn a_tile_is_identical_alone_or_in_a_batch_and_on_any_thread_count() {
        let scene = PreparedScene::new(&knot_scene(128, 16));
        let wall = WallLayout::grid(2, 1, 96, 64).with_tile_size(32);
        let grid = TileGrid::new(wall);
        let camera = CameraMode::orbit_of(&knot_scene(128, 16).bounds()).camera_for_frame(3);
        let view = FrameView::new(
            3,
            &camera,
            RenderParams::interactive(),
            wall.width(),
            wall.height(),
        );
        let (all, counts) = render_tiles(&scene, &view, grid.tiles());
        assert!(counts.primary == wall.visible_pixels() && counts.shadow > 0);
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        for (i, tile) in grid.tiles().iter().enumerate() {
            let (alone, _) =
                one.install(|| render_tiles(&scene, &view, std::slice::from_ref(tile)));
            assert_eq!(alone[0], all[i], "tile {i}");
        }
        // Something other than background was drawn.
        let distinct: std::collections::HashSet<&[u8]> =
            all.iter().flat_map(|t| t.chunks(3)).collect();
        assert!(distinct.len() > 20);
    }

    #[test]
    fn shadows_off_traces_no_shadow_rays() {
        let scene = PreparedScene::new(&knot_scene(64, 8));
        let wall = WallLayout::grid(1, 1, 40, 30);
        let grid = TileGrid::new(wall);
        let camera = CameraMode::orbit_of(&knot_scene(64, 8).bounds()).camera_for_frame(0);
        let view = FrameView::new(
            0,
            &camera,
            RenderParams {
                shadows: false,
                ..RenderParams::interactive()
            },
            40,
            30,
        );
        let (_, counts) = render_tiles(&scene, &view, grid.tiles());
        assert_eq!(
            counts,
            RayCounts {
                primary: 1200,
                shadow: 0,
                ambient: 0
            }
        );
    }

    #[test]
    fn a_scene_without_lights_traces_no_shadow_rays_and_ao_only_when_asked() {
        let mut scene = knot_scene(64, 8);
        scene.lights.clear();
        let prepared = PreparedScene::new(&scene);
        let wall = WallLayout::grid(1, 1, 40, 30);
        let grid = TileGrid::new(wall);
        let camera = CameraMode::orbit_of(&scene.bounds()).camera_for_frame(0);
        for params in RenderParams::PRESETS {
            let view = FrameView::new(0, &camera, params, 40, 30);
            let (_, counts) = render_tiles(&prepared, &view, grid.tiles());
            assert_eq!(counts.shadow, 0, "{params:?}");
            assert_eq!(counts.ambient > 0, params.ao_samples > 0, "{params:?}");
        }
    }

    #[test]
    fn every_preset_is_deterministic_and_finite() {
        let scene = knot_scene(96, 12);
        let prepared = PreparedScene::new(&scene);
        let wall = WallLayout::grid(1, 1, 48, 32).with_tile_size(16);
        let grid = TileGrid::new(wall);
        let camera = CameraMode::orbit_of(&scene.bounds()).camera_for_frame(7);
        for params in RenderParams::PRESETS {
            let view = FrameView::new(7, &camera, params, 48, 32);
            let (a, _) = render_tiles(&prepared, &view, grid.tiles());
            let one = rayon::ThreadPoolBuilder::new()
                .num_threads(1)
                .build()
                .unwrap();
            let (b, _) = one.install(|| render_tiles(&prepared, &view, grid.tiles()));
            assert_eq!(a, b, "{params:?}");
        }
    }

    #[test]
    fn particles_are_drawn_colour_mapped_and_cropped_and_only_they_get_a_sphere_bvh() {
        use crate::scene::particles::{write_tpart, Particle};
        assert!(PreparedScene::new(&knot_scene(32, 4)).spheres.is_none());
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("p.tpart");
        let particles: Vec<Particle> = (0..50)
            .map(|i| Particle {
                center: Vec3::new((i % 10) as f32, (i / 10) as f32, 0.0),
                radius: 0.4,
                attribute: i as f32,
            })
            .collect();
        write_tpart(&path, &particles).unwrap();
        let scene = Scene::load(&crate::scene::SceneSpec::File(path)).unwrap();
        assert_eq!(scene.particles.len(), 50);
        let prepared = PreparedScene::new(&scene);
        assert!(prepared.spheres.is_some() && prepared.accel.nodes.is_empty());
        let wall = WallLayout::grid(1, 1, 64, 48).with_tile_size(32);
        let grid = TileGrid::new(wall);
        let camera = Camera {
            eye: Vec3::new(4.5, 2.0, 14.0),
            target: Vec3::new(4.5, 2.0, 0.0),
            up: Vec3::Y,
            fov_y_deg: 50.0,
        };
        let background_pixels = |params: RenderParams| {
            let view = FrameView::new(0, &camera, params, 64, 48);
            let (tiles, _) = render_tiles(&prepared, &view, grid.tiles());
            let rays = camera.rays_for(64, 48);
            grid.tiles()
                .iter()
                .zip(&tiles)
                .map(|(t, rgb)| {
                    (0..t.pixel_count())
                        .filter(|&k| {
                            let (x, y) = (t.x + k as u32 % t.width, t.y + k as u32 / t.width);
                            rgb[k * 3..k * 3 + 3]
                                == encode_srgb_ish(background(rays.direction(x, y)))
                        })
                        .count()
                })
                .sum::<usize>()
        };
        let all = background_pixels(RenderParams::interactive());
        let none = background_pixels(RenderParams {
            crop: Some((1000.0, 2000.0)),
            ..RenderParams::interactive()
        });
        let half = background_pixels(RenderParams {
            crop: Some((0.0, 24.5)),
            ..RenderParams::interactive()
        });
        assert_eq!(
            none,
            64 * 48,
            "everything cropped away leaves only background"
        );
        assert!(all < half && half < none, "{all} < {half} < {none}");
    }
}
