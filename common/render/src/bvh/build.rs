//! Building the tree: obvhs' binary BVH over the scene's triangles, with the preset that suits
//! the scene's size, flattened into [`BvhNode`]s and leaf-ordered triangles; groups of triangles
//! with equal boxes are built apart (`coincident`). The build is deterministic on any number of
//! threads, so every render node makes the same tree.

use crate::bvh::coincident::{coincident_groups, flatten_expanding};
use crate::bvh::collapse::collapse;
use crate::bvh::layout::depth_first;
use crate::bvh::node::{BvhNode, LeafTriangle};
use crate::bvh::tree::Accel;
use crate::scene::Scene;
use obvhs::bvh2::builder::build_bvh2_from_tris;
use obvhs::triangle::Triangle;
use obvhs::BvhBuildParams;
use rayon::prelude::*;
use std::time::Duration;

impl Accel {
    /// Builds the BVH over all triangles of `scene`. The build is deterministic: the same scene
    /// gives the same tree on every node, which keeps tiles bit-identical wherever rendered.
    pub fn build(scene: &Scene) -> Accel {
        if scene.triangles.is_empty() {
            return Accel::from_parts(Vec::new(), Vec::new(), Vec::new(), 64);
        }
        let tris = obvhs_triangles(scene);
        let groups = coincident_groups(&tris);
        if !groups.is_empty() {
            return Self::build_with_groups(&tris, &groups);
        }
        let bvh = build_bvh2_from_tris(&tris, Self::preset(tris.len()), &mut Duration::default());
        // obvhs' own arrays go as soon as ours are made: the build's peak is its sum.
        let obvhs::bvh2::Bvh2 {
            nodes,
            primitive_indices,
            max_depth,
            ..
        } = bvh;
        let (ours, order) = depth_first(nodes, |n| n.into(), primitive_indices);
        Self::from_order(ours, &tris, order, max_depth)
    }

    /// The build when many triangles share one box (see `coincident`): each group goes to
    /// obvhs as one triangle and comes back as a balanced subtree.
    fn build_with_groups(tris: &[Triangle], groups: &[Vec<u32>]) -> Accel {
        let (nodes, order, depth) = grouped_tree(tris, groups);
        tracing::info!(
            "{} triangles in {} groups with equal boxes: each built as one balanced subtree",
            groups.iter().map(Vec::len).sum::<usize>(),
            groups.len()
        );
        Self::from_order(nodes, tris, order, depth)
    }

    /// The accelerator from binary nodes laid out by `layout::depth_first` and the scene
    /// triangle of each leaf slot.
    fn from_order(nodes: Vec<BvhNode>, tris: &[Triangle], order: Vec<u32>, depth: usize) -> Accel {
        // Collapsed before the leaf triangles are made, so the binary tree is gone by then.
        let wide = collapse(&nodes);
        drop(nodes);
        let triangles = order
            .par_iter()
            .map(|&i| {
                let t = &tris[i as usize];
                LeafTriangle {
                    a: t.v0.into(),
                    b: t.v1.into(),
                    c: t.v2.into(),
                }
            })
            .collect();
        Self::from_parts(wide, triangles, order, depth)
    }

    /// The obvhs preset for a scene of `triangles`: the best tree that still builds in about a
    /// second on a wall node; bigger scenes trade tree quality for build time.
    pub fn preset(triangles: usize) -> BvhBuildParams {
        match triangles {
            // Small leaves: on the 70k-triangle bunny, leaves of up to 4 against obvhs' medium
            // or fast presets (leaves of 8) made shadow packets 25 % and AO rays 10 % faster,
            // primary rays 4 % slower, at about twice the bytes per triangle (which a mesh this
            // size can afford). On multi-million-triangle meshes the larger tree cost more in
            // cache misses than it saved (primary rays on the 4.2M knot 17.6 -> 12.1 Mrays/s),
            // so they take larger leaves.
            //
            // No leaf collapse in obvhs at all (leaves of 1, which also skips the second
            // reinsertion pass): our own collapse makes the wide tree's leaves of up to 8
            // anyway, from the binary tree's costs. obvhs' collapse was a fifth of the build;
            // without it the dragon built at 2.17-2.25 -> 2.55-2.56 Mtris/s and the CT bone at
            // 2.48-2.58 -> 2.68-2.78 (2 threads), with the same bytes per triangle and peak
            // memory (the mesh's loading sets it) and rays the same within noise.
            //
            // And obvhs' fast search (PLOC distance 6 against medium's 14, reinsertion of 2 %
            // against 5 %): the wide tree our collapse makes from it is no slower, and faster
            // for primary rays. 1 thread, 960x540, 2 alternated rounds against medium's
            // search: primary rays on the bunny 45.2-45.7 -> 53.5 Mrays/s, the CT bone
            // 25.6-26.2 -> 27.6, the dragon 17.7-17.9 -> 18.0-18.3; eye-light frames 13 %,
            // 5 % and 2 % faster; AO and single shadow rays the same within 2 %. No
            // reinsertion at all built faster still but lost 3 % of the bunny's AO; the
            // minimum search lost 4 % of the dragon's primary rays.
            0..1_000_000 => BvhBuildParams {
                max_prims_per_leaf: 1,
                ..BvhBuildParams::fast_build()
            },
            // Leaves of up to 16 (obvhs' fast preset has 8): on the 4.2M knot the build ran
            // 1.97 -> 2.5-2.7 Mtris/s (2 threads) with primary, shadow and AO rays unchanged
            // within noise, since packets test a leaf against all their lanes at once.
            1_000_000..8_000_000 => BvhBuildParams {
                max_prims_per_leaf: 16,
                ..BvhBuildParams::fast_build()
            },
            _ => BvhBuildParams::very_fast_build(),
        }
    }

