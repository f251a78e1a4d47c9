//! A shared scene on the render node: its share read from the prepared files, the cache sized
//! from the memory budget, and the fetch hub through which render threads wait for what is in
//! neither (see `fetch_driver` for the loop that fetches, and `block_server` for the answers
//! to other nodes).

use crate::fetch_driver::{self, DriverHandle};
use anyhow::{bail, Context, Result};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::Duration;
use tessera_cli::bytes::show_bytes;
use tessera_core::dsm::{BlockCache, BlockId, Residency};
use tessera_model::wall::TileId;
use tessera_protocol::dsm::{BlockHolder, DsmSpec, DsmStats};
use tessera_render::dsm::layout::DEFAULT_BLOCK_BYTES;
use tessera_render::dsm::pool::BlockPool;
use tessera_render::dsm::prepare::{self, BlockFile, Manifest, Share};
use tessera_render::dsm::series::SharedSeries;
use tessera_render::dsm::tree::warm_cache;
use tessera_render::dsm::{
    Block, BlockFetch, BlockLayout, DsmReader, DsmTree, Landing, PinLimits, NODE_OVERHEAD_BYTES,
};
use tessera_render::volume::SharedVolume;
use tessera_render::PreparedScene;
use tokio::sync::mpsc;

/// Set (to anything) in a render node's environment, its render threads wait for a block they
/// miss instead of setting the packet aside: how shared scenes were rendered before, kept to
/// measure the two against each other in one run (`deploy/bench/dsm-parking.sh`).
pub const WAIT_FOR_BLOCKS: &str = "TESSERA_DSM_WAIT_FOR_BLOCKS";

/// Set (to anything) in a render node's environment, it starts with an empty cache instead of
/// filling it from the prepared files while it loads (`dsm::tree::warm_cache`): to measure
/// the first frames' cost of fetching everything on demand.
pub const COLD_CACHE: &str = "TESSERA_DSM_COLD_CACHE";

/// What the node was told, by its own flags, about shared scenes.
#[derive(Clone, Debug, Default)]
pub struct DsmOptions {
    /// Its own copy of the prepared folder, in place of the master's path.
    pub prepared: Option<PathBuf>,
    /// Its own memory budget, in place of the session's.
    pub memory_budget: Option<u64>,
    /// Its render threads (each may hold a few blocks beyond the cache's).
    pub threads: usize,
}

/// Where render threads ask for blocks: one landing per block however many threads want it,
/// a channel of misses to the driver, and the driver's deliveries back. A thread either waits
/// for its block ([`BlockFetch::fetch`]) or goes on and looks at the landing later
/// ([`BlockFetch::request`]); every delivery wakes the threads that wait.
pub struct FetchHub {
    misses: mpsc::UnboundedSender<BlockId>,
    waiting: Mutex<HashMap<BlockId, Landing>>,
    /// Blocks delivered so far; a delivery notifies `landed`.
    delivered: Mutex<u64>,
    landed: Condvar,
    closed: AtomicBool,
    /// Where a thread reads a block itself once the driver is gone (a batch still rendering
    /// when its session ended).
    files: Mutex<BlockFile>,
}

impl FetchHub {
    fn new(misses: mpsc::UnboundedSender<BlockId>, files: BlockFile) -> Self {
        FetchHub {
            misses,
            waiting: Mutex::new(HashMap::new()),
            delivered: Mutex::new(0),
            landed: Condvar::new(),
            closed: AtomicBool::new(false),
            files: Mutex::new(files),
        }
    }

    /// Block `k` from the prepared files.
    ///
    /// # Panics
    /// If it cannot be read: the frame cannot be rendered without it.
    fn read_from_files(&self, k: BlockId) -> Arc<Block> {
        let read = self.files.lock().unwrap_or_else(|e| e.into_inner()).read(k);
        match read {
            Ok(block) => Arc::new(block),
            Err(e) => panic!("block {k} can be had from nowhere: {e}"),
        }
    }

    /// Block `k` arrived: its landing is filled and the threads that wait look again.
    pub fn deliver(&self, k: BlockId, block: Arc<Block>) {
        let landing = self
            .waiting
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .remove(&k);
        if let Some(l) = landing {
            l.land(block);
            *self.delivered.lock().unwrap_or_else(|e| e.into_inner()) += 1;
            self.landed.notify_all();
        }
    }

