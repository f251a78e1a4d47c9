//! The scene a render node renders in one session: loaded whole (replicated, and kept for a
//! later session of the same scene), or its share of a shared scene read from the prepared
//! files, with the block server and fetch loop that go with it.

use crate::batch::Series;
use crate::dsm::DsmScene;
use crate::node::NodeSide;
use anyhow::{bail, Context, Result};
use std::path::PathBuf;
use std::sync::atomic::AtomicUsize;
use std::sync::{Arc, Mutex, RwLock};
use std::time::Instant;
use tessera_model::scene_spec::SceneSpec;
use tessera_net::link::MasterLink;
use tessera_net::quic;
use tessera_protocol::dsm::DataSpec;
use tessera_protocol::{FromNode, LoadStep, RenderNodeId, Session, ToNode, LOAD_REPORT_INTERVAL};
use tessera_render::scene::{footprint, Scene};
use tessera_render::volume::SeriesCache;
use tessera_render::PreparedScene;

/// A scene prepared for rendering, kept across sessions: a node that rejoins a restarted
/// master for the same replicated scene does not load it again.
pub struct Loaded {
    hash: [u8; 32],
    /// Batches render one at a time: the lock is taken for writing only between them, when a
    /// time series moves to another step.
    prepared: Arc<RwLock<PreparedScene>>,
    series: Option<Series>,
    /// The step of the series `prepared` holds.
    shown_step: Arc<AtomicUsize>,
}

/// Aborts the task when the session that started it ends.
pub struct AbortOnDrop(tokio::task::JoinHandle<()>);

impl Drop for AbortOnDrop {
    fn drop(&mut self) {
        self.0.abort();
    }
}

/// The scene of one session.
pub struct SceneHere {
    pub prepared: Arc<RwLock<PreparedScene>>,
    pub series: Option<Series>,
    pub shown_step: Arc<AtomicUsize>,
    /// For a shared scene: its fetching, and the server of this node's blocks.
    pub shared: Option<DsmScene>,
    _server: Option<AbortOnDrop>,
}

/// The session's scene: reused, loaded, or (shared) this node's share.
pub async fn scene_here(
    side: &NodeSide,
    link: &mut MasterLink,
    node: RenderNodeId,
    session: &Session,
    loaded: &mut Option<Loaded>,
) -> Result<SceneHere> {
    if let DataSpec::Dsm(spec) = session.data() {
        // Its share depends on its rank in this session: nothing carries over.
        *loaded = None;
        return shared_here(side, link, node, session, spec).await;
    }
    if loaded
        .as_ref()
        .is_some_and(|l| l.hash == session.scene_hash())
    {
        tracing::info!(
            "render node {}: joined, the scene is loaded already",
            node.0
        );
    } else {
        tracing::info!("render node {}: joined, loading the scene", node.0);
        // The old scene goes first: two at once may not fit.
        *loaded = None;
        fits_in_memory(session.scene(), side.dsm.memory_budget)?;
        let (prepared, series) = prepare(
            session,
            side.pool.clone(),
            side.bvh_cache.clone(),
            side.volume_cache_bytes,
            link,
        )
        .await?;
        *loaded = Some(Loaded {
            hash: session.scene_hash(),
            prepared: Arc::new(RwLock::new(prepared)),
            series,
            shown_step: Arc::new(AtomicUsize::new(0)),
        });
    }
    let l = loaded.as_ref().expect("loaded above");
    Ok(SceneHere {
        prepared: l.prepared.clone(),
        series: l.series.clone(),
        shown_step: l.shown_step.clone(),
        shared: None,
        _server: None,
    })
}

async fn shared_here(
    side: &NodeSide,
    link: &mut MasterLink,
    node: RenderNodeId,
    session: &Session,
    spec: &tessera_protocol::dsm::DsmSpec,
) -> Result<SceneHere> {
    // The master says the node's rank right after the welcome.
    let (rank, holders) = match link.recv().await? {
        ToNode::BlockHolders { rank, holders } => (rank, holders),
        other => bail!(
            "the master broke the protocol: a {} message where the block holders were due",
            other.kind()
        ),
    };
    tracing::info!(
        "render node {}: joined a shared scene as rank {}, reading its share",
        node.0,
        rank.map_or("none (it holds no blocks)".to_string(), |r| r.to_string())
    );
    let endpoint = side.endpoint.clone();
    // Only other render nodes connect to a render node: for blocks, with windows of their own.
    endpoint.set_server_config(Some(quic::block_server_config(&side.identity)?));
    let start = crate::dsm::start(
        spec,
        session.scene_hash(),
        rank,
        holders,
        &side.dsm,
        (endpoint.clone(), quic::block_client_config(&side.identity)?),
    );
    let (prepared, shared) = reporting(link, &Mutex::new(LoadStep::ReadingShare), start).await?;
    let prepared = Arc::new(RwLock::new(prepared));
    let server = AbortOnDrop(tokio::spawn(crate::block_server::serve(
        endpoint.clone(),
        prepared.clone(),
    )));
    if rank.is_some() {
        link.send(&FromNode::BlocksAt {
            addr: endpoint.local_addr()?,
        })
        .await?;
    }
    Ok(SceneHere {
        prepared,
        series: shared.series.clone().map(Series::Shared),
        shown_step: Arc::new(AtomicUsize::new(0)),
        shared: Some(shared),
        _server: Some(server),
    })
}

