//! A standby master, sans IO: it follows a primary's [`MasterSnapshot`]s and takes the run
//! over once the primary is gone.
//!
//! # The replication protocol
//!
//! The primary's driver, once a standby's connection is up (mutual TLS, a `master`
//! certificate), calls [`Master::attach_standby`] and sends the [`Replica`] it returns; from
//! then on, after each `handle_*` call, it sends every [`Master::poll_replica`] (one when the
//! snapshot changed, none otherwise), in order, on one reliable ordered stream, with a
//! heartbeat every [`StandbyConfig::heartbeat_interval`] (see [`ToStandby`]). The standby
//! answers each replica with the [`ReplicaAck`] that [`Standby::poll_ack`] gives, which the
//! primary hands to [`Master::handle_replica_ack`]. When the standby's connection closes the
//! primary calls [`Master::detach_standby`].
//!
//! A replica is small: its session lines are only those the standby has not seen, and its
//! distributions (histograms of bounded size) come only when they were refreshed, every
//! [`SAMPLES_EVERY`] presents. So the report of a taken-over run may lack up to that many
//! frames' durations from before the takeover; its counters lack none the standby received.
//!
//! # Why the ids are safe
//!
//! A primary with a standby starts no frame at or past the horizon of the last replica its
//! standby acknowledged (a snapshot's next frame plus [`REPLICA_HORIZON`]). The master that
//! takes over starts at that horizon, with a state id past any the old one can have reached
//! by then (at most one new state per frame): no frame or state id of the new master is one
//! the old master used, so no display can put a tile of an old frame into a new one.

use super::figures::{Figures, RunSamples};
use super::report::Takeover;
use super::*;
use serde::{Deserialize, Serialize};
use tessera_model::state::StateId;
use tessera_protocol::control::ViewName;

/// Frames a primary may run past the last snapshot its standby acknowledged.
pub const REPLICA_HORIZON: u64 = 64;

/// Presents between two refreshes of a replica's distributions (see the module docs).
pub const SAMPLES_EVERY: u64 = 32;

/// Largest encoded message between a primary and its standby (a snapshot with a whole
/// session's lines), checked when decoding.
pub const MAX_REPLICA_BYTES: usize = 64 << 20;

/// A line of the session record: frame `frame` started with `wall` under id `state`, and
/// the frame's own camera (what `--record` writes, one line each time the state changes).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SessionLine {
    /// The frame.
    pub frame: FrameId,
    /// The id of the state it renders.
    pub state: StateId,
    /// The state, with the frame's own quality knobs (a refinement pass raises them).
    pub wall: WallState,
    /// The frame's own camera (an orbit's, turned to this frame).
    pub camera_at_frame: Camera,
}

/// Which render node held a rank of a shared scene, as the primary knew it.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct RankHolder {
    /// The rank.
    pub rank: u32,
    /// The host of the render node holding it: a render node from there that rejoins the
    /// master that took over gets this rank back first, since it has its blocks loaded.
    pub host: String,
    /// Where it answered for its blocks, once it said.
    pub addr: Option<SocketAddr>,
}

/// Everything a standby needs to take a run over: the sans-IO master's state, less what
/// lives only as long as a connection.
///
/// Deliberately not in it: the peers and their connections, render node ids, displays'
/// pixel addresses and clock offsets (nodes rejoin the new master and are measured again);
/// the frames in flight and their tiles (abandoned: the new master starts past them); the
/// load balancer's speeds and the failure detectors' histories (learnt again in a few
/// frames); control clients' pending replies and snapshots waiting for files (their clients
/// reconnect and ask again); the navigator's drag in progress; and the nodes' own figures,
/// which they send the master that ends the run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MasterSnapshot {
    /// The term of the master that made it; the master that takes over has one more.
    pub term: u64,
    /// The id of the state frames start with now.
    pub state_id: StateId,
    /// The state frames start with now.
    pub state: WallState,
    /// The state the next frame starts with: `state` and every change queued since.
    pub next_state: WallState,
    /// The first frame not yet started.
    pub next_frame: FrameId,
    /// No frame at or past this one was started: where a master that takes over starts.
    pub horizon: FrameId,
    /// Frames the run is to present (`None`: until interrupted).
    pub frame_limit: Option<u64>,
    /// Saved views, by name.
    pub views: BTreeMap<ViewName, CameraMode>,
    /// Whether the displays show the overlay.
    pub overlay: bool,
    /// Whether a time series plays, and at how many steps per second (`None`: one a frame).
    pub playing: (bool, Option<f32>),
    /// Who held each rank of a shared scene.
    pub ranks: Vec<RankHolder>,
    /// The report's counters so far.
    pub figures: Figures,
    /// The report's distributions, as of the last refresh (every [`SAMPLES_EVERY`] presents).
    pub samples: RunSamples,
    /// The session record so far.
    pub session: Vec<SessionLine>,
    /// The takeovers of the run so far.
    pub takeovers: Vec<Takeover>,
}

