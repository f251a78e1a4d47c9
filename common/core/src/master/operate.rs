//! What an operator's console adds to the control interface: the wall's status at a glance,
//! a time series' playback on its own clock, snapshots of a still wall and at the final
//! quality (announced once every display wrote its files), window input from elsewhere than a
//! window, and the displays' thumbnails that picture the wall.

use super::*;
use tessera_model::input::InputEvent;
use tessera_protocol::control::{
    ControlReply, ControlRequest, Playback, SeriesStatus, WallStatus, PLAYBACK_SPEEDS,
};
use tessera_protocol::{Thumbnail, MAX_THUMBNAIL_BYTES, MAX_THUMBNAIL_FACTOR};

/// What the master knows of the scene for its operators, besides what it renders.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct OperatorConfig {
    /// Steps of the scene's time series; `None` without one.
    pub series_steps: Option<u32>,
    /// Whether the series plays from the start (`--play`).
    pub play: bool,
    /// The volume's smallest and largest value, where the scene has a volume.
    pub volume_range: Option<[f32; 2]>,
    /// The particles' attribute range, where the scene has particles.
    pub particle_range: Option<[f32; 2]>,
    /// Widest the console's picture of the whole wall is, in pixels.
    pub picture_width: u32,
}

/// The live side of [`OperatorConfig`].
#[derive(Debug, Default)]
pub(super) struct Operating {
    /// Whether the series plays.
    pub(super) playing: bool,
    /// Steps per second while playing; `None`: a step each frame.
    pub(super) steps_per_second: Option<f32>,
    /// When the next step is due, while playing at a speed.
    next_step_at: Option<Instant>,
    /// A snapshot at the final quality waits for the wall to converge.
    final_snapshot_waits: bool,
    /// Snapshots whose files some displays have not yet said they wrote.
    saving: BTreeMap<FrameId, Vec<(DisplayId, Option<bool>)>>,
    /// Control clients' snapshot requests, answered once the files are written: the client,
    /// its request's id, and the frame (`None`: the final-quality frame to come).
    deferred: Vec<(PeerId, u32, Option<FrameId>, ControlReply)>,
    /// The frame a snapshot at the final quality was taken of, once the wall converged.
    final_frame: Option<FrameId>,
    /// When frames began to be in flight, while they are.
    busy_since: Option<Instant>,
    /// Time spent rendering before `busy_since`.
    pub(super) rendering: Duration,
}

/// An event of the console's side of the run, for the driver.
#[derive(Clone, Debug, PartialEq)]
pub enum ConsoleEvent {
    /// Every display that was asked wrote (or failed to write) its files of this snapshot.
    SnapshotSaved {
        /// The frame the files are of.
        frame: FrameId,
        /// Each display asked, and whether it wrote its file.
        displays: Vec<(DisplayId, bool)>,
    },
    /// A display's thumbnail (see [`Master::ask_thumbnails`]).
    Thumbnail(DisplayId, Thumbnail),
}

impl Operating {
    pub(super) fn new(cfg: &OperatorConfig) -> Operating {
        Operating {
            playing: cfg.play && cfg.series_steps.is_some(),
            ..Operating::default()
        }
    }
}

impl Master {
    /// Answers a request of the master's own process (its console), stamped now.
    pub fn handle_local_control(&mut self, request: ControlRequest, now: Now) -> ControlReply {
        let reply = self
            .answer(request, now.unix_ns, now)
            .unwrap_or_else(ControlReply::Refused);
        self.pump(now);
        reply
    }

    /// Asks every display for a thumbnail of what it shows (they come back as
    /// [`ConsoleEvent::Thumbnail`]), shrunk so that the whole wall is at most
    /// [`OperatorConfig::picture_width`] wide and each thumbnail within its bound.
    pub fn ask_thumbnails(&mut self) {
        let factor = self.thumbnail_factor();
        let displays: Vec<PeerId> = self.displays.values().copied().collect();
        for peer in displays {
            self.send(peer, ToNode::SendThumbnail { factor });
        }
    }