/// Refuses, before anything is allocated, a replicated scene whose estimated footprint (see
/// [`footprint`]) exceeds this node's `--memory-budget`, or the memory the host has
/// available when none is given. A scene that cannot be estimated is let through.
///
/// # Errors
/// The scene does not fit: the message names both sizes and the flag, and travels to the
/// master as any load failure does.
pub(crate) fn fits_in_memory(spec: &SceneSpec, budget: Option<u64>) -> Result<()> {
    let Some(needed) = footprint::estimate(spec) else {
        return Ok(());
    };
    let hint = "raise --memory-budget, render a smaller scene, or share it across the render nodes (tessera-master prepare, then --data dsm)";
    let (budget, name) = match budget {
        Some(b) => (b, "this node's --memory-budget".to_string()),
        None => match crate::memory::available_bytes() {
            Some(b) => (
                b,
                "the memory available on this host (MemAvailable; --memory-budget sets a budget)"
                    .to_string(),
            ),
            None => return Ok(()),
        },
    };
    footprint::check_fits(needed, budget, &name, hint)
        .with_context(|| format!("refusing the replicated scene {spec:?}"))
}

/// The scene, prepared, and for a time series the cache its steps are read through.
type Prepared = (PreparedScene, Option<Series>);

/// Loads and prepares the session's scene on a blocking thread, off the driver's runtime,
/// and tells the master how far it is every [`LOAD_REPORT_INTERVAL`] until it is done (a
/// scene that loads faster says nothing).
async fn prepare(
    session: &Session,
    pool: Arc<rayon::ThreadPool>,
    bvh_cache: Option<PathBuf>,
    volume_cache_bytes: usize,
    link: &mut MasterLink,
) -> Result<Prepared> {
    let spec = session.scene().clone();
    let expected = session.scene_hash();
    let step = Arc::new(Mutex::new(LoadStep::Reading));
    let at = step.clone();
    let task = tokio::task::spawn_blocking(move || {
        load(&spec, expected, &pool, bvh_cache, volume_cache_bytes, &at)
    });
    reporting(link, &step, async { task.await? }).await
}

/// Awaits `work`, telling the master what `step` says the node is doing every
/// [`LOAD_REPORT_INTERVAL`] (work done sooner says nothing).
async fn reporting<T>(
    link: &mut MasterLink,
    step: &Mutex<LoadStep>,
    work: impl std::future::Future<Output = Result<T>>,
) -> Result<T> {
    let t0 = Instant::now();
    let first = tokio::time::Instant::now() + LOAD_REPORT_INTERVAL;
    let mut every = tokio::time::interval_at(first, LOAD_REPORT_INTERVAL);
    let mut work = std::pin::pin!(work);
    loop {
        tokio::select! {
            done = &mut work => return done,
            _ = every.tick() => {
                let step = *step.lock().unwrap_or_else(|e| e.into_inner());
                let elapsed_s = t0.elapsed().as_secs() as u32;
                link.send(&FromNode::Loading { step, elapsed_s }).await?;
            }
        }
    }
}

/// [`prepare`]'s blocking part; `step` says what it is doing.
fn load(
    spec: &SceneSpec,
    expected: [u8; 32],
    pool: &rayon::ThreadPool,
    bvh_cache: Option<PathBuf>,
    volume_cache_bytes: usize,
    step: &Mutex<LoadStep>,
) -> Result<Prepared> {
    let set = |now: LoadStep| *step.lock().unwrap_or_else(|e| e.into_inner()) = now;
    let scene = Scene::load(spec)?;
    // The parser's garbage goes before the tree arrives, or it stays resident beside it.
    crate::memory::release_freed();
    if scene.content_hash() != expected {
        bail!("this node's copy of the scene {spec:?} differs from the master's; every render node needs the same file");
    }
    set(match scene.triangles.len() {
        0 => LoadStep::Preparing,
        n => LoadStep::BuildingBvh {
            triangles: n as u64,
        },
    });
    let t0 = Instant::now();
    let triangles = scene.triangles.len();
    // The mesh's vertices and triangles go before a cached tree is read (see `load_lean`).
    let lean = pool.install(|| {
        tessera_render::bvh::cache::load_lean(
            scene,
            bvh_cache.as_deref(),
            || Scene::load(spec),
            crate::memory::release_freed,
        )
    })?;
    set(LoadStep::Preparing);
    tracing::info!(
        "BVH of {triangles} triangles {:?} in {:.2} s",
        lean.source,
        t0.elapsed().as_secs_f64()
    );
    let mut scene = lean.scene;
    if lean.slot_material.is_some() {
        // Mapped to the slots already: the scene's own order is not needed again.
        scene.triangle_material = Vec::new();
    }
    let mut prepared =
        PreparedScene::from_accel_in(&scene, lean.accel, lean.bounds, lean.slot_material);
    prepared.slim_for_rendering();
    // Two readers: one step ahead while the next loads, on a node whose cores render.
    let series = (!scene.series.is_empty()).then(|| {
        Series::Files(Arc::new(SeriesCache::new(
            scene.series.clone(),
            scene.render_from_world,
            volume_cache_bytes,
            2,
        )))
    });
    // The loaded copy goes, and with it the loader's and the build's peak (see `memory`).
    drop(scene);
    crate::memory::release_freed();
    Ok((prepared, series))
}
