//! The master's driver loop: accepts peers, hands what they say to the sans-IO
//! [`Master`] with the time it happened, and carries out what it returns (messages into each
//! peer's bounded queue, connections closed, the recording, the progress bar). Every decision
//! is the `Master`'s; this is the only place in the master with sockets and `Instant::now()`.

use crate::console::{Bridge, Incoming};
use crate::peers::{accept_peer, Event, PeerSender};
use crate::record::Recorder;
use crate::standby_link::{serve_standby, StandbyPeer};
use anyhow::{Context, Result};
use std::collections::HashMap;
use std::future::Future;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tessera_core::master::report::Report;
use tessera_core::master::standby::{MasterSnapshot, StandbyConfig, ToStandby};
use tessera_core::master::{
    CertifiedRole, CloseReason, Credentials, Join, Master, MasterConfig, MasterEvent, Now, PeerId,
};
use tessera_model::wall::DisplayId;
use tessera_net::cluster::CertRole;
use tessera_net::unix_ns;
use tessera_protocol::{RenderNodeId, Role, ToNode};
use tokio::sync::mpsc;

/// What a run needs to know: the master's own configuration, and what only the driver does.
#[derive(Clone, Debug)]
pub struct RunConfig {
    /// Everything the sans-IO master decides with: the wall, the scene, the camera, the
    /// frames to run, the nodes to wait for.
    pub master: MasterConfig,
    /// Whether to draw a bar of the frames presented on stderr, from the first frame on.
    pub show_progress: bool,
    /// Where to record the session, if anywhere.
    pub record: Option<PathBuf>,
    /// The volume's histogram, for the console; `None` without a volume.
    pub histogram: Option<crate::console::Histogram>,
    /// With `serve --standby-of`: the run this master takes over, once its primary is gone.
    pub takeover: Option<TakeoverFrom>,
}

/// What a standby that took over carries on from.
#[derive(Clone, Debug)]
pub struct TakeoverFrom {
    /// The primary's last replicated snapshot.
    pub snapshot: Box<MasterSnapshot>,
    /// When the primary last spoke: the wall's dark time runs from then to the first frame
    /// this master presents.
    pub last_heard: Instant,
}

/// What the driver tells the tools around the run (the launcher) while the wall runs.
#[derive(Clone, Default)]
pub struct RunSignals {
    /// Set once the first frame starts: the launcher tells a failed start from a node lost
    /// mid-run by it.
    pub started: Arc<AtomicBool>,
    /// Each render node the master took in, with the address its connection comes from, in
    /// the order they joined: the launcher finds the process behind the address, so that
    /// its log lines name the process as the master's name the node (`render node 2`).
    pub render_joins: Arc<Mutex<Vec<(RenderNodeId, SocketAddr)>>>,
    /// Node processes the launcher saw exit mid-run, and how: a process that is gone is
    /// dead at once, not after the failure detector's acceptable pause. `exit_notify` wakes
    /// the driver to read them.
    pub exited: Arc<Mutex<Vec<(ExitedNode, String)>>>,
    /// Notified after each push onto `exited`.
    pub exit_notify: Arc<tokio::sync::Notify>,
}

/// A node whose process the launcher saw exit.
#[derive(Clone, Copy, Debug)]
pub enum ExitedNode {
    /// A render node, by the id the master gave it.
    Render(RenderNodeId),
    /// A display.
    Display(DisplayId),
}

/// How a run ended: its figures and, if it did not complete, why.
pub struct RunEnd {
    /// What the run measured: all of it for a run that completed, what it had for one that
    /// did not (nodes' own figures come only at a normal shutdown).
    pub report: Report,
    /// Why the run did not complete; `None` if it did.
    pub error: Option<anyhow::Error>,
}

/// A joined peer's connection and its queue of messages.
struct Link {
    /// The peer's bounded queue; a task of its own writes it to the peer's stream.
    tx: PeerSender,
    /// The connection, to close when the master says so or the run ends.
    conn: quinn::Connection,
}

impl Link {
    /// Closes the connection with `reason`'s code and phrase.
    fn close(&self, reason: CloseReason) {
        self.conn.close(reason.code().into(), reason.phrase());
    }
}

