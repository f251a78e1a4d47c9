//! The probe of the control interface: the volume's value and world position under a wall
//! pixel. The master keeps the scene's volume (bricked, as the render nodes hold it) for it;
//! a scene without a volume keeps nothing and refuses probes.

use std::sync::Arc;
use tessera_core::master::VolumeProbe;
use tessera_model::camera::Camera;
use tessera_model::local_origin::RenderFromWorld;
use tessera_model::params::RenderParams;
use tessera_model::wall::WallLayout;
use tessera_protocol::control::{ProbeHit, Refusal};
use tessera_render::scene::Scene;
use tessera_render::volume::PreparedVolume;
use tessera_render::PixelRays;

/// The scene's volume, for probing.
pub struct Prober {
    volume: PreparedVolume,
    frame: RenderFromWorld,
}

impl std::fmt::Debug for Prober {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Prober").finish_non_exhaustive()
    }
}

impl Prober {
    /// A prober for `scene`'s volume; None for a scene without one.
    pub fn of_scene(scene: &Scene) -> Option<Arc<Self>> {
        let volume = scene.volume.as_ref()?;
        Some(Arc::new(Prober {
            volume: PreparedVolume::new(volume, &scene.render_from_world),
            frame: scene.render_from_world,
        }))
    }
}

impl VolumeProbe for Prober {
    fn probe(
        &self,
        camera: &Camera,
        params: &RenderParams,
        wall: &WallLayout,
        (x, y): (u32, u32),
    ) -> Result<Option<ProbeHit>, Refusal> {
        let (w, h) = (wall.width(), wall.height());
        if x >= w || y >= h {
            return Err(Refusal::OutsideWall {
                x,
                y,
                width: w,
                height: h,
            });
        }
        let rays = PixelRays::new(camera, w, h);
        let dir = rays.direction_at(x, y, 0.5, 0.5);
        let interval = params.cuts().interval(rays.eye, dir);
        if interval.0 > interval.1 {
            return Ok(None);
        }
        Ok(self
            .volume
            .probe(params.volume(), rays.eye, dir, interval)
            .map(|(t, value)| ProbeHit {
                world: self.frame.world_point(rays.eye + dir * t).to_array(),
                value,
                distance: t,
            }))
    }
}
