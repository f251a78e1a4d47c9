//! A display node's session, sans IO: what it does with each message from the master and each
//! tile a render node sends.
//!
//! It wraps the [`FrameAssembler`] and adds what the driver loop used to decide on its own:
//! what a present shows and under which names it is saved, when to report a frame complete,
//! the overlay's figures (who rendered each tile, the display's frame rate), and the figures
//! reported at shutdown. (Heartbeats are not the session's: `tessera_net::link` sends them as
//! datagrams, whatever the driver loop is doing.)

use crate::assemble::{AssembleError, FrameAssembler, PresentedFrame};
use std::collections::{BTreeMap, VecDeque};
use std::sync::Arc;
use std::time::Instant;
use tessera_model::colormap::ColorMap;
use tessera_model::params::RenderParams;
use tessera_model::state::StateId;
use tessera_model::wall::{ScreenRect, TileGrid, TileId};
use tessera_protocol::pixels::BatchSource;
use tessera_protocol::{DisplayStats, FrameId, FromNode, ToNode};

/// Presents whose times the overlay's frame rate is measured over.
const PRESENTS_TIMED: usize = 64;

/// A message from the master that makes no sense to this display.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum DisplaySessionError {
    /// A `FrameStart` for a frame already presented, or too far ahead.
    #[error("the master broke the frame barrier: {0}")]
    FrameBarrier(AssembleError),
    /// A present of a frame already presented or not complete, or whose tiles' state its
    /// `FrameStart` did not announce.
    #[error("the master broke the swap barrier: {0}")]
    SwapBarrier(AssembleError),
    /// A message only render nodes, control clients or the handshake take; the message's kind.
    #[error("the master broke the protocol: it sent a display a {0} message")]
    NotForDisplays(&'static str),
}

/// What to draw over one frame, on request: the display's frame rate and frame time, and who
/// rendered each tile in how long.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Overlay {
    /// Frames per second this display presents.
    pub fps: f32,
    /// Time since the present before this one.
    pub frame_ms: f32,
    /// Each tile of the frame: its rectangle on this screen, who rendered it, in how long.
    pub tiles: Vec<TileInfo>,
    /// The state and quality the frame was rendered with: the status line.
    pub status: Option<FrameStatus>,
    /// The particles' attribute range `[lo, hi]` the colour map spans, where the scene has
    /// particles: the legend's ends.
    pub particles: Option<[f32; 2]>,
}

/// What a frame shows, as its status line and legend say: the state's id, the quality knobs,
/// and how particles are coloured.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameStatus {
    /// The wall state the frame renders.
    pub state: StateId,
    /// Samples per pixel.
    pub spp: u32,
    /// Ambient-occlusion rays per hit.
    pub ao_samples: u32,
    /// Whether shadow rays are traced.
    pub shadows: bool,
    /// The colour map of particles' attributes.
    pub colormap: ColorMap,
    /// The attribute range `(lo, hi)` of the particles drawn, if cropped.
    pub crop: Option<(f32, f32)>,
}

impl FrameStatus {
    /// The status of a frame of state `state` rendered with `params`.
    pub fn of(state: StateId, params: &RenderParams) -> Self {
        FrameStatus {
            state,
            spp: params.spp(),
            ao_samples: params.ao_samples(),
            shadows: params.shadows(),
            colormap: params.colormap(),
            crop: params.crop(),
        }
    }
}

/// Frame starts remembered for the status line: more than are ever in flight at once.
const STARTS_KEPT: usize = 16;

/// One tile as the overlay shows it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TileInfo {
    /// Its left edge, in the screen's pixels.
    pub x: u32,
    /// Its top edge, in the screen's pixels.
    pub y: u32,
    /// Its width in pixels.
    pub width: u32,
    /// Its height in pixels.
    pub height: u32,
    /// The render node that drew it.
    pub node: u32,
    /// Its rendering time, averaged over its batch.
    pub ms: f32,
}

/// A frame to present, as the swap barrier says.
#[derive(Debug)]
pub struct PresentOrder {
    /// The frame's pixels.
    pub shown: PresentedFrame,
    /// When to show it on this display's clock (ns since the Unix epoch), if the master gave
    /// a deadline; otherwise at once.
    pub deadline: Option<u64>,
    /// The file names to save it under (the session's frame, snapshots a control client
    /// asked for), in the folder the node was given; none if it is not to be saved.
    pub save_as: Vec<String>,
    /// Whether a snapshot is among `save_as`: the master is told once it is written
    /// ([`FromNode::Saved`]).
    pub snapshot: bool,
    /// Who rendered each tile of it, for the overlay.
    sources: BTreeMap<TileId, BatchSource>,
}

