//! Triangles with bit-for-bit equal boxes, in numbers: a million copies of one triangle, or a
//! mesh collapsed onto a coarse grid. obvhs' PLOC pairs each cluster with its nearest
//! neighbour; among equal boxes every distance ties, few pairs are mutual, and the build goes
//! quadratic (10k copies took 1.7 s, 100k more than two minutes). So such a group goes to
//! obvhs as one triangle, and its leaf is expanded here afterwards into a balanced subtree of
//! small leaves, which costs O(n log n) however many copies there are.

use crate::bvh::tree::BvhNode;
use glam::Vec3;
use obvhs::bvh2::Bvh2;
use obvhs::triangle::Triangle;
use rayon::prelude::*;

/// Groups smaller than this go to obvhs as they are: its build stays fast with a few ties
/// (quad pairs share a box everywhere), and the normal tree of a normal mesh is unchanged.
pub(crate) const GROUP_MIN: usize = 64;

/// Triangles per leaf of an expanded group.
const GROUP_LEAF: usize = 4;

/// Equal-box groups of at least [`GROUP_MIN`] triangles, each sorted, in order of their first
/// member; empty (after one cheap counting pass) for any ordinary mesh.
pub(crate) fn coincident_groups(tris: &[Triangle]) -> Vec<Vec<u32>> {
    let bits = |t: &Triangle| {
        let b = t.aabb();
        [b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z].map(f32::to_bits)
    };
    let hash = |t: &Triangle| {
        bits(t).iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &w| {
            (h ^ w as u64).wrapping_mul(0x0000_0100_0000_01b3)
        })
    };
    // A count per hash bucket; a bucket reaching GROUP_MIN is (nearly always) a real group.
    let buckets = tris.len().next_power_of_two().max(1024);
    let mut counts = vec![0u8; buckets];
    let mut suspect = false;
    for t in tris {
        let c = &mut counts[(hash(t) as usize) & (buckets - 1)];
        *c = c.saturating_add(1);
        suspect |= *c as usize >= GROUP_MIN;
    }
    drop(counts);
    if !suspect {
        return Vec::new();
    }
    let mut keyed: Vec<([u32; 6], u32)> = tris
        .par_iter()
        .enumerate()
        .map(|(i, t)| (bits(t), i as u32))
        .collect();
    keyed.par_sort_unstable();
    let mut groups: Vec<Vec<u32>> = keyed
        .chunk_by(|a, b| a.0 == b.0)
        .filter(|run| run.len() >= GROUP_MIN)
        .map(|run| run.iter().map(|&(_, i)| i).collect())
        .collect();
    groups.sort_unstable_by_key(|g| g[0]);
    groups
}

/// What goes into a subtree: a box and the scene triangles under it.
struct Item {
    min: Vec3,
    max: Vec3,
    members: Vec<u32>,
}

enum Source {
    Obvhs(u32),
    Items(Vec<Item>),
}

/// Flattens `bvh` (built over `input`, whose entry `k` is scene triangle `input[k]` of `tris`) into
/// depth-first nodes and a leaf order of scene triangles, expanding each leaf entry that stands
/// for a group (`group_of[k]`: index into `groups`) into all the group's triangles.
pub(crate) fn flatten_expanding(
    bvh: &Bvh2,
    tris: &[Triangle],
    input: &[u32],
    group_of: &[Option<u32>],
    groups: &[Vec<u32>],
) -> (Vec<BvhNode>, Vec<u32>) {
    let mut nodes = vec![BLANK_NODE];
    let mut order: Vec<u32> =
        Vec::with_capacity(groups.iter().map(Vec::len).sum::<usize>() + input.len());
    let mut stack = vec![(Source::Obvhs(0), 0usize)];
    while let Some((source, at)) = stack.pop() {
        let items = match source {
            Source::Obvhs(i) => {
                let n = &bvh.nodes[i as usize];
                let (min, max) = (n.aabb().min.into(), n.aabb().max.into());
                if !n.is_leaf() {
                    let first = add_inner(&mut nodes, at, min, max);
                    stack.push((Source::Obvhs(n.first_index + 1), first + 1));
                    stack.push((Source::Obvhs(n.first_index), first));
                    continue;
                }
                let entries = &bvh.primitive_indices
                    [n.first_index as usize..(n.first_index + n.prim_count) as usize];
                if entries.iter().all(|&k| group_of[k as usize].is_none()) {
                    nodes[at] = BvhNode {
                        min,
                        max,
                        first: order.len() as u32,
                        count: n.prim_count,
                    };
                    order.extend(entries.iter().map(|&k| input[k as usize]));
                    continue;
                }
                leaf_items(tris, entries, input, group_of, groups)
            }
            Source::Items(items) => items,
        };
        let (min, max) = items
            .iter()
            .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), it| {
                (lo.min(it.min), hi.max(it.max))
            });
        if let [item] = &items[..] {
            nodes[at] = BvhNode {
                min,
                max,
                first: order.len() as u32,
                count: item.members.len() as u32,
            };
            order.extend(&item.members);
            continue;
        }
        let mut left = items;
        let right = left.split_off(left.len() / 2);
        let first = add_inner(&mut nodes, at, min, max);
        stack.push((Source::Items(right), first + 1));
        stack.push((Source::Items(left), first));
    }
    (nodes, order)
}

/// Makes node `at` an inner node over `min..max` with two new (blank) children, and returns
/// the first child's index.
fn add_inner(nodes: &mut Vec<BvhNode>, at: usize, min: Vec3, max: Vec3) -> usize {
    let first = nodes.len();
    nodes.extend([BLANK_NODE, BLANK_NODE]);
    nodes[at] = BvhNode {
        min,
        max,
        first: first as u32,
        count: 0,
    };
    first
}

const BLANK_NODE: BvhNode = BvhNode {
    min: Vec3::ZERO,
    max: Vec3::ZERO,
    first: 0,
    count: 0,
};

/// A leaf's entries as items: its plain triangles in one, each group in chunks of
/// [`GROUP_LEAF`].
fn leaf_items(
    tris: &[Triangle],
    entries: &[u32],
    input: &[u32],
    group_of: &[Option<u32>],
    groups: &[Vec<u32>],
) -> Vec<Item> {
    let item = |members: Vec<u32>| {
        let (min, max) =
            members
                .iter()
                .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), &m| {
                    let b = tris[m as usize].aabb();
                    (lo.min(b.min.into()), hi.max(b.max.into()))
                });
        Item { min, max, members }
    };
    let plain: Vec<u32> = entries
        .iter()
        .filter(|&&k| group_of[k as usize].is_none())
        .map(|&k| input[k as usize])
        .collect();
    let mut items: Vec<Item> = entries
        .iter()
        .filter_map(|&k| group_of[k as usize])
        .flat_map(|g| groups[g as usize].chunks(GROUP_LEAF))
        .map(|chunk| item(chunk.to_vec()))
        .collect();
    if !plain.is_empty() {
        items.insert(0, item(plain));
    }
    items
}

#[cfg(test)]
mod tests {
    use crate::bvh::tree::Accel;
    use crate::geometry::Ray;
    use crate::scene::{knot_scene, Scene};
    use glam::Vec3;
    use std::time::Duration;

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
            assert_eq!(
                got,
                crate::bvh::tree::brute_force_t(&accel, &ray),
                "ray {i}"
            );
        }
    }
}
