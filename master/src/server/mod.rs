//! The master's driver loop: accepts nodes, feeds the sans-IO [`Coordinator`] and carries out
//! what it returns. This is the only place in the master with sockets and `Instant::now()`.

mod control;
mod holders;
mod join;
mod messages;
mod report_of;

use crate::peers::{accept_peer, Event, PeerId, PeerSender};
use crate::record::Recorder;
use crate::report::{DisplayReport, Percentiles, RenderNodeReport, Report, WallReport};
use crate::timing::{Timing, PINGS};
use anyhow::{bail, Context, Result};
use std::collections::{BTreeMap, HashMap};
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tessera_core::balance::{BalanceConfig, Coordinator, Output};
use tessera_net::unix_ns;
use tessera_wire::camera::CameraMode;
use tessera_wire::params::RenderParams;
use tessera_wire::protocol::pixels::Compression;
use tessera_wire::protocol::{
    DisplayEndpoint, FrameId, FromNode, NodeStats, RenderNodeId, Role, Session, SessionSpec, ToNode,
};
use tessera_wire::scene_spec::SceneSpec;
use tessera_wire::state::{StateChange, WallState};
use tessera_wire::wall::{DisplayId, TileGrid, TileId, WallLayout};
use tokio::sync::mpsc;

/// What a run needs to know.
#[derive(Clone, Debug)]
pub struct RunConfig {
    pub wall: WallLayout,
    /// Progressive refinement while the camera holds still, if the run does it.
    pub refinement: Option<tessera_core::balance::Refinement>,
    /// Where displays put their windows (from the wall file).
    pub windows: BTreeMap<u32, tessera_wire::window::WindowPlacement>,
    pub scene: SceneSpec,
    pub scene_hash: [u8; 32],
    /// How render nodes hold the scene.
    pub data: tessera_wire::protocol::dsm::DataSpec,
    pub camera: CameraMode,
    pub params: RenderParams,
    /// Frames to run; `None` runs until interrupted.
    pub frames: Option<u64>,
    /// Render nodes to wait for before the first frame.
    pub render_nodes: u32,
    pub save_frame: Option<FrameId>,
    /// How render nodes pack tiles for the displays.
    pub compression: Compression,
    pub join_timeout: Duration,
    /// A render node or display silent this long is treated as gone.
    pub node_deadline: Duration,
    /// Whether the wall goes on without a lost display.
    pub display_loss: crate::args::DisplayLoss,
    /// Whether idle render nodes take over copies of a late node's tiles.
    pub speculate: bool,
    pub show_progress: bool,
    /// Displays present this long after the master's barrier decision, all at the same
    /// instant; zero presents on arrival.
    pub present_margin: Duration,
    /// Where to record the session, if anywhere.
    pub record: Option<std::path::PathBuf>,
    /// A recorded session to drive the wall from.
    pub replay: Option<crate::record::Session>,
    /// Where input from the windows orbits about, and the scene's size (half its diagonal).
    pub pivot: glam::Vec3,
    pub scene_size: f32,
    /// Steps of the time series the wall plays, one a frame (None: it does not play).
    pub play_steps: Option<u32>,
    /// The scene's volume, for the control interface's probe (None: no volume).
    pub probe: Option<std::sync::Arc<crate::probe::Prober>>,
}

enum PeerRole {
    Render { node: RenderNodeId, cores: u32 },
    Display(DisplayId),
    Control,
}

struct Peer {
    role: PeerRole,
    host: String,
    tx: PeerSender,
    conn: quinn::Connection,
    ready: bool,
    stats: Option<NodeStats>,
}

