//! The direct-mapped cache of remote blocks that a render node's threads share.

use super::BlockId;
use serde::{Deserialize, Serialize};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, PoisonError, RwLock};

/// A direct-mapped cache of blocks of type B, one reader/writer guard per line. A reader
/// takes the line's read guard only long enough to check the tag and clone the block's Arc,
/// then keeps the block as long as it uses it (the Arc), so a thread replacing the line never
/// waits for readers of the old block and a miss never blocks threads that hit other lines.
///
/// The paper's threads hold a line's guard while they traverse its block, and must release
/// it before entering the next block lest two blocks of one path want the same line; with
/// the Arc a thread may hold any number of blocks and no such rule is needed.
///
/// Which line a block goes to is the caller's choice ([`super::Residency::cache_line`]); the
/// tag keeps a block read under another block's number from ever being returned.
#[derive(Debug)]
pub struct BlockCache<B> {
    lines: Box<[RwLock<Option<Line<B>>>]>,
    hits: AtomicU64,
    misses: AtomicU64,
    evictions: AtomicU64,
    filled: AtomicU64,
}

#[derive(Debug)]
struct Line<B> {
    block: BlockId,
    data: Arc<B>,
}

/// What a [`BlockCache`] has counted since it was made.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct CacheStats {
    /// Lookups that found their block.
    pub hits: u64,
    /// Lookups that did not.
    pub misses: u64,
    /// Insertions that replaced a different block.
    pub evictions: u64,
    /// Lines holding a block (lines are filled once and never emptied).
    pub filled: u64,
}

impl<B> BlockCache<B> {
    /// An empty cache of `lines` lines; with 0 lines every lookup misses and nothing is kept.
    pub fn new(lines: usize) -> Self {
        BlockCache {
            lines: (0..lines).map(|_| RwLock::new(None)).collect(),
            hits: AtomicU64::new(0),
            misses: AtomicU64::new(0),
            evictions: AtomicU64::new(0),
            filled: AtomicU64::new(0),
        }
    }

    /// Number of lines.
    pub fn lines(&self) -> usize {
        self.lines.len()
    }

    /// Block k if `line` holds it, counting a hit or a miss. `line` must be below
    /// [`BlockCache::lines`] (any line of a 0-line cache misses).
    pub fn get(&self, k: BlockId, line: usize) -> Option<Arc<B>> {
        let found = self.line(line).and_then(|slot| {
            // A writer that panicked left either the old line or the new one, both whole.
            let guard = slot.read().unwrap_or_else(PoisonError::into_inner);
            guard
                .as_ref()
                .filter(|l| l.block == k)
                .map(|l| Arc::clone(&l.data))
        });
        let counter = if found.is_some() {
            &self.hits
        } else {
            &self.misses
        };
        counter.fetch_add(1, Ordering::Relaxed);
        found
    }

    /// Whether `line` holds block k now, counting nothing (a prefetcher asking what to
    /// fetch is not a reader).
    pub fn holds(&self, k: BlockId, line: usize) -> bool {
        self.line(line).is_some_and(|slot| {
            let guard = slot.read().unwrap_or_else(PoisonError::into_inner);
            guard.as_ref().is_some_and(|l| l.block == k)
        })
    }

    /// Whether `line` holds no block yet.
    pub fn is_vacant(&self, line: usize) -> bool {
        self.line(line).is_some_and(|slot| {
            let guard = slot.read().unwrap_or_else(PoisonError::into_inner);
            guard.is_none()
        })
    }

    /// Puts block k in `line`, replacing whatever was there (an eviction if it was another
    /// block). Readers of the old block keep it until they drop it.
    pub fn insert(&self, k: BlockId, line: usize, block: Arc<B>) {
        let Some(slot) = self.line(line) else {
            return;
        };
        let old = {
            let mut guard = slot.write().unwrap_or_else(PoisonError::into_inner);
            guard.replace(Line {
                block: k,
                data: block,
            })
        };
        match &old {
            None => self.filled.fetch_add(1, Ordering::Relaxed),
            Some(l) if l.block != k => self.evictions.fetch_add(1, Ordering::Relaxed),
            Some(_) => 0,
        };
        // `old` drops here, after the guard: freeing a large block never holds up the line.
    }

