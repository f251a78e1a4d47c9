//! Why a run ended without its report, and why a master could not be set up.

use super::*;

/// Why a run ended without its report.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum RunError {
    /// The nodes the wall needs were not all ready within the join timeout.
    #[error(
        "timed out after {waited:?} waiting for nodes: {missing} — start the missing nodes or raise --join-timeout"
    )]
    JoinTimeout {
        /// The join timeout.
        waited: Duration,
        /// Which displays were not ready and how many render nodes were (see
        /// [`Master::missing_summary`]).
        missing: String,
    },
    /// Every node joined, but not all were ready within the load timeout.
    #[error(
        "the nodes joined but were not all ready {waited:?} later: {missing} — see their logs, or raise --load-timeout for a scene that loads this long"
    )]
    LoadTimeout {
        /// The load timeout.
        waited: Duration,
        /// Who was not ready, and what the render nodes said they were doing.
        missing: String,
    },
    /// Ctrl-C before every node was ready.
    #[error("interrupted before the first frame")]
    InterruptedBeforeStart,
    /// A display was lost before the first frame, or under [`DisplayLoss::Stop`].
    #[error(
        "{who} disconnected ({reason}); the wall stops (--display-loss stop, or it had not started)"
    )]
    DisplayLost {
        /// The display, as log lines name it: `display 2 (host)`.
        who: String,
        /// Why its connection closed.
        reason: String,
    },
    /// A display lost under [`DisplayLoss::Wait`] did not rejoin within the join timeout.
    #[error(
        "display {} was not back {:.1} s after it was lost; the wall waited for it (--display-loss wait, at most --join-timeout)",
        .display.0, .waited.as_secs_f64()
    )]
    DisplayNotBack {
        /// The display the wall waited for.
        display: DisplayId,
        /// How long it waited since the display was lost.
        waited: Duration,
    },
    /// Frames are in flight but every render node, or every display, is gone.
    #[error("every render node or every display is gone; the frames in flight cannot complete")]
    Stalled,
    /// A node follows a master of a higher term (a standby took over): this one stepped
    /// down, so that the wall never has two masters.
    #[error(
        "stepped down: a node follows a master of term {seen}, newer than this master's {term} (a standby took the wall over)"
    )]
    SteppedDown {
        /// This master's term.
        term: u64,
        /// The term the node follows.
        seen: u64,
    },
}

/// Why a master could not be set up.
#[derive(Debug, thiserror::Error)]
pub enum MasterError {
    /// A change of the recorded session cannot be scheduled.
    #[error("the replayed session: {0}")]
    Replay(BalanceError),
}
