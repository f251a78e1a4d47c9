//! The master's decisions, sans IO: who may join and as what, when a display that rejoined is
//! shown frames again, which render node holds which rank of a shared scene, what each
//! control request and window input does to the wall's state, when displays present, what a
//! lost display costs under each [`DisplayLoss`] policy, the figures of the run and its
//! report. The load balancer and frame barrier ([`Coordinator`]) sit inside it.
//!
//! It follows quinn-proto's shape: `handle_*` methods take what happened (a peer joined, a
//! message, a connection closed, a timer, an interrupt) with the time it happened ([`Now`]);
//! `poll_*` methods give what to do (a message for a peer, a connection to close with a typed
//! [`CloseReason`], the next timeout, events for the operator's tools) and, once the run is
//! over, its [`Report`] or the [`RunError`] that ended it. Poll every `poll_*` queue after each
//! `handle_*` call. The master's driver (`tessera-master`'s `server`) moves bytes between
//! sockets and these calls; the simulator ([`crate::sim::SimWall`]) drives the very same
//! `Master` over a virtual network.
//!
//! A second master can stand by: the primary sends it [`standby::MasterSnapshot`]s as they
//! change ([`Master::attach_standby`], [`Master::poll_replica`]) and runs no further than the
//! standby acknowledged; a [`standby::Standby`] says when the primary is gone, and
//! [`Master::take_over`] carries the run on under the next term, past every frame and state
//! the old master used. The [`standby`] module documents the protocol.
//!
//! # Examples
//!
//! A one-display wall with one render node: both join, say they are ready, and the first
//! frame starts.
//!
//! ```
//! use std::time::Instant;
//! use tessera_core::master::{Credentials, Join, Master, MasterConfig, Now, PeerId};
//! use tessera_protocol::{FromNode, Hello, Role, ToNode, PROTOCOL_VERSION};
//! use tessera_model::wall::{DisplayId, WallSpec};
//!
//! let wall = WallSpec::grid(1, 1, 64, 64).tile_size(32).build().unwrap();
//! let now = Now { instant: Instant::now(), unix_ns: 1 };
//! let mut master = Master::new(MasterConfig::new(wall, 1), now).unwrap();
//! let join = |peer, role| Join {
//!     peer: PeerId(peer),
//!     credentials: Credentials::for_role(&role),
//!     hello: Hello { version: PROTOCOL_VERSION, host: "h".into(), role },
//!     remote: "127.0.0.1:9000".parse().unwrap(),
//! };
//! let display = Role::Display { display: DisplayId(0), pixel_addr: "127.0.0.1:9100".parse().unwrap() };
//! master.handle_join(join(1, display), now);
//! master.handle_join(join(2, Role::Render { cores: 4 }), now);
//! master.handle_message(PeerId(1), FromNode::Ready, now);
//! master.handle_message(PeerId(2), FromNode::Ready, now);
//! let mut started = Vec::new();
//! while let Some(t) = master.poll_transmit() {
//!     if let (PeerId(1), ToNode::FrameStart(start)) = (t.peer, t.msg) {
//!         started.push(start.frame.0);
//!     }
//! }
//! assert_eq!(started, [0], "frame 0 starts on the display");
//! ```

mod barrier;
mod control;
mod errors;
pub use errors::{MasterError, RunError};
pub mod figures;
mod liveness;
mod loading;
mod membership;
pub use membership::JoinRefusal;
mod messages;
pub mod navigate;
mod operate;
#[cfg(test)]
mod operate_tests;
pub use operate::{ConsoleEvent, OperatorConfig};
mod ranks;
pub mod report;
mod report_of;
pub mod standby;
#[cfg(test)]
mod standby_tests;
mod takeover;
#[cfg(test)]
mod tests;
pub mod timing;