/// The driver's side of a run: the links, the tools around the master, and the master.
struct Driver {
    /// The sans-IO master, which makes every decision.
    master: Master,
    /// Every joined peer's link, until its connection closes.
    links: HashMap<PeerId, Link>,
    /// With `--record`: writes what each frame is rendered with, a line when it changes.
    recorder: Option<Recorder>,
    /// The progress bar, once the first frame started, if one was asked for.
    progress: Option<indicatif::ProgressBar>,
    /// [`RunConfig::show_progress`].
    show_progress: bool,
    /// What the launcher is told (see [`RunSignals`]).
    signals: RunSignals,
    /// The operator's console, if one is served.
    console: Option<Bridge>,
    /// Where the session is being recorded, by `--record` or from the console.
    recording: Option<PathBuf>,
    /// Where peers' tasks send their events: a standby's task gets a copy.
    events_tx: mpsc::Sender<Event>,
    /// The attached standby master, if any.
    standby: Option<StandbyPeer>,
    /// Standbys attached so far: the next one's generation.
    standbys: u64,
    /// Since when the attached standby has left a replica unacknowledged (`None`: none
    /// outstanding). A standby cut off from the primary acks nothing, and the primary, which
    /// runs no further than its standby acknowledged, would stall until the connection's idle
    /// timeout (12 s): past [`STANDBY_ACK_BOUND`] it is dropped instead.
    standby_unacked_since: Option<Instant>,
    /// After a takeover, until its first frame is presented: when the old primary last spoke.
    dark_since: Option<Instant>,
}

/// How long a primary waits for its standby to acknowledge a replica before it goes on
/// without it: four failure bounds, so that a standby host starved for a moment (a busy
/// machine) is not dropped, while a standby cut off stalls the wall for 2 s, not for the
/// connection's 12 s idle timeout (found by the partition test under CI load: the primary had
/// stopped at its standby's horizon).
const STANDBY_ACK_BOUND: Duration = Duration::from_millis(4 * 500);

/// This moment on both of the master's clocks, for the event about to be handed to it.
fn now() -> Now {
    Now {
        instant: Instant::now(),
        unix_ns: unix_ns(),
    }
}

/// Runs a whole wall on `endpoint` and returns how it ended, with its figures whether it
/// completed or not; `signals` tell the launcher how it goes.
///
/// When `stop` turns true (Ctrl-C), no new frame starts; frames in flight finish and the nodes
/// are shut down as after a normal run. When `fatal` completes (the launcher found a node
/// process the wall cannot do without dead), the run ends at once with its error.
///
/// # Errors
/// Only a run that could not start: the recording cannot be created, or the replayed
/// session cannot be scheduled.
pub async fn run_wall(
    endpoint: quinn::Endpoint,
    cfg: RunConfig,
    signals: RunSignals,
    mut stop: tokio::sync::watch::Receiver<bool>,
    fatal: impl Future<Output = anyhow::Error>,
    console: Option<Bridge>,
) -> Result<RunEnd> {
    let (events_tx, mut events) = mpsc::channel(crate::peers::EVENT_QUEUE);
    let events_own = events_tx.clone();
    let acceptor = spawn_acceptor(endpoint.clone(), events_tx);
    tracing::info!(
        "waiting for {} display node(s) and {} render node(s) on {}",
        cfg.master.wall.display_count(),
        cfg.master.render_nodes,
        endpoint.local_addr()?
    );
    let dark_since = cfg.takeover.as_ref().map(|t| t.last_heard);
    let master = match cfg.takeover {
        Some(from) => Master::take_over(cfg.master, *from.snapshot, now())?,
        None => Master::new(cfg.master, now())?,
    };
    let mut recorder = cfg.record.as_deref().map(Recorder::create).transpose()?;
    if let Some(recorder) = &mut recorder {
        // A taken-over run's file starts with what its primary recorded (none for a new run).
        recorder.taken_over(master.session_lines())?;
    }
    let mut driver = Driver {
        recorder,
        master,
        events_tx: events_own,
        standby: None,
        standbys: 0,
        standby_unacked_since: None,
        dark_since,
        links: HashMap::new(),
        progress: None,
        show_progress: cfg.show_progress,
        signals,
        console,
        recording: cfg.record.clone(),
    };
    let result = tokio::select! {
        result = driver.run(&mut events, &mut stop) => result,
        error = fatal => Err(error),
    };
    driver.close_links();
    acceptor.abort();
    endpoint.close(0u32.into(), b"run over");
    let _ = tokio::time::timeout(Duration::from_secs(2), endpoint.wait_idle()).await;
    Ok(match result {
        Ok(report) => RunEnd {
            report,
            error: None,
        },
        Err(error) => RunEnd {
            report: driver.master.report_so_far(),
            error: Some(error),
        },
    })
}