/// What the driver must do besides sending messages to the master.
#[derive(Debug)]
pub enum DisplayEvent {
    /// Show a frame: wait for its deadline, read the clock, call
    /// [`DisplaySession::handle_shown`], show it (headless: report it presented at once) and
    /// save it under its names.
    Present(PresentOrder),
    /// Answer the master's clock probe with this display's clock, read now.
    Pong {
        /// The sequence number of the ping, to send back with the clock.
        seq: u32,
    },
    /// The master ended the wall: send [`DisplaySession::stats`] (with the bytes received
    /// added) and leave.
    Shutdown,
    /// Save the frame shown now as `name` and tell the master ([`FromNode::Saved`] of
    /// `frame`): a still wall's snapshot.
    SaveShown {
        /// The last frame presented.
        frame: FrameId,
        /// The file name, in the folder the node was given.
        name: String,
    },
    /// Send the master the frame shown now, shrunk `factor` times ([`FromNode::Thumbnail`]).
    Thumbnail {
        /// Screen pixels per thumbnail pixel across and down.
        factor: u32,
    },
    /// The overlay was turned on or off: show the frame shown now again, with
    /// [`DisplaySession::overlay_now`] over it, so that a still wall shows the change.
    Redraw,
}

/// A display's side of one master's wall, from its `Ready` to the shutdown.
///
/// Inputs are `handle_*` methods. After any of them the driver calls
/// [`DisplaySession::poll_transmit`] until it returns `None` (the messages to the master, in
/// order; before carrying out any event, so the master hears a frame complete before this
/// display waits for a present's deadline), then [`DisplaySession::poll_event`] until it
/// returns `None`.
///
/// # Examples
///
/// ```
/// use std::sync::Arc;
/// use std::time::Instant;
/// use tessera_core::node::display::{DisplayEvent, DisplaySession};
/// use tessera_protocol::pixels::BatchSource;
/// use tessera_protocol::{FrameId, FromNode, ToNode};
/// use tessera_model::state::StateId;
/// use tessera_model::wall::{DisplayId, TileGrid, WallSpec};
///
/// // One 16×16 screen, one tile.
/// let wall = WallSpec::grid(1, 1, 16, 16).tile_size(16).build().unwrap();
/// let screen = wall.screen(DisplayId(0)).unwrap();
/// let grid = Arc::new(TileGrid::new(wall));
/// let tile = grid.tiles()[0].id;
/// let mut display = DisplaySession::new(grid, screen, None);
///
/// let (frame, state) = (FrameId(0), StateId(0));
/// display.handle_tile(frame, state, tile, &[9; 16 * 16 * 3], BatchSource::default())?;
/// assert_eq!(display.poll_transmit(), Some(FromNode::FrameComplete { frame }));
/// display.handle_message(ToNode::FrameStart(tessera_protocol::FrameStart::new(
///     frame,
///     state,
///     tessera_model::camera::Camera::new(glam::Vec3::Z, glam::Vec3::ZERO, glam::Vec3::Y, 45.0).unwrap(),
///     tessera_model::params::RenderParams::interactive(),
/// )))?;
/// display.handle_message(ToNode::Present { frame })?;
/// let Some(DisplayEvent::Present(order)) = display.poll_event() else { panic!() };
/// assert_eq!((order.shown.frame, order.deadline), (frame, None));
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub struct DisplaySession {
    screen: ScreenRect,
    grid: Arc<TileGrid>,
    assembler: FrameAssembler,
    /// The session's frame to save as `display-<id>.png`.
    save_frame: Option<FrameId>,
    /// Frames a control client asked to keep, saved as they are presented.
    snapshots: Vec<FrameId>,
    presented: u64,
    overlay: bool,
    /// Who rendered each tile of the frames under assembly, for the overlay.
    sources: BTreeMap<FrameId, BTreeMap<TileId, BatchSource>>,
    /// The last frame presented, and who rendered its tiles: what a still wall shows.
    last_shown: Option<(FrameId, BTreeMap<TileId, BatchSource>)>,
    /// When the last presents happened, for the overlay's frame rate.
    present_times: VecDeque<Instant>,
    /// The latest frames' states and quality, for the status line.
    starts: VecDeque<(FrameId, FrameStatus)>,
    /// The particles' attribute range, where the scene has particles: the overlay's legend.
    particle_range: Option<[f32; 2]>,
    transmit: VecDeque<FromNode>,
    events: VecDeque<DisplayEvent>,
}

