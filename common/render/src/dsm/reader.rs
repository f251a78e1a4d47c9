//! One render thread's reads of a [`DsmTree`], as a [`TreeMemory`] the traversals read.
//!
//! Ize et al. keep the block a thread is in until it leaves it (§4.1). A packet traversal
//! leaves and comes back often: the entries on its stack name their parents, which lie in the
//! blocks above, and a leaf's triangles lie in their own blocks. On the CAD engine with
//! ambient occlusion a read left the block of the read before it more often than it stayed
//! (2.1 M changes against 1.75 M stays a frame), so a reader keeps the blocks it entered in a
//! small direct-mapped table, of nodes and of triangles apart: finding a block again is one
//! compare, where a search of the last few blocks (32 compares at worst) held ambient occlusion
//! at three quarters of the replicated rate with every block at hand. Only a block the table
//! does not hold costs a lookup (its own memory, or the shared cache, with its guard and
//! reference count, or a fetch).
//!
//! A reader that parks its misses ([`DsmReader::park_misses`]) does not wait for a block that
//! is not here: it asks for it, notes it, and reads a stand-in no ray enters or hits, so the
//! traversal runs to its end with a result the caller throws away; the caller traces the same
//! rays again once the blocks have landed, handing them back as pins (`crate::parking`).

use super::layout::{nodes_of, BlockLayout, Chunk, FastDiv};
use super::tree::{DsmTree, Hold, Landing};
use super::Block;
use crate::bvh::memory::{prefetch_leaf, prefetch_node, TreeMemory};
use crate::bvh::node::{BvhNode, LeafTriangle, WideNode};
use crate::scene::particles::Particle;
use crate::volume::{BrickSource, Bricks};
use std::ops::Range;
use std::sync::Arc;
use tessera_core::dsm::BlockId;

/// Node blocks a reader keeps (a power of two: block k goes to entry k mod this).
const NODE_HOLDS: usize = 64;
/// Triangle blocks a reader keeps (a power of two).
const TRIANGLE_HOLDS: usize = 32;
/// Volume bricks a reader keeps (a power of two), any brick in any entry, the oldest entry
/// replaced. A packet's rays are marched one after the other, each through a row of up to
/// 20 bricks, and the next ray through much the same row: with 4 entries the CT head read
/// 564 000 bricks a frame from the cache (a lock and a reference count each) and ran at a
/// third of the replicated rate; 32 entries mapped by brick number still thrashed, as 25
/// bricks in 32 places collide.
const BRICK_HOLDS: usize = 32;
/// Blocks of the particles' tree nodes and of particles a reader keeps (powers of two). A
/// block holds 256 nodes or 409 particles of 8 KiB, and a walk reads a few hundred bytes of
/// each block it enters.
const SPHERE_NODE_HOLDS: usize = 16;
const SPHERE_HOLDS: usize = 16;

/// The blocks a reader entered: node or triangle block k in entry k mod `N`, a brick in any.
struct Holds<'s, const N: usize> {
    /// Each entry's block, and in the high half the trace it was entered or found in (see
    /// `Parking::trace`).
    ids: [u64; N],
    /// Each entry's first byte, kept beside its id so that a read inside a held block is a
    /// compare and an offset, as in a process's own array.
    bases: [*const Chunk; N],
    held: [Hold<'s>; N],
}

impl<const N: usize> Holds<'_, N> {
    const MASK: usize = {
        assert!(N.is_power_of_two());
        N - 1
    };

    /// Entry `i`'s block, unless it is a stand-in or nothing.
    #[inline(always)]
    fn chunks_at(&self, i: usize) -> Option<&[Chunk]> {
        match &self.held[i] {
            Hold::Absent(_) | Hold::Nothing => None,
            held => Some(held.chunks()),
        }
    }

    fn new() -> Self {
        Holds {
            ids: [u64::MAX; N],
            bases: [std::ptr::null(); N],
            held: std::array::from_fn(|_| Hold::Nothing),
        }
    }
}