/// The wall run by one master: state of the peers plus the coordinator.
struct Wall {
    cfg: RunConfig,
    coordinator: Coordinator,
    peers: HashMap<PeerId, Peer>,
    displays: BTreeMap<DisplayId, PeerId>,
    display_endpoints: BTreeMap<DisplayId, SocketAddr>,
    next_render_id: u32,
    started: Option<Instant>,
    frame_started: HashMap<FrameId, Instant>,
    presents: Vec<(FrameId, Instant)>,
    timing: Timing,
    lost_render_nodes: u32,
    /// Displays lost while the wall went on without them, or waited for them.
    lost_displays: u32,
    /// Frames presented while some display was not showing them (lost, or not yet back).
    frames_short_of_displays: u64,
    /// For a display that rejoined the running wall, the first frame it is shown.
    display_since: BTreeMap<DisplayId, FrameId>,
    /// State changes the barrier applied.
    changes_applied: u64,
    finished: bool,
    progress: Option<indicatif::ProgressBar>,
    live: control::Live,
    recorder: Option<crate::record::Recorder>,
    /// Turns input from the display windows into state changes.
    navigator: tessera_core::navigate::Navigator,
    /// The state of the frames starting now (as the last `StateApplied` said).
    frame_state: WallState,
    /// A shared scene's ranks: which render node holds each, and where it answers for its
    /// blocks once it said so.
    holders: holders::Holders,
}

/// Runs a whole wall on `endpoint` and returns its report. `started` is set once the first frame
/// starts (the launcher uses it to tell a failed start from a node lost mid-run).
///
/// When `stop` turns true (Ctrl-C), no new frame starts; frames in flight finish and the nodes
/// are shut down as after a normal run.
pub async fn run_wall(
    endpoint: quinn::Endpoint,
    cfg: RunConfig,
    started: Arc<AtomicBool>,
    mut stop: tokio::sync::watch::Receiver<bool>,
) -> Result<Report> {
    let (events_tx, mut events) = mpsc::channel(crate::peers::EVENT_QUEUE);
    let acceptor = {
        let endpoint = endpoint.clone();
        tokio::spawn(async move {
            let mut next = 0u64;
            while let Some(incoming) = endpoint.accept().await {
                next += 1;
                tokio::spawn(accept_peer(incoming, PeerId(next), events_tx.clone()));
            }
        })
    };
    let grid = TileGrid::new(cfg.wall.clone());
    let mut coordinator = Coordinator::new(
        grid.len() as u32,
        cfg.wall.display_count(),
        cfg.camera,
        cfg.params,
        cfg.frames,
        BalanceConfig {
            node_deadline: cfg.node_deadline,
            speculate: cfg.speculate,
            wait_for_lost_displays: (cfg.display_loss == crate::args::DisplayLoss::Wait)
                .then_some(cfg.join_timeout),
            ..BalanceConfig::default()
        },
    );
    coordinator.set_refinement(cfg.refinement);
    coordinator.set_tile_displays(
        (0..grid.len() as u32)
            .map(|t| grid.tile(TileId(t)).expect("every id below len").display)
            .collect(),
    );
    if let Some(session) = &cfg.replay {
        for line in &session.lines {
            coordinator.schedule_change(FrameId(line.frame), StateChange::All(line.wall))?;
        }
    }
    let recorder = cfg.record.as_deref().map(Recorder::create).transpose()?;
    let frame_state = coordinator.state().1;
    let mut wall = Wall {
        coordinator,
        peers: HashMap::new(),
        displays: BTreeMap::new(),
        display_endpoints: BTreeMap::new(),
        next_render_id: 0,
        started: None,
        frame_started: HashMap::new(),
        presents: Vec::new(),
        timing: Timing::default(),
        lost_render_nodes: 0,
        lost_displays: 0,
        frames_short_of_displays: 0,
        display_since: BTreeMap::new(),
        changes_applied: 0,
        finished: false,
        progress: None,
        live: control::Live::default(),
        recorder,
        navigator: tessera_core::navigate::Navigator::new(cfg.camera, cfg.pivot, cfg.scene_size),
        frame_state,
        holders: holders::Holders::default(),
        cfg,
    };
    tracing::info!(
        "waiting for {} display node(s) and {} render node(s) on {}",
        wall.cfg.wall.display_count(),
        wall.cfg.render_nodes,
        endpoint.local_addr()?
    );
    let join_deadline = tokio::time::Instant::now() + wall.cfg.join_timeout;
    // Whether the interrupt was handled. Not `*stop.borrow()` in the branch's condition: an
    // interrupt that came while an event was being handled would already read true there,
    // disable the branch before `changed()` ever reported it, and be lost (the wall then ran
    // on after Ctrl-C). `changed()` reports a value not yet seen whenever it is polled.
    let mut stopping = false;
    let result = loop {
        let deadline_passed =
            wall.started.is_none() && tokio::time::Instant::now() >= join_deadline;
        if deadline_passed {
            break Err(anyhow::anyhow!(
                "timed out after {:?} waiting for nodes: {} — start the missing nodes or raise --join-timeout",
                wall.cfg.join_timeout,
                wall.missing_summary()
            ));
        }
        // The coordinator's own timer (render nodes' deadlines); far off when it has none.
        let timer = wall.coordinator.poll_timeout();
        let timer_at = timer.map_or(join_deadline + Duration::from_secs(86_400), |t| {
            tokio::time::Instant::from_std(t)
        });
        let event = tokio::select! {
            e = events.recv() => e,
            _ = tokio::time::sleep_until(join_deadline), if wall.started.is_none() => continue,
            _ = tokio::time::sleep_until(timer_at), if timer.is_some() => {
                wall.coordinator.handle_timeout(Instant::now());
                if let Err(e) = wall.pump() {
                    break Err(e);
                }
                if wall.finished {
                    break Ok(());
                }
                continue;
            }
            changed = stop.changed(), if !stopping => {
                stopping = true;
                if changed.is_err() && !*stop.borrow() {
                    // The interrupt watcher is gone without an interrupt: nothing to stop.
                    continue;
                }
                if wall.started.is_none() {
                    break Err(anyhow::anyhow!("interrupted before the first frame"));
                }
                tracing::warn!("interrupted: finishing the frames in flight, then shutting down");
                wall.coordinator.stop_after_in_flight();
                if let Err(e) = wall.pump() {
                    break Err(e);
                }
                if wall.finished {
                    break Ok(());
                }
                continue;
            }
        };
        let Some(event) = event else {
            break Err(anyhow::anyhow!("endpoint closed"));
        };
        if let Err(e) = wall.handle(event) {
            break Err(e);
        }
        if wall.started.is_none() && wall.all_ready() {
            let now = Instant::now();
            wall.started = Some(now);
            started.store(true, Ordering::SeqCst);
            if wall.cfg.show_progress {
                wall.progress = Some(progress_bar(wall.cfg.frames));
            }
            tracing::info!("all nodes ready, starting frames");
            wall.coordinator.start(now);
        }
        if let Err(e) = wall.pump() {
            break Err(e);
        }
        if wall.finished {
            break Ok(());
        }
    };
    if let Some(bar) = &wall.progress {
        bar.finish_and_clear();
    }
    let outcome = match result {
        Ok(()) => {
            tracing::info!(
                "{} frames presented; asking the nodes for their figures",
                wall.presents.len()
            );
            wall.shutdown(&mut events).await;
            Ok(wall.report())
        }
        Err(e) => Err(e),
    };
    for peer in wall.peers.values() {
        peer.conn.close(0u32.into(), b"run over");
    }
    acceptor.abort();
    endpoint.close(0u32.into(), b"run over");
    let _ = tokio::time::timeout(Duration::from_secs(2), endpoint.wait_idle()).await;
    outcome
}

