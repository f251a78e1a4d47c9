//! A coordinator that carries on another's run (a standby master taking over), and the
//! horizon that keeps a primary within what its standby knows.

use super::*;

impl Coordinator {
    /// Carries on a run from frame `frame` with state `state` under id `state_id`: the first
    /// frame to start is `frame`, and it renders `state` under `state_id` even if no change
    /// is queued by then. Frames before `frame` count as presented (or abandoned); changes a
    /// replayed session scheduled for them are dropped. Call before [`Coordinator::start`].
    pub fn resume(&mut self, frame: FrameId, state_id: StateId, state: WallState) {
        self.next_frame = frame;
        self.next_present = frame;
        self.state_since = frame;
        self.state = state;
        self.next = state;
        self.state_id = state_id;
        self.converged = false;
        self.scheduled = self.scheduled.split_off(&frame);
    }

    /// No frame at or past `horizon` starts (`None`: no bound). A primary with a standby
    /// runs only as far as the standby acknowledged, so that a standby taking over starts
    /// past every frame the primary can have started. A horizon further on lets the frames
    /// held back start now.
    pub fn set_frame_horizon(&mut self, horizon: Option<FrameId>, now: Instant) {
        self.frame_horizon = horizon;
        self.try_start_frames(now);
    }
}