/// One thread's reads of a [`DsmTree`] (see the module doc). Make one per thread with
/// [`DsmTree::reader`] and keep it across rays.
pub struct DsmReader<'s> {
    tree: &'s DsmTree,
    /// Division by the nodes and the triangles a block holds.
    per_node_block: FastDiv,
    per_triangle_block: FastDiv,
    triangles_per_block: u32,
    node_blocks: u32,
    nodes: Holds<'s, NODE_HOLDS>,
    tris: Holds<'s, TRIANGLE_HOLDS>,
    /// The first block of volume bricks, brick `i` in block `first_brick + i`.
    first_brick: BlockId,
    bricks: Holds<'s, BRICK_HOLDS>,
    spheres: SphereReads<'s>,
    /// The entry of the brick read last (a march reads the same brick for several
    /// macro-cells), and the entry a brick not in the table goes to next.
    brick_last: usize,
    brick_next: usize,
    tally: Tally,
    parking: Parking,
}

/// What a reader reads of the particles: their tree's nodes and the particles, each a region
/// of blocks with a table of its own.
struct SphereReads<'s> {
    nodes: Holds<'s, SPHERE_NODE_HOLDS>,
    spheres: Holds<'s, SPHERE_HOLDS>,
    per_node_block: FastDiv,
    per_sphere_block: FastDiv,
    first_node_block: BlockId,
    first_sphere_block: BlockId,
    node_count: u32,
    sphere_count: u32,
}

/// Blocks a trace reads as if held, whatever the cache holds: those an earlier trace of the
/// same rays read or missed.
pub type Pins = Vec<(BlockId, Arc<Block>)>;

/// What a reader that parks its misses keeps (see the module doc).
#[derive(Default)]
struct Parking {
    on: bool,
    /// The other nodes' blocks that left the reader's table during this trace, and those the
    /// caller handed in: what an earlier trace of the same rays read or missed. A traversal
    /// comes back to blocks it has read (its stack names parents in the blocks above), and
    /// must find there what it found before, whatever the cache let go of meanwhile: a
    /// stand-in where a parent was would send it to a leaf of `EMPTY` triangles. A block is
    /// in the table or here, so it is never lost in the middle of a trace.
    pins: Pins,
    /// Blocks missed since [`DsmReader::take_missed`], each asked for once.
    missed: Vec<(BlockId, Landing)>,
    /// The trace under way, in the high half: a block a trace reads is marked with it in the
    /// reader's table, so that only the blocks this trace read are pinned when they leave it.
    trace: u64,
}

impl Parking {
    /// Pins `held` (block `k`, leaving a reader's table) if it is another node's. A block may
    /// be pinned twice in a trace: the pins are made unique when the trace ends, rather than
    /// searched at every block that leaves the table.
    fn keep(&mut self, k: BlockId, held: Hold<'_>) {
        if let Hold::Cached(block) = held {
            self.pins.push((k, block));
        }
    }

    /// Block `k` is not here: asked for (once a trace), and a stand-in read meanwhile.
    #[cold]
    fn miss<'s>(&mut self, tree: &'s DsmTree, k: BlockId) -> Hold<'s> {
        if self.missed.iter().all(|(m, _)| *m != k) {
            let landing = tree.fetcher().request(k);
            if let Some(block) = landing.block() {
                // At hand at once: the next packets find it in the cache.
                tree.cache_landed(k, block);
            }
            self.missed.push((k, landing));
            tree.count_missed();
        }
        Hold::Absent(tree.absent(k >= tree.layout().node_blocks))
    }
}

/// What a reader counts of the blocks it looks up.
#[derive(Default)]
struct Tally {
    /// Lookups of blocks it held none of, and of those, blocks this node holds itself.
    reads: u64,
    local: u64,
    /// The other nodes' blocks read since [`DsmReader::take_footprint`], and the bricks of
    /// this node's: what the same pixels will read again next frame, to be fetched ahead of
    /// them.
    footprint: Vec<BlockId>,
}

impl<'s> DsmReader<'s> {
    /// Blocks a reader keeps at most (they stay alive while it does, whatever the cache).
    pub const HOLDS: usize =
        NODE_HOLDS + TRIANGLE_HOLDS + BRICK_HOLDS + SPHERE_NODE_HOLDS + SPHERE_HOLDS;

