//! What a render node traces a shared scene from: the top of the tree (held by every node),
//! its own share of the blocks, the direct-mapped cache of the others, and a fetch for what is
//! in neither; and [`DsmReader`], one thread's view of it, which a traversal reads through
//! [`TreeMemory`](crate::bvh::memory::TreeMemory).

use super::layout::{Block, BlockLayout, Chunk};
use super::DsmReader;
use serde::{Deserialize, Serialize};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};
use tessera_core::dsm::{BlockCache, BlockId, Residency};

/// Brings a block this node neither holds nor has in its cache.
///
/// A render thread either waits for the block ([`BlockFetch::fetch`]), or asks for it and goes
/// on with other work ([`BlockFetch::request`]), coming back when it has landed: the way the
/// frame loop traces a shared scene (`crate::parking`), so that a miss never idles a core.
pub trait BlockFetch: Send + Sync {
    /// Block `k`: asks its owner for it and waits for it. Called on a render thread, which
    /// waits alone: threads reading other blocks go on.
    ///
    /// # Panics
    /// When the block can be had from nowhere (every owner gone and the prepared files too):
    /// the frame cannot be rendered, and the render node fails with the message.
    fn fetch(&self, k: BlockId) -> Arc<Block>;

    /// Asks for block `k` without waiting: the returned landing is filled when it arrives
    /// (one landing per block however many ask). By default the block is fetched at once,
    /// which suits a fetch that has every block at hand.
    fn request(&self, k: BlockId) -> Landing {
        let landing = Landing::default();
        landing.land(self.fetch(k));
        landing
    }

    /// How many blocks have landed so far: what [`BlockFetch::wait_for_landing`] waits past.
    fn landings(&self) -> u64 {
        0
    }

    /// Waits until more than `seen` blocks have landed, or `timeout` has passed; `false` if
    /// nothing will land any more (the fetch loop is gone: [`BlockFetch::fetch`] still reads
    /// the block, from the prepared files).
    fn wait_for_landing(&self, seen: u64, timeout: Duration) -> bool {
        let _ = (seen, timeout);
        true
    }
}

/// Bounds on the blocks packets set aside keep alive beside the cache's (`crate::parking`):
/// past either, a packet that misses is traced again at once, its thread waiting for each
/// block it misses, instead of being set aside.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PinLimits {
    /// Bytes of blocks one packet's traces may keep (those they read or missed).
    pub per_packet: usize,
    /// Bytes of the distinct blocks all the packets set aside at once may keep or wait for.
    pub parked: usize,
}

impl Default for PinLimits {
    /// 4 MiB a packet (a packet of the gallery with ambient occlusion and mirrors reads about
    /// 300 other nodes' blocks of 2 KiB), and no bound on all of them: for a process with no
    /// memory budget.
    fn default() -> Self {
        PinLimits {
            per_packet: 4 << 20,
            parked: usize::MAX,
        }
    }
}

/// Where a block asked for with [`BlockFetch::request`] lands; clones share it.
#[derive(Clone, Default, Debug)]
pub struct Landing(Arc<OnceLock<Arc<Block>>>);

impl Landing {
    /// The block arrived (a second landing of the same block is ignored).
    pub fn land(&self, block: Arc<Block>) {
        let _ = self.0.set(block);
    }

