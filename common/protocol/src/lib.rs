//! Tessera's protocol: every message between the master, render nodes, displays and control
//! clients ([`ToNode`], [`FromNode`]), the control interface's requests and answers
//! ([`control`]), how render nodes share a scene's blocks ([`dsm`]), and their framing.
//! What the messages carry (walls, cameras, wall states) is `tessera-model`'s.
//!
//! Control messages are postcard-encoded enums in length-prefixed frames ([`codec`]) on one
//! bidirectional QUIC stream per node–master connection. Pixels travel separately, render node to
//! display node, as RGB8 (raw or LZ4 per tile) with one small header per tile ([`pixels`]), one
//! unidirectional stream per (frame, batch of tiles, display). Every decoder has a size limit and returns an error on
//! malformed input; semantic checks (is this tile mine? is this frame in flight?) are done by the
//! state machine that consumes the message.

#![warn(missing_docs)]

pub mod codec;
pub mod control;
pub mod dsm;
mod error;
mod live;
pub mod pixels;
mod tiles;
pub use live::{Progress, Thumbnail, MAX_THUMBNAIL_BYTES, MAX_THUMBNAIL_FACTOR, PROGRESS_INTERVAL};
pub use tiles::{to_ranges, TileRange};

pub use error::ProtocolError;

use crate::control::{ControlReply, ControlRequest};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::net::SocketAddr;
use tessera_model::camera::Camera;
use tessera_model::input::InputEvent;
use tessera_model::light::Lights;
use tessera_model::params::RenderParams;
use tessera_model::scene_spec::SceneSpec;
use tessera_model::state::StateId;
use tessera_model::wall::{DisplayId, WallLayout};
use tessera_model::window::WindowPlacement;

/// Bumped on any incompatible change of a message or of the pixel stream format.
pub const PROTOCOL_VERSION: u32 = 13;

/// ALPN of Tessera's QUIC connections; a peer speaking anything else is refused by TLS.
pub const ALPN: &[u8] = b"tessera/1";

/// A frame number; frames are numbered from 0 in the order they are presented.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize,
)]
pub struct FrameId(pub u64);

/// Identifies a render node within one run, assigned by the master in join order.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize,
)]
pub struct RenderNodeId(pub u32);

/// Most rendering threads a render node may claim.
pub const MAX_CORES: u32 = 1 << 16;
/// Longest host name in a hello (Linux's `HOST_NAME_MAX` is 64; DNS names go to 253).
pub const MAX_HOST_BYTES: usize = 255;

/// What a connecting node is.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum Role {
    /// A render node: it traces tiles and streams their pixels to the displays.
    Render {
        /// Threads the node renders with, 1 to [`MAX_CORES`].
        cores: u32,
    },
    /// A display node: it shows one display's pixels.
    Display {
        /// The display it shows: its place on the wall.
        display: DisplayId,
        /// Where render nodes reach this display. An unspecified IP (0.0.0.0 / ::) means
        /// "the address the master sees me connect from".
        pixel_addr: SocketAddr,
    },
    /// An operator's or a script's client of the control interface.
    Control,
}

/// The first message on every control stream. Its host name and core count are checked on
/// arrival ([`Hello::check`]), since the master prints one and sizes work by the other.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Hello {
    /// The sender's [`PROTOCOL_VERSION`]; the master refuses any other.
    pub version: u32,
    /// What the sender joins as.
    pub role: Role,
    /// Host name, for log lines and reports.
    pub host: String,
}

#[derive(Deserialize)]
struct HelloRaw {
    version: u32,
    role: Role,
    host: String,
}

impl Hello {
    /// Checks what the master relies on.
    ///
    /// # Errors
    /// A host name over [`MAX_HOST_BYTES`] or with control characters, a render node with no
    /// cores or more than [`MAX_CORES`].
    pub fn check(&self) -> Result<(), ProtocolError> {
        if self.host.len() > MAX_HOST_BYTES || self.host.chars().any(char::is_control) {
            return Err(ProtocolError::BadHost(self.host.chars().take(64).collect()));
        }
        if let Role::Render { cores } = self.role {
            if !(1..=MAX_CORES).contains(&cores) {
                return Err(ProtocolError::BadCores(cores));
            }
        }
        Ok(())
    }
}

impl TryFrom<HelloRaw> for Hello {
    type Error = ProtocolError;

    fn try_from(raw: HelloRaw) -> Result<Self, ProtocolError> {
        let hello = Hello {
            version: raw.version,
            role: raw.role,
            host: raw.host,
        };
        hello.check()?;
        Ok(hello)
    }
}