impl DisplaySession {
    /// A session of the display showing `screen` of the wall `grid` cuts into tiles, the
    /// display having just told the master it is ready; `save_frame` is the session's frame to
    /// save, if any.
    pub fn new(grid: Arc<TileGrid>, screen: ScreenRect, save_frame: Option<FrameId>) -> Self {
        DisplaySession {
            screen,
            assembler: FrameAssembler::new(&grid, screen),
            grid,
            save_frame,
            snapshots: Vec::new(),
            presented: 0,
            overlay: false,
            sources: BTreeMap::new(),
            last_shown: None,
            present_times: VecDeque::new(),
            starts: VecDeque::new(),
            particle_range: None,
            transmit: VecDeque::new(),
            events: VecDeque::new(),
        }
    }

    /// The session, its scene's particles' attribute range being `range` (as the master's
    /// session says): the overlay then carries it, for the colour map's legend.
    pub fn with_particle_range(mut self, range: Option<[f32; 2]>) -> Self {
        self.particle_range = range;
        self
    }

    /// Frames presented so far.
    pub fn presented(&self) -> u64 {
        self.presented
    }

    /// Whether the overlay is on.
    pub fn overlay(&self) -> bool {
        self.overlay
    }

    /// Takes a message from the master.
    ///
    /// # Errors
    /// A frame start or present that breaks the barriers (see [`AssembleError`]), or a
    /// message only render nodes or the handshake take.
    pub fn handle_message(&mut self, msg: ToNode) -> Result<(), DisplaySessionError> {
        match msg {
            ToNode::PresentAt { frame, clock_ns } => self.present(frame, Some(clock_ns))?,
            ToNode::Present { frame } => self.present(frame, None)?,
            ToNode::Ping { seq } => self.events.push_back(DisplayEvent::Pong { seq }),
            ToNode::Shutdown => self.events.push_back(DisplayEvent::Shutdown),
            // The frame's state: every tile of the frame must have been rendered with it.
            ToNode::FrameStart(start) => {
                self.assembler
                    .handle_frame_start(start.frame, start.state)
                    .map_err(DisplaySessionError::FrameBarrier)?;
                if self.starts.len() == STARTS_KEPT {
                    self.starts.pop_front();
                }
                let status = FrameStatus::of(start.state, &start.params);
                self.starts.push_back((start.frame, status));
            }
            ToNode::StartAt { frame } => self.assembler.start_at(frame),
            ToNode::Cancel { frame } => {
                self.assembler.cancel_up_to(frame);
                self.sources.retain(|f, _| *f > frame);
                // The frame after may be here already, complete.
                self.report_next_complete();
            }
            ToNode::Overlay { on } => {
                self.overlay = on;
                self.events.push_back(DisplayEvent::Redraw);
            }
            ToNode::SaveFrame { frame } => self.snapshots.push(frame),
            ToNode::SaveShown { frame } => {
                let name = format!("display-{}-frame-{}.png", self.screen.id.0, frame.0);
                self.events
                    .push_back(DisplayEvent::SaveShown { frame, name });
            }
            ToNode::SendThumbnail { factor } => {
                self.events.push_back(DisplayEvent::Thumbnail { factor })
            }
            other @ (ToNode::Assign { .. }
            | ToNode::Welcome { .. }
            | ToNode::Refused { .. }
            | ToNode::ControlReply { .. }
            | ToNode::DisplayAt { .. }
            | ToNode::BlockHolders { .. }) => {
                return Err(DisplaySessionError::NotForDisplays(other.kind()))
            }
        }
        Ok(())
    }

    /// A tile from a render node; `source` says who rendered it, in how long. A tile that
    /// completes the next frame to present has it reported complete.
    ///
    /// # Errors
    /// A tile the assembler refuses (another display's, a wrong length, a frame outside the
    /// window, another state): the driver closes the connection it came on.
    pub fn handle_tile(
        &mut self,
        frame: FrameId,
        state: StateId,
        tile: TileId,
        rgb: &[u8],
        source: BatchSource,
    ) -> Result<(), AssembleError> {
        let done = self.assembler.handle_tile(frame, state, tile, rgb)?;
        self.sources.entry(frame).or_default().insert(tile, source);
        if done.is_some() {
            self.report_next_complete();
        }
        Ok(())
    }

