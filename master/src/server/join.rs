//! Peers joining and leaving the wall: who they say they are, whether their certificate lets
//! them be that, what the master answers, and what their departure costs the run.

use super::*;
use tessera_net::cluster::CertRole;
use tessera_wire::protocol::Hello;

/// Whether a certificate naming `roles` may join as `role`. Certificates from before roles
/// (naming none) may be render or display nodes, never control clients.
/// Whether a certificate naming `roles` may join as `role` (a display certificate also names
/// its display: `for_display` says whether it names the one claimed). A certificate from
/// before roles may not join at all: any node of the cluster could claim any place with it.
fn allowed(role: &Role, roles: &[CertRole], for_display: bool) -> bool {
    match role {
        Role::Render { .. } => roles.contains(&CertRole::Render),
        Role::Display { .. } => roles.contains(&CertRole::Display) && for_display,
        Role::Control => roles.contains(&CertRole::Control),
    }
}

impl Wall {
    pub(super) fn handle(&mut self, event: Event) -> Result<()> {
        let now = Instant::now();
        match event {
            Event::Joined {
                peer,
                hello,
                conn,
                tx,
            } => self.join(peer, hello, conn, tx),
            Event::Msg(peer, msg) => {
                if let Err(e) = self.handle_msg(peer, msg, now) {
                    let who = self.describe(peer);
                    tracing::error!("closing {who}: {e:#}");
                    if let Some(p) = self.peers.get(&peer) {
                        p.conn.close(2u32.into(), b"protocol violation");
                    }
                    self.drop_peer(peer, now, "protocol violation")?;
                }
            }
            Event::Closed(peer, reason) => self.drop_peer(peer, now, &reason)?,
        }
        Ok(())
    }

    fn join(&mut self, peer: PeerId, hello: Hello, conn: quinn::Connection, tx: PeerSender) {
        let remote = conn.remote_address();
        let roles = tessera_net::quic::peer_roles(&conn);
        let for_display = match hello.role {
            Role::Display { display, .. } => tessera_net::quic::peer_is_display(&conn, display.0),
            _ => false,
        };
        if !allowed(&hello.role, &roles, for_display) {
            let named: Vec<&str> = roles.iter().map(|r| r.name()).collect();
            let what = match (&hello.role, named.is_empty()) {
                (_, true) => "no role (issued before roles)".to_string(),
                (Role::Display { .. }, false) if roles.contains(&CertRole::Display) => {
                    "another display".to_string()
                }
                _ => named.join(", "),
            };
            let reason = format!(
                "its certificate is for {what}, not for joining as {}; issue one with `tessera-master issue-cert --role ...`",
                role_name(&hello.role)
            );
            tracing::warn!("refused {} from {remote}: {reason}", hello.host);
            let _ = tx.try_send(ToNode::Refused { reason });
            return;
        }
        let host = hello.host;
        let role = match hello.role {
            Role::Display {
                display,
                pixel_addr,
            } => match self.join_display(display, pixel_addr, &host, remote) {
                Ok(()) => PeerRole::Display(display),
                Err(reason) => {
                    tracing::warn!("refused {host} from {remote}: {reason}");
                    let _ = tx.try_send(ToNode::Refused { reason });
                    return;
                }
            },
            Role::Render { cores } => {
                let node = RenderNodeId(self.next_render_id);
                self.next_render_id += 1;
                let rank = self.take_rank(node);
                let holds = rank.map_or(String::new(), |r| format!(", holds rank {r}"));
                tracing::info!(
                    "render node {} joined from {host} ({remote}), {cores} cores{holds}",
                    node.0
                );
                PeerRole::Render { node, cores }
            }
            Role::Control => {
                tracing::info!("control client joined from {host} ({remote})");
                PeerRole::Control
            }
        };
        // Render nodes wait for every display's address before the first frame; once the
        // wall runs, a lost display's is not coming back until it rejoins (then they are told).
        let welcome_now = !matches!(role, PeerRole::Render { .. })
            || self.all_displays_known()
            || self.started.is_some();
        let is_display = matches!(role, PeerRole::Display(_));
        if let PeerRole::Display(display) = role {
            // A display rejoining a running wall is shown frames only once it is ready: see
            // `display_ready`.
            if self.started.is_none() {
                self.displays.insert(display, peer);
            }
        }
        self.peers.insert(
            peer,
            Peer {
                role,
                host,
                tx,
                conn,
                ready: false,
                stats: None,
            },
        );
        if welcome_now {
            self.welcome(peer);
        }
        if is_display && self.all_displays_known() {
            // Render nodes that came first wait for every display's address.
            let waiting: Vec<PeerId> = self
                .peers
                .iter()
                .filter(|(_, p)| matches!(p.role, PeerRole::Render { .. }) && !p.ready)
                .map(|(id, _)| *id)
                .collect();
            for p in waiting {
                self.welcome(p);
            }
        }
    }