impl<'de> Deserialize<'de> for Hello {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        tessera_model::checked::deserialize::<D, HelloRaw, Self>(d)
    }
}

/// Where a display node accepts pixels.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DisplayEndpoint {
    /// The display node it reaches.
    pub display: DisplayId,
    /// Where render nodes open pixel streams to it.
    pub addr: SocketAddr,
}

/// Everything a node needs to take part in a run, sent once after the handshake.
///
/// Its wall and scene are checked by their own types; [`Session::new`] (and deserializing)
/// also checks that the displays it lists are the wall's, each at most once. With at most
/// [`tessera_model::wall::MAX_DISPLAYS`] displays and a path of at most
/// [`tessera_model::scene_spec::MAX_PATH_BYTES`], a session is always far below the control codec's
/// size limit.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(into = "SessionSpec")]
pub struct Session(SessionSpec);

/// The fields of a [`Session`], unchecked.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SessionSpec {
    /// The wall: its displays' pixels, what each shows, and its tiles.
    pub wall: WallLayout,
    /// The scene every render node loads.
    pub scene: SceneSpec,
    /// Content hash of the scene as the master loaded it; a render node that loads different
    /// bytes would render different pixels, so it refuses to join.
    pub scene_hash: [u8; 32],
    /// Where each display node accepts pixels, as far as known when the session was made (a
    /// render node's lists every display); later changes come in [`ToNode::DisplayAt`].
    pub displays: Vec<DisplayEndpoint>,
    /// Frame whose pixels the displays save as PNG, if any.
    pub save_frame: Option<FrameId>,
    /// How render nodes pack tiles' pixels; displays refuse streams packed otherwise.
    pub compression: pixels::Compression,
    /// Where displays put their windows, by display id, if the wall file says.
    pub windows: BTreeMap<u32, WindowPlacement>,
    /// How render nodes hold the scene: each all of it, or a share of its blocks.
    pub data: dsm::DataSpec,
    /// The particles' attribute range `[lo, hi]` the colour map spans, where the scene has
    /// particles: the legend a display's overlay draws.
    pub particle_range: Option<[f32; 2]>,
}

impl Session {
    /// The session `spec` describes, checked.
    ///
    /// # Errors
    /// A display the wall does not have, or one listed twice; a bad particle range.
    pub fn new(spec: SessionSpec) -> Result<Self, ProtocolError> {
        let count = spec.wall.display_count();
        let mut seen = std::collections::BTreeSet::new();
        for d in &spec.displays {
            if d.display.0 >= count {
                return Err(ProtocolError::UnknownDisplay {
                    display: d.display.0,
                    count,
                });
            }
            if !seen.insert(d.display) {
                return Err(ProtocolError::DuplicateDisplay(d.display.0));
            }
        }
        if let Some(&display) = spec.windows.keys().find(|&&d| d >= count) {
            return Err(ProtocolError::UnknownDisplay { display, count });
        }
        if let dsm::DataSpec::Dsm(shared) = &spec.data {
            shared.check()?;
        }
        if let Some([lo, hi]) = spec.particle_range {
            if !(lo.is_finite() && hi.is_finite() && lo <= hi) {
                return Err(ProtocolError::BadParticleRange { lo, hi });
            }
        }
        Ok(Session(spec))
    }

    /// The wall: its displays' pixels, what each shows, and its tiles.
    pub fn wall(&self) -> &WallLayout {
        &self.0.wall
    }

    /// The scene every render node loads.
    pub fn scene(&self) -> &SceneSpec {
        &self.0.scene
    }

    /// Content hash of the scene as the master loaded it; a render node that loads other bytes
    /// refuses to join.
    pub fn scene_hash(&self) -> [u8; 32] {
        self.0.scene_hash
    }

    /// Where each display node accepts pixels, as far as known when the session was made.
    pub fn displays(&self) -> &[DisplayEndpoint] {
        &self.0.displays
    }

    /// Frame whose pixels the displays save as PNG, if any.
    pub fn save_frame(&self) -> Option<FrameId> {
        self.0.save_frame
    }

    /// How render nodes pack tiles' pixels; displays refuse streams packed otherwise.
    pub fn compression(&self) -> pixels::Compression {
        self.0.compression
    }

    /// Where display `display`'s window goes, if the wall file says.
    pub fn window(&self, display: DisplayId) -> Option<WindowPlacement> {
        self.0.windows.get(&display.0).copied()
    }

