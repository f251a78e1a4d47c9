//! A whole wall in one process, no sockets: the real
//! [`Coordinator`](crate::balance::Coordinator), [`RenderWorker`]s and [`FrameAssembler`]s
//! exchanging the real messages through a simulated network with a virtual clock, seeded
//! latency, jitter and loss, render nodes of different speeds, and scripted render-node deaths.
//!
//! Pixels are a cheap function of (frame, tile, byte) instead of ray-traced, so hundreds of
//! virtual nodes run in milliseconds and every presented frame can be checked byte for byte.
//! With [`PixelCheck::OnePerTile`] each display assembles a thumbnail with one pixel per tile
//! instead of its full screen: the tile ids, their owners and every message are the same, but a
//! wall of 64 full-HD screens fits in a few kilobytes and a run of 100 frames in seconds.
//!
//! # The network
//!
//! Every link is QUIC in the real system, so the model is QUIC's, not UDP's:
//!
//! * **Latency.** A message arrives `latency_us` plus a seeded jitter of up to half of that after
//!   its last transmission.
//! * **Loss.** Each transmission is lost with probability `loss` (a seeded coin per try). QUIC
//!   retransmits after a probe timeout, here three one-way latencies (about 1.5 round trips),
//!   doubling after every further loss; so a message is never lost for good while its sender
//!   lives, it is late. A render node that dies before a retransmission takes that pixel batch
//!   with it.
//! * **Order.** Control messages travel on one stream per direction and node, as in the real
//!   nodes: a retransmitted message holds back everything behind it (head-of-line blocking).
//!   Pixel batches and the acknowledgements that tell a render node its pixels arrived each go
//!   on a stream of their own and may overtake each other.
//! * **Deaths.** A render node killed with [`SimWall::kill_at`] dies shortly after the frame
//!   starts, with tiles in hand. Messages to and from it are dropped from then on, and the
//!   master learns of the death as the real one does: live nodes send a heartbeat every
//!   [`HEARTBEAT_INTERVAL`], over the simulated network, and the coordinator declares a node
//!   gone once it has been silent for its deadline (its `poll_timeout` is one of the
//!   simulation's events).
//!
//! # Balance efficiency
//!
//! A render node is busy while it renders a batch. Its busy fraction is busy time over the
//! time it was alive within the frames' span, from the first frame's start until the master
//! knows the last frame is rendered; [`SimReport::efficiency`] is the mean over render nodes.

mod events;
#[cfg(test)]
mod master_tests;
mod metrics;
mod net;
#[cfg(test)]
mod pause_tests;
mod pauses;
mod peers;
#[cfg(test)]
mod tests;

pub use metrics::{SimReport, Spread};
pub use net::Rng;
pub use pauses::{Actor, Dropped};
pub use peers::ControlAnswer;

use crate::assemble::FrameAssembler;
use crate::balance::BalanceConfig;
use crate::master::{
    Credentials, DisplayLoss, Join, Master, MasterConfig, MasterEvent, Now, PeerId,
};
use crate::worker::{BatchSizer, RenderWorker};
use metrics::{busy_fractions, NodeClock};
use net::{Network, Stream};
use std::cmp::Reverse;
use std::collections::{BTreeMap, BinaryHeap};
use std::time::{Duration, Instant};
use tessera_protocol::HEARTBEAT_INTERVAL;

const HEARTBEAT_US: u64 = HEARTBEAT_INTERVAL.as_micros() as u64;
use tessera_model::screens::{PhysicalSpec, ScreenSpec, Viewer};
use tessera_model::state::{StateChange, StateId};
use tessera_model::wall::{
    DisplayId, ScreenRect, TileGrid, TileId, WallDescription, WallError, WallLayout, WallSpec,
};
use tessera_protocol::control::{ControlReply, ControlRequest};
use tessera_protocol::dsm::DataSpec;
use tessera_protocol::{FrameId, FromNode, Hello, RenderNodeId, Role, ToNode};