    /// Checks a display's claim and records where render nodes reach it.
    fn join_display(
        &mut self,
        display: DisplayId,
        pixel_addr: SocketAddr,
        host: &str,
        remote: SocketAddr,
    ) -> Result<(), String> {
        let count = self.cfg.wall.display_count();
        if display.0 >= count {
            return Err(format!(
                "display {} does not exist on a {count}-display wall",
                display.0
            ));
        }
        let joining = self
            .peers
            .values()
            .any(|p| matches!(p.role, PeerRole::Display(d) if d == display));
        if self.displays.contains_key(&display) || joining {
            return Err(format!("display {} has already joined", display.0));
        }
        let addr = if pixel_addr.ip().is_unspecified() {
            SocketAddr::new(remote.ip(), pixel_addr.port())
        } else {
            pixel_addr
        };
        let id = display.0;
        tracing::info!("display {id} joined from {host} ({remote}), pixels at {addr}");
        if host == tessera_net::hostname() {
            self.timing.same_host(display);
        }
        self.display_endpoints.insert(display, addr);
        Ok(())
    }

    /// A display that rejoined the running wall is ready: it is shown the frames that start
    /// from now on, and render nodes are told where its pixels go.
    pub(super) fn display_ready(&mut self, peer: PeerId, display: DisplayId, now: Instant) {
        if self.started.is_none() || self.displays.contains_key(&display) {
            return;
        }
        let from = self.coordinator.next_frame();
        // Before anything of those frames can reach it: render nodes learn its address only
        // after this, and must connect before they send it a tile.
        self.send(peer, ToNode::StartAt { frame: from });
        self.displays.insert(display, peer);
        self.display_since.insert(display, from);
        self.coordinator.handle_display_joined(display, now);
        let (id, first) = (display.0, from.0);
        tracing::info!("display {id} rejoined the running wall; it shows frames from {first} on");
        if let Some(&addr) = self.display_endpoints.get(&display) {
            let renders: Vec<PeerId> = self
                .peers
                .iter()
                .filter(|(_, p)| matches!(p.role, PeerRole::Render { .. }) && p.ready)
                .map(|(id, _)| *id)
                .collect();
            for r in renders {
                self.send(r, ToNode::DisplayAt { display, addr });
            }
        }
    }

    pub(super) fn drop_peer(&mut self, peer: PeerId, now: Instant, reason: &str) -> Result<()> {
        let who = self.describe(peer);
        let Some(p) = self.peers.remove(&peer) else {
            return Ok(());
        };
        if self.finished {
            return Ok(());
        }
        match p.role {
            PeerRole::Display(d) => {
                self.displays.remove(&d);
                self.display_since.remove(&d);
                use crate::args::DisplayLoss;
                let policy = self.cfg.display_loss;
                if self.started.is_none() || policy == DisplayLoss::Stop {
                    self.display_endpoints.remove(&d);
                    bail!(
                        "{who} disconnected ({reason}); the wall stops (--display-loss stop, or it had not started)"
                    );
                }
                self.lost_displays += 1;
                // Render nodes that join from now on do not try to reach it.
                self.display_endpoints.remove(&d);
                if policy == DisplayLoss::Wait {
                    tracing::error!(
                        "{who} disconnected ({reason}); the wall waits for it to rejoin, at most {} s (--display-loss wait)",
                        self.cfg.join_timeout.as_secs()
                    );
                } else {
                    tracing::error!(
                        "{who} disconnected ({reason}); the other displays go on without it (--display-loss stop ends the run instead)"
                    );
                }
                self.coordinator.handle_display_left(d, now);
            }
            PeerRole::Render { node, .. } => {
                if p.ready && self.started.is_some() {
                    self.lost_render_nodes += 1;
                    tracing::error!(
                        "{who} disconnected ({reason}); its tiles go to the other render nodes"
                    );
                } else {
                    tracing::warn!("{who} left before the first frame ({reason})");
                }
                if p.ready {
                    self.coordinator.handle_render_left(node, now);
                }
                self.lose_rank(node, &who);
            }
            PeerRole::Control => tracing::info!("{who} left ({reason})"),
        }
        Ok(())
    }
}

fn role_name(role: &Role) -> &'static str {
    match role {
        Role::Render { .. } => "a render node",
        Role::Display { .. } => "a display",
        Role::Control => "a control client",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_certificate_lets_its_holder_join_only_as_its_role_and_display() {
        let render = Role::Render { cores: 1 };
        assert!(allowed(&render, &[CertRole::Render], false));
        assert!(
            !allowed(&render, &[], false),
            "certificates from before roles"
        );
        assert!(!allowed(&render, &[CertRole::Control], false));
        assert!(!allowed(&render, &[CertRole::Display], true));
        let display = Role::Display {
            display: DisplayId(0),
            pixel_addr: "127.0.0.1:9".parse().unwrap(),
        };
        assert!(allowed(&display, &[CertRole::Display], true));
        assert!(
            !allowed(&display, &[CertRole::Display], false),
            "another display's"
        );
        assert!(
            !allowed(&display, &[CertRole::Render], false),
            "a render node's"
        );
        assert!(!allowed(&display, &[], false));
        assert!(allowed(&Role::Control, &[CertRole::Control], false));
        assert!(!allowed(&Role::Control, &[], false));
        assert!(!allowed(&Role::Control, &[CertRole::Render], false));
        assert!(!allowed(&Role::Control, &[CertRole::Master], false));
    }
}
