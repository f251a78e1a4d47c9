//! The acceleration structure: a binary BVH built by obvhs, flattened into our own node array
//! with the triangles stored in leaf order, so a leaf's triangles are contiguous in memory.
//! Rays walk its 8-wide collapse (`accel_wide`), which shares its leaves: single rays in
//! `accel_wide`, 8×8 packets in `accel_packet`. The binary tree is what obvhs builds and what the
//! cache stores; a render node frees it once the 8-wide one is made.

use crate::bvh::memory::{Resident, TreeMemory};
use crate::bvh::traverse_ray::NodeTest;
use crate::geometry::{Bounds, Ray};
use crate::isa::Isa;
use crate::scene::Scene;
use glam::Vec3;
use obvhs::bvh2::builder::build_bvh2_from_tris;
use obvhs::triangle::Triangle;
use obvhs::BvhBuildParams;
use std::time::Duration;

/// One BVH node. Inner nodes have `count == 0` and children at `first` and `first + 1`;
/// leaves hold triangles `first .. first + count` of [`Accel::triangles`].
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct BvhNode {
    pub min: Vec3,
    pub max: Vec3,
    pub first: u32,
    pub count: u32,
}

/// A triangle's corners, stored in leaf order.
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct LeafTriangle {
    pub a: Vec3,
    pub b: Vec3,
    pub c: Vec3,
}

/// The closest hit found by [`Accel::closest_hit`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    pub t: f32,
    /// Index into [`Accel::triangles`] (leaf order).
    pub slot: u32,
}

/// The scene's bounding volume hierarchy: obvhs builds it, and it is flattened here into
/// depth-first nodes with the triangles copied in leaf order, so traversal reads memory in the
/// order it visits it. Single rays use [`Accel::closest_hit`] and [`Accel::occluded`], 8×8
/// packets the packet traversal in `accel_packet`, both on the 8-wide collapse of the tree.
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
    /// The binary tree as built (and cached); empty once slimmed for rendering.
    pub nodes: Vec<BvhNode>,
    /// The same tree collapsed 8-wide, which every traversal walks (see `accel_wide`).
    pub wide: Vec<crate::bvh::traverse_ray::WideNode>,
    pub triangles: Vec<LeafTriangle>,
    /// Scene triangle index of each leaf slot.
    pub scene_index: Vec<u32>,
    max_depth: usize,
}

impl Accel {
    /// Builds the BVH over all triangles of `scene`. The build is deterministic: the same scene
    /// gives the same tree on every node, which keeps tiles bit-identical wherever rendered.
    pub fn build(scene: &Scene) -> Accel {
        if scene.triangles.is_empty() {
            return Accel::from_parts(Vec::new(), Vec::new(), Vec::new(), 64);
        }
        let tris: Vec<Triangle> = scene
            .triangles
            .iter()
            .map(|t| Triangle {
                v0: scene.positions[t[0] as usize].into(),
                v1: scene.positions[t[1] as usize].into(),
                v2: scene.positions[t[2] as usize].into(),
            })
            .collect();
        let groups = crate::bvh::coincident::coincident_groups(&tris);
        if !groups.is_empty() {
            return Self::build_with_groups(&tris, &groups);
        }
        let bvh = build_bvh2_from_tris(&tris, Self::preset(tris.len()), &mut Duration::default());
        let nodes = bvh.nodes.iter().map(BvhNode::from).collect();
        Self::from_order(nodes, &tris, bvh.primitive_indices, bvh.max_depth)
    }