use crate::balance::{BalanceConfig, BalanceError, Coordinator, Refinement};
use navigate::Navigator;
use report::Report;
use std::collections::{BTreeMap, HashMap, VecDeque};
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tessera_model::camera::{Camera, CameraMode};
use tessera_model::params::RenderParams;
use tessera_model::scene_spec::SceneSpec;
use tessera_model::state::{StateChange, WallState};
use tessera_model::wall::{DisplayId, TileGrid, TileId, WallLayout};
use tessera_model::window::WindowPlacement;
use tessera_protocol::control::{ProbeHit, Refusal};
use tessera_protocol::dsm::DataSpec;
use tessera_protocol::pixels::Compression;
use tessera_protocol::{FrameId, FromNode, Hello, NodeStats, RenderNodeId, Role, ToNode};
use timing::Timing;

/// How long the master waits, once the frames are over, for the nodes' figures.
pub const STATS_WAIT: Duration = Duration::from_secs(10);

/// The moment something happened, on both of the master's clocks: the monotonic one that
/// deadlines run on, and the Unix clock that displays stamp their presents with.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Now {
    /// The monotonic clock, for deadlines and timeouts.
    pub instant: Instant,
    /// Nanoseconds since the Unix epoch.
    pub unix_ns: u64,
}

/// A peer's connection, as the driver numbers them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct PeerId(pub u64);

/// What the wall does when a display is lost mid-run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum DisplayLoss {
    /// The other displays go on; the lost one may rejoin and is shown frames again.
    #[default]
    GoOn,
    /// No new frame starts until it rejoins, for at most the join timeout.
    Wait,
    /// The run ends.
    Stop,
}

/// A role a certificate may name.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum CertifiedRole {
    /// May join as a render node.
    Render,
    /// May join as a display (the one it names; see [`Credentials::names_claimed_display`]).
    Display,
    /// May join as a control client.
    Control,
    /// The master's own certificate; it lets a peer join in no role.
    Master,
}

/// What the peer's certificate lets it be, as the driver read it from the TLS session.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Credentials {
    /// The roles the certificate names; none for a certificate from before roles.
    pub roles: Vec<CertifiedRole>,
    /// Whether the certificate names the display the hello claims.
    pub names_claimed_display: bool,
    /// Whether the peer runs on the master's own host (so it reads the master's clock).
    pub same_host: bool,
}

impl Credentials {
    /// A certificate for exactly `role` (and its display), on another host: what tests and the
    /// simulator join with.
    pub fn for_role(role: &Role) -> Credentials {
        let (role, display) = match role {
            Role::Render { .. } => (CertifiedRole::Render, false),
            Role::Display { .. } => (CertifiedRole::Display, true),
            Role::Control => (CertifiedRole::Control, false),
        };
        Credentials {
            roles: vec![role],
            names_claimed_display: display,
            same_host: false,
        }
    }
}

/// A peer that finished its handshake and said hello.
#[derive(Clone, Debug)]
pub struct Join {
    /// The connection, as the driver numbers it.
    pub peer: PeerId,
    /// What the peer says it is: its role, host and protocol version.
    pub hello: Hello,
    /// Where its connection comes from.
    pub remote: SocketAddr,
    /// What its certificate lets it be.
    pub credentials: Credentials,
}

/// A message for one peer.
#[derive(Clone, Debug, PartialEq)]
pub struct Transmit {
    /// The connection to send it on.
    pub peer: PeerId,
    /// The message.
    pub msg: ToNode,
}

/// Why the master closes a connection.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CloseReason {
    /// It sent what its role never sends, or a message that broke the protocol.
    ProtocolViolation,
    /// It was silent past the node deadline.
    SilentPastDeadline,
    /// It left its bounded queue of messages unread (the driver finds this, not the master).
    NotReading,
    /// The run is over.
    RunOver,
    /// The same display joined again on a new connection (it was restarted).
    Replaced,
    /// A node follows a master of a higher term: this master steps down.
    SteppedDown,
}

