//! The master's sans-IO core: two-level load balancer and frame barrier.
//!
//! [`Coordinator`] never touches a socket or the clock. The driver feeds it what happened
//! (`handle_*`, each with `now`) and drains what to send (`poll_output`), in that order, after
//! every input. Its rules:
//!
//! * **Barrier.** State changes queued with [`Coordinator::queue_change`] are applied only when a
//!   frame starts and travel in that frame's `FrameStart`, under a new state id; however many
//!   were queued between two barriers, they make one new state, and none is lost. Frame f+1 starts once every tile of
//!   frame f has been handed out and frame f−1 is presented, so at most two frames are in
//!   flight and rendering f+1 overlaps presenting f. Starting f+1 when f's pool runs dry
//!   rather than when f's last tile is rendered keeps nodes busy over f's tail: the nodes that
//!   run out of work first take their share of f+1 while the slowest finish f's last tiles.
//! * **Balancing.** At frame start each render node gets a static, contiguous share of
//!   `static_fraction` of the tiles; the rest is handed out on request in progressively smaller
//!   batches (guided self-scheduling: a batch is the pool divided by twice the node count).
//!   Static shares are sized by how many tiles each node rendered of the last presented
//!   frames (smoothed), so a node twice as fast gets twice the share: with equal shares a wall
//!   whose slowest node is ten times slower than its fastest waited on the slow nodes' shares
//!   (79.8 % efficiency in the simulator, 512 nodes).
//! * **Failures.** When a render node leaves, its unfinished tiles go back to the pool and to the
//!   nodes that are waiting for work, so the frame still completes. A node that is silent for
//!   `node_deadline` (no heartbeat, no report) is treated as gone at once, without waiting for
//!   the transport to notice: the driver asks [`Coordinator::poll_timeout`] when to call
//!   [`Coordinator::handle_timeout`], quinn's convention for time in a state machine.
//! * **Swap barrier.** When every display has every tile of the oldest unpresented frame, all
//!   displays are told to present it at once. A lost display is struck from the frames in
//!   flight; then the others go on without it, or, with
//!   [`BalanceConfig::wait_for_lost_displays`], no frame starts until it is back.

mod cancel;
mod failures;
mod frames;
mod liveness;
mod output;
mod refine;
mod resume;
mod shares;
mod speculate;
mod steering;

pub use cancel::{INTERRUPT_GRACE, MIN_RUNAWAY, RUNAWAY_FACTOR};
pub use liveness::DeathDetector;
pub use output::{BalanceError, Output};
pub use refine::Refinement;

use frames::InFlight;
use liveness::Liveness;
use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::time::{Duration, Instant};
use tessera_model::camera::CameraMode;
use tessera_model::params::{ParamsError, RenderParams};
use tessera_model::state::{StateChange, StateId, WallState};
use tessera_model::wall::{DisplayId, TileId};
use tessera_protocol::{to_ranges, FrameId, FrameStart, RenderNodeId, TileRange, ToNode};

/// Tuning of the load balancer.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BalanceConfig {
    /// Share of a frame's tiles handed out statically at frame start (0 = all on request).
    pub static_fraction: f32,
    /// Smallest batch handed out on request.
    pub min_batch: u32,
    /// A node silent this long is suspected: a render node's tiles are copied to the others
    /// and it gets no static share, but it stays in the run and is back when it speaks.
    pub node_deadline: Duration,
    /// When a silent node is dead (see [`DeathDetector`]): then its connection is closed.
    pub death: DeathDetector,
    /// Whether idle nodes get copies of the tiles of a node late past its lease (off: they
    /// wait for the deadline, and no tile is ever rendered twice).
    pub speculate: bool,
    /// While someone steers, start the next frame only once the one in flight is rendered
    /// (lower input latency, a little less throughput); see `steering`.
    pub hold_while_steering: bool,
    /// What a lost display does to the wall. `None`: the others go on without it. `Some(at
    /// most)`: the wall pauses, no frame starts until it rejoins, and if it is not back within
    /// `at most`, [`Output::DisplayNotBack`] ends the wait (the driver ends the run).
    pub wait_for_lost_displays: Option<Duration>,
}

/// The default [`BalanceConfig::node_deadline`]: six heartbeats, a few frame periods.
pub const DEFAULT_NODE_DEADLINE: Duration = Duration::from_millis(300);