    /// The block, once it has landed.
    pub fn block(&self) -> Option<&Arc<Block>> {
        self.0.get()
    }
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
    /// Time render threads waited for fetched blocks, in all: thread-seconds, a wait with
    /// nothing else to trace counted once for every thread of the pool.
    pub fetch_wait_s: f64,
    /// Traces of a packet set aside because a block was missing, to be traced again once it
    /// landed (`crate::parking`).
    pub parked: u64,
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
    parked: AtomicU64,
    /// Whether the frame loop sets a packet that misses aside (`crate::parking`) rather than
    /// waiting for its block on the render thread.
    parks_misses: std::sync::atomic::AtomicBool,
    /// Bounds on the memory parked packets keep beside the cache (see [`PinLimits`]).
    pin_limits: std::sync::Mutex<PinLimits>,
    /// What a traversal reads in place of a block that is not here yet: a node block of
    /// nodes no ray enters, a triangle block of triangles no ray hits (all corners NaN).
    absent_nodes: Box<[Chunk]>,
    absent_triangles: Box<[Chunk]>,
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
            parked: AtomicU64::new(0),
            parks_misses: std::sync::atomic::AtomicBool::new(true),
            pin_limits: std::sync::Mutex::new(PinLimits::default()),
            absent_nodes: absent_block(chunks_per_block, &[crate::bvh::node::BLANK]),
            absent_triangles: absent_block(chunks_per_block, &[NAN_TRIANGLE]),
        })
    }

    /// What a traversal reads in place of a missing node block (`triangles` false) or
    /// triangle block: nothing a ray can enter or hit.
    pub(super) fn absent(&self, triangles: bool) -> &[Chunk] {
        if triangles {
            &self.absent_triangles
        } else {
            &self.absent_nodes
        }
    }

    /// Whether a packet that misses a block is set aside and traced again once it landed (the
    /// default), or its render thread waits for the block (as before packets were parked: for
    /// measuring one against the other).
    pub fn set_parks_misses(&self, on: bool) {
        self.parks_misses.store(on, Ordering::Relaxed);
    }

    /// Bounds the memory that packets set aside keep beside the cache: a memory budget must
    /// hold it (a render node counts it before it sizes its cache).
    pub fn set_pin_limits(&self, limits: PinLimits) {
        *self.pin_limits.lock().unwrap_or_else(|e| e.into_inner()) = limits;
    }

    /// See [`DsmTree::set_pin_limits`].
    pub fn pin_limits(&self) -> PinLimits {
        *self.pin_limits.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// See [`DsmTree::set_parks_misses`].
    pub fn parks_misses(&self) -> bool {
        self.parks_misses.load(Ordering::Relaxed)
    }

    /// The fetch this tree's misses go to.
    pub fn fetcher(&self) -> &dyn BlockFetch {
        &*self.fetch
    }

    /// Puts block `k`, which landed for a packet set aside, in the cache unless it is there
    /// (a fetch loop puts what arrives there itself; other fetches may not).
    pub(crate) fn cache_landed(&self, k: BlockId, block: &Arc<Block>) {
        let lines = self.cache.lines();
        if lines == 0 || self.local(k).is_some() {
            return;
        }
        let line = self.residency.cache_line(k, lines);
        if !self.cache.holds(k, line) {
            self.cache.insert(k, line, block.clone());
        }
    }

    /// Counts a block missed and asked for without waiting (one a packet was set aside for).
    pub(super) fn count_missed(&self) {
        self.fetched.fetch_add(1, Ordering::Relaxed);
    }

    /// Counts `packets` traces set aside for a missing block.
    pub(crate) fn count_parked(&self, packets: u64) {
        self.parked.fetch_add(packets, Ordering::Relaxed);
    }

    /// Counts thread time spent with nothing to trace but what waits for blocks.
    pub(crate) fn count_idle(&self, thread_time: Duration) {
        self.fetch_wait_ns
            .fetch_add(thread_time.as_nanos() as u64, Ordering::Relaxed);
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
            parked: self.parked.load(Ordering::Relaxed),
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

    /// Block `k` if it is here without asking anyone: this node's own memory, the cache, or
    /// `pins` (blocks the caller keeps alive). The cache is looked at before the pins: it
    /// usually has the block, and a trace's pins grow to hundreds (ambient occlusion on the
    /// dragon spent a tenth of its time scanning them).
    pub(super) fn try_hold(&self, k: BlockId, pins: &[(BlockId, Arc<Block>)]) -> Option<Hold<'_>> {
        if let Some(chunks) = self.local(k) {
            return Some(Hold::Local(chunks));
        }
        let lines = self.cache.lines();
        let line = self.residency.cache_line(k, lines);
        let cached = (lines > 0).then(|| self.cache.get(k, line)).flatten();
        cached
            .or_else(|| pins.iter().find(|(p, _)| *p == k).map(|(_, b)| b.clone()))
            .map(Hold::Cached)
    }

    /// Block `k`, from wherever it is: this node's own memory, the cache, or its owner.
    pub(super) fn hold(&self, k: BlockId) -> Hold<'_> {
        if let Some(held) = self.try_hold(k, &[]) {
            return held;
        }
        let t0 = Instant::now();
        let block = self.fetch.fetch(k);
        self.fetch_wait_ns
            .fetch_add(t0.elapsed().as_nanos() as u64, Ordering::Relaxed);
        self.fetched.fetch_add(1, Ordering::Relaxed);
        let lines = self.cache.lines();
        if lines > 0 {
            let line = self.residency.cache_line(k, lines);
            self.cache.insert(k, line, block.clone());
        }
        Hold::Cached(block)
    }
}