impl CloseReason {
    /// The QUIC application error code the connection closes with.
    pub fn code(self) -> u32 {
        match self {
            CloseReason::ProtocolViolation => 2,
            CloseReason::NotReading => 4,
            CloseReason::SilentPastDeadline => 5,
            CloseReason::RunOver => 0,
            CloseReason::Replaced => 6,
            CloseReason::SteppedDown => 7,
        }
    }

    /// The reason phrase the connection closes with.
    pub fn phrase(self) -> &'static [u8] {
        match self {
            CloseReason::ProtocolViolation => b"protocol violation",
            CloseReason::NotReading => b"not reading",
            CloseReason::SilentPastDeadline => b"silent past the deadline",
            CloseReason::RunOver => b"run over",
            CloseReason::Replaced => b"replaced by a new connection",
            CloseReason::SteppedDown => b"stepped down: a newer master leads the wall",
        }
    }
}

/// What the run did that the tools around the master want to know (progress, recording).
#[derive(Clone, Debug, PartialEq)]
pub enum MasterEvent {
    /// Every node is ready and the first frame started.
    Started,
    /// A frame started, and the wall state it started with (what a session recording keeps).
    FrameStarted(Box<(tessera_protocol::FrameStart, WallState)>),
    /// Every display still in the run presented this frame.
    FramePresented(FrameId),
    /// The last tile of this frame is done (the frame may still wait for its present).
    FrameRendered(FrameId),
}

/// What the master answers a probe of the volume with: implemented where the renderer is
/// (the master crate), called here without I/O.
pub trait VolumeProbe: Send + Sync + std::fmt::Debug {
    /// What wall pixel `(x, y)` shows of the volume, seen by `camera` with `params`.
    ///
    /// # Errors
    /// A pixel outside the wall.
    fn probe(
        &self,
        camera: &Camera,
        params: &RenderParams,
        wall: &WallLayout,
        pixel: (u32, u32),
    ) -> Result<Option<ProbeHit>, Refusal>;
}

/// What a run needs to know.
#[derive(Clone, Debug)]
pub struct MasterConfig {
    /// The wall's screens and tiles.
    pub wall: WallLayout,
    /// Progressive refinement while the camera holds still, if the run does it.
    pub refinement: Option<Refinement>,
    /// Where displays put their windows (from the wall file).
    pub windows: BTreeMap<u32, WindowPlacement>,
    /// What render nodes load and render.
    pub scene: SceneSpec,
    /// Content hash of the scene as the master loaded it; render nodes that load other bytes
    /// refuse to join.
    pub scene_hash: [u8; 32],
    /// How render nodes hold the scene.
    pub data: DataSpec,
    /// The camera of the first frame's state: fixed, or a path over the frames.
    pub camera: CameraMode,
    /// The render knobs of the first frame's state.
    pub params: RenderParams,
    /// Frames to run; `None` runs until interrupted.
    pub frames: Option<u64>,
    /// Render nodes to wait for before the first frame.
    pub render_nodes: u32,
    /// The frame every display saves as `display-<id>.png` (None: none).
    pub save_frame: Option<FrameId>,
    /// How render nodes pack tiles for the displays.
    pub compression: Compression,
    /// How long nodes have to join before the first frame (and a lost display to come back
    /// under [`DisplayLoss::Wait`]).
    pub join_timeout: Duration,
    /// How long, once every node the wall needs has joined, they have to load the scene and
    /// say they are ready: a big scene may load for minutes.
    pub load_timeout: Duration,
    /// The load balancer's knobs: the node deadline, speculation; its display wait is set
    /// from `display_loss` and `join_timeout`.
    pub balance: BalanceConfig,
    /// What a display lost mid-run does to the wall.
    pub display_loss: DisplayLoss,
    /// Displays present this long after the barrier decision, all at the same instant; zero
    /// presents on arrival.
    pub present_margin: Duration,
    /// Changes a recorded session makes, by frame.
    pub replay: Vec<(FrameId, WallState)>,
    /// Where input from the windows orbits about (the scene's centre).
    pub pivot: glam::Vec3,
    /// The scene's size (half its diagonal), in scene units: the unit of a fly step and of the
    /// closest zoom; a size that is not positive and finite counts as 1.
    pub scene_size: f32,
    /// What operators see of the scene, and whether its series plays from the start.
    pub operator: OperatorConfig,
    /// The scene's volume, for the control interface's probe (None: no volume).
    pub probe: Option<Arc<dyn VolumeProbe>>,
}

