//! Triangles with bit-for-bit equal boxes, in numbers: a million copies of one triangle, or a
//! mesh collapsed onto a coarse grid. obvhs' PLOC pairs each cluster with its nearest
//! neighbour; among equal boxes every distance ties, few pairs are mutual, and the build goes
//! quadratic (10k copies took 1.7 s, 100k more than two minutes). So such a group goes to
//! obvhs as one triangle, and its leaf is expanded here afterwards into a balanced subtree of
//! small leaves, which costs O(n log n) however many copies there are.

use crate::bvh::node::BvhNode;
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