/// A triangle no ray hits: every test of it compares a NaN.
const NAN_TRIANGLE: crate::bvh::node::LeafTriangle = crate::bvh::node::LeafTriangle {
    a: glam::Vec3::NAN,
    b: glam::Vec3::NAN,
    c: glam::Vec3::NAN,
};

/// A block of `chunks` chunks holding `item` over and over (as many whole items as fit).
fn absent_block<T: bytemuck::Pod>(chunks: usize, item: &[T; 1]) -> Box<[Chunk]> {
    let mut block = vec![Chunk([0; 64]); chunks].into_boxed_slice();
    let bytes: &mut [u8] = bytemuck::cast_slice_mut(&mut block);
    let one: &[u8] = bytemuck::cast_slice(item);
    for at in bytes.chunks_exact_mut(one.len()) {
        at.copy_from_slice(one);
    }
    block
}

/// A block a reader is in: its own memory's, a cached one it keeps alive while it reads it, or
/// the stand-in for one that has not landed yet.
pub(super) enum Hold<'s> {
    Nothing,
    Local(&'s [Chunk]),
    Cached(Arc<Block>),
    Absent(&'s [Chunk]),
}

impl Hold<'_> {
    #[inline(always)]
    pub(super) fn chunks(&self) -> &[Chunk] {
        match self {
            Hold::Local(chunks) | Hold::Absent(chunks) => chunks,
            Hold::Cached(block) => block.chunks(),
            Hold::Nothing => &[],
        }
    }
}

/// Fills `cache` from the prepared files before the first frame, as a replicated node loads
/// its copy before it: every block this node does not hold (as `residency` and `layout`'s top
/// blocks say), lowest first, into the lines still vacant, so the top of the tree and the
/// nodes above the leaves win a line over the blocks that map to it after them. Without it a
/// shared node's first frames fetch their whole working set on demand (with a whole-scene
/// cache, the dragon's first 15 frames ran at 0.64 of replicated against 0.71 over 60).
/// Returns the blocks read.
///
/// # Errors
/// A block that cannot be read, or does not match its checksum.
pub fn warm_cache(
    (layout, residency): (&BlockLayout, &Residency),
    cache: &BlockCache<Block>,
    pool: &Arc<super::pool::BlockPool>,
    file: &mut super::prepare::BlockFile,
) -> Result<u64, super::PrepareError> {
    let lines = cache.lines();
    let mut read = 0;
    for k in layout.top_blocks..layout.total() {
        if read as usize >= lines {
            break;
        }
        if residency.resident_slot(k).is_some() {
            continue;
        }
        let line = residency.cache_line(k, lines);
        if cache.is_vacant(line) {
            let mut block = pool.take();
            file.read_into(k, block.chunks_mut())?;
            cache.insert(k, line, Arc::new(block));
            read += 1;
        }
    }
    Ok(read)
}
