//! The DSM of many render nodes in one process, on a virtual clock: the real [`Residency`],
//! [`BlockCache`] and [`Fetcher`] of every node, their requests and answers carried by a
//! simulated network, and render threads reading seeded streams of blocks.
//!
//! * **Reads.** Each node runs `threads` virtual render threads, each doing a fixed number of
//!   reads `read_us` apart. A thread that misses either waits for the block (blocking reads,
//!   the default) or, with [`DsmSim::parking`]`(p)`, sets the read aside and goes on with the
//!   next one, up to `p` reads waiting at once (render threads parking packets): it idles only
//!   when all `p` wait. A thread reads blocks within `window` of a centre, the part of the
//!   scene its tile's rays see, and before each read moves its centre anywhere with
//!   probability 1 − `locality`, as a new tile sees another part. A read looks in the
//!   resident array, then in the cache; on a miss the read waits for the block. Block k's
//!   content is [`sim_block`]`(k)`, checked on every read, so a block filed under the wrong
//!   number or slot shows as a wrong read.
//! * **Network.** A message arrives `latency_us` plus a seeded jitter of up to half of that
//!   after it is sent, or, with probability `loss`, never: unlike the QUIC streams of the
//!   real nodes, nothing retransmits it, so the fetcher's timeout must. An owner answers a
//!   request with one message holding every block asked for.
//! * **Deaths.** A node killed at a virtual time stops: it answers nothing and its threads'
//!   remaining reads are abandoned. The others learn of it `detect_us` later (a transport's
//!   idle timeout) through [`Fetcher::handle_peer_lost`]; until then their timeouts retry.
//!   A block with no live owner is read from "disk" in `disk_us`.
//!
//! The misses of a node's threads at one virtual instant are flushed together, as a driver
//! draining a burst of misses does.

use super::{
    BlockCache, BlockId, DsmError, FetchConfig, FetchOutput, FetchStats, Fetcher, Residency,
};
use crate::sim::Rng;
use std::cmp::Reverse;
use std::collections::{BTreeMap, BTreeSet, BinaryHeap};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// A run stops at this virtual time even with reads left (a loss of 1 would retry forever).
const MAX_US: u64 = 60_000_000;

