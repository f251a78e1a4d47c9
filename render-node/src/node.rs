//! The render node's driver loop: the only place in the render node with sockets and
//! `Instant::now()`. It feeds the sans-IO [`RenderWorker`] what the master says and what the
//! render threads and display links report, and carries out what the worker decides.

use crate::pixels_out::{send_pixels, Batch, Delivery};
use anyhow::{bail, Context, Result};
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::sync::{RwLock, RwLockReadGuard, RwLockWriteGuard};
use std::time::{Duration, Instant};
use tessera_core::worker::{BatchSizer, RenderWorker};
use tessera_net::cluster::NodeIdentity;
use tessera_net::link::{LinkError, MasterLink, Welcome};
use tessera_net::quic;
use tessera_net::sd_notify;
use tessera_render::{render_tiles_footprints, FrameView, PreparedScene, RayCounts};
use tessera_wire::protocol::pixels::BatchSource;
use tessera_wire::protocol::{FrameId, FromNode, NodeStats, RenderStats, Role, ToNode};
use tessera_wire::state::StateId;
use tessera_wire::wall::{TileGrid, TileId};
use tokio::sync::mpsc;

fn read(scene: &RwLock<PreparedScene>) -> RwLockReadGuard<'_, PreparedScene> {
    scene.read().unwrap_or_else(|e| e.into_inner())
}

fn write(scene: &RwLock<PreparedScene>) -> RwLockWriteGuard<'_, PreparedScene> {
    scene.write().unwrap_or_else(|e| e.into_inner())
}

/// What the node was started with.
pub struct Options {
    pub master: String,
    pub cert_dir: PathBuf,
    pub threads: Option<usize>,
    pub bvh_cache: Option<PathBuf>,
    /// Bytes a time series' read-ahead steps may take.
    pub volume_cache_bytes: usize,
    /// With `--reconnect`: how long to wait for a lost master to come back and rejoin it.
    pub reconnect: Option<Duration>,
    /// This host's copy of a shared scene, and its own memory budget.
    pub shared: crate::shared::SharedOptions,
}

/// What every session of a node shares: its cores, its identity, its socket.
pub(crate) struct NodeSide {
    pub pool: Arc<rayon::ThreadPool>,
    pub threads: usize,
    pub endpoint: quinn::Endpoint,
    pub identity: NodeIdentity,
    pub bvh_cache: Option<PathBuf>,
    pub volume_cache_bytes: usize,
    pub shared: crate::shared::SharedOptions,
}

/// A batch the render threads finished.
struct Rendered {
    frame: FrameId,
    state: StateId,
    tiles: Vec<TileId>,
    /// Each tile's payload, packed as the session's compression says.
    payloads: Vec<Vec<u8>>,
    rays: RayCounts,
    /// Rendering alone.
    took: Duration,
    /// Rendering and packing: what sizes the next batch.
    batch_took: Duration,
    /// For a shared scene, the other nodes' blocks each tile read.
    footprints: Vec<Vec<u32>>,
}

/// Joins the master and renders until it shuts the wall down; with `--reconnect`, a lost
/// master is waited for (bounded) and rejoined, as often as it is lost.
pub async fn run(options: Options) -> Result<()> {
    let threads = options
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let pool = Arc::new(
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()?,
    );
    let identity = NodeIdentity::load(&options.cert_dir)?;
    let master_addr = tessera_net::resolve(&options.master).await?;
    let bind: SocketAddr = if master_addr.is_ipv6() {
        "[::]:0"
    } else {
        "0.0.0.0:0"
    }
    .parse()?;
    let endpoint = quic::endpoint(bind, &identity, false)?;
    let role = Role::Render {
        cores: threads as u32,
    };
    let mut joined = MasterLink::join(&endpoint, master_addr, role.clone())
        .await
        .context("is tessera-master running there? see --help")?;
    let side = NodeSide {
        pool,
        threads,
        endpoint,
        identity,
        bvh_cache: options.bvh_cache,
        volume_cache_bytes: options.volume_cache_bytes,
        shared: crate::shared::SharedOptions {
            threads,
            ..options.shared
        },
    };
    let mut loaded = None;
    loop {
        let (link, welcome) = joined;
        let outcome = session(&side, link, welcome, &mut loaded).await;
        let within = match (outcome, options.reconnect) {
            (Ok(()), _) => return Ok(()),
            (Err(e), Some(within)) if LinkError::lost_master_in(e.as_ref()) => {
                tracing::warn!(
                    "render node: {e:#}; waiting up to {} s for it to come back (--reconnect)",
                    within.as_secs()
                );
                within
            }
            (Err(e), _) => return Err(e),
        };
        joined = MasterLink::rejoin(&side.endpoint, master_addr, role.clone(), within).await?;
        tracing::info!("render node: the master is back; rejoined");
    }
}