/// How fast each render node renders a full tile.
#[derive(Clone, Debug, PartialEq)]
pub enum NodeSpeeds {
    /// Node k takes `100 + 37k mod 200` µs: a fixed, even spread over 100..300 µs.
    Cycle,
    /// Each node takes `fastest_us` times a seeded factor drawn uniformly from `[1, spread]`.
    Spread {
        /// Virtual microseconds a full tile takes on the fastest node there can be.
        fastest_us: u64,
        /// The slowest node's factor: a node takes up to this many times `fastest_us`
        /// (below 1 counts as 1).
        spread: f64,
    },
    /// Node k takes `tile_us[k mod len]` µs.
    List(Vec<u64>),
}

/// How a simulated render node sizes its batches and its refill threshold.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Batching {
    /// As the real render node does: [`BatchSizer`] on the measured (virtual) cost per tile and
    /// the measured request round trip, for one render thread.
    Measured,
    /// `batch` tiles at once, asking for more below `low_water` queued tiles.
    Fixed {
        /// Tiles per batch (0 counts as 1).
        batch: usize,
        /// The queue length below which the node asks for more.
        low_water: usize,
    },
}

/// How much of the picture the displays assemble and check.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PixelCheck {
    /// Every pixel of every screen.
    Full,
    /// One pixel per tile: the same tiles and messages, a thumbnail's memory.
    OnePerTile,
}

/// A simulated wall's nodes and network.
#[derive(Clone, Debug, PartialEq)]
pub struct SimConfig {
    /// Render nodes the wall waits for before the first frame.
    pub render_nodes: u32,
    /// How fast each of them renders a tile.
    pub speeds: NodeSpeeds,
    /// One-way latency of every link, in virtual microseconds, before jitter.
    pub latency_us: u64,
    /// Probability that one transmission of a message is lost (it is then retransmitted).
    pub loss: f64,
    /// How many tiles a render node takes at once, and when it asks for more.
    pub batching: Batching,
    /// How much of the picture the displays assemble and check.
    pub pixels: PixelCheck,
    /// The master's load balancer knobs.
    pub balance: BalanceConfig,
    /// Queue a state change (samples per pixel, alternating) as every frame starts, so every
    /// frame has a state of its own: what a person steering the wall does, at its worst.
    pub change_every_frame: bool,
    /// What the wall does when a display leaves.
    pub display_loss: DisplayLoss,
    /// How render nodes hold the scene: a shared scene gives the first ones ranks.
    pub data: DataSpec,
}

impl SimConfig {
    /// `render_nodes` nodes of [`NodeSpeeds::Cycle`] speeds and measured batches, 50 µs links
    /// with no loss, every pixel checked, the balancer's defaults, no change every frame, a wall
    /// that goes on without a lost display, and a replicated scene.
    pub fn new(render_nodes: u32) -> Self {
        SimConfig {
            render_nodes,
            speeds: NodeSpeeds::Cycle,
            latency_us: 50,
            loss: 0.0,
            batching: Batching::Measured,
            pixels: PixelCheck::Full,
            balance: BalanceConfig::default(),
            change_every_frame: false,
            display_loss: DisplayLoss::GoOn,
            data: DataSpec::Replicated,
        }
    }
}

/// A near-square grid of `displays` screens of `width × height` pixels in `tile_size` tiles:
/// as many rows as the largest divisor of `displays` not above its square root, so that every
/// display count gives exactly that many screens (a prime count gives one row). A grid too
/// large for one virtual image (65,536 pixels a side) is the same screens as a wall of
/// screens (a millimetre a pixel, one frustum each), which has no such limit.
///
/// # Errors
/// A wall that [`WallLayout::new`] refuses (too many displays or tiles).
pub fn near_square_wall(
    displays: u32,
    width: u32,
    height: u32,
    tile_size: u32,
) -> Result<WallLayout, WallError> {
    let rows = (1..=displays.max(1))
        .take_while(|&r| u64::from(r) * u64::from(r) <= u64::from(displays))
        .filter(|r| displays.is_multiple_of(*r))
        .last()
        .unwrap_or(1);
    let columns = displays.max(1) / rows;
    match WallSpec::grid(columns, rows, width, height)
        .tile_size(tile_size)
        .build()
    {
        Err(WallError::TooLarge { .. }) => {}
        grid => return grid,
    }
    let (w, h) = (width as f64, height as f64);
    let screens = (0..columns * rows)
        .map(|i| ScreenSpec {
            resolution: [width, height],
            x_mm: Some((i % columns) as f64 * w),
            y_mm: Some((rows - 1 - i / columns) as f64 * h),
            width_mm: Some(w),
            height_mm: Some(h),
            ..ScreenSpec::default()
        })
        .collect();
    let (cx, cy) = (columns as f64 * w / 2.0, rows as f64 * h / 2.0);
    WallLayout::new(WallDescription::Screens(PhysicalSpec {
        tile_size,
        viewer: Viewer {
            position_mm: [cx, cy, cx.max(cy)],
            scene_units_per_m: 1.0,
        },
        stereo: Default::default(),
        screens,
        ring: None,
    }))
}