/// Block k's content in the simulation: a function of k alone, different for every block.
pub fn sim_block(k: BlockId) -> u64 {
    // splitmix64's finaliser: a bijection, so no two blocks share a content.
    let mut z = u64::from(k).wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A simulated DSM run: its nodes, workload, network and deaths, set with builder methods.
///
/// # Examples
///
/// Eight nodes, each block on two of them, 2 % loss, node 3 dying 2 ms in: every read of the
/// survivors completes, and with the right content.
///
/// ```
/// use tessera_core::dsm::sim::DsmSim;
///
/// let report = DsmSim::new(7, 8, 512)
///     .replicas(2)
///     .cache_lines(64)
///     .loss(0.02)
///     .kill_at(3, 2_000)
///     .run()
///     .unwrap();
/// assert_eq!(report.incomplete, 0);
/// assert_eq!(report.wrong, 0);
/// assert!(report.abandoned > 0); // node 3's reads after its death
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct DsmSim {
    seed: u64,
    nodes: u32,
    blocks: u32,
    replicas: u32,
    cache_lines: usize,
    threads: u32,
    reads: u32,
    read_us: u64,
    locality: f64,
    window: u32,
    latency_us: u64,
    loss: f64,
    detect_us: u64,
    disk_us: u64,
    fetch: FetchConfig,
    kills: Vec<(u32, u64)>,
    parking: u32,
}

impl DsmSim {
    /// `blocks` blocks over `nodes` nodes, one owner each, a cache of as many lines as a
    /// node's resident share, 4 threads of 300 reads per node 2 µs apart (within 8 blocks of
    /// a centre that moves before 2 % of the reads); 50 µs links without loss, a 1 ms fetch
    /// timeout, deaths noticed in 5 ms, disk reads of 200 µs.
    pub fn new(seed: u64, nodes: u32, blocks: u32) -> Self {
        DsmSim {
            seed,
            nodes,
            blocks,
            replicas: 1,
            cache_lines: blocks.div_ceil(nodes.max(1)) as usize,
            threads: 4,
            reads: 300,
            read_us: 2,
            locality: 0.98,
            window: 8,
            latency_us: 50,
            loss: 0.0,
            detect_us: 5_000,
            disk_us: 200,
            fetch: FetchConfig {
                batch_max: 64,
                timeout: Duration::from_millis(1),
            },
            kills: Vec::new(),
            parking: 1,
        }
    }

    /// Reads a thread may have waiting at once before it idles: 1 (the default) is a
    /// blocking read; more is the latency hiding of parked packets.
    pub fn parking(mut self, waiting: u32) -> Self {
        self.parking = waiting.max(1);
        self
    }

    /// How many nodes hold each block.
    pub fn replicas(mut self, replicas: u32) -> Self {
        self.replicas = replicas;
        self
    }

    /// Lines of every node's cache.
    pub fn cache_lines(mut self, lines: usize) -> Self {
        self.cache_lines = lines;
        self
    }

    /// Render threads per node, and reads per thread.
    pub fn workload(mut self, threads: u32, reads_per_thread: u32) -> Self {
        self.threads = threads;
        self.reads = reads_per_thread;
        self
    }

    /// A thread reads within `window` blocks of its centre, which it moves anywhere with
    /// probability 1 − `locality` before each read.
    pub fn locality(mut self, locality: f64, window: u32) -> Self {
        self.locality = locality;
        self.window = window;
        self
    }

    /// One-way latency of every message, before jitter.
    pub fn latency_us(mut self, latency_us: u64) -> Self {
        self.latency_us = latency_us;
        self
    }

    /// Probability that a message is never delivered.
    pub fn loss(mut self, loss: f64) -> Self {
        self.loss = loss;
        self
    }

    /// The fetchers' batch size and timeout.
    pub fn fetch_config(mut self, config: FetchConfig) -> Self {
        self.fetch = config;
        self
    }

    /// How long the others take to learn of a death.
    pub fn detect_us(mut self, detect_us: u64) -> Self {
        self.detect_us = detect_us;
        self
    }

    /// Node `node` dies at virtual time `at_us` (a node not in the run is ignored).
    pub fn kill_at(mut self, node: u32, at_us: u64) -> Self {
        self.kills.push((node, at_us));
        self
    }

    /// Runs until every live node's reads are done or nothing more can happen.
    ///
    /// # Errors
    /// A layout [`Residency::new`] refuses (no nodes, or replicas not within 1..=nodes).
    pub fn run(&self) -> Result<DsmReport, DsmError> {
        Ok(Run::new(self)?.run())
    }
}

/// What a [`DsmSim`] run did, summed over its nodes.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DsmReport {
    /// Reads started.
    pub reads: u64,
    /// Reads of blocks the reading node holds.
    pub resident_reads: u64,
    /// Cache lookups that found their block.
    pub hits: u64,
    /// Cache lookups that did not: the thread waited for a fetch.
    pub misses: u64,
    /// Misses of a block the node had fetched before: it was evicted since.
    pub repeat_misses: u64,
    /// Cache lines overwritten with another block.
    pub evictions: u64,
    /// Reads that got their block.
    pub completed: u64,
    /// Reads of nodes alive at the end that never completed: the failures.
    pub incomplete: u64,
    /// Reads of killed nodes left undone at their death.
    pub abandoned: u64,
    /// Reads that got another block's content.
    pub wrong: u64,
    /// Messages sent, requests and answers.
    pub messages: u64,
    /// Messages the network dropped.
    pub lost_messages: u64,
    /// Every node's fetcher counts, merged (p99 latency: the largest node's).
    pub fetch: FetchStats,
    /// Virtual time of the last event (a fetch timer may fire after the last read).
    pub end_us: u64,
    /// Virtual time the last read got its block.
    pub done_us: u64,
    /// Threads' time with nothing to read but what waits for blocks, over all threads.
    pub idle_us: u64,
    /// Threads over all nodes.
    pub threads: u64,
}

impl DsmReport {
    /// Misses as a percentage of all reads (the paper's miss rate).
    pub fn miss_percent(&self) -> f64 {
        if self.reads == 0 {
            return 0.0;
        }
        100.0 * self.misses as f64 / self.reads as f64
    }

