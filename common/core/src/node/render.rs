//! A render node's session, sans IO: what it does with each message from the master, each
//! batch its render threads finish and each delivery to the displays.
//!
//! It wraps the node's queue ([`RenderWorker`]) and batch sizing ([`BatchSizer`]) and adds
//! what the driver loop used to decide on its own: one batch on the render threads at a time,
//! the blocks a shared scene fetches ahead of a batch, the time step a volume series must show
//! before a batch renders, which displays are still worth sending to, what goes back to the
//! master undelivered, and the figures reported at shutdown. (Heartbeats are not the session's:
//! `tessera_net::link` sends them as datagrams, whatever the driver loop is doing.)

use crate::worker::{BatchSizer, RenderWorker, WorkerError};
use std::collections::{BTreeMap, VecDeque};
use std::net::SocketAddr;
use std::time::{Duration, Instant};
use tessera_model::wall::{DisplayId, TileId};
use tessera_protocol::dsm::BlockHolder;
use tessera_protocol::pixels::BatchSource;
use tessera_protocol::{
    to_ranges, FrameId, FrameStart, FromNode, RenderNodeId, RenderStats, ToNode,
};

/// A message from the master that makes no sense to this render node.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum RenderSessionError {
    /// A message the node's queue refuses: an assignment it cannot take, or a message for
    /// displays.
    #[error(transparent)]
    Worker(#[from] WorkerError),
    /// `BlockHolders` sent to a node whose scene is not in distributed shared memory.
    #[error("block holders for a replicated scene")]
    HoldersForReplicatedScene,
}

/// What a render node's session starts from, once its scene is here and its displays reached.
#[derive(Clone, Debug)]
pub struct RenderSetup {
    /// The id the master's welcome gave this node.
    pub node: RenderNodeId,
    /// Tiles of the wall: assignments beyond are refused.
    pub tile_count: u32,
    /// Render threads: the smallest batch, and how many tiles to keep queued.
    pub threads: usize,
    /// Whether the scene is in distributed shared memory: each batch then fetches the blocks
    /// it and the next batch read, and the master's block holders are expected.
    pub shared: bool,
    /// For a volume that plays a time series: its steps, and the one loaded now.
    pub volume: Option<VolumeSteps>,
    /// The displays reached before the session began: their links are numbered from
    /// [`LinkId`] 0 in this order (see [`RenderSession::link`]).
    pub displays: Vec<DisplayId>,
}

/// One connection to a display, numbered by the session.
///
/// A display that restarts is reached again on a new connection while news of the old one (a
/// delivery that failed on it, a connection attempt to its old address) may still be on its
/// way. Keyed by display alone, that late news would drop the new connection and freeze the
/// wall; keyed by link, it is recognised as stale and ignored.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct LinkId(pub u64);

/// A time series of volumes: how many steps it has and which one the scene holds.
///
/// The step a frame shows is its `time_step` modulo the series' length, so a control client
/// may count up for ever and the series loops.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct VolumeSteps {
    /// Steps in the series (at least one).
    pub steps: usize,
    /// The step the scene holds now.
    pub shown: usize,
}

impl VolumeSteps {
    /// The step to load before rendering `start`, if it is not the one the scene holds; from
    /// then on it is.
    fn swap_for(&mut self, start: &FrameStart) -> Option<usize> {
        let step = start.params.volume().time_step as usize % self.steps.max(1);
        (self.shown != step).then(|| {
            self.shown = step;
            step
        })
    }
}

/// A batch to hand to the render threads.
#[derive(Clone, Debug, PartialEq)]
pub struct BatchOrder {
    /// The frame the tiles belong to, with its camera, parameters and state.
    pub start: FrameStart,
    /// The tiles to render, in order.
    pub tiles: Vec<TileId>,
    /// For a shared scene, the tiles whose blocks to fetch now: this batch's and as many of
    /// the next ones, asked for together so the owners answer them in one round. Empty for a
    /// replicated scene.
    pub prefetch: Vec<TileId>,
    /// The volume step to load into the scene before rendering, if it changes.
    pub volume_step: Option<usize>,
}