    /// How render nodes hold the scene.
    pub fn data(&self) -> &dsm::DataSpec {
        &self.0.data
    }

    /// The particles' attribute range `[lo, hi]` (finite, in order), if the scene has particles.
    pub fn particle_range(&self) -> Option<[f32; 2]> {
        self.0.particle_range
    }
}

impl TryFrom<SessionSpec> for Session {
    type Error = ProtocolError;

    fn try_from(spec: SessionSpec) -> Result<Self, ProtocolError> {
        Session::new(spec)
    }
}

impl From<Session> for SessionSpec {
    fn from(session: Session) -> Self {
        session.0
    }
}

impl<'de> Deserialize<'de> for Session {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        tessera_model::checked::deserialize::<D, SessionSpec, Self>(d)
    }
}

/// Broadcast at the frame barrier: the state every node renders frame `frame` with.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameStart {
    /// The frame these settings are for.
    pub frame: FrameId,
    /// The wall state this frame renders; every pixel stream of the frame carries it.
    pub state: StateId,
    /// The frame's camera (an orbit's already turned to this frame).
    pub camera: Camera,
    /// The frame's quality knobs.
    pub params: RenderParams,
    /// Lights in place of the scene's own, if a control client set some.
    pub lights: Option<Lights>,
}

impl FrameStart {
    /// Frame `frame` of state `state` with the scene's own lights.
    pub fn new(frame: FrameId, state: StateId, camera: Camera, params: RenderParams) -> Self {
        FrameStart {
            frame,
            state,
            camera,
            params,
            lights: None,
        }
    }
}

/// Master → node.
// A frame start (with its light set) is the largest message; messages live one at a time on
// their way to or from a stream, so boxing it would buy an allocation per frame and node and
// save no memory that matters.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum ToNode {
    /// The peer is in: its render node id (none for a display or a control client) and the
    /// session it takes part in.
    Welcome {
        /// The render node's id; `None` for a display or a control client.
        node: Option<RenderNodeId>,
        /// What the run renders and where: the wall, the scene, the displays' addresses.
        session: Session,
        /// The master's term: 0 for the first master of a run, one more at each takeover by a
        /// standby. A node refuses a master whose term is below the highest it has seen
        /// (answering [`FromNode::StaleMaster`]): an old primary that comes back cannot lead
        /// it again.
        term: u64,
    },
    /// The master turned the peer's hello down (another protocol version, a certificate for
    /// another role, a display already taken): it cannot join.
    Refused {
        /// Why, for the peer to print.
        reason: String,
    },
    /// Starts a frame: broadcast to every node at the frame barrier.
    FrameStart(FrameStart),
    /// Tiles of `frame` for a render node to render; empty means "nothing left for now".
    Assign {
        /// The frame the tiles are of.
        frame: FrameId,
        /// The tiles, as ranges of ids.
        tiles: Vec<TileRange>,
    },
    /// The swap barrier: every display shows `frame` now.
    Present {
        /// The frame to show.
        frame: FrameId,
    },
    /// The swap barrier with a deadline: show `frame` when this display's clock (ns since the
    /// Unix epoch) reads `clock_ns`, or at once if that has passed. Every display waking at
    /// the same instant, rather than whenever the message arrives, is what keeps them in step.
    PresentAt {
        /// The frame to show.
        frame: FrameId,
        /// When to show it, on the display's own clock (ns since the Unix epoch).
        clock_ns: u64,
    },
    /// The run is over: send your stats and close.
    Shutdown,
    /// Clock probe: a display answers at once with [`FromNode::Pong`], so the master can map
    /// the display's clock onto its own (NTP-style, keeping the fastest round trip).
    Ping {
        /// Probe number, echoed in the [`FromNode::Pong`].
        seq: u32,
    },
    /// The answer to the control client's request `id`.
    ControlReply {
        /// The request's id, as the client numbered it.
        id: u32,
        /// The master's answer.
        reply: ControlReply,
    },
    /// Show or hide the overlay (displays).
    Overlay {
        /// `true` shows the overlay, `false` hides it.
        on: bool,
    },
    /// Save `frame` as `display-<id>-frame-<K>.png` once it is presented (displays).
    SaveFrame {
        /// The frame to save.
        frame: FrameId,
    },
    /// Save what the screen shows now as `display-<id>-frame-<K>.png`, `K` being `frame`, the
    /// last frame presented (displays): a still wall renders nothing more to save.
    SaveShown {
        /// The frame presented last, which names the file.
        frame: FrameId,
    },
    /// Send the frame shown now, shrunk `factor` times in each direction, as a
    /// [`FromNode::Thumbnail`] (displays): the operator's console pictures the wall with it.
    SendThumbnail {
        /// Screen pixels per thumbnail pixel across and down, 1 to [`MAX_THUMBNAIL_FACTOR`].
        factor: u32,
    },
    /// A display (re)joined the running wall: its pixels go to `addr` now (render nodes).
    DisplayAt {
        /// The display that (re)joined.
        display: DisplayId,
        /// Where it accepts pixel streams now.
        addr: SocketAddr,
    },
    /// A display that rejoined a running wall shows frames from `frame` on (displays).
    StartAt {
        /// The first frame the display shows.
        frame: FrameId,
    },
    /// Render nodes of a shared scene: this node's rank (None: it holds no blocks) and where
    /// the nodes holding blocks answer for them; sent again when one is lost.
    BlockHolders {
        /// This node's rank among those that hold blocks; `None`: it holds none.
        rank: Option<u32>,
        /// Every holder's rank and address.
        holders: Vec<dsm::BlockHolder>,
    },
    /// Frames up to `frame` are abandoned (a newer state made them stale while they ran far
    /// longer than the frames before, or the run was interrupted): render nodes stop and drop
    /// their tiles, displays never show them. Later frames go on as usual.
    Cancel {
        /// The last frame abandoned.
        frame: FrameId,
    },
}