    /// The build when many triangles share one box (see `accel_coincident`): each group goes to
    /// obvhs as one triangle and comes back as a balanced subtree.
    fn build_with_groups(tris: &[Triangle], groups: &[Vec<u32>]) -> Accel {
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
            Self::preset(subset.len()),
            &mut Duration::default(),
        );
        drop(subset);
        let (nodes, order) =
            crate::bvh::coincident::flatten_expanding(&bvh, tris, &input, &group_of, groups);
        let largest = groups.iter().map(Vec::len).max().unwrap_or(1);
        tracing::info!(
            "{} triangles in {} groups with equal boxes: each built as one balanced subtree",
            groups.iter().map(Vec::len).sum::<usize>(),
            groups.len()
        );
        let depth = bvh.max_depth + 2 * (usize::BITS - largest.leading_zeros()) as usize + 2;
        Self::from_order(nodes, tris, order, depth)
    }

    /// The accelerator from flattened nodes and the scene triangle of each leaf slot.
    fn from_order(nodes: Vec<BvhNode>, tris: &[Triangle], order: Vec<u32>, depth: usize) -> Accel {
        let triangles = order
            .iter()
            .map(|&i| {
                let t = &tris[i as usize];
                LeafTriangle {
                    a: t.v0.into(),
                    b: t.v1.into(),
                    c: t.v2.into(),
                }
            })
            .collect();
        Self::from_parts(nodes, triangles, order, depth)
    }

    /// The obvhs preset for a scene of `triangles`: the best tree that still builds in about a
    /// second on a wall node; bigger scenes trade tree quality for build time.
    pub fn preset(triangles: usize) -> BvhBuildParams {
        match triangles {
            // Leaves of up to 4 and a cheaper collapse: on the 70k-triangle bunny, against
            // obvhs' medium or fast presets (leaves of 8), shadow packets 25 % and AO rays
            // 10 % faster, primary rays 4 % slower, at about twice the bytes per triangle
            // (which a mesh this size can afford). On multi-million-triangle meshes the larger
            // tree cost more in cache misses than it saved (primary rays on the 4.2M knot
            // 17.6 -> 12.1 Mrays/s), so they take larger leaves.
            0..1_000_000 => BvhBuildParams {
                max_prims_per_leaf: 4,
                collapse_traversal_cost: 0.5,
                ..BvhBuildParams::medium_build()
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

    pub fn preset_name(triangles: usize) -> &'static str {
        match triangles {
            0..1_000_000 => "medium-leaf4",
            1_000_000..8_000_000 => "fast-leaf16",
            _ => "very_fast",
        }
    }

    /// Reassembles a BVH from its arrays (see `accel_cache`).
    pub fn from_parts(
        nodes: Vec<BvhNode>,
        triangles: Vec<LeafTriangle>,
        scene_index: Vec<u32>,
        max_depth: usize,
    ) -> Self {
        Accel {
            wide: crate::bvh::traverse_ray::collapse(&nodes),
            nodes,
            triangles,
            scene_index,
            max_depth: max_depth.clamp(64, 1 << 16),
        }
    }

    pub fn max_depth(&self) -> usize {
        self.max_depth
    }

    /// The box around every triangle, from the wide tree's root (which a render node keeps
    /// when it frees the binary tree).
    pub fn bounds(&self) -> Bounds {
        let mut bounds = Bounds::EMPTY;
        if let Some(root) = self.wide.first() {
            for k in (0..crate::bvh::traverse_ray::WIDTH)
                .filter(|&k| root.count[k] != crate::bvh::traverse_ray::EMPTY)
            {
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

    /// The nearest triangle hit in `(t_min, t_max)`. Of hits at the same distance the lowest
    /// slot wins, so the answer depends on the tree, never on the order it is walked in.
    pub fn closest_hit(
        &self,
        ray: &Ray,
        t_min: f32,
        t_max: f32,
        stack: &mut Vec<u32>,
    ) -> Option<Hit> {
        closest_hit(&mut self.resident(), ray, (t_min, t_max), stack)
    }

    /// The portable build of [`Accel::closest_hit`], also what the SIMD builds are tested
    /// against.
    pub fn closest_hit_generic(
        &self,
        ray: &Ray,
        t_min: f32,
        t_max: f32,
        stack: &mut Vec<u32>,
    ) -> Option<Hit> {
        closest_hit_with(
            &mut self.resident(),
            ray,
            (t_min, t_max),
            stack,
            crate::bvh::traverse_ray::enter_mask,
        )
    }

    /// Whether anything blocks the ray in `(t_min, t_max)`; stops at the first blocker.
    pub fn occluded(&self, ray: &Ray, t_min: f32, t_max: f32, stack: &mut Vec<u32>) -> bool {
        occluded(&mut self.resident(), ray, (t_min, t_max), stack)
    }

    /// The portable build of [`Accel::occluded`].
    pub fn occluded_generic(
        &self,
        ray: &Ray,
        t_min: f32,
        t_max: f32,
        stack: &mut Vec<u32>,
    ) -> bool {
        occluded_with(
            &mut self.resident(),
            ray,
            (t_min, t_max),
            stack,
            crate::bvh::traverse_ray::enter_mask,
        )
    }
}

/// The nearest triangle hit in `interval` of a tree in `mem`, on the widest SIMD build this CPU
/// runs (see [`Accel::closest_hit`]).
pub fn closest_hit<M: TreeMemory>(
    mem: &mut M,
    ray: &Ray,
    interval: (f32, f32),
    stack: &mut Vec<u32>,
) -> Option<Hit> {
    #[cfg(target_arch = "x86_64")]
    if Isa::best() != Isa::Portable {
        // SAFETY: best() is a build this CPU runs, and every one above portable has AVX2.
        return unsafe { closest_hit_avx2(mem, ray, interval, stack) };
    }
    closest_hit_with(
        mem,
        ray,
        interval,
        stack,
        crate::bvh::traverse_ray::enter_mask,
    )
}

/// [`closest_hit`] with the wide node tests 8 lanes wide.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn closest_hit_avx2<M: TreeMemory>(
    mem: &mut M,
    ray: &Ray,
    interval: (f32, f32),
    stack: &mut Vec<u32>,
) -> Option<Hit> {
    closest_hit_with(mem, ray, interval, stack, |node, origin, inv, t_far| {
        // SAFETY: this function runs only where the CPU has AVX2.
        unsafe { crate::bvh::traverse_ray::enter_mask_avx2(node, origin, inv, t_far) }
    })
}

/// [`closest_hit`] with `enter` testing the ray against a wide node's children. A leaf is
/// tested in the pieces the memory holds it in (one, unless it straddles two shared blocks):
/// hits compare by distance and then slot, so the pieces give the whole leaf's answer.
#[inline(always)]
fn closest_hit_with<M: TreeMemory>(
    mem: &mut M,
    ray: &Ray,
    (t_min, t_max): (f32, f32),
    stack: &mut Vec<u32>,
    enter: impl NodeTest,
) -> Option<Hit> {
    let mut best: Option<Hit> = None;
    let mut t_far = t_max;
    crate::bvh::traverse_ray::traverse_wide::<true, M>(
        mem,
        enter,
        ray,
        stack,
        &mut t_far,
        |mem, slots, t_far| {
            let mut at = slots.start;
            while at < slots.end {
                let tris = mem.triangles(at..slots.end);
                best = crate::bvh::leaf_ray::closest_hit(ray, tris, at, (t_min, t_max), best);
                at += tris.len() as u32;
            }
            if let Some(b) = best {
                *t_far = b.t;
            }
            false
        },
    );
    best
}

/// Whether anything in `mem`'s tree blocks the ray in `interval`; stops at the first blocker
/// (see [`Accel::occluded`]).
pub fn occluded<M: TreeMemory>(
    mem: &mut M,
    ray: &Ray,
    interval: (f32, f32),
    stack: &mut Vec<u32>,
) -> bool {
    #[cfg(target_arch = "x86_64")]
    if Isa::best() != Isa::Portable {
        // SAFETY: best() is a build this CPU runs, and every one above portable has AVX2.
        return unsafe { occluded_avx2(mem, ray, interval, stack) };
    }
    occluded_with(
        mem,
        ray,
        interval,
        stack,
        crate::bvh::traverse_ray::enter_mask,
    )
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn occluded_avx2<M: TreeMemory>(
    mem: &mut M,
    ray: &Ray,
    interval: (f32, f32),
    stack: &mut Vec<u32>,
) -> bool {
    occluded_with(mem, ray, interval, stack, |node, origin, inv, t_far| {
        // SAFETY: this function runs only where the CPU has AVX2.
        unsafe { crate::bvh::traverse_ray::enter_mask_avx2(node, origin, inv, t_far) }
    })
}

/// [`occluded`] with `enter` testing the ray against a wide node's children.
#[inline(always)]
fn occluded_with<M: TreeMemory>(
    mem: &mut M,
    ray: &Ray,
    (t_min, t_max): (f32, f32),
    stack: &mut Vec<u32>,
    enter: impl NodeTest,
) -> bool {
    let mut t_far = t_max;
    let mut blocked = false;
    crate::bvh::traverse_ray::traverse_wide::<ORDERED_OCCLUSION, M>(
        mem,
        enter,
        ray,
        stack,
        &mut t_far,
        |mem, slots, _| {
            let mut at = slots.start;
            while at < slots.end && !blocked {
                let tris = mem.triangles(at..slots.end);
                blocked = crate::bvh::leaf_ray::any_hit(ray, tris, t_min, t_max);
                at += tris.len() as u32;
            }
            blocked
        },
    );
    blocked
}

/// Whether occlusion rays visit nearer children first (see `traverse_wide`).
const ORDERED_OCCLUSION: bool = false;

impl Hit {
    /// Whether a hit at `t` on `slot` beats `best`: nearer, or as near on a lower slot.
    #[inline(always)]
    pub(crate) fn closer(t: f32, slot: u32, best: Option<Hit>) -> bool {
        best.is_none_or(|b| t < b.t || (t == b.t && slot < b.slot))
    }
}

impl From<&obvhs::bvh2::node::Bvh2Node> for BvhNode {
    fn from(n: &obvhs::bvh2::node::Bvh2Node) -> Self {
        BvhNode {
            min: n.aabb().min.into(),
            max: n.aabb().max.into(),
            first: n.first_index,
            count: n.prim_count,
        }
    }
}

/// Single-ray traversal of any of our binary BVHs (triangles or spheres): visits the leaf slots
/// whose boxes the ray enters before `t_far`, nearer child first. `visit` may shrink `t_far`
/// and returns `true` to stop.
#[inline(always)]
pub(crate) fn traverse_nodes(
    nodes: &[BvhNode],
    ray: &Ray,
    stack: &mut Vec<u32>,
    t_far: &mut f32,
    mut visit: impl FnMut(u32, &mut f32) -> bool,
) {
    stack.clear();
    let Some(root) = nodes.first() else {
        return;
    };
    if ray.box_entry(root.min, root.max, *t_far).is_infinite() {
        return;
    }
    stack.push(0);
    while let Some(index) = stack.pop() {
        let node = &nodes[index as usize];
        if node.count > 0 {
            for slot in node.first..node.first + node.count {
                if visit(slot, t_far) {
                    return;
                }
            }
            continue;
        }
        let (l, r) = (node.first, node.first + 1);
        let (ln, rn) = (&nodes[l as usize], &nodes[r as usize]);
        let tl = ray.box_entry(ln.min, ln.max, *t_far);
        let tr = ray.box_entry(rn.min, rn.max, *t_far);
        // Push the farther child first so the nearer one is popped next.
        match (tl.is_finite(), tr.is_finite()) {
            (true, true) if tl <= tr => stack.extend([r, l]),
            (true, true) => stack.extend([l, r]),
            (true, false) => stack.push(l),
            (false, true) => stack.push(r),
            (false, false) => {}
        }
    }
}

/// The nearest hit distance over every leaf triangle, one by one: what the tests check the
/// traversals against.
#[cfg(test)]
pub(crate) fn brute_force_t(accel: &Accel, ray: &Ray) -> Option<f32> {
    accel
        .triangles
        .iter()
        .filter_map(|t| ray.hit_triangle(t.a, t.b, t.c, 0.0, f32::INFINITY))
        .min_by(f32::total_cmp)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::knot_scene;

    #[test]
    fn bvh_closest_hit_matches_brute_force() {
        let scene = knot_scene(64, 12);
        let accel = Accel::build(&scene);
        let mut stack = accel.new_stack();
        let center = scene.bounds().center();
        for i in 0..400 {
            let a = i as f32 * 0.37;
            let origin =
                center + Vec3::new(a.cos() * 9.0, 1.5 + (a * 0.7).sin() * 2.0, a.sin() * 9.0);
            let ray = Ray::new(
                origin,
                center - origin + Vec3::new((a * 3.1).sin(), 0.0, 0.0),
            );
            let got = accel
                .closest_hit(&ray, 0.0, f32::INFINITY, &mut stack)
                .map(|h| h.t);
            let brute = brute_force_t(&accel, &ray);
            assert_eq!(got, brute, "ray {i}");
            assert_eq!(
                accel.occluded(&ray, 0.0, f32::INFINITY, &mut stack),
                brute.is_some()
            );
        }
    }

    #[test]
    fn single_rays_give_the_portable_answers_on_the_simd_build() {
        let scene = knot_scene(96, 12);
        let accel = Accel::build(&scene);
        let mut stack = accel.new_stack();
        let center = scene.bounds().center();
        for i in 0..500 {
            let a = i as f32 * 0.53;
            let origin = center + Vec3::new(a.cos() * 7.0, 2.0 + a.sin(), (a * 1.3).sin() * 7.0);
            let ray = Ray::new(origin, center - origin + Vec3::new(a.sin(), 0.0, a.cos()));
            let t_max = if i % 2 == 0 { f32::INFINITY } else { 9.0 };
            assert_eq!(
                accel.closest_hit(&ray, 0.0, t_max, &mut stack),
                accel.closest_hit_generic(&ray, 0.0, t_max, &mut stack),
                "ray {i}"
            );
            assert_eq!(
                accel.occluded(&ray, 0.0, t_max, &mut stack),
                accel.occluded_generic(&ray, 0.0, t_max, &mut stack),
                "ray {i}"
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
    fn the_bounds_are_the_binary_roots_and_need_only_the_wide_tree() {
        let scene = knot_scene(64, 8);
        let mut accel = Accel::build(&scene);
        let root = accel.nodes[0];
        assert_eq!(
            accel.bounds(),
            Bounds {
                min: root.min,
                max: root.max
            }
        );
        accel.nodes = Vec::new();
        assert_eq!(
            accel.bounds(),
            Bounds {
                min: root.min,
                max: root.max
            }
        );
    }

    #[test]
    fn build_is_deterministic() {
        let scene = knot_scene(200, 24);
        let (a, b) = (Accel::build(&scene), Accel::build(&scene));
        assert_eq!(a.scene_index, b.scene_index);
        assert_eq!(a.nodes.len(), b.nodes.len());
        for (x, y) in a.nodes.iter().zip(&b.nodes) {
            assert_eq!(
                (x.min, x.max, x.first, x.count),
                (y.min, y.max, y.first, y.count)
            );
        }
    }
}
