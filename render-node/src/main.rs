//! `tessera-render-node`: joins a master, ray-traces the tiles it is given on every core, and
//! sends each finished tile straight to the display that owns it.

mod bench;

use anyhow::{bail, Context, Result};
use clap::Parser;
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tessera_common::net::cluster::NodeIdentity;
use tessera_common::net::framed::{read_msg, spawn_reader, write_msg};
use tessera_common::net::quic;
use tessera_common::protocol::pixels::{encode_batch, Compression};
use tessera_common::protocol::{
    FrameId, FromNode, Hello, NodeStats, RenderStats, Role, Session, ToNode, PROTOCOL_VERSION,
};
use tessera_common::render::{render_tiles, FrameView, PreparedScene, RayCounts};
use tessera_common::scene::Scene;
use tessera_common::wall::{DisplayId, TileGrid, TileId};
use tessera_common::worker::{BatchSizer, RenderWorker};
use tokio::sync::mpsc;

/// Tessera render node: renders the tiles a master assigns and sends them to the displays.
///
/// Without a subcommand it joins a master (`--master HOST:PORT --cert-dir DIR`).
#[derive(Parser)]
#[command(version, about, long_about = None, args_conflicts_with_subcommands = true)]
struct Cli {
    #[command(subcommand)]
    command: Option<Tool>,
    /// The master's address, HOST:PORT.
    #[arg(long)]
    master: Option<String>,
    /// This node's certificate directory (node.pem, node.key, ca.pem) from `tessera-master issue-cert`.
    #[arg(long)]
    cert_dir: Option<PathBuf>,
    /// Rendering threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Directory of cached BVHs, keyed by scene content (default: ~/.cache/tessera/bvh).
    #[arg(long)]
    bvh_cache: Option<PathBuf>,
    /// Always build the BVH; neither read nor write the cache.
    #[arg(long)]
    no_bvh_cache: bool,
}

/// The BVH cache directory the flags ask for.
pub fn cache_dir(dir: Option<PathBuf>, disabled: bool) -> Option<PathBuf> {
    if disabled {
        None
    } else {
        dir.or_else(tessera_common::accel_cache::default_cache_dir)
    }
}

#[derive(clap::Subcommand)]
enum Tool {
    /// Measure Mrays/s of primary, shadow and ambient-occlusion rays on one image.
    Bench(bench::BenchArgs),
    /// Write a scene's triangles as OBJ (to feed the same mesh to another renderer).
    ExportObj {
        /// `builtin`, `knot:SEGMENTS:SIDES` or a mesh path.
        #[arg(long)]
        scene: String,
        /// The OBJ file to write.
        #[arg(long)]
        out: PathBuf,
    },
}

