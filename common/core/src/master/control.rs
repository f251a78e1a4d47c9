//! The control interface, master side: each request of a control client is answered at once
//! from the master's state, and a change is checked and queued for the next frame barrier,
//! all of it or none. Window input goes through the [`Navigator`] to the same queue.

use super::*;
use tessera_protocol::control::{
    ControlReply, ControlRequest, DisplayFigures, LiveFigures, NodeFigures, ViewName,
};
use tessera_protocol::FrameStart;

/// Most saved views and outstanding snapshots a run keeps: a client asking for more is
/// refused rather than allowed to grow the master's memory.
const MAX_VIEWS: usize = 1000;
const MAX_SNAPSHOTS: usize = 10_000;

/// What the master keeps for the control interface and the displays' overlay.
#[derive(Default)]
pub(super) struct Live {
    /// Saved views, by name.
    pub(super) views: BTreeMap<ViewName, CameraMode>,
    /// Tiles each render node reported done since it joined.
    pub(super) tiles: BTreeMap<RenderNodeId, u64>,
    /// Presents each display reported.
    pub(super) presented: BTreeMap<DisplayId, u64>,
    /// The last frame started, whose camera a saved view keeps.
    pub(super) last_start: Option<FrameStart>,
    pub(super) overlay: bool,
    /// Frames a control client asked the displays to save, for `wall-frame-<K>.png`.
    pub(super) snapshots: Vec<FrameId>,
    /// The render node that last reported each tile done, by tile id.
    pub(super) tile_owners: Vec<u32>,
    /// Each render node's last progress.
    pub(super) progress: BTreeMap<RenderNodeId, tessera_protocol::Progress>,
}

impl Master {
    pub(super) fn handle_control(
        &mut self,
        peer: PeerId,
        id: u32,
        request: ControlRequest,
        stamp_ns: u64,
        now: Now,
    ) {
        let reply = match self.answer(request, stamp_ns, now) {
            Ok(reply) => reply,
            Err(why) => ControlReply::Refused(why),
        };
        if matches!(reply, ControlReply::Snapshot { .. }) && !self.displays.is_empty() {
            self.defer_snapshot_reply(peer, id, reply);
            return;
        }
        self.send(peer, ToNode::ControlReply { id, reply });
    }

    pub(super) fn answer(
        &mut self,
        request: ControlRequest,
        stamp_ns: u64,
        now: Now,
    ) -> Result<ControlReply, Refusal> {
        // A client that could not map its clock onto the master's says 0: stamp it on arrival.
        let stamp = if stamp_ns == 0 { now.unix_ns } else { stamp_ns };
        Ok(match request {
            ControlRequest::Change(changes) => self.queue_all(&changes, stamp, now)?,
            ControlRequest::Clock => ControlReply::Clock {
                master_ns: now.unix_ns,
            },
            ControlRequest::State => {
                let (id, current) = self.coordinator.state();
                ControlReply::State {
                    frame: self.live.last_start.map_or(0, |s| s.frame.0),
                    id,
                    current,
                    next: self.coordinator.next_state(),
                }
            }
            ControlRequest::Figures => ControlReply::Figures(self.figures(now)),
            ControlRequest::SaveView(name) => {
                if self.live.views.len() >= MAX_VIEWS && !self.live.views.contains_key(&name) {
                    return Err(Refusal::ViewsFull {
                        max: MAX_VIEWS as u32,
                    });
                }
                let camera = self.current_camera();
                self.live.views.insert(name, camera);
                ControlReply::Done
            }
            ControlRequest::GotoView(name) => {
                let camera = *self
                    .live
                    .views
                    .get(&name)
                    .ok_or_else(|| Refusal::NoSuchView(name.clone()))?;
                self.queue_all(&[StateChange::Camera(camera)], stamp, now)?
            }
            ControlRequest::Views => ControlReply::Views(self.view_names()),
            ControlRequest::Overlay(on) => {
                self.set_overlay(on);
                ControlReply::Done
            }
            ControlRequest::Snapshot { final_quality } => {
                if self.live.snapshots.len() >= MAX_SNAPSHOTS {
                    return Err(Refusal::SnapshotsFull {
                        max: MAX_SNAPSHOTS as u32,
                    });
                }
                self.snapshot(final_quality)?
            }
            ControlRequest::Input(event) => self.input_request(event, stamp, now)?,
            ControlRequest::Playback(playback) => self.playback(playback, stamp, now)?,
            ControlRequest::Status => ControlReply::Status(self.status()),
            ControlRequest::Replay(states) => self.replay(states)?,
            ControlRequest::TileOwners => ControlReply::TileOwners(self.live.tile_owners.clone()),
            ControlRequest::Fit => {
                let fit = self.fit_camera();
                self.queue_all(&[StateChange::Camera(fit)], stamp, now)?
            }
            ControlRequest::Probe { x, y } => {
                let prober = self.cfg.probe.as_ref().ok_or(Refusal::NoVolume)?;
                // What the wall shows: the last frame started, else the state the first will have.
                let (camera, params) = match self.live.last_start {
                    Some(start) => (start.camera, start.params),
                    None => (
                        self.frame_state.camera.camera_for_frame(0),
                        self.frame_state.params,
                    ),
                };
                ControlReply::Probe(prober.probe(&camera, &params, &self.cfg.wall, (x, y))?)
            }
        })
    }

