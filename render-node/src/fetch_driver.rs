//! The render node's fetch loop: the only place a shared scene's blocks are fetched, around the
//! sans-IO [`Fetcher`]. Render threads' misses come in over a channel; what is missed at once
//! goes out as one request per owner; arrived blocks go into the cache and to the threads that
//! wait; the master's news of holders tells it who is gone; and an empty request now and then
//! measures the transport's round trip on the same connections, the floor under a remote read.

use crate::dsm::FetchHub;
use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tessera_core::dsm::{
    BlockCache, BlockId, FetchConfig, FetchOutput, FetchStats, Fetcher, Residency,
};
use tessera_net::framed::write_msg;
use tessera_net::quic;
use tessera_protocol::dsm::{decode_block_header, BlockHolder, BlockRequest, BLOCK_HEADER_LEN};
use tessera_render::dsm::pool::BlockPool;
use tessera_render::dsm::prepare::BlockFile;
use tessera_render::dsm::Block;
use tokio::sync::{mpsc, oneshot, OnceCell};

/// Most blocks of 8 KiB in flight that a prefetch may add to (of larger blocks, as many bytes'
/// worth): blocks fetched ahead wait in buffers and channels until the loop takes them, memory
/// a budget must hold (unbounded, prefetches took 30 MiB of a thrashing node's budget).
pub const PREFETCH_IN_FLIGHT: usize = 256;

/// How often the round trip to a peer is measured.
const PING_EVERY: Duration = Duration::from_millis(500);

/// What the loop starts with.
pub struct Setup {
    pub residency: Residency,
    pub holders: Vec<BlockHolder>,
    pub misses: mpsc::UnboundedReceiver<BlockId>,
    pub hub: Arc<FetchHub>,
    pub cache: Arc<BlockCache<Block>>,
    /// Where arriving blocks are put.
    pub pool: Arc<BlockPool>,
    pub file: BlockFile,
    pub endpoint: quinn::Endpoint,
    /// How it connects to other render nodes (block traffic's windows).
    pub client: quinn::ClientConfig,
    /// Most blocks in flight a prefetch may add to ([`PREFETCH_IN_FLIGHT`] for the block size).
    pub prefetch_in_flight: usize,
}

/// The loop's figures.
#[derive(Clone, Debug, Default)]
pub struct DriverStats {
    pub fetch: FetchStats,
    /// The fastest round trip of an empty request to a peer, in µs (0: never measured).
    pub round_trip_us: f64,
}

/// What the node says to the loop; dropping it stops the loop.
pub struct DriverHandle {
    holders: mpsc::UnboundedSender<Vec<BlockHolder>>,
    prefetch: mpsc::UnboundedSender<Vec<BlockId>>,
    stats: mpsc::UnboundedSender<oneshot::Sender<DriverStats>>,
    task: tokio::task::JoinHandle<()>,
}

impl Drop for DriverHandle {
    fn drop(&mut self) {
        self.task.abort();
    }
}

impl DriverHandle {
    /// The master's news: these nodes hold blocks now, at these addresses.
    pub fn holders(&self, holders: Vec<BlockHolder>) {
        let _ = self.holders.send(holders);
    }

    /// Blocks the next tiles will probably read: fetched ahead, into the cache.
    pub fn prefetch(&self, blocks: Vec<BlockId>) {
        if !blocks.is_empty() {
            let _ = self.prefetch.send(blocks);
        }
    }

    pub async fn stats(&self) -> DriverStats {
        let (tx, rx) = oneshot::channel();
        if self.stats.send(tx).is_err() {
            return DriverStats::default();
        }
        rx.await.unwrap_or_default()
    }
}

/// Starts the loop on the current runtime.
pub fn spawn(setup: Setup) -> DriverHandle {
    let (holders_tx, holders_rx) = mpsc::unbounded_channel();
    let (prefetch_tx, prefetch_rx) = mpsc::unbounded_channel();
    let (stats_tx, stats_rx) = mpsc::unbounded_channel();
    let task = tokio::spawn(run(setup, holders_rx, prefetch_rx, stats_rx));
    DriverHandle {
        holders: holders_tx,
        prefetch: prefetch_tx,
        stats: stats_tx,
        task,
    }
}