    /// A short name of [`Accel::preset`] for a scene of `triangles`, for benchmark output and the
    /// cache key.
    pub fn preset_name(triangles: usize) -> &'static str {
        match triangles {
            0..1_000_000 => "fast-leaf1",
            1_000_000..8_000_000 => "fast-leaf16",
            _ => "very_fast",
        }
    }
}

/// The binary tree over `tris` when `groups` of them share one box, laid out as
/// `layout::depth_first` lays a tree out (the flattening does that itself), with the scene triangle
/// of each leaf slot and a bound on the depth.
fn grouped_tree(tris: &[Triangle], groups: &[Vec<u32>]) -> (Vec<BvhNode>, Vec<u32>, usize) {
    let mut grouped = vec![false; tris.len()];
    for g in groups {
        for &m in g {
            grouped[m as usize] = true;
        }
    }
    let mut input: Vec<u32> = (0..tris.len() as u32)
        .filter(|&i| !grouped[i as usize])
        .collect();
    let mut group_of = vec![None; input.len()];
    for (g, members) in groups.iter().enumerate() {
        input.push(members[0]);
        group_of.push(Some(g as u32));
    }
    drop(grouped);
    let subset: Vec<Triangle> = input.iter().map(|&i| tris[i as usize]).collect();
    let bvh = build_bvh2_from_tris(
        &subset,
        Accel::preset(subset.len()),
        &mut Duration::default(),
    );
    drop(subset);
    let (nodes, order) = flatten_expanding(&bvh, tris, &input, &group_of, groups);
    let largest = groups.iter().map(Vec::len).max().unwrap_or(1);
    let depth = bvh.max_depth + 2 * (usize::BITS - largest.leading_zeros()) as usize + 2;
    (nodes, order, depth)
}

/// The scene's triangles as obvhs takes them, made on every thread: one thread alone took
/// 14 ms of the dragon's build, and as much for the leaf triangles.
pub(super) fn obvhs_triangles(scene: &Scene) -> Vec<Triangle> {
    scene
        .triangles
        .par_iter()
        .map(|t| Triangle {
            v0: scene.positions[t[0] as usize].into(),
            v1: scene.positions[t[1] as usize].into(),
            v2: scene.positions[t[2] as usize].into(),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bvh::node::{EMPTY, WIDTH};
    use crate::geometry::Bounds;
    use crate::scene::knot_scene;

    /// The grouped build's flattening already lays the tree out depth first: laying it out
    /// again changes nothing.
    #[test]
    fn the_grouped_tree_is_laid_out_depth_first() {
        let mut scene = knot_scene(64, 12);
        let base = scene.positions.len() as u32;
        let centre = scene.bounds().center();
        scene
            .positions
            .extend([centre, centre + glam::Vec3::X, centre + glam::Vec3::Z]);
        scene.triangles.extend([[base, base + 1, base + 2]; 500]);
        let tris = obvhs_triangles(&scene);
        let groups = coincident_groups(&tris);
        assert_eq!(groups.len(), 1);
        let (nodes, order, _) = grouped_tree(&tris, &groups);
        let (again, again_order) = depth_first(nodes.clone(), |n| *n, order.clone());
        assert_eq!(
            bytemuck::cast_slice::<_, u8>(&again),
            bytemuck::cast_slice::<_, u8>(&nodes)
        );
        assert_eq!(again_order, order);
    }

    /// The collapse fills its table in halves at once for large subtrees: the wide tree is the
    /// same bit for bit as from one sweep, whichever size is split.
    #[test]
    fn the_collapse_is_the_same_swept_in_halves() {
        let tris = obvhs_triangles(&knot_scene(96, 12));
        let bvh = build_bvh2_from_tris(&tris, Accel::preset(tris.len()), &mut Duration::default());
        let (nodes, _) = depth_first(bvh.nodes, |n| n.into(), bvh.primitive_indices);
        let one = crate::bvh::collapse::collapse_with(&nodes, usize::MAX);
        for parallel_from in [4, 64, 1000] {
            let halves = crate::bvh::collapse::collapse_with(&nodes, parallel_from);
            assert_eq!(
                bytemuck::cast_slice::<_, u8>(&halves),
                bytemuck::cast_slice::<_, u8>(&one),
                "split from {parallel_from} nodes"
            );
        }
    }

    /// Render nodes with different core counts must build the same tree: the leaf order
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