    /// A person's input at a display window: what the navigator makes of it, queued for the
    /// next barrier like a control command (and refused in the log, not on the wall, if the
    /// knobs it turns would leave their bounds).
    pub(super) fn handle_input(
        &mut self,
        display: DisplayId,
        event: tessera_model::input::InputEvent,
        stamp: u64,
        now: Now,
    ) {
        use navigate::NavAction;
        let current = self.current_camera();
        let frame = self.live.last_start.map_or(0, |s| s.frame.0);
        let camera = current.camera_for_frame(frame);
        let params = self.coordinator.next_state().params;
        let action = self.navigator.handle(&event, &camera, &params, now.instant);
        tracing::debug!("input {event:?} at frame {frame}: {action:?}");
        match action {
            Some(NavAction::Change(change)) => {
                self.record.timing.input_arrived(stamp, now.unix_ns);
                if let Err(e) = self.coordinator.queue_change(change, stamp, now.instant) {
                    tracing::warn!("input {event:?} refused: {e}");
                }
            }
            Some(NavAction::ToggleOverlay) => self.set_overlay(!self.live.overlay),
            Some(NavAction::Probe { fx, fy }) => self.probe_click(display, fx, fy, now),
            None => {}
        }
    }

    /// A click in display `display`'s window at `(fx, fy)` of its screen: the probe there, on
    /// the master's log (where whoever runs the wall reads it).
    fn probe_click(&mut self, display: DisplayId, fx: f32, fy: f32, now: Now) {
        let shown_on = display.0;
        let Some(screen) = self.cfg.wall.screen(display) else {
            return;
        };
        let x = screen.x + ((fx * screen.width as f32) as u32).min(screen.width - 1);
        let y = screen.y + ((fy * screen.height as f32) as u32).min(screen.height - 1);
        match self.answer(ControlRequest::Probe { x, y }, 0, now) {
            Ok(ControlReply::Probe(Some(hit))) => tracing::info!(
                "probe at wall pixel {x},{y} (display {shown_on}): value {} at world {:.3?}, {:.3} from the eye",
                hit.value,
                hit.world,
                hit.distance
            ),
            Ok(_) => tracing::info!(
                "probe at wall pixel {x},{y} (display {shown_on}): no volume there"
            ),
            Err(why) => tracing::info!("probe at wall pixel {x},{y}: {why}"),
        }
    }

    pub(super) fn view_names(&self) -> Vec<ViewName> {
        self.live.views.keys().cloned().collect()
    }

    pub(super) fn set_overlay(&mut self, on: bool) {
        self.live.overlay = on;
        let displays: Vec<PeerId> = self.displays.values().copied().collect();
        for peer in displays {
            self.send(peer, ToNode::Overlay { on });
        }
    }

    /// Queues `changes` all or none: each is checked against the state the ones before it make.
    pub(super) fn queue_all(
        &mut self,
        changes: &[StateChange],
        stamp: u64,
        now: Now,
    ) -> Result<ControlReply, Refusal> {
        let refusal = |index: usize, reason: String| Refusal::BadChange {
            index: index as u32 + 1,
            count: changes.len() as u32,
            reason,
        };
        let mut next = self.coordinator.next_state();
        for (i, change) in changes.iter().enumerate() {
            next = next.apply(change).map_err(|e| refusal(i, e.to_string()))?;
        }
        if let Some((i, reason)) = self.volume_misfit(changes) {
            return Err(refusal(i, reason));
        }
        self.record.timing.input_arrived(stamp, now.unix_ns);
        for (i, change) in changes.iter().enumerate() {
            self.coordinator
                .queue_change(*change, stamp, now.instant)
                .map_err(|e| refusal(i, e.to_string()))?;
        }
        // The last change may have started a frame already: the reply names the state it made.
        let (state_id, frame) = self.coordinator.queued_state();
        Ok(ControlReply::Queued {
            changes: changes.len() as u32,
            state_id,
            frame: frame.0,
        })
    }