impl MasterConfig {
    /// A wall of `wall` with `render_nodes` render nodes, the empty scene replicated, a
    /// fixed camera on the z axis, interactive quality, no frame limit and the defaults of
    /// [`BalanceConfig`]: what tests and the simulator start from.
    pub fn new(wall: WallLayout, render_nodes: u32) -> MasterConfig {
        let camera = Camera::new(glam::Vec3::Z, glam::Vec3::ZERO, glam::Vec3::Y, 45.0)
            .expect("a valid constant camera");
        MasterConfig {
            wall,
            refinement: None,
            windows: BTreeMap::new(),
            scene: SceneSpec::Empty,
            scene_hash: [0; 32],
            data: DataSpec::Replicated,
            camera: CameraMode::fixed(camera),
            params: RenderParams::interactive(),
            frames: None,
            render_nodes,
            save_frame: None,
            compression: Compression::None,
            join_timeout: Duration::from_secs(30),
            load_timeout: Duration::from_secs(600),
            balance: BalanceConfig::default(),
            display_loss: DisplayLoss::GoOn,
            present_margin: Duration::ZERO,
            replay: Vec::new(),
            pivot: glam::Vec3::ZERO,
            scene_size: 1.0,
            operator: OperatorConfig::default(),
            probe: None,
        }
    }
}

/// Where the run is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Phase {
    /// Waiting for every node to be ready, until the deadline.
    Joining {
        deadline: Instant,
    },
    Running,
    /// Frames over; the nodes were asked for their figures, which may come until the deadline.
    Collecting {
        deadline: Instant,
    },
    /// The outcome is set.
    Done,
}

enum PeerRole {
    Render { node: RenderNodeId, cores: u32 },
    Display(DisplayId),
    Control,
}

struct Peer {
    role: PeerRole,
    host: String,
    remote: SocketAddr,
    /// Sent its welcome: a render node gets one, however many displays rejoin meanwhile.
    welcomed: bool,
    ready: bool,
    stats: Option<NodeStats>,
}

/// What the run measured so far, for the figures and the report.
#[derive(Default)]
struct RunRecord {
    started: Option<Instant>,
    frame_started: HashMap<FrameId, Instant>,
    presents: Vec<(FrameId, Instant)>,
    timing: Timing,
    lost_render_nodes: u32,
    /// Displays lost while the wall went on without them, or waited for them.
    lost_displays: u32,
    /// Frames presented while some display was not showing them (lost, or not yet back).
    frames_short_of_displays: u64,
    /// The nodes counted in the two losses above, by name.
    lost: Vec<report::LostNode>,
    /// State changes the barrier applied.
    changes_applied: u64,
    /// Frames abandoned in flight (runaways, or at an interrupt).
    frames_cancelled: u32,
    /// Refinement passes dropped because a change made them stale.
    refinement_passes_dropped: u32,
    /// Nodes found silent past the suspicion deadline (each time).
    suspicions: u32,
    /// Times the master woke later than it asked to, and the longest.
    master_pauses: u32,
    longest_master_pause: Duration,
}

