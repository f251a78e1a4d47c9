//! Failures, by the coordinator's own clock or as the driver reports them: heartbeats and
//! their deadlines (render nodes and displays), and a display that is gone.

use super::*;

impl Coordinator {
    /// `node` said it is alive.
    ///
    /// # Errors
    /// A node that is not (or no longer) part of the run.
    pub fn handle_heartbeat(
        &mut self,
        node: RenderNodeId,
        now: Instant,
    ) -> Result<(), BalanceError> {
        if !self.nodes.contains_key(&node) {
            return Err(BalanceError::UnknownNode(node));
        }
        self.heard_render(node, now);
        Ok(())
    }

    /// `node` said something: a suspected node is back.
    pub(super) fn heard_render(&mut self, node: RenderNodeId, now: Instant) {
        if let Some(silent) = self.liveness.heard(node, now) {
            self.outputs.push_back(Output::RenderBack { node, silent });
        }
    }

    /// `display` said something: a suspected display is back.
    pub(super) fn heard_display(&mut self, display: DisplayId, now: Instant) {
        if let Some(silent) = self.display_liveness.heard(display, now) {
            self.outputs
                .push_back(Output::DisplayBack { display, silent });
        }
    }

    /// The render nodes suspected now (silent past the deadline, not yet dead).
    pub fn suspected_render_nodes(&self) -> impl Iterator<Item = RenderNodeId> + '_ {
        self.liveness.suspected()
    }

    /// The master did not run for `blind` until `now` (its process was stopped, or starved):
    /// silence in that time counts against nobody.
    pub fn credit_blind_time(&mut self, blind: Duration, now: Instant) {
        self.liveness.credit(blind, now);
        self.display_liveness.credit(blind, now);
    }

    /// When [`Coordinator::handle_timeout`] is next due (`None`: nothing is timed, as once
    /// the run is finished): a node's deadline, or a late node's lease that an idle node
    /// could take over.
    pub fn poll_timeout(&self) -> Option<Instant> {
        if self.is_finished() {
            return None;
        }
        [
            self.liveness.next_deadline(),
            self.display_liveness.next_deadline(),
            self.next_speculation(),
            self.next_wait_end(),
            self.next_cancel(),
        ]
        .into_iter()
        .flatten()
        .min()
    }

    /// Time passed: nodes silent past the deadline are suspected (a render node's tiles are
    /// copied to idle nodes at once), nodes silent past what their rhythm allows are gone, as
    /// if they had left, and idle nodes get copies of the tiles of nodes late past their lease.
    pub fn handle_timeout(&mut self, now: Instant) {
        let renders = self.liveness.expired(now);
        for (node, silent) in renders.suspected {
            self.outputs
                .push_back(Output::RenderSuspected { node, silent });
        }
        for (node, silent) in renders.dead {
            self.outputs
                .push_back(Output::RenderTimedOut { node, silent });
            self.handle_render_left(node, now);
        }
        let displays = self.display_liveness.expired(now);
        for (display, silent) in displays.suspected {
            self.outputs
                .push_back(Output::DisplaySuspected { display, silent });
        }
        for (display, silent) in displays.dead {
            self.outputs
                .push_back(Output::DisplayTimedOut { display, silent });
            self.handle_display_left(display, now);
        }
        if let Some(limit) = self.config.wait_for_lost_displays {
            let over: Vec<(DisplayId, Duration)> = self
                .awaited_displays
                .iter()
                .map(|(&d, &since)| (d, now.saturating_duration_since(since)))
                .filter(|&(_, waited)| waited >= limit)
                .collect();
            for (display, waited) in over {
                self.awaited_displays.remove(&display);
                self.outputs
                    .push_back(Output::DisplayNotBack { display, waited });
            }
        }
        self.feed_speculation(now);
        self.cancel_runaways(now);
    }

    /// When the wait for the display lost first runs out.
    fn next_wait_end(&self) -> Option<Instant> {
        let limit = self.config.wait_for_lost_displays?;
        self.awaited_displays.values().min().map(|&t| t + limit)
    }

    /// The lost displays the wall waits for before it starts another frame.
    pub fn awaited_displays(&self) -> impl Iterator<Item = DisplayId> + '_ {
        self.awaited_displays.keys().copied()
    }

    /// Which display each tile is on (`tiles[t]` for tile `t`), so that a display's loss
    /// also settles its tiles: nobody renders what nobody will show. Without it a lost
    /// display's tiles are still rendered and delivered to no one.
    pub fn set_tile_displays(&mut self, tiles: Vec<DisplayId>) {
        if tiles.len() == self.tile_count as usize {
            self.tile_displays = tiles;
        }
    }

    /// The displays the swap barrier waits for.
    pub fn live_displays(&self) -> impl Iterator<Item = DisplayId> + '_ {
        self.live_displays.iter().copied()
    }

    /// Display `display` is gone (its connection closed, or it was silent past the deadline):
    /// the barrier stops waiting for it and its tiles are settled in every frame in flight,
    /// so the other displays present those. Then the others go on, or, under
    /// [`BalanceConfig::wait_for_lost_displays`], no frame starts until it rejoins.
    pub fn handle_display_left(&mut self, display: DisplayId, now: Instant) {
        if !self.live_displays.remove(&display) {
            return;
        }
        if self.config.wait_for_lost_displays.is_some() {
            self.awaited_displays.insert(display, now);
        }
        self.display_liveness.forget(display);
        let gone = self.tiles_of(display);
        for frame in self.in_flight.values_mut() {
            frame.drop_tiles(&gone);
            frame.displays_complete.remove(&display);
            // For good: if it rejoins, it starts with a later frame, never with these.
            frame.displays_expected.remove(&display);
        }
        // Waiting, the frames in flight settle with no display left, and the wall waits.
        let waiting = !self.awaited_displays.is_empty();
        if self.live_displays.is_empty() && !self.in_flight.is_empty() && !waiting {
            self.outputs.push_back(Output::Stalled);
        }
        self.try_present(now);
        self.try_start_frames(now);
    }

    /// Display `display` is back (a restarted display rejoined): frames that start from now
    /// on include it and its tiles; frames in flight go on without it. A wall that waited for
    /// it goes on.
    pub fn handle_display_joined(&mut self, display: DisplayId, now: Instant) {
        if display.0 < self.display_count && self.live_displays.insert(display) {
            self.heard_display(display, now);
        }
        if self.awaited_displays.remove(&display).is_some() {
            self.try_start_frames(now);
        }
    }

    /// `node` could not deliver `tiles` of `frame` (their display was unreachable): they are
    /// rendered again, by whichever node asks next.
    ///
    /// # Errors
    /// A node not part of the run.
    pub fn handle_tiles_returned(
        &mut self,
        node: RenderNodeId,
        frame: FrameId,
        tiles: &[TileRange],
        now: Instant,
    ) -> Result<(), BalanceError> {
        if !self.nodes.contains_key(&node) {
            return Err(BalanceError::UnknownNode(node));
        }
        self.heard_render(node, now);
        if let Some(state) = self.in_flight.get_mut(&frame) {
            let in_range = |t: &TileId| t.0 < self.tile_count;
            state.give_back(node, tiles.iter().flat_map(|r| r.tiles()).filter(in_range));
        }
        self.feed_waiting(now);
        self.try_start_frames(now);
        Ok(())
    }

    /// `display` said it is alive (a display's heartbeat).
    pub fn handle_display_heartbeat(&mut self, display: DisplayId, now: Instant) {
        if self.live_displays.contains(&display) {
            self.heard_display(display, now);
        }
    }

    pub(super) fn tiles_of(&self, display: DisplayId) -> Vec<TileId> {
        self.tile_displays
            .iter()
            .enumerate()
            .filter(|(_, d)| **d == display)
            .map(|(t, _)| TileId(t as u32))
            .collect()
    }

    /// Sets how many frames the run has in all (`None`: until stopped).
    pub fn set_frame_limit(&mut self, limit: Option<u64>) {
        self.frame_limit = limit;
    }

    /// Stops starting new frames; frames in flight still finish, for at most
    /// [`cancel::INTERRUPT_GRACE`] after `now`, and are cancelled then.
    pub fn interrupt(&mut self, now: Instant) {
        self.interrupted_at.get_or_insert(now);
        self.stop_after_in_flight();
    }

    /// Stops starting new frames; frames in flight still finish.
    pub fn stop_after_in_flight(&mut self) {
        self.frame_limit = Some(self.next_frame.0);
        if self.is_finished() {
            self.outputs.push_back(Output::Finished);
        }
    }
}
