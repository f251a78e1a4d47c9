//! The primary's side of a standby (its snapshot, the replicas it sends, the horizon it keeps
//! to), a master that takes a run over from a snapshot, and a stale master stepping down.
//! See [`super::standby`] for the protocol.

use super::figures::{Figures, RunSamples};
use super::report::Takeover;
use super::standby::{
    RankHolder, Replica, ReplicaAck, SessionLine, REPLICA_HORIZON, SAMPLES_EVERY,
};
use super::*;
use tessera_model::state::StateId;
use tessera_protocol::FrameStart;

/// What the attached standby has been sent.
pub(super) struct Replication {
    /// The last snapshot sent, without its session lines and distributions.
    sent: MasterSnapshot,
    /// Session lines sent.
    lines_sent: usize,
    /// The distributions as last refreshed, and the frames presented then.
    samples: RunSamples,
    samples_at: u64,
    /// Whether they were refreshed since the last replica.
    samples_fresh: bool,
    /// The horizon the standby acknowledged last: no frame starts at or past it.
    acked: FrameId,
}

/// The figures of the masters before this one.
pub(super) struct Prior {
    pub(super) figures: Figures,
    pub(super) samples: RunSamples,
}

use super::standby::MasterSnapshot;

impl Master {
    /// This master's term: 0 for the first master of a run, one more at each takeover. Its
    /// welcomes carry it.
    pub fn term(&self) -> u64 {
        self.term
    }

    /// The session record so far: a line each time a frame started with another state.
    pub fn session_lines(&self) -> &[SessionLine] {
        &self.session
    }

    /// Everything a standby needs to take the run over now (see [`MasterSnapshot`]). Its
    /// distributions are those last sent to the attached standby, else computed now (in
    /// time proportional to the frames so far).
    pub fn standby_snapshot(&self) -> MasterSnapshot {
        let mut snapshot = self.snapshot_core();
        snapshot.session = self.session.clone();
        snapshot.samples = match &self.replication {
            Some(r) => r.samples.clone(),
            None => self.samples_so_far(),
        };
        snapshot
    }

    /// The snapshot without its session lines and distributions: the cheap part.
    fn snapshot_core(&self) -> MasterSnapshot {
        let (state_id, state) = self.coordinator.state();
        let next_frame = self.coordinator.next_frame();
        let ranks = self
            .ranks
            .held()
            .into_iter()
            .map(|(rank, node, addr)| RankHolder {
                rank,
                host: self
                    .renders
                    .get(&node)
                    .and_then(|p| self.peers.get(p))
                    .map_or_else(String::new, |p| p.host.clone()),
                addr,
            })
            .collect();
        MasterSnapshot {
            term: self.term,
            state_id,
            state,
            next_state: self.coordinator.next_state(),
            next_frame,
            horizon: FrameId(next_frame.0 + REPLICA_HORIZON),
            frame_limit: self.cfg.frames,
            views: self.live.views.clone(),
            overlay: self.live.overlay,
            playing: (self.operating.playing, self.operating.steps_per_second),
            ranks,
            figures: self.figures_so_far(),
            samples: RunSamples::default(),
            session: Vec::new(),
            takeovers: self.takeovers.clone(),
        }
    }

    /// A standby's connection is up: send it this whole replica. From now on the master
    /// runs no further than the horizon its standby acknowledged (see
    /// [`Master::handle_replica_ack`]), and [`Master::poll_replica`] gives what to send it.
    /// One standby at a time: attaching another replaces the first.
    pub fn attach_standby(&mut self, now: Now) -> Replica {
        let samples = self.samples_so_far();
        let sent = self.snapshot_core();
        // A standby that never got this replica cannot take over, so running up to its
        // horizon before the acknowledgement is safe.
        let acked = sent.horizon;
        self.replication = Some(Replication {
            sent,
            lines_sent: self.session.len(),
            samples,
            samples_at: self.frames_presented(),
            samples_fresh: false,
            acked,
        });
        self.coordinator.set_frame_horizon(Some(acked), now.instant);
        self.pump(now);
        Replica::whole(self.standby_snapshot())
    }

    /// The standby's connection closed: the master runs on without a horizon.
    pub fn detach_standby(&mut self, now: Now) {
        if self.replication.take().is_some() {
            tracing::warn!("the standby master is gone; the wall runs on without one");
            self.coordinator.set_frame_horizon(None, now.instant);
            self.pump(now);
        }
    }

    /// The standby holds the snapshot with this horizon: frames before it may start.
    pub fn handle_replica_ack(&mut self, ack: ReplicaAck, now: Now) {
        let Some(r) = &mut self.replication else {
            return;
        };
        if ack.horizon > r.acked {
            r.acked = ack.horizon;
            self.coordinator
                .set_frame_horizon(Some(ack.horizon), now.instant);
            self.pump(now);
        }
    }

