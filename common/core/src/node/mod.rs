//! What a render node and a display node do with each message of a session, without the
//! sockets: [`render::RenderSession`] and [`display::DisplaySession`].
//!
//! A session runs from the master's welcome to its shutdown. Its driver loop (in the node
//! crates) reads the clock and moves bytes: it hands a session each message from the master,
//! each finished batch or tile and each timer that fires, with `now`, and then carries out what
//! the session's `poll_*` methods return, in the order they document. Every decision in
//! between (which tiles to render next, when to ask for more, which volume step a batch needs,
//! which display to give up on, when to beat, what a present shows, what to report) is taken
//! here, so a test runs a whole session on a virtual clock.

pub mod display;
pub mod render;

#[cfg(test)]
mod display_tests;
#[cfg(test)]
mod render_tests;

use std::time::{Duration, Instant};
use tessera_protocol::HEARTBEAT_INTERVAL;

/// When a node says it is alive next: at once when its session starts, then every
/// [`HEARTBEAT_INTERVAL`] after the last beat went out.
///
/// The master declares a node silent past its deadline dead, so the driver beats whatever
/// the render threads, the window or the tiles are doing; a driver loop that hangs stops
/// beating, and is dead too. A beat that fires late (past [`Heartbeat::LATE`]) pushes the next
/// one back rather than sending a burst to catch up: a burst says nothing one beat does not.
/// (tokio's `MissedTickBehavior::Delay`, which the drivers used before this was theirs.)
#[derive(Clone, Copy, Debug)]
struct Heartbeat {
    next: Instant,
}

impl Heartbeat {
    /// How late a beat may fire and keep the beats after it on their schedule.
    const LATE: Duration = Duration::from_millis(5);

    fn new(now: Instant) -> Self {
        Heartbeat { next: now }
    }

    fn deadline(&self) -> Instant {
        self.next
    }

    /// Whether a beat is due at `now`; if so, the next one is an interval later.
    fn fire(&mut self, now: Instant) -> bool {
        if now < self.next {
            return false;
        }
        let from = if now > self.next + Self::LATE {
            now
        } else {
            self.next
        };
        self.next = from + HEARTBEAT_INTERVAL;
        true
    }
}