    /// The first change that sets volume knobs the scene cannot take, and why: a scene without
    /// a volume takes none, and a time step must be one of the series' (0 for one volume).
    fn volume_misfit(&self, changes: &[StateChange]) -> Option<(usize, String)> {
        let now = *self.coordinator.next_state().params.volume();
        changes.iter().enumerate().find_map(|(i, c)| {
            let StateChange::Volume(v) = c else {
                return None;
            };
            let op = &self.cfg.operator;
            let has_volume = op.volume_range.is_some() || op.series_steps.is_some();
            if !has_volume && *v != now {
                return Some((
                    i,
                    "the scene has no volume: iso-values, transfer function, step and time \
                     step do not apply"
                        .to_string(),
                ));
            }
            let steps = self.cfg.operator.series_steps.unwrap_or(1);
            (v.time_step >= steps).then(|| {
                let reason = match self.cfg.operator.series_steps {
                    Some(steps) => format!(
                        "time step {} is outside the series' {steps} steps (0 to {})",
                        v.time_step,
                        steps - 1
                    ),
                    None => format!(
                        "time step {}: the scene is one volume, not a series (only 0)",
                        v.time_step
                    ),
                };
                (i, reason)
            })
        })
    }

    /// Playing a time series: the next barrier shows the step after the one queued last.
    pub(super) fn advance_time_step(&mut self, steps: u32, now: Now) {
        let mut volume = *self.coordinator.next_state().params.volume();
        volume.time_step = (volume.time_step + 1) % steps.max(1);
        let change = StateChange::Volume(volume);
        if let Err(e) = self
            .coordinator
            .queue_change(change, now.unix_ns, now.instant)
        {
            tracing::warn!("playing the series: {e}");
        }
    }

    /// The camera on the wall now, as a fixed camera: what a saved view keeps and where
    /// steering starts from (an orbit frozen at its last frame).
    pub(super) fn current_camera(&self) -> CameraMode {
        let mode = self.coordinator.next_state().camera;
        match (mode.fixed_camera(), self.live.last_start) {
            (Some(_), _) | (None, None) => mode,
            (None, Some(start)) => CameraMode::fixed(start.camera),
        }
    }

    fn figures(&self, now: Now) -> LiveFigures {
        let now = now.instant;
        let idle = self.coordinator.is_converged() && self.coordinator.frames_in_flight() == 0;
        // A still wall's figures are those of its last second of rendering, not of its rest.
        let until = match self.record.presents.last() {
            Some(&(_, at)) if idle => at,
            _ => now,
        };
        let recent: Vec<Instant> = self
            .record
            .presents
            .iter()
            .rev()
            .map(|(_, at)| *at)
            .take_while(|at| until.duration_since(*at) <= Duration::from_secs(1))
            .collect();
        // A frame started after the wall rested took its own time, not the rest before it.
        let gap = |(f0, at0): (FrameId, Instant), (f1, at1): (FrameId, Instant)| {
            let _ = f0;
            let since_start = self
                .record
                .frame_started
                .get(&f1)
                .map(|s| at1.duration_since(*s));
            let gap = at1.duration_since(at0);
            since_start.map_or(gap, |s| s.min(gap))
        };
        let gaps: Vec<f64> = self
            .record
            .presents
            .windows(2)
            .rev()
            .take(recent.len().max(1))
            .map(|w| gap(w[0], w[1]).as_secs_f64() * 1000.0)
            .collect();
        let mean = |v: &[f64]| {
            if v.is_empty() {
                0.0
            } else {
                v.iter().sum::<f64>() / v.len() as f64
            }
        };
        LiveFigures {
            frames_presented: self.record.presents.len() as u64,
            fps: recent.len() as f64,
            frame_ms_last: gaps.first().copied().unwrap_or(0.0),
            frame_ms_mean: mean(&gaps),
            changes_applied: self.record.changes_applied,
            idle,
            rendering_s: self.rendering_time(now).as_secs_f64(),
            render_nodes: self.render_node_figures(),
            displays: self.display_figures(),
        }
    }

    /// Each render node's figures as its last progress report gave them.
    fn render_node_figures(&self) -> Vec<NodeFigures> {
        self.peers
            .values()
            .filter_map(|p| match p.role {
                PeerRole::Render { node, cores } => {
                    let progress = self.live.progress.get(&node);
                    Some(NodeFigures {
                        id: node.0,
                        host: p.host.clone(),
                        cores,
                        tiles: self.live.tiles.get(&node).copied().unwrap_or(0),
                        rays: progress.map(|p| p.rays),
                        peak_mib: progress
                            .filter(|p| p.max_rss_bytes > 0)
                            .map(|p| p.max_rss_bytes as f64 / (1024.0 * 1024.0)),
                        dsm_misses: progress.and_then(|p| p.dsm_misses),
                    })
                }
                _ => None,
            })
            .collect()
    }

    /// Each display's frames presented so far.
    fn display_figures(&self) -> Vec<DisplayFigures> {
        self.displays
            .iter()
            .map(|(d, peer)| DisplayFigures {
                id: d.0,
                host: self
                    .peers
                    .get(peer)
                    .map_or_else(String::new, |p| p.host.clone()),
                frames_presented: self.live.presented.get(d).copied().unwrap_or(0),
            })
            .collect()
    }
}