/// How a batch went on the render threads.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BatchDone {
    /// Tiles the batch rendered.
    pub tiles: usize,
    /// Rays of every kind the batch traced.
    pub rays: u64,
    /// Rendering alone: what the node's rays per second and a tile's time are measured by.
    pub took: Duration,
    /// Rendering and packing the pixels: what sizes the next batch.
    pub batch_took: Duration,
}

/// What the driver must do besides sending messages to the master.
#[derive(Clone, Debug, PartialEq)]
pub enum RenderEvent {
    /// A display (re)joined at `addr`: connect to it off the loop, so that one that does not
    /// answer holds up nothing, and say so with [`RenderSession::handle_display_reached`].
    ConnectDisplay {
        /// The display to connect to.
        display: DisplayId,
        /// Where it takes tiles.
        addr: SocketAddr,
        /// The link the connection will be, once reached.
        link: LinkId,
    },
    /// A delivery to `display` failed on its current link: drop that connection, once. Later
    /// batches skip the display, and the master, which hears from every display, decides
    /// whether it is gone.
    ForgetDisplay {
        /// The display whose connection to drop.
        display: DisplayId,
        /// The connection to drop: only if it is still the display's.
        link: LinkId,
        /// Why the delivery failed, for the log.
        reason: String,
    },
    /// Where the blocks of the shared scene are held now: for the fetcher.
    BlockHolders(Vec<BlockHolder>),
    /// The master ended the wall: send [`RenderSession::stats`] (with the driver's own
    /// figures added) and leave.
    Shutdown,
    /// Frames up to `frame` are abandoned: stop the batch on the render threads if it is of
    /// one of them (it then comes back as [`RenderSession::handle_cancelled`]).
    CancelUpTo(FrameId),
}

/// A render node's side of one master's wall, from its `Ready` to the shutdown.
///
/// Inputs are `handle_*` methods, each with `now` where time matters. After any of them the
/// driver calls, in this order: [`RenderSession::poll_batch`] (a batch to start, if the
/// render threads are free), [`RenderSession::poll_transmit`] until it returns `None` (the
/// messages to the master, in order), and [`RenderSession::poll_event`] until it returns
/// `None`.
///
/// # Examples
///
/// ```
/// use std::time::{Duration, Instant};
/// use glam::Vec3;
/// use tessera_core::node::render::{BatchDone, RenderSession, RenderSetup};
/// use tessera_model::camera::Camera;
/// use tessera_model::params::RenderParams;
/// use tessera_protocol::{FrameId, FrameStart, FromNode, RenderNodeId, TileRange, ToNode};
/// use tessera_model::state::StateId;
/// use tessera_model::wall::DisplayId;
///
/// let t0 = Instant::now();
/// let setup = RenderSetup {
///     node: RenderNodeId(3),
///     tile_count: 100,
///     threads: 2,
///     shared: false,
///     volume: None,
///     displays: vec![DisplayId(0)],
/// };
/// let mut node = RenderSession::new(setup, t0);
///
/// let camera = Camera::new(Vec3::Z, Vec3::ZERO, Vec3::Y, 45.0).unwrap();
/// let start = FrameStart::new(FrameId(0), StateId(0), camera, RenderParams::interactive());
/// node.handle_message(ToNode::FrameStart(start), t0)?;
/// let share = vec![TileRange::new(0, 4).unwrap()];
/// node.handle_message(ToNode::Assign { frame: FrameId(0), tiles: share }, t0)?;
///
/// // One batch at a time: two tiles (one per thread), then nothing until it is done.
/// let order = node.poll_batch(t0).unwrap();
/// assert_eq!(order.tiles.len(), 2);
/// assert!(node.poll_batch(t0).is_none());
/// let took = Duration::from_millis(4);
/// let done = BatchDone { tiles: 2, rays: 1000, took, batch_took: took };
/// assert_eq!(node.handle_rendered(done).render_us, 2000, "per tile");
/// assert_eq!(node.poll_batch(t0).unwrap().tiles.len(), 2);
/// # Ok::<(), tessera_core::node::render::RenderSessionError>(())
/// ```
pub struct RenderSession {
    node: RenderNodeId,
    worker: RenderWorker,
    sizer: BatchSizer,
    shared: bool,
    volume: Option<VolumeSteps>,
    /// A batch is on the render threads: the next waits for it.
    rendering: bool,
    /// The displays with a connection worth sending to, and that connection.
    displays: BTreeMap<DisplayId, LinkId>,
    /// The newest connection asked for to each display not reached on it yet: an older one
    /// that answers late is not taken.
    asked: BTreeMap<DisplayId, LinkId>,
    /// The number of the next link.
    next_link: u64,
    /// Tiles, rays and busy seconds so far.
    stats: RenderStats,
    started: Instant,
    transmit: VecDeque<FromNode>,
    events: VecDeque<RenderEvent>,
}

