//! What the wire carries for a scene in distributed shared memory: how the session shares it,
//! where the render nodes that hold its blocks are, the block requests render nodes send each
//! other, and what each node reports of its reads.
//!
//! A block request travels on a bidirectional stream of its own, render node to render node:
//! a length-prefixed [`BlockRequest`] (postcard, like every control message), answered on the
//! same stream by, for each block asked in order, a [`BLOCK_HEADER_LEN`]-byte header (the
//! block's id, little-endian, and whether it follows) and then, if it does, its raw bytes.

use serde::{Deserialize, Serialize};
use std::net::SocketAddr;
use std::path::PathBuf;

/// Most blocks one request may ask for.
pub const MAX_BLOCKS_PER_REQUEST: usize = 4096;
/// Most render nodes that hold blocks.
pub const MAX_RANKS: u32 = 4096;

/// How the render nodes hold the scene.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum DataSpec {
    /// Every render node loads the whole scene.
    Replicated,
    /// The scene is prepared in blocks, each render node holds a share (see [`DsmSpec`]).
    Dsm(DsmSpec),
}

/// A scene shared in blocks: where they are prepared, how they are spread.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DsmSpec {
    /// The prepared folder on the master's host; a render node's `--prepared` names its own.
    pub dir: PathBuf,
    /// Size of one block in bytes: the unit of sharing, fetching and caching.
    pub block_bytes: u32,
    /// Render nodes that hold blocks (the first to join); more render nodes hold none. 0:
    /// none holds any, each reads the blocks it misses from the prepared files into its cache
    /// (out of core: the files on one machine or a shared filesystem).
    pub ranks: u32,
    /// Nodes that hold each block (2: a second owner, so a death loses nothing).
    pub replicas: u32,
    /// Bytes a render node may use in all, unless its own `--memory-budget` says.
    pub memory_budget: Option<u64>,
    /// The cache as a share of the scene's blocks, in place of what the budget leaves (an
    /// experiment's knob).
    pub cache_fraction: Option<f32>,
}

/// Why a shared scene's spread was refused.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum DsmSpecError {
    /// More render nodes were to hold blocks than [`MAX_RANKS`].
    #[error("{0} ranks (0 to {MAX_RANKS})")]
    Ranks(u32),
    /// Each block was to have no holder, or more holders than there are ranks.
    #[error("{replicas} replicas of {ranks} ranks")]
    Replicas {
        /// Holders each block was to have.
        replicas: u32,
        /// Render nodes that hold blocks.
        ranks: u32,
    },
    /// The cache fraction is not above 0 and at most 1 (or is NaN).
    #[error("cache fraction {0} (0 < f <= 1)")]
    CacheFraction(f32),
}

impl DsmSpec {
    /// Checks the spread.
    ///
    /// # Errors
    /// More ranks than [`MAX_RANKS`], replicas not within 1..=ranks (1 out of core), a cache
    /// fraction not in (0, 1].
    pub fn check(&self) -> Result<(), DsmSpecError> {
        if self.ranks > MAX_RANKS {
            return Err(DsmSpecError::Ranks(self.ranks));
        }
        if !(1..=self.ranks.max(1)).contains(&self.replicas) {
            return Err(DsmSpecError::Replicas {
                replicas: self.replicas,
                ranks: self.ranks,
            });
        }
        if let Some(f) = self.cache_fraction {
            if !(f > 0.0 && f <= 1.0) {
                return Err(DsmSpecError::CacheFraction(f));
            }
        }
        Ok(())
    }
}

/// A render node that holds blocks, and where it answers requests for them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct BlockHolder {
    /// Its rank, 0 to `ranks - 1`: which share of the blocks it holds.
    pub rank: u32,
    /// Where it answers block requests.
    pub addr: SocketAddr,
}

/// Render node → render node: send me these blocks.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct BlockRequest {
    /// The ids of the blocks wanted, at most [`MAX_BLOCKS_PER_REQUEST`]; they are answered in
    /// this order.
    pub blocks: Vec<u32>,
    /// Asked ahead of need (a prefetch): answered after the blocks render threads wait for.
    pub ahead: bool,
}

/// The header before each answered block: its id and whether its bytes follow (a node asked
/// for a block it does not hold says so, and the asker goes elsewhere).
pub const BLOCK_HEADER_LEN: usize = 5;

/// The header of block `block`'s answer; `follows` says its bytes come after it.
pub fn encode_block_header(block: u32, follows: bool) -> [u8; BLOCK_HEADER_LEN] {
    let b = block.to_le_bytes();
    [b[0], b[1], b[2], b[3], follows as u8]
}

/// A block answer's header whose "follows" byte is neither 0 nor 1.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error("block {block}: bad header byte {byte}")]
pub struct BadBlockHeader {
    /// The block id the header names.
    pub block: u32,
    /// The "follows" byte as it arrived.
    pub byte: u8,
}

/// A block answer's header: the block's id, and whether its bytes follow.
///
/// # Errors
/// A "follows" byte other than 0 or 1.
pub fn decode_block_header(raw: [u8; BLOCK_HEADER_LEN]) -> Result<(u32, bool), BadBlockHeader> {
    let block = u32::from_le_bytes([raw[0], raw[1], raw[2], raw[3]]);
    match raw[4] {
        0 => Ok((block, false)),
        1 => Ok((block, true)),
        byte => Err(BadBlockHeader { block, byte }),
    }
}