    /// Blocks a reader of a scene laid out as `layout` keeps at most: its tables of nodes and
    /// triangles if it has triangles, of bricks if it has a volume, of the particles' tree
    /// and particles if it has particles.
    pub fn holds(layout: &BlockLayout) -> usize {
        let table = |has: bool, entries: usize| if has { entries } else { 0 };
        table(layout.node_count > 0, NODE_HOLDS + TRIANGLE_HOLDS)
            + table(layout.brick_blocks > 0, BRICK_HOLDS)
            + table(layout.sphere_count > 0, SPHERE_NODE_HOLDS + SPHERE_HOLDS)
    }

    pub(super) fn new(tree: &'s DsmTree) -> Self {
        let layout = tree.layout();
        DsmReader {
            tree,
            per_node_block: FastDiv::new(layout.nodes_per_block()),
            per_triangle_block: FastDiv::new(layout.triangles_per_block()),
            triangles_per_block: layout.triangles_per_block(),
            node_blocks: layout.node_blocks,
            nodes: Holds::new(),
            tris: Holds::new(),
            first_brick: layout.first_brick_block(),
            bricks: Holds::new(),
            spheres: SphereReads {
                nodes: Holds::new(),
                spheres: Holds::new(),
                per_node_block: FastDiv::new(layout.sphere_nodes_per_block()),
                per_sphere_block: FastDiv::new(layout.spheres_per_block()),
                first_node_block: layout.first_sphere_node_block(),
                first_sphere_block: layout.first_sphere_block(),
                node_count: layout.sphere_node_count,
                sphere_count: layout.sphere_count,
            },
            brick_last: 0,
            brick_next: 0,
            tally: Tally::default(),
            parking: Parking::default(),
        }
    }

    /// Whether a miss is parked (asked for, and a stand-in read) rather than waited for, and
    /// the blocks to read as if held (see the module doc).
    pub fn park_misses(&mut self, on: bool, pins: Pins) {
        self.parking.on = on;
        self.parking.pins = pins;
        // A new trace: no entry, a stand-in least of all, is read without a look first.
        self.parking.trace = self.parking.trace.wrapping_add(1 << 32);
    }

    /// The blocks missed since the last call, each with where it lands; the pins handed in
    /// come back with them. After a miss, what was traced read stand-ins and must be traced
    /// again; the next [`DsmReader::park_misses`] starts a trace that looks at every entry
    /// again, stand-ins included.
    pub fn take_missed(&mut self) -> (Vec<(BlockId, Landing)>, Pins) {
        let missed = std::mem::take(&mut self.parking.missed);
        let mut pins = std::mem::take(&mut self.parking.pins);
        if !missed.is_empty() {
            pins.sort_unstable_by_key(|(k, _)| *k);
            pins.dedup_by_key(|(k, _)| *k);
        }
        (missed, pins)
    }

    /// Blocks this trace missed so far: after one, what it traces starts from void results.
    pub fn missed_count(&self) -> usize {
        self.parking.missed.len()
    }

    /// The other nodes' blocks read since the last call, in the order read (repeats kept).
    pub fn take_footprint(&mut self) -> Vec<BlockId> {
        std::mem::take(&mut self.tally.footprint)
    }

    /// The first byte of block `k`, from the table or, when another block has its entry,
    /// looked up in that one's place.
    #[inline(always)]
    fn base_of<const N: usize>(
        tree: &'s DsmTree,
        holds: &mut Holds<'s, N>,
        k: BlockId,
        (tally, parking): (&mut Tally, &mut Parking),
    ) -> *const Chunk {
        Self::base_at(
            tree,
            holds,
            (k as usize & Holds::<N>::MASK, k),
            (tally, parking),
        )
    }

    /// [`DsmReader::base_of`] with block `k` in entry `i`.
    #[inline(always)]
    fn base_at<const N: usize>(
        tree: &'s DsmTree,
        holds: &mut Holds<'s, N>,
        (i, k): (usize, BlockId),
        (tally, parking): (&mut Tally, &mut Parking),
    ) -> *const Chunk {
        if holds.ids[i] == parking.trace | k as u64 {
            return holds.bases[i];
        }
        Self::enter(tree, holds, (i, k), tally, parking)
    }

