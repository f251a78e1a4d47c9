//! The fetch protocol of one render node, sans-IO: which peer to ask for which missing
//! block, in how many messages, and what to do when an answer does not come.

use super::{BlockId, Residency};
use hdrhistogram::Histogram;
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::time::{Duration, Instant};

/// Tuning of a [`Fetcher`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FetchConfig {
    /// Most blocks in one request message (0 counts as 1).
    pub batch_max: usize,
    /// A request unanswered this long goes to the next owner (or again to the same one if it
    /// is the only one alive).
    pub timeout: Duration,
}

impl Default for FetchConfig {
    /// 64 blocks a message (half a megabyte of 8 KiB blocks, the paper's size); 500 ms, well
    /// past a LAN round trip with a loaded owner, short enough that a lost answer costs a
    /// frame or two rather than a stall.
    fn default() -> Self {
        FetchConfig {
            batch_max: 64,
            timeout: Duration::from_millis(500),
        }
    }
}

/// What the driver must do.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum FetchOutput {
    /// Ask node `peer` for `blocks` (one message). `ahead`: every block of it is a prefetch,
    /// which the peer may answer after the requests render threads wait for.
    Request {
        /// The rank of the owner to ask.
        peer: u32,
        /// The blocks to ask it for, at most [`FetchConfig::batch_max`] of them.
        blocks: Vec<BlockId>,
        /// Whether the whole message is prefetch, with no render thread waiting on it.
        ahead: bool,
    },
    /// No owner of `block` is alive: the driver reads it from the prepared files on disk
    /// itself and then calls [`Fetcher::handle_arrived`]`(block, None, now)`.
    ReadLocally {
        /// The block none of whose owners is alive.
        block: BlockId,
    },
}

/// What a [`Fetcher`] has counted since it was made.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FetchStats {
    /// [`Fetcher::handle_miss`] calls, including those for a block already asked for.
    pub misses: u64,
    /// [`Fetcher::handle_prefetch`] calls, likewise.
    pub prefetches: u64,
    /// Blocks asked ahead that a render thread then missed before they came: asked again,
    /// at a miss's priority.
    pub promoted: u64,
    /// Request messages.
    pub requests: u64,
    /// Blocks in those messages (a block asked again counts again).
    pub blocks_requested: u64,
    /// Blocks that arrived while wanted, from a peer or from disk.
    pub blocks_arrived: u64,
    /// Blocks that arrived when no longer wanted: the late answer to a request sent again.
    pub duplicates: u64,
    /// Blocks asked again after a timeout.
    pub retries: u64,
    /// Blocks handed to the driver to read from disk: no owner was alive.
    pub read_locally: u64,
    /// From when a block was first wanted to its arrival.
    pub latency: LatencySummary,
}

impl FetchStats {
    /// Adds another node's counts to these (latencies as [`LatencySummary::merge`]).
    pub fn merge(&mut self, other: &FetchStats) {
        self.misses += other.misses;
        self.prefetches += other.prefetches;
        self.promoted += other.promoted;
        self.requests += other.requests;
        self.blocks_requested += other.blocks_requested;
        self.blocks_arrived += other.blocks_arrived;
        self.duplicates += other.duplicates;
        self.retries += other.retries;
        self.read_locally += other.read_locally;
        self.latency = self.latency.merge(&other.latency);
    }
}

/// Fetch latencies in microseconds; all 0 when nothing was measured.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LatencySummary {
    /// Blocks measured.
    pub count: u64,
    /// Shortest wait.
    pub min_us: f64,
    /// Mean wait.
    pub avg_us: f64,
    /// Longest wait.
    pub max_us: f64,
    /// 99th percentile (to the histogram's 3 significant digits).
    pub p99_us: f64,
}