    /// The frame of `order` is being shown at `now` (its deadline passed): the overlay to
    /// draw over it, if the overlay is on, timed against the presents before it.
    pub fn handle_shown(&mut self, order: &PresentOrder, now: Instant) -> Option<Overlay> {
        let overlay = self
            .overlay
            .then(|| self.overlay_of(order.shown.frame, &order.sources, now));
        self.last_shown = Some((order.shown.frame, order.sources.clone()));
        self.present_times.push_back(now);
        while self.present_times.len() > PRESENTS_TIMED {
            self.present_times.pop_front();
        }
        overlay
    }

    /// The state and quality `frame` was rendered with, if its start is recent enough to be
    /// remembered: what a window's status line says.
    pub fn status_of(&self, frame: FrameId) -> Option<FrameStatus> {
        self.starts
            .iter()
            .find(|(f, _)| *f == frame)
            .map(|(_, status)| *status)
    }

    /// The overlay over the frame shown now, timed now, if the overlay is on.
    pub fn overlay_now(&self, now: Instant) -> Option<Overlay> {
        let (frame, sources) = self.last_shown.as_ref()?;
        self.overlay.then(|| self.overlay_of(*frame, sources, now))
    }

    /// The next message for the master.
    pub fn poll_transmit(&mut self) -> Option<FromNode> {
        self.transmit.pop_front()
    }

    /// The next thing the driver must do besides sending (see [`DisplayEvent`]).
    pub fn poll_event(&mut self) -> Option<DisplayEvent> {
        self.events.pop_front()
    }

    /// The session's figures; the bytes received are the driver's to fill in.
    pub fn stats(&self) -> DisplayStats {
        DisplayStats {
            pixels_owned: self.screen.width as u64 * self.screen.height as u64,
            pixel_bytes_received: 0,
            wire_bytes_received: 0,
            stream_bytes_received: 0,
            frames_presented: self.presented,
            duplicate_tiles: self.assembler.duplicates(),
        }
    }

    /// The swap barrier: `frame` is shown (at `deadline`, if the master gave one).
    fn present(
        &mut self,
        frame: FrameId,
        deadline: Option<u64>,
    ) -> Result<(), DisplaySessionError> {
        let shown = self
            .assembler
            .handle_present(frame)
            .map_err(DisplaySessionError::SwapBarrier)?;
        self.presented += 1;
        self.report_next_complete();
        let sources = self.sources.remove(&frame).unwrap_or_default();
        self.sources.retain(|f, _| *f > frame);
        let snapshot = self.snapshots.contains(&frame);
        let save_as = self.save_names(frame);
        self.events.push_back(DisplayEvent::Present(PresentOrder {
            shown,
            deadline,
            save_as,
            snapshot,
            sources,
        }));
        Ok(())
    }

    /// Reports the next frame to present complete, once, when it is assembled.
    fn report_next_complete(&mut self) {
        if let Some(frame) = self.assembler.poll_complete() {
            self.transmit.push_back(FromNode::FrameComplete { frame });
        }
    }

    /// The files `frame` is saved as: the session's frame, and snapshots asked for.
    fn save_names(&mut self, frame: FrameId) -> Vec<String> {
        let me = self.screen.id.0;
        let mut names = Vec::new();
        if self.save_frame == Some(frame) {
            names.push(format!("display-{me}.png"));
        }
        if let Some(i) = self.snapshots.iter().position(|&f| f == frame) {
            self.snapshots.swap_remove(i);
            names.push(format!("display-{me}-frame-{}.png", frame.0));
        }
        names
    }

    fn overlay_of(
        &self,
        frame: FrameId,
        sources: &BTreeMap<TileId, BatchSource>,
        now: Instant,
    ) -> Overlay {
        let last = self.present_times.back().copied();
        let frame_ms = last.map_or(0.0, |t| now.duration_since(t).as_secs_f32() * 1000.0);
        let window = self.present_times.front().map(|t| now.duration_since(*t));
        let fps = match window {
            Some(span) if !span.is_zero() => self.present_times.len() as f32 / span.as_secs_f32(),
            _ => 0.0,
        };
        let tiles = sources
            .iter()
            .filter_map(|(id, source)| {
                let t = self.grid.tile(*id)?;
                Some(TileInfo {
                    x: t.x - self.screen.x,
                    y: t.y - self.screen.y,
                    width: t.width,
                    height: t.height,
                    node: source.node.0,
                    ms: source.render_us as f32 / 1000.0,
                })
            })
            .collect();
        let status = self.status_of(frame);
        Overlay {
            fps,
            frame_ms,
            tiles,
            status,
            particles: self.particle_range,
        }
    }
}
