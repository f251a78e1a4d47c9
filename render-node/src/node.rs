//! The render node's driver loop: the only place in the render node with sockets and
//! `Instant::now()`. It moves bytes and reads clocks: what the master says, what the render
//! threads and display links report go to the sans-IO [`RenderSession`], and the driver
//! carries out what it returns (a batch to render, messages to the master, displays to connect
//! to or drop, block holders for the fetcher, the shutdown). Heartbeats are the link's, sent
//! whatever this loop is doing. Losing the master and joining it again is
//! `tessera_net::reconnect`'s loop.

use crate::batch::{read, Rendered, Renderer};
use crate::pixels_out::{send_pixels, Batch, Delivery, DisplayConn};
use anyhow::{bail, Context, Result};
use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tessera_core::node::render::{
    BatchOrder, LinkId, RenderEvent, RenderSession, RenderSetup, VolumeSteps,
};
use tessera_core::node::term::MasterTerm;
use tessera_model::wall::{DisplayId, TileGrid};
use tessera_net::cluster::NodeIdentity;
use tessera_net::link::{LinkError, MasterLink, Welcome};
use tessera_net::quic;
use tessera_net::reconnect::Reconnect;
use tessera_net::sd_notify;
use tessera_protocol::{FrameId, FromNode, NodeStats, Role, ToNode};
use tessera_render::volume::VolumeError;
use tessera_render::Cancel;
use tokio::sync::mpsc;

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
    /// With a list of masters: how long a master may be silent before the node joins the next.
    pub failover_after: Duration,
    /// This host's copy of a shared scene, and its own memory budget.
    pub dsm: crate::dsm::DsmOptions,
}

/// What every session of a node shares: its cores, its identity, its socket.
pub(crate) struct NodeSide {
    pub pool: Arc<rayon::ThreadPool>,
    pub threads: usize,
    pub endpoint: quinn::Endpoint,
    pub identity: NodeIdentity,
    pub bvh_cache: Option<PathBuf>,
    pub volume_cache_bytes: usize,
    pub dsm: crate::dsm::DsmOptions,
}

/// How much a render thread yields the CPU to its own node's driver: render threads that
/// never wait for a block (misses are parked) keep every core busy, and an owner's answer to
/// another node's block request, sent from the driver, must not wait behind them: with both at
/// one priority, remote reads took 10 ms on a 2-core local wall against a 0.1 ms round trip.
const RENDER_THREAD_NICENESS: libc::c_int = 5;

/// Lowers the calling render thread's priority by [`RENDER_THREAD_NICENESS`] below the
/// process's (Linux nice values are per thread). A failure leaves it where it was.
fn yield_to_the_driver() {
    #[cfg(target_os = "linux")]
    // SAFETY: gettid, getpriority and setpriority only read or set the calling thread's
    // scheduling priority.
    unsafe {
        let tid = libc::gettid() as libc::id_t;
        let now = libc::getpriority(libc::PRIO_PROCESS, tid);
        libc::setpriority(libc::PRIO_PROCESS, tid, now + RENDER_THREAD_NICENESS);
    }
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
            .start_handler(|_| yield_to_the_driver())
            .build()?,
    );
    let identity = NodeIdentity::load(&options.cert_dir)?;
    let masters = tessera_net::reconnect::resolve_masters(&options.master).await?;
    let bind: SocketAddr = if masters[0].is_ipv6() {
        "[::]:0"
    } else {
        "0.0.0.0:0"
    }
    .parse()?;
    let endpoint = quic::endpoint(bind, &identity, false)?;
    let mut reconnect = Reconnect::new(
        endpoint.clone(),
        masters,
        Role::Render {
            cores: threads as u32,
        },
        options.reconnect,
        "render node".into(),
    );
    reconnect.failover_after = options.failover_after;
    let first = reconnect
        .join()
        .await
        .context("is tessera-master running there? see --help")?;
    let side = NodeSide {
        pool,
        threads,
        endpoint,
        identity,
        bvh_cache: options.bvh_cache,
        volume_cache_bytes: options.volume_cache_bytes,
        dsm: crate::dsm::DsmOptions {
            threads,
            ..options.dsm
        },
    };
    let mut loaded = None;
    let mut term = MasterTerm::default();
    reconnect
        .run(first, async |link, welcome| {
            if let Err(stale) = term.admit(welcome.term) {
                tracing::warn!("render node: {stale}; trying the next master");
                link.refuse_stale(&stale.message()).await;
                return Err(LinkError::StaleMaster(stale.to_string()).into());
            }
            session(&side, link, welcome, &mut loaded).await
        })
        .await
}