impl LatencySummary {
    /// The summary of both sets of samples: count, min, max and average are exact; the 99th
    /// percentile is the larger of the two, an upper bound (at most 1 % of each set lies above
    /// its own p99, so at most 1 % of the union lies above the larger), since the samples
    /// themselves are gone.
    pub fn merge(&self, other: &LatencySummary) -> LatencySummary {
        if other.count == 0 {
            return self.clone();
        }
        if self.count == 0 {
            return other.clone();
        }
        let count = self.count + other.count;
        LatencySummary {
            count,
            min_us: self.min_us.min(other.min_us),
            avg_us: (self.avg_us * self.count as f64 + other.avg_us * other.count as f64)
                / count as f64,
            max_us: self.max_us.max(other.max_us),
            p99_us: self.p99_us.max(other.p99_us),
        }
    }

    fn of(h: &Histogram<u64>) -> LatencySummary {
        if h.is_empty() {
            return LatencySummary::default();
        }
        LatencySummary {
            count: h.len(),
            min_us: h.min() as f64,
            avg_us: h.mean(),
            max_us: h.max() as f64,
            p99_us: h.value_at_quantile(0.99) as f64,
        }
    }
}

/// Where a wanted block stands.
#[derive(Clone, Copy, Debug)]
enum Asked {
    /// Waiting for the next flush.
    Queued,
    /// Asked of `owners(k)[owner]`, retried at `deadline`.
    Peer { owner: usize, deadline: Instant },
    /// With the driver, which reads it from disk.
    Disk,
}

#[derive(Clone, Copy, Debug)]
struct Want {
    since: Instant,
    asked: Asked,
    /// Wanted ahead of need only (a prefetch), not yet by a render thread.
    ahead: bool,
}

/// The fetch protocol of one render node as a state machine: render threads' misses come in
/// through the driver (`handle_miss`, `flush`), requests and disk reads go out
/// (`poll_output`), answers and losses come back in (`handle_arrived`, `handle_peer_lost`),
/// and time only through `now` and `poll_timeout` / `handle_timeout`.
///
/// A block is asked of its primary owner, or of the next live one: misses land on the
/// interleaved owners evenly, and a retry goes round the owners so that a silent one is
/// not asked twice in a row while another may answer.
///
/// # Examples
///
/// ```
/// use std::time::{Duration, Instant};
/// use tessera_core::dsm::{FetchConfig, FetchOutput, Fetcher, Residency};
///
/// // Node 0 of 4; block 5 lives on node 1.
/// let mut f = Fetcher::new(Residency::new(16, 4, Some(0), 1).unwrap(), FetchConfig::default());
/// let now = Instant::now();
/// f.handle_miss(5, now);
/// f.handle_miss(5, now); // a second thread misses it too: asked once
/// f.flush(now);
/// assert_eq!(f.poll_output(), Some(FetchOutput::Request { peer: 1, blocks: vec![5], ahead: false }));
/// assert_eq!(f.poll_output(), None);
/// assert_eq!(f.in_flight(), 1);
///
/// let later = now + Duration::from_micros(80);
/// assert_eq!(f.handle_arrived(5, Some(1), later), Some(Duration::from_micros(80)));
/// assert_eq!(f.in_flight(), 0);
/// assert_eq!(f.handle_arrived(5, Some(1), later), None); // a late copy
/// assert_eq!(f.stats().duplicates, 1);
/// ```
#[derive(Debug)]
pub struct Fetcher {
    residency: Residency,
    config: FetchConfig,
    /// Every block asked for and not arrived. Ordered maps keep runs reproducible.
    wants: BTreeMap<BlockId, Want>,
    /// The `Queued` blocks, in the order they were wanted.
    queue: Vec<BlockId>,
    deadlines: BTreeSet<(Instant, BlockId)>,
    lost: BTreeSet<u32>,
    outputs: VecDeque<FetchOutput>,
    stats: FetchStats,
    latency: Histogram<u64>,
}

impl Fetcher {
    /// A fetcher for the node `residency` describes.
    pub fn new(residency: Residency, config: FetchConfig) -> Self {
        Fetcher {
            residency,
            config,
            wants: BTreeMap::new(),
            queue: Vec::new(),
            deadlines: BTreeSet::new(),
            lost: BTreeSet::new(),
            outputs: VecDeque::new(),
            stats: FetchStats::default(),
            latency: Histogram::new_with_bounds(1, 60_000_000, 3)
                .expect("1 µs to 60 s at 3 digits is a valid histogram"),
        }
    }