fn progress_bar(frames: Option<u64>) -> indicatif::ProgressBar {
    let bar = match frames {
        Some(n) => indicatif::ProgressBar::new(n),
        None => indicatif::ProgressBar::no_length(),
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{spinner} frame {pos}/{len} {per_sec} {elapsed_precise}",
        )
        .expect("valid template"),
    );
    bar
}

impl Wall {
    fn all_ready(&self) -> bool {
        let displays_ready = self.displays.len() == self.cfg.wall.display_count() as usize
            && self.displays.values().all(|p| self.peers[p].ready);
        displays_ready && self.ready_render_nodes() >= self.cfg.render_nodes as usize
    }

    fn ready_render_nodes(&self) -> usize {
        self.peers
            .values()
            .filter(|p| p.ready && matches!(p.role, PeerRole::Render { .. }))
            .count()
    }

    fn missing_summary(&self) -> String {
        let missing: Vec<String> = (0..self.cfg.wall.display_count())
            .map(DisplayId)
            .filter(|d| !self.displays.get(d).is_some_and(|p| self.peers[p].ready))
            .map(|d| d.0.to_string())
            .collect();
        let renders = self.ready_render_nodes();
        format!(
            "displays not ready: [{}]; render nodes ready: {renders} of {}",
            missing.join(", "),
            self.cfg.render_nodes
        )
    }

