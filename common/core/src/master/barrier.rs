//! The coordinator's outputs carried out: messages to the render nodes and displays, present
//! deadlines on each display's clock, a rejoined display shown only its own frames, the
//! figures of each frame, and the end of the run.

use super::*;
use crate::balance::Output;

impl Master {
    /// Carries out everything the coordinator has to say.
    pub(super) fn pump(&mut self, now: Now) {
        while let Some(out) = self.coordinator.poll_output() {
            if self.phase == Phase::Done {
                return;
            }
            self.carry_out(out, now);
        }
    }

    fn carry_out(&mut self, out: Output, now: Now) {
        match out {
            Output::ToRender(node, msg) => {
                if let Some(&peer) = self.renders.get(&node) {
                    self.send(peer, msg);
                }
            }
            Output::ToDisplays(ToNode::Present { frame }) => self.present(frame, now),
            Output::ToDisplays(msg) => self.send_to_displays(msg),
            Output::FrameStarted(frame) => {
                self.record.frame_started.insert(frame, now.instant);
                self.record.timing.frame_started(frame, now.unix_ns);
                self.playing_frame_started(now);
            }
            Output::FramePresented(frame) => {
                self.presented(frame, now);
                self.rendering_paused(now);
            }
            Output::FrameCancelled {
                frame,
                ran,
                usual,
                refinement,
            } => self.cancelled(frame, ran, usual, refinement),
            Output::FrameRendered(frame) => {
                self.events.push_back(MasterEvent::FrameRendered(frame))
            }
            Output::StateApplied {
                frame,
                changes,
                wall,
                stamps,
                ..
            } => {
                self.record.changes_applied += changes;
                self.frame_state = wall;
                self.record.timing.inputs_applied(frame, &stamps);
            }
            Output::Converged(frame) => {
                tracing::info!(
                    "frame {} is at the final quality; nothing renders until something changes",
                    frame.0
                );
                self.converged_at(frame);
            }
            Output::Refused { frame, error } => {
                tracing::warn!(
                    "a change replayed at frame {} was refused: {error}",
                    frame.0
                )
            }
            Output::Finished => self.shut_down(now),
            Output::DisplayTimedOut { display, silent } => {
                if let Some(&peer) = self.displays.get(&display) {
                    self.drop_silent(peer, silent, now);
                }
            }
            Output::DisplayNotBack { display, waited } => {
                self.fail(RunError::DisplayNotBack { display, waited })
            }
            Output::RenderTimedOut { node, silent } => {
                if let Some(&peer) = self.renders.get(&node) {
                    self.drop_silent(peer, silent, now);
                }
            }
            Output::Stalled => self.fail(RunError::Stalled),
            Output::RenderSuspected { .. }
            | Output::DisplaySuspected { .. }
            | Output::RenderBack { .. }
            | Output::DisplayBack { .. } => self.suspicion(&out),
        }
    }

    /// A message for every display; a frame start is also the frame shown next.
    fn send_to_displays(&mut self, msg: ToNode) {
        if let ToNode::FrameStart(start) = msg {
            self.live.last_start = Some(start);
            let started = Box::new((start, self.frame_state));
            self.events.push_back(MasterEvent::FrameStarted(started));
            self.note_session_line(start);
        }
        let peers: Vec<PeerId> = self.displays.values().copied().collect();
        for peer in peers {
            self.send(peer, msg.clone());
        }
    }

    /// The barrier let `frame` be presented: each display that shows it is told when, on its
    /// own clock, or to present on arrival when the run has no margin.
    fn present(&mut self, frame: FrameId, now: Now) {
        let margin = self.cfg.present_margin;
        let at = now.unix_ns + margin.as_nanos() as u64;
        let shown: Vec<(DisplayId, PeerId)> = self
            .displays
            .iter()
            // A rejoined display never saw the frames before its first: not theirs to show.
            .filter(|(d, _)| self.display_since.get(d).is_none_or(|&f| frame >= f))
            .map(|(&d, &p)| (d, p))
            .collect();
        for (d, peer) in shown {
            let msg = if margin.is_zero() {
                ToNode::Present { frame }
            } else {
                let clock_ns = (at as i64 + self.record.timing.offset(d)) as u64;
                ToNode::PresentAt { frame, clock_ns }
            };
            self.send(peer, msg);
        }
    }

    fn presented(&mut self, frame: FrameId, now: Now) {
        self.record.presents.push((frame, now.instant));
        let shown_by = |d: &DisplayId| {
            self.displays.contains_key(d) && self.display_since.get(d).is_none_or(|&f| frame >= f)
        };
        if !(0..self.cfg.wall.display_count()).all(|d| shown_by(&DisplayId(d))) {
            self.record.frames_short_of_displays += 1;
        }
        self.events.push_back(MasterEvent::FramePresented(frame));
    }

    /// A frame was abandoned in flight: counted, and said.
    fn cancelled(&mut self, frame: FrameId, ran: Duration, usual: Option<Duration>, pass: bool) {
        self.record.frame_started.remove(&frame);
        if pass {
            // Stale refinement passes are dropped as a matter of course: nothing to warn of.
            tracing::debug!("refinement pass {} dropped for a change", frame.0);
            self.record.refinement_passes_dropped += 1;
            return;
        }
        self.record.frames_cancelled += 1;
        let usual = usual.map_or("none shown yet".to_string(), |u| {
            format!("{} ms", u.as_millis())
        });
        tracing::warn!(
            "frame {} cancelled after {} ms (recent frames: {usual}): no display shows it; the next frame starts with the newest state",
            frame.0,
            ran.as_millis()
        );
    }
}