impl ToNode {
    /// The message's name, for log lines and errors that must not print its whole content.
    pub fn kind(&self) -> &'static str {
        match self {
            ToNode::Welcome { .. } => "welcome",
            ToNode::Refused { .. } => "refused",
            ToNode::FrameStart(_) => "frame start",
            ToNode::Assign { .. } => "assign",
            ToNode::Present { .. } => "present",
            ToNode::PresentAt { .. } => "present at",
            ToNode::Shutdown => "shutdown",
            ToNode::Ping { .. } => "ping",
            ToNode::ControlReply { .. } => "control reply",
            ToNode::Overlay { .. } => "overlay",
            ToNode::SaveFrame { .. } => "save frame",
            ToNode::SaveShown { .. } => "save shown",
            ToNode::SendThumbnail { .. } => "send thumbnail",
            ToNode::DisplayAt { .. } => "display at",
            ToNode::StartAt { .. } => "start at",
            ToNode::BlockHolders { .. } => "block holders",
            ToNode::Cancel { .. } => "cancel",
        }
    }
}

/// Node → master.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum FromNode {
    /// The first message on a control stream: what the peer is and which protocol it speaks.
    Hello(Hello),
    /// Scene loaded, displays reached: the node can take frames.
    Ready,
    /// These tiles reached their displays. With `want_more` the node asks for another batch.
    TilesDone {
        /// The frame the tiles are of.
        frame: FrameId,
        /// The tiles delivered, as ranges of ids.
        tiles: Vec<TileRange>,
        /// Whether the node asks for another batch.
        want_more: bool,
    },
    /// A display has every tile of `frame`.
    FrameComplete {
        /// The frame whose tiles are all in.
        frame: FrameId,
    },
    /// A display showed `frame`, at `clock_ns` on its own clock (ns since the Unix epoch).
    Presented {
        /// The frame shown.
        frame: FrameId,
        /// When, on the display's clock (ns since the Unix epoch).
        clock_ns: u64,
    },
    /// Answer to [`ToNode::Ping`]: the display's clock when it answered.
    Pong {
        /// The [`ToNode::Ping`]'s probe number.
        seq: u32,
        /// The display's clock when it answered, in ns since the Unix epoch.
        clock_ns: u64,
    },
    /// The node's figures, sent after [`ToNode::Shutdown`] before it closes.
    Stats(NodeStats),
    /// The node cannot go on; the master logs this and treats the node as gone.
    Failed {
        /// What went wrong, for the master's log.
        message: String,
    },
    /// A control client's request `id`, made at `stamp_ns` (the master's clock as the client
    /// maps it; 0 when unknown).
    Control {
        /// The request's id, numbered by the client; the reply carries it back.
        id: u32,
        /// What the client asks.
        request: ControlRequest,
        /// When it was made, in ns since the Unix epoch on the master's clock; 0 when unknown.
        stamp_ns: u64,
    },
    /// A person's input at a display's window, at `clock_ns` on the display's clock.
    Input {
        /// What the person did.
        event: InputEvent,
        /// When, on the display's clock (ns since the Unix epoch).
        clock_ns: u64,
    },
    /// A render node's running figures, every [`PROGRESS_INTERVAL`]: what an operator's
    /// console shows of it while the wall runs.
    Progress(Progress),
    /// Answer to [`ToNode::SendThumbnail`]: the frame a display shows, shrunk, as RGB8 rows
    /// top down. Empty when it has shown nothing yet.
    Thumbnail(Thumbnail),
    /// A display wrote the files of a snapshot of `frame` (`ok`), or could not (`!ok`, and
    /// its log says why).
    Saved {
        /// The frame the files are of.
        frame: FrameId,
        /// Whether every file was written.
        ok: bool,
    },
    /// A render node or display is alive. It never travels on the control stream: a node
    /// sends [`HEARTBEAT_DATAGRAM`] as a QUIC datagram every [`HEARTBEAT_INTERVAL`], and the
    /// master's driver hands each one to its state machine as this message.
    Heartbeat,
    /// A render node is still loading the scene: what it is doing and for how long it has
    /// been at it (sent when the step changes and every [`LOAD_REPORT_INTERVAL`]), so that
    /// the master's log says why the wall has not started yet.
    Loading {
        /// What the node is doing.
        step: LoadStep,
        /// Seconds since it started loading.
        elapsed_s: u32,
    },
    /// A render node could not deliver these tiles (their display was unreachable): they go
    /// back to the master, to be rendered again, by this node or another.
    TilesReturned {
        /// The frame the tiles are of.
        frame: FrameId,
        /// The tiles not delivered, as ranges of ids.
        tiles: Vec<TileRange>,
    },
    /// A render node of a shared scene answers block requests at `addr` (an unspecified IP:
    /// the address the master sees it at).
    BlocksAt {
        /// Where it answers block requests.
        addr: SocketAddr,
    },
    /// The node has followed a master of a higher term than this master's welcome said
    /// (a standby took over): this master is stale and steps down. The node closes the
    /// connection after it.
    StaleMaster {
        /// The highest term the node has seen.
        seen: u64,
    },
}