    /// What to send the attached standby, if the snapshot changed since the last replica:
    /// the new session lines only, and the distributions only when refreshed (every
    /// [`SAMPLES_EVERY`] presents, and when the frames are over). Poll it after each
    /// `handle_*` call, before sending the transmits.
    pub fn poll_replica(&mut self) -> Option<Replica> {
        let presented = self.frames_presented();
        let due = self.replication.as_ref().is_some_and(|r| {
            presented >= r.samples_at + SAMPLES_EVERY
                || self.frames_over() && presented > r.samples_at
        });
        let fresh = due.then(|| self.samples_so_far());
        let core = self.snapshot_core();
        let lines = self.session.len();
        let r = self.replication.as_mut()?;
        if let Some(samples) = fresh {
            r.samples = samples;
            r.samples_at = presented;
            r.samples_fresh = true;
        }
        if core == r.sent && lines == r.lines_sent && !r.samples_fresh {
            return None;
        }
        let mut snapshot = core.clone();
        snapshot.session = self.session[r.lines_sent..].to_vec();
        let has_samples = std::mem::take(&mut r.samples_fresh);
        if has_samples {
            snapshot.samples = r.samples.clone();
        }
        let session_from = r.lines_sent as u64;
        r.sent = core;
        r.lines_sent = lines;
        Some(Replica {
            session_from,
            has_samples,
            snapshot,
        })
    }

    /// A master that carries on the run of `snapshot` (see [`super::standby::StandbyEvent`])
    /// as of `now`: term one more than the snapshot's, no nodes yet (they rejoin as at a
    /// start, within the join timeout), the snapshot's views, session and figures. Its first
    /// frame is the snapshot's horizon, with the snapshot's next state under an id past any
    /// the old master can have used, so that no display mixes the two masters' tiles.
    /// `cfg` is the run's configuration as the standby was started with it; its frame limit
    /// is the snapshot's.
    ///
    /// # Errors
    /// As [`Master::new`].
    pub fn take_over(
        mut cfg: MasterConfig,
        snapshot: MasterSnapshot,
        now: Now,
    ) -> Result<Master, MasterError> {
        cfg.frames = snapshot.frame_limit;
        let mut master = Master::new(cfg, now)?;
        let frame = snapshot.horizon.max(snapshot.next_frame);
        // The old master started at most one new state a frame up to the horizon.
        let skipped = frame.0 - snapshot.next_frame.0;
        let state_id = StateId(snapshot.state_id.0 + skipped + 1);
        master
            .coordinator
            .resume(frame, state_id, snapshot.next_state);
        master.frame_state = snapshot.next_state;
        master.term = snapshot.term + 1;
        master.live.views = snapshot.views;
        master.live.overlay = snapshot.overlay;
        (master.operating.playing, master.operating.steps_per_second) = snapshot.playing;
        master.former_ranks = snapshot.ranks;
        master.session = snapshot.session;
        master.prior = Some(Prior {
            figures: snapshot.figures,
            samples: snapshot.samples,
        });
        master.takeovers = snapshot.takeovers;
        master.takeovers.push(Takeover {
            term: master.term,
            frame: frame.0,
            at_unix_ns: now.unix_ns,
            dark_ms: None,
        });
        tracing::warn!(
            "took the wall over as master of term {}: frames resume at {} with state {}",
            master.term,
            frame.0,
            state_id.0
        );
        Ok(master)
    }

    /// How long the wall was dark at this master's takeover, as its driver measured it
    /// (see [`Takeover::dark_ms`]); ignored by a master that took nothing over.
    pub fn record_takeover_dark(&mut self, dark: Duration) {
        let term = self.term;
        if let Some(t) = self.takeovers.last_mut().filter(|t| t.term == term) {
            t.dark_ms = Some(dark.as_secs_f64() * 1000.0);
        }
    }

    /// The dark time of this master's own takeover, as recorded.
    pub(super) fn dark(&self) -> Duration {
        self.takeovers
            .last()
            .filter(|t| t.term == self.term)
            .and_then(|t| t.dark_ms)
            .map_or(Duration::ZERO, |ms| Duration::from_secs_f64(ms / 1000.0))
    }

    /// Frame `start` started: a session line if its state differs from the last line's.
    pub(super) fn note_session_line(&mut self, start: FrameStart) {
        let wall = WallState {
            params: start.params,
            ..self.frame_state
        };
        if self.session.last().is_some_and(|l| l.wall == wall) {
            return;
        }
        self.session.push(SessionLine {
            frame: start.frame,
            state: start.state,
            wall,
            camera_at_frame: start.camera,
        });
    }

    /// A node follows a master of term `seen`: if that is newer than this one's, this master
    /// steps down, closing every connection, and the run ends with
    /// [`RunError::SteppedDown`]; a node that says so of an older term broke the protocol.
    pub(super) fn stale_master(&mut self, peer: PeerId, seen: u64, now: Now) {
        if seen <= self.term {
            let close = CloseReason::ProtocolViolation;
            let why = format!("said term {seen} is newer than this master's {}", self.term);
            tracing::error!("closing {}: {why}", self.describe(peer));
            self.close_and_drop(peer, close, now, &why);
            self.pump(now);
            return;
        }
        tracing::error!(
            "{} follows a master of term {seen}; this master (term {}) steps down",
            self.describe(peer),
            self.term
        );
        let mut peers: Vec<PeerId> = self.peers.keys().copied().collect();
        peers.sort();
        for p in peers {
            self.closes.push_back((p, CloseReason::SteppedDown));
        }
        self.fail(RunError::SteppedDown {
            term: self.term,
            seen,
        });
    }
}
