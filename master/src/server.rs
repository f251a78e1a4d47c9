//! The master's driver loop: accepts nodes, feeds the sans-IO [`Coordinator`] and carries out
//! what it returns. This is the only place in the master with sockets and `Instant::now()`.

use crate::peers::{accept_peer, Event, PeerId};
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
use tessera_wire::wall::{DisplayId, TileGrid, WallLayout};
use tokio::sync::mpsc;

/// What a run needs to know.
#[derive(Clone, Debug)]
pub struct RunConfig {
    pub wall: WallLayout,
    pub scene: SceneSpec,
    pub scene_hash: [u8; 32],
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
    pub show_progress: bool,
    /// Displays present this long after the master's barrier decision, all at the same
    /// instant; zero presents on arrival.
    pub present_margin: Duration,
}

enum PeerRole {
    Render { node: RenderNodeId, cores: u32 },
    Display(DisplayId),
}

struct Peer {
    role: PeerRole,
    host: String,
    tx: mpsc::UnboundedSender<ToNode>,
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
    /// State changes the barrier applied.
    changes_applied: u64,
    finished: bool,
    progress: Option<indicatif::ProgressBar>,
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
    let (events_tx, mut events) = mpsc::unbounded_channel();
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
    let grid = TileGrid::new(cfg.wall);
    let coordinator = Coordinator::new(
        grid.len() as u32,
        cfg.wall.display_count(),
        cfg.camera,
        cfg.params,
        cfg.frames,
        BalanceConfig::default(),
    );
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
        changes_applied: 0,
        finished: false,
        progress: None,
        cfg,
    };
    tracing::info!(
        "waiting for {} display node(s) and {} render node(s) on {}",
        wall.cfg.wall.display_count(),
        wall.cfg.render_nodes,
        endpoint.local_addr()?
    );
    let join_deadline = tokio::time::Instant::now() + wall.cfg.join_timeout;
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
        let event = tokio::select! {
            e = events.recv() => e,
            _ = tokio::time::sleep_until(join_deadline), if wall.started.is_none() => continue,
            _ = stop.changed(), if !*stop.borrow() => {
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
        let renders_ready = self
            .peers
            .values()
            .filter(|p| p.ready && matches!(p.role, PeerRole::Render { .. }))
            .count();
        displays_ready && renders_ready >= self.cfg.render_nodes as usize
    }

    fn missing_summary(&self) -> String {
        let missing: Vec<String> = (0..self.cfg.wall.display_count())
            .map(DisplayId)
            .filter(|d| !self.displays.get(d).is_some_and(|p| self.peers[p].ready))
            .map(|d| d.0.to_string())
            .collect();
        let renders = self
            .peers
            .values()
            .filter(|p| p.ready && matches!(p.role, PeerRole::Render { .. }))
            .count();
        format!(
            "displays not ready: [{}]; render nodes ready: {renders} of {}",
            missing.join(", "),
            self.cfg.render_nodes
        )
    }

    fn session(&self) -> Session {
        Session::new(SessionSpec {
            wall: self.cfg.wall,
            scene: self.cfg.scene.clone(),
            scene_hash: self.cfg.scene_hash,
            displays: self
                .display_endpoints
                .iter()
                .map(|(&display, &addr)| DisplayEndpoint { display, addr })
                .collect(),
            save_frame: self.cfg.save_frame,
            compression: self.cfg.compression,
        })
        .expect("displays are checked against the wall, and for duplicates, when they join")
    }

    fn send(&self, peer: PeerId, msg: ToNode) {
        if let Some(p) = self.peers.get(&peer) {
            // A closed channel means the peer is gone; its Closed event is on the way.
            let _ = p.tx.send(msg);
        }
    }

    fn render_peer(&self, node: RenderNodeId) -> Option<PeerId> {
        self.peers
            .iter()
            .find(|(_, p)| matches!(p.role, PeerRole::Render { node: n, .. } if n == node))
            .map(|(id, _)| *id)
    }

    fn welcome_render(&self, peer: PeerId) {
        if let Some(Peer {
            role: PeerRole::Render { node, .. },
            ..
        }) = self.peers.get(&peer)
        {
            self.send(
                peer,
                ToNode::Welcome {
                    node: *node,
                    session: self.session(),
                },
            );
        }
    }

    fn all_displays_known(&self) -> bool {
        self.display_endpoints.len() == self.cfg.wall.display_count() as usize
    }

    fn handle(&mut self, event: Event) -> Result<()> {
        let now = Instant::now();
        match event {
            Event::Joined {
                peer,
                hello,
                conn,
                tx,
            } => {
                let remote = conn.remote_address();
                match hello.role {
                    Role::Display {
                        display,
                        pixel_addr,
                    } => {
                        if display.0 >= self.cfg.wall.display_count()
                            || self.displays.contains_key(&display)
                        {
                            let reason = if display.0 >= self.cfg.wall.display_count() {
                                format!(
                                    "display {} does not exist on a {}-display wall",
                                    display.0,
                                    self.cfg.wall.display_count()
                                )
                            } else {
                                format!("display {} has already joined", display.0)
                            };
                            tracing::warn!("refused {} from {remote}: {reason}", hello.host);
                            let _ = tx.send(ToNode::Refused { reason });
                            return Ok(());
                        }
                        let addr = if pixel_addr.ip().is_unspecified() {
                            SocketAddr::new(remote.ip(), pixel_addr.port())
                        } else {
                            pixel_addr
                        };
                        let id = display.0;
                        tracing::info!(
                            "display {id} joined from {} ({remote}), pixels at {addr}",
                            hello.host
                        );
                        if hello.host == tessera_net::hostname() {
                            self.timing.same_host(display);
                        }
                        self.displays.insert(display, peer);
                        self.display_endpoints.insert(display, addr);
                        self.peers.insert(
                            peer,
                            Peer {
                                role: PeerRole::Display(display),
                                host: hello.host,
                                tx,
                                conn,
                                ready: false,
                                stats: None,
                            },
                        );
                        self.send(
                            peer,
                            ToNode::Welcome {
                                node: RenderNodeId(u32::MAX),
                                session: self.session(),
                            },
                        );
                        if self.all_displays_known() {
                            let waiting: Vec<PeerId> = self
                                .peers
                                .iter()
                                .filter(|(_, p)| {
                                    matches!(p.role, PeerRole::Render { .. }) && !p.ready
                                })
                                .map(|(id, _)| *id)
                                .collect();
                            for p in waiting {
                                self.welcome_render(p);
                            }
                        }
                    }
                    Role::Render { cores } => {
                        let node = RenderNodeId(self.next_render_id);
                        self.next_render_id += 1;
                        tracing::info!(
                            "render node {} joined from {} ({remote}), {cores} cores",
                            node.0,
                            hello.host
                        );
                        self.peers.insert(
                            peer,
                            Peer {
                                role: PeerRole::Render { node, cores },
                                host: hello.host,
                                tx,
                                conn,
                                ready: false,
                                stats: None,
                            },
                        );
                        if self.all_displays_known() {
                            self.welcome_render(peer);
                        }
                    }
                }
            }
            Event::Msg(peer, msg) => {
                if let Err(e) = self.handle_msg(peer, msg, now) {
                    let who = self.describe(peer);
                    tracing::error!("closing {who}: {e:#}");
                    if let Some(p) = self.peers.get(&peer) {
                        p.conn.close(2u32.into(), b"protocol violation");
                    }
                    self.drop_peer(peer, now, "protocol violation")?;
                }
            }
            Event::Closed(peer, reason) => self.drop_peer(peer, now, &reason)?,
        }
        Ok(())
    }

    fn describe(&self, peer: PeerId) -> String {
        match self.peers.get(&peer).map(|p| (&p.role, &p.host)) {
            Some((PeerRole::Render { node, .. }, host)) => {
                format!("render node {} ({host})", node.0)
            }
            Some((PeerRole::Display(d), host)) => format!("display {} ({host})", d.0),
            None => format!("peer {}", peer.0),
        }
    }

    fn drop_peer(&mut self, peer: PeerId, now: Instant, reason: &str) -> Result<()> {
        let who = self.describe(peer);
        let Some(p) = self.peers.remove(&peer) else {
            return Ok(());
        };
        if self.finished {
            return Ok(());
        }
        match p.role {
            PeerRole::Display(d) => {
                self.displays.remove(&d);
                self.display_endpoints.remove(&d);
                bail!(
                    "{who} disconnected ({reason}); a wall cannot go on without one of its screens"
                );
            }
            PeerRole::Render { node, .. } => {
                if p.ready && self.started.is_some() {
                    self.lost_render_nodes += 1;
                    tracing::error!(
                        "{who} disconnected ({reason}); its tiles go to the other render nodes"
                    );
                } else {
                    tracing::warn!("{who} left before the first frame ({reason})");
                }
                if p.ready {
                    self.coordinator.handle_render_left(node, now);
                }
            }
        }
        Ok(())
    }

    fn handle_msg(&mut self, peer: PeerId, msg: FromNode, now: Instant) -> Result<()> {
        let Some(p) = self.peers.get_mut(&peer) else {
            return Ok(());
        };
        match (&p.role, msg) {
            (_, FromNode::Stats(stats)) => p.stats = Some(stats),
            (_, FromNode::Failed { message }) => {
                bail!("it failed: {message}");
            }
            (_, FromNode::Hello(_)) => bail!("sent a second hello"),
            (PeerRole::Render { node, .. }, FromNode::Ready) => {
                let node = *node;
                if !p.ready {
                    p.ready = true;
                    if self.started.is_some() {
                        tracing::info!("render node {} joins the running wall", node.0);
                    }
                    self.coordinator.handle_render_joined(node, now);
                }
            }
            (PeerRole::Display(d), FromNode::Ready) => {
                let d = *d;
                p.ready = true;
                for seq in 0..PINGS {
                    self.timing.ping_sent(d, seq, unix_ns());
                    self.send(peer, ToNode::Ping { seq });
                }
            }
            (
                PeerRole::Render { node, .. },
                FromNode::TilesDone {
                    frame,
                    tiles,
                    want_more,
                },
            ) => {
                let node = *node;
                self.coordinator
                    .handle_tiles_done(node, frame, &tiles, want_more, now)?;
            }
            (PeerRole::Display(d), FromNode::FrameComplete { frame }) => {
                let d = *d;
                self.coordinator.handle_frame_complete(d, frame, now)?;
            }
            (PeerRole::Display(_), msg @ (FromNode::Presented { .. } | FromNode::Pong { .. })) => {
                self.note_timing(peer, &msg);
            }
            (_, other) => bail!("sent {other:?}, which its role never sends"),
        }
        Ok(())
    }

    /// Records a display's present stamp or clock probe answer.
    fn note_timing(&mut self, peer: PeerId, msg: &FromNode) {
        let Some(PeerRole::Display(d)) = self.peers.get(&peer).map(|p| &p.role) else {
            return;
        };
        match *msg {
            FromNode::Presented { frame, clock_ns } => self.timing.presented(*d, frame, clock_ns),
            FromNode::Pong { seq, clock_ns } => self.timing.pong(*d, seq, clock_ns, unix_ns()),
            _ => {}
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
                        let clock_ns = (at as i64 + self.timing.offset(d)) as u64;
                        self.send(*peer, ToNode::PresentAt { frame, clock_ns });
                    }
                }
                Output::ToDisplays(msg) => {
                    for peer in self.displays.values() {
                        self.send(*peer, msg.clone());
                    }
                }
                Output::FrameStarted(frame) => {
                    self.frame_started.insert(frame, Instant::now());
                    self.timing.frame_started(frame, unix_ns());
                }
                Output::FramePresented(frame) => {
                    self.presents.push((frame, Instant::now()));
                    if let Some(bar) = &self.progress {
                        bar.inc(1);
                    }
                }
                Output::FrameRendered(_) => {}
                Output::StateApplied { changes, .. } => self.changes_applied += changes,
                Output::Finished => self.finished = true,
                Output::Stalled => {
                    bail!("every render node is gone; the frames in flight cannot complete")
                }
            }
        }
        Ok(())
    }

    /// Asks every node for its stats and waits for them (bounded).
    async fn shutdown(&mut self, events: &mut mpsc::UnboundedReceiver<Event>) {
        for peer in self.peers.keys() {
            self.send(*peer, ToNode::Shutdown);
        }
        let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
        while self.peers.values().any(|p| p.stats.is_none()) {
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

    fn report(&self) -> Report {
        let start = self.started.unwrap_or_else(Instant::now);
        let last = self.presents.last().map_or(start, |(_, t)| *t);
        let elapsed = last.duration_since(start).as_secs_f64();
        let mut previous = start;
        let mut frame_ms = Vec::new();
        let mut start_to_present = Vec::new();
        for (frame, at) in &self.presents {
            frame_ms.push(at.duration_since(previous).as_secs_f64() * 1000.0);
            previous = *at;
            if let Some(s) = self.frame_started.get(frame) {
                start_to_present.push(at.duration_since(*s).as_secs_f64() * 1000.0);
            }
        }
        let mut displays: Vec<DisplayReport> = self
            .peers
            .values()
            .filter_map(|p| match (&p.role, &p.stats) {
                (PeerRole::Display(d), Some(NodeStats::Display(s))) => {
                    let owned = s.pixels_owned as f64 * 3.0 * s.frames_presented as f64;
                    Some(DisplayReport {
                        id: d.0,
                        host: p.host.clone(),
                        stats: s.clone(),
                        wire_bytes_per_pixel_byte: if owned > 0.0 {
                            s.wire_bytes_received as f64 / owned
                        } else {
                            0.0
                        },
                    })
                }
                _ => None,
            })
            .collect();
        displays.sort_by_key(|d| d.id);
        let mut render_nodes: Vec<RenderNodeReport> = self
            .peers
            .values()
            .filter_map(|p| match (&p.role, &p.stats) {
                (PeerRole::Render { node, cores }, Some(NodeStats::Render(s))) => {
                    Some(RenderNodeReport {
                        id: node.0,
                        host: p.host.clone(),
                        cores: *cores,
                        stats: s.clone(),
                        rays_per_s: if s.busy_s > 0.0 {
                            s.rays as f64 / s.busy_s
                        } else {
                            0.0
                        },
                    })
                }
                _ => None,
            })
            .collect();
        render_nodes.sort_by_key(|r| r.id);
        let frames = self.presents.len() as u64;
        Report {
            frames,
            compression: self.cfg.compression,
            wall: WallReport::of(&self.cfg.wall),
            displays,
            render_nodes,
            fps: if elapsed > 0.0 {
                frames as f64 / elapsed
            } else {
                0.0
            },
            frame_ms: Percentiles::of_ms(&frame_ms),
            start_to_present_ms: Percentiles::of_ms(&start_to_present),
            frame_period_ms: if frames > 0 {
                elapsed * 1000.0 / frames as f64
            } else {
                0.0
            },
            timing: self.timing.summary(self.cfg.wall.display_count()),
            elapsed_s: elapsed,
            render_nodes_lost: self.lost_render_nodes,
            changes_applied: self.changes_applied,
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