/// How often a render node says it is alive. The master's deadline for a silent node
/// (`--node-deadline`) must be several of these, so that a late packet or two is not a death.
pub const HEARTBEAT_INTERVAL: std::time::Duration = std::time::Duration::from_millis(50);

/// The default failure bound of a primary master: a standby takes the wall over once its
/// primary has been silent this long (`serve --failover-after`), and a node with a list of
/// masters gives a master silent this long up for the next (the nodes' `--failover-after`).
/// Ten missed 50 ms beats: a wall on a LAN presents again within a second of its master's
/// death, while a primary's stall shorter than this is no death. A standby that does act on a
/// live primary's stall is harmless: the nodes, which never lost the primary, stay with it.
pub const FAILOVER_AFTER: std::time::Duration = std::time::Duration::from_millis(500);

/// The payload of a heartbeat datagram (see [`FromNode::Heartbeat`]). A datagram is never
/// retransmitted nor queued behind a lost packet of the control stream, so a beat says that the
/// node is alive now, not that the stream caught up. The version is in it so that a stray
/// datagram of another protocol is not taken for a beat.
pub const HEARTBEAT_DATAGRAM: &[u8] = b"tessera-beat/7";

/// How often a loading render node tells the master how far it is (see
/// [`FromNode::Loading`]).
pub const LOAD_REPORT_INTERVAL: std::time::Duration = std::time::Duration::from_secs(2);

/// What a loading render node is doing (see [`FromNode::Loading`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum LoadStep {
    /// Reading the scene's files (or generating a procedural scene) and hashing them.
    Reading,
    /// Building (or reading from the cache) the BVH of this many triangles.
    BuildingBvh {
        /// Triangles in the scene.
        triangles: u64,
    },
    /// Preparing what the render threads read (volume bricks, the packed BVH).
    Preparing,
    /// Reading its share of a scene shared across the render nodes (`--data dsm`).
    ReadingShare,
}

impl std::fmt::Display for LoadStep {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            LoadStep::Reading => write!(f, "reading the scene"),
            LoadStep::BuildingBvh { triangles } => {
                write!(f, "building the BVH of {triangles} triangles")
            }
            LoadStep::Preparing => write!(f, "preparing it for rendering"),
            LoadStep::ReadingShare => write!(f, "reading its share of the shared scene"),
        }
    }
}

/// Measured by a node, reported at shutdown.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum NodeStats {
    /// A render node's figures.
    Render(RenderStats),
    /// A display node's figures.
    Display(DisplayStats),
}