    /// The share of the threads' time until the last read was done spent idle waiting for
    /// blocks, in percent.
    pub fn idle_percent(&self) -> f64 {
        let thread_us = self.done_us as f64 * self.threads as f64;
        if thread_us > 0.0 {
            100.0 * self.idle_us as f64 / thread_us
        } else {
            0.0
        }
    }
}

#[derive(Clone, Debug, PartialEq, Eq, PartialOrd, Ord)]
enum Event {
    /// A thread starts its next read.
    Read {
        node: usize,
        thread: usize,
    },
    Flush(usize),
    Timer(usize),
    Request {
        from: u32,
        to: u32,
        blocks: Vec<BlockId>,
    },
    Reply {
        from: u32,
        to: u32,
        blocks: Vec<(BlockId, u64)>,
    },
    DiskRead {
        node: usize,
        block: BlockId,
    },
    Kill(usize),
    PeerLost {
        node: usize,
        lost: u32,
    },
}

impl Event {
    /// The node the event happens at: nothing happens at a dead one.
    fn at_node(&self) -> usize {
        match self {
            Event::Read { node, .. }
            | Event::Flush(node)
            | Event::Timer(node)
            | Event::DiskRead { node, .. }
            | Event::Kill(node)
            | Event::PeerLost { node, .. } => *node,
            Event::Request { to, .. } | Event::Reply { to, .. } => *to as usize,
        }
    }
}

struct Thread {
    rng: Rng,
    /// The middle of the part of the scene the thread's rays see now.
    centre: BlockId,
    /// Reads not started yet.
    left: u32,
    /// Reads started that wait for their block.
    waiting: u32,
    /// Since when it idles (every read it may set aside waits), if it does.
    idle_since: Option<u64>,
}

impl Thread {
    fn next_block(&mut self, total: u32, locality: f64, window: u32) -> BlockId {
        if self.rng.unit() >= locality {
            self.centre = (self.rng.next_u64() % u64::from(total)) as BlockId;
        }
        let span = 2 * u64::from(window) + 1;
        let step = (self.rng.next_u64() % span) as i64 - i64::from(window);
        (i64::from(self.centre) + step).clamp(0, i64::from(total) - 1) as BlockId
    }
}

struct Node {
    residency: Residency,
    resident: Vec<u64>,
    cache: BlockCache<u64>,
    fetcher: Fetcher,
    threads: Vec<Thread>,
    /// Threads waiting for each block in flight.
    waiting: BTreeMap<BlockId, Vec<usize>>,
    /// Blocks that ever arrived here: a miss of one of them is a repeat.
    fetched: BTreeSet<BlockId>,
    alive: bool,
    flush_pending: bool,
    /// The time of the timer event pending, if any.
    timer_at: Option<u64>,
}

struct Run<'a> {
    sim: &'a DsmSim,
    base: Instant,
    now: u64,
    seq: u64,
    events: BinaryHeap<Reverse<(u64, u64, Event)>>,
    nodes: Vec<Node>,
    jitter: Rng,
    coins: Rng,
    report: DsmReport,
}

