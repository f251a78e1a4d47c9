//! Tracing a frame's tiles: the scene prepared for tracing, what one frame is rendered with,
//! and the parallel loop over 8×8 packets.
//!
//! Every pixel is a pure function of (scene, camera, params, pixel), so a tile is byte-identical
//! on whichever node renders it and the single-process reference equals the wall.

use crate::bvh::Accel;
use crate::packet::{runs_by, PacketHit, RayPacket};
use crate::pixel_rays::PixelRays;
use crate::sampling::SampleStream;
use crate::scene::{Light, Material, Scene};
use crate::shade::{self, background, encode_srgb_ish, Shader};
use crate::shadow_packet;
use crate::slot_materials::SlotMaterials;
use crate::spheres::SphereAccel;
use crate::surface_hit::{nearest_surface, SurfaceHit};
use crate::tracer::Tracer;
use crate::volume::PreparedVolume;
use glam::Vec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::sync::Arc;
use tessera_model::camera::Camera;
use tessera_model::light::Lights;
use tessera_model::params::RenderParams;
use tessera_model::wall::{Tile, WallLayout};
use tessera_protocol::FrameStart;

/// Edge of a packet: tiles are traced as 8×8 = 64-ray packets.
pub const PACKET: u32 = 8;

/// A scene ready to trace: materials and lights from the scene, plus its BVH.
pub struct PreparedScene {
    /// The BVH over the triangles; for a scene in shared memory only its depth (the tree and
    /// triangles are in `shared`).
    pub accel: Accel,
    /// The triangles and their tree in distributed shared memory, when the scene is shared
    /// rather than replicated on every render node.
    pub shared: Option<crate::dsm::DsmTree>,
    /// Material index of each leaf slot.
    pub(crate) slot_material: SlotMaterials,
    pub(crate) materials: Vec<Material>,
    /// Whether any material is transparent: without, the blending path is never entered.
    pub blends: bool,
    pub(crate) lights: Vec<Light>,
    /// Length of the scene's bounding-box diagonal: the scale of offsets and AO reach.
    pub(crate) diagonal: f32,
    /// Particles, if the scene has any.
    pub spheres: Option<SphereAccel>,
    /// Attribute values mapped to the two ends of the colour map.
    pub(crate) attribute_range: (f32, f32),
    /// The scene's volume, bricked, if it has one: for a time series, the step being shown
    /// (see [`PreparedScene::set_volume`]).
    pub volume: Option<Arc<PreparedVolume>>,
}

impl PreparedScene {
    /// Builds the BVH of `scene` and takes its materials, lights, particles and volume.
    pub fn new(scene: &Scene) -> Self {
        Self::from_accel(scene, Accel::build(scene))
    }

    /// Uses an already built (e.g. cached) BVH of `scene`.
    pub fn from_accel(scene: &Scene, accel: Accel) -> Self {
        let slot_material = SlotMaterials::PerSlot(
            accel
                .scene_index
                .iter()
                .map(|&i| scene.triangle_material[i as usize])
                .collect(),
        );
        let range = scene
            .particles
            .iter()
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), p| {
                (lo.min(p.attribute), hi.max(p.attribute))
            });
        PreparedScene {
            diagonal: scene.bounds().diagonal().length(),
            accel,
            shared: None,
            slot_material,
            materials: scene.materials.clone(),
            blends: scene.has_transparency(),
            lights: scene.lights.clone(),
            spheres: SphereAccel::build(&scene.particles),
            attribute_range: range,
            volume: scene
                .volume
                .as_ref()
                .map(|v| Arc::new(PreparedVolume::new(v, &scene.render_from_world))),
        }
    }

    /// Frees what only building, caching and AOVs read, for a render node: the binary tree
    /// (packets and single rays both walk its 8-wide collapse) and the map from leaf slots to
    /// scene triangles (only AOVs' primitive index needs it). 16 bytes a triangle on the 4.2M
    /// knot.
    pub fn slim_for_rendering(&mut self) {
        self.accel.nodes = Vec::new();
        self.accel.scene_index = Vec::new();
    }

    /// Bytes of the per-slot material indices (for memory reports).
    pub fn slot_material_bytes(&self) -> usize {
        self.slot_material.bytes()
    }

    /// Shows `volume` from now on: a time series' next step, from a [`crate::volume::SeriesCache`].
    pub fn set_volume(&mut self, volume: Arc<PreparedVolume>) {
        self.volume = Some(volume);
    }

    /// Triangles in the scene, wherever they are held.
    pub fn triangle_count(&self) -> usize {
        match &self.shared {
            Some(tree) => tree.layout().triangle_count as usize,
            None => self.accel.triangles.len(),
        }
    }

    /// No triangles, particles or volume: every pixel is the backdrop.
    pub fn is_empty(&self) -> bool {
        self.accel.triangles.is_empty()
            && self.shared.is_none()
            && self.spheres.is_none()
            && self.volume.is_none()
    }

    /// The scene's own lights, in render coordinates (a frame may light it with others: see
    /// [`FrameView::lights`]).
    pub fn lights(&self) -> &[Light] {
        &self.lights
    }

    pub(crate) fn spheres(&self) -> &SphereAccel {
        self.spheres
            .as_ref()
            .expect("a sphere hit implies the scene has spheres")
    }
}