    /// Screen pixels per thumbnail pixel: the wall within the picture's width, every screen
    /// within the thumbnail's bytes.
    pub fn thumbnail_factor(&self) -> u32 {
        let wall = &self.cfg.wall;
        let width = self.cfg.operator.picture_width.max(1);
        let mut factor = wall.width().div_ceil(width).max(1);
        let largest = wall
            .screens()
            .map(|s| s.width as u64 * s.height as u64)
            .max()
            .unwrap_or(0);
        while largest * 3 / (factor as u64 * factor as u64) > MAX_THUMBNAIL_BYTES as u64 {
            factor += 1;
        }
        factor.min(MAX_THUMBNAIL_FACTOR)
    }

    /// The next console event, if any.
    pub fn poll_console(&mut self) -> Option<ConsoleEvent> {
        self.console_events.pop_front()
    }

    pub(super) fn thumbnail(&mut self, display: DisplayId, thumbnail: Thumbnail) {
        if self.console_events.len() < 64 {
            self.console_events
                .push_back(ConsoleEvent::Thumbnail(display, thumbnail));
        }
    }

    pub(super) fn status(&self) -> WallStatus {
        let (id, _) = self.coordinator.state();
        let op = &self.cfg.operator;
        WallStatus {
            frame: self.live.last_start.map_or(0, |s| s.frame.0),
            state_id: id,
            state: self.coordinator.next_state(),
            converged: self.coordinator.is_converged(),
            overlay: self.live.overlay,
            views: self.view_names(),
            series: op.series_steps.map(|steps| SeriesStatus {
                steps,
                playing: self.operating.playing,
                steps_per_second: self.operating.steps_per_second,
            }),
            volume_range: op.volume_range,
            particle_range: op.particle_range,
        }
    }

    /// A fixed camera that frames the scene's bounding sphere (around the pivot, of radius
    /// the scene's size) in the wall's vertical field of view, seen from the direction the
    /// camera looks from now.
    pub(super) fn fit_camera(&self) -> CameraMode {
        let frame = self.live.last_start.map_or(0, |s| s.frame.0);
        let now = self.current_camera().camera_for_frame(frame);
        CameraMode::fixed(self.navigator.fit(&now).unwrap_or(now))
    }

    /// `node` rendered `tiles`: the console's heatmap says so. Tile ids were checked by the
    /// coordinator against the grid before this.
    pub(super) fn note_tile_owners(
        &mut self,
        node: RenderNodeId,
        tiles: &[tessera_protocol::TileRange],
    ) {
        let owners = &mut self.live.tile_owners;
        for range in tiles {
            if owners.len() < range.end() as usize {
                owners.resize(range.end() as usize, tessera_protocol::control::NO_OWNER);
            }
            owners[range.start() as usize..range.end() as usize].fill(node.0);
        }
    }

    /// A recorded session replayed from the next frame on: each state lands on the frame
    /// its offset says, as a session replayed from the start would.
    pub(super) fn replay(
        &mut self,
        states: Vec<(u64, WallState)>,
    ) -> Result<ControlReply, Refusal> {
        if states.len() > tessera_protocol::control::MAX_REPLAYED {
            return Err(Refusal::ReplayTooLong);
        }
        let first = self.coordinator.next_frame().0;
        for (offset, state) in states {
            let frame = FrameId(first.saturating_add(offset));
            // The next frame or later: never a frame already started.
            let _ = self
                .coordinator
                .schedule_change(frame, StateChange::All(state));
        }
        Ok(ControlReply::Done)
    }

    /// A console's window input: what the navigator makes of it, queued like a command.
    pub(super) fn input_request(
        &mut self,
        event: InputEvent,
        stamp: u64,
        now: Now,
    ) -> Result<ControlReply, Refusal> {
        use navigate::NavAction;
        if matches!(event, InputEvent::Click { .. }) {
            return Err(Refusal::BadInput(
                "a click probes: ask a probe of the pixel instead".into(),
            ));
        }
        let frame = self.live.last_start.map_or(0, |s| s.frame.0);
        let camera = self.current_camera().camera_for_frame(frame);
        let params = self.coordinator.next_state().params;
        match self.navigator.handle(&event, &camera, &params, now.instant) {
            Some(NavAction::Change(change)) => self.queue_all(&[change], stamp, now),
            Some(NavAction::ToggleOverlay) => {
                self.set_overlay(!self.live.overlay);
                Ok(ControlReply::Done)
            }
            Some(NavAction::Probe { .. }) | None => Ok(ControlReply::Done),
        }
    }

