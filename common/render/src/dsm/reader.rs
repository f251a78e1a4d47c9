//! One render thread's reads of a [`SharedTree`], as a [`TreeMemory`] the traversals read.
//!
//! Ize et al. keep the block a thread is in until it leaves it (§4.1). A packet traversal
//! leaves and comes back often: the entries on its stack name their parents, which lie in the
//! blocks above, and a leaf's triangles lie in their own blocks. So a reader keeps the last few
//! blocks it entered, of nodes and of triangles apart, and finds one of them again with a few
//! compares; only a block it holds none of costs a lookup (its own memory, or the shared
//! cache, with its guard and reference count, or a fetch). On the bunny at 1/1 cache a reader
//! holding one block of each spent a fifth of the frame in those lookups.

use super::layout::{nodes_of, triangles_of};
use super::shared::{Hold, SharedTree};
use crate::accel::LeafTriangle;
use crate::accel_wide::WideNode;
use crate::tree_memory::{NoPrefetch, TreeMemory};
use std::ops::Range;
use tessera_core::dsm::BlockId;

/// Node blocks a reader keeps.
const NODE_HOLDS: usize = 32;
/// Triangle blocks a reader keeps.
const TRIANGLE_HOLDS: usize = 16;

/// The last `N` blocks a reader entered, the one in use first to look at.
struct Holds<'s, const N: usize> {
    ids: [BlockId; N],
    held: [Hold<'s>; N],
    current: usize,
    /// The next slot to give up, round robin.
    victim: usize,
}

impl<const N: usize> Holds<'_, N> {
    fn new() -> Self {
        Holds {
            ids: [BlockId::MAX; N],
            held: std::array::from_fn(|_| Hold::Nothing),
            current: 0,
            victim: 0,
        }
    }
}

/// One thread's reads of a [`SharedTree`] (see the module doc). Make one per thread with
/// [`SharedTree::reader`] and keep it across rays.
pub struct SharedReader<'s> {
    tree: &'s SharedTree,
    nodes: Holds<'s, NODE_HOLDS>,
    tris: Holds<'s, TRIANGLE_HOLDS>,
    /// Lookups of blocks it held none of, and of those, blocks this node holds itself.
    reads: u64,
    local: u64,
    /// The other nodes' blocks read since [`SharedReader::take_footprint`]: what the same
    /// pixels will read again next frame, to be fetched ahead of them.
    footprint: Vec<BlockId>,
}

impl<'s> SharedReader<'s> {
    /// Blocks a reader keeps at most (they stay alive while it does, whatever the cache).
    pub const HOLDS: usize = NODE_HOLDS + TRIANGLE_HOLDS;

    pub(super) fn new(tree: &'s SharedTree) -> Self {
        SharedReader {
            tree,
            nodes: Holds::new(),
            tris: Holds::new(),
            reads: 0,
            local: 0,
            footprint: Vec::new(),
        }
    }

    /// The other nodes' blocks read since the last call, in the order read (repeats kept).
    pub fn take_footprint(&mut self) -> Vec<BlockId> {
        std::mem::take(&mut self.footprint)
    }

    /// Makes block `k` the current one of `holds`: found among those kept, or looked up in
    /// place of the oldest.
    #[inline(always)]
    fn enter<const N: usize>(
        tree: &'s SharedTree,
        holds: &mut Holds<'s, N>,
        k: BlockId,
        counts: (&mut u64, &mut u64, &mut Vec<BlockId>),
    ) {
        if holds.ids[holds.current] == k {
            return;
        }
        if let Some(i) = holds.ids.iter().position(|&id| id == k) {
            holds.current = i;
            return;
        }
        let i = holds.victim;
        holds.victim = (i + 1) % N;
        // Let go of the old block first: a line replaced meanwhile frees it at once.
        holds.held[i] = Hold::Nothing;
        holds.held[i] = tree.hold(k);
        holds.ids[i] = k;
        holds.current = i;
        *counts.0 += 1;
        if matches!(holds.held[i], Hold::Local(_)) {
            *counts.1 += 1;
        } else {
            counts.2.push(k);
        }
    }
}

impl Drop for SharedReader<'_> {
    fn drop(&mut self) {
        self.tree.count_reads(self.reads, self.local);
    }
}

impl TreeMemory for SharedReader<'_> {
    type Prefetch = NoPrefetch;

    fn is_empty(&self) -> bool {
        self.tree.layout().node_count == 0
    }

    #[inline(always)]
    fn node(&mut self, index: u32) -> &WideNode {
        let (k, at) = self.tree.layout().node_block(index);
        let counts = (&mut self.reads, &mut self.local, &mut self.footprint);
        Self::enter(self.tree, &mut self.nodes, k, counts);
        &nodes_of(self.nodes.held[self.nodes.current].chunks())[at as usize]
    }

    #[inline(always)]
    fn triangle(&mut self, slot: u32) -> &LeafTriangle {
        &self.triangles(slot..slot + 1)[0]
    }

    #[inline(always)]
    fn triangles(&mut self, slots: Range<u32>) -> &[LeafTriangle] {
        let layout = self.tree.layout();
        let (k, at, next) = layout.triangle_block(slots.start);
        let per = layout.triangles_per_block();
        let counts = (&mut self.reads, &mut self.local, &mut self.footprint);
        Self::enter(self.tree, &mut self.tris, k, counts);
        let end = slots.end.min(next) - slots.start + at;
        &triangles_of(self.tris.held[self.tris.current].chunks(), per)[at as usize..end as usize]
    }

    fn prefetcher(&self) -> NoPrefetch {
        NoPrefetch
    }
}
