//! Single rays through the 8-wide tree (shadow, ambient-occlusion, reflected rays, and packets
//! without a common origin): each node's children tested at once (`node_test_ray`), entered
//! ones pushed nearest last and prefetched, leaves tested 8 triangles at a time (`leaf_ray`).
//!
//! Closest hits are order-independent: of two hits at the same distance the lower slot wins,
//! so this traversal and the packet traversal agree bit for bit.

use crate::bvh::leaf_ray;
use crate::bvh::memory::TreeMemory;
use crate::bvh::node::{Hit, WideNode, WIDTH};
#[cfg(target_arch = "x86_64")]
use crate::bvh::node_test_ray::enter_mask_avx2;
use crate::bvh::node_test_ray::{enter_mask, BoxRay, NodeTest};
use crate::bvh::tree::Accel;
use crate::geometry::Ray;
use crate::isa::{isa_builds, Build, Isa};

impl Accel {
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
        let interval = (t_min, t_max);
        closest_hit_on(Isa::Portable, &mut self.resident(), ray, interval, stack)
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
        occluded_on(
            Isa::Portable,
            &mut self.resident(),
            ray,
            (t_min, t_max),
            stack,
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
    closest_hit_on(Isa::best(), mem, ray, interval, stack)
}

isa_builds! {
    /// [`closest_hit`] on the build `isa`. Single rays have an AVX2 build and no wider one: the
    /// node test is AVX2 intrinsics (`enter_mask_avx2`), and AVX-512 CPUs run that build.
    pub fn closest_hit_on<M: TreeMemory>(
        mem: &mut M,
        ray: &Ray,
        interval: (f32, f32),
        stack: &mut Vec<u32>,
    ) -> Option<Hit> = closest_hit_kernel on [Avx2];
}

/// [`closest_hit`] on `build`. A leaf is tested in the pieces the memory holds it in (one,
/// unless it straddles two shared blocks): hits compare by distance and then slot, so the
/// pieces give the whole leaf's answer.
#[inline(always)]
fn closest_hit_kernel<M: TreeMemory>(
    build: impl Build,
    mem: &mut M,
    ray: &Ray,
    (t_min, t_max): (f32, f32),
    stack: &mut Vec<u32>,
) -> Option<Hit> {
    let mut best: Option<Hit> = None;
    let mut t_far = t_max;
    let enter = node_test(build);
    let boxes = BoxRay::new(ray, t_min);
    traverse_wide::<true, M>(
        mem,
        enter,
        &boxes,
        stack,
        &mut t_far,
        |mem, slots, t_far| {
            let mut at = slots.start;
            while at < slots.end {
                let tris = mem.triangles(at..slots.end);
                best = leaf_ray::closest_hit(build, ray, tris, at, (t_min, t_max), best);
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
    occluded_on(Isa::best(), mem, ray, interval, stack)
}

isa_builds! {
    /// [`occluded`] on the build `isa` (an AVX2 build and no wider, as [`closest_hit_on`]).
    pub fn occluded_on<M: TreeMemory>(
        mem: &mut M,
        ray: &Ray,
        interval: (f32, f32),
        stack: &mut Vec<u32>,
    ) -> bool = occluded_kernel on [Avx2];
}

/// [`occluded`] on `build`.
#[inline(always)]
fn occluded_kernel<M: TreeMemory>(
    build: impl Build,
    mem: &mut M,
    ray: &Ray,
    (t_min, t_max): (f32, f32),
    stack: &mut Vec<u32>,
) -> bool {
    let mut t_far = t_max;
    let mut blocked = false;
    let enter = node_test(build);
    let boxes = BoxRay::new(ray, t_min);
    traverse_wide::<ORDERED_OCCLUSION, M>(
        mem,
        enter,
        &boxes,
        stack,
        &mut t_far,
        |mem, slots, _| {
            let mut at = slots.start;
            while at < slots.end && !blocked {
                let tris = mem.triangles(at..slots.end);
                blocked = leaf_ray::any_hit(build, ray, tris, t_min, t_max);
                at += tris.len() as u32;
            }
            blocked
        },
    );
    blocked
}

/// The wide node test of the build `B`: AVX2 intrinsics on every build above portable. `B` is
/// a type, so the choice is made at compile time, and each build has its own closure, which
/// inlines into that build's `#[target_feature]` function (a closure shared by two builds was
/// left a call in each, and the leaf test in it compiled without AVX2: AO rays ran 27 % more
/// instructions).
#[inline(always)]
fn node_test<B: Build>(_: B) -> impl NodeTest {
    move |node: &WideNode, ray: &BoxRay, t_far: f32| {
        #[cfg(target_arch = "x86_64")]
        if B::ISA != Isa::Portable {
            // SAFETY: a `B` exists only where the CPU runs its build (see `Build`), and every
            // build above portable has AVX2.
            return unsafe { enter_mask_avx2(node, ray, t_far) };
        }
        enter_mask(node, ray, t_far)
    }
}

/// Whether occlusion rays visit nearer children first (see `traverse_wide`).
const ORDERED_OCCLUSION: bool = false;

/// Visits the leaves whose boxes `ray` enters before `t_far` (nearer children first when
/// `ORDERED`: closest hits want that, any-hit rays do not); `visit` gets the memory and a
/// leaf's slots, may shrink `t_far`, and returns `true` to stop.
#[inline(always)]
pub(crate) fn traverse_wide<const ORDERED: bool, M: TreeMemory>(
    mem: &mut M,
    enter: impl NodeTest,
    ray: &BoxRay,
    stack: &mut Vec<u32>,
    t_far: &mut f32,
    mut visit: impl FnMut(&mut M, std::ops::Range<u32>, &mut f32) -> bool,
) {
    stack.clear();
    if mem.is_empty() {
        return;
    }
    if !ORDERED {
        traverse_unordered(mem, enter, ray, stack, t_far, visit);
        return;
    }
    // Entries are (child, count) pairs: count 0 is an inner node.
    stack.extend([0, 0]);
    while let (Some(count), Some(child)) = (stack.pop(), stack.pop()) {
        if count > 0 {
            if visit(mem, child..child + count, t_far) {
                return;
            }
            continue;
        }
        let node = mem.node(child);
        let (t, mut entered) = enter(node, ray, *t_far);
        let (children, counts) = (node.child, node.count);
        // The entered children, nearest first (an insertion sort of at most WIDTH).
        let mut order = [0usize; WIDTH];
        let mut n = 0;
        while entered != 0 {
            let k = entered.trailing_zeros() as usize;
            entered &= entered - 1;
            let mut j = n;
            while j > 0 && t[order[j - 1]] > t[k] {
                order[j] = order[j - 1];
                j -= 1;
            }
            order[j] = k;
            n += 1;
        }
        for &k in order[..n].iter().rev() {
            mem.prefetch(children[k], counts[k]);
            stack.extend([children[k], counts[k]]);
        }
    }
}

/// [`traverse_wide`] for rays that any hit ends: children in no order (the order buys little
/// when the first hit stops the ray, and costs a sort per node: AO rays a few per cent faster
/// without it on the bunny). One entered child is descended into at once instead of going
/// through the stack.
#[inline(always)]
fn traverse_unordered<M: TreeMemory>(
    mem: &mut M,
    enter: impl NodeTest,
    ray: &BoxRay,
    stack: &mut Vec<u32>,
    t_far: &mut f32,
    mut visit: impl FnMut(&mut M, std::ops::Range<u32>, &mut f32) -> bool,
) {
    // (child, count): count 0 is an inner node.
    let (mut child, mut count) = (0u32, 0u32);
    loop {
        if count > 0 {
            if visit(mem, child..child + count, t_far) {
                return;
            }
        } else {
            let node = mem.node(child);
            let (_, mut entered) = enter(node, ray, *t_far);
            let (children, counts) = (node.child, node.count);
            if entered != 0 {
                let next = (u32::BITS - 1 - entered.leading_zeros()) as usize;
                entered &= !(1 << next);
                while entered != 0 {
                    let k = entered.trailing_zeros() as usize;
                    entered &= entered - 1;
                    mem.prefetch(children[k], counts[k]);
                    stack.extend([children[k], counts[k]]);
                }
                (child, count) = (children[next], counts[next]);
                continue;
            }
        }
        match (stack.pop(), stack.pop()) {
            (Some(c), Some(ch)) => (child, count) = (ch, c),
            _ => return,
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
    use crate::scene::{knot_scene, Scene};
    use glam::Vec3;
    use std::time::Duration;

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

    /// A ray that starts beyond its origin skips the boxes it leaves before then: the hits it
    /// finds are still every triangle's nearest beyond `t_min`, one by one.
    #[test]
    fn a_ray_from_t_min_finds_what_brute_force_finds_beyond_it() {
        let scene = knot_scene(64, 12);
        let accel = Accel::build(&scene);
        let mut stack = accel.new_stack();
        let center = scene.bounds().center();
        let mut skipped = 0;
        for i in 0..400 {
            let a = i as f32 * 0.29;
            let origin = center + Vec3::new(a.cos() * 6.0, (a * 0.7).sin(), a.sin() * 6.0);
            let ray = Ray::new(
                origin,
                center - origin + Vec3::new(0.0, (a * 2.3).sin(), 0.0),
            );
            let t_min = [0.0, 0.3, 0.5, 0.8][i % 4];
            let brute = accel
                .triangles
                .iter()
                .filter_map(|t| ray.hit_triangle(t.a, t.b, t.c, t_min, f32::INFINITY))
                .min_by(f32::total_cmp);
            let got = accel.closest_hit(&ray, t_min, f32::INFINITY, &mut stack);
            assert_eq!(got.map(|h| h.t), brute, "ray {i} from {t_min}");
            let blocked = accel.occluded(&ray, t_min, f32::INFINITY, &mut stack);
            assert_eq!(blocked, brute.is_some(), "ray {i} from {t_min}");
            skipped += (brute_force_t(&accel, &ray) != brute) as u32;
        }
        assert!(
            skipped > 20,
            "some rays must pass a hit before t_min ({skipped})"
        );
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

    /// The AVX2 node test gives the portable one's mask and entry distances, on a collapsed
    /// tree's real nodes (with empty slots) and rays from inside and outside, some parallel
    /// to an axis.
    #[test]
    #[cfg(target_arch = "x86_64")]
    fn the_avx2_node_test_is_the_portable_one() {
        if !std::arch::is_x86_feature_detected!("avx2") {
            return;
        }
        let accel = Accel::build(&knot_scene(64, 8));
        let mut seen = 0u32;
        for (n, node) in accel.wide.iter().enumerate() {
            for r in 0..12 {
                let f = (n * 12 + r) as f32;
                let origin = Vec3::new((f * 0.37).sin() * 3.0, (f * 0.11).cos() * 2.0, 0.5);
                let k = r % WIDTH;
                let centre = Vec3::new(
                    node.lo[0][k] + node.hi[0][k],
                    node.lo[1][k] + node.hi[1][k],
                    node.lo[2][k] + node.hi[2][k],
                ) * 0.5;
                let dir = match r % 4 {
                    0 => Vec3::X,
                    1 if node.count[k] != crate::bvh::node::EMPTY => centre - origin,
                    _ => Vec3::new((f * 0.7).cos(), (f * 1.3).sin(), (f * 0.3).cos() - 0.2),
                };
                let ray = Ray::new(origin, dir);
                let ray = BoxRay::new(&ray, if r % 5 == 0 { 0.7 } else { 0.0 });
                let t_far = if r % 3 == 0 { f32::INFINITY } else { 1.5 };
                let portable = enter_mask(node, &ray, t_far);
                // SAFETY: the CPU has AVX2, checked above.
                let avx2 = unsafe { crate::bvh::node_test_ray::enter_mask_avx2(node, &ray, t_far) };
                assert_eq!(avx2.1, portable.1, "node {n} ray {r}");
                for k in (0..WIDTH).filter(|k| portable.1 >> k & 1 == 1) {
                    assert_eq!(avx2.0[k], portable.0[k], "node {n} ray {r} child {k}");
                }
                seen += portable.1.count_ones();
            }
        }
        assert!(seen > 100, "the rays must enter some boxes ({seen})");
    }

    /// Builds on another thread and fails if it does not finish within `limit`: a hang guard,
    /// the build itself takes well under a second.
    fn build_within(scene: Scene, limit: Duration) -> (Scene, Accel) {
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let accel = Accel::build(&scene);
            let _ = tx.send((scene, accel));
        });
        rx.recv_timeout(limit)
            .expect("the BVH build did not finish: PLOC stuck among equal boxes?")
    }

    fn assert_each_triangle_once(scene: &Scene, accel: &Accel) {
        let mut seen = accel.scene_index.clone();
        seen.sort_unstable();
        assert_eq!(seen, (0..scene.triangles.len() as u32).collect::<Vec<_>>());
    }

    #[test]
    fn a_million_copies_of_one_triangle_build_and_are_hit() {
        let n = 1_000_000;
        let scene = Scene {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y],
            triangles: vec![[0, 1, 2]; n],
            triangle_material: vec![0; n],
            materials: vec![crate::scene::NEUTRAL],
            ..Scene::default()
        };
        let (scene, accel) = build_within(scene, Duration::from_secs(120));
        assert_each_triangle_once(&scene, &accel);
        let mut stack = accel.new_stack();
        let down = Ray::new(Vec3::new(0.25, 0.25, 2.0), Vec3::NEG_Z);
        let hit = accel
            .closest_hit(&down, 0.0, f32::INFINITY, &mut stack)
            .unwrap();
        assert_eq!(hit.t, 2.0);
        let beside = Ray::new(Vec3::new(0.75, 0.75, 2.0), Vec3::NEG_Z);
        assert!(accel
            .closest_hit(&beside, 0.0, f32::INFINITY, &mut stack)
            .is_none());
    }

    #[test]
    fn a_mesh_with_a_stack_of_copies_traces_as_brute_force_does() {
        let mut scene = knot_scene(64, 12);
        let base = scene.positions.len() as u32;
        let centre = scene.bounds().center();
        scene
            .positions
            .extend([centre, centre + Vec3::X, centre + Vec3::Z]);
        for _ in 0..5000 {
            scene.triangles.push([base, base + 1, base + 2]);
            scene.triangle_material.push(0);
        }
        let (scene, accel) = build_within(scene, Duration::from_secs(120));
        assert_each_triangle_once(&scene, &accel);
        let mut stack = accel.new_stack();
        for i in 0..300 {
            let a = i as f32 * 0.41;
            let origin = centre + Vec3::new(a.cos() * 9.0, 3.0 + a.sin(), a.sin() * 9.0);
            let ray = Ray::new(
                origin,
                centre + Vec3::new(0.3, 0.0, 0.3) * (a * 1.7).sin() - origin,
            );
            let got = accel
                .closest_hit(&ray, 0.0, f32::INFINITY, &mut stack)
                .map(|h| h.t);
            assert_eq!(got, brute_force_t(&accel, &ray), "ray {i}");
        }
    }
}