/// A render node's figures. Seconds are checked on arrival (finite, not negative), since the
/// master divides by them for the report.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct RenderStats {
    /// Tiles rendered (a tile rendered again, after a loss or speculatively, counts again).
    pub tiles: u64,
    /// Rays of every kind traced.
    pub rays: u64,
    /// Seconds spent rendering (wall clock of render calls).
    pub busy_s: f64,
    /// Seconds from the first frame start to shutdown.
    pub elapsed_s: f64,
    /// A time series' steps this node loaded, and the seconds each took (load and brick).
    pub volume_load_s: Vec<f64>,
    /// Step changes of a time series whose step the readers had ready; of a shared series,
    /// steps shown whose bricks were all here in time.
    pub prefetch_hits: u64,
    /// Step changes of a time series the node had to wait for; of a shared series, steps
    /// late: the render threads idled waiting for their bricks.
    pub prefetch_misses: u64,
    /// Seconds the node waited for steps not yet loaded (of a shared series, for bricks).
    pub volume_stall_s: f64,
    /// The node's peak resident memory (VmHWM), in bytes; 0 where the OS does not say.
    pub max_rss_bytes: u64,
    /// Its reads of a shared scene, if the scene was shared (boxed: most runs have none).
    pub dsm: Option<Box<dsm::DsmStats>>,
}

/// Most per-step load times a node reports: a longer run reports its first ones.
pub const MAX_REPORTED_LOADS: usize = 4096;

#[derive(Deserialize)]
struct RenderStatsRaw {
    tiles: u64,
    rays: u64,
    busy_s: f64,
    elapsed_s: f64,
    volume_load_s: Vec<f64>,
    prefetch_hits: u64,
    prefetch_misses: u64,
    volume_stall_s: f64,
    max_rss_bytes: u64,
    dsm: Option<Box<dsm::DsmStats>>,
}

impl TryFrom<RenderStatsRaw> for RenderStats {
    type Error = ProtocolError;

    fn try_from(raw: RenderStatsRaw) -> Result<Self, ProtocolError> {
        let seconds = [
            ("busy_s", raw.busy_s),
            ("elapsed_s", raw.elapsed_s),
            ("volume_stall_s", raw.volume_stall_s),
        ];
        let loads = raw.volume_load_s.iter().map(|&v| ("volume_load_s", v));
        for (field, value) in seconds.into_iter().chain(loads) {
            if !(value.is_finite() && value >= 0.0) {
                return Err(ProtocolError::BadSeconds { field, value });
            }
        }
        if let Some(Err((field, value))) = raw.dsm.as_ref().map(|d| d.check()) {
            return Err(ProtocolError::BadSeconds { field, value });
        }
        if raw.volume_load_s.len() > MAX_REPORTED_LOADS {
            return Err(ProtocolError::BadSeconds {
                field: "volume_load_s (too many)",
                value: raw.volume_load_s.len() as f64,
            });
        }
        Ok(RenderStats {
            tiles: raw.tiles,
            rays: raw.rays,
            busy_s: raw.busy_s,
            elapsed_s: raw.elapsed_s,
            volume_load_s: raw.volume_load_s,
            prefetch_hits: raw.prefetch_hits,
            prefetch_misses: raw.prefetch_misses,
            volume_stall_s: raw.volume_stall_s,
            max_rss_bytes: raw.max_rss_bytes,
            dsm: raw.dsm,
        })
    }
}

impl<'de> Deserialize<'de> for RenderStats {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        tessera_model::checked::deserialize::<D, RenderStatsRaw, Self>(d)
    }
}

/// A display node's figures.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DisplayStats {
    /// Pixels of its framebuffer.
    pub pixels_owned: u64,
    /// Pixel bytes received, as unpacked (3 per pixel, whatever the compression; tile headers
    /// excluded).
    pub pixel_bytes_received: u64,
    /// UDP payload bytes received on render-node connections, as quinn counts them: every
    /// datagram's QUIC packet headers, AEAD tags, frames (handshake, ACKs, retransmissions
    /// included), but not the IP and UDP headers.
    pub wire_bytes_received: u64,
    /// Application bytes of pixel streams as sent (stream and tile headers included, tiles
    /// compressed if the run compresses).
    pub stream_bytes_received: u64,
    /// Frames it showed.
    pub frames_presented: u64,
    /// Tiles that arrived a second time, or after their frame was shown, and were ignored.
    pub duplicate_tiles: u64,
}

#[cfg(test)]
mod tests;