/// The master of one wall run: see the module documentation.
pub struct Master {
    cfg: MasterConfig,
    coordinator: Coordinator,
    phase: Phase,
    peers: HashMap<PeerId, Peer>,
    /// Displays shown frames: joined before the start, or ready after rejoining.
    displays: BTreeMap<DisplayId, PeerId>,
    renders: BTreeMap<RenderNodeId, PeerId>,
    /// Where render nodes reach each display's pixel endpoint.
    display_endpoints: BTreeMap<DisplayId, SocketAddr>,
    /// For a display that rejoined the running wall, the first frame it is shown.
    display_since: BTreeMap<DisplayId, FrameId>,
    next_render_id: u32,
    record: RunRecord,
    live: control::Live,
    operating: operate::Operating,
    /// What the console is told (see [`ConsoleEvent`]).
    console_events: VecDeque<ConsoleEvent>,
    navigator: Navigator,
    /// The state of the frames starting now (as the last `StateApplied` said).
    frame_state: WallState,
    ranks: ranks::Ranks,
    /// Whether every node has joined, and how far loading render nodes are.
    loading: loading::Loading,
    transmits: VecDeque<Transmit>,
    closes: VecDeque<(PeerId, CloseReason)>,
    events: VecDeque<MasterEvent>,
    outcome: Option<Result<Report, RunError>>,
    /// 0 for the first master of a run; one more at each takeover.
    term: u64,
    /// The session record: a line each time a frame starts with another state.
    session: Vec<standby::SessionLine>,
    /// What the standby has been sent, while one is attached.
    replication: Option<takeover::Replication>,
    /// The figures of the masters before this one, after a takeover.
    prior: Option<takeover::Prior>,
    /// The run's takeovers so far.
    takeovers: Vec<report::Takeover>,
    /// Who held each rank under the master before a takeover.
    former_ranks: Vec<standby::RankHolder>,
}

impl Master {
    /// A master waiting for its nodes until `now` plus the join timeout.
    ///
    /// # Errors
    /// A replayed session whose changes the coordinator cannot schedule.
    pub fn new(mut cfg: MasterConfig, now: Now) -> Result<Master, MasterError> {
        let grid = TileGrid::new(cfg.wall.clone());
        cfg.balance.wait_for_lost_displays =
            (cfg.display_loss == DisplayLoss::Wait).then_some(cfg.join_timeout);
        let mut coordinator = Coordinator::new(
            grid.len() as u32,
            cfg.wall.display_count(),
            cfg.camera,
            cfg.params,
            cfg.frames,
            cfg.balance,
        );
        coordinator.set_refinement(cfg.refinement);
        coordinator.set_tile_displays(
            (0..grid.len() as u32)
                .map(|t| grid.tile(TileId(t)).expect("every id below len").display)
                .collect(),
        );
        for &(frame, wall) in &cfg.replay {
            coordinator
                .schedule_change(frame, StateChange::All(wall))
                .map_err(MasterError::Replay)?;
        }
        let frame_state = coordinator.state().1;
        Ok(Master {
            coordinator,
            phase: Phase::Joining {
                deadline: now.instant + cfg.join_timeout,
            },
            peers: HashMap::new(),
            displays: BTreeMap::new(),
            renders: BTreeMap::new(),
            display_endpoints: BTreeMap::new(),
            display_since: BTreeMap::new(),
            next_render_id: 0,
            record: RunRecord::default(),
            live: control::Live::default(),
            operating: operate::Operating::new(&cfg.operator),
            console_events: VecDeque::new(),
            navigator: Navigator::new(cfg.camera, cfg.pivot, cfg.scene_size),
            frame_state,
            ranks: ranks::Ranks::default(),
            loading: loading::Loading::default(),
            transmits: VecDeque::new(),
            closes: VecDeque::new(),
            events: VecDeque::new(),
            outcome: None,
            term: 0,
            session: Vec::new(),
            replication: None,
            prior: None,
            takeovers: Vec::new(),
            former_ranks: Vec::new(),
            cfg,
        })
    }

    /// A peer joined: it is welcomed, or refused with [`ToNode::Refused`] (its certificate
    /// is for another role, or its display is taken or does not exist).
    pub fn handle_join(&mut self, join: Join, now: Now) {
        if self.phase == Phase::Done {
            return;
        }
        self.credit_own_pause(now);
        self.join(join, now);
        self.start_if_ready(now);
        self.pump(now);
    }