    pub(super) fn playback(
        &mut self,
        playback: Playback,
        stamp: u64,
        now: Now,
    ) -> Result<ControlReply, Refusal> {
        let steps = self.cfg.operator.series_steps.ok_or(Refusal::NoSeries)?;
        if let Some(speed) = playback.steps_per_second {
            if !PLAYBACK_SPEEDS.contains(&speed) {
                return Err(Refusal::BadSpeed(speed));
            }
        }
        let mut reply = ControlReply::Done;
        if let Some(by) = playback.step_by {
            let mut volume = *self.coordinator.next_state().params.volume();
            let at = (volume.time_step as i64 + by as i64).rem_euclid(steps.max(1) as i64);
            volume.time_step = at as u32;
            reply = self.queue_all(&[StateChange::Volume(volume)], stamp, now)?;
            self.operating.playing = false;
        }
        if let Some(speed) = playback.steps_per_second {
            self.operating.steps_per_second = Some(speed);
        }
        if let Some(playing) = playback.playing {
            self.operating.playing = playing;
        }
        self.operating.next_step_at =
            match (self.operating.playing, self.operating.steps_per_second) {
                (true, Some(speed)) => Some(now.instant + Duration::from_secs_f32(1.0 / speed)),
                _ => None,
            };
        // A still wall starts no frame, so a series played a step a frame needs a first push.
        if self.operating.playing && self.operating.steps_per_second.is_none() {
            self.advance_time_step(steps, now);
        }
        Ok(reply)
    }

    /// A frame started: a series played a step a frame moves on.
    pub(super) fn playing_frame_started(&mut self, now: Now) {
        if let (true, None, Some(steps)) = (
            self.operating.playing,
            self.operating.steps_per_second,
            self.cfg.operator.series_steps,
        ) {
            self.advance_time_step(steps, now);
        }
        self.operating.busy_since.get_or_insert(now.instant);
    }

    /// A frame was presented: the time since frames began to be in flight counts as rendering
    /// once none is.
    pub(super) fn rendering_paused(&mut self, now: Now) {
        if self.coordinator.frames_in_flight() == 0 {
            if let Some(since) = self.operating.busy_since.take() {
                self.operating.rendering += now.instant.saturating_duration_since(since);
            }
        }
    }

    /// Time spent rendering so far.
    pub(super) fn rendering_time(&self, now: Instant) -> Duration {
        let open = self
            .operating
            .busy_since
            .map_or(Duration::ZERO, |s| now.saturating_duration_since(s));
        self.operating.rendering + open
    }

    /// When a series played at a speed takes its next step.
    pub(super) fn series_timer(&self) -> Option<Instant> {
        self.operating.next_step_at
    }

    /// Takes a series' step that is due.
    pub(super) fn series_timeout(&mut self, now: Now) {
        let (Some(at), Some(steps), Some(speed)) = (
            self.operating.next_step_at,
            self.cfg.operator.series_steps,
            self.operating.steps_per_second,
        ) else {
            return;
        };
        if now.instant >= at {
            self.advance_time_step(steps, now);
            let period = Duration::from_secs_f32(1.0 / speed);
            // A wall slower than the speed skips ahead rather than owing steps.
            let next = (at + period).max(now.instant + period / 2);
            self.operating.next_step_at = Some(next);
        }
    }

    /// A snapshot: the frame shown now on a still wall, the final frame once it comes, or
    /// the next frame to start.
    pub(super) fn snapshot(&mut self, final_quality: bool) -> Result<ControlReply, Refusal> {
        let converged = self.coordinator.is_converged();
        if final_quality && !converged {
            if self
                .coordinator
                .next_state()
                .camera
                .fixed_camera()
                .is_none()
            {
                return Err(Refusal::NeverStill);
            }
            // Without refinement every frame is at the final quality: the next one will do.
            if self.cfg.refinement.is_some() {
                self.operating.final_snapshot_waits = true;
                return Ok(ControlReply::Snapshot {
                    frame: self.coordinator.next_frame().0,
                    shown: false,
                });
            }
        }
        let presented = self.coordinator.presented();
        if converged && self.coordinator.frames_in_flight() == 0 && presented > 0 {
            let frame = FrameId(presented - 1);
            self.save_frame(frame, |frame| ToNode::SaveShown { frame });
            return Ok(ControlReply::Snapshot {
                frame: frame.0,
                shown: true,
            });
        }
        // The final pass in flight, or a frame to come.
        let next = self.coordinator.next_frame();
        let frame = if converged && next.0 > 0 {
            FrameId(next.0 - 1)
        } else {
            next
        };
        self.save_frame(frame, |frame| ToNode::SaveFrame { frame });
        Ok(ControlReply::Snapshot {
            frame: frame.0,
            shown: false,
        })
    }