    #[cold]
    #[inline(never)]
    fn enter<const N: usize>(
        tree: &'s DsmTree,
        holds: &mut Holds<'s, N>,
        (i, k): (usize, BlockId),
        tally: &mut Tally,
        parking: &mut Parking,
    ) -> *const Chunk {
        let entry = holds.ids[i];
        if entry as BlockId == k && matches!(holds.held[i], Hold::Local(_) | Hold::Cached(_)) {
            // Entered in an earlier trace and still held: now read in this one too.
            holds.ids[i] = parking.trace | k as u64;
            return holds.bases[i];
        }
        // Let go of the old block first: a line replaced meanwhile frees it at once. A trace
        // that parks its misses keeps it instead if it read it (see `Parking::pins`).
        let old = std::mem::replace(&mut holds.held[i], Hold::Nothing);
        holds.held[i] = if parking.on {
            if entry & !(BlockId::MAX as u64) == parking.trace {
                parking.keep(entry as BlockId, old);
            }
            tree.try_hold(k, &parking.pins)
                .unwrap_or_else(|| parking.miss(tree, k))
        } else {
            drop(old);
            tree.hold(k)
        };
        holds.ids[i] = parking.trace | k as u64;
        holds.bases[i] = holds.held[i].chunks().as_ptr();
        match holds.held[i] {
            Hold::Local(_) => {
                tally.reads += 1;
                tally.local += 1;
                // A series' next step has the same brick in another block, maybe another
                // node's: the footprint that fetches it ahead needs this node's bricks too.
                let layout = tree.layout();
                if (layout.first_brick_block()..layout.first_sphere_node_block()).contains(&k) {
                    tally.footprint.push(k);
                }
            }
            Hold::Cached(_) => {
                tally.reads += 1;
                tally.footprint.push(k);
            }
            Hold::Absent(_) | Hold::Nothing => {}
        }
        holds.bases[i]
    }
}

impl<'s> DsmReader<'s> {
    /// Node `index` of the particles' tree, or `None` while its block is not here (see
    /// [`crate::spheres::SphereSource`]) or past the tree's end.
    #[inline]
    pub fn sphere_node(&mut self, index: u32) -> Option<BvhNode> {
        let reads = &mut self.spheres;
        if index >= reads.node_count {
            return None;
        }
        let (b, at) = reads.per_node_block.div_rem(index);
        let k = reads.first_node_block + b;
        let held = Self::read_held(
            self.tree,
            &mut reads.nodes,
            k,
            (&mut self.tally, &mut self.parking),
        )?;
        let nodes: &[BvhNode] = bytemuck::cast_slice(held);
        Some(nodes[at as usize])
    }

    /// The particle in leaf slot `slot`, or `None` while its block is not here or past the
    /// last particle.
    #[inline]
    pub fn sphere(&mut self, slot: u32) -> Option<Particle> {
        let reads = &mut self.spheres;
        if slot >= reads.sphere_count {
            return None;
        }
        let (b, at) = reads.per_sphere_block.div_rem(slot);
        let k = reads.first_sphere_block + b;
        let held = Self::read_held(
            self.tree,
            &mut reads.spheres,
            k,
            (&mut self.tally, &mut self.parking),
        )?;
        let size = std::mem::size_of::<Particle>();
        let bytes: &[u8] = bytemuck::cast_slice(held);
        let at = at as usize * size;
        Some(bytemuck::pod_read_unaligned(&bytes[at..at + size]))
    }

    /// Block `k` from a direct-mapped table, or `None` while it is not here.
    #[inline(always)]
    fn read_held<'h, const N: usize>(
        tree: &'s DsmTree,
        holds: &'h mut Holds<'s, N>,
        k: BlockId,
        (tally, parking): (&mut Tally, &mut Parking),
    ) -> Option<&'h [Chunk]> {
        Self::base_of(tree, holds, k, (tally, parking));
        holds.chunks_at(k as usize & Holds::<N>::MASK)
    }
}

impl Drop for DsmReader<'_> {
    fn drop(&mut self) {
        self.tree.count_reads(self.tally.reads, self.tally.local);
    }
}

