//! Shadow rays of a packet's primary hits, traced as packets: one packet per light, from every
//! hit point that faces the light towards it.
//!
//! Hit points of one 8×8 block lie close together and their rays share a direction
//! (directional light) or an end (point light), so they traverse the same few BVH nodes; as
//! single rays they cost five times a primary ray. The answers are the very ones single rays
//! give (same rays, same intervals, same triangle test; see `accel_packet`'s tests), so pixels
//! do not change, only the time.

use super::cut::CutPlanes;
use super::packet::{RayPacket, PACKET_RAYS};
use super::shade::{faces_light, hit_frame, offset_origin, towards_light, SurfaceHit};
use super::{FrameView, PreparedScene};
use crate::geometry::Ray;
use glam::Vec3;

/// Lights whose shadows are traced as packets; further lights use single rays.
pub const PACKET_LIGHTS: usize = 64;

/// For each lane with a surface: bit k set when light k (of the first [`PACKET_LIGHTS`]) is
/// blocked. Lanes whose surface faces away from a light have no shadow ray for it, and their
/// bit is unused.
pub fn primary_shadows(
    scene: &PreparedScene,
    view: &FrameView,
    eye: Vec3,
    directions: &[Vec3],
    surfaces: &[Option<SurfaceHit>],
    stack: &mut Vec<u32>,
) -> [u64; PACKET_RAYS] {
    let mut blocked = [0u64; PACKET_RAYS];
    let frames: [Option<(Vec3, Vec3)>; PACKET_RAYS] = std::array::from_fn(|i| {
        let hit = (*surfaces.get(i)?)?;
        let (point, normal) = hit_frame(scene, eye, directions[i], hit);
        Some((point, normal))
    });
    let cuts: &CutPlanes = &view.params.cuts;
    let mut lanes = [0usize; PACKET_RAYS];
    for (k, light) in scene.lights().iter().enumerate().take(PACKET_LIGHTS) {
        let mut count = 0;
        let mut rays = [(Vec3::ZERO, Vec3::ZERO, 0.0f32); PACKET_RAYS];
        for (i, frame) in frames.iter().enumerate() {
            let Some((point, normal)) = *frame else {
                continue;
            };
            let (towards, reach, _) = towards_light(light, point);
            if faces_light(normal, towards).is_none() {
                continue;
            }
            let start = offset_origin(point, normal, scene.diagonal);
            rays[count] = (start, towards, reach);
            lanes[count] = i;
            count += 1;
        }
        if count == 0 {
            continue;
        }
        let mut packet = RayPacket::from_rays(rays[..count].iter().map(|&(o, d, _)| (o, d)));
        for (j, &(start, towards, reach)) in rays[..count].iter().enumerate() {
            let (t_min, t_cut) = cuts.interval(start, towards);
            packet.t_min[j] = t_min;
            packet.t_max[j] = reach.min(t_cut);
        }
        let mut hit = scene.accel.occluded_lanes(&mut packet, stack);
        if let Some(spheres) = scene.spheres.as_ref() {
            for (j, &(start, towards, _)) in rays[..count].iter().enumerate() {
                let (t_min, t_max) = (packet.t_min[j], packet.t_max[j]);
                if hit >> j & 1 == 0
                    && t_min <= t_max
                    && spheres.occluded(
                        &Ray::new(start, towards),
                        t_min,
                        t_max,
                        view.params.crop,
                        stack,
                    )
                {
                    hit |= 1 << j;
                }
            }
        }
        for (j, &lane) in lanes[..count].iter().enumerate() {
            if hit >> j & 1 == 1 {
                blocked[lane] |= 1 << k;
            }
        }
    }
    blocked
}