/// The deterministic pixel bytes of `tile` in `frame` rendered with `state`: a tile of
/// another frame or state has other pixels, so the displays' images show any mix.
pub fn sim_pixels(grid: &TileGrid, frame: FrameId, state: StateId, tile: TileId) -> Vec<u8> {
    let t = grid.tile(tile).expect("tile of the grid");
    (0..t.pixel_count() * 3)
        .map(|i| {
            (i as u64)
                .wrapping_mul(31)
                .wrapping_add(tile.0 as u64 * 7 + frame.0 * 13 + state.0 * 101) as u8
        })
        .collect()
}

enum Event {
    FromRender(RenderNodeId, FromNode),
    FromDisplay(PeerId, DisplayId, FromNode),
    ToRender(RenderNodeId, ToNode),
    /// To and from a display's connection: one that closed takes what was in flight with it.
    ToDisplay(PeerId, DisplayId, ToNode),
    Pixels {
        from: RenderNodeId,
        /// When the transmission that got through left the render node.
        last_tx: u64,
        display: DisplayId,
        frame: FrameId,
        state: StateId,
        tiles: Vec<TileId>,
    },
    Rendered(RenderNodeId, FrameId, StateId, Vec<TileId>),
    Delivered(RenderNodeId, FrameId, Vec<TileId>),
    Kill(RenderNodeId),
    /// A display's connection closes (it left, or its process died).
    DisplayLeaves(DisplayId),
    /// A display started again joins the wall.
    DisplayJoins(DisplayId),
    /// A new render node joins the running wall.
    RenderJoins,
    FromControl(u32, FromNode),
    /// A live render node's heartbeat timer fired.
    Heartbeat(RenderNodeId),
    /// A display's heartbeat timer fired.
    DisplayBeat(DisplayId),
}

struct SimNode {
    worker: RenderWorker,
    busy: bool,
    /// `None` for [`Batching::Fixed`].
    sizer: Option<BatchSizer>,
}

/// A whole wall in one process on a virtual clock: the real [`Master`] (with its
/// coordinator), [`RenderWorker`]s and [`FrameAssembler`]s, exchanging the real messages over a simulated
/// network (see the module documentation for the model).
///
/// # Examples
///
/// Sixty-four render nodes and eight displays, one node dying in frame 3, 1 % loss: every frame
/// is still presented on every display, exactly as rendered.
///
/// ```
/// use tessera_core::sim::{SimConfig, SimWall};
/// use tessera_protocol::{FrameId, RenderNodeId};
/// use tessera_model::wall::{DisplayId, WallSpec};
///
/// let wall = WallSpec::grid(4, 2, 256, 144).tile_size(32).build().unwrap();
/// let config = SimConfig { loss: 0.01, ..SimConfig::new(64) };
/// let mut sim = SimWall::with_config(7, wall, &config);
/// sim.kill_at(RenderNodeId(17), FrameId(3));
/// assert_eq!(sim.run_frames(10), 10);
/// let all: Vec<FrameId> = (0..10).map(FrameId).collect();
/// for d in 0..8 {
///     assert_eq!(sim.presented(DisplayId(d)), &all[..]);
/// }
/// assert!(sim.corrupt_frames().is_empty());
/// assert_eq!(sim.live_render_nodes(), 63);
/// ```
pub struct SimWall {
    grid: TileGrid,
    /// The grid the displays assemble: `grid` itself, or its one-pixel-per-tile thumbnail.
    pixel_grid: TileGrid,
    master: Master,
    /// Who each peer of the master is, and the peer of each node now.
    peers: peers::Peers,
    nodes: BTreeMap<RenderNodeId, SimNode>,
    clocks: Vec<NodeClock>,
    displays: Vec<FrameAssembler>,
    presented: Vec<Vec<FrameId>>,
    /// Frames whose presented pixels differed from what was rendered.
    corrupt: Vec<(DisplayId, FrameId)>,
    events: BinaryHeap<Reverse<(u64, u64, usize)>>,
    slab: Vec<Option<Event>>,
    free_slots: Vec<usize>,
    seq: u64,
    now_us: u64,
    base: Instant,
    net: Network,
    kills: Vec<(RenderNodeId, FrameId)>,
    batch: usize,
    frames: u64,
    span: (Option<u64>, Option<u64>),
    last_present_us: u64,
    processed: u64,
    lost_with_sender: u64,
    late_tiles: u64,
    late_from_live: u64,
    change_every_frame: bool,
    /// The state each started frame was announced with.
    states: BTreeMap<FrameId, StateId>,
    /// What is scripted to happen as frames start: displays leaving, control requests,
    /// render nodes joining.
    script: Vec<(FrameId, peers::Scripted)>,
    /// When the master and nodes are stopped.
    pauses: pauses::Pauses,
    beat_jitter_us: u64,
    beat_rng: Rng,
    /// Connections the master closed, with when.
    dropped: Vec<Dropped>,
}