    /// The driver is gone: threads waiting now, or later, read their blocks themselves
    /// instead of waiting for ever.
    pub fn close(&self) {
        self.closed.store(true, Ordering::SeqCst);
        self.waiting
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clear();
        let _guard = self.delivered.lock().unwrap_or_else(|e| e.into_inner());
        self.landed.notify_all();
    }
}

impl BlockFetch for FetchHub {
    fn fetch(&self, k: BlockId) -> Arc<Block> {
        let landing = self.request(k);
        let mut delivered = self.delivered.lock().unwrap_or_else(|e| e.into_inner());
        loop {
            if let Some(b) = landing.block() {
                return b.clone();
            }
            if self.closed.load(Ordering::SeqCst) {
                drop(delivered);
                return self.read_from_files(k);
            }
            // Bounded, so that a close between the check and the wait is seen.
            delivered = self
                .landed
                .wait_timeout(delivered, Duration::from_millis(100))
                .unwrap_or_else(|e| e.into_inner())
                .0;
        }
    }

    fn request(&self, k: BlockId) -> Landing {
        if self.closed.load(Ordering::SeqCst) {
            let landing = Landing::default();
            landing.land(self.read_from_files(k));
            return landing;
        }
        let mut waiting = self.waiting.lock().unwrap_or_else(|e| e.into_inner());
        waiting
            .entry(k)
            .or_insert_with(|| {
                let _ = self.misses.send(k);
                Landing::default()
            })
            .clone()
    }

    fn landings(&self) -> u64 {
        *self.delivered.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn wait_for_landing(&self, seen: u64, timeout: Duration) -> bool {
        let delivered = self.delivered.lock().unwrap_or_else(|e| e.into_inner());
        if *delivered == seen && !self.closed.load(Ordering::SeqCst) {
            let _ = self
                .landed
                .wait_timeout(delivered, timeout)
                .unwrap_or_else(|e| e.into_inner());
        }
        !self.closed.load(Ordering::SeqCst)
    }
}

/// A scene in distributed shared memory on this node, and what keeps its fetching going.
pub struct DsmScene {
    pub manifest: Manifest,
    pub rank: Option<u32>,
    pub cache_lines: usize,
    pub driver: DriverHandle,
    hub: Arc<FetchHub>,
    /// Its render threads.
    threads: usize,
    /// The memory budget it sized its cache by, if any.
    budget: Option<u64>,
    /// The other nodes' blocks each tile read when this node last rendered it.
    footprints: HashMap<TileId, Vec<BlockId>>,
    /// The scene's volume series, if it is one: every step's bricks are blocks.
    pub series: Option<Arc<SharedSeries>>,
}

impl DsmScene {
    /// Remembers what each of `tiles` read (`footprints`, in the same order).
    pub fn note_footprints(&mut self, tiles: &[TileId], footprints: Vec<Vec<BlockId>>) {
        for (&tile, footprint) in tiles.iter().zip(footprints) {
            self.footprints.insert(tile, footprint);
        }
    }

    /// Fetches ahead, in as few requests as the fetcher can make, the blocks `tiles` read
    /// last time that are neither held here nor cached now: a batch's misses then come in
    /// together instead of one render thread's stall at a time. At most a quarter of the cache
    /// is asked for at once, so that the blocks in use are not pushed out by those to come.
    ///
    /// For a series shown at `step`, the bricks read last time are taken to this step, and
    /// then to the next, which is fetched while this one is shown (another quarter at most).
    pub fn prefetch(
        &self,
        scene: &PreparedScene,
        tiles: impl Iterator<Item = TileId>,
        step: Option<usize>,
    ) {
        let Some(tree) = scene.shared.as_ref() else {
            return;
        };
        let most = self.cache_lines / 4;
        let read: Vec<BlockId> = tiles
            .filter_map(|t| self.footprints.get(&t))
            .flatten()
            .copied()
            .collect();
        let needed = |to: Option<usize>| {
            let mut wanted: Vec<BlockId> = match (&self.series, to) {
                (Some(series), Some(to)) => read
                    .iter()
                    .map(|&k| series.same_brick_at(k, to).unwrap_or(k))
                    .collect(),
                _ => read.clone(),
            };
            wanted.sort_unstable();
            wanted.dedup();
            wanted.retain(|&k| !tree.is_here(k));
            wanted.truncate(most);
            wanted
        };
        let mut wanted = needed(step);
        if let (Some(_), Some(step)) = (&self.series, step) {
            let now: std::collections::HashSet<BlockId> = wanted.iter().copied().collect();
            let ahead = needed(Some(step + 1));
            wanted.extend(ahead.into_iter().filter(|k| !now.contains(k)));
        }
        self.driver.prefetch(wanted);
    }