/// Accepts every peer that connects to `endpoint`, each with the next [`PeerId`], its events
/// sent to `events`.
fn spawn_acceptor(
    endpoint: quinn::Endpoint,
    events: mpsc::Sender<Event>,
) -> tokio::task::JoinHandle<()> {
    tokio::spawn(async move {
        let mut next = 0u64;
        while let Some(incoming) = endpoint.accept().await {
            next += 1;
            tokio::spawn(accept_peer(incoming, PeerId(next), events.clone()));
        }
    })
}

impl Driver {
    /// The run is over: the progress bar goes, and every node and the standby are told.
    fn close_links(&self) {
        if let Some(bar) = &self.progress {
            bar.finish_and_clear();
        }
        for link in self.links.values() {
            link.close(CloseReason::RunOver);
        }
        if let Some(standby) = &self.standby {
            // Said on purpose: a standby takes over from a primary that is gone, not from one
            // whose run is over.
            let code = crate::standby_link::RUN_OVER;
            standby.conn.close(code.into(), b"run over");
        }
    }

    /// Feeds the master until its run is over.
    async fn run(
        &mut self,
        events: &mut mpsc::Receiver<Event>,
        stop: &mut tokio::sync::watch::Receiver<bool>,
    ) -> Result<Report> {
        // Whether the interrupt was handled. Not `*stop.borrow()` in the branch's condition: an
        // interrupt that came while an event was being handled would already read true there,
        // disable the branch before `changed()` ever reported it, and be lost (the wall then ran
        // on after Ctrl-C). `changed()` reports a value not yet seen whenever it is polled.
        let mut stopping = false;
        let mut tick = tokio::time::interval(crate::console::TICK);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
        let mut beat = tokio::time::interval(StandbyConfig::default().heartbeat_interval);
        beat.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            if let Some(outcome) = self.master.take_outcome() {
                return Ok(outcome?);
            }
            let timer = self.master.poll_timeout();
            let timer_at = tokio::time::Instant::from_std(
                timer.unwrap_or_else(|| Instant::now() + Duration::from_secs(86_400)),
            );
            tokio::select! {
                event = events.recv() => {
                    let event = event.context("endpoint closed")?;
                    self.handle(event);
                }
                _ = tokio::time::sleep_until(timer_at), if timer.is_some() => {
                    // What arrived before the timer fired counts first: a master that was
                    // paused must not find its nodes silent while their heartbeats wait here.
                    for _ in 0..crate::peers::EVENT_QUEUE {
                        let Ok(event) = events.try_recv() else { break };
                        self.handle(event);
                        self.carry_out()?;
                    }
                    self.master.handle_timeout(now());
                }
                () = self.signals.exit_notify.notified() => self.processes_exited(),
                Some(incoming) = async {
                    match self.console.as_mut() {
                        Some(c) => c.next().await,
                        None => std::future::pending().await,
                    }
                } => match incoming {
                    // A console that gave up waiting has nothing to be told.
                    Incoming::Call(call) => {
                        let reply = self.master.handle_local_control(call.request, now());
                        let _ = call.reply.send(reply);
                    }
                    Incoming::Record(call) => {
                        let _ = call.reply.send(self.record_from_console(call.start));
                    }
                },
                _ = tick.tick(), if self.console.is_some() => self.console_tick(),
                _ = beat.tick(), if self.standby.is_some() => {
                    self.send_standby(ToStandby::Heartbeat);
                    self.drop_silent_standby();
                }
                changed = stop.changed(), if !stopping => {
                    stopping = true;
                    // The interrupt watcher gone without an interrupt: nothing to stop.
                    if changed.is_ok() || *stop.borrow() {
                        self.master.handle_interrupt(now());
                    }
                }
            }
            self.carry_out()?;
        }
    }

    /// Hands one peer event to the master: a join (with what the peer's certificate lets it
    /// be), a message, or a closed connection.
    fn handle(&mut self, event: Event) {
        match event {
            Event::Joined {
                peer,
                hello,
                conn,
                tx,
            } => {
                let credentials = credentials(&conn, &hello.role, &hello.host);
                let remote = conn.remote_address();
                self.links.insert(peer, Link { tx, conn });
                let join = Join {
                    peer,
                    hello,
                    remote,
                    credentials,
                };
                self.master.handle_join(join, now());
                if let Some(node) = self.master.render_node_of(peer) {
                    let joins = &self.signals.render_joins;
                    let mut joins = joins.lock().unwrap_or_else(|e| e.into_inner());
                    joins.push((node, remote));
                }
            }
            Event::Msg(peer, msg) => self.master.handle_message(peer, msg, now()),
            Event::Closed(peer, reason) => {
                self.links.remove(&peer);
                self.master.handle_closed(peer, &reason, now());
            }
            Event::Standby(conn) => self.attach_standby(conn),
            Event::StandbyAck(generation, ack) => {
                if self
                    .standby
                    .as_ref()
                    .is_some_and(|s| s.generation == generation)
                {
                    self.standby_unacked_since = None;
                    self.master.handle_replica_ack(ack, now());
                }
            }
            Event::StandbyClosed(generation, reason) => {
                if self
                    .standby
                    .as_ref()
                    .is_some_and(|s| s.generation == generation)
                {
                    tracing::warn!("the standby master's connection closed: {reason}");
                    self.standby = None;
                    self.standby_unacked_since = None;
                    self.master.detach_standby(now());
                } else {
                    tracing::info!("a dropped standby master's connection closed: {reason}");
                }
            }
        }
    }

    /// A standby master connected: one with a `master` certificate is attached (replacing
    /// any before it) and sent the whole snapshot; any other is closed.
    fn attach_standby(&mut self, conn: quinn::Connection) {
        let remote = conn.remote_address();
        let roles = tessera_net::quic::peer_roles(&conn);
        if !roles.contains(&CertRole::Master) {
            tracing::warn!(
                "refused a standby from {remote}: its certificate is not a master's (roles {roles:?})"
            );
            conn.close(1u32.into(), b"a standby needs a master certificate");
            return;
        }
        if let Some(old) = self.standby.take() {
            old.conn.close(1u32.into(), b"replaced by another standby");
        }
        tracing::info!("standby master at {remote} attached");
        let replica = self.master.attach_standby(now());
        self.standbys += 1;
        let first = ToStandby::Replica(Box::new(replica));
        let peer = serve_standby(conn, self.standbys, first, self.events_tx.clone());
        self.standby = Some(peer);
        // Its first replica, sent with the stream, is outstanding.
        self.standby_unacked_since = Some(Instant::now());
    }

    /// Drops the standby if it left a replica unacknowledged past the failure bound (see
    /// `standby_unacked_since`).
    fn drop_silent_standby(&mut self) {
        let bound = STANDBY_ACK_BOUND;
        if self
            .standby_unacked_since
            .is_none_or(|t| t.elapsed() <= bound)
        {
            return;
        }
        if let Some(standby) = self.standby.take() {
            tracing::warn!(
                "the standby master acknowledged nothing for {} ms: going on without it",
                bound.as_millis()
            );
            let code = crate::standby_link::DROPPED;
            standby
                .conn
                .close(code.into(), b"no acknowledgement within the failure bound");
        }
        self.standby_unacked_since = None;
        self.master.detach_standby(now());
    }

    /// Queues a message for the standby's writer.
    fn send_standby(&self, msg: ToStandby) {
        if let Some(standby) = &self.standby {
            // A writer that ended has its `StandbyClosed` on the way.
            let _ = standby.tx.send(msg);
        }
    }

    /// Starts recording the session into `start`, or stops (`None`): the console's Record.
    /// The file being written, or why not.
    fn record_from_console(&mut self, start: Option<PathBuf>) -> Result<Option<PathBuf>, String> {
        match (start, &self.recording) {
            (Some(_), Some(now)) => Err(format!("already recording to {}", now.display())),
            (Some(path), None) => {
                self.recorder = Some(Recorder::create(&path).map_err(|e| format!("{e:#}"))?);
                tracing::info!("recording the session to {}", path.display());
                self.recording = Some(path.clone());
                Ok(Some(path))
            }
            (None, _) => {
                // Dropping the recorder writes what it holds and closes the file.
                self.recorder = None;
                if let Some(path) = self.recording.take() {
                    tracing::info!("recorded the session to {}", path.display());
                }
                Ok(None)
            }
        }
    }

    /// Tells the console what the wall is doing, and asks the displays for thumbnails when
    /// there is something new to picture.
    fn console_tick(&mut self) {
        use tessera_protocol::control::ControlRequest;
        let Some(console) = &mut self.console else {
            return;
        };
        let status = self
            .master
            .handle_local_control(ControlRequest::Status, now());
        let figures = self
            .master
            .handle_local_control(ControlRequest::Figures, now());
        if console.publish(status, figures) {
            self.master.ask_thumbnails();
        }
    }

    /// Node processes the launcher saw exit: their connections are closed now, as if the
    /// nodes had left, rather than waited out as silence.
    fn processes_exited(&mut self) {
        let exited = {
            let mut exited = self
                .signals
                .exited
                .lock()
                .unwrap_or_else(|e| e.into_inner());
            std::mem::take(&mut *exited)
        };
        for (node, how) in exited {
            let peer = match node {
                ExitedNode::Render(id) => self.master.peer_of_render(id),
                ExitedNode::Display(d) => self.master.peer_of_display(d),
            };
            let Some(peer) = peer else { continue };
            if let Some(link) = self.links.remove(&peer) {
                link.close(CloseReason::RunOver);
            }
            let reason = format!("its process {how}");
            self.master.handle_closed(peer, &reason, now());
        }
    }

    /// Carries out what the master decided: messages, closes, and its events.
    fn carry_out(&mut self) -> Result<()> {
        // Before the transmits: the standby learns of a frame no later than the nodes do.
        while let Some(replica) = self.master.poll_replica() {
            self.send_standby(ToStandby::Replica(Box::new(replica)));
            if self.standby.is_some() {
                self.standby_unacked_since.get_or_insert_with(Instant::now);
            }
        }
        loop {
            if let Some(t) = self.master.poll_transmit() {
                self.send(t.peer, t.msg);
            } else if let Some((peer, reason)) = self.master.poll_close() {
                if let Some(link) = self.links.get(&peer) {
                    link.close(reason);
                }
            } else if let Some(event) = self.master.poll_event() {
                self.note(event)?;
            } else if let Some(event) = self.master.poll_console() {
                let factor = self.master.thumbnail_factor();
                if let Some(console) = &mut self.console {
                    console.handle(event, factor);
                }
            } else {
                return Ok(());
            }
        }
    }

    /// Does the driver's part of one of the master's events: the launcher's started flag,
    /// the recording, the progress bar.
    fn note(&mut self, event: MasterEvent) -> Result<()> {
        match event {
            MasterEvent::Started => {
                self.signals.started.store(true, Ordering::SeqCst);
                if self.show_progress {
                    self.progress = Some(progress_bar(self.master.frames_limit()));
                }
            }
            MasterEvent::FrameStarted(started) => {
                if let Some(recorder) = &mut self.recorder {
                    recorder.frame(&started.0, started.1)?;
                }
            }
            MasterEvent::FrameRendered(_) => {}
            MasterEvent::FramePresented(_) => {
                if let Some(since) = self.dark_since.take() {
                    let dark = since.elapsed();
                    self.master.record_takeover_dark(dark);
                    if let Some(recorder) = &mut self.recorder {
                        recorder.takeover(self.master.term(), dark)?;
                    }
                    // Scripts and tests read this line.
                    eprintln!(
                        "tessera-master: took the wall over; dark for {} ms",
                        dark.as_millis()
                    );
                }
                if let Some(bar) = &self.progress {
                    bar.inc(1);
                }
            }
        }
        Ok(())
    }

    /// Queues a message for a peer; one that left its queue full is closed: it is gone or
    /// hostile, and its `Closed` event tells the master.
    fn send(&self, peer: PeerId, msg: ToNode) {
        let Some(link) = self.links.get(&peer) else {
            return;
        };
        match link.tx.try_send(msg) {
            Ok(()) => {}
            // The peer is gone; its Closed event is on the way.
            Err(mpsc::error::TrySendError::Closed(_)) => {}
            Err(mpsc::error::TrySendError::Full(_)) => {
                tracing::error!(
                    "closing peer {}: it left {} messages unread",
                    peer.0,
                    crate::peers::PEER_QUEUE
                );
                link.close(CloseReason::NotReading);
            }
        }
    }
}

/// What the peer's certificate lets it be, read from its TLS session.
fn credentials(conn: &quinn::Connection, role: &Role, host: &str) -> Credentials {
    let roles = tessera_net::quic::peer_roles(conn)
        .into_iter()
        .map(|r| match r {
            CertRole::Master => CertifiedRole::Master,
            CertRole::Render => CertifiedRole::Render,
            CertRole::Display => CertifiedRole::Display,
            CertRole::Control => CertifiedRole::Control,
        })
        .collect();
    let names_claimed_display = match role {
        Role::Display { display, .. } => tessera_net::quic::peer_is_display(conn, display.0),
        _ => false,
    };
    Credentials {
        roles,
        names_claimed_display,
        same_host: host == tessera_net::hostname(),
    }
}

/// A bar of frames presented, out of `frames` (`None`: a run until interrupted, no total).
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

/// Binds the master's endpoint.
pub fn bind(
    addr: SocketAddr,
    identity: &tessera_net::cluster::NodeIdentity,
) -> Result<quinn::Endpoint> {
    tessera_net::quic::endpoint(addr, identity, true)
        .context("cannot start the master's QUIC endpoint")
}
