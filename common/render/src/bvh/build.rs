//! Building the tree: the binned SAH build (`binned`) over the scene's triangles, collapsed
//! 8-wide (`collapse`), with the triangles copied in leaf order. The build is deterministic on
//! any number of threads, so every render node makes the same tree.

use crate::bvh::binned::{self, Prim};
use crate::bvh::collapse::collapse;
use crate::bvh::node::LeafTriangle;
use crate::bvh::tree::Accel;
use crate::scene::Scene;
use rayon::prelude::*;

impl Accel {
    /// Builds the BVH over all triangles of `scene`. The build is deterministic: the same scene
    /// gives the same tree on every node, which keeps tiles bit-identical wherever rendered.
    pub fn build(scene: &Scene) -> Accel {
        let corners = |t: &[u32; 3]| t.map(|v| scene.positions[v as usize]);
        let mut prims: Vec<Prim> = (scene.triangles.par_iter())
            .map(|t| Prim::new(corners(t)))
            .collect();
        let mut order: Vec<u32> = (0..prims.len() as u32).collect();
        let (nodes, depth) = binned::build(&mut prims, &mut order);
        drop(prims);
        // Collapsed before the leaf triangles are made, so the binary tree is gone by then.
        let wide = collapse(&nodes);
        drop(nodes);
        let triangles = (order.par_iter())
            .map(|&i| {
                let [a, b, c] = corners(&scene.triangles[i as usize]);
                LeafTriangle { a, b, c }
            })
            .collect();
        Self::from_parts(wide, triangles, order, depth)
    }

    /// A short name of the build, for benchmark output and the cache key.
    pub const BUILDER: &'static str = "binned-sah";
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bvh::node::{EMPTY, WIDTH};
    use crate::geometry::Bounds;
    use crate::scene::knot_scene;

    /// breaks ties between equally near hits, so another tree could mean other pixels.
    #[test]
    fn the_build_is_the_same_on_any_number_of_threads() {
        let scene = knot_scene(400, 48);
        let build = |threads| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| Accel::build(&scene))
        };
        let one = build(1);
        for threads in [2, 3, 7] {
            let many = build(threads);
            assert_eq!(
                bytemuck::cast_slice::<_, u8>(&many.wide),
                bytemuck::cast_slice::<_, u8>(&one.wide),
                "{threads} threads"
            );
            assert_eq!(
                bytemuck::cast_slice::<_, u8>(&many.triangles),
                bytemuck::cast_slice::<_, u8>(&one.triangles),
                "{threads} threads"
            );
        }
    }

    #[test]
    fn the_bounds_are_the_triangles_box() {
        let scene = knot_scene(64, 8);
        let accel = Accel::build(&scene);
        let mut expected = Bounds::EMPTY;
        for t in &accel.triangles {
            [t.a, t.b, t.c].into_iter().for_each(|p| expected.grow(p));
        }
        assert_eq!(accel.bounds(), expected);
    }

    #[test]
    fn build_is_deterministic() {
        let scene = knot_scene(200, 24);
        let (a, b) = (Accel::build(&scene), Accel::build(&scene));
        assert_eq!(a.scene_index, b.scene_index);
        assert_eq!(
            bytemuck::cast_slice::<_, u8>(&a.wide),
            bytemuck::cast_slice::<_, u8>(&b.wide)
        );
    }

    #[test]
    fn every_leaf_appears_once_in_the_collapsed_tree() {
        let accel = Accel::build(&knot_scene(120, 16));
        let mut slots: Vec<u32> = accel
            .wide
            .iter()
            .flat_map(|n| {
                (0..WIDTH)
                    .filter(|&k| n.count[k] != EMPTY && n.count[k] > 0)
                    .flat_map(move |k| n.child[k]..n.child[k] + n.count[k])
            })
            .collect();
        slots.sort_unstable();
        assert_eq!(slots, (0..accel.triangles.len() as u32).collect::<Vec<_>>());
    }

    /// The collapse fills wide nodes and joins small subtrees into leaves: the greedy one it
    /// replaced left the knot's nodes half full (4.2 children on average, leaves of 1.3; now 7.3 and
    /// 1.9).
    #[test]
    fn wide_nodes_are_nearly_full_and_leaves_join_small_subtrees() {
        let accel = Accel::build(&knot_scene(400, 48));
        let children: usize = accel
            .wide
            .iter()
            .map(|n| n.count.iter().filter(|&&c| c != EMPTY).count())
            .sum();
        let leaves: Vec<u32> = accel
            .wide
            .iter()
            .flat_map(|n| n.count.into_iter().filter(|&c| c != EMPTY && c > 0))
            .collect();
        let fill = children as f64 / accel.wide.len() as f64;
        let leaf = accel.triangles.len() as f64 / leaves.len() as f64;
        eprintln!(
            "{} wide nodes, {fill:.2} children each, leaves of {leaf:.2}",
            accel.wide.len()
        );
        assert!(fill > 6.5, "{fill:.2} children per wide node");
        assert!(leaf > 1.6, "{leaf:.2} triangles per leaf");
    }
}