    /// The layout this fetcher asks by.
    pub fn residency(&self) -> &Residency {
        &self.residency
    }

    /// A render thread needs block k (not resident, not cached). Asked once however many
    /// threads miss it: a block already queued or in flight is not asked again.
    pub fn handle_miss(&mut self, k: BlockId, now: Instant) {
        self.stats.misses += 1;
        self.want(k, now, false);
    }

    /// The same for a block wanted soon (prefetch of the next tiles' blocks); counted apart
    /// from misses.
    pub fn handle_prefetch(&mut self, k: BlockId, now: Instant) {
        self.stats.prefetches += 1;
        self.want(k, now, true);
    }

    /// Turns what was queued since the last flush into Request outputs, one per peer (split at
    /// batch_max): the driver calls it after draining a burst of misses, so the misses of a
    /// packet and of the other threads travel together.
    pub fn flush(&mut self, now: Instant) {
        let queued: Vec<(BlockId, usize)> = self.queue.drain(..).map(|k| (k, 0)).collect();
        self.ask(queued, now);
    }

    /// Block k arrived (from peer `from`, or read locally: None). Returns how long it was
    /// waited for, if it was asked for (a late duplicate returns None and is counted as a
    /// duplicate). The first copy to arrive wins, whoever sent it.
    pub fn handle_arrived(
        &mut self,
        k: BlockId,
        from: Option<u32>,
        now: Instant,
    ) -> Option<Duration> {
        debug_assert!(
            from.is_none() || from != self.residency.rank(),
            "block {k} from this node itself"
        );
        let Some(want) = self.wants.remove(&k) else {
            self.stats.duplicates += 1;
            return None;
        };
        match want.asked {
            Asked::Queued => self.queue.retain(|&q| q != k),
            Asked::Peer { deadline, .. } => {
                self.deadlines.remove(&(deadline, k));
            }
            Asked::Disk => {}
        }
        self.stats.blocks_arrived += 1;
        let waited = now.saturating_duration_since(want.since);
        let us = u64::try_from(waited.as_micros()).unwrap_or(u64::MAX);
        self.latency.saturating_record(us.max(1));
        Some(waited)
    }

    /// A peer is gone (dead, disconnected): what was asked of it goes to the next live owner,
    /// or ReadLocally when none is left; it is never asked again unless handle_peer_back.
    pub fn handle_peer_lost(&mut self, rank: u32, now: Instant) {
        if Some(rank) == self.residency.rank() || !self.lost.insert(rank) {
            return;
        }
        let orphans: Vec<(BlockId, usize, Instant)> = self
            .wants
            .iter()
            .filter_map(|(&k, w)| match w.asked {
                Asked::Peer { owner, deadline } if self.owner(k, owner) == rank => {
                    Some((k, owner, deadline))
                }
                _ => None,
            })
            .collect();
        let orphans = orphans
            .into_iter()
            .map(|(k, owner, deadline)| {
                self.deadlines.remove(&(deadline, k));
                (k, owner + 1)
            })
            .collect();
        self.ask(orphans, now);
    }

    /// A peer lost before is back: it may be asked again (what was moved off it stays where
    /// it went).
    pub fn handle_peer_back(&mut self, rank: u32) {
        self.lost.remove(&rank);
    }

    /// When [`Fetcher::handle_timeout`] has something to do: the earliest request deadline.
    pub fn poll_timeout(&self) -> Option<Instant> {
        self.deadlines.first().map(|&(at, _)| at)
    }

    /// Requests unanswered past the timeout are asked of the next live owner (round robin over
    /// the owners), counted as retries.
    pub fn handle_timeout(&mut self, now: Instant) {
        let mut late = Vec::new();
        while let Some(&(at, k)) = self.deadlines.first() {
            if at > now {
                break;
            }
            self.deadlines.pop_first();
            if let Some(Want {
                asked: Asked::Peer { owner, .. },
                ..
            }) = self.wants.get(&k)
            {
                late.push((k, owner + 1));
            }
        }
        self.stats.retries += late.len() as u64;
        self.ask(late, now);
    }

