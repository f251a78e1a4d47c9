//! Where the renderer's coordinates sit in the world: a mesh 10⁶ from the origin would lose its
//! shape in f32 (there the grid of representable values is 0.0625 wide), so scenes are read in
//! f64 and moved to a local origin near their middle before they become f32. Everything given
//! in world coordinates — a camera from the command line, a cutting plane — is moved the same
//! way, in f64, before it meets the scene.

use glam::{DVec3, Vec3};
use serde::{Deserialize, Serialize};

/// The translation from world to render coordinates: `render = world - world_origin`.
///
/// # Examples
///
/// ```
/// use glam::{DVec3, Vec3};
/// use tessera_model::local_origin::RenderFromWorld;
///
/// let frame = RenderFromWorld::new(DVec3::splat(1e6));
/// // 1e6 + 0.3 has no f32 of its own (its neighbours are 0.0625 apart), but 0.3 does.
/// assert_eq!(frame.point(DVec3::splat(1e6 + 0.3)), Vec3::splat(0.3));
/// assert_eq!(frame.world_point(Vec3::splat(0.3)), DVec3::splat(1e6 + 0.3000000119));
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RenderFromWorld {
    /// The world point that is the renderer's origin.
    pub world_origin: DVec3,
}

impl RenderFromWorld {
    /// Render coordinates are world coordinates: for scenes near the origin.
    pub const IDENTITY: RenderFromWorld = RenderFromWorld {
        world_origin: DVec3::ZERO,
    };

    /// The frame whose origin is the world point `world_origin`.
    pub fn new(world_origin: DVec3) -> Self {
        RenderFromWorld { world_origin }
    }

    /// The middle of the box around `points`, as the local origin for them (identity for none).
    pub fn centred_on(points: &[DVec3]) -> Self {
        let Some(first) = points.first() else {
            return Self::IDENTITY;
        };
        let (lo, hi) = points
            .iter()
            .fold((*first, *first), |(lo, hi), p| (lo.min(*p), hi.max(*p)));
        Self::new((lo + hi) * 0.5)
    }

    /// A world point in render coordinates, rounded to f32 only after the subtraction.
    pub fn point(&self, world: DVec3) -> Vec3 {
        (world - self.world_origin).as_vec3()
    }

    /// A render-coordinate point back in the world (e.g. to export a mesh).
    pub fn world_point(&self, render: Vec3) -> DVec3 {
        render.as_dvec3() + self.world_origin
    }

    /// The plane `normal · p = distance` in world coordinates, as the same plane in render
    /// coordinates (its normal is unchanged by a translation).
    pub fn plane_distance(&self, normal: Vec3, distance: f64) -> f32 {
        (distance - normal.as_dvec3().dot(self.world_origin)) as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_plane_keeps_its_points() {
        let frame = RenderFromWorld::new(DVec3::new(1e6, -2e6, 3e6));
        let n = Vec3::new(0.0, 0.6, 0.8);
        let world = DVec3::new(1e6 + 1.0, -2e6 + 2.0, 3e6 + 0.5);
        let d = n.as_dvec3().dot(world);
        let local = frame.point(world);
        assert!((n.dot(local) - frame.plane_distance(n, d)).abs() < 1e-5);
    }

    #[test]
    fn the_centre_of_the_points_is_the_origin() {
        let frame = RenderFromWorld::centred_on(&[DVec3::splat(1e6), DVec3::splat(1e6 + 2.0)]);
        assert_eq!(frame.world_origin, DVec3::splat(1e6 + 1.0));
        assert_eq!(RenderFromWorld::centred_on(&[]), RenderFromWorld::IDENTITY);
    }
}