impl SimWall {
    /// A wall of `layout` with `render_nodes` nodes of [`NodeSpeeds::Cycle`] speeds, 50 µs links
    /// and no loss.
    pub fn new(seed: u64, layout: WallLayout, render_nodes: u32) -> Self {
        Self::with_config(seed, layout, &SimConfig::new(render_nodes))
    }

    /// A wall of `layout` with the nodes and network of `config`; `seed` draws the node
    /// speeds, the jitter and the losses, so the same seed replays the same run.
    pub fn with_config(seed: u64, layout: WallLayout, config: &SimConfig) -> Self {
        let grid = TileGrid::new(layout.clone());
        let pixel_grid = match config.pixels {
            PixelCheck::Full => grid.clone(),
            PixelCheck::OnePerTile => TileGrid::new(
                grid.thumbnail()
                    .expect("as many tiles as the valid wall it stands for, and fewer pixels"),
            ),
        };
        debug_assert_eq!(grid.len(), pixel_grid.len());
        // One origin for every clock of the run, the master's creation included: a master
        // made at another real instant than `base` had deadlines some nanoseconds off the
        // simulated microseconds, and the same seed replayed a different run.
        let base = Instant::now();
        let master = Master::new(
            MasterConfig {
                balance: config.balance,
                display_loss: config.display_loss,
                data: config.data.clone(),
                // The join timeout is also how long a wall waits for a lost display.
                join_timeout: Duration::from_secs(30),
                ..MasterConfig::new(layout.clone(), config.render_nodes)
            },
            peers::now_at(base, 0),
        )
        .expect("no session to replay");
        let displays = pixel_grid
            .layout()
            .screens()
            .map(|s| FrameAssembler::new(&pixel_grid, s))
            .collect();
        let clocks = node_clocks(seed, config);
        SimWall {
            master,
            peers: peers::Peers::new(config.batching),
            nodes: BTreeMap::new(),
            clocks,
            displays,
            presented: vec![Vec::new(); layout.display_count() as usize],
            corrupt: Vec::new(),
            events: BinaryHeap::new(),
            slab: Vec::new(),
            free_slots: Vec::new(),
            seq: 0,
            now_us: 0,
            base,
            net: Network::new(seed, config.latency_us, config.loss.clamp(0.0, 1.0)),
            kills: Vec::new(),
            batch: match config.batching {
                Batching::Fixed { batch, .. } => batch.max(1),
                Batching::Measured => 1,
            },
            frames: 0,
            span: (None, None),
            last_present_us: 0,
            processed: 0,
            lost_with_sender: 0,
            late_tiles: 0,
            late_from_live: 0,
            change_every_frame: config.change_every_frame,
            states: BTreeMap::new(),
            script: Vec::new(),
            pauses: pauses::Pauses::default(),
            beat_jitter_us: 0,
            beat_rng: Rng::derived(seed, 7),
            dropped: Vec::new(),
            grid,
            pixel_grid,
        }
    }

    /// Render node `node` dies shortly after frame `frame` starts, with tiles of it in hand.
    pub fn kill_at(&mut self, node: RenderNodeId, frame: FrameId) {
        self.kills.push((node, frame));
    }