impl<'a> Run<'a> {
    fn new(sim: &'a DsmSim) -> Result<Self, DsmError> {
        // Checked once for all, a run of no nodes included.
        Residency::new(sim.blocks, sim.nodes, None, sim.replicas)?;
        let nodes = (0..sim.nodes)
            .map(|rank| Self::node(sim, rank))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Run {
            sim,
            base: Instant::now(),
            now: 0,
            seq: 0,
            events: BinaryHeap::new(),
            nodes,
            jitter: Rng::derived(sim.seed, 1),
            coins: Rng::derived(sim.seed, 2),
            report: DsmReport::default(),
        })
    }

    fn node(sim: &DsmSim, rank: u32) -> Result<Node, DsmError> {
        let residency = Residency::new(sim.blocks, sim.nodes, Some(rank), sim.replicas)?;
        let mut resident = vec![0; residency.resident_len()];
        for (slot, k) in residency.resident_blocks() {
            resident[slot] = sim_block(k);
        }
        let threads = (0..sim.threads)
            .map(|t| {
                let mut rng =
                    Rng::derived(sim.seed, 1000 + u64::from(rank) * 65_536 + u64::from(t));
                let centre = (rng.next_u64() % u64::from(sim.blocks.max(1))) as BlockId;
                let left = if sim.blocks == 0 { 0 } else { sim.reads };
                Thread {
                    rng,
                    centre,
                    left,
                    waiting: 0,
                    idle_since: None,
                }
            })
            .collect();
        Ok(Node {
            fetcher: Fetcher::new(residency.clone(), sim.fetch),
            cache: BlockCache::new(sim.cache_lines),
            residency,
            resident,
            threads,
            waiting: BTreeMap::new(),
            fetched: BTreeSet::new(),
            alive: true,
            flush_pending: false,
            timer_at: None,
        })
    }

    fn run(mut self) -> DsmReport {
        for n in 0..self.nodes.len() {
            for t in 0..self.nodes[n].threads.len() {
                if self.nodes[n].threads[t].left > 0 {
                    // Threads start a microsecond apart, as real ones never start together.
                    self.push(t as u64, Event::Read { node: n, thread: t });
                }
            }
        }
        for &(node, at) in &self.sim.kills {
            if node < self.sim.nodes {
                self.push(at, Event::Kill(node as usize));
            }
        }
        while let Some(Reverse((at, _, event))) = self.events.pop() {
            if at > MAX_US {
                break;
            }
            self.now = at;
            if self.nodes[event.at_node()].alive {
                self.handle(event);
            }
        }
        self.finish()
    }

    fn handle(&mut self, event: Event) {
        let now = self.instant();
        match event {
            Event::Read { node, thread } => self.read(node, thread),
            Event::Flush(n) => {
                self.nodes[n].flush_pending = false;
                self.nodes[n].fetcher.flush(now);
                self.drain(n);
            }
            Event::Timer(n) => {
                if self.nodes[n].timer_at == Some(self.now) {
                    self.nodes[n].timer_at = None;
                }
                self.nodes[n].fetcher.handle_timeout(now);
                self.drain(n);
            }
            Event::Request { from, to, blocks } => {
                let owner = &self.nodes[to as usize];
                let blocks = blocks
                    .into_iter()
                    .filter_map(|k| {
                        let slot = owner.residency.resident_slot(k);
                        debug_assert!(slot.is_some(), "node {to} asked for block {k}");
                        Some((k, owner.resident[slot?]))
                    })
                    .collect();
                self.send(Event::Reply {
                    from: to,
                    to: from,
                    blocks,
                });
            }
            Event::Reply { from, to, blocks } => {
                for (k, content) in blocks {
                    self.arrived(to as usize, k, Some(from), content);
                }
            }
            Event::DiskRead { node, block } => self.arrived(node, block, None, sim_block(block)),
            Event::Kill(n) => self.kill(n),
            Event::PeerLost { node, lost } => {
                self.nodes[node].fetcher.handle_peer_lost(lost, now);
                self.drain(node);
            }
        }
    }

    fn read(&mut self, n: usize, t: usize) {
        let (sim, now) = (self.sim, self.instant());
        let node = &mut self.nodes[n];
        let k = node.threads[t].next_block(sim.blocks, sim.locality, sim.window);
        node.threads[t].left -= 1;
        self.report.reads += 1;
        if let Some(slot) = node.residency.resident_slot(k) {
            self.report.resident_reads += 1;
            let content = node.resident[slot];
            self.check(k, content);
            return self.go_on(n, t);
        }
        let line = node.residency.cache_line(k, node.cache.lines());
        if let Some(block) = node.cache.get(k, line) {
            self.check(k, *block);
            return self.go_on(n, t);
        }
        if node.fetched.contains(&k) {
            self.report.repeat_misses += 1;
        }
        node.fetcher.handle_miss(k, now);
        node.waiting.entry(k).or_default().push(t);
        let thread = &mut node.threads[t];
        thread.waiting += 1;
        let blocked = thread.waiting >= sim.parking;
        if blocked {
            thread.idle_since = Some(self.now);
        }
        if !node.flush_pending {
            // After the other events of this instant: the burst travels in one flush.
            node.flush_pending = true;
            self.push(self.now, Event::Flush(n));
        }
        if !blocked {
            self.go_on(n, t);
        }
    }

    /// A read got block `k` with `content`.
    fn check(&mut self, k: BlockId, content: u64) {
        self.report.completed += 1;
        self.report.done_us = self.now;
        if content != sim_block(k) {
            self.report.wrong += 1;
        }
    }

    /// Thread `t` of node `n` starts its next read, if it has one left, and otherwise idles
    /// until the reads it set aside are done.
    fn go_on(&mut self, n: usize, t: usize) {
        let thread = &mut self.nodes[n].threads[t];
        if thread.left > 0 {
            self.push(
                self.now + self.sim.read_us,
                Event::Read { node: n, thread: t },
            );
        } else if thread.waiting > 0 {
            thread.idle_since = Some(self.now);
        }
    }

    /// A read of thread `t` that waited got its block: the thread goes on if it idled.
    fn complete(&mut self, n: usize, t: usize, k: BlockId, content: u64) {
        self.check(k, content);
        let thread = &mut self.nodes[n].threads[t];
        thread.waiting -= 1;
        if let Some(since) = thread.idle_since.take() {
            self.report.idle_us += self.now - since;
            self.go_on(n, t);
        }
    }

    fn arrived(&mut self, n: usize, k: BlockId, from: Option<u32>, content: u64) {
        let now = self.instant();
        let node = &mut self.nodes[n];
        if node.fetcher.handle_arrived(k, from, now).is_none() {
            return;
        }
        let line = node.residency.cache_line(k, node.cache.lines());
        node.cache.insert(k, line, Arc::new(content));
        node.fetched.insert(k);
        for t in node.waiting.remove(&k).unwrap_or_default() {
            self.complete(n, t, k, content);
        }
    }

    fn kill(&mut self, n: usize) {
        self.nodes[n].alive = false;
        let at = self.now + self.sim.detect_us;
        let lost = n as u32;
        for node in 0..self.nodes.len() {
            if node != n && self.nodes[node].alive {
                self.push(at, Event::PeerLost { node, lost });
            }
        }
    }

    /// Carries out what node n's fetcher asks, and sets its timer.
    fn drain(&mut self, n: usize) {
        while let Some(out) = self.nodes[n].fetcher.poll_output() {
            match out {
                FetchOutput::Request { peer, blocks, .. } => self.send(Event::Request {
                    from: n as u32,
                    to: peer,
                    blocks,
                }),
                FetchOutput::ReadLocally { block } => {
                    let at = self.now + self.sim.disk_us;
                    self.push(at, Event::DiskRead { node: n, block });
                }
            }
        }
        let Some(deadline) = self.nodes[n].fetcher.poll_timeout() else {
            return;
        };
        // Rounded up: a timer a fraction of a microsecond early would find nothing due.
        let nanos = deadline.saturating_duration_since(self.base).as_nanos();
        let at = (nanos.div_ceil(1000) as u64).max(self.now);
        if self.nodes[n].timer_at.is_none_or(|pending| at < pending) {
            self.nodes[n].timer_at = Some(at);
            self.push(at, Event::Timer(n));
        }
    }

    fn send(&mut self, message: Event) {
        self.report.messages += 1;
        if self.sim.loss > 0.0 && self.coins.unit() < self.sim.loss {
            self.report.lost_messages += 1;
            return;
        }
        let latency = self.sim.latency_us;
        let at = self.now + latency + self.jitter.next_u64() % (latency / 2 + 1);
        self.push(at, message);
    }

    fn push(&mut self, at: u64, event: Event) {
        self.seq += 1;
        self.events.push(Reverse((at, self.seq, event)));
    }

    fn instant(&self) -> Instant {
        self.base + Duration::from_micros(self.now)
    }

    fn finish(mut self) -> DsmReport {
        let mut fetch = FetchStats::default();
        for node in &self.nodes {
            let left: u64 = node
                .threads
                .iter()
                .map(|t| u64::from(t.left + t.waiting))
                .sum();
            self.report.threads += node.threads.len() as u64;
            if node.alive {
                self.report.incomplete += left;
            } else {
                self.report.abandoned += left;
            }
            let cache = node.cache.stats();
            self.report.hits += cache.hits;
            self.report.misses += cache.misses;
            self.report.evictions += cache.evictions;
            fetch.merge(&node.fetcher.stats());
        }
        self.report.fetch = fetch;
        self.report.end_us = self.now;
        self.report
    }
}