impl BrickSource for DsmReader<'_> {
    #[inline]
    fn samples<'a>(&'a mut self, bricks: &'a Bricks, index: usize) -> Option<&'a [f32]> {
        let k = self.first_brick + bricks.first_shared() + index as BlockId;
        let ids = &self.bricks.ids;
        // An entry's low half is its block whatever trace it was read in (`base_at` looks
        // again at one from an earlier trace).
        let i = if ids[self.brick_last] as BlockId == k {
            self.brick_last
        } else if let Some(i) = ids.iter().position(|&id| id as BlockId == k) {
            i
        } else {
            self.brick_next = (self.brick_next + 1) % BRICK_HOLDS;
            self.brick_next
        };
        self.brick_last = i;
        Self::base_at(
            self.tree,
            &mut self.bricks,
            (i, k),
            (&mut self.tally, &mut self.parking),
        );
        self.bricks.chunks_at(i).map(bytemuck::cast_slice)
    }
}

impl TreeMemory for DsmReader<'_> {
    fn is_empty(&self) -> bool {
        self.tree.layout().node_count == 0
    }

    #[inline(always)]
    fn node(&mut self, index: u32) -> &WideNode {
        let (k, at) = self.per_node_block.div_rem(index);
        let base = Self::base_of(
            self.tree,
            &mut self.nodes,
            k,
            (&mut self.tally, &mut self.parking),
        );
        debug_assert!(std::ptr::eq(
            &nodes_of(self.nodes.held[k as usize & (NODE_HOLDS - 1)].chunks())[at as usize],
            base.cast::<WideNode>().wrapping_add(at as usize)
        ));
        // SAFETY: `base` is the first byte of block k, which the table's entry keeps alive (a
        // cached block's `Arc`, or the tree's own memory, which outlives the reader) and which
        // no one writes; an entry changes only in `enter`, which needs `&mut self`, so not
        // while the returned node is borrowed. A block is whole 64-byte-aligned chunks and
        // holds `nodes_per_block` nodes, and `at` is below that.
        unsafe { &*base.cast::<WideNode>().add(at as usize) }
    }

    #[inline(always)]
    fn triangle(&mut self, slot: u32) -> &LeafTriangle {
        &self.triangles(slot..slot + 1)[0]
    }

    #[inline(always)]
    fn triangles(&mut self, slots: Range<u32>) -> &[LeafTriangle] {
        let per = self.triangles_per_block;
        let (b, at) = self.per_triangle_block.div_rem(slots.start);
        let k = self.node_blocks + b;
        let base = Self::base_of(
            self.tree,
            &mut self.tris,
            k,
            (&mut self.tally, &mut self.parking),
        );
        let end = (slots.end - slots.start + at).min(per);
        debug_assert!(at < end);
        let len = (end - at) as usize;
        // SAFETY: as in `node`: the block stays alive and unchanged while the slice is
        // borrowed, it holds `per` whole triangles (`triangles_per_block`: as many as fit its
        // bytes), and `at..end` lies within them.
        unsafe { std::slice::from_raw_parts(base.cast::<LeafTriangle>().add(at as usize), len) }
    }

    /// Only a child whose block is in the reader's table: any other is a lookup away (its
    /// own memory, the cache, or a fetch), which a hint must not start.
    #[inline(always)]
    fn prefetch(&self, child: u32, count: u32) {
        if count == 0 {
            let (k, at) = self.per_node_block.div_rem(child);
            let i = k as usize & (NODE_HOLDS - 1);
            if self.nodes.ids[i] as BlockId == k {
                prefetch_node(
                    self.nodes.bases[i]
                        .cast::<WideNode>()
                        .wrapping_add(at as usize),
                );
            }
        } else if count != crate::bvh::node::EMPTY {
            let (b, at) = self.per_triangle_block.div_rem(child);
            let k = self.node_blocks + b;
            let i = k as usize & (TRIANGLE_HOLDS - 1);
            if self.tris.ids[i] as BlockId == k {
                let first = self.tris.bases[i].cast::<LeafTriangle>();
                prefetch_leaf(first.wrapping_add(at as usize), count);
            }
        }
    }
}