/// One master's wall, from the welcome to its shutdown (or the master's loss).
async fn session(
    side: &NodeSide,
    mut link: MasterLink,
    welcome: Welcome,
    loaded: &mut Option<crate::loading::Loaded>,
) -> Result<()> {
    let session = welcome.session;
    let node = welcome
        .node
        .context("the master welcomed this render node without a render node id")?;
    let here = match crate::loading::scene_here(side, &mut link, node, &session, loaded).await {
        Ok(here) => here,
        Err(e) => {
            link.fail(format!("{e:#}")).await;
            return Err(e);
        }
    };
    let mut displays = BTreeMap::new();
    for d in session.displays() {
        let what = format!("display {}", d.display.0);
        displays.insert(
            d.display,
            quic::connect(&side.endpoint, d.addr, &what).await?,
        );
    }
    link.send(&FromNode::Ready).await?;
    sd_notify::ready(&format!("render node {}: rendering for the wall", node.0));
    tracing::info!(
        "render node {}: ready ({} triangles, {} threads)",
        node.0,
        read(&here.prepared).triangle_count(),
        side.threads
    );
    let grid = Arc::new(TileGrid::new(session.wall().clone()));
    let setup = RenderSetup {
        node,
        tile_count: grid.len() as u32,
        threads: side.threads,
        shared: here.shared.is_some(),
        volume: here.series.as_ref().map(|series| VolumeSteps {
            steps: series.len(),
            shown: here.shown_step.load(Ordering::Relaxed),
        }),
        displays: displays.keys().copied().collect(),
    };
    let renderer = Renderer {
        prepared: here.prepared.clone(),
        series: here.series.clone(),
        shown_step: here.shown_step.clone(),
        grid,
        pool: side.pool.clone(),
        compression: session.compression(),
    };
    let started = RenderSession::new(setup, Instant::now());
    let displays = displays
        .into_iter()
        .map(|(display, conn)| {
            let link = started
                .link(display)
                .expect("the setup numbered every display");
            (display, DisplayConn { link, conn })
        })
        .collect();
    let mut driver = Driver::new(started, renderer, here, displays, link.master_silent());
    match driver.drive(&side.endpoint, &mut link).await? {
        End::Shutdown => {
            let stats = driver.stats().await;
            let summary = format!("{} tiles, {} rays", stats.tiles, stats.rays);
            link.finish(NodeStats::Render(stats)).await?;
            tracing::info!("render node {}: done, {summary}", node.0);
            Ok(())
        }
        End::Failed(message) => {
            link.fail(message.clone()).await;
            bail!("{message}")
        }
    }
}

/// How a session's loop ended, when it was not by an error of the link or the master's.
enum End {
    /// The master shut the wall down.
    Shutdown,
    /// This node cannot go on; the master is told why.
    Failed(String),
}

/// One thing that happened, for the session to hear of.
// One lives for one turn of the loop, on the stack, as the message in it did before: boxing
// the master's messages would allocate for each.
#[allow(clippy::large_enum_variant)]
enum Input {
    Master(Result<ToNode, LinkError>),
    /// Time to tell the master how far this node is.
    Progress,
    Rendered(Result<Option<Rendered>, VolumeError>),
    Reached(DisplayId, DisplayConn),
    Delivered(Delivery),
}

/// A session's sockets, channels and render threads around its [`RenderSession`].
struct Driver {
    session: RenderSession,
    renderer: Renderer,
    here: crate::loading::SceneHere,
    displays: BTreeMap<DisplayId, DisplayConn>,
    /// Cancelled when the session ends, however it ends (see `Drop`): a batch still on the
    /// render threads stops within a sample of a packet instead of tracing on for a master
    /// that is gone.
    cancel: Cancel,
    /// The batch on the render threads: its frame and its own token.
    batch: Option<(FrameId, Cancel)>,
    done: Channel<Result<Option<Rendered>, VolumeError>>,
    delivered: Channel<Delivery>,
    /// Displays reached at the new address the master gave.
    reached: Channel<(DisplayId, DisplayConn)>,
}

