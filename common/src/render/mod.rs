//! The first renderer: primary rays, headlight Lambert shading and hard shadows from the scene's
//! directional light, traced in 8×8 packets that rayon threads take from a shared queue.
//!
//! Every pixel is a pure function of (scene, camera, params, pixel), so a tile is byte-identical
//! on whichever node renders it and the single-process reference equals the wall.

mod camera;

pub use camera::{Camera, CameraError, CameraMode, PixelRays};

use crate::accel::Accel;
use crate::geometry::{triangle_normal, Ray};
use crate::scene::Scene;
use crate::wall::Tile;
use glam::Vec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Edge of a packet: tiles are traced as 8×8 = 64-ray packets.
pub const PACKET: u32 = 8;

/// Per-frame quality knobs, changed only at the frame barrier.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RenderParams {
    /// Trace shadow rays towards the light.
    pub shadows: bool,
}

impl RenderParams {
    /// What the interactive wall renders by default.
    pub const fn interactive() -> Self {
        RenderParams { shadows: true }
    }
}

impl Default for RenderParams {
    fn default() -> Self {
        Self::interactive()
    }
}

/// A scene ready to trace: materials and light from the scene, plus its BVH.
pub struct PreparedScene {
    pub accel: Accel,
    /// Material albedo of each leaf slot of `accel`.
    slot_albedo: Vec<Vec3>,
    light_dir: Vec3,
}

impl PreparedScene {
    pub fn new(scene: &Scene) -> Self {
        let accel = Accel::build(scene);
        let slot_albedo = accel
            .scene_index
            .iter()
            .map(|&i| scene.materials[scene.triangle_material[i as usize] as usize].albedo)
            .collect();
        PreparedScene {
            accel,
            slot_albedo,
            light_dir: scene.light_dir,
        }
    }
}

/// What one frame is rendered with.
#[derive(Clone, Copy, Debug)]
pub struct FrameView {
    pub rays: PixelRays,
    pub params: RenderParams,
}

impl FrameView {
    pub fn new(camera: &Camera, params: RenderParams, wall_width: u32, wall_height: u32) -> Self {
        FrameView {
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
}

impl RayCounts {
    pub fn total(&self) -> u64 {
        self.primary + self.shadow
    }

    fn add(self, other: RayCounts) -> RayCounts {
        RayCounts {
            primary: self.primary + other.primary,
            shadow: self.shadow + other.shadow,
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
    let mut counts = RayCounts::default();
    for row in 0..PACKET.min(tile.height - py) {
        for col in 0..PACKET.min(tile.width - px) {
            let (x, y) = (tile.x + px + col, tile.y + py + row);
            let (color, c) = shade_pixel(scene, view, x, y, stack);
            counts = counts.add(c);
            let o = ((row * PACKET + col) * 3) as usize;
            out[o..o + 3].copy_from_slice(&encode_srgb_ish(color));
        }
    }
    (out, counts)
}

fn shade_pixel(
    scene: &PreparedScene,
    view: &FrameView,
    x: u32,
    y: u32,
    stack: &mut Vec<u32>,
) -> (Vec3, RayCounts) {
    let dir = view.rays.direction(x, y);
    let ray = Ray::new(view.rays.eye, dir);
    let mut counts = RayCounts {
        primary: 1,
        shadow: 0,
    };
    let Some(hit) = scene.accel.closest_hit(&ray, 0.0, f32::INFINITY, stack) else {
        return (background(dir), counts);
    };
    let tri = &scene.accel.triangles[hit.slot as usize];
    let mut normal = triangle_normal(tri.a, tri.b, tri.c).normalize_or_zero();
    if normal.dot(dir) > 0.0 {
        normal = -normal;
    }
    let albedo = scene.slot_albedo[hit.slot as usize];
    let headlight = (-normal.dot(dir)).max(0.0);
    let mut sun = normal.dot(scene.light_dir).max(0.0);
    if sun > 0.0 && view.params.shadows {
        let point = ray.at(hit.t);
        // Offset along the normal in proportion to the coordinates' magnitude: a fixed epsilon
        // is either acne far from the origin or a visible gap near it.
        let scale = point.abs().max_element().max(1.0);
        let origin = point + normal * (scale * 2e-5);
        counts.shadow += 1;
        if scene.accel.occluded(
            &Ray::new(origin, scene.light_dir),
            0.0,
            f32::INFINITY,
            stack,
        ) {
            sun = 0.0;
        }
    }
    (albedo * (0.1 + 0.35 * headlight + 0.65 * sun), counts)
}

fn background(dir: Vec3) -> Vec3 {
    let t = 0.5 + 0.5 * dir.y;
    Vec3::new(0.05, 0.06, 0.09).lerp(Vec3::new(0.32, 0.42, 0.62), t)
}

/// Linear to 8-bit with a gamma of 2 (a square root is exact in IEEE arithmetic, so it is the
/// same on every CPU, unlike `powf`). Non-finite values come out black, never as garbage.
fn encode_srgb_ish(color: Vec3) -> [u8; 3] {
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
        let view = FrameView::new(&camera, RenderParams { shadows: false }, 40, 30);
        let (_, counts) = render_tiles(&scene, &view, grid.tiles());
        assert_eq!(
            counts,
            RayCounts {
                primary: 1200,
                shadow: 0
            }
        );
    }
}
