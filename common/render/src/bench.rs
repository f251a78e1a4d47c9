//! Throughput of each kind of ray on a whole image, for `tessera-render-node bench`.
//!
//! Primary rays are traced as 8×8 packets exactly as when rendering; shadow and
//! ambient-occlusion rays start from the primary hits. Shadow rays are timed twice: as packets
//! (the hits of one primary packet together, as the renderer traces them) and as single rays. Each pass is timed alone so the figures
//! compare with other tracers' (e.g. Embree's) ray-cast-only numbers.

use crate::bvh::node::Hit;
use crate::geometry::Ray;
use crate::packet::{PacketHit, RayPacket, PACKET_RAYS};
use crate::sampling::{Hemisphere, PixelSeed};
use crate::scene::Light;
use crate::{offset_origin, surface, FrameView, PreparedScene, PACKET};
use glam::Vec3;
use rayon::prelude::*;
use std::time::Instant;

/// Rays traced and seconds taken by one pass.
#[derive(Clone, Copy, Debug, Default)]
pub struct Pass {
    /// Rays traced.
    pub rays: u64,
    /// Wall-clock seconds the pass took, its rays traced on every thread of the pool.
    pub seconds: f64,
}

impl Pass {
    /// Millions of rays a second; 0 for a pass that took no time.
    pub fn mrays_per_s(&self) -> f64 {
        if self.seconds > 0.0 {
            self.rays as f64 / self.seconds / 1e6
        } else {
            0.0
        }
    }
}

/// What [`time_passes`] measured: each pass, and the hits the secondary rays start from.
#[derive(Clone, Copy, Debug, Default)]
pub struct PassTimes {
    /// Primary rays that hit something (each starts the shadow and AO rays).
    pub hits: u64,
    /// Primary rays, in 8×8 packets.
    pub primary: Pass,
    /// Shadow rays in packets, as the renderer traces them.
    pub shadow: Pass,
    /// The same shadow rays one by one.
    pub shadow_single: Pass,
    /// Ambient-occlusion rays, `ao_samples` per hit, as [`AoRays::reach`] says.
    pub ambient: Pass,
    /// With [`AoReach::Unbounded`], the same directions from where the renderer starts them
    /// (the offset origin, from t = 0), unbounded: what [`PassTimes::ambient`] measured before
    /// it traced Embree's rays.
    pub ambient_from_surface: Option<Pass>,
    /// The same rays, each hit's as packets of up to 64 with a common origin; timed only when
    /// asked for ([`AoRays::packets`]), since they take twice the single rays' time.
    pub ambient_packets: Option<Pass>,
}

/// The ambient-occlusion rays [`time_passes`] traces.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AoRays {
    /// Rays per primary hit.
    pub samples: u32,
    /// How far they reach.
    pub reach: AoReach,
    /// Whether to time them as common-origin packets too.
    pub packets: bool,
}

/// How far ambient-occlusion rays reach in [`time_passes`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum AoReach {
    /// As the renderer traces them: a share of the scene's diagonal (`RenderParams::ao_range`).
    Renderer,
    /// As Embree's `ao` tutorial shader traces them: from the hit point itself, from
    /// t = [`EMBREE_AO_T_NEAR`] (in scene units), unbounded.
    Unbounded,
}

/// Where Embree's `ao` shader starts its rays (`tnear`, in the scene's units; 3.13's
/// `tutorial_device.cpp`): on the dragon, about three triangles' widths, so those rays skip the
/// triangles around the hit, which the renderer's rays (from an origin pushed a few ulps off
/// the surface, t from 0) test.
pub const EMBREE_AO_T_NEAR: f32 = 0.001;

/// Where a primary ray hit: the point, the origin secondary rays start from (pushed off the
/// surface, see [`offset_origin`]), and the normal facing the eye.
#[derive(Clone, Copy, Debug)]
struct Start {
    point: Vec3,
    origin: Vec3,
    normal: Vec3,
}

/// An ambient-occlusion ray's start and reach: origin, t_min, t_max.
type AoFrom = fn(&Start, f32) -> (Vec3, f32, f32);

