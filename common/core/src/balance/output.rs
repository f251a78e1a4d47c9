//! What the coordinator tells its driver, and the messages it refuses.

use super::*;

/// What the driver must do.
#[derive(Clone, Debug, PartialEq)]
pub enum Output {
    /// Send this message to that render node.
    ToRender(RenderNodeId, ToNode),
    /// Send to every display.
    ToDisplays(ToNode),
    /// The frame started: its `FrameStart` and static shares follow in the outputs.
    FrameStarted(FrameId),
    /// A new state takes effect with `frame`: the `changes` queued since the last barrier,
    /// collapsed into one, with the entry stamps they were queued with (for input latency).
    StateApplied {
        /// The first frame rendered with the new state.
        frame: FrameId,
        /// The new state's id, one more than the last.
        state: StateId,
        /// The new state itself.
        wall: WallState,
        /// How many changes (queued or scheduled) it folds in.
        changes: u64,
        /// One per change, in the order they were applied: the `stamp` given to
        /// [`Coordinator::queue_change`], or 0 for a change from
        /// [`Coordinator::schedule_change`].
        stamps: Vec<u64>,
    },
    /// `frame` is the final refinement pass: nothing more starts until something changes.
    Converged(FrameId),
    /// A change scheduled for `frame` was refused by the state there.
    Refused {
        /// The frame whose barrier the change was scheduled for.
        frame: FrameId,
        /// Why the state there refused it.
        error: ParamsError,
    },
    /// Every tile of the frame reached its display.
    FrameRendered(FrameId),
    /// `Present` was sent for this frame.
    FramePresented(FrameId),
    /// The frame was abandoned and will never be shown (see [`ToNode::Cancel`]): it ran for
    /// `ran`, where recent frames took `usual`, and a newer state waited (or the run was
    /// interrupted).
    FrameCancelled {
        /// The frame abandoned.
        frame: FrameId,
        /// How long it had been in flight.
        ran: Duration,
        /// The smoothed start-to-present time of the frames before it, if any was shown.
        usual: Option<Duration>,
        /// It was a refinement pass made stale by a change: cancelled at once, as a matter of
        /// course, rather than as a runaway.
        refinement: bool,
    },
    /// The last frame of the run was presented.
    Finished,
    /// Frames are in flight but no render node is left to render them, or no display to show
    /// them (and none is waited for).
    Stalled,
    /// `node` was silent past [`BalanceConfig::node_deadline`]: its tiles are copied to the
    /// others, and it stays connected.
    RenderSuspected {
        /// The node suspected.
        node: RenderNodeId,
        /// How long since it was last heard from.
        silent: Duration,
    },
    /// A suspected display: the barrier still waits for it, until it speaks or is dead.
    DisplaySuspected {
        /// The display suspected.
        display: DisplayId,
        /// How long since it was last heard from.
        silent: Duration,
    },
    /// A suspected render node spoke again: it is simply back, and gets work again.
    RenderBack {
        /// The node back.
        node: RenderNodeId,
        /// How long it had been silent.
        silent: Duration,
    },
    /// A suspected display spoke again.
    DisplayBack {
        /// The display back.
        display: DisplayId,
        /// How long it had been silent.
        silent: Duration,
    },
    /// `node` was silent for `silent`, long past what its rhythm allows (see
    /// [`DeathDetector`]), and is treated as gone; the driver should close its connection.
    RenderTimedOut {
        /// The node given up for dead.
        node: RenderNodeId,
        /// How long since it was last heard from.
        silent: Duration,
    },
    /// `display` was silent long past what its rhythm allows and the wall goes on without it;
    /// the driver should close its connection.
    DisplayTimedOut {
        /// The display given up for dead.
        display: DisplayId,
        /// How long since it was last heard from.
        silent: Duration,
    },
    /// A display lost under [`BalanceConfig::wait_for_lost_displays`] was not back within
    /// the limit; no frame has started since it was lost.
    DisplayNotBack {
        /// The lost display the wall waited for.
        display: DisplayId,
        /// How long the wall waited since it was lost.
        waited: Duration,
    },
}

/// A message that does not fit the coordinator's state: a buggy or hostile peer.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum BalanceError {
    /// A message from a render node that never joined, or already left.
    #[error("render node {0:?} is not part of this run")]
    UnknownNode(RenderNodeId),
    /// A display id past the wall's displays.
    #[error("display {0:?} is not part of this wall")]
    UnknownDisplay(DisplayId),
    /// A report of tiles done or a frame complete, for a frame that has not started yet.
    #[error("frame {0:?} has not started")]
    FutureFrame(FrameId),
    /// A change scheduled for the barrier of a frame that has already started.
    #[error("frame {0:?} has already started")]
    PastFrame(FrameId),
    /// A render node reported a tile done that it does not hold: never given to it, already
    /// reported, or past the wall's tiles.
    #[error("tile {tile} of frame {frame:?} was not assigned to render node {node:?}")]
    NotAssigned {
        /// The node that sent the report.
        node: RenderNodeId,
        /// The frame the report was for.
        frame: FrameId,
        /// The first tile (wall-wide index) it does not hold; for a range past the wall's
        /// tiles, the range's end.
        tile: u32,
    },
}
