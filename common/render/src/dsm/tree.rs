//! What a render node traces a shared scene from: the top of the tree (held by every node),
//! its own share of the blocks, the direct-mapped cache of the others, and a fetch for what is
//! in neither; and [`DsmReader`], one thread's view of it, which a traversal reads through
//! [`TreeMemory`](crate::bvh::memory::TreeMemory).

use super::layout::{Block, BlockLayout, Chunk};
use super::DsmReader;
use serde::{Deserialize, Serialize};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Instant;
use tessera_core::dsm::{BlockCache, BlockId, Residency};

/// Brings a block this node neither holds nor has in its cache.
pub trait BlockFetch: Send + Sync {
    /// Block `k`: asks its owner for it and waits for it. Called on a render thread, which
    /// waits alone: threads reading other blocks go on.
    ///
    /// # Panics
    /// When the block can be had from nowhere (every owner gone and the prepared files too):
    /// the frame cannot be rendered, and the render node fails with the message.
    fn fetch(&self, k: BlockId) -> Arc<Block>;
}

/// Counters of one node's reads, over its run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DsmTreeStats {
    /// Blocks a traversal moved into (each block read, however many nodes it read there).
    pub block_reads: u64,
    /// Of those, blocks this node holds (the top of the tree, its share).
    pub local_reads: u64,
    /// Of those, blocks that had to be fetched (cache misses).
    pub fetched: u64,
    /// Time render threads waited for fetched blocks, in all.
    pub fetch_wait_s: f64,
}

/// A scene's tree and triangles in distributed shared memory, as one render node holds them.
pub struct DsmTree {
    layout: BlockLayout,
    residency: Residency,
    chunks_per_block: usize,
    /// Blocks `0..layout.top_blocks`, which every node holds.
    top: Box<[Chunk]>,
    /// This node's share, at its residency's slots.
    resident: Box<[Chunk]>,
    cache: Arc<BlockCache<Block>>,
    fetch: Arc<dyn BlockFetch>,
    block_reads: AtomicU64,
    local_reads: AtomicU64,
    fetched: AtomicU64,
    fetch_wait_ns: AtomicU64,
}

/// Arrays that do not match the layout they come with.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
#[error("{what} holds {got} bytes where the layout needs {want}")]
pub struct SizeMismatch {
    what: &'static str,
    got: usize,
    want: usize,
}

impl DsmTree {
    /// The tree from its parts: `top` holds blocks `0..layout.top_blocks`, `resident` the
    /// blocks `residency` gives this node at their slots; the rest is read through `cache`,
    /// and fetched by `fetch` when the cache does not have it.
    ///
    /// # Errors
    /// `top` or `resident` not the size the layout and residency call for.
    pub fn new(
        layout: BlockLayout,
        residency: Residency,
        top: Box<[Chunk]>,
        resident: Box<[Chunk]>,
        cache: Arc<BlockCache<Block>>,
        fetch: Arc<dyn BlockFetch>,
    ) -> Result<DsmTree, SizeMismatch> {
        let chunks_per_block = (layout.block_bytes / 64) as usize;
        let check = |what, got: usize, blocks: usize| {
            let want = blocks * chunks_per_block;
            if got == want {
                Ok(())
            } else {
                Err(SizeMismatch {
                    what,
                    got: got * 64,
                    want: want * 64,
                })
            }
        };
        check("the top of the tree", top.len(), layout.top_blocks as usize)?;
        check(
            "the resident share",
            resident.len(),
            residency.resident_len(),
        )?;
        Ok(DsmTree {
            layout,
            residency,
            chunks_per_block,
            top,
            resident,
            cache,
            fetch,
            block_reads: AtomicU64::new(0),
            local_reads: AtomicU64::new(0),
            fetched: AtomicU64::new(0),
            fetch_wait_ns: AtomicU64::new(0),
        })
    }

    /// Where the nodes and triangles sit in blocks.
    pub fn layout(&self) -> &BlockLayout {
        &self.layout
    }

    /// Which blocks this node holds for good, and where in its share.
    pub fn residency(&self) -> &Residency {
        &self.residency
    }

    /// The cache of blocks this node does not hold, shared by its render threads.
    pub fn cache(&self) -> &BlockCache<Block> {
        &self.cache
    }

    /// Bytes this node holds of the scene for good: the top of the tree and its share.
    pub fn resident_bytes(&self) -> usize {
        (self.top.len() + self.resident.len()) * 64
    }

    /// One thread's reader; make one per thread and keep it across rays.
    pub fn reader(&self) -> DsmReader<'_> {
        DsmReader::new(self)
    }

    /// Adds one reader's counts (when it is done).
    pub(super) fn count_reads(&self, reads: u64, local: u64) {
        self.block_reads.fetch_add(reads, Ordering::Relaxed);
        self.local_reads.fetch_add(local, Ordering::Relaxed);
    }

    /// The read and fetch counters so far (readers add theirs when they are dropped).
    pub fn stats(&self) -> DsmTreeStats {
        DsmTreeStats {
            block_reads: self.block_reads.load(Ordering::Relaxed),
            local_reads: self.local_reads.load(Ordering::Relaxed),
            fetched: self.fetched.load(Ordering::Relaxed),
            fetch_wait_s: self.fetch_wait_ns.load(Ordering::Relaxed) as f64 * 1e-9,
        }
    }

    /// Whether block `k` is here now: held by this node or in its cache (a prefetch of it
    /// would be wasted).
    pub fn is_here(&self, k: BlockId) -> bool {
        let lines = self.cache.lines();
        self.local(k).is_some()
            || (lines > 0 && self.cache.holds(k, self.residency.cache_line(k, lines)))
    }

    /// Block `k`'s bytes if this node holds it.
    pub fn local(&self, k: BlockId) -> Option<&[Chunk]> {
        let (array, slot) = if self.layout.is_top(k) {
            (&self.top, k as usize)
        } else {
            (&self.resident, self.residency.resident_slot(k)?)
        };
        let at = slot * self.chunks_per_block;
        array.get(at..at + self.chunks_per_block)
    }

    /// Block `k`, from wherever it is: this node's own memory, the cache, or its owner.
    pub(super) fn hold(&self, k: BlockId) -> Hold<'_> {
        if let Some(chunks) = self.local(k) {
            return Hold::Local(chunks);
        }
        let line = self.residency.cache_line(k, self.cache.lines());
        if let Some(block) = (self.cache.lines() > 0)
            .then(|| self.cache.get(k, line))
            .flatten()
        {
            return Hold::Cached(block);
        }
        let t0 = Instant::now();
        let block = self.fetch.fetch(k);
        self.fetch_wait_ns
            .fetch_add(t0.elapsed().as_nanos() as u64, Ordering::Relaxed);
        self.fetched.fetch_add(1, Ordering::Relaxed);
        if self.cache.lines() > 0 {
            self.cache.insert(k, line, block.clone());
        }
        Hold::Cached(block)
    }
}

/// A block a reader is in: its own memory's, or a cached one it keeps alive while it reads it.
pub(super) enum Hold<'s> {
    Nothing,
    Local(&'s [Chunk]),
    Cached(Arc<Block>),
}

impl Hold<'_> {
    #[inline(always)]
    pub(super) fn chunks(&self) -> &[Chunk] {
        match self {
            Hold::Local(chunks) => chunks,
            Hold::Cached(block) => block.chunks(),
            Hold::Nothing => &[],
        }
    }
}