    /// A message from a peer. One its role never sends closes its connection.
    pub fn handle_message(&mut self, peer: PeerId, msg: FromNode, now: Now) {
        if self.phase == Phase::Done {
            return;
        }
        self.credit_own_pause(now);
        if let FromNode::StaleMaster { seen } = msg {
            self.stale_master(peer, seen, now);
            return;
        }
        if let Phase::Collecting { .. } = self.phase {
            self.collect(peer, msg, now);
            return;
        }
        if let Err(e) = self.message(peer, msg, now) {
            tracing::error!("closing {}: {e}", self.describe(peer));
            let close = CloseReason::ProtocolViolation;
            self.close_and_drop(peer, close, now, "protocol violation");
        }
        self.start_if_ready(now);
        self.pump(now);
    }

    /// A peer's connection closed (`reason` as the transport says it).
    pub fn handle_closed(&mut self, peer: PeerId, reason: &str, now: Now) {
        self.credit_own_pause(now);
        match self.phase {
            Phase::Done => {}
            Phase::Collecting { .. } => {
                if self.peers.get(&peer).is_some_and(|p| p.stats.is_none()) {
                    self.peers.remove(&peer);
                }
                self.finish_if_collected();
            }
            _ => {
                self.drop_noted(peer, now, reason);
                self.pump(now);
            }
        }
    }

    /// The time [`Master::poll_timeout`] gave has come (or passed).
    pub fn handle_timeout(&mut self, now: Now) {
        self.credit_own_pause(now);
        match self.phase {
            Phase::Joining { deadline } if now.instant >= deadline => self.joining_timed_out(),
            Phase::Collecting { deadline } if now.instant >= deadline => {
                tracing::warn!(
                    "some nodes sent no stats within {} s; the report lacks them",
                    STATS_WAIT.as_secs()
                );
                self.finish();
            }
            Phase::Running => {
                self.coordinator.handle_timeout(now.instant);
                self.series_timeout(now);
                self.pump(now);
            }
            _ => {}
        }
    }

    /// Ctrl-C: no new frame starts; frames in flight have [`crate::balance::INTERRUPT_GRACE`]
    /// to finish (then they are cancelled) and the nodes are shut down as after a normal run.
    pub fn handle_interrupt(&mut self, now: Now) {
        self.credit_own_pause(now);
        match self.phase {
            Phase::Joining { .. } => self.fail(RunError::InterruptedBeforeStart),
            Phase::Running => {
                tracing::warn!(
                    "interrupted: finishing the frames in flight (at most {} s), then shutting down",
                    crate::balance::INTERRUPT_GRACE.as_secs()
                );
                self.coordinator.interrupt(now.instant);
                self.pump(now);
            }
            Phase::Collecting { .. } | Phase::Done => {}
        }
    }

    /// The next message to send.
    pub fn poll_transmit(&mut self) -> Option<Transmit> {
        self.transmits.pop_front()
    }

    /// The next connection to close, and why.
    pub fn poll_close(&mut self) -> Option<(PeerId, CloseReason)> {
        self.closes.pop_front()
    }

    /// The next event for the tools around the master.
    pub fn poll_event(&mut self) -> Option<MasterEvent> {
        self.events.pop_front()
    }

    /// When to call [`Master::handle_timeout`]; `None` while nothing is timed.
    pub fn poll_timeout(&self) -> Option<Instant> {
        match self.phase {
            Phase::Joining { deadline } | Phase::Collecting { deadline } => Some(deadline),
            Phase::Running => match (self.coordinator.poll_timeout(), self.series_timer()) {
                (Some(a), Some(b)) => Some(a.min(b)),
                (a, b) => a.or(b),
            },
            Phase::Done => None,
        }
    }

    /// Whether the run is over (its outcome is ready, or was taken).
    pub fn is_done(&self) -> bool {
        self.phase == Phase::Done
    }

    /// The run's report, or what ended it; once, when the run is over.
    pub fn take_outcome(&mut self) -> Option<Result<Report, RunError>> {
        self.outcome.take()
    }