/// Traces one frame of `width × height` primary rays, then one shadow ray per hit towards the
/// first light, then `ao.samples` ambient-occlusion rays per hit, timing each pass.
pub fn time_passes(
    scene: &PreparedScene,
    view: &FrameView,
    width: u32,
    height: u32,
    ao: AoRays,
) -> PassTimes {
    let blocks: Vec<(u32, u32)> = (0..height.div_ceil(PACKET))
        .flat_map(|by| (0..width.div_ceil(PACKET)).map(move |bx| (bx * PACKET, by * PACKET)))
        .collect();
    let (primary, block_hits) = time_primary(scene, view, &blocks, (width, height));
    let traced: Vec<(RayPacket, [PacketHit; PACKET_RAYS])> = blocks
        .iter()
        .zip(block_hits)
        .map(|(&(x0, y0), hits)| {
            let (w, h) = (PACKET.min(width - x0), PACKET.min(height - y0));
            (RayPacket::primary(&view.rays, x0, y0, w, h), hits)
        })
        .collect();
    let starts = ray_starts(scene, view, &traced);
    let towards = scene.lights().first().map(|l| match *l {
        Light::Directional { towards, .. } => towards,
        Light::Point { position, .. } => position.normalize_or_zero(),
    });
    let reach = scene.diagonal * view.params.ao_range();
    let renderer: AoFrom = |s, reach| (s.origin, 0.0, reach);
    let embree: AoFrom = |s, _| (s.point, EMBREE_AO_T_NEAR, f32::INFINITY);
    let surface: AoFrom = |s, _| (s.origin, 0.0, f32::INFINITY);
    let ao_from = match ao.reach {
        AoReach::Renderer => renderer,
        AoReach::Unbounded => embree,
    };
    let samples = (ao.samples, reach);
    PassTimes {
        hits: starts.len() as u64,
        primary,
        shadow: time_shadow_packets(scene, view, &traced, towards),
        shadow_single: time_shadow_rays(scene, &starts, towards),
        ambient: time_ambient(scene, view, &starts, samples, ao_from),
        ambient_from_surface: (ao.reach == AoReach::Unbounded)
            .then(|| time_ambient(scene, view, &starts, samples, surface)),
        ambient_packets: ao
            .packets
            .then(|| time_ambient_packets(scene, view, &starts, samples, ao_from)),
    }
}

/// Times the primary rays of `blocks` (8×8 packets of the `width × height` image), and returns
/// each block's hits.
fn time_primary(
    scene: &PreparedScene,
    view: &FrameView,
    blocks: &[(u32, u32)],
    (width, height): (u32, u32),
) -> (Pass, Vec<[PacketHit; PACKET_RAYS]>) {
    // Only the traversal is timed: the hits go to a buffer allocated and touched before the
    // clock starts (collecting packets inside the timed loop cost page faults and copies of
    // ~110 MB a frame at 1920x1080, which no tracer's ray rate includes), and the packets are
    // made again after it.
    let mut block_hits = vec![[PacketHit::MISS; PACKET_RAYS]; blocks.len()];
    let t0 = Instant::now();
    block_hits
        .par_iter_mut()
        .zip(blocks.par_iter())
        .for_each_init(
            || scene.tracer(),
            |tracer, (hits, &(x0, y0))| {
                let (w, h) = (PACKET.min(width - x0), PACKET.min(height - y0));
                let mut packet = RayPacket::primary(&view.rays, x0, y0, w, h);
                tracer.closest_hits(&mut packet, hits);
            },
        );
    let pass = Pass {
        rays: (width * height) as u64,
        seconds: t0.elapsed().as_secs_f64(),
    };
    (pass, block_hits)
}

/// Where the secondary rays of each primary hit start, and the surface normal there.
fn ray_starts(
    scene: &PreparedScene,
    view: &FrameView,
    traced: &[(RayPacket, [PacketHit; PACKET_RAYS])],
) -> Vec<Start> {
    let primary: Vec<(Vec3, Vec3, Option<Hit>)> = traced
        .iter()
        .flat_map(|(packet, hits)| {
            (0..packet.len()).map(move |i| {
                (
                    view.rays.eye,
                    packet.direction(i),
                    hits[i].slot().map(|slot| Hit { t: hits[i].t, slot }),
                )
            })
        })
        .collect();
    primary
        .par_iter()
        .map_init(
            || scene.tracer(),
            |tracer, &(o, d, hit)| hit.map(|h| surface(tracer, o, d, h)),
        )
        .flatten()
        .map(|(point, normal)| Start {
            point,
            origin: offset_origin(point, normal, scene.diagonal),
            normal,
        })
        .collect()
}