/// What a primary sends its standby: a snapshot, whole or as the change since the last.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Replica {
    /// How many of the session's lines came before `snapshot.session` (0: all of them).
    pub session_from: u64,
    /// Whether `snapshot.samples` is meant (else they are unchanged and sent empty).
    pub has_samples: bool,
    /// The snapshot, its session lines from `session_from` on.
    pub snapshot: MasterSnapshot,
}

impl Replica {
    /// A whole snapshot.
    pub fn whole(snapshot: MasterSnapshot) -> Replica {
        Replica {
            session_from: 0,
            has_samples: true,
            snapshot,
        }
    }
}

/// A standby's word that it holds the snapshot whose horizon this is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ReplicaAck {
    /// The acknowledged snapshot's [`MasterSnapshot::horizon`].
    pub horizon: FrameId,
}

/// A message from the primary to its standby.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum ToStandby {
    /// A snapshot or a change of it.
    Replica(Box<Replica>),
    /// The primary is alive.
    Heartbeat,
}

/// Why a primary's or a standby's message could not be read.
#[derive(Debug, thiserror::Error)]
pub enum ReplicaError {
    /// More bytes than [`MAX_REPLICA_BYTES`].
    #[error("a replica message of {0} bytes is over the {MAX_REPLICA_BYTES}-byte limit")]
    TooLarge(usize),
    /// Not a message of this version.
    #[error("a replica message does not decode: {0}")]
    Decode(String),
    /// A change of a snapshot the standby does not hold (it missed lines before it).
    #[error("a replica's session lines start at {from}, but the standby holds {held}")]
    Gap {
        /// The first line the replica has.
        from: u64,
        /// Lines the standby holds.
        held: u64,
    },
}

/// Encodes a message between a primary and its standby (postcard).
///
/// # Errors
/// One over [`MAX_REPLICA_BYTES`].
pub fn encode<T: Serialize>(msg: &T) -> Result<Vec<u8>, ReplicaError> {
    let bytes = postcard::to_stdvec(msg).map_err(|e| ReplicaError::Decode(e.to_string()))?;
    if bytes.len() > MAX_REPLICA_BYTES {
        return Err(ReplicaError::TooLarge(bytes.len()));
    }
    Ok(bytes)
}

/// Decodes a message between a primary and its standby.
///
/// # Errors
/// Too many bytes, or bytes that are not such a message.
pub fn decode<T: for<'de> Deserialize<'de>>(bytes: &[u8]) -> Result<T, ReplicaError> {
    if bytes.len() > MAX_REPLICA_BYTES {
        return Err(ReplicaError::TooLarge(bytes.len()));
    }
    postcard::from_bytes(bytes).map_err(|e| ReplicaError::Decode(e.to_string()))
}

/// How a standby judges its primary.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StandbyConfig {
    /// How often the primary's driver sends [`ToStandby::Heartbeat`].
    pub heartbeat_interval: Duration,
    /// A primary silent this long (no heartbeat, no replica) is gone.
    pub failure_bound: Duration,
}

impl Default for StandbyConfig {
    /// Beats every 50 ms, gone after [`tessera_protocol::FAILOVER_AFTER`] of silence (500 ms):
    /// short enough for a LAN's wall to present again within a second of its primary's death.
    /// A standby that acts on a live primary's stall does no harm: the nodes judge the primary
    /// by its packets, which its connection keeps sending, and stay with it (term fencing
    /// leaves the standby's higher term without a wall).
    fn default() -> Self {
        StandbyConfig {
            heartbeat_interval: tessera_protocol::HEARTBEAT_INTERVAL,
            failure_bound: tessera_protocol::FAILOVER_AFTER,
        }
    }
}