/// What the request tasks report.
enum Arrival {
    Block(BlockId, Option<u32>, Arc<Block>),
    /// A request to this rank failed: its connection is made again for the next one.
    Failed(u32),
    RoundTrip(f64),
}

/// A node holding blocks: where it is, and the one connection to it, made on first use.
struct Peer {
    addr: SocketAddr,
    conn: Arc<OnceCell<quinn::Connection>>,
}

struct Loop {
    fetcher: Fetcher,
    peers: BTreeMap<u32, Peer>,
    hub: Arc<FetchHub>,
    cache: Arc<BlockCache<Block>>,
    pool: Arc<BlockPool>,
    /// The one thread that reads blocks from the prepared files (see [`disk_reader`]).
    disk: std::sync::mpsc::Sender<(BlockId, Block)>,
    endpoint: quinn::Endpoint,
    client: quinn::ClientConfig,
    arrivals: mpsc::UnboundedSender<Arrival>,
    round_trip_us: f64,
    next_ping: u32,
    /// Blocks asked for ahead that wait for room in flight: the last list asked for, sent as
    /// earlier ones land, so that a list longer than the room (a series' next step) is
    /// fetched whole, in batches, while frames render.
    ahead: std::collections::VecDeque<BlockId>,
    /// Most blocks in flight that prefetches may add to.
    prefetch_in_flight: usize,
}

async fn run(
    setup: Setup,
    mut holders: mpsc::UnboundedReceiver<Vec<BlockHolder>>,
    mut prefetch: mpsc::UnboundedReceiver<Vec<BlockId>>,
    mut stats: mpsc::UnboundedReceiver<oneshot::Sender<DriverStats>>,
) {
    let Setup {
        residency,
        holders: first,
        mut misses,
        hub,
        cache,
        pool,
        file,
        endpoint,
        client,
        prefetch_in_flight,
    } = setup;
    let (arrivals, mut arrived) = mpsc::unbounded_channel();
    let mut l = Loop {
        fetcher: Fetcher::new(residency, FetchConfig::default()),
        peers: BTreeMap::new(),
        hub: hub.clone(),
        cache,
        pool,
        disk: disk_reader(file, arrivals.clone()),
        endpoint,
        client,
        arrivals,
        round_trip_us: f64::INFINITY,
        next_ping: 0,
        ahead: Default::default(),
        prefetch_in_flight,
    };
    l.set_holders(first);
    let mut ping = tokio::time::interval(PING_EVERY);
    ping.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        let timer = l.fetcher.poll_timeout();
        let timer_at = tokio::time::Instant::from_std(
            timer.unwrap_or_else(|| Instant::now() + Duration::from_secs(3600)),
        );
        tokio::select! {
            k = misses.recv() => {
                let Some(k) = k else { break };
                l.missed(k, &mut misses);
            }
            Some(blocks) = prefetch.recv() => {
                // The newest wishes replace the older ones still waiting.
                l.ahead = blocks.into();
                l.send_ahead(0);
            }
            Some(a) = arrived.recv() => {
                l.arrival(a);
                // In batches: once half the room is free, not a request per landing.
                l.send_ahead(l.prefetch_in_flight / 2);
            }
            Some(list) = holders.recv() => l.set_holders(list),
            Some(reply) = stats.recv() => {
                let _ = reply.send(l.stats());
            }
            _ = tokio::time::sleep_until(timer_at), if timer.is_some() => {
                l.fetcher.handle_timeout(Instant::now());
            }
            _ = ping.tick() => l.ping(),
        }
        while let Some(out) = l.fetcher.poll_output() {
            l.carry_out(out);
        }
    }
    hub.close();
}

impl Loop {
    /// Block `k` was missed: it and everything missed meanwhile go in the same requests.
    fn missed(&mut self, k: BlockId, misses: &mut mpsc::UnboundedReceiver<BlockId>) {
        let now = Instant::now();
        self.fetcher.handle_miss(k, now);
        while let Ok(k) = misses.try_recv() {
            self.fetcher.handle_miss(k, now);
        }
        self.fetcher.flush(now);
    }

