//! Tracing a frame's tiles: the parallel loop over 8×8 packets, each shaded through
//! `shade` and `shadow_packet` (the scene and the frame they are traced with are `prepared`'s).
//!
//! Every pixel is a pure function of (scene, camera, params, pixel), so a tile is byte-identical
//! on whichever node renders it and the single-process reference equals the wall.

use crate::cancel::Cancel;
use crate::geometry::triangle_normal;
use crate::isa::Isa;
use crate::lanes::EyeLightLanes;
use crate::packet::{lane_mask, runs_by, PacketHit, RayPacket};
use crate::prepared::{FrameView, PreparedScene, RayCounts};
use crate::sampling::SampleStream;
use crate::shade::{self, background, encode_srgb_ish, Shader};
use crate::shadow_packet;
use crate::surface_hit::{nearest_surface, PrimaryHit, SurfaceHit};
use crate::tracer::Tracer;
use glam::Vec3;
use std::sync::Mutex;
use tessera_model::wall::Tile;

/// Edge of a packet: tiles are traced as 8×8 = 64-ray packets.
pub const PACKET: u32 = 8;

/// Renders `tiles` as RGB8, row-major per tile, on the current rayon pool. All packets of all
/// tiles go into one parallel loop so that threads stay busy across tile boundaries.
///
/// Must not be called on a tokio worker thread: use `spawn_blocking`.
pub fn render_tiles(
    scene: &PreparedScene,
    view: &FrameView,
    tiles: &[Tile],
) -> (Vec<Vec<u8>>, RayCounts) {
    let (images, counts, _) =
        render_tiles_with(scene, view, tiles, ShadowRays::Packets, &Cancel::new())
            .expect("a token nobody holds is never cancelled");
    (images, counts)
}

/// The tiles' pixels, the rays traced and, per tile, the other nodes' blocks it read.
pub type Traced = (
    Vec<Vec<u8>>,
    RayCounts,
    Vec<Vec<tessera_core::dsm::BlockId>>,
);

/// [`render_tiles`], and for a scene in shared memory the other nodes' blocks each tile read
/// (sorted, once each): what the same tile will read next frame, to be fetched ahead of it.
///
/// `cancel` is checked before each sample of each packet; `None` if it was cancelled before
/// the last packet was done (the pixels traced so far are dropped: a display must never show
/// part of a tile).
pub fn render_tiles_footprints(
    scene: &PreparedScene,
    view: &FrameView,
    tiles: &[Tile],
    cancel: &Cancel,
) -> Option<Traced> {
    render_tiles_with(scene, view, tiles, ShadowRays::Packets, cancel)
}

/// How primary hits trace their shadow rays; both give the same pixels. `Single` also shades
/// every eye-light hit through the general per-ray path: the reference the fast path of
/// [`eye_light_packet`] is checked against.
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
    cancel: &Cancel,
) -> Option<Traced> {
    let mut footprints = vec![Vec::new(); tiles.len()];
    if scene.is_empty() {
        // Nothing to hit: every pixel is the one backdrop colour and no ray is traced. Encoding
        // it per pixel cost the empty-scene wall (max-fps) a sixth of its CPU.
        let rgb = encode_srgb_ish(background(Vec3::Z));
        let images = tiles.iter().map(|t| rgb.repeat(t.pixel_count())).collect();
        return Some((images, RayCounts::default(), footprints));
    }
    let packets = packets_of(tiles);
    // Each packet's pixels go straight into its tile: collected per packet and copied into
    // the tiles afterwards, they were 9 MB a 1920x1080 frame written, read and faulted in
    // again, a twentieth of an eye-light frame. A tile's lock is taken once per packet, for
    // a copy of its rows (the threads work on distant packets, so it is hardly ever waited for).
    // A packet of a shared scene set aside for a block (`parking`) is traced again and copies
    // its pixels again: the last trace's, which read only real blocks, are the ones kept.
    let images: Vec<Mutex<Vec<u8>>> = tiles
        .iter()
        .map(|t| Mutex::new(vec![0; t.pixel_count() * 3]))
        .collect();
    let traced = crate::parking::trace_all(scene, packets.len(), cancel, |tracer, p| {
        let (i, px, py) = packets[p];
        let (pixels, counts) = trace_packet(
            scene,
            view,
            &tiles[i],
            (px, py),
            (shadow_rays, cancel),
            tracer,
        );
        let mut image = images[i].lock().unwrap_or_else(|e| e.into_inner());
        copy_packet(&mut image, &tiles[i], (px, py), &pixels);
        (counts, tracer.take_footprint())
    })?;
    if cancel.is_cancelled() {
        return None;
    }
    let mut counts = RayCounts::default();
    for (&(i, _, _), (c, footprint)) in packets.iter().zip(&traced) {
        footprints[i].extend_from_slice(footprint);
        counts = counts.add(*c);
    }
    for f in &mut footprints {
        f.sort_unstable();
        f.dedup();
    }
    let images = images
        .into_iter()
        .map(|m| m.into_inner().unwrap_or_else(|e| e.into_inner()))
        .collect();
    Some((images, counts, footprints))
}