/// The default [`DeathDetector::acceptable_pause`] of a served wall: a stopped process, a
/// scheduler that starved a node for seconds, a network blip of two seconds are not deaths.
/// Its tiles moved at suspicion, so a real death costs only the wait for its connection.
pub const DEFAULT_ACCEPTABLE_PAUSE: Duration = Duration::from_secs(3);

impl Default for BalanceConfig {
    fn default() -> Self {
        BalanceConfig {
            static_fraction: 0.5,
            min_batch: 1,
            node_deadline: DEFAULT_NODE_DEADLINE,
            death: DeathDetector::default(),
            speculate: true,
            hold_while_steering: true,
            wait_for_lost_displays: None,
        }
    }
}

struct RenderNode {
    /// When it last showed progress on its tiles: a report of tiles done, or being given
    /// work while it held none. A node late by its lease has its tiles copied to idle nodes.
    last_progress: Instant,
    /// Smoothed time between its progress reports while it holds work.
    progress_gap: Option<Duration>,
}

/// The master's load balancer and frame barrier, as a state machine: inputs are `handle_*`
/// calls (each with `now`), outputs are drained with [`Coordinator::poll_output`] after every
/// input, in order.
///
/// # Examples
///
/// One frame of a one-display wall, with one render node, and no socket in sight:
///
/// ```
/// use std::time::Instant;
/// use glam::Vec3;
/// use tessera_core::balance::{BalanceConfig, Coordinator, Output};
/// use tessera_model::camera::{Camera, CameraMode};
/// use tessera_model::params::RenderParams;
/// use tessera_protocol::{FrameId, RenderNodeId, ToNode};
/// use tessera_model::wall::DisplayId;
///
/// let camera = CameraMode::fixed(Camera::new(Vec3::Z, Vec3::ZERO, Vec3::Y, 45.0).unwrap());
/// let now = Instant::now();
/// // 8 tiles on 1 display, a run of 1 frame.
/// let mut c = Coordinator::new(8, 1, camera, RenderParams::interactive(), Some(1),
///                              BalanceConfig::default());
/// let node = RenderNodeId(0);
/// c.handle_render_joined(node, now);
/// c.start(now);
///
/// // The frame starts: a FrameStart for everyone, then the node's static share.
/// let mut assigned = Vec::new();
/// while let Some(out) = c.poll_output() {
///     if let Output::ToRender(_, ToNode::Assign { tiles, .. }) = out {
///         assigned.extend(tiles);
///     }
/// }
/// // The node renders its share and asks for the rest, until the pool is empty.
/// while !assigned.is_empty() {
///     c.handle_tiles_done(node, FrameId(0), &assigned, true, now).unwrap();
///     assigned.clear();
///     while let Some(out) = c.poll_output() {
///         if let Output::ToRender(_, ToNode::Assign { tiles, .. }) = out {
///             assigned.extend(tiles);
///         }
///     }
/// }
/// // The display has every tile: the swap barrier tells every display to present.
/// c.handle_frame_complete(DisplayId(0), FrameId(0), now).unwrap();
/// let outputs: Vec<Output> = std::iter::from_fn(|| c.poll_output()).collect();
/// assert!(outputs.contains(&Output::ToDisplays(ToNode::Present { frame: FrameId(0) })));
/// assert!(outputs.contains(&Output::Finished));
/// assert_eq!(c.presented(), 1);
/// ```
pub struct Coordinator {
    tile_count: u32,
    display_count: u32,
    config: BalanceConfig,
    /// Displays the swap barrier waits for: every one, until one is gone.
    live_displays: BTreeSet<DisplayId>,
    display_liveness: Liveness<DisplayId>,
    /// Lost displays the wall waits for (under [`BalanceConfig::wait_for_lost_displays`]),
    /// and since when: no frame starts while there is one.
    awaited_displays: BTreeMap<DisplayId, Instant>,
    /// The display of each tile, where the driver said (see [`Coordinator::set_tile_displays`]).
    tile_displays: Vec<DisplayId>,
    /// The state frames start with now, and its id.
    state: WallState,
    state_id: StateId,
    /// The state after every change queued since the last barrier.
    next: WallState,
    /// Changes folded into `next`, and the stamps they came with.
    pending_changes: u64,
    /// When the last change was queued: someone steering (see `steering`).
    last_change_at: Option<Instant>,
    pending_stamps: Vec<u64>,
    /// Changes to apply at the barrier of a given frame (a replayed session).
    scheduled: BTreeMap<FrameId, Vec<StateChange>>,
    refinement: Option<Refinement>,
    /// The frame the current state took effect with.
    state_since: FrameId,
    /// The last frame started was at the final quality and nothing has changed since: no
    /// frame starts until something does.
    converged: bool,
    frame_limit: Option<u64>,
    /// No frame at or past this one starts (see [`Coordinator::set_frame_horizon`]).
    frame_horizon: Option<FrameId>,
    running: bool,
    nodes: BTreeMap<RenderNodeId, RenderNode>,
    /// Nodes that asked for work and got none; they get returned tiles first. A set of its
    /// own, so that the timer need not scan every node for them (2,048 nodes in the simulator).
    waiting: BTreeSet<RenderNodeId>,
    liveness: Liveness<RenderNodeId>,
    /// Tiles each node rendered per frame, smoothed over the presented frames.
    tiles_per_frame: BTreeMap<RenderNodeId, f64>,
    in_flight: BTreeMap<FrameId, InFlight>,
    next_frame: FrameId,
    next_present: FrameId,
    stalled: bool,
    /// Tiles copied to a second node because the first was late with them.
    speculated_tiles: u64,
    /// Time from a frame's start to its present, smoothed over the presented frames.
    frame_time: Option<Duration>,
    /// When the run was interrupted: frames in flight get a moment to finish, then are
    /// cancelled.
    interrupted_at: Option<Instant>,
    outputs: VecDeque<Output>,
}