/// What one frame is rendered with.
#[derive(Clone, Debug)]
pub struct FrameView {
    /// The frame's number: it seeds the frame's random samples (jitter, AO directions).
    pub frame: u64,
    /// The rays of the camera's one image (a grid wall's virtual image).
    pub rays: PixelRays,
    /// Each viewport's own rays, for a wall that is not one image (physical screens, stereo);
    /// `None`: every tile takes `rays`.
    pub viewports: Option<Arc<[PixelRays]>>,
    /// The frame's render parameters (shading, samples, cutting planes, volume settings).
    pub params: RenderParams,
    /// Lights in place of the scene's own, if the frame's state has some.
    pub lights: Option<Lights>,
}

impl FrameView {
    /// Frame `frame` seen by `camera` with `params` and the scene's own lights.
    pub fn new(
        frame: u64,
        camera: &Camera,
        params: RenderParams,
        wall_width: u32,
        wall_height: u32,
    ) -> Self {
        FrameView {
            frame,
            rays: PixelRays::new(camera, wall_width, wall_height),
            viewports: None,
            params,
            lights: None,
        }
    }

    /// Frame `frame` of `wall` seen by `camera` with `params`: one frustum for a grid wall's
    /// one image, else one a viewport (see `views`).
    pub fn for_wall(frame: u64, camera: &Camera, params: RenderParams, wall: &WallLayout) -> Self {
        let (w, h) = wall.image_size().unwrap_or((wall.width(), wall.height()));
        FrameView {
            viewports: crate::views::viewport_rays(camera, wall),
            ..Self::new(frame, camera, params, w, h)
        }
    }

    /// What a frame start says to render, on `wall`.
    pub fn of_start(start: &FrameStart, wall: &WallLayout) -> Self {
        FrameView {
            lights: start.lights,
            ..Self::for_wall(start.frame.0, &start.camera, start.params, wall)
        }
    }

    /// The rays of `tile`'s viewport.
    #[inline]
    pub fn rays_for(&self, tile: &Tile) -> &PixelRays {
        match &self.viewports {
            Some(v) => &v[tile.viewport as usize],
            None => &self.rays,
        }
    }

    /// The lights this frame is lit by: its state's, or else the scene's.
    #[inline]
    pub fn lights<'a>(&'a self, scene: &'a PreparedScene) -> &'a [Light] {
        match &self.lights {
            Some(lights) => lights.as_slice(),
            None => &scene.lights,
        }
    }
}

/// Rays traced, by kind.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct RayCounts {
    /// Camera rays, one per pixel sample.
    pub primary: u64,
    /// Rays towards a light, testing whether a surface point is in its shadow.
    pub shadow: u64,
    /// Ambient-occlusion rays.
    pub ambient: u64,
    /// Rays reflected by mirrors.
    pub reflected: u64,
    /// Rays continued through transparent surfaces (each one a blend).
    pub transmitted: u64,
}