impl RenderSession {
    /// A session that starts at `now`, the node having just told the master it is ready.
    pub fn new(setup: RenderSetup, now: Instant) -> Self {
        let sizer = BatchSizer::new(setup.threads);
        let displays: BTreeMap<_, _> = setup
            .displays
            .iter()
            .zip(0..)
            .map(|(&d, i)| (d, LinkId(i)))
            .collect();
        RenderSession {
            node: setup.node,
            worker: RenderWorker::new(setup.tile_count, sizer.low_water(None)),
            sizer,
            shared: setup.shared,
            volume: setup.volume,
            rendering: false,
            next_link: setup.displays.len() as u64,
            displays,
            asked: BTreeMap::new(),
            stats: RenderStats::default(),
            started: now,
            transmit: VecDeque::new(),
            events: VecDeque::new(),
        }
    }

    /// The id the master gave this node.
    pub fn node(&self) -> RenderNodeId {
        self.node
    }

    /// The link a display is reached on now, if it is.
    pub fn link(&self, display: DisplayId) -> Option<LinkId> {
        self.displays.get(&display).copied()
    }

    /// Whether a batch is on the render threads.
    pub fn is_rendering(&self) -> bool {
        self.rendering
    }

    /// The volume series' steps and the one the scene holds (or is about to), if it plays one.
    pub fn volume(&self) -> Option<VolumeSteps> {
        self.volume
    }

    /// Takes a message from the master.
    ///
    /// # Errors
    /// A message that makes no sense to a render node (see [`WorkerError`]), or block holders
    /// for a scene that is not shared. The session is unchanged.
    pub fn handle_message(&mut self, msg: ToNode, now: Instant) -> Result<(), RenderSessionError> {
        match msg {
            ToNode::Shutdown => self.events.push_back(RenderEvent::Shutdown),
            ToNode::Cancel { frame } => {
                self.worker.handle_message(&msg, now)?;
                self.events.push_back(RenderEvent::CancelUpTo(frame));
            }
            ToNode::DisplayAt { display, addr } => {
                let link = LinkId(self.next_link);
                self.next_link += 1;
                self.asked.insert(display, link);
                self.events.push_back(RenderEvent::ConnectDisplay {
                    display,
                    addr,
                    link,
                });
            }
            ToNode::BlockHolders { holders, .. } if self.shared => {
                self.events.push_back(RenderEvent::BlockHolders(holders));
            }
            ToNode::BlockHolders { .. } => {
                return Err(RenderSessionError::HoldersForReplicatedScene)
            }
            msg => self.worker.handle_message(&msg, now)?,
        }
        Ok(())
    }

    /// The render threads finished the batch [`RenderSession::poll_batch`] handed out: the
    /// threads are free, the next batch is sized by this one, and the pixels go to their
    /// displays with the returned source (a tile's time averaged over the batch, which a
    /// display's overlay shows).
    pub fn handle_rendered(&mut self, done: BatchDone) -> BatchSource {
        self.rendering = false;
        self.sizer.record(done.tiles, done.batch_took);
        self.worker
            .set_low_water(self.sizer.low_water(self.worker.round_trip()));
        self.stats.tiles += done.tiles as u64;
        self.stats.rays += done.rays;
        self.stats.busy_s += done.took.as_secs_f64();
        let per_tile = done.took.as_micros() / done.tiles.max(1) as u128;
        BatchSource {
            node: self.node,
            render_us: per_tile.min(u32::MAX as u128) as u32,
        }
    }