/// Copies the packet at `(px, py)` of `tile` (8×8 pixels, rows of [`PACKET`], those outside
/// the tile unused) into the tile's RGB8 `image`.
fn copy_packet(
    image: &mut [u8],
    tile: &Tile,
    (px, py): (u32, u32),
    pixels: &[u8; (PACKET * PACKET * 3) as usize],
) {
    let w = PACKET.min(tile.width - px) as usize;
    for row in 0..PACKET.min(tile.height - py) {
        let dst = (((py + row) * tile.width + px) * 3) as usize;
        let src = (row * PACKET * 3) as usize;
        image[dst..dst + w * 3].copy_from_slice(&pixels[src..src + w * 3]);
    }
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
    let never = Cancel::new();
    let traced = crate::parking::trace_all(scene, packets.len(), &never, |tracer, p| {
        let (i, px, py) = packets[p];
        packet_sum(
            scene,
            view,
            &tiles[i],
            (px, py),
            (ShadowRays::Packets, &never),
            tracer,
        )
    })
    .expect("a token nobody holds is never cancelled");
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
    shadow_rays: (ShadowRays, &Cancel),
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
        crate::lanes::encode_channels(Isa::best(), &flat[..n], spp as f32, &mut out[..n]);
    } else {
        for (i, color) in sum.iter().enumerate().take((w * h) as usize) {
            let o = (((i as u32 / w) * PACKET + i as u32 % w) * 3) as usize;
            out[o..o + 3].copy_from_slice(&encode_srgb_ish(*color / spp as f32));
        }
    }
    (out, counts)
}

/// The colours of the packet at `(px, py)` in `tile`, summed over the frame's samples (lane i
/// is pixel (i % 8, i / 8) of the block), and the rays traced. Stops short, with a partial
/// sum, once `cancel` is cancelled: one sample of a packet at the largest ambient-occlusion
/// count is about a millisecond of a core, the whole packet at the largest quality seconds.
#[inline(always)]
fn packet_sum(
    scene: &PreparedScene,
    view: &FrameView,
    tile: &Tile,
    (px, py): (u32, u32),
    (shadow_rays, cancel): (ShadowRays, &Cancel),
    tracer: &mut Tracer<'_>,
) -> ([Vec3; 64], RayCounts) {
    let (x0, y0) = (tile.x + px, tile.y + py);
    let (w, h) = (PACKET.min(tile.width - px), PACKET.min(tile.height - py));
    let mut counts = RayCounts::default();
    let mut sum = [Vec3::ZERO; 64];
    let spp = view.params.spp().max(1);
    for s in 0..spp {
        // After a miss the packet is traced again anyway (`parking`): its other samples wait.
        if cancel.is_cancelled() || tracer.has_missed() {
            break;
        }
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
    if shadow_rays == ShadowRays::Packets && eye_light_packet(scene, view, packet, tracer, sum) {
        // After a miss the packet is traced again (`parking`): nothing counted.
        let traced = if tracer.has_missed() { 0 } else { packet.len() };
        return RayCounts {
            primary: traced as u64,
            ..RayCounts::default()
        };
    }
    let surfaces = first_surfaces(scene, view, packet, tracer);
    if tracer.has_missed() {
        // Some first hits are void (a block of the tree was not here): shading them would
        // trace secondary rays from wrong points and fetch blocks nobody needs.
        return RayCounts::default();
    }
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
    let shadows = (shadow_rays == ShadowRays::Packets)
        .then(|| shadow_packet_of(scene, view, packet, &surfaces, shader.tracer))
        .flatten();
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
                    let m = material.unwrap_or_else(|| scene.material_of(hit, view));
                    shader.pixel = (x0 + i as u32 % w, y0 + i as u32 / w);
                    shader.primary = shadows.as_ref().and_then(|s| s[i]);
                    shader.shade(eye, dir, hit, &m, 0)
                }
            };
            sum[i] += match &volume_tables {
                Some(tables) => {
                    let t_end = surfaces[i].map_or(packet.t_max[i], |h| h.t());
                    let interval = (packet.t_min[i], t_end);
                    shade::through_volume(scene, tables, (eye, dir), interval, color, shader.tracer)
                }
                None => color,
            };
        }
    }
    shader.counts
}