/// One master's wall, from the welcome to its shutdown (or the master's loss).
async fn session(
    side: &NodeSide,
    mut link: MasterLink,
    welcome: Welcome,
    loaded: &mut Option<crate::loading::Loaded>,
) -> Result<()> {
    let NodeSide {
        pool,
        threads,
        endpoint,
        ..
    } = side;
    let threads = *threads;
    let (node, session) = (welcome.node, welcome.session);
    let mut here = match crate::loading::scene_here(side, &mut link, node, &session, loaded).await {
        Ok(here) => here,
        Err(e) => {
            link.fail(format!("{e:#}")).await;
            return Err(e);
        }
    };
    let (prepared, series, shown_step) = (
        here.prepared.clone(),
        here.series.clone(),
        here.shown_step.clone(),
    );
    let mut displays = BTreeMap::new();
    for d in session.displays() {
        let c = quic::connect(endpoint, d.addr, &format!("display {}", d.display.0)).await?;
        displays.insert(d.display, c);
    }
    link.send(&FromNode::Ready).await?;
    sd_notify::ready(&format!("render node {}: rendering for the wall", node.0));
    tracing::info!(
        "render node {}: ready ({} triangles, {threads} threads)",
        node.0,
        read(&prepared).triangle_count()
    );

    let grid = Arc::new(TileGrid::new(session.wall().clone()));
    let compression = session.compression();
    let mut sizer = BatchSizer::new(threads);
    let mut worker = RenderWorker::new(grid.len() as u32, sizer.low_water(None));
    let (done_tx, mut done_rx) = mpsc::unbounded_channel::<Result<Rendered, String>>();
    let (delivered_tx, mut delivered_rx) = mpsc::unbounded_channel::<Delivery>();
    let (reconnected_tx, mut reconnected_rx) =
        mpsc::unbounded_channel::<(tessera_wire::wall::DisplayId, quinn::Connection)>();
    let mut rendering = false;
    let mut stats = RenderStats::default();
    let first_frame = Instant::now();
    // The master declares a node silent past its deadline dead: the driver loop beats
    // whatever the render threads are doing (a hung loop stops beating, and is dead too).
    let mut heartbeat = tokio::time::interval(tessera_wire::protocol::HEARTBEAT_INTERVAL);
    heartbeat.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        if !rendering {
            if let Some((start, tiles)) = worker.next_batch(sizer.batch()) {
                rendering = true;
                if let Some(shared) = &here.shared {
                    // This batch's blocks and the next one's, asked for together.
                    let next = worker.upcoming().take(tiles.len());
                    shared.prefetch(&read(&prepared), tiles.iter().copied().chain(next));
                }
                let (prepared, grid, pool, done_tx) = (
                    prepared.clone(),
                    grid.clone(),
                    pool.clone(),
                    done_tx.clone(),
                );
                let (series, shown_step) = (series.clone(), shown_step.clone());
                tokio::task::spawn_blocking(move || {
                    let t0 = Instant::now();
                    let view = FrameView::of_start(&start, grid.layout());
                    if let Some(series) = &series {
                        let step = view.params.volume().time_step as usize % series.len();
                        if shown_step.swap(step, Ordering::Relaxed) != step {
                            match series.get(step) {
                                Ok(volume) => write(&prepared).set_volume(volume),
                                Err(e) => {
                                    let _ = done_tx.send(Err(e.to_string()));
                                    return;
                                }
                            }
                        }
                    }
                    let prepared = read(&prepared);
                    let geometry: Vec<_> = tiles
                        .iter()
                        .map(|t| {
                            *grid
                                .tile(*t)
                                .expect("the worker checked every assigned tile")
                        })
                        .collect();
                    let (pixels, rays, footprints) =
                        pool.install(|| render_tiles_footprints(&prepared, &view, &geometry));
                    // Rendering time alone, so rays/s does not depend on the compression.
                    let took = t0.elapsed();
                    let payloads = pool.install(|| {
                        pixels
                            .into_par_iter()
                            .map(|rgb| compression.encode_tile(rgb))
                            .collect()
                    });
                    let _ = done_tx.send(Ok(Rendered {
                        frame: start.frame,
                        state: start.state,
                        tiles,
                        payloads,
                        rays,
                        took,
                        batch_took: t0.elapsed(),
                        footprints,
                    }));
                });
            }
            if let Some(request) = worker.poll_request(Instant::now()) {
                link.send(&request).await?;
            }
        }
        tokio::select! {
            msg = link.recv() => match msg? {
                ToNode::Shutdown => {
                    stats.elapsed_s = first_frame.elapsed().as_secs_f64();
                    if let Some(series) = &series {
                        let s = series.stats();
                        stats.volume_load_s = s.load_seconds;
                        stats.volume_load_s.truncate(tessera_wire::protocol::MAX_REPORTED_LOADS);
                        (stats.prefetch_hits, stats.prefetch_misses) = (s.hits, s.misses);
                        stats.volume_stall_s = s.stall_seconds;
                    }
                    if let Some(shared) = &here.shared {
                        let driver = shared.driver.stats().await;
                        stats.dsm = Some(Box::new(shared.stats(driver, &read(&prepared))));
                    }
                    stats.max_rss_bytes = crate::memory::peak_resident_bytes().unwrap_or(0);
                    let summary = format!("{} tiles, {} rays", stats.tiles, stats.rays);
                    link.finish(NodeStats::Render(stats)).await?;
                    tracing::info!("render node {}: done, {summary}", node.0);
                    return Ok(());
                }
                ToNode::DisplayAt { display: moved, addr } => {
                    // Connected off the loop: a display that does not answer holds up nothing.
                    let (endpoint, reconnected) = (endpoint.clone(), reconnected_tx.clone());
                    tokio::spawn(async move {
                        let id = moved.0;
                        match quic::connect(&endpoint, addr, &format!("display {id}")).await {
                            Ok(conn) => {
                                let _ = reconnected.send((moved, conn));
                            }
                            Err(e) => tracing::warn!("cannot reach display {id} at {addr}: {e:#}"),
                        }
                    });
                }
                ToNode::BlockHolders { holders, .. } => match &here.shared {
                    Some(shared) => shared.driver.holders(holders),
                    None => bail!("the master broke the protocol: block holders for a replicated scene"),
                },
                msg => worker
                    .handle_message(&msg, Instant::now())
                    .context("the master broke the protocol")?,
            },
            Some(done) = done_rx.recv() => {
                let Rendered { frame, state, tiles, payloads, rays, took, batch_took, footprints } = match done {
                    Ok(r) => r,
                    Err(e) => {
                        link.fail(format!("cannot load the volume's time step: {e}")).await;
                        bail!("cannot load the volume's time step: {e}");
                    }
                };
                rendering = false;
                if let Some(shared) = &mut here.shared {
                    shared.note_footprints(&tiles, footprints);
                }
                sizer.record(tiles.len(), batch_took);
                worker.set_low_water(sizer.low_water(worker.round_trip()));
                stats.tiles += tiles.len() as u64;
                stats.rays += rays.total();
                stats.busy_s += took.as_secs_f64();
                // Per tile, averaged over the batch: what a display's overlay shows per tile.
                let per_tile = took.as_micros() / tiles.len().max(1) as u128;
                let source = BatchSource {
                    node,
                    render_us: per_tile.min(u32::MAX as u128) as u32,
                };
                let batch = Batch { frame, state, source, tiles, payloads };
                send_pixels(&displays, &grid, compression, batch, delivered_tx.clone());
            }
            _ = heartbeat.tick() => link.send(&FromNode::Heartbeat).await?,
            Some((moved, conn)) = reconnected_rx.recv() => {
                tracing::info!("render node {}: display {} reached at its new address", node.0, moved.0);
                displays.insert(moved, conn);
            }
            Some(Delivery { frame, delivered, undelivered, lost }) = delivered_rx.recv() => {
                for (gone, e) in lost {
                    // Once: later batches skip it, and the master, which hears from every
                    // display, decides whether it is gone.
                    if displays.remove(&gone).is_some() {
                        tracing::warn!(
                            "render node {}: display {} unreachable ({e}); its tiles go back undelivered",
                            node.0,
                            gone.0
                        );
                    }
                }
                if !undelivered.is_empty() {
                    let tiles = tessera_wire::protocol::to_ranges(undelivered);
                    link.send(&FromNode::TilesReturned { frame, tiles }).await?;
                }
                let report = worker.handle_delivered(frame, &delivered, Instant::now());
                link.send(&report).await?;
            }
        }
    }
}
