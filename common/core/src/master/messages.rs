//! What the master does with each message a peer sends, by the peer's role.

use super::*;

/// Why a peer's message closes its connection.
#[derive(Debug, thiserror::Error)]
pub(super) enum Violation {
    #[error("it failed: {0}")]
    Failed(String),
    #[error("sent a second hello")]
    SecondHello,
    #[error(transparent)]
    Balance(#[from] BalanceError),
    #[error(transparent)]
    NoRank(#[from] ranks::NoRank),
    #[error("sent {0}, which its role never sends")]
    NotItsRole(String),
}

impl Master {
    pub(super) fn message(
        &mut self,
        peer: PeerId,
        msg: FromNode,
        now: Now,
    ) -> Result<(), Violation> {
        let Some(p) = self.peers.get_mut(&peer) else {
            return Ok(());
        };
        match (&p.role, msg) {
            (_, FromNode::Stats(stats)) => p.stats = Some(stats),
            (_, FromNode::Failed { message }) => return Err(Violation::Failed(message)),
            (_, FromNode::Hello(_)) => return Err(Violation::SecondHello),
            (&PeerRole::Render { node, .. }, msg) => self.render_said(node, peer, msg, now)?,
            (&PeerRole::Display(d), msg) => self.display_said(d, peer, msg, now)?,
            (
                PeerRole::Control,
                FromNode::Control {
                    id,
                    request,
                    stamp_ns,
                },
            ) => self.handle_control(peer, id, request, stamp_ns, now),
            (PeerRole::Control, other) => return Err(Violation::NotItsRole(format!("{other:?}"))),
        }
        Ok(())
    }

    fn render_said(
        &mut self,
        node: RenderNodeId,
        peer: PeerId,
        msg: FromNode,
        now: Now,
    ) -> Result<(), Violation> {
        match msg {
            FromNode::Ready => {
                let p = self.peers.get_mut(&peer).expect("the caller found it");
                if !p.ready {
                    p.ready = true;
                    if self.record.started.is_some() {
                        tracing::info!("render node {} joins the running wall", node.0);
                    }
                    self.coordinator.handle_render_joined(node, now.instant);
                }
            }
            FromNode::TilesDone {
                frame,
                tiles,
                want_more,
            } => {
                self.coordinator
                    .handle_tiles_done(node, frame, &tiles, want_more, now.instant)?;
                let done: usize = tiles.iter().map(|r| r.len()).sum();
                *self.live.tiles.entry(node).or_default() += done as u64;
                self.note_tile_owners(node, &tiles);
            }
            FromNode::Heartbeat => {
                // From a node not (or no longer) in the run, a beat in flight when it was
                // declared gone or one before it is ready: nothing to keep alive.
                let _ = self.coordinator.handle_heartbeat(node, now.instant);
            }
            FromNode::Loading { step, elapsed_s } => {
                self.note_loading(peer, node, step, elapsed_s);
            }
            FromNode::TilesReturned { frame, tiles } => {
                self.coordinator
                    .handle_tiles_returned(node, frame, &tiles, now.instant)?;
            }
            FromNode::Progress(progress) => {
                self.live.progress.insert(node, progress);
            }
            FromNode::BlocksAt { addr } => {
                let remote = self.peers[&peer].remote;
                self.blocks_at(node, addr, remote)?;
            }
            other => return Err(Violation::NotItsRole(format!("{other:?}"))),
        }
        Ok(())
    }

    fn display_said(
        &mut self,
        d: DisplayId,
        peer: PeerId,
        msg: FromNode,
        now: Now,
    ) -> Result<(), Violation> {
        match msg {
            FromNode::Ready => {
                self.peers
                    .get_mut(&peer)
                    .expect("the caller found it")
                    .ready = true;
                let first = self.coordinator.next_frame();
                if self.record.started.is_none() && first > FrameId(0) {
                    // A master that took a wall over starts at its standby's horizon: the
                    // display is told before any tile of that frame can reach it.
                    self.send(peer, ToNode::StartAt { frame: first });
                }
                self.display_ready(peer, d, now);
                for seq in 0..timing::PINGS {
                    self.record.timing.ping_sent(d, seq, now.unix_ns);
                    self.send(peer, ToNode::Ping { seq });
                }
            }
            FromNode::Heartbeat => self.coordinator.handle_display_heartbeat(d, now.instant),
            FromNode::FrameComplete { frame } => {
                self.coordinator
                    .handle_frame_complete(d, frame, now.instant)?;
            }
            msg @ (FromNode::Presented { .. } | FromNode::Pong { .. }) => {
                if matches!(msg, FromNode::Presented { .. }) {
                    *self.live.presented.entry(d).or_default() += 1;
                }
                self.note_timing(peer, &msg, now);
            }
            FromNode::Thumbnail(thumbnail) => self.thumbnail(d, thumbnail),
            FromNode::Saved { frame, ok } => self.display_saved(d, frame, ok),
            FromNode::Input { event, clock_ns } => {
                // On the master's clock, as present stamps are mapped.
                let stamp = (clock_ns as i64 - self.record.timing.offset(d)).max(1) as u64;
                self.handle_input(d, event, stamp, now);
            }
            other => return Err(Violation::NotItsRole(format!("{other:?}"))),
        }
        Ok(())
    }

    /// Records a display's present stamp or clock probe answer.
    pub(super) fn note_timing(&mut self, peer: PeerId, msg: &FromNode, now: Now) {
        let Some(PeerRole::Display(d)) = self.peers.get(&peer).map(|p| &p.role) else {
            return;
        };
        let d = *d;
        match *msg {
            FromNode::Presented { frame, clock_ns } => {
                self.record.timing.presented(d, frame, clock_ns)
            }
            FromNode::Pong { seq, clock_ns } => {
                self.record.timing.pong(d, seq, clock_ns, now.unix_ns)
            }
            _ => {}
        }
    }
}