    /// The batch [`RenderSession::poll_batch`] handed out was cancelled on the render
    /// threads (its frame is no longer wanted): the threads are free, and nothing is
    /// reported: its tiles are neither done nor sized by, and the master, which cancelled
    /// the frame or is gone, does not wait for them.
    pub fn handle_cancelled(&mut self) {
        self.rendering = false;
    }

    /// A connection asked for by [`RenderEvent::ConnectDisplay`] was made. Returns whether
    /// it is the display's link from now on (replacing any older one); `false` when a newer
    /// address was given meanwhile, and the driver closes this connection.
    pub fn handle_display_reached(&mut self, display: DisplayId, link: LinkId) -> bool {
        if self.asked.get(&display) != Some(&link) {
            return false;
        }
        self.asked.remove(&display);
        self.displays.insert(display, link);
        true
    }

    /// A batch's delivery ended: `delivered` reached their displays; `undelivered` did not,
    /// since the links in `lost` failed (with why). The undelivered tiles go back to the
    /// master, to be rendered again by this node or another; the delivered ones are reported
    /// done, asking for more if the queue is low. A failed link that is no longer its
    /// display's (the display was reached again since) changes nothing.
    pub fn handle_delivery(
        &mut self,
        frame: FrameId,
        delivered: &[TileId],
        undelivered: Vec<TileId>,
        lost: Vec<(DisplayId, LinkId, String)>,
        now: Instant,
    ) {
        for (display, link, reason) in lost {
            if self.displays.get(&display) == Some(&link) {
                self.displays.remove(&display);
                self.events.push_back(RenderEvent::ForgetDisplay {
                    display,
                    link,
                    reason,
                });
            }
        }
        if !undelivered.is_empty() {
            let tiles = to_ranges(undelivered);
            self.transmit
                .push_back(FromNode::TilesReturned { frame, tiles });
        }
        let report = self.worker.handle_delivered(frame, delivered, now);
        self.transmit.push_back(report);
    }

    /// The next batch, if the render threads are free and tiles are queued. While the threads
    /// are free this also asks the master for more work when the queue runs low (after the
    /// batch is taken, so the request counts what is left): call
    /// [`RenderSession::poll_transmit`] after it.
    pub fn poll_batch(&mut self, now: Instant) -> Option<BatchOrder> {
        if self.rendering {
            return None;
        }
        let order = self
            .worker
            .next_batch(self.sizer.batch())
            .map(|(start, tiles)| {
                self.rendering = true;
                let prefetch = if self.shared {
                    let next = self.worker.upcoming().take(tiles.len());
                    tiles.iter().copied().chain(next).collect()
                } else {
                    Vec::new()
                };
                let volume_step = self.volume.as_mut().and_then(|v| v.swap_for(&start));
                BatchOrder {
                    start,
                    tiles,
                    prefetch,
                    volume_step,
                }
            });
        if let Some(request) = self.worker.poll_request(now) {
            self.transmit.push_back(request);
        }
        order
    }

    /// The next message for the master.
    pub fn poll_transmit(&mut self) -> Option<FromNode> {
        self.transmit.pop_front()
    }

    /// The next thing the driver must do besides sending (see [`RenderEvent`]).
    pub fn poll_event(&mut self) -> Option<RenderEvent> {
        self.events.pop_front()
    }

    /// The figures of the session up to `now`: tiles, rays, busy and elapsed seconds. The
    /// driver adds what only it can measure (memory, volume loads, shared-memory reads).
    pub fn stats(&self, now: Instant) -> RenderStats {
        RenderStats {
            elapsed_s: now.saturating_duration_since(self.started).as_secs_f64(),
            ..self.stats.clone()
        }
    }
}
