//! Runaway frames: a frame that a newer state made stale and that runs far longer than the
//! frames before it (a quality setting of 2^18 rays a pixel, asked by mistake) is cancelled,
//! so the correction shows within seconds instead of hours. During ordinary continuous motion
//! every frame is stale by the next one's change too, but runs about as long as the others:
//! those complete and are presented as always. Cancelled frames are never presented, on any
//! display; the barrier moves past them.

use super::*;

/// A stale frame is a runaway once it ran this many times the recent frame time...
pub const RUNAWAY_FACTOR: u32 = 8;
/// ...and at least this long: a scheduler's hiccup never cancels anything.
pub const MIN_RUNAWAY: Duration = Duration::from_secs(1);
/// Before any frame was presented, a stale frame runs this long before it is a runaway.
pub const FIRST_FRAME_RUNAWAY: Duration = Duration::from_secs(5);
/// After an interrupt, frames in flight have this long to finish before they are cancelled.
pub const INTERRUPT_GRACE: Duration = Duration::from_secs(1);

impl Coordinator {
    /// A presented frame's start-to-present time, smoothed into the recent frame time.
    pub(super) fn learn_frame_time(&mut self, frame: &InFlight, now: Instant) {
        let Some(started) = frame.started_at else {
            return;
        };
        let took = now.saturating_duration_since(started);
        self.frame_time = Some(match self.frame_time {
            Some(old) => (old * 3 + took) / 4,
            None => took,
        });
    }

    fn runaway_after(&self) -> Duration {
        self.frame_time.map_or(FIRST_FRAME_RUNAWAY, |t| {
            (t * RUNAWAY_FACTOR).max(MIN_RUNAWAY)
        })
    }

    /// When the frames in flight are to be cancelled, if nothing changes first: the oldest's
    /// runaway limit while a newer state waits, or the end of an interrupt's grace.
    pub(super) fn next_cancel(&self) -> Option<Instant> {
        let oldest = self.in_flight.values().next()?.started_at?;
        let stale = (self.pending_changes > 0).then(|| oldest + self.runaway_after());
        let interrupted = self.interrupted_at.map(|at| at + INTERRUPT_GRACE);
        stale.into_iter().chain(interrupted).min()
    }

    /// Cancels the frames in flight if their time is up (see [`Coordinator::next_cancel`]).
    pub(super) fn cancel_runaways(&mut self, now: Instant) {
        if self.next_cancel().is_some_and(|at| at <= now) {
            self.cancel_in_flight(now, false);
        }
    }

    /// Abandons every frame in flight: render nodes stop them, displays never show them, and
    /// the next frame starts with whatever state waits. `refinement`: they are refinement
    /// passes a change made stale (see `steering`).
    pub(super) fn cancel_in_flight(&mut self, now: Instant, refinement: bool) {
        let Some(&last) = self.in_flight.keys().next_back() else {
            return;
        };
        let usual = self.frame_time;
        for (frame, state) in std::mem::take(&mut self.in_flight) {
            let ran = state
                .started_at
                .map_or(Duration::ZERO, |s| now.saturating_duration_since(s));
            self.outputs.push_back(Output::FrameCancelled {
                frame,
                ran,
                usual,
                refinement,
            });
        }
        let cancel = ToNode::Cancel { frame: last };
        self.outputs.push_back(Output::ToDisplays(cancel.clone()));
        for &node in self.nodes.keys() {
            self.outputs
                .push_back(Output::ToRender(node, cancel.clone()));
        }
        self.next_present = FrameId(last.0 + 1);
        if self.is_finished() {
            self.outputs.push_back(Output::Finished);
        }
        self.try_start_frames(now);
    }
}