impl RayCounts {
    /// Rays of every kind together.
    pub fn total(&self) -> u64 {
        self.primary + self.shadow + self.ambient + self.reflected + self.transmitted
    }

    fn add(self, other: RayCounts) -> RayCounts {
        RayCounts {
            primary: self.primary + other.primary,
            shadow: self.shadow + other.shadow,
            ambient: self.ambient + other.ambient,
            reflected: self.reflected + other.reflected,
            transmitted: self.transmitted + other.transmitted,
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
    let (images, counts, _) = render_tiles_with(scene, view, tiles, ShadowRays::Packets);
    (images, counts)
}

/// [`render_tiles`], and for a scene in shared memory the other nodes' blocks each tile read
/// (sorted, once each): what the same tile will read next frame, to be fetched ahead of it.
pub fn render_tiles_footprints(
    scene: &PreparedScene,
    view: &FrameView,
    tiles: &[Tile],
) -> (
    Vec<Vec<u8>>,
    RayCounts,
    Vec<Vec<tessera_core::dsm::BlockId>>,
) {
    render_tiles_with(scene, view, tiles, ShadowRays::Packets)
}

/// How primary hits trace their shadow rays; both give the same pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum ShadowRays {
    Packets,
    #[cfg_attr(not(test), allow(dead_code))]
    Single,
}

pub(crate) fn render_tiles_with(
    scene: &PreparedScene,
    view: &FrameView,
    tiles: &[Tile],
    shadow_rays: ShadowRays,
) -> (
    Vec<Vec<u8>>,
    RayCounts,
    Vec<Vec<tessera_core::dsm::BlockId>>,
) {
    let mut footprints = vec![Vec::new(); tiles.len()];
    if scene.is_empty() {
        // Nothing to hit: every pixel is the one backdrop colour and no ray is traced. Encoding
        // it per pixel cost the empty-scene wall (max-fps) a sixth of its CPU.
        let rgb = encode_srgb_ish(background(Vec3::Z));
        let images = tiles.iter().map(|t| rgb.repeat(t.pixel_count())).collect();
        return (images, RayCounts::default(), footprints);
    }
    let packets = packets_of(tiles);
    type Traced = ([u8; (PACKET * PACKET * 3) as usize], RayCounts, Vec<u32>);
    let traced: Vec<Traced> = packets
        .par_iter()
        .map_init(
            || scene.tracer(),
            |tracer, &(i, px, py)| {
                let (pixels, counts) =
                    trace_packet(scene, view, &tiles[i], (px, py), shadow_rays, tracer);
                (pixels, counts, tracer.take_footprint())
            },
        )
        .collect();
    let mut images: Vec<Vec<u8>> = tiles.iter().map(|t| vec![0; t.pixel_count() * 3]).collect();
    let mut counts = RayCounts::default();
    for (&(i, px, py), (pixels, c, footprint)) in packets.iter().zip(&traced) {
        footprints[i].extend_from_slice(footprint);
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
    for f in &mut footprints {
        f.sort_unstable();
        f.dedup();
    }
    (images, counts, footprints)
}

/// Renders `tiles` as linear colour (what [`render_tiles`] encodes to 8 bits, before encoding),
/// row-major per tile: for error measurements against a converged reference.
pub fn render_tiles_linear(
    scene: &PreparedScene,
    view: &FrameView,
    tiles: &[Tile],
) -> (Vec<Vec<Vec3>>, RayCounts) {
    let packets = packets_of(tiles);
    let spp = view.params.spp().max(1) as f32;
    let traced: Vec<([Vec3; 64], RayCounts)> = packets
        .par_iter()
        .map_init(
            || scene.tracer(),
            |tracer, &(i, px, py)| {
                packet_sum(
                    scene,
                    view,
                    &tiles[i],
                    (px, py),
                    ShadowRays::Packets,
                    tracer,
                )
            },
        )
        .collect();
    let mut images: Vec<Vec<Vec3>> = tiles
        .iter()
        .map(|t| vec![Vec3::ZERO; t.pixel_count()])
        .collect();
    let mut counts = RayCounts::default();
    for (&(i, px, py), (sum, c)) in packets.iter().zip(&traced) {
        counts = counts.add(*c);
        let tile = &tiles[i];
        let w = PACKET.min(tile.width - px);
        for lane in 0..(w * PACKET.min(tile.height - py)) {
            let at = ((py + lane / w) * tile.width + px + lane % w) as usize;
            // Per channel, as the 8-bit encoding divides.
            images[i][at] = Vec3::from_array(sum[lane as usize].to_array().map(|c| c / spp));
        }
    }
    (images, counts)
}

/// Every 8×8 packet of `tiles`: its tile and its corner in the tile.
fn packets_of(tiles: &[Tile]) -> Vec<(usize, u32, u32)> {
    tiles
        .iter()
        .enumerate()
        .flat_map(|(i, t)| {
            (0..t.height.div_ceil(PACKET)).flat_map(move |py| {
                (0..t.width.div_ceil(PACKET)).map(move |px| (i, px * PACKET, py * PACKET))
            })
        })
        .collect()
}

/// Samples of supersampling and of ambient occlusion are drawn from one key space per pixel:
/// sample `s` of the pixel's jitter has key `JITTER_KEYS + s`, ambient-occlusion ray `k` of
/// supersample `s` has key `s · ao_samples + k`.
const JITTER_KEYS: u32 = 1 << 31;

/// Traces the packet whose top-left corner is `(px, py)` inside `tile`; returns 8×8 RGB8 pixels
/// (pixels outside the tile left black) and the rays traced.
fn trace_packet(
    scene: &PreparedScene,
    view: &FrameView,
    tile: &Tile,
    (px, py): (u32, u32),
    shadow_rays: ShadowRays,
    tracer: &mut Tracer<'_>,
) -> ([u8; (PACKET * PACKET * 3) as usize], RayCounts) {
    let mut out = [0u8; (PACKET * PACKET * 3) as usize];
    let (w, h) = (PACKET.min(tile.width - px), PACKET.min(tile.height - py));
    let spp = view.params.spp().max(1);
    let (sum, counts) = packet_sum(scene, view, tile, (px, py), shadow_rays, tracer);
    if w == PACKET {
        // Lane i is pixel (i % 8, i / 8), so the channels lie in `out`'s order: encoded in
        // one flat loop that runs several channels at once.
        let flat: &[f32] = bytemuck::cast_slice(&sum[..]);
        let n = (w * h * 3) as usize;
        for (o, &c) in out[..n].iter_mut().zip(&flat[..n]) {
            *o = shade::encode_channel(c / spp as f32);
        }
    } else {
        for (i, color) in sum.iter().enumerate().take((w * h) as usize) {
            let o = (((i as u32 / w) * PACKET + i as u32 % w) * 3) as usize;
            out[o..o + 3].copy_from_slice(&encode_srgb_ish(*color / spp as f32));
        }
    }
    (out, counts)
}

/// The colours of the packet at `(px, py)` in `tile`, summed over the frame's samples (lane i
/// is pixel (i % 8, i / 8) of the block), and the rays traced.
#[inline(always)]
fn packet_sum(
    scene: &PreparedScene,
    view: &FrameView,
    tile: &Tile,
    (px, py): (u32, u32),
    shadow_rays: ShadowRays,
    tracer: &mut Tracer<'_>,
) -> ([Vec3; 64], RayCounts) {
    let (x0, y0) = (tile.x + px, tile.y + py);
    let (w, h) = (PACKET.min(tile.width - px), PACKET.min(tile.height - py));
    let mut counts = RayCounts::default();
    let mut sum = [Vec3::ZERO; 64];
    let spp = view.params.spp().max(1);
    for s in 0..spp {
        let sample = view.params.first_sample() + s;
        let mut packet = if spp == 1 && view.params.first_sample() == 0 {
            RayPacket::primary(view.rays_for(tile), x0, y0, w, h)
        } else {
            RayPacket::primary_jittered(view.rays_for(tile), x0, y0, w, h, |x, y| {
                let mut stream = SampleStream::new(view.frame, x, y, JITTER_KEYS + sample);
                (stream.next_f32(), stream.next_f32())
            })
        };
        let c = shade_packet(
            scene,
            view,
            &mut packet,
            (x0, y0, w),
            (sample, shadow_rays),
            tracer,
            &mut sum,
        );
        counts = counts.add(c);
    }
    (sum, counts)
}

/// What each ray of `packet` (clipped, from its viewport's eye) hits first: a triangle, a
/// particle or an iso-surface.
fn first_surfaces(
    scene: &PreparedScene,
    view: &FrameView,
    packet: &mut RayPacket,
    tracer: &mut Tracer<'_>,
) -> [Option<SurfaceHit>; 64] {
    let eye = packet.origin;
    let mut hits = [PacketHit::MISS; 64];
    tracer.closest_hits(packet, &mut hits);
    if scene.spheres.is_none() && scene.volume.is_none() {
        // Triangles only: the packet's hits are the surfaces (a seventh of an eyelight
        // frame went into asking each ray about particles there are none of).
        return std::array::from_fn(|i| SurfaceHit::of_triangle(hits[i]));
    }
    std::array::from_fn(|i| {
        (i < packet.len()).then(|| {
            let ray = (eye, packet.direction(i));
            let interval = (packet.t_min[i], packet.t_max[i]);
            nearest_surface(scene, view, ray, interval, hits[i], tracer)
        })?
    })
}

/// Traces `packet` (the rays of the block at `x0, y0`, `w` wide) and adds each ray's colour to
/// `sum`.
fn shade_packet(
    scene: &PreparedScene,
    view: &FrameView,
    packet: &mut RayPacket,
    (x0, y0, w): (u32, u32, u32),
    (sample, shadow_rays): (u32, ShadowRays),
    tracer: &mut Tracer<'_>,
    sum: &mut [Vec3; 64],
) -> RayCounts {
    // The eye of the packet's viewport (each eye of a stereo wall has its own).
    let eye = packet.origin;
    packet.clip(view.params.cuts());
    let surfaces = first_surfaces(scene, view, packet, tracer);
    let mut shader = Shader {
        scene,
        view,
        tracer,
        counts: RayCounts {
            primary: packet.len() as u64,
            ..RayCounts::default()
        },
        pixel: (x0, y0),
        first_ao_key: sample * view.params.ao_samples(),
        primary: None,
    };
    let packet_shadows = shadow_rays == ShadowRays::Packets;
    let shadows =
        (packet_shadows && view.params.shadows() && !view.lights(scene).is_empty()).then(|| {
            let directions: [Vec3; 64] = std::array::from_fn(|i| packet.direction(i));
            shadow_packet::primary_shadows(
                scene,
                view,
                eye,
                &directions[..packet.len()],
                &surfaces[..packet.len()],
                shader.tracer,
            )
        });
    // Sub-packets of consecutive rays that hit the same material (or nothing) are shaded
    // together, the material looked up once per run: ranges of the packet, not copies.
    let keys: [Option<u16>; 64] =
        std::array::from_fn(|i| surfaces[i].map(|s| s.material_key(scene)));
    let volume_tables = shade::volume_tables(scene, view);
    for (key, run) in runs_by(&keys[..packet.len()]) {
        // Particles and iso-surfaces have keys past the scene's materials.
        let material = key
            .filter(|&k| (k as usize) < scene.materials.len())
            .map(|k| scene.materials[k as usize]);
        for i in run {
            let dir = packet.direction(i);
            let color = match surfaces[i] {
                None => background(dir),
                Some(hit) => {
                    let m = material.unwrap_or_else(|| scene.material_of(hit));
                    shader.pixel = (x0 + i as u32 % w, y0 + i as u32 / w);
                    shader.primary = shadows.and_then(|s| s[i]);
                    shader.shade(eye, dir, hit, &m, 0)
                }
            };
            sum[i] += match &volume_tables {
                Some(tables) => {
                    let t_end = surfaces[i].map_or(packet.t_max[i], |h| h.t());
                    let interval = (packet.t_min[i], t_end);
                    shade::through_volume(scene, tables, (eye, dir), interval, color)
                }
                None => color,
            };
        }
    }
    shader.counts
}