impl Drop for Driver {
    fn drop(&mut self) {
        self.cancel.cancel();
    }
}

/// Both ends of an unbounded channel.
struct Channel<T> {
    tx: mpsc::UnboundedSender<T>,
    rx: mpsc::UnboundedReceiver<T>,
}

impl<T> Channel<T> {
    fn new() -> Self {
        let (tx, rx) = mpsc::unbounded_channel();
        Channel { tx, rx }
    }
}

impl Driver {
    fn new(
        session: RenderSession,
        renderer: Renderer,
        here: crate::loading::SceneHere,
        displays: BTreeMap<DisplayId, DisplayConn>,
        master_silent: Arc<std::sync::atomic::AtomicBool>,
    ) -> Self {
        Driver {
            session,
            renderer,
            here,
            displays,
            // A master silent for `link::MASTER_SILENCE` holds the render threads where they
            // are: stopped for a dead master (the connection closes later), going on for a
            // paused one.
            cancel: Cancel::new().held_while(master_silent),
            batch: None,
            done: Channel::new(),
            delivered: Channel::new(),
            reached: Channel::new(),
        }
    }

    /// Moves messages, batches and timers between the session and the world until the
    /// session ends.
    async fn drive(&mut self, endpoint: &quinn::Endpoint, link: &mut MasterLink) -> Result<End> {
        let mut progress = tokio::time::interval(tessera_protocol::PROGRESS_INTERVAL);
        progress.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
        loop {
            if let Some(order) = self.session.poll_batch(Instant::now()) {
                self.start(order);
            }
            self.transmit(link).await?;
            let input = tokio::select! {
                msg = link.recv() => Input::Master(msg),
                Some(done) = self.done.rx.recv() => Input::Rendered(done),
                Some((display, conn)) = self.reached.rx.recv() => Input::Reached(display, conn),
                Some(delivery) = self.delivered.rx.recv() => Input::Delivered(delivery),
                _ = progress.tick() => Input::Progress,
            };
            if let Input::Progress = input {
                let stats = self.stats().await;
                let progress = tessera_protocol::Progress {
                    rays: stats.rays,
                    max_rss_bytes: stats.max_rss_bytes,
                    dsm_misses: stats.dsm.map(|d| d.cache_misses),
                };
                link.send(&FromNode::Progress(progress)).await?;
                continue;
            }
            if let Some(end) = self.handle(input)? {
                return Ok(end);
            }
            self.transmit(link).await?;
            if let Some(end) = self.events(endpoint) {
                return Ok(end);
            }
        }
    }

    fn handle(&mut self, input: Input) -> Result<Option<End>> {
        match input {
            Input::Master(msg) => self
                .session
                .handle_message(msg?, Instant::now())
                .context("the master broke the protocol")?,
            Input::Rendered(Ok(Some(rendered))) => self.rendered(rendered),
            Input::Rendered(Ok(None)) => self.session.handle_cancelled(),
            Input::Rendered(Err(e)) => {
                return Ok(Some(End::Failed(format!(
                    "cannot load the volume's time step: {e}"
                ))))
            }
            Input::Reached(moved, reached) => self.reached(moved, reached),
            Input::Progress => {}
            Input::Delivered(d) => {
                self.session.handle_delivery(
                    d.frame,
                    &d.delivered,
                    d.undelivered,
                    d.lost,
                    Instant::now(),
                );
            }
        }
        Ok(None)
    }

    /// A display was reached at an address the master gave: its link from now on, unless a
    /// newer address came meanwhile.
    fn reached(&mut self, moved: DisplayId, reached: DisplayConn) {
        let node = self.session.node().0;
        if !self.session.handle_display_reached(moved, reached.link) {
            reached
                .conn
                .close(0u32.into(), b"a newer address was given");
            return;
        }
        tracing::info!(
            "render node {node}: display {} reached at its new address",
            moved.0
        );
        if let Some(old) = self.displays.insert(moved, reached) {
            old.conn
                .close(0u32.into(), b"the display was reached again");
        }
    }

