//! Why a message was refused: [`ProtocolError`], one variant per invariant a message can break.

use crate::dsm;
use crate::MAX_CORES;

/// A message whose fields break an invariant of the protocol.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ProtocolError {
    /// A hello's host name is longer than [`MAX_HOST_BYTES`](crate::MAX_HOST_BYTES) or holds control characters;
    /// carries its first 64 characters.
    #[error("host name {0:?} is too long or holds control characters")]
    BadHost(String),
    /// A render node's hello claims no cores or more than [`MAX_CORES`].
    #[error("a render node claims {0} cores; 1 to {MAX_CORES} are allowed")]
    BadCores(u32),
    /// A tile range ends before it starts.
    #[error("tile range {start}..{end} ends before it starts")]
    BackwardRange {
        /// The first tile id.
        start: u32,
        /// One past the last tile id.
        end: u32,
    },
    /// A session lists an endpoint or a window for a display the wall does not have.
    #[error("session lists display {display}, but the wall has {count} displays")]
    UnknownDisplay {
        /// The display listed.
        display: u32,
        /// Displays the wall has.
        count: u32,
    },
    /// A session lists two endpoints for one display.
    #[error("session lists display {0} twice")]
    DuplicateDisplay(u32),
    /// A render node's stats hold a time that is negative or not finite, or more than
    /// [`MAX_REPORTED_LOADS`](crate::MAX_REPORTED_LOADS) load times.
    #[error("stats field {field} is {value}, not a finite number of seconds")]
    BadSeconds {
        /// The stats field at fault, as the struct names it.
        field: &'static str,
        /// Its value, in seconds (microseconds for the latencies; a count for too many loads).
        value: f64,
    },
    /// A session's shared scene has a spread [`dsm::DsmSpec::check`] refuses.
    #[error("session shares the scene with {0}")]
    BadShared(dsm::DsmSpecError),
    /// A session's particle attribute range is not finite, or ends below where it starts.
    #[error("session's particle range {lo}..{hi} is not a finite range from low to high")]
    BadParticleRange {
        /// Its low end.
        lo: f32,
        /// Its high end.
        hi: f32,
    },
}

// By hand, not `#[from]`, which would make the spread's error a source as well and an error
// chain would say it twice.
impl From<dsm::DsmSpecError> for ProtocolError {
    fn from(e: dsm::DsmSpecError) -> Self {
        ProtocolError::BadShared(e)
    }
}
