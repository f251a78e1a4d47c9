//! What the master does with each message a peer sends, by the peer's role.

use super::*;

impl Wall {
    pub(super) fn handle_msg(&mut self, peer: PeerId, msg: FromNode, now: Instant) -> Result<()> {
        let Some(p) = self.peers.get_mut(&peer) else {
            return Ok(());
        };
        match (&p.role, msg) {
            (_, FromNode::Stats(stats)) => p.stats = Some(stats),
            (_, FromNode::Failed { message }) => {
                bail!("it failed: {message}");
            }
            (_, FromNode::Hello(_)) => bail!("sent a second hello"),
            (PeerRole::Render { node, .. }, FromNode::Ready) => {
                let node = *node;
                if !p.ready {
                    p.ready = true;
                    if self.started.is_some() {
                        tracing::info!("render node {} joins the running wall", node.0);
                    }
                    self.coordinator.handle_render_joined(node, now);
                }
            }
            (PeerRole::Display(d), FromNode::Ready) => {
                let d = *d;
                p.ready = true;
                self.display_ready(peer, d, now);
                for seq in 0..PINGS {
                    self.timing.ping_sent(d, seq, unix_ns());
                    self.send(peer, ToNode::Ping { seq });
                }
            }
            (
                PeerRole::Render { node, .. },
                FromNode::TilesDone {
                    frame,
                    tiles,
                    want_more,
                },
            ) => {
                let node = *node;
                self.coordinator
                    .handle_tiles_done(node, frame, &tiles, want_more, now)?;
                let done: usize = tiles.iter().map(|r| r.len()).sum();
                *self.live.tiles.entry(node).or_default() += done as u64;
            }
            (&PeerRole::Display(d), FromNode::Heartbeat) => {
                self.coordinator.handle_display_heartbeat(d, now);
            }
            (&PeerRole::Render { node, .. }, FromNode::Heartbeat) => {
                // From a node not (or no longer) in the run, a beat in flight when it was
                // declared gone or one before it is ready: nothing to keep alive.
                let _ = self.coordinator.handle_heartbeat(node, now);
            }
            (&PeerRole::Render { node, .. }, FromNode::TilesReturned { frame, tiles }) => {
                self.coordinator
                    .handle_tiles_returned(node, frame, &tiles, now)?;
            }
            (PeerRole::Display(d), FromNode::FrameComplete { frame }) => {
                let d = *d;
                self.coordinator.handle_frame_complete(d, frame, now)?;
            }
            (PeerRole::Display(d), msg @ (FromNode::Presented { .. } | FromNode::Pong { .. })) => {
                if matches!(msg, FromNode::Presented { .. }) {
                    *self.live.presented.entry(*d).or_default() += 1;
                }
                self.note_timing(peer, &msg);
            }
            (
                PeerRole::Control,
                FromNode::Control {
                    id,
                    request,
                    stamp_ns,
                },
            ) => self.handle_control(peer, id, request, stamp_ns),
            (&PeerRole::Display(d), FromNode::Input { event, clock_ns }) => {
                // On the master's clock, as present stamps are mapped.
                let stamp = (clock_ns as i64 - self.timing.offset(d)).max(1) as u64;
                self.handle_input(d, event, stamp);
            }
            (&PeerRole::Render { node, .. }, FromNode::BlocksAt { addr }) => {
                let remote = p.conn.remote_address();
                self.blocks_at(node, addr, remote)?;
            }
            (_, other) => bail!("sent {other:?}, which its role never sends"),
        }
        Ok(())
    }

    /// Records a display's present stamp or clock probe answer.
    pub(super) fn note_timing(&mut self, peer: PeerId, msg: &FromNode) {
        let Some(PeerRole::Display(d)) = self.peers.get(&peer).map(|p| &p.role) else {
            return;
        };
        match *msg {
            FromNode::Presented { frame, clock_ns } => self.timing.presented(*d, frame, clock_ns),
            FromNode::Pong { seq, clock_ns } => self.timing.pong(*d, seq, clock_ns, unix_ns()),
            _ => {}
        }
    }
}