    /// What this node measured of its reads of `scene` (this shared scene), with what its
    /// fetch loop measured (`driver`).
    pub fn stats(
        &self,
        driver: crate::fetch_driver::DriverStats,
        scene: &PreparedScene,
    ) -> DsmStats {
        let tree = scene.shared.as_ref().expect("a shared scene");
        let (reads, cache) = (tree.stats(), tree.cache().stats());
        let (fetch, latency) = (&driver.fetch, &driver.fetch.latency);
        DsmStats {
            rank: self.rank,
            resident_bytes: tree.resident_bytes() as u64,
            cache_bytes: self.cache_lines as u64 * self.manifest.layout.block_bytes as u64,
            cache_lines: self.cache_lines as u64,
            block_reads: reads.block_reads,
            local_reads: reads.local_reads,
            fetched: reads.fetched,
            fetch_wait_s: reads.fetch_wait_s,
            render_threads: self.threads as u32,
            parked: reads.parked,
            memory_budget: self.budget.unwrap_or(0),
            cache_hits: cache.hits,
            cache_misses: cache.misses,
            evictions: cache.evictions,
            requests: fetch.requests,
            blocks_requested: fetch.blocks_requested,
            blocks_arrived: fetch.blocks_arrived,
            retries: fetch.retries,
            read_locally: fetch.read_locally,
            prefetched: fetch.prefetches,
            latency_count: latency.count,
            latency_min_us: latency.min_us,
            latency_avg_us: latency.avg_us,
            latency_max_us: latency.max_us,
            latency_p99_us: latency.p99_us,
            round_trip_us: driver.round_trip_us,
        }
    }
}

impl Drop for DsmScene {
    fn drop(&mut self) {
        self.hub.close();
    }
}

/// Cache lines for a node holding `resident` bytes of a scene of `manifest`: the share the
/// experiment asks for, or what the budget leaves, or an eighth of the scene.
fn cache_lines(
    manifest: &Manifest,
    spec: &DsmSpec,
    budget: Option<u64>,
    (resident, spare): (u64, u64),
) -> Result<usize> {
    let layout = &manifest.layout;
    if let Some(f) = spec.cache_fraction {
        return Ok((layout.total() as f64 * f as f64).ceil() as usize);
    }
    let Some(budget) = budget else {
        return Ok(layout.total().div_ceil(8) as usize);
    };
    let spare_bytes = spare * layout.block_bytes as u64;
    let held = resident + NODE_OVERHEAD_BYTES + spare_bytes;
    if held > budget {
        bail!(
            "a memory budget of {} does not hold this node's share of the scene ({}), its fixed overhead ({}) and its blocks in flight ({}): raise --memory-budget or add render nodes",
            show_bytes(budget),
            show_bytes(resident),
            show_bytes(NODE_OVERHEAD_BYTES),
            show_bytes(spare_bytes)
        );
    }
    Ok(((budget - held) / (layout.block_bytes as u64 + LINE_OVERHEAD_BYTES)) as usize)
}

/// What a cache line costs besides its block's bytes: the line's guard and pointer, the
/// block's handle and reference counts, the pool's slot and the allocator's header. Uncounted,
/// 72 000 lines of 8 KiB (a 50-million-triangle mesh out of core) ran 2-3 MiB past a budget.
const LINE_OVERHEAD_BYTES: u64 = 128;

/// Blocks of 8 KiB one packet's traces may keep alive (what they read and missed; see
/// [`PinLimits`]).
const PACKET_PIN_BLOCKS: u64 = 64;
/// Distinct blocks of 8 KiB all the packets set aside at once may keep alive or wait for,
/// under a memory budget (without one, as many as the cache has lines if that is more).
const PARKED_BLOCKS: u64 = 256;

/// The spare room's counts, which are of 8 KiB blocks: of larger ones (a volume's bricks are
/// 140.5 KiB), as many bytes' worth, but no fewer than a packet or a batch needs of them.
/// Counted in blocks whatever their size, the room for a volume's was 105 MiB for one thread,
/// three times the CT head itself.
#[derive(Clone, Copy, Debug)]
struct Spare {
    packet_pins: u64,
    parked: u64,
    prefetch: u64,
    slack: u64,
}

impl Spare {
    fn for_blocks(block_bytes: u32) -> Spare {
        let scaled = |blocks: u64, floor: u64| {
            (blocks * DEFAULT_BLOCK_BYTES as u64 / block_bytes as u64).max(floor)
        };
        Spare {
            packet_pins: scaled(PACKET_PIN_BLOCKS, 16),
            parked: scaled(PARKED_BLOCKS, 64),
            prefetch: scaled(crate::fetch_driver::PREFETCH_IN_FLIGHT as u64, 32),
            slack: scaled(64, 8),
        }
    }
}

/// Blocks a node may hold besides its cache's: those its render threads keep (what
/// [`DsmReader::holds`] says each reader holds of this scene, some evicted from the cache
/// meanwhile, and the pins of the packet each traces), those the packets set aside keep and
/// wait for, and those fetched ahead. Without this room a node with every block parked for
/// ran 2.4 MiB over a 48 MiB budget.
fn spare_blocks(threads: usize, layout: &BlockLayout) -> u64 {
    let spare = Spare::for_blocks(layout.block_bytes);
    let per_thread = DsmReader::holds(layout) as u64 + 1 + spare.packet_pins;
    threads as u64 * per_thread + spare.parked + spare.prefetch + spare.slack
}

/// Bounds what packets set aside keep: under a memory budget to the room [`spare_blocks`]
/// made for it; without one to as many blocks as the cache holds, and a packet to the
/// default (an ambient-occlusion packet at a 1/8 cache of the dragon reads more than 64
/// blocks, and past 64 waited for each: idle 54 % of the time); with [`WAIT_FOR_BLOCKS`]
/// set, none is set aside.
fn park_within_spare(tree: &DsmTree, budgeted: bool) {
    let block_bytes = tree.layout().block_bytes as u64;
    let spare = Spare::for_blocks(tree.layout().block_bytes);
    let lines = tree.cache().lines() as u64;
    let limits = if budgeted {
        PinLimits {
            per_packet: (spare.packet_pins * block_bytes) as usize,
            parked: (spare.parked * block_bytes) as usize,
        }
    } else {
        PinLimits {
            parked: (spare.parked.max(lines) * block_bytes) as usize,
            ..PinLimits::default()
        }
    };
    tree.set_pin_limits(limits);
    if std::env::var_os(WAIT_FOR_BLOCKS).is_some() {
        tracing::info!("{WAIT_FOR_BLOCKS} is set: render threads wait for missing blocks");
        tree.set_parks_misses(false);
    }
}

/// This node's share of the scene prepared in `dir`, the files it reads blocks from (one for
/// its fetch loop, one for its render threads' blocks no owner can send), and what it holds
/// whole of the scene's volume (a step each for a series; none without a volume).
async fn read_prepared(
    dir: &Path,
    manifest: &Manifest,
    residency: &Residency,
) -> Result<(Share, (BlockFile, BlockFile), Vec<SharedVolume>)> {
    let (share, file, fallback) = {
        let (dir, manifest, residency) = (dir.to_path_buf(), manifest.clone(), residency.clone());
        tokio::task::spawn_blocking(move || -> Result<_> {
            let mut file = BlockFile::open(&dir, &manifest)?;
            let share = file.read_share(&residency, &mut |_, _| {})?;
            Ok((share, file, BlockFile::open(&dir, &manifest)?))
        })
        .await??
    };
    let volume = match &manifest.volume {
        Some(entry) => tessera_render::dsm::volume::load(dir, entry)?,
        None => Vec::new(),
    };
    Ok((share, (file, fallback), volume))
}

/// Fills `cache` from `file` (see [`tessera_render::dsm::tree::warm_cache`]) on a blocking
/// thread, unless [`COLD_CACHE`] is set; gives the file back.
async fn warm(
    mut file: BlockFile,
    (layout, residency): (&BlockLayout, &Residency),
    cache: &Arc<BlockCache<Block>>,
    pool: &Arc<BlockPool>,
) -> Result<BlockFile> {
    if std::env::var_os(COLD_CACHE).is_some() {
        return Ok(file);
    }
    let (layout, residency, cache, pool) =
        (*layout, residency.clone(), cache.clone(), pool.clone());
    let t0 = std::time::Instant::now();
    let (file, read) = tokio::task::spawn_blocking(move || -> Result<_> {
        let read = warm_cache((&layout, &residency), &cache, &pool, &mut file)?;
        Ok((file, read))
    })
    .await??;
    tracing::info!(
        "filled {read} cache lines from the prepared files in {:.2} s",
        t0.elapsed().as_secs_f64()
    );
    Ok(file)
}

/// The scene's series, if it is one, and the bytes a node holds of its volume besides the
/// bricks (counted as its own, as blocks are).
fn series_of(manifest: &Manifest, volume: &[SharedVolume]) -> (Option<Arc<SharedSeries>>, u64) {
    let first_brick = manifest.layout.first_brick_block();
    let series = (manifest.series_steps > 0 && !volume.is_empty())
        .then(|| Arc::new(SharedSeries::new(volume.to_vec(), first_brick)));
    let held = match (&series, volume.first()) {
        (Some(series), _) => series.held_besides_bricks(),
        (None, Some(v)) => v.held_besides_bricks(),
        (None, None) => 0,
    };
    (series, held)
}

/// Loads this node's share of the scene `spec` describes (as rank `rank`), sizes its cache
/// and starts fetching: the scene to render, and the handle that keeps it fed.
pub async fn start(
    spec: &DsmSpec,
    scene_hash: [u8; 32],
    rank: Option<u32>,
    holders: Vec<BlockHolder>,
    options: &DsmOptions,
    (endpoint, client): (quinn::Endpoint, quinn::ClientConfig),
) -> Result<(PreparedScene, DsmScene)> {
    let dir = options.prepared.clone().unwrap_or_else(|| spec.dir.clone());
    let hash = prepare::hash_hex(&scene_hash);
    let manifest =
        prepare::load_manifest(&dir, Some((&hash, spec.block_bytes))).with_context(|| {
            format!(
                "the prepared scene in {} (--prepared DIR names this host's copy)",
                dir.display()
            )
        })?;
    let layout = manifest.layout;
    // Out of core (no ranks): one rank nobody holds, whose blocks are read from the files.
    let residency = Residency::new(layout.total(), spec.ranks.max(1), rank, spec.replicas)?;
    let (share, (file, fallback), volume) = read_prepared(&dir, &manifest, &residency).await?;
    let blocks_held = ((share.0.len() + share.1.len()) * 64) as u64;
    let (series, volume_held) = series_of(&manifest, &volume);
    let resident = blocks_held + volume_held;
    let budget = options.memory_budget.or(spec.memory_budget);
    let spare = spare_blocks(options.threads, &layout);
    let lines = cache_lines(&manifest, spec, budget, (resident, spare))?;
    let pool = BlockPool::new((lines as u64 + spare).try_into()?, layout.block_bytes);
    tracing::info!(
        "rank {}: holds {} of the scene's {} ({} blocks), caches {} lines ({})",
        rank.map_or("none".to_string(), |r| r.to_string()),
        show_bytes(resident),
        show_bytes(layout.total_bytes()),
        residency.resident_blocks().count(),
        lines,
        show_bytes(lines as u64 * layout.block_bytes as u64)
    );
    let (miss_tx, miss_rx) = mpsc::unbounded_channel();
    let hub = Arc::new(FetchHub::new(miss_tx, fallback));
    let cache = Arc::new(BlockCache::new(lines));
    let file = warm(file, (&layout, &residency), &cache, &pool).await?;
    let tree = DsmTree::new(
        layout,
        residency.clone(),
        share.0,
        share.1,
        cache.clone(),
        hub.clone(),
    )?;
    park_within_spare(&tree, budget.is_some());
    let prepared = PreparedScene::from_shared(&manifest, tree, volume.into_iter().next());
    let driver = fetch_driver::spawn(fetch_driver::Setup {
        residency,
        holders,
        misses: miss_rx,
        hub: hub.clone(),
        cache,
        pool,
        file,
        endpoint,
        client,
        prefetch_in_flight: Spare::for_blocks(layout.block_bytes).prefetch as usize,
    });
    Ok((
        prepared,
        DsmScene {
            manifest,
            rank,
            cache_lines: lines,
            driver,
            hub,
            threads: options.threads,
            budget,
            footprints: HashMap::new(),
            series,
        },
    ))
}