    /// State changes the barrier applied so far.
    pub fn changes_applied(&self) -> u64 {
        self.record.changes_applied
    }

    /// Frames presented so far.
    pub fn frames_presented(&self) -> u64 {
        self.record.presents.len() as u64
    }

    /// Whether the frames are over (the nodes are being asked for their figures, or the run
    /// is done).
    pub fn frames_over(&self) -> bool {
        matches!(self.phase, Phase::Collecting { .. } | Phase::Done)
    }

    /// Runs `frames` frames in all (`None`: until interrupted), whatever the configuration
    /// said.
    pub fn set_frame_limit(&mut self, frames: Option<u64>) {
        self.cfg.frames = frames;
        self.coordinator.set_frame_limit(frames);
    }

    /// Frames the run is to present; `None` runs until interrupted.
    pub fn frames_limit(&self) -> Option<u64> {
        self.cfg.frames
    }

    /// The first frame not yet started.
    pub fn next_frame(&self) -> FrameId {
        self.coordinator.next_frame()
    }

    /// The state the next frame starts with, changes queued so far applied.
    pub fn next_state(&self) -> WallState {
        self.coordinator.next_state()
    }

    /// The peer of render node `node`, if it is in the run.
    pub fn peer_of_render(&self, node: RenderNodeId) -> Option<PeerId> {
        self.renders.get(&node).copied()
    }

    /// The peer showing display `display` now, if any.
    pub fn peer_of_display(&self, display: DisplayId) -> Option<PeerId> {
        self.displays.get(&display).copied()
    }

    /// The render node a peer joined as, if it did.
    pub fn render_node_of(&self, peer: PeerId) -> Option<RenderNodeId> {
        match self.peers.get(&peer)?.role {
            PeerRole::Render { node, .. } => Some(node),
            _ => None,
        }
    }

    fn send(&mut self, peer: PeerId, msg: ToNode) {
        self.transmits.push_back(Transmit { peer, msg });
    }

    fn fail(&mut self, error: RunError) {
        self.phase = Phase::Done;
        self.outcome = Some(Err(error));
    }

    fn start_if_ready(&mut self, now: Now) {
        self.load_if_all_joined(now);
        if matches!(self.phase, Phase::Joining { .. }) && self.all_ready() {
            self.phase = Phase::Running;
            self.record.started = Some(now.instant);
            tracing::info!("all nodes ready, starting frames");
            self.events.push_back(MasterEvent::Started);
            self.coordinator.start(now.instant);
        }
    }

    /// The frames are over: every node is asked for its figures.
    fn shut_down(&mut self, now: Now) {
        self.drop_suspected_at_the_end(now);
        tracing::info!(
            "{} frames presented; asking the nodes for their figures",
            self.record.presents.len()
        );
        self.phase = Phase::Collecting {
            deadline: now.instant + STATS_WAIT,
        };
        // In peer order, not the hash map's (random per process): the simulator draws each
        // message's fate in the order they are sent, and a seed must replay the same run.
        let mut peers: Vec<PeerId> = self.peers.keys().copied().collect();
        peers.sort();
        for peer in peers {
            self.send(peer, ToNode::Shutdown);
        }
        self.finish_if_collected();
    }

    /// While collecting: stats are kept, present stamps and clock answers still count.
    fn collect(&mut self, peer: PeerId, msg: FromNode, now: Now) {
        match msg {
            FromNode::Stats(stats) => {
                if let Some(p) = self.peers.get_mut(&peer) {
                    p.stats = Some(stats);
                }
                self.finish_if_collected();
            }
            msg => self.note_timing(peer, &msg, now),
        }
    }

    fn finish_if_collected(&mut self) {
        // Nodes report their figures; control clients have none to give.
        let waiting = |p: &Peer| p.stats.is_none() && !matches!(p.role, PeerRole::Control);
        if !self.peers.values().any(waiting) {
            self.finish();
        }
    }

    fn finish(&mut self) {
        self.phase = Phase::Done;
        self.outcome = Some(Ok(self.report()));
    }
}
