//! Where a node's fetched blocks live: block-sized slots allocated at start, which blocks take
//! and give back, so that what the cache and the blocks in flight use is
//! bounded by the region and stays put. Blocks allocated one by one from the heap, fetched and
//! evicted thousands of times a frame, left the allocator's heaps at two to three times the
//! bytes of the blocks alive in them (a 30 MiB cache in 60-90 MiB of heap).

use super::layout::{Block, Chunk};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

/// A fixed set of block slots.
pub struct BlockPool {
    /// Each free slot's chunks: a slot's memory moves between the pool and its block and is
    /// never freed until the pool is.
    free: Mutex<Vec<Box<[Chunk]>>>,
    block_bytes: u32,
    slots: u32,
    /// Blocks asked for when every slot was in use (allocated on their own instead).
    overflow: AtomicU64,
}

impl BlockPool {
    /// `slots` blocks of `block_bytes`.
    pub fn new(slots: u32, block_bytes: u32) -> Arc<BlockPool> {
        let per = (block_bytes / 64) as usize;
        // Slot by slot rather than one region split up: a Box must free what it allocated.
        // Untouched, a slot costs no resident memory; one fetched into stays resident for good,
        // which is the point.
        let free = (0..slots)
            .map(|_| vec![Chunk([0; 64]); per].into_boxed_slice())
            .collect();
        Arc::new(BlockPool {
            free: Mutex::new(free),
            block_bytes,
            slots,
            overflow: AtomicU64::new(0),
        })
    }

    /// A block whose bytes are to be filled: a free slot, or, when every slot is in use, a
    /// block allocated on its own (counted in [`BlockPool::overflow`]).
    pub fn take(self: &Arc<Self>) -> Block {
        let slot = self.free.lock().unwrap_or_else(|e| e.into_inner()).pop();
        match slot {
            Some(chunks) => Block::pooled(chunks, self.clone()),
            None => {
                self.overflow.fetch_add(1, Ordering::Relaxed);
                Block::zeroed(self.block_bytes)
            }
        }
    }

    pub(super) fn give_back(&self, chunks: Box<[Chunk]>) {
        self.free
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push(chunks);
    }

    /// How many slots the pool was made with.
    pub fn slots(&self) -> u32 {
        self.slots
    }

    /// Blocks allocated outside the pool because it was empty.
    pub fn overflow(&self) -> u64 {
        self.overflow.load(Ordering::Relaxed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slots_go_round_and_an_empty_pool_still_gives_blocks() {
        let pool = BlockPool::new(2, 2048);
        let mut a = pool.take();
        a.bytes_mut()[0] = 7;
        let b = pool.take();
        let c = pool.take();
        assert_eq!(pool.overflow(), 1);
        assert_eq!(c.bytes().len(), 2048);
        drop(a);
        // The slot came back (with whatever it held: a taker overwrites it).
        let again = pool.take();
        assert_eq!(again.bytes()[0], 7);
        assert_eq!(pool.overflow(), 1);
        drop((b, c, again));
        assert_eq!(pool.free.lock().unwrap().len(), 2);
    }
}
