//! Latency while someone steers: a frame started ahead (the second in flight) renders the
//! state of before the next input, so that input waits a whole extra frame behind it. While
//! changes keep coming, the next frame is therefore started only once the one in flight is
//! rendered, unless a change is already waiting (then it starts at once and carries it). A
//! wall nobody steers pipelines two frames as always.
//!
//! And a refinement pass in flight (more samples than the state asks for, many frame times
//! long) is stale the moment something changes: it is cancelled at once, so that the first
//! move after a still view shows within a frame time, not after the pass; the displays keep
//! showing the last frame meanwhile.

use super::*;

/// Changes this close together, in frame times, are someone steering.
const STEERING_FRAMES: u32 = 3;
/// Bounds of that window, whatever the frame time.
const STEERING_MIN: Duration = Duration::from_millis(50);
const STEERING_MAX: Duration = Duration::from_secs(1);
/// The window before any frame was timed.
const STEERING_FIRST: Duration = Duration::from_millis(250);

impl Coordinator {
    /// A change was queued: refinement passes in flight are cancelled, the held frame starts.
    pub(super) fn on_change(&mut self, now: Instant) {
        if self.in_flight.values().any(|f| f.refinement_pass) {
            self.cancel_in_flight(now, true);
        } else {
            self.try_start_frames(now);
        }
    }

    /// Whether the next frame waits for the one in flight to be rendered: someone steers
    /// (a change came within the window) and no change waits to be applied.
    pub(super) fn holds_next_frame(&self, now: Instant) -> bool {
        if self.pending_changes > 0 || !self.config.hold_while_steering {
            return false;
        }
        let window = self.frame_time.map_or(STEERING_FIRST, |t| {
            (t * STEERING_FRAMES).clamp(STEERING_MIN, STEERING_MAX)
        });
        self.last_change_at
            .is_some_and(|at| now.saturating_duration_since(at) < window)
    }
}