    fn stats(&self) -> DriverStats {
        DriverStats {
            fetch: self.fetcher.stats(),
            round_trip_us: if self.round_trip_us.is_finite() {
                self.round_trip_us
            } else {
                0.0
            },
        }
    }

    /// Asks for waiting prefetches, when at most `below` blocks are in flight, up to the
    /// room prefetches have, skipping those that have come meanwhile.
    fn send_ahead(&mut self, below: usize) {
        if self.ahead.is_empty() || self.fetcher.in_flight() > below {
            return;
        }
        let now = Instant::now();
        let lines = self.cache.lines();
        let mut room = self
            .prefetch_in_flight
            .saturating_sub(self.fetcher.in_flight());
        while room > 0 {
            let Some(k) = self.ahead.pop_front() else {
                break;
            };
            let residency = self.fetcher.residency();
            let here = residency.resident_slot(k).is_some()
                || (lines > 0 && self.cache.holds(k, residency.cache_line(k, lines)));
            if !here {
                self.fetcher.handle_prefetch(k, now);
                room -= 1;
            }
        }
        self.fetcher.flush(now);
    }

    fn arrival(&mut self, a: Arrival) {
        match a {
            Arrival::Block(k, from, block) => {
                let line = self.fetcher.residency().cache_line(k, self.cache.lines());
                if self.cache.lines() > 0 {
                    self.cache.insert(k, line, block.clone());
                }
                self.fetcher.handle_arrived(k, from, Instant::now());
                self.hub.deliver(k, block);
            }
            Arrival::Failed(rank) => {
                if let Some(p) = self.peers.get_mut(&rank) {
                    p.conn = Arc::new(OnceCell::new());
                }
            }
            Arrival::RoundTrip(us) => self.round_trip_us = self.round_trip_us.min(us),
        }
    }

    /// The master's list of holders: ranks no longer in it are lost (their blocks go to other
    /// owners or the disk), ranks new in it may be asked.
    fn set_holders(&mut self, list: Vec<BlockHolder>) {
        let now = Instant::now();
        let me = self.fetcher.residency().rank();
        let ranks = self.fetcher.residency().ranks();
        let listed: BTreeMap<u32, SocketAddr> = list
            .into_iter()
            .filter(|h| h.rank < ranks && Some(h.rank) != me)
            .map(|h| (h.rank, h.addr))
            .collect();
        for rank in (0..ranks).filter(|&r| Some(r) != me) {
            match (listed.get(&rank), self.peers.get(&rank).map(|p| p.addr)) {
                (Some(&addr), Some(old)) if addr == old => {}
                (Some(&addr), _) => {
                    self.fetcher.handle_peer_back(rank);
                    self.peers.insert(
                        rank,
                        Peer {
                            addr,
                            conn: Arc::new(OnceCell::new()),
                        },
                    );
                }
                (None, _) => {
                    self.peers.remove(&rank);
                    self.fetcher.handle_peer_lost(rank, now);
                }
            }
        }
    }

    fn carry_out(&mut self, out: FetchOutput) {
        match out {
            FetchOutput::Request {
                peer,
                blocks,
                ahead,
            } => {
                let Some(p) = self.peers.get(&peer) else {
                    // Not announced yet (or gone): the timeout asks the next owner.
                    return;
                };
                let (conn, addr) = (p.conn.clone(), p.addr);
                let dial = (self.endpoint.clone(), self.client.clone());
                let (tx, pool) = (self.arrivals.clone(), self.pool.clone());
                tokio::spawn(async move {
                    let result = async {
                        let conn = connection(&conn, &dial, addr, peer).await?;
                        read_blocks(&conn, (&blocks, ahead), &pool, peer, &tx).await
                    }
                    .await;
                    if let Err(e) = result {
                        tracing::warn!("blocks from rank {peer} at {addr}: {e:#}");
                        let _ = tx.send(Arrival::Failed(peer));
                    }
                });
            }
            FetchOutput::ReadLocally { block } => {
                // Into the pool, as blocks from peers are: out of core every miss is read
                // here, and blocks allocated one by one took a node 10-20 MiB past its budget.
                let _ = self.disk.send((block, self.pool.take()));
            }
        }
    }