    /// The counters so far (each read on its own: a snapshot of a busy cache may be a few
    /// lookups apart between fields).
    pub fn stats(&self) -> CacheStats {
        CacheStats {
            hits: self.hits.load(Ordering::Relaxed),
            misses: self.misses.load(Ordering::Relaxed),
            evictions: self.evictions.load(Ordering::Relaxed),
            filled: self.filled.load(Ordering::Relaxed),
        }
    }

    fn line(&self, line: usize) -> Option<&RwLock<Option<Line<B>>>> {
        debug_assert!(
            line < self.lines.len() || self.lines.is_empty(),
            "line {line} of a {}-line cache",
            self.lines.len()
        );
        self.lines.get(line)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::Rng;
    use std::thread;

    /// Block k's content: every word depends on k, so a torn or mislabelled block shows.
    fn content(k: BlockId) -> [u64; 8] {
        std::array::from_fn(|i| u64::from(k).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ i as u64)
    }

    #[test]
    fn a_lookup_hits_only_the_block_its_line_holds() {
        let cache = BlockCache::new(4);
        assert!(cache.get(5, 1).is_none());
        cache.insert(5, 1, Arc::new(content(5)));
        assert_eq!(*cache.get(5, 1).unwrap(), content(5));
        assert!(cache.get(9, 1).is_none(), "same line, other tag");
        cache.insert(5, 1, Arc::new(content(5)));
        cache.insert(9, 1, Arc::new(content(9)));
        assert_eq!(
            cache.stats(),
            CacheStats {
                hits: 1,
                misses: 2,
                evictions: 1,
                filled: 1
            }
        );
    }

    #[test]
    fn a_reader_keeps_its_block_after_the_line_is_replaced() {
        let cache = BlockCache::new(1);
        cache.insert(3, 0, Arc::new(content(3)));
        let held = cache.get(3, 0).unwrap();
        cache.insert(4, 0, Arc::new(content(4)));
        assert_eq!(*held, content(3));
        assert_eq!(*cache.get(4, 0).unwrap(), content(4));
    }

    #[test]
    fn a_cache_of_no_lines_misses_every_lookup() {
        let cache = BlockCache::new(0);
        cache.insert(1, 0, Arc::new(content(1)));
        assert!(cache.get(1, 0).is_none());
        assert_eq!(cache.lines(), 0);
        assert_eq!(cache.stats().misses, 1);
        assert_eq!(cache.stats().filled, 0);
    }

    #[test]
    fn threads_reading_and_replacing_lines_at_once_always_read_the_block_they_asked_for() {
        const THREADS: u64 = 6;
        const LOOKUPS: u64 = 4000;
        let cache = Arc::new(BlockCache::new(16));
        let workers: Vec<_> = (0..THREADS)
            .map(|t| {
                let cache = Arc::clone(&cache);
                thread::spawn(move || {
                    let mut rng = Rng::derived(11, t);
                    for _ in 0..LOOKUPS {
                        // 64 blocks on 16 lines: four blocks fight over each line.
                        let k = (rng.next_u64() % 64) as BlockId;
                        let line = k as usize % 16;
                        match cache.get(k, line) {
                            Some(block) => assert_eq!(*block, content(k), "block {k}"),
                            None => cache.insert(k, line, Arc::new(content(k))),
                        }
                    }
                })
            })
            .collect();
        for w in workers {
            w.join().expect("a reader saw another block's content");
        }
        let stats = cache.stats();
        assert_eq!(stats.hits + stats.misses, THREADS * LOOKUPS);
        assert!(stats.hits > 0 && stats.evictions > 0, "{stats:?}");
        assert_eq!(stats.filled, 16);
    }
}