fn main() -> ExitCode {
    tessera_common::logging::init();
    let cli = Cli::parse();
    let result = match cli.command {
        Some(Tool::Bench(args)) => bench::run(args),
        Some(Tool::ExportObj { scene, out }) => export_obj(&scene, &out),
        None => join(cli),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("tessera-render-node: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn export_obj(scene: &str, out: &std::path::Path) -> Result<()> {
    let scene = Scene::load(&tessera_common::scene::SceneSpec::from_arg(scene)?)?;
    scene
        .export_obj(out)
        .with_context(|| format!("cannot write {}", out.display()))?;
    eprintln!(
        "wrote {} ({} triangles)",
        out.display(),
        scene.triangles.len()
    );
    Ok(())
}

fn join(cli: Cli) -> Result<()> {
    let (Some(master), Some(cert_dir)) = (cli.master, cli.cert_dir) else {
        bail!("to join a wall give --master HOST:PORT and --cert-dir DIR (see --help)");
    };
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .map_err(anyhow::Error::from)
        .and_then(|rt| {
            rt.block_on(run(
                master,
                cert_dir,
                cli.threads,
                cache_dir(cli.bvh_cache, cli.no_bvh_cache),
            ))
        })
}

enum Done {
    Rendered {
        frame: FrameId,
        tiles: Vec<TileId>,
        /// Each tile's payload, packed as the session's compression says.
        payloads: Vec<Vec<u8>>,
        rays: RayCounts,
        /// Rendering alone.
        took: Duration,
        /// Rendering and packing: what sizes the next batch.
        batch_took: Duration,
    },
    Delivered {
        frame: FrameId,
        tiles: Vec<TileId>,
    },
    DeliveryFailed(String),
}

async fn run(
    master: String,
    cert_dir: PathBuf,
    threads: Option<usize>,
    bvh_cache: Option<PathBuf>,
) -> Result<()> {
    let threads =
        threads.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let pool = Arc::new(
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()?,
    );
    let identity = NodeIdentity::load(&cert_dir)?;
    let master_addr = tessera_common::net::resolve_master(&master).await?;
    let bind: SocketAddr = if master_addr.is_ipv6() {
        "[::]:0"
    } else {
        "0.0.0.0:0"
    }
    .parse()?;
    let endpoint = quic::endpoint(bind, &identity, false)?;
    let conn = quic::connect(&endpoint, master_addr, "the master")
        .await
        .context("is tessera-master running there? see --help")?;
    let (mut send, mut recv) = conn.open_bi().await?;
    let host = tessera_common::net::hostname();
    write_msg(
        &mut send,
        &FromNode::Hello(Hello {
            version: PROTOCOL_VERSION,
            role: Role::Render {
                cores: threads as u32,
            },
            host,
        }),
    )
    .await?;
    let (node, session) = match read_msg::<ToNode>(&mut recv).await? {
        Some(ToNode::Welcome { node, session }) => (node, session),
        Some(ToNode::Refused { reason }) => bail!("the master refused this node: {reason}"),
        Some(other) => bail!("expected a welcome from the master, got {other:?}"),
        None => bail!("the master closed the connection during the handshake"),
    };
    tracing::info!("render node {}: joined, loading the scene", node.0);
    let prepared = match prepare(&session, pool.clone(), bvh_cache).await {
        Ok(p) => p,
        Err(e) => {
            let _ = write_msg(
                &mut send,
                &FromNode::Failed {
                    message: format!("{e:#}"),
                },
            )
            .await;
            let _ = send.finish();
            let _ = tokio::time::timeout(Duration::from_secs(2), send.stopped()).await;
            return Err(e);
        }
    };
    let mut displays = BTreeMap::new();
    for d in &session.displays {
        let c = quic::connect(&endpoint, d.addr, &format!("display {}", d.display.0)).await?;
        displays.insert(d.display, c);
    }
    write_msg(&mut send, &FromNode::Ready).await?;
    tracing::info!(
        "render node {}: ready ({} triangles, {threads} threads)",
        node.0,
        prepared.accel.triangles.len()
    );

    let grid = Arc::new(TileGrid::new(session.wall));
    let compression = session.compression;
    let prepared = Arc::new(prepared);
    let mut sizer = BatchSizer::new(threads);
    let mut worker = RenderWorker::new(sizer.low_water(None));
    let (done_tx, mut done_rx) = mpsc::unbounded_channel::<Done>();
    let mut rendering = false;
    let mut stats = RenderStats::default();
    let first_frame = Instant::now();
    let mut control = spawn_reader::<ToNode>(recv);
    loop {
        if !rendering {
            if let Some((start, tiles)) = worker.next_batch(sizer.batch()) {
                rendering = true;
                let (prepared, grid, pool, done_tx) = (
                    prepared.clone(),
                    grid.clone(),
                    pool.clone(),
                    done_tx.clone(),
                );
                tokio::task::spawn_blocking(move || {
                    let t0 = Instant::now();
                    let view = FrameView::new(
                        start.frame.0,
                        &start.camera,
                        start.params,
                        grid.layout().width(),
                        grid.layout().height(),
                    );
                    let geometry: Vec<_> = tiles
                        .iter()
                        .map(|t| *grid.tile(*t).expect("assigned tiles are validated"))
                        .collect();
                    let (pixels, rays) = pool.install(|| render_tiles(&prepared, &view, &geometry));
                    // Rendering time alone, so rays/s does not depend on the compression.
                    let took = t0.elapsed();
                    let payloads = pool.install(|| {
                        pixels
                            .into_par_iter()
                            .map(|rgb| compression.encode_tile(rgb))
                            .collect()
                    });
                    let _ = done_tx.send(Done::Rendered {
                        frame: start.frame,
                        tiles,
                        payloads,
                        rays,
                        took,
                        batch_took: t0.elapsed(),
                    });
                });
            }
            if let Some(request) = worker.poll_request(Instant::now()) {
                write_msg(&mut send, &request).await?;
            }
        }
        tokio::select! {
            msg = control.recv() => {
                match msg.unwrap_or(Ok(None)) {
                    Ok(Some(ToNode::Shutdown)) => {
                        stats.elapsed_s = first_frame.elapsed().as_secs_f64();
                        write_msg(&mut send, &FromNode::Stats(NodeStats::Render(stats.clone()))).await?;
                        let _ = send.finish();
                        // The master closes the connection once it has everyone's stats.
                        let _ = tokio::time::timeout(Duration::from_secs(10), conn.closed()).await;
                        tracing::info!("render node {}: done, {} tiles, {} rays", node.0, stats.tiles, stats.rays);
                        return Ok(());
                    }
                    Ok(Some(msg)) => {
                        check_assignment(&msg, &grid)?;
                        worker.handle_message(&msg, Instant::now()).map_err(anyhow::Error::msg)?;
                    }
                    Ok(None) => bail!("the master ended the session without a shutdown"),
                    Err(e) => bail!("lost the master: {e:#}"),
                }
            }
            Some(done) = done_rx.recv() => match done {
                Done::Rendered { frame, tiles, payloads, rays, took, batch_took } => {
                    rendering = false;
                    sizer.record(tiles.len(), batch_took);
                    worker.set_low_water(sizer.low_water(worker.round_trip()));
                    stats.tiles += tiles.len() as u64;
                    stats.rays += rays.total();
                    stats.busy_s += took.as_secs_f64();
                    send_pixels(&displays, &grid, frame, compression, tiles, payloads, done_tx.clone());
                }
                Done::Delivered { frame, tiles } => {
                    let report = worker.handle_delivered(frame, &tiles, Instant::now());
                    write_msg(&mut send, &report).await?;
                }
                Done::DeliveryFailed(e) => bail!("cannot deliver pixels: {e}"),
            },
        }
    }
}

/// Refuses assignments of tiles the wall does not have before they reach the worker.
fn check_assignment(msg: &ToNode, grid: &TileGrid) -> Result<()> {
    if let ToNode::Assign { tiles, .. } = msg {
        for r in tiles {
            if r.start > r.end || r.end as usize > grid.len() {
                bail!(
                    "the master assigned tiles {}..{}, but the wall has {}",
                    r.start,
                    r.end,
                    grid.len()
                );
            }
        }
    }
    Ok(())
}

/// One stream per (frame, batch, display); the report goes back once every display has the
/// pixels, so tiles lost with a display connection are never counted as done.
fn send_pixels(
    displays: &BTreeMap<DisplayId, quinn::Connection>,
    grid: &TileGrid,
    frame: FrameId,
    compression: Compression,
    tiles: Vec<TileId>,
    payloads: Vec<Vec<u8>>,
    done: mpsc::UnboundedSender<Done>,
) {
    let mut by_display: BTreeMap<DisplayId, Vec<usize>> = BTreeMap::new();
    for (i, t) in tiles.iter().enumerate() {
        by_display
            .entry(grid.tile(*t).expect("validated").display)
            .or_default()
            .push(i);
    }
    let mut sends = Vec::new();
    for (display, indices) in by_display {
        let Some(conn) = displays.get(&display).cloned() else {
            let _ = done.send(Done::DeliveryFailed(format!(
                "no connection to display {}",
                display.0
            )));
            return;
        };
        let bytes = encode_batch(
            frame,
            compression,
            indices.iter().map(|&i| (tiles[i], payloads[i].as_slice())),
        );
        sends.push(async move {
            let mut stream = conn.open_uni().await?;
            stream.write_all(&bytes).await?;
            stream.finish()?;
            stream.stopped().await?;
            anyhow::Ok(())
        });
    }
    tokio::spawn(async move {
        for s in sends {
            if let Err(e) = s.await {
                let _ = done.send(Done::DeliveryFailed(format!("{e:#}")));
                return;
            }
        }
        let _ = done.send(Done::Delivered { frame, tiles });
    });
}

async fn prepare(
    session: &Session,
    pool: Arc<rayon::ThreadPool>,
    bvh_cache: Option<PathBuf>,
) -> Result<PreparedScene> {
    session.wall.validate()?;
    let spec = session.scene.clone();
    let expected = session.scene_hash;
    tokio::task::spawn_blocking(move || {
        let scene = Scene::load(&spec)?;
        if scene.content_hash() != expected {
            bail!("this node's copy of the scene {spec:?} differs from the master's; every render node needs the same file");
        }
        let t0 = Instant::now();
        let (accel, source) = pool.install(|| tessera_common::accel_cache::load_or_build(&scene, bvh_cache.as_deref()));
        tracing::info!("BVH of {} triangles {:?} in {:.2} s", scene.triangles.len(), source, t0.elapsed().as_secs_f64());
        Ok(PreparedScene::from_accel(&scene, accel))
    })
    .await?
}