    fn session(&self) -> Session {
        Session::new(SessionSpec {
            wall: self.cfg.wall.clone(),
            scene: self.cfg.scene.clone(),
            scene_hash: self.cfg.scene_hash,
            displays: self
                .display_endpoints
                .iter()
                .map(|(&display, &addr)| DisplayEndpoint { display, addr })
                .collect(),
            save_frame: self.cfg.save_frame,
            compression: self.cfg.compression,
            windows: self.cfg.windows.clone(),
            data: self.cfg.data.clone(),
        })
        .expect("displays are checked against the wall, and for duplicates, when they join")
    }

    fn send(&self, peer: PeerId, msg: ToNode) {
        let Some(p) = self.peers.get(&peer) else {
            return;
        };
        match p.tx.try_send(msg) {
            Ok(()) => {}
            // The peer is gone; its Closed event is on the way.
            Err(mpsc::error::TrySendError::Closed(_)) => {}
            Err(mpsc::error::TrySendError::Full(_)) => {
                tracing::error!(
                    "closing {}: it left {} messages unread",
                    self.describe(peer),
                    crate::peers::PEER_QUEUE
                );
                p.conn.close(4u32.into(), b"not reading");
            }
        }
    }

    fn render_peer(&self, node: RenderNodeId) -> Option<PeerId> {
        self.peers
            .iter()
            .find(|(_, p)| matches!(p.role, PeerRole::Render { node: n, .. } if n == node))
            .map(|(id, _)| *id)
    }

    /// Sends a peer the session. Render nodes get it only once every display's address is
    /// known; displays and control clients at once (their node id is a placeholder).
    fn welcome(&self, peer: PeerId) {
        let node = match self.peers.get(&peer).map(|p| &p.role) {
            Some(PeerRole::Render { node, .. }) => *node,
            Some(PeerRole::Display(_) | PeerRole::Control) => RenderNodeId(u32::MAX),
            None => return,
        };
        self.send(
            peer,
            ToNode::Welcome {
                node,
                session: self.session(),
            },
        );
        if node != RenderNodeId(u32::MAX) {
            self.send_holders(peer, node);
        }
    }

    fn all_displays_known(&self) -> bool {
        self.display_endpoints.len() == self.cfg.wall.display_count() as usize
    }

    fn describe(&self, peer: PeerId) -> String {
        match self.peers.get(&peer).map(|p| (&p.role, &p.host)) {
            Some((PeerRole::Render { node, .. }, host)) => {
                format!("render node {} ({host})", node.0)
            }
            Some((PeerRole::Display(d), host)) => format!("display {} ({host})", d.0),
            Some((PeerRole::Control, host)) => format!("control client {} ({host})", peer.0),
            None => format!("peer {}", peer.0),
        }
    }