/// What a render node of a shared scene measured of its reads. Seconds and microseconds are
/// checked on arrival like every figure the master divides by.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DsmStats {
    /// Its rank, if it held blocks.
    pub rank: Option<u32>,
    /// Bytes of the scene it held for good (the top of the tree and its share).
    pub resident_bytes: u64,
    /// Bytes of its cache of other nodes' blocks: `cache_lines` blocks.
    pub cache_bytes: u64,
    /// Blocks its cache holds at once.
    pub cache_lines: u64,
    /// Blocks a traversal moved into (each block read, however many tree nodes it read there).
    pub block_reads: u64,
    /// Of those, blocks this node holds for good (the top of the tree, its share).
    pub local_reads: u64,
    /// Of those, blocks that had to be fetched (cache misses).
    pub fetched: u64,
    /// Render threads' time waiting for fetched blocks, in all (thread-seconds: a wait with
    /// nothing else to trace counts once for each thread).
    pub fetch_wait_s: f64,
    /// Its render threads: with the time it rendered, what `fetch_wait_s` is a share of.
    pub render_threads: u32,
    /// Packets set aside for a missing block and traced again once it landed.
    pub parked: u64,
    /// The memory budget it kept to, in bytes (its own `--memory-budget` or the session's); 0
    /// if it had none.
    pub memory_budget: u64,
    /// Cache lookups that found their block.
    pub cache_hits: u64,
    /// Cache lookups that did not: the block was fetched.
    pub cache_misses: u64,
    /// Cache lines overwritten with another block.
    pub evictions: u64,
    /// [`BlockRequest`] messages sent.
    pub requests: u64,
    /// Blocks asked for in those messages (a block asked again counts again).
    pub blocks_requested: u64,
    /// Blocks that arrived while wanted, from a peer or from the prepared files.
    pub blocks_arrived: u64,
    /// Blocks asked for again after a timeout.
    pub retries: u64,
    /// Blocks read from the prepared files because none of their holders was left.
    pub read_locally: u64,
    /// Blocks asked for ahead of need (prefetches).
    pub prefetched: u64,
    /// Remote reads timed, from when a block was first wanted to its arrival.
    pub latency_count: u64,
    /// Fastest remote read, in microseconds.
    pub latency_min_us: f64,
    /// Mean remote read, in microseconds.
    pub latency_avg_us: f64,
    /// Slowest remote read, in microseconds.
    pub latency_max_us: f64,
    /// 99th percentile of remote reads, in microseconds.
    pub latency_p99_us: f64,
    /// Round trip of an empty request to a peer on the same connections (the transport's
    /// floor under a remote read), the fastest seen; 0 when never measured.
    pub round_trip_us: f64,
}

impl DsmStats {
    /// Checks the figures the master divides by or prints as times.
    ///
    /// # Errors
    /// A figure that is not finite or is negative, with its field's name.
    pub fn check(&self) -> Result<(), (&'static str, f64)> {
        for (field, v) in [
            ("fetch_wait_s", self.fetch_wait_s),
            ("latency_min_us", self.latency_min_us),
            ("latency_avg_us", self.latency_avg_us),
            ("latency_max_us", self.latency_max_us),
            ("latency_p99_us", self.latency_p99_us),
            ("round_trip_us", self.round_trip_us),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err((field, v));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn block_headers_round_trip_and_bad_flags_are_refused() {
        for (k, f) in [(0, false), (7, true), (u32::MAX, true)] {
            assert_eq!(decode_block_header(encode_block_header(k, f)), Ok((k, f)));
        }
        let mut bad = encode_block_header(3, true);
        bad[4] = 2;
        let error = decode_block_header(bad).unwrap_err();
        assert_eq!(error, BadBlockHeader { block: 3, byte: 2 });
        assert_eq!(error.to_string(), "block 3: bad header byte 2");
    }

    #[test]
    fn a_shared_spec_out_of_bounds_is_refused() {
        let ok = DsmSpec {
            dir: "/tmp/x".into(),
            block_bytes: 8192,
            ranks: 4,
            replicas: 2,
            memory_budget: None,
            cache_fraction: Some(0.125),
        };
        assert!(ok.check().is_ok());
        let out_of_core = DsmSpec {
            ranks: 0,
            replicas: 1,
            ..ok.clone()
        };
        assert!(out_of_core.check().is_ok());
        for bad in [
            DsmSpec {
                ranks: MAX_RANKS + 1,
                ..ok.clone()
            },
            DsmSpec {
                ranks: 0,
                ..ok.clone()
            },
            DsmSpec {
                replicas: 5,
                ..ok.clone()
            },
            DsmSpec {
                cache_fraction: Some(0.0),
                ..ok.clone()
            },
            DsmSpec {
                cache_fraction: Some(f32::NAN),
                ..ok.clone()
            },
        ] {
            assert!(bad.check().is_err(), "{bad:?}");
        }
    }
}