    /// Hands a batch to the render threads.
    fn start(&mut self, order: BatchOrder) {
        if let Some(shared) = &self.here.shared {
            shared.prefetch(
                &read(&self.renderer.prepared),
                order.prefetch.iter().copied(),
                order.volume_step,
            );
        }
        let (renderer, done) = (self.renderer.clone(), self.done.tx.clone());
        // A token of its own, so that one frame can be stopped without the session.
        let cancel = self.cancel.child();
        self.batch = Some((order.start.frame, cancel.clone()));
        tokio::task::spawn_blocking(move || {
            let _ = done.send(renderer.render(order, &cancel));
        });
    }

    /// A batch is rendered: its pixels go to their displays.
    fn rendered(&mut self, rendered: Rendered) {
        let source = self.session.handle_rendered(rendered.done());
        let Rendered {
            frame,
            state,
            tiles,
            payloads,
            footprints,
            ..
        } = rendered;
        if let Some(shared) = &mut self.here.shared {
            shared.note_footprints(&tiles, footprints);
        }
        let batch = Batch {
            frame,
            state,
            source,
            tiles,
            payloads,
        };
        let (grid, compression) = (&self.renderer.grid, self.renderer.compression);
        send_pixels(
            &self.displays,
            grid,
            compression,
            batch,
            self.delivered.tx.clone(),
        );
    }

    async fn transmit(&mut self, link: &mut MasterLink) -> Result<(), LinkError> {
        while let Some(msg) = self.session.poll_transmit() {
            link.send(&msg).await?;
        }
        Ok(())
    }

    /// Carries out what the session asks besides messages; the shutdown ends the loop.
    fn events(&mut self, endpoint: &quinn::Endpoint) -> Option<End> {
        let node = self.session.node().0;
        while let Some(event) = self.session.poll_event() {
            match event {
                RenderEvent::Shutdown => return Some(End::Shutdown),
                RenderEvent::ConnectDisplay {
                    display,
                    addr,
                    link,
                } => self.connect(endpoint, display, addr, link),
                RenderEvent::ForgetDisplay {
                    display: gone,
                    link,
                    reason,
                } => {
                    // The session forgets only the display's current link; matched again
                    // here so the map can never lose a newer connection.
                    if self.displays.get(&gone).is_some_and(|c| c.link == link) {
                        self.displays.remove(&gone);
                    }
                    tracing::warn!(
                        "render node {node}: display {} unreachable ({reason}); its tiles go back undelivered",
                        gone.0
                    );
                }
                RenderEvent::BlockHolders(holders) => {
                    if let Some(shared) = &self.here.shared {
                        shared.driver.holders(holders);
                    }
                }
                RenderEvent::CancelUpTo(frame) => {
                    if let Some((batch_frame, token)) = &self.batch {
                        if *batch_frame <= frame {
                            token.cancel();
                        }
                    }
                }
            }
        }
        None
    }

    /// Connects to a display off the loop: one that does not answer holds up nothing.
    fn connect(
        &self,
        endpoint: &quinn::Endpoint,
        display: DisplayId,
        addr: SocketAddr,
        link: LinkId,
    ) {
        let (endpoint, reached) = (endpoint.clone(), self.reached.tx.clone());
        tokio::spawn(async move {
            let id = display.0;
            match quic::connect(&endpoint, addr, &format!("display {id}")).await {
                Ok(conn) => {
                    let _ = reached.send((display, DisplayConn { link, conn }));
                }
                Err(e) => tracing::warn!("cannot reach display {id} at {addr}: {e:#}"),
            }
        });
    }

    /// The session's figures with what only the driver measures: the volume's loads, the
    /// shared scene's reads, the node's peak memory.
    async fn stats(&self) -> tessera_protocol::RenderStats {
        let mut stats = self.session.stats(Instant::now());
        if let Some(series) = &self.renderer.series {
            let s = series.stats();
            stats.volume_load_s = s.load_seconds;
            stats
                .volume_load_s
                .truncate(tessera_protocol::MAX_REPORTED_LOADS);
            (stats.prefetch_hits, stats.prefetch_misses) = (s.hits, s.misses);
            stats.volume_stall_s = s.stall_seconds;
        }
        if let Some(shared) = &self.here.shared {
            let driver = shared.driver.stats().await;
            let prepared = read(&self.renderer.prepared);
            stats.dsm = Some(Box::new(shared.stats(driver, &prepared)));
        }
        stats.max_rss_bytes = crate::memory::peak_resident_bytes().unwrap_or(0);
        stats
    }
}