impl Coordinator {
    /// A coordinator for a wall of `tile_count` tiles on `display_count` displays, running
    /// `frame_limit` frames (or until stopped).
    pub fn new(
        tile_count: u32,
        display_count: u32,
        camera: CameraMode,
        params: RenderParams,
        frame_limit: Option<u64>,
        config: BalanceConfig,
    ) -> Self {
        Coordinator {
            tile_count,
            display_count,
            config,
            live_displays: (0..display_count).map(DisplayId).collect(),
            display_liveness: Liveness::new(config.node_deadline, config.death),
            awaited_displays: BTreeMap::new(),
            tile_displays: Vec::new(),
            state: WallState {
                camera,
                params,
                lights: None,
            },
            state_id: StateId(0),
            next: WallState {
                camera,
                params,
                lights: None,
            },
            pending_changes: 0,
            last_change_at: None,
            pending_stamps: Vec::new(),
            scheduled: BTreeMap::new(),
            refinement: None,
            state_since: FrameId(0),
            converged: false,
            frame_limit,
            frame_horizon: None,
            running: false,
            nodes: BTreeMap::new(),
            waiting: BTreeSet::new(),
            liveness: Liveness::new(config.node_deadline, config.death),
            tiles_per_frame: BTreeMap::new(),
            in_flight: BTreeMap::new(),
            next_frame: FrameId(0),
            next_present: FrameId(0),
            stalled: false,
            speculated_tiles: 0,
            frame_time: None,
            interrupted_at: None,
            outputs: VecDeque::new(),
        }
    }

    // ---- getters ----

