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

/// The tree's cost by the surface area heuristic as Embree reports its own (`verbose=2`,
/// `bvh_statistics.cpp`): what a ray through the root's box, uniform over directions, expects
/// to visit. Tree quality compared with Embree's in its own terms.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TreeSah {
    /// Inner nodes: their boxes' areas over the root's, the root counted once.
    pub nodes: f64,
    /// Leaves: their boxes' areas over the root's, each times its blocks of 4 triangles
    /// (Embree's `triangle4` leaves test four at a time).
    pub leaves: f64,
    /// Leaves in the tree.
    pub leaf_count: usize,
    /// Triangles per leaf on average.
    pub leaf_size: f64,
}

impl Accel {
    /// The tree's [`TreeSah`]: inner nodes' box areas, and leaves' times their blocks of 4
    /// triangles, over the root's.
    ///
    /// ```
    /// use tessera_render::bvh::Accel;
    /// use tessera_render::scene::knot_scene;
    ///
    /// let sah = Accel::build(&knot_scene(64, 8)).sah();
    /// assert!(sah.nodes >= 1.0 && sah.leaves > 0.0);
    /// ```
    pub fn sah(&self) -> TreeSah {
        let half_area = |lo: Vec3, hi: Vec3| {
            let d = (hi - lo).as_dvec3();
            d.x * d.y + d.y * d.z + d.z * d.x
        };
        let root = self.bounds();
        let root_area = half_area(root.min, root.max);
        let (mut nodes, mut leaves, mut leaf_count, mut triangles) = (root_area, 0.0, 0, 0);
        for node in &self.wide {
            for k in (0..WIDTH).filter(|&k| node.count[k] != EMPTY) {
                let lo = Vec3::new(node.lo[0][k], node.lo[1][k], node.lo[2][k]);
                let hi = Vec3::new(node.hi[0][k], node.hi[1][k], node.hi[2][k]);
                match node.count[k] {
                    0 => nodes += half_area(lo, hi),
                    count => {
                        leaves += half_area(lo, hi) * count.div_ceil(4) as f64;
                        leaf_count += 1;
                        triangles += count as usize;
                    }
                }
            }
        }
        let over_root = |a: f64| if root_area > 0.0 { a / root_area } else { 0.0 };
        TreeSah {
            nodes: over_root(nodes),
            leaves: over_root(leaves),
            leaf_count,
            leaf_size: triangles as f64 / leaf_count.max(1) as f64,
        }
    }
}