/// What a standby tells its driver.
#[derive(Clone, Debug, PartialEq)]
pub enum StandbyEvent {
    /// The primary is gone: take over with [`Master::take_over`] from this snapshot, and
    /// close the connection to the primary if it is still open.
    TakeOver(Box<MasterSnapshot>),
}

/// A standby master: see the module docs. `handle_*` takes what happened, `poll_*` says what
/// to do; poll [`Standby::poll_ack`] and [`Standby::poll_event`] after each `handle_*` call.
#[derive(Debug)]
pub struct Standby {
    cfg: StandbyConfig,
    held: Option<MasterSnapshot>,
    /// When the primary was last heard, or when the standby started.
    heard: Instant,
    acks: VecDeque<ReplicaAck>,
    event: Option<StandbyEvent>,
    /// Took over (or gave up): it handles nothing more.
    done: bool,
}

impl Standby {
    /// A standby that has heard nothing yet, as of `now`.
    pub fn new(cfg: StandbyConfig, now: Instant) -> Standby {
        Standby {
            cfg,
            held: None,
            heard: now,
            acks: VecDeque::new(),
            event: None,
            done: false,
        }
    }

    /// The snapshot held, if any.
    pub fn snapshot(&self) -> Option<&MasterSnapshot> {
        self.held.as_ref()
    }

    /// A replica from the primary: the standby holds its snapshot and acknowledges it.
    ///
    /// # Errors
    /// [`ReplicaError::Gap`]: a change of lines the standby never got (it holds what it held;
    /// the primary's driver should detach and attach it again).
    pub fn handle_replica(&mut self, replica: Replica, now: Instant) -> Result<(), ReplicaError> {
        if self.done {
            return Ok(());
        }
        self.heard = now;
        let Replica {
            session_from,
            has_samples,
            mut snapshot,
        } = replica;
        let held_lines = self.held.as_ref().map_or(0, |h| h.session.len() as u64);
        if session_from > held_lines {
            return Err(ReplicaError::Gap {
                from: session_from,
                held: held_lines,
            });
        }
        if let Some(held) = self.held.take() {
            let mut session = held.session;
            session.truncate(session_from as usize);
            session.append(&mut snapshot.session);
            snapshot.session = session;
            if !has_samples {
                snapshot.samples = held.samples;
            }
        }
        let horizon = snapshot.horizon;
        self.held = Some(snapshot);
        self.acks.push_back(ReplicaAck { horizon });
        Ok(())
    }

    /// A heartbeat from the primary.
    pub fn handle_heartbeat(&mut self, now: Instant) {
        self.heard = self.heard.max(now);
    }

    /// The connection to the primary closed: it is gone.
    pub fn handle_primary_closed(&mut self, now: Instant) {
        let _ = now;
        self.take_over();
    }

    /// The time [`Standby::poll_timeout`] gave has come (or passed).
    pub fn handle_timeout(&mut self, now: Instant) {
        if now.saturating_duration_since(self.heard) >= self.cfg.failure_bound {
            self.take_over();
        }
    }

    /// When to call [`Standby::handle_timeout`]: the failure bound after the primary was
    /// last heard; `None` once it took over.
    pub fn poll_timeout(&self) -> Option<Instant> {
        (!self.done).then(|| self.heard + self.cfg.failure_bound)
    }

    /// The next acknowledgement to send the primary.
    pub fn poll_ack(&mut self) -> Option<ReplicaAck> {
        self.acks.pop_front()
    }

    /// What to do: take over, once.
    pub fn poll_event(&mut self) -> Option<StandbyEvent> {
        self.event.take()
    }

    /// Whether it took over, or gave up without a snapshot to take over from.
    pub fn is_done(&self) -> bool {
        self.done
    }

    fn take_over(&mut self) {
        if self.done {
            return;
        }
        self.done = true;
        self.acks.clear();
        match self.held.take() {
            Some(snapshot) => self.event = Some(StandbyEvent::TakeOver(Box::new(snapshot))),
            // Nothing to carry on: the primary never got a run to us.
            None => tracing::error!("the primary is gone before it sent a snapshot"),
        }
    }
}
