//! Shadow rays of a packet's primary hits, traced as packets: one packet per light, from every
//! hit point that faces the light towards it.
//!
//! Hit points of one 8×8 block lie close together and their rays share a direction
//! (directional light) or an end (point light), so they traverse the same few BVH nodes; as
//! single rays they cost five times a primary ray. The answers are the very ones single rays
//! give (same rays, same intervals, same triangle test; see `bvh::traverse_packet`'s tests), so
//! pixels do not change, only the time. What a primary hit is, and the way to each light, are
//! `surface_hit`'s, which shading reads too.

use crate::geometry::Ray;
use crate::packet::{RayPacket, PACKET_RAYS};
use crate::prepared::{FrameView, PreparedScene};
use crate::surface_hit::{
    faces_light, hit_frame, iso_occludes, leaving_point, towards_light, PrimaryHit, SurfaceHit,
    PACKET_LIGHTS,
};
use crate::tracer::Tracer;
use glam::Vec3;
use tessera_model::cut::CutPlanes;

/// For each lane with a surface: its hit, with the lights that are blocked.
pub fn primary_shadows(
    scene: &PreparedScene,
    view: &FrameView,
    eye: Vec3,
    directions: &[Vec3],
    surfaces: &[Option<SurfaceHit>],
    tracer: &mut Tracer<'_>,
) -> [Option<PrimaryHit>; PACKET_RAYS] {
    let mut hits: [Option<PrimaryHit>; PACKET_RAYS] = std::array::from_fn(|i| {
        let hit = (*surfaces.get(i)?)?;
        let (point, normal) = hit_frame(scene, tracer, eye, directions[i], hit);
        Some(PrimaryHit {
            point,
            normal,
            start: leaving_point(scene, hit, point, normal),
            blocked: 0,
        })
    });
    let mut lanes = [0usize; PACKET_RAYS];
    for (k, light) in view.lights(scene).iter().enumerate().take(PACKET_LIGHTS) {
        let mut count = 0;
        let mut rays = [(Vec3::ZERO, Vec3::ZERO, 0.0f32); PACKET_RAYS];
        for (i, hit) in hits.iter().enumerate() {
            let Some(hit) = hit else {
                continue;
            };
            let (towards, reach, _) = towards_light(light, hit.point);
            if faces_light(hit.normal, towards).is_none() {
                continue;
            }
            rays[count] = (hit.start, towards, reach);
            lanes[count] = i;
            count += 1;
        }
        if count == 0 {
            continue;
        }
        let occluded = blocked(scene, view, &rays[..count], tracer);
        for (j, &lane) in lanes[..count].iter().enumerate() {
            if let (Some(hit), true) = (hits[lane].as_mut(), occluded >> j & 1 == 1) {
                hit.blocked |= 1 << k;
            }
        }
    }
    hits
}

/// Which of `rays` (start, direction towards a light, distance to it) are blocked before the
/// light, as bits: by triangles, traced as one packet; then, ray by ray for those still
/// free, by particles and iso-surfaces.
fn blocked(
    scene: &PreparedScene,
    view: &FrameView,
    rays: &[(Vec3, Vec3, f32)],
    tracer: &mut Tracer<'_>,
) -> u64 {
    let cuts: &CutPlanes = view.params.cuts();
    let mut packet = RayPacket::from_rays(rays.iter().map(|&(o, d, _)| (o, d)));
    for (j, &(start, towards, reach)) in rays.iter().enumerate() {
        let (t_min, t_cut) = cuts.interval(start, towards);
        packet.t_min[j] = t_min;
        packet.t_max[j] = reach.min(t_cut);
    }
    let mut occluded = tracer.occluded_lanes(&mut packet);
    if let Some(spheres) = scene.spheres.as_ref() {
        for (j, &(start, towards, _)) in rays.iter().enumerate() {
            let (t_min, t_max) = (packet.t_min[j], packet.t_max[j]);
            if occluded >> j & 1 == 0
                && t_min <= t_max
                && tracer.sphere_occluded(
                    spheres,
                    (&Ray::new(start, towards), t_min, t_max),
                    view.params.crop(),
                )
            {
                occluded |= 1 << j;
            }
        }
    }
    if scene.volume.is_some() {
        for (j, &(start, towards, _)) in rays.iter().enumerate() {
            let interval = (packet.t_min[j], packet.t_max[j]);
            if occluded >> j & 1 == 0
                && interval.0 <= interval.1
                && iso_occludes(scene, view, &Ray::new(start, towards), interval, tracer)
            {
                occluded |= 1 << j;
            }
        }
    }
    occluded
}