    /// The render nodes that have joined and not left, in id order.
    pub fn render_nodes(&self) -> impl Iterator<Item = RenderNodeId> + '_ {
        self.nodes.keys().copied()
    }

    /// The next frame to start.
    pub fn next_frame(&self) -> FrameId {
        self.next_frame
    }

    /// Whether the wall reached its final quality and starts no frame until something changes.
    pub fn is_converged(&self) -> bool {
        self.converged
    }

    /// Frames started and not yet presented or cancelled.
    pub fn frames_in_flight(&self) -> usize {
        self.in_flight.len()
    }

    /// Changes queued for the next barrier.
    pub fn pending_changes(&self) -> usize {
        self.pending_changes as usize
    }

    /// Frames presented so far.
    pub fn presented(&self) -> u64 {
        self.next_present.0
    }

    /// Whether the run's last frame is presented; always false without a frame limit.
    pub fn is_finished(&self) -> bool {
        self.frame_limit
            .is_some_and(|limit| self.next_present.0 >= limit)
    }

    // ---- commands ----

    /// Refine frames while the camera holds still (see [`Refinement`]); `None`: never.
    pub fn set_refinement(&mut self, refinement: Option<Refinement>) {
        self.refinement = refinement;
    }

    /// The state frames start with now, and its id.
    pub fn state(&self) -> (StateId, WallState) {
        (self.state_id, self.state)
    }

    /// Applies `change` at the barrier of `frame` exactly, after the changes queued by then
    /// (a replayed session: its states land on the frames they were recorded at).
    ///
    /// # Errors
    /// A frame already started; a change that the state at that barrier refuses is skipped
    /// there, with the others, and reported by [`Output::Refused`].
    pub fn schedule_change(
        &mut self,
        frame: FrameId,
        change: StateChange,
    ) -> Result<(), BalanceError> {
        if frame < self.next_frame {
            return Err(BalanceError::PastFrame(frame));
        }
        self.scheduled.entry(frame).or_default().push(change);
        Ok(())
    }

    /// The id of the state that holds every change queued so far, and the first frame that
    /// renders it: the next barrier's, or, where a change started a frame at once (an idle
    /// or converged wall), the state and frame already started.
    pub fn queued_state(&self) -> (StateId, FrameId) {
        if self.pending_changes > 0 {
            (StateId(self.state_id.0 + 1), self.next_frame)
        } else {
            (self.state_id, self.state_since)
        }
    }

    /// The state the next barrier will apply: the current one with every queued change.
    pub fn next_state(&self) -> WallState {
        self.next
    }

    /// Queues a state change for the next frame barrier, checked against the state it will
    /// apply to (the current one with every change queued before it). `stamp` is when the
    /// change entered the wall (the driver's clock); it comes back in
    /// [`Output::StateApplied`].
    ///
    /// # Errors
    /// A combination that [`WallState::apply`] refuses; nothing is queued.
    pub fn queue_change(
        &mut self,
        change: StateChange,
        stamp: u64,
        now: Instant,
    ) -> Result<(), ParamsError> {
        self.next = self.next.apply(&change)?;
        self.pending_changes += 1;
        self.pending_stamps.push(stamp);
        self.last_change_at = Some(now);
        // A converged wall renders again once something changed, and a frame held back while
        // someone steers (or a refinement pass's successor) starts now to carry the change.
        self.converged = false;
        self.on_change(now);
        Ok(())
    }

    /// Allows frames to start (call once the expected nodes have joined).
    pub fn start(&mut self, now: Instant) {
        self.running = true;
        for d in self.live_displays.clone() {
            self.heard_display(d, now);
        }
        self.try_start_frames(now);
    }

    // ---- inputs ----

    /// A render node is ready for frames. It joins the frames in flight at once.
    pub fn handle_render_joined(&mut self, node: RenderNodeId, now: Instant) {
        self.stalled = false;
        let mut joined_frames = false;
        for frame in self.in_flight.values() {
            if !frame.all_rendered() {
                // A latecomer's share is empty; like every share it follows the start, and
                // the node asks for work once it has it.
                self.outputs
                    .push_back(Output::ToRender(node, ToNode::FrameStart(frame.start)));
                self.outputs.push_back(Output::ToRender(
                    node,
                    ToNode::Assign {
                        frame: frame.start.frame,
                        tiles: Vec::new(),
                    },
                ));
                joined_frames = true;
            }
        }
        self.nodes.insert(
            node,
            RenderNode {
                last_progress: now,
                progress_gap: None,
            },
        );
        if !joined_frames {
            self.waiting.insert(node);
        }
        self.heard_render(node, now);
        self.feed_waiting(now);
        self.try_start_frames(now);
    }

    /// A render node's connection closed: its unfinished tiles go to the others.
    pub fn handle_render_left(&mut self, node: RenderNodeId, now: Instant) {
        if self.nodes.remove(&node).is_none() {
            return;
        }
        self.waiting.remove(&node);
        self.liveness.forget(node);
        self.tiles_per_frame.remove(&node);
        for frame in self.in_flight.values_mut() {
            frame.reclaim(node);
        }
        self.feed_waiting(now);
        self.check_stalled();
        self.try_start_frames(now);
    }

    /// A render node finished `tiles` of `frame` (they reached their displays).
    pub fn handle_tiles_done(
        &mut self,
        node: RenderNodeId,
        frame: FrameId,
        tiles: &[TileRange],
        want_more: bool,
        now: Instant,
    ) -> Result<(), BalanceError> {
        if !self.nodes.contains_key(&node) {
            return Err(BalanceError::UnknownNode(node));
        }
        self.heard_render(node, now);
        if frame >= self.next_frame {
            return Err(BalanceError::FutureFrame(frame));
        }
        if !tiles.is_empty() {
            self.note_progress(node, now);
        }
        if let Some(state) = self.in_flight.get_mut(&frame) {
            let was_rendered = state.all_rendered();
            for range in tiles {
                if range.end() > self.tile_count {
                    return Err(BalanceError::NotAssigned {
                        node,
                        frame,
                        tile: range.end(),
                    });
                }
                state.mark_done(node, range.tiles())?;
            }
            if !was_rendered && state.all_rendered() {
                self.outputs.push_back(Output::FrameRendered(frame));
            }
        }
        // A frame already presented needs nothing more: its tiles all arrived.
        if want_more {
            self.assign_batch(node, now);
        }
        self.try_start_frames(now);
        Ok(())
    }

    /// Display `display` has every tile of `frame`.
    pub fn handle_frame_complete(
        &mut self,
        display: DisplayId,
        frame: FrameId,
        now: Instant,
    ) -> Result<(), BalanceError> {
        if display.0 >= self.display_count {
            return Err(BalanceError::UnknownDisplay(display));
        }
        if !self.live_displays.contains(&display) {
            // Gone already: what it still says counts for nothing.
            return Ok(());
        }
        self.heard_display(display, now);
        if frame >= self.next_frame {
            return Err(BalanceError::FutureFrame(frame));
        }
        if let Some(state) = self.in_flight.get_mut(&frame) {
            state.displays_complete.insert(display);
        }
        self.try_present(now);
        self.try_start_frames(now);
        Ok(())
    }

    // ---- outputs ----

    /// The next thing the driver must do, in the order they arose; `None` once there is
    /// nothing left until the next input.
    pub fn poll_output(&mut self) -> Option<Output> {
        self.outputs.pop_front()
    }

    // ---- internals ----

    fn try_present(&mut self, now: Instant) {
        while let Some(state) = self.in_flight.get(&self.next_present) {
            let waiting = state
                .displays_expected
                .iter()
                .any(|d| !state.displays_complete.contains(d));
            if waiting {
                return;
            }
            let frame = self.next_present;
            if !state.all_rendered() {
                // Every display has every tile, so every tile was rendered; the reports of
                // that are still on their way.
                self.outputs.push_back(Output::FrameRendered(frame));
            }
            if let Some(state) = self.in_flight.remove(&frame) {
                self.learn_speeds(&state);
                self.learn_frame_time(&state, now);
            }
            self.outputs
                .push_back(Output::ToDisplays(ToNode::Present { frame }));
            self.outputs.push_back(Output::FramePresented(frame));
            self.next_present = FrameId(frame.0 + 1);
            if self.is_finished() {
                self.outputs.push_back(Output::Finished);
            }
        }
    }

    /// What `frame` renders with: the state's knobs, or a refinement pass of them. Marks the
    /// wall converged when this is the final pass and nothing waits to change.
    fn frame_params(&mut self, frame: FrameId) -> RenderParams {
        let Some(refinement) = self.refinement else {
            return self.state.params;
        };
        // An orbiting camera never holds still.
        if self.state.camera.fixed_camera().is_none() {
            return self.state.params;
        }
        let age = frame.0 - self.state_since.0;
        let (params, last) = refinement.frame_params(self.state.params, age);
        let waiting = self.pending_changes > 0
            || self
                .scheduled
                .keys()
                .next()
                .is_some_and(|&f| f <= self.next_frame);
        if last && !waiting {
            self.converged = true;
            self.outputs.push_back(Output::Converged(frame));
            // A run of so many frames has nothing more to show: end it here.
            if self.frame_limit.is_some() {
                self.frame_limit = Some(frame.0 + 1);
            }
        }
        params
    }

    fn can_start_next(&self, now: Instant) -> bool {
        if !self.running || self.nodes.is_empty() {
            return false;
        }
        if self
            .frame_limit
            .is_some_and(|limit| self.next_frame.0 >= limit)
            || self.frame_horizon.is_some_and(|h| self.next_frame >= h)
        {
            return false;
        }
        if self.converged || !self.awaited_displays.is_empty() {
            return false;
        }
        // At most two frames in flight, and every tile of the newer one handed out; while
        // someone steers, every tile of it rendered (see `steering`).
        let holds = self.holds_next_frame(now);
        match self.in_flight.len() {
            0 => true,
            1 => self
                .in_flight
                .values()
                .next()
                .is_some_and(|f| f.pool_is_empty() && (!holds || f.all_rendered())),
            _ => false,
        }
    }

    fn try_start_frames(&mut self, now: Instant) {
        while self.can_start_next(now) {
            let frame = self.next_frame;
            self.next_frame = FrameId(frame.0 + 1);
            for change in self.scheduled.remove(&frame).unwrap_or_default() {
                // Queued inside the barrier that applies it: nothing to restart.
                match self.next.apply(&change) {
                    Ok(next) => {
                        self.next = next;
                        self.pending_changes += 1;
                        self.pending_stamps.push(0);
                    }
                    Err(error) => self.outputs.push_back(Output::Refused { frame, error }),
                }
            }
            if self.pending_changes > 0 {
                self.state = self.next;
                self.state_id = StateId(self.state_id.0 + 1);
                self.state_since = frame;
                self.outputs.push_back(Output::StateApplied {
                    frame,
                    state: self.state_id,
                    wall: self.state,
                    changes: std::mem::take(&mut self.pending_changes),
                    stamps: std::mem::take(&mut self.pending_stamps),
                });
            }
            let params = self.frame_params(frame);
            let start = FrameStart {
                frame,
                state: self.state_id,
                camera: self.state.camera.camera_for_frame(frame.0),
                params,
                lights: self.state.lights,
            };
            let own = self.state.params;
            let mut state = InFlight::new(start, self.tile_count);
            state.started_at = Some(now);
            state.refinement_pass =
                params.spp() > own.spp() || params.ao_samples() > own.ao_samples();
            state.displays_expected = self.live_displays.clone();
            for d in 0..self.display_count {
                let display = DisplayId(d);
                if !self.live_displays.contains(&display) {
                    state.drop_tiles(&self.tiles_of(display));
                }
            }
            self.outputs.push_back(Output::FrameStarted(frame));
            self.outputs
                .push_back(Output::ToDisplays(ToNode::FrameStart(start)));
            let (nodes, suspected) = self.share_holders();
            let shares = state.static_shares(&nodes, self.config.static_fraction);
            // A suspected node gets the start and an empty share: back, it asks for work.
            let empty = std::iter::repeat_with(Vec::new);
            let holders = nodes.iter().map(|&(n, _)| n).zip(shares);
            for (node, tiles) in holders.chain(suspected.into_iter().zip(empty)) {
                if !tiles.is_empty() {
                    self.note_given(node, now);
                }
                self.outputs
                    .push_back(Output::ToRender(node, ToNode::FrameStart(start)));
                self.outputs.push_back(Output::ToRender(
                    node,
                    ToNode::Assign {
                        frame,
                        tiles: to_ranges(tiles),
                    },
                ));
            }
            self.in_flight.insert(frame, state);
            self.waiting.clear();
        }
    }

    /// Hands `node` the next batch from the oldest frame that has unassigned tiles, or marks it
    /// waiting and tells it there is nothing for now.
    fn assign_batch(&mut self, node: RenderNodeId, now: Instant) {
        let node_count = self.nodes.len().max(1) as u32;
        let min_batch = self.config.min_batch;
        if self.in_flight.values().any(|f| !f.pool_is_empty()) {
            self.note_given(node, now);
        }
        for (frame, state) in self.in_flight.iter_mut() {
            let batch = state.take_batch(node, node_count, min_batch);
            if !batch.is_empty() {
                self.outputs.push_back(Output::ToRender(
                    node,
                    ToNode::Assign {
                        frame: *frame,
                        tiles: to_ranges(batch),
                    },
                ));
                self.waiting.remove(&node);
                return;
            }
        }
        if self.speculate_for(node, now) {
            return;
        }
        if self.nodes.contains_key(&node) {
            // Always answer, so the node knows its request is settled.
            self.waiting.insert(node);
            let frame = FrameId(self.next_frame.0.saturating_sub(1));
            self.outputs.push_back(Output::ToRender(
                node,
                ToNode::Assign {
                    frame,
                    tiles: Vec::new(),
                },
            ));
        }
    }

    /// Gives reclaimed tiles to nodes that are idle.
    fn feed_waiting(&mut self, now: Instant) {
        let waiting: Vec<RenderNodeId> = self.waiting.iter().copied().collect();
        for node in waiting {
            if self.in_flight.values().all(|f| f.pool_is_empty()) {
                return;
            }
            self.waiting.remove(&node);
            self.assign_batch(node, now);
        }
    }

    fn check_stalled(&mut self) {
        if self.nodes.is_empty() && !self.in_flight.is_empty() && !self.stalled {
            self.stalled = true;
            self.outputs.push_back(Output::Stalled);
        }
    }
}

#[cfg(test)]
mod cancel_tests;
#[cfg(test)]
mod liveness_tests;
#[cfg(test)]
mod tests;
