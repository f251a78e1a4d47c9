//! Read-only distributed shared memory (DSM): how render nodes share a scene larger than any
//! one node's memory, after Ize et al. 2011, §4 (itself after DeMarle et al. 2005).
//!
//! The scene's data is cut into fixed-size blocks numbered `0..total`; what a block holds
//! (BVH nodes, triangles, bricks) is the renderer's business, not this module's. Each node
//! keeps a resident share, interleaved so that the blocks of any one region of the scene are
//! spread over every node: block k lives on node `k mod N`, at slot `k / N` of its resident
//! array. A block a node does not hold is fetched from its owner and kept in a direct-mapped
//! cache, at the line given by the paper's mapping `(k − ⌊(k + N − rank) / N⌋) mod lines`,
//! which counts only the blocks the node does not hold, so that no line waits for a block that
//! never comes to it and a cache as large as the rest of the scene holds all of it at once.
//!
//! Three parts:
//!
//! * [`Residency`]: who holds which block and where, and the cache line of the others.
//! * [`BlockCache`]: the cache every render thread of a node reads at once, one
//!   reader/writer guard per line, blocks handed out as `Arc`s.
//! * [`Fetcher`]: the fetch protocol, sans-IO: misses in, request messages out, answers,
//!   timeouts and lost peers in.
//!
//! Where this departs from the paper: remote reads are messages a peer answers, not RDMA
//! reads, so misses are batched per peer ([`FetchConfig::batch_max`]); a block can have a
//! second owner ([`Residency::replicas`]) so that a node's death loses nothing, and a block
//! whose every owner is gone is read from the prepared files on disk
//! ([`FetchOutput::ReadLocally`]); and a thread keeps a block by its `Arc`, not by holding the
//! line's guard, so it may hold several blocks at once without the paper's deadlock rule.
//!
//! Who drives it: a render node's driver loop owns the [`Fetcher`]. Render threads look a
//! block up in the resident array, then in the [`BlockCache`]; on a miss they tell the driver
//! and wait for the block. The driver calls [`Fetcher::handle_miss`] for each miss it drains,
//! then [`Fetcher::flush`], sends what [`Fetcher::poll_output`] asks, and when a block
//! arrives inserts it in the cache, calls [`Fetcher::handle_arrived`] and wakes the threads
//! that wait for it; [`Fetcher::poll_timeout`] tells it when to call
//! [`Fetcher::handle_timeout`], and the transport tells it of lost peers.
//! [`sim::DsmSim`] drives the same parts for many virtual nodes over a simulated network.

mod cache;
mod fetch;
mod residency;
pub mod sim;
#[cfg(test)]
mod sim_tests;

pub use cache::{BlockCache, CacheStats};
pub use fetch::{FetchConfig, FetchOutput, FetchStats, Fetcher, LatencySummary};
pub use residency::{BlockId, Residency};

/// A DSM layout that cannot exist.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum DsmError {
    /// No node to hold the blocks.
    #[error("a DSM needs at least one node to hold its blocks (ranks is 0)")]
    NoRanks,
    /// This node's rank is not one of the ranks.
    #[error("rank {rank} is not below the number of ranks, {ranks}")]
    RankOutOfRange {
        /// The rank given for this node.
        rank: u32,
        /// How many nodes hold the blocks.
        ranks: u32,
    },
    /// Each block must have at least one owner, and can have at most one per node.
    #[error("{replicas} replicas of each block: there must be between 1 and {ranks} (the ranks)")]
    Replicas {
        /// The owners asked for per block.
        replicas: u32,
        /// How many nodes hold the blocks: the most owners a block can have.
        ranks: u32,
    },
}