    /// Frames presented by each display, in order.
    pub fn presented(&self, display: DisplayId) -> &[FrameId] {
        &self.presented[display.0 as usize]
    }

    /// State changes the barrier applied (each a frame's worth when changing every frame).
    pub fn changes_applied(&self) -> u64 {
        self.master.changes_applied()
    }

    /// The state each started frame was rendered with.
    pub fn frame_states(&self) -> &BTreeMap<FrameId, StateId> {
        &self.states
    }

    /// Each (display, frame) whose presented pixels differed from what the frame's state
    /// renders, in the order presented: empty on a correct run.
    pub fn corrupt_frames(&self) -> &[(DisplayId, FrameId)] {
        &self.corrupt
    }

    /// Render nodes joined and not killed.
    pub fn live_render_nodes(&self) -> usize {
        self.nodes.len()
    }

    /// Virtual time since the simulation began.
    pub fn virtual_time(&self) -> Duration {
        Duration::from_micros(self.now_us)
    }

    /// Frames presented on every display: the length of the longest prefix `0..k` of frames
    /// that every display presented in order.
    pub fn frames_completed(&self) -> u64 {
        self.presented
            .iter()
            .map(|shown| {
                shown
                    .iter()
                    .enumerate()
                    .take_while(|(i, f)| f.0 == *i as u64)
                    .count() as u64
            })
            .min()
            .unwrap_or(0)
    }

    /// What the run measured so far.
    pub fn report(&self) -> SimReport {
        let start = self.span.0.unwrap_or(0);
        let end = self.span.1.unwrap_or(self.now_us);
        let fractions = busy_fractions(&self.clocks, start, end);
        let spread = Spread::of(&fractions);
        let mean = if fractions.is_empty() {
            0.0
        } else {
            fractions.iter().sum::<f64>() / fractions.len() as f64
        };
        let frames_completed = self.frames_completed();
        let elapsed_s = self.last_present_us.saturating_sub(start) as f64 * 1e-6;
        SimReport {
            render_nodes: self.clocks.len() as u32,
            render_nodes_killed: self.clocks.iter().filter(|c| c.died_at.is_some()).count() as u32,
            displays: self.displays.len() as u32,
            tiles_per_frame: self.grid.len() as u32,
            frames_requested: self.frames,
            frames_completed,
            efficiency: mean,
            efficiency_min: spread.min,
            busy_fraction: spread,
            span_s: end.saturating_sub(start) as f64 * 1e-6,
            elapsed_s,
            fps: if elapsed_s > 0.0 {
                frames_completed as f64 / elapsed_s
            } else {
                0.0
            },
            latency_us: self.net.latency_us(),
            loss: self.net.loss(),
            messages: self.net.messages,
            retransmissions: self.net.retransmissions,
            pixel_batches_lost_with_sender: self.lost_with_sender,
            duplicate_tiles: self.displays.iter().map(FrameAssembler::duplicates).sum(),
            late_tiles: self.late_tiles,
            late_tiles_from_live_nodes: self.late_from_live,
            corrupt_frames: self.corrupt.len() as u64,
            events: self.processed,
        }
    }

    fn now(&self) -> Instant {
        self.base + Duration::from_micros(self.now_us)
    }

    /// The virtual now on both of the master's clocks.
    fn master_now(&self) -> Now {
        peers::now_at(self.base, self.now_us)
    }

    /// When the master asked to be called back, in simulated microseconds.
    fn master_timeout_us(&self) -> Option<u64> {
        let due = self.master.poll_timeout()?;
        // Rounded up: a deadline between two microseconds is due at the later one, or the
        // master would be woken, still early, forever.
        let ns = due.saturating_duration_since(self.base).as_nanos();
        let due = ns.div_ceil(1000) as u64;
        // A stopped master's timer fires when it runs again.
        Some(self.pauses.until(Actor::Master, due).unwrap_or(due))
    }

    fn schedule_at(&mut self, at: u64, event: Event) {
        let slot = match self.free_slots.pop() {
            Some(slot) => {
                self.slab[slot] = Some(event);
                slot
            }
            None => {
                self.slab.push(Some(event));
                self.slab.len() - 1
            }
        };
        self.events.push(Reverse((at, self.seq, slot)));
        self.seq += 1;
    }