    /// Answers a control client's snapshot once its files are written (see
    /// [`ConsoleEvent::SnapshotSaved`]) rather than at once, so that what it prints exists.
    pub(super) fn defer_snapshot_reply(&mut self, peer: PeerId, id: u32, reply: ControlReply) {
        let waits_for_final = self.operating.final_snapshot_waits;
        let frame = match reply {
            ControlReply::Snapshot { frame, .. } if !waits_for_final => Some(FrameId(frame)),
            _ => None,
        };
        self.operating.deferred.push((peer, id, frame, reply));
    }

    /// The wall converged at `frame`: a snapshot waiting for the final quality takes it.
    pub(super) fn converged_at(&mut self, frame: FrameId) {
        if std::mem::take(&mut self.operating.final_snapshot_waits) {
            self.operating.final_frame = Some(frame);
            self.save_frame(frame, |frame| ToNode::SaveFrame { frame });
        }
    }

    fn save_frame(&mut self, frame: FrameId, msg: impl Fn(FrameId) -> ToNode) {
        self.live.snapshots.push(frame);
        let displays: Vec<(DisplayId, PeerId)> =
            self.displays.iter().map(|(&d, &p)| (d, p)).collect();
        for &(_, peer) in &displays {
            self.send(peer, msg(frame));
        }
        let waiting = displays.iter().map(|&(d, _)| (d, None)).collect();
        self.operating.saving.insert(frame, waiting);
    }

    /// Display `display` wrote (or not) its files of `frame`'s snapshot.
    pub(super) fn display_saved(&mut self, display: DisplayId, frame: FrameId, ok: bool) {
        let shown = display.0;
        tracing::debug!("display {shown} saved frame {} ({ok})", frame.0);
        let Some(waiting) = self.operating.saving.get_mut(&frame) else {
            return;
        };
        for (d, saved) in waiting.iter_mut() {
            if *d == display {
                *saved = Some(ok);
            }
        }
        self.snapshot_done_if_all(frame);
    }

    /// Answers the control clients waiting for `frame`'s files.
    fn answer_deferred(&mut self, frame: FrameId) {
        let is_final = self.operating.final_frame == Some(frame);
        let (ready, waiting): (Vec<_>, Vec<_>) = std::mem::take(&mut self.operating.deferred)
            .into_iter()
            .partition(|(_, _, f, _)| *f == Some(frame) || f.is_none() && is_final);
        self.operating.deferred = waiting;
        for (peer, id, _, reply) in ready {
            let reply = match reply {
                ControlReply::Snapshot { shown, .. } => ControlReply::Snapshot {
                    frame: frame.0,
                    shown,
                },
                other => other,
            };
            self.send(peer, ToNode::ControlReply { id, reply });
        }
    }

    /// A display left: its snapshots will not come.
    pub(super) fn display_gone_from_snapshots(&mut self, display: DisplayId) {
        let frames: Vec<FrameId> = self.operating.saving.keys().copied().collect();
        for frame in frames {
            if let Some(waiting) = self.operating.saving.get_mut(&frame) {
                for (d, saved) in waiting.iter_mut() {
                    if *d == display && saved.is_none() {
                        *saved = Some(false);
                    }
                }
            }
            self.snapshot_done_if_all(frame);
        }
    }

    fn snapshot_done_if_all(&mut self, frame: FrameId) {
        let done = self
            .operating
            .saving
            .get(&frame)
            .is_some_and(|w| w.iter().all(|(_, s)| s.is_some()));
        if !done {
            return;
        }
        if let Some(waiting) = self.operating.saving.remove(&frame) {
            tracing::info!("snapshot of frame {}: every display answered", frame.0);
            self.answer_deferred(frame);
            let displays = waiting
                .into_iter()
                .map(|(d, s)| (d, s.unwrap_or(false)))
                .collect();
            self.console_events
                .push_back(ConsoleEvent::SnapshotSaved { frame, displays });
        }
    }
}