    /// Measures the round trip of an empty request to the next peer.
    fn ping(&mut self) {
        let Some((&rank, p)) = self
            .peers
            .range(self.next_ping..)
            .next()
            .or_else(|| self.peers.iter().next())
        else {
            return;
        };
        self.next_ping = rank + 1;
        let (conn, addr, tx) = (p.conn.clone(), p.addr, self.arrivals.clone());
        let pool = self.pool.clone();
        let dial = (self.endpoint.clone(), self.client.clone());
        tokio::spawn(async move {
            let Ok(conn) = connection(&conn, &dial, addr, rank).await else {
                return;
            };
            let t0 = Instant::now();
            if read_blocks(&conn, (&[], false), &pool, rank, &tx)
                .await
                .is_ok()
            {
                let _ = tx.send(Arrival::RoundTrip(t0.elapsed().as_secs_f64() * 1e6));
            }
        });
    }
}

async fn connection(
    cell: &OnceCell<quinn::Connection>,
    (endpoint, client): &(quinn::Endpoint, quinn::ClientConfig),
    addr: SocketAddr,
    rank: u32,
) -> anyhow::Result<quinn::Connection> {
    let what = format!("the render node of rank {rank}");
    let conn = cell
        .get_or_try_init(|| quic::connect_with(endpoint, Some(client.clone()), addr, &what))
        .await?;
    Ok(conn.clone())
}

/// Asks for `blocks` on a stream of its own and hands each to the loop as it arrives.
async fn read_blocks(
    conn: &quinn::Connection,
    (blocks, ahead): (&[BlockId], bool),
    pool: &Arc<BlockPool>,
    rank: u32,
    tx: &mpsc::UnboundedSender<Arrival>,
) -> anyhow::Result<()> {
    let (mut send, mut recv) = conn.open_bi().await?;
    let request = BlockRequest {
        blocks: blocks.to_vec(),
        ahead,
    };
    write_msg(&mut send, &request).await?;
    send.finish()?;
    for &k in blocks {
        let mut header = [0u8; BLOCK_HEADER_LEN];
        recv.read_exact(&mut header).await?;
        let (got, follows) = decode_block_header(header)?;
        if got != k {
            anyhow::bail!("asked for block {k}, got {got}");
        }
        if !follows {
            // It does not hold it (yet): the timeout asks again, or another owner.
            continue;
        }
        let mut block = pool.take();
        recv.read_exact(block.bytes_mut()).await?;
        let _ = tx.send(Arrival::Block(k, Some(rank), Arc::new(block)));
    }
    // The answer's end: a ping waits for it, a request has had all it asked for.
    let _ = recv.read_to_end(0).await;
    Ok(())
}

/// Starts the thread that reads the blocks no owner can send from the prepared files, one at a
/// time, into the pooled blocks it is handed, and sends them on as arrivals; it ends when the
/// loop drops its sender. One thread: a blocking task a block, out of core, started hundreds
/// at once, all waiting on the one file, and their stacks and allocator arenas took a node
/// 10-20 MiB past its budget.
fn disk_reader(
    mut file: BlockFile,
    arrivals: mpsc::UnboundedSender<Arrival>,
) -> std::sync::mpsc::Sender<(BlockId, Block)> {
    let (tx, rx) = std::sync::mpsc::channel::<(BlockId, Block)>();
    std::thread::Builder::new()
        .name("dsm-disk".into())
        .spawn(move || {
            for (block, mut into) in rx {
                match file.read_into(block, into.chunks_mut()) {
                    Ok(()) => {
                        let _ = arrivals.send(Arrival::Block(block, None, Arc::new(into)));
                    }
                    Err(e) => tracing::error!("block {block}, no owner left: {e}"),
                }
            }
        })
        .expect("a thread for the prepared files");
    tx
}