/// Times shadow rays towards the light as packets: the hit points of one primary packet, in
/// order, as the renderer traces them.
fn time_shadow_packets(
    scene: &PreparedScene,
    view: &FrameView,
    traced: &[(RayPacket, [PacketHit; PACKET_RAYS])],
    towards: Option<Vec3>,
) -> Pass {
    let packets: Vec<Vec<Vec3>> = traced
        .par_iter()
        .map_init(
            || scene.tracer(),
            |tracer, (packet, hits)| {
                (0..packet.len())
                    .filter_map(|i| {
                        let hit = hits[i].slot().map(|slot| Hit { t: hits[i].t, slot })?;
                        let (p, n) = surface(tracer, view.rays.eye, packet.direction(i), hit);
                        Some(offset_origin(p, n, scene.diagonal))
                    })
                    .collect()
            },
        )
        .collect();
    let t_packets = Instant::now();
    let shadow_packets: u64 = match towards {
        Some(l) => packets
            .par_iter()
            .map_init(
                || scene.tracer(),
                |tracer, starts| {
                    let mut packet = RayPacket::from_rays(starts.iter().map(|&o| (o, l)));
                    std::hint::black_box(tracer.occluded_lanes(&mut packet));
                    starts.len() as u64
                },
            )
            .sum(),
        None => 0,
    };
    Pass {
        rays: shadow_packets,
        seconds: t_packets.elapsed().as_secs_f64(),
    }
}

/// Times the same shadow rays one by one.
fn time_shadow_rays(scene: &PreparedScene, starts: &[Start], towards: Option<Vec3>) -> Pass {
    let t1 = Instant::now();
    let shadow_rays: u64 = match towards {
        Some(l) => starts
            .par_iter()
            .map_init(
                || scene.tracer(),
                |tracer, s| {
                    let ray = Ray::new(s.origin, l);
                    std::hint::black_box(tracer.occluded(&ray, 0.0, f32::INFINITY));
                    1u64
                },
            )
            .sum(),
        None => 0,
    };
    Pass {
        rays: shadow_rays,
        seconds: t1.elapsed().as_secs_f64(),
    }
}

/// Times the same ambient-occlusion directions as [`time_ambient`], those of each start traced
/// together as packets of up to 64 from their common origin (to `from`'s reach; packets start
/// at t = 0).
fn time_ambient_packets(
    scene: &PreparedScene,
    view: &FrameView,
    starts: &[Start],
    (ao_samples, reach): (u32, f32),
    from: AoFrom,
) -> Pass {
    time_ambient_with(scene, view, starts, ao_samples, |tracer, s, directions| {
        let (o, _, t_max) = from(s, reach);
        let mut directions = directions.peekable();
        while directions.peek().is_some() {
            let chunk = directions.by_ref().take(PACKET_RAYS);
            let mut packet = RayPacket::from_origin(o, chunk, t_max);
            std::hint::black_box(tracer.occluded_lanes(&mut packet));
        }
    })
}

/// Times `ao_samples` ambient-occlusion rays from each start, each from where and to where
/// `from` says (`reach` the renderer's).
fn time_ambient(
    scene: &PreparedScene,
    view: &FrameView,
    starts: &[Start],
    (ao_samples, reach): (u32, f32),
    from: AoFrom,
) -> Pass {
    time_ambient_with(scene, view, starts, ao_samples, |tracer, s, directions| {
        let (o, t_min, t_max) = from(s, reach);
        for d in directions {
            std::hint::black_box(tracer.occluded(&Ray::new(o, d), t_min, t_max));
        }
    })
}

/// Times `trace`, handed each start and its `ao_samples` cosine-distributed directions (the
/// same for every way of tracing them), on every thread of the pool.
fn time_ambient_with(
    scene: &PreparedScene,
    view: &FrameView,
    starts: &[Start],
    ao_samples: u32,
    trace: impl Fn(&mut crate::Tracer<'_>, &Start, &mut dyn Iterator<Item = Vec3>) + Sync,
) -> Pass {
    let t0 = Instant::now();
    let ao_rays: u64 = starts
        .par_iter()
        .enumerate()
        .map_init(
            || scene.tracer(),
            |tracer, (i, s)| {
                let hemisphere = Hemisphere::around(s.normal);
                let seed = PixelSeed::new(view.frame, i as u32, 0);
                let mut directions = (0..ao_samples).map(|k| {
                    let mut stream = seed.stream(k);
                    hemisphere.cosine_direction(&mut stream)
                });
                trace(tracer, s, &mut directions);
                ao_samples as u64
            },
        )
        .sum();
    Pass {
        rays: ao_rays,
        seconds: t0.elapsed().as_secs_f64(),
    }
}