    /// The next thing for the driver to do, in order.
    pub fn poll_output(&mut self) -> Option<FetchOutput> {
        self.outputs.pop_front()
    }

    /// Blocks asked of a peer or of the disk and not arrived yet (not those waiting for the
    /// next flush).
    pub fn in_flight(&self) -> usize {
        self.wants.len() - self.queue.len()
    }

    /// The counters so far, with the latency histogram summarised.
    pub fn stats(&self) -> FetchStats {
        FetchStats {
            latency: LatencySummary::of(&self.latency),
            ..self.stats.clone()
        }
    }

    fn want(&mut self, k: BlockId, now: Instant, ahead: bool) {
        let held = k >= self.residency.total() || self.residency.owns(k);
        debug_assert!(
            !held,
            "block {k} is resident here or out of range: it never misses"
        );
        if held {
            return;
        }
        if let Some(w) = self.wants.get_mut(&k) {
            // A render thread now waits for a block asked ahead, at a prefetch's priority,
            // behind the other streams: asked again as a miss; the first copy wins.
            if w.ahead && !ahead {
                w.ahead = false;
                if let Asked::Peer { deadline, .. } = w.asked {
                    self.deadlines.remove(&(deadline, k));
                    w.asked = Asked::Queued;
                    self.queue.push(k);
                    self.stats.promoted += 1;
                }
            }
            return;
        }
        let asked = Asked::Queued;
        self.wants.insert(
            k,
            Want {
                since: now,
                asked,
                ahead,
            },
        );
        self.queue.push(k);
    }

    /// Asks each block of the first live owner from the owner index given (round robin),
    /// grouped into one message per peer, or hands it to the disk when none is alive.
    fn ask(&mut self, blocks: Vec<(BlockId, usize)>, now: Instant) {
        let deadline = now + self.config.timeout;
        let mut by_peer: BTreeMap<(u32, bool), Vec<BlockId>> = BTreeMap::new();
        for (k, from) in blocks {
            let ahead = self.wants.get(&k).is_some_and(|w| w.ahead);
            let asked = match self.live_owner(k, from) {
                Some(owner) => {
                    by_peer
                        .entry((self.owner(k, owner), ahead))
                        .or_default()
                        .push(k);
                    self.deadlines.insert((deadline, k));
                    Asked::Peer { owner, deadline }
                }
                None => {
                    self.stats.read_locally += 1;
                    self.outputs
                        .push_back(FetchOutput::ReadLocally { block: k });
                    Asked::Disk
                }
            };
            if let Some(w) = self.wants.get_mut(&k) {
                w.asked = asked;
            }
        }
        let batch = self.config.batch_max.max(1);
        // Misses first: a peer answers streams in the order they open.
        let mut groups: Vec<((u32, bool), Vec<BlockId>)> = by_peer.into_iter().collect();
        groups.sort_by_key(|&((peer, ahead), _)| (ahead, peer));
        for ((peer, ahead), blocks) in groups {
            for chunk in blocks.chunks(batch) {
                self.stats.requests += 1;
                self.stats.blocks_requested += chunk.len() as u64;
                self.outputs.push_back(FetchOutput::Request {
                    peer,
                    blocks: chunk.to_vec(),
                    ahead,
                });
            }
        }
    }

    /// The index of k's first owner from `from` on (cyclically) that is alive and not this
    /// node.
    fn live_owner(&self, k: BlockId, from: usize) -> Option<usize> {
        let replicas = self.residency.replicas() as usize;
        (0..replicas)
            .map(|step| (from + step) % replicas)
            .find(|&i| {
                let peer = self.owner(k, i);
                !self.lost.contains(&peer) && Some(peer) != self.residency.rank()
            })
    }

    fn owner(&self, k: BlockId, index: usize) -> u32 {
        self.residency
            .owners(k)
            .nth(index)
            .expect("an owner index below replicas")
    }
}

#[cfg(test)]
#[path = "fetch_tests.rs"]
mod tests;