    /// Sends a message over the network (see the module doc for latency, loss and order).
    fn send(&mut self, event: Event) {
        let stream = match &event {
            Event::ToRender(n, _) => Stream::ToRender(n.0),
            Event::FromRender(n, _) => Stream::FromRender(n.0),
            Event::FromControl(c, _) => Stream::FromControl(*c),
            Event::ToDisplay(_, d, _) => Stream::ToDisplay(d.0),
            Event::FromDisplay(_, d, _) => Stream::FromDisplay(d.0),
            _ => Stream::Own,
        };
        let at = self.net.deliver(self.now_us, stream).at;
        self.schedule_at(at, event);
    }

    /// Runs until nothing is left to happen (the last `Present` delivered) or a bound on
    /// simulated events is hit. Returns the number of frames presented.
    pub fn run_frames(&mut self, frames: u64) -> u64 {
        self.run_frames_reporting(frames, |_| {})
    }

    /// [`SimWall::run_frames`], calling `progress` with the frames presented so far every
    /// [`PROGRESS_EVERY`] events: a long run can show how far it is.
    pub fn run_frames_reporting(&mut self, frames: u64, mut progress: impl FnMut(u64)) -> u64 {
        self.frames = frames;
        self.master.set_frame_limit(Some(frames));
        // Every node joins and is ready at once; the master starts the first frame when the
        // last one is.
        for d in 0..self.displays.len() as u32 {
            self.join_display(DisplayId(d));
        }
        for _ in 0..self.clocks.len() {
            self.join_render_node();
        }
        self.pump();
        let budget = 200u64
            .saturating_mul(frames)
            .saturating_mul(self.grid.len() as u64 + 10)
            .saturating_mul(self.nodes.len() as u64 + 1);
        while let Some(&Reverse((at, _, slot))) = self.events.peek() {
            self.processed += 1;
            if self.processed > budget {
                break;
            }
            if self.processed.is_multiple_of(PROGRESS_EVERY) {
                progress(self.master.frames_presented());
            }
            // The master's own timer is an event too, due before or with the next one.
            if let Some(due) = self.master_timeout_us().filter(|&due| due <= at) {
                self.now_us = due.max(self.now_us);
                self.master.handle_timeout(self.master_now());
                self.pump();
                continue;
            }
            self.events.pop();
            let event = self.slab[slot].take().expect("each event runs once");
            self.free_slots.push(slot);
            let stopped = Self::actor_of(&event).and_then(|a| self.pauses.until(a, at));
            if let Some(until) = stopped {
                // Whatever happens to a stopped process happens when it goes on.
                self.schedule_at(until, event);
                continue;
            }
            // Heartbeats still on their way when the run ends are not part of it: they would
            // stretch its virtual time to the next beat.
            let beat = matches!(
                event,
                Event::Heartbeat(_)
                    | Event::DisplayBeat(_)
                    | Event::FromRender(_, FromNode::Heartbeat)
                    | Event::FromDisplay(_, _, FromNode::Heartbeat)
            );
            if beat && self.master.frames_over() {
                continue;
            }
            self.now_us = at;
            self.handle(event);
            self.pump();
        }
        self.master.frames_presented()
    }
}

/// Events between two calls of [`SimWall::run_frames_reporting`]'s progress.
pub const PROGRESS_EVERY: u64 = 4096;

/// Each render node's clock, its speed drawn from `config.speeds` (seeded).
fn node_clocks(seed: u64, config: &SimConfig) -> Vec<NodeClock> {
    let mut speeds = Rng::derived(seed, 2);
    (0..config.render_nodes as u64)
        .map(|k| NodeClock {
            tile_us: match &config.speeds {
                NodeSpeeds::Cycle => 100 + (37 * k) % 200,
                NodeSpeeds::Spread { fastest_us, spread } => {
                    let factor = 1.0 + (spread - 1.0).max(0.0) * speeds.unit();
                    ((*fastest_us as f64 * factor).round() as u64).max(1)
                }
                NodeSpeeds::List(list) if !list.is_empty() => list[k as usize % list.len()].max(1),
                NodeSpeeds::List(_) => 100,
            },
            ..NodeClock::default()
        })
        .collect()
}