    fn pump(&mut self) -> Result<()> {
        while let Some(out) = self.coordinator.poll_output() {
            match out {
                Output::ToRender(node, msg) => {
                    if let Some(peer) = self.render_peer(node) {
                        self.send(peer, msg);
                    }
                }
                Output::ToDisplays(ToNode::Present { frame })
                    if !self.cfg.present_margin.is_zero() =>
                {
                    let at = unix_ns() + self.cfg.present_margin.as_nanos() as u64;
                    for (&d, peer) in &self.displays {
                        if self.display_since.get(&d).is_some_and(|&f| frame < f) {
                            continue;
                        }
                        let clock_ns = (at as i64 + self.timing.offset(d)) as u64;
                        self.send(*peer, ToNode::PresentAt { frame, clock_ns });
                    }
                }
                // A rejoined display never saw the frames before its first: not theirs to show.
                Output::ToDisplays(ToNode::Present { frame }) => {
                    for (&d, peer) in &self.displays {
                        if self.display_since.get(&d).is_some_and(|&f| frame < f) {
                            continue;
                        }
                        self.send(*peer, ToNode::Present { frame });
                    }
                }
                Output::ToDisplays(msg) => {
                    if let ToNode::FrameStart(start) = msg {
                        self.live.last_start = Some(start);
                        if let Some(recorder) = &mut self.recorder {
                            recorder.frame(&start, self.frame_state)?;
                        }
                    }
                    for peer in self.displays.values() {
                        self.send(*peer, msg.clone());
                    }
                }
                Output::FrameStarted(frame) => {
                    self.frame_started.insert(frame, Instant::now());
                    self.timing.frame_started(frame, unix_ns());
                    if let Some(steps) = self.cfg.play_steps {
                        self.advance_time_step(steps);
                    }
                }
                Output::FramePresented(frame) => {
                    self.presents.push((frame, Instant::now()));
                    let shown_by = |d: &DisplayId| {
                        self.displays.contains_key(d)
                            && self.display_since.get(d).is_none_or(|&f| frame >= f)
                    };
                    if !(0..self.cfg.wall.display_count()).all(|d| shown_by(&DisplayId(d))) {
                        self.frames_short_of_displays += 1;
                    }
                    if let Some(bar) = &self.progress {
                        bar.inc(1);
                    }
                }
                Output::FrameRendered(_) => {}
                Output::StateApplied {
                    frame,
                    changes,
                    wall,
                    stamps,
                    ..
                } => {
                    self.changes_applied += changes;
                    self.frame_state = wall;
                    self.timing.inputs_applied(frame, &stamps);
                }
                Output::Converged(frame) => tracing::info!(
                    "frame {} is at the final quality; nothing renders until something changes",
                    frame.0
                ),
                Output::Refused { frame, error } => {
                    tracing::warn!(
                        "a change replayed at frame {} was refused: {error}",
                        frame.0
                    )
                }
                Output::Finished => self.finished = true,
                Output::DisplayTimedOut { display, silent } => {
                    if let Some(&peer) = self.displays.get(&display) {
                        self.drop_silent(peer, silent)?;
                    }
                }
                Output::DisplayNotBack { display, waited } => bail!(
                    "display {} was not back {:.1} s after it was lost; the wall waited for it (--display-loss wait, at most --join-timeout)",
                    display.0,
                    waited.as_secs_f64()
                ),
                Output::RenderTimedOut { node, silent } => {
                    if let Some(peer) = self.render_peer(node) {
                        self.drop_silent(peer, silent)?;
                    }
                }
                Output::Stalled => {
                    bail!("every render node or every display is gone; the frames in flight cannot complete")
                }
            }
        }
        Ok(())
    }

    /// Closes the connection of a peer the coordinator found silent past the deadline, and
    /// drops it as if it had left.
    fn drop_silent(&mut self, peer: PeerId, silent: Duration) -> Result<()> {
        if let Some(p) = self.peers.get(&peer) {
            p.conn.close(5u32.into(), b"silent past the deadline");
        }
        let reason = format!(
            "silent for {} ms, past the {} ms deadline",
            silent.as_millis(),
            self.cfg.node_deadline.as_millis()
        );
        self.drop_peer(peer, Instant::now(), &reason)
    }

    /// Asks every node for its stats and waits for them (bounded).
    async fn shutdown(&mut self, events: &mut mpsc::Receiver<Event>) {
        for peer in self.peers.keys() {
            self.send(*peer, ToNode::Shutdown);
        }
        let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
        // Nodes report their figures; control clients have none to give.
        let waiting = |p: &Peer| p.stats.is_none() && !matches!(p.role, PeerRole::Control);
        while self.peers.values().any(waiting) {
            let event = tokio::select! {
                e = events.recv() => e,
                _ = tokio::time::sleep_until(deadline) => {
                    tracing::warn!("some nodes sent no stats within 10 s; the report lacks them");
                    break;
                }
            };
            match event {
                Some(Event::Msg(peer, FromNode::Stats(stats))) => {
                    if let Some(p) = self.peers.get_mut(&peer) {
                        p.stats = Some(stats);
                    }
                }
                Some(Event::Msg(peer, msg)) => self.note_timing(peer, &msg),
                Some(Event::Closed(peer, _)) => {
                    if self.peers.get(&peer).is_some_and(|p| p.stats.is_none()) {
                        self.peers.remove(&peer);
                    }
                }
                Some(_) => {}
                None => break,
            }
        }
    }
}

/// Binds the master's endpoint.
pub fn bind(
    addr: SocketAddr,
    identity: &tessera_net::cluster::NodeIdentity,
) -> Result<quinn::Endpoint> {
    tessera_net::quic::endpoint(addr, identity, true)
        .context("cannot start the master's QUIC endpoint")
}
