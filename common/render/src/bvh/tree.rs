//! The tree as a whole ([`Accel`]): a binary BVH built by obvhs (`build`), collapsed 8-wide
//! (`collapse`), with the triangles stored in leaf order, so a leaf's triangles are contiguous
//! in memory. The binary tree lives only during the build: the cache stores the 8-wide one, so
//! loading it makes no second tree. Searching it is the traversals' (`traverse_ray`,
//! `traverse_packet`), which add their methods to [`Accel`] there.

use crate::bvh::memory::Resident;
use crate::bvh::node::{LeafTriangle, WideNode, EMPTY, WIDTH};
use crate::geometry::Bounds;
use glam::Vec3;

/// The scene's bounding volume hierarchy: obvhs builds it, and it is flattened here into
/// depth-first nodes with the triangles copied in leaf order, so traversal reads memory in the
/// order it visits it. Single rays use [`Accel::closest_hit`] and [`Accel::occluded`], 8×8
/// packets [`Accel::closest_hits`] and [`Accel::occluded_lanes`], all on the 8-wide collapse of
/// the tree.
///
/// # Examples
///
/// ```
/// use glam::Vec3;
/// use tessera_render::bvh::Accel;
/// use tessera_render::geometry::Ray;
/// use tessera_render::scene::knot_scene;
///
/// let scene = knot_scene(64, 8);
/// let bvh = Accel::build(&scene);
/// assert_eq!(bvh.triangles.len(), scene.triangles.len());
///
/// // A ray from above the scene, straight down at its centre, hits something...
/// let bounds = scene.bounds();
/// let top = Vec3::new(bounds.center().x, bounds.max.y + 1.0, bounds.center().z);
/// let mut stack = bvh.new_stack();
/// let down = Ray::new(top, Vec3::NEG_Y);
/// let hit = bvh.closest_hit(&down, 0.0, f32::INFINITY, &mut stack).expect("the floor at least");
/// // ...that a shadow ray towards it finds too, and the triangle is the scene's own.
/// assert!(bvh.occluded(&down, 0.0, hit.t + 1e-3, &mut stack));
/// assert!((bvh.scene_index[hit.slot as usize] as usize) < scene.triangles.len());
/// // Looking up into the sky, nothing.
/// let up = Ray::new(top, Vec3::Y);
/// assert!(bvh.closest_hit(&up, 0.0, f32::INFINITY, &mut stack).is_none());
/// ```
pub struct Accel {
    /// The tree, 8-wide (see `collapse`), the root first and every node before its children:
    /// what every traversal walks and the cache stores.
    pub wide: Vec<WideNode>,
    /// The triangles' corners in leaf order (render coordinates): leaf slots index this.
    pub triangles: Vec<LeafTriangle>,
    /// Scene triangle index of each leaf slot.
    pub scene_index: Vec<u32>,
    max_depth: usize,
}

impl Accel {
    /// Reassembles a BVH from its arrays (see `cache`).
    pub fn from_parts(
        wide: Vec<WideNode>,
        triangles: Vec<LeafTriangle>,
        scene_index: Vec<u32>,
        max_depth: usize,
    ) -> Self {
        Accel {
            wide,
            triangles,
            scene_index,
            max_depth: max_depth.clamp(64, 1 << 16),
        }
    }

    /// Depth of the binary tree, at least 64: what traversal stacks are sized for.
    pub fn max_depth(&self) -> usize {
        self.max_depth
    }

    /// The box around every triangle, from the wide tree's root.
    pub fn bounds(&self) -> Bounds {
        let mut bounds = Bounds::EMPTY;
        if let Some(root) = self.wide.first() {
            for k in (0..WIDTH).filter(|&k| root.count[k] != EMPTY) {
                bounds.grow(Vec3::new(root.lo[0][k], root.lo[1][k], root.lo[2][k]));
                bounds.grow(Vec3::new(root.hi[0][k], root.hi[1][k], root.hi[2][k]));
            }
        }
        bounds
    }

    /// A traversal stack deep enough for this tree; reuse it across rays.
    pub fn new_stack(&self) -> Vec<u32> {
        Vec::with_capacity(self.max_depth * 2)
    }

    /// The tree and triangles as a traversal reads them.
    #[inline(always)]
    pub fn resident(&self) -> Resident<'_> {
        Resident {
            wide: &self.wide,
            triangles: &self.triangles,
        }
    }
}