/// The shadow packet of `packet`'s hits (which lights each sees), if the frame traces shadow
/// rays towards any light.
fn shadow_packet_of(
    scene: &PreparedScene,
    view: &FrameView,
    packet: &RayPacket,
    surfaces: &[Option<SurfaceHit>; 64],
    tracer: &mut Tracer<'_>,
) -> Option<[Option<PrimaryHit>; 64]> {
    let params = &view.params;
    if !params.shadows() || params.eye_light() || view.lights(scene).is_empty() {
        return None;
    }
    let directions: [Vec3; 64] = std::array::from_fn(|i| packet.direction(i));
    Some(shadow_packet::primary_shadows(
        scene,
        view,
        packet.origin,
        &directions[..packet.len()],
        &surfaces[..packet.len()],
        tracer,
    ))
}

/// Eye-light shading of a packet of a triangle-only scene without textures or vertex colours,
/// traced and shaded straight from its closest hits: the normal from the triangle, the albedo
/// from its material. The same bits as `Shader::shade` (its normal is the same one, flipped
/// towards the eye, which the absolute value of [`shade::eye_light`] ignores), without its
/// per-hit machinery. False, with nothing traced, for any other frame or scene; after a miss
/// (`tracer.has_missed`) nothing is shaded.
fn eye_light_packet(
    scene: &PreparedScene,
    view: &FrameView,
    packet: &mut RayPacket,
    tracer: &mut Tracer<'_>,
    sum: &mut [Vec3; 64],
) -> bool {
    let plain = scene.spheres.is_none() && scene.volume.is_none() && scene.colors.is_none();
    if !(view.params.eye_light() && plain) {
        return false;
    }
    let mut hits = [PacketHit::MISS; 64];
    tracer.closest_hits(packet, &mut hits);
    if tracer.has_missed() {
        return true;
    }
    // In three passes, so that the middle one, a square root and a division per lane, runs
    // eight or sixteen lanes at a time: lane after lane they were a latency chain, a seventh
    // of an eye-light frame.
    let mut lanes = EyeLightLanes {
        normals: [[0.0; 64]; 3],
        albedo: [[0.0; 64]; 3],
        hit: [0; 64],
    };
    for (i, hit) in hits.iter().enumerate().take(packet.len()) {
        if let Some(slot) = hit.slot() {
            let tri = tracer.triangle(slot);
            let normal = triangle_normal(tri.a, tri.b, tri.c);
            let albedo = scene.materials[scene.slot_material.of(slot) as usize].albedo;
            for axis in 0..3 {
                lanes.normals[axis][i] = normal[axis];
                lanes.albedo[axis][i] = albedo[axis];
            }
            lanes.hit[i] = lane_mask(true);
        }
    }
    let rgb: &mut [[f32; 3]; 64] = bytemuck::cast_mut(sum);
    crate::lanes::eye_light_colors_on(Isa::best(), &lanes, &packet.dir, rgb);
    true
}
