//! Peers joining and leaving the wall: who they say they are, whether their certificate lets
//! them be that, what the master answers, when a display that rejoined is shown frames again,
//! and what a departure costs the run under each display-loss policy.

use super::*;
use tessera_protocol::{DisplayEndpoint, Session, SessionSpec, PROTOCOL_VERSION};

/// Whether a certificate naming `roles` may join as `role` (a display certificate also names
/// its display: `for_display` says whether it names the one claimed). A certificate from
/// before roles may not join at all: any node of the cluster could claim any place with it.
pub(super) fn allowed(role: &Role, roles: &[CertifiedRole], for_display: bool) -> bool {
    match role {
        Role::Render { .. } => roles.contains(&CertifiedRole::Render),
        Role::Display { .. } => roles.contains(&CertifiedRole::Display) && for_display,
        Role::Control => roles.contains(&CertifiedRole::Control),
    }
}

/// Why the master refused a peer's hello; sent to it as text in [`ToNode::Refused`].
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum JoinRefusal {
    /// The peer speaks this other protocol version.
    #[error(
        "protocol version {0} is not the master's {PROTOCOL_VERSION}; run the same Tessera version everywhere"
    )]
    Version(u32),
    /// The peer's certificate names other roles (`names`, or none) than the `role` it claims.
    #[error(
        "its certificate is for {names}, not for joining as {role}; issue one with `tessera-master issue-cert --role ...`"
    )]
    Certificate {
        /// The roles the certificate names, as `issue-cert --role` spells them.
        names: String,
        /// The role claimed, as a log line names it ("a render node").
        role: &'static str,
    },
    /// A display claimed a place past the wall's last display.
    #[error("display {display} does not exist on a {count}-display wall")]
    NoSuchDisplay {
        /// The display claimed.
        display: u32,
        /// Displays the wall has.
        count: u32,
    },
    /// Another peer holds (or is joining as) that display.
    #[error("display {0} has already joined")]
    DisplayTaken(u32),
}

fn role_name(role: &Role) -> &'static str {
    match role {
        Role::Render { .. } => "a render node",
        Role::Display { .. } => "a display",
        Role::Control => "a control client",
    }
}

fn certified_name(role: CertifiedRole) -> &'static str {
    match role {
        CertifiedRole::Render => "render",
        CertifiedRole::Display => "display",
        CertifiedRole::Control => "control",
        CertifiedRole::Master => "master",
    }
}

impl Master {
    pub(super) fn join(&mut self, join: Join, now: Now) {
        let Join {
            peer,
            hello,
            remote,
            credentials,
        } = join;
        if let Err(refusal) = self.admit(&hello, &credentials) {
            tracing::warn!("refused {} from {remote}: {refusal}", hello.host);
            let reason = refusal.to_string();
            self.send(peer, ToNode::Refused { reason });
            return;
        }
        let host = hello.host;
        let role = match hello.role {
            Role::Display {
                display,
                pixel_addr,
            } => {
                let same_host = credentials.same_host;
                match self.join_display(display, pixel_addr, (&host, remote, same_host), now) {
                    Ok(()) => PeerRole::Display(display),
                    Err(refusal) => {
                        tracing::warn!("refused {host} from {remote}: {refusal}");
                        let reason = refusal.to_string();
                        self.send(peer, ToNode::Refused { reason });
                        return;
                    }
                }
            }
            Role::Render { cores } => {
                let node = RenderNodeId(self.next_render_id);
                self.next_render_id += 1;
                let rank = self.take_rank(node, &host);
                let holds = rank.map_or(String::new(), |r| format!(", holds rank {r}"));
                tracing::info!(
                    "render node {} joined from {host} ({remote}), {cores} cores{holds}",
                    node.0
                );
                self.renders.insert(node, peer);
                PeerRole::Render { node, cores }
            }
            Role::Control => {
                tracing::info!("control client joined from {host} ({remote})");
                PeerRole::Control
            }
        };
        self.admitted(peer, role, host, remote);
    }

    /// Why a peer may not join as it claims, if it may not: another protocol version, or a
    /// certificate for another role.
    fn admit(&self, hello: &Hello, credentials: &Credentials) -> Result<(), JoinRefusal> {
        if hello.version != PROTOCOL_VERSION {
            return Err(JoinRefusal::Version(hello.version));
        }
        let role = &hello.role;
        let roles = &credentials.roles;
        if allowed(role, roles, credentials.names_claimed_display) {
            return Ok(());
        }
        let named: Vec<&str> = roles.iter().map(|r| certified_name(*r)).collect();
        let what = match (role, named.is_empty()) {
            (_, true) => "no role (issued before roles)".to_string(),
            (Role::Display { .. }, false) if roles.contains(&CertifiedRole::Display) => {
                "another display".to_string()
            }
            _ => named.join(", "),
        };
        Err(JoinRefusal::Certificate {
            names: what,
            role: role_name(role),
        })
    }

    /// Records an admitted peer and welcomes it, or holds its welcome back (see below).
    fn admitted(&mut self, peer: PeerId, role: PeerRole, host: String, remote: SocketAddr) {
        // Render nodes wait for every display's address before the first frame; once the
        // wall runs, a lost display's is not coming back until it rejoins (then they are told).
        let welcome_now = !matches!(role, PeerRole::Render { .. })
            || self.all_displays_known()
            || self.record.started.is_some();
        let is_display = matches!(role, PeerRole::Display(_));
        if let PeerRole::Display(display) = role {
            // A display rejoining a running wall is shown frames only once it is ready: see
            // `display_ready`.
            if self.record.started.is_none() {
                self.displays.insert(display, peer);
            }
        }
        self.peers.insert(
            peer,
            Peer {
                role,
                host,
                remote,
                welcomed: false,
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
                .renders
                .values()
                .copied()
                .filter(|p| self.peers.get(p).is_some_and(|p| !p.welcomed))
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
        (host, remote, same_host): (&str, SocketAddr, bool),
        now: Now,
    ) -> Result<(), JoinRefusal> {
        let count = self.cfg.wall.display_count();
        if display.0 >= count {
            return Err(JoinRefusal::NoSuchDisplay {
                display: display.0,
                count,
            });
        }
        self.replace_restarted_display(display, host, now);
        let joining = self
            .peers
            .values()
            .any(|p| matches!(p.role, PeerRole::Display(d) if d == display));
        if self.displays.contains_key(&display) || joining {
            return Err(JoinRefusal::DisplayTaken(display.0));
        }
        let addr = if pixel_addr.ip().is_unspecified() {
            SocketAddr::new(remote.ip(), pixel_addr.port())
        } else {
            pixel_addr
        };
        let id = display.0;
        tracing::info!("display {id} joined from {host} ({remote}), pixels at {addr}");
        if same_host {
            self.record.timing.same_host(display);
        }
        self.display_endpoints.insert(display, addr);
        Ok(())
    }

    /// A display of the running wall joins again while its old connection is still there
    /// (restarted quicker than its silence could be called a death; its certificate says it
    /// is that display): the old connection is dropped as lost, and the new one rejoins.
    fn replace_restarted_display(&mut self, display: DisplayId, host: &str, now: Now) {
        if self.record.started.is_none() {
            return;
        }
        let Some(&old) = self.displays.get(&display) else {
            return;
        };
        let reason = format!("replaced: display {} joined again from {host}", display.0);
        self.close_and_drop(old, CloseReason::Replaced, now, &reason);
    }

    /// A display that rejoined the running wall is ready: it is shown the frames that start
    /// from now on, and render nodes are told where its pixels go.
    pub(super) fn display_ready(&mut self, peer: PeerId, display: DisplayId, now: Now) {
        if self.record.started.is_none() || self.displays.contains_key(&display) {
            return;
        }
        let from = self.coordinator.next_frame();
        // Before anything of those frames can reach it: render nodes learn its address only
        // after this, and must connect before they send it a tile.
        self.send(peer, ToNode::StartAt { frame: from });
        self.displays.insert(display, peer);
        self.display_since.insert(display, from);
        self.coordinator.handle_display_joined(display, now.instant);
        let (id, first) = (display.0, from.0);
        tracing::info!("display {id} rejoined the running wall; it shows frames from {first} on");
        if let Some(&addr) = self.display_endpoints.get(&display) {
            let ready: Vec<PeerId> = self
                .renders
                .values()
                .copied()
                .filter(|p| self.peers.get(p).is_some_and(|p| p.ready))
                .collect();
            for r in ready {
                self.send(r, ToNode::DisplayAt { display, addr });
            }
        }
    }

    /// A peer is gone (it left, broke the protocol, or was silent past the deadline).
    pub(super) fn drop_peer(&mut self, peer: PeerId, now: Now, reason: &str) {
        let who = self.describe(peer);
        let Some(p) = self.peers.remove(&peer) else {
            return;
        };
        if !matches!(self.phase, Phase::Joining { .. } | Phase::Running) {
            return;
        }
        match p.role {
            PeerRole::Display(d) => self.lose_display(d, &who, reason, now),
            PeerRole::Render { node, .. } => {
                self.renders.remove(&node);
                if p.ready && self.record.started.is_some() {
                    self.record.lost_render_nodes += 1;
                    tracing::error!(
                        "{who} disconnected ({reason}); its tiles go to the other render nodes"
                    );
                } else {
                    tracing::warn!("{who} left before the first frame ({reason})");
                }
                if p.ready {
                    self.coordinator.handle_render_left(node, now.instant);
                }
                self.lose_rank(node, &who);
            }
            PeerRole::Control => tracing::info!("{who} left ({reason})"),
        }
    }

    /// What a lost display costs: the run (before the start, or under [`DisplayLoss::Stop`]),
    /// or its frames until it rejoins.
    fn lose_display(&mut self, d: DisplayId, who: &str, reason: &str, now: Now) {
        self.displays.remove(&d);
        self.display_since.remove(&d);
        self.display_gone_from_snapshots(d);
        // Render nodes that join from now on do not try to reach it.
        self.display_endpoints.remove(&d);
        let policy = self.cfg.display_loss;
        if self.record.started.is_none() || policy == DisplayLoss::Stop {
            self.fail(RunError::DisplayLost {
                who: who.to_string(),
                reason: reason.to_string(),
            });
            return;
        }
        self.record.lost_displays += 1;
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
        self.coordinator.handle_display_left(d, now.instant);
    }

    pub(super) fn all_ready(&self) -> bool {
        let displays_ready = self.displays.len() == self.cfg.wall.display_count() as usize
            && self.displays.values().all(|p| self.peers[p].ready);
        displays_ready && self.ready_render_nodes() >= self.cfg.render_nodes as usize
    }

    fn ready_render_nodes(&self) -> usize {
        self.renders
            .values()
            .filter(|p| self.peers.get(p).is_some_and(|p| p.ready))
            .count()
    }

    /// Which nodes a wall that has not started still waits for.
    pub fn missing_summary(&self) -> String {
        let missing: Vec<String> = (0..self.cfg.wall.display_count())
            .map(DisplayId)
            .filter(|d| !self.displays.get(d).is_some_and(|p| self.peers[p].ready))
            .map(|d| d.0.to_string())
            .collect();
        let renders = self.ready_render_nodes();
        format!(
            "displays not ready: [{}]; render nodes ready: {renders} of {}",
            missing.join(", "),
            self.cfg.render_nodes
        )
    }

    fn session(&self) -> Session {
        Session::new(SessionSpec {
            wall: self.cfg.wall.clone(),
            scene: self.cfg.scene.clone(),
            scene_hash: self.cfg.scene_hash,
            displays: self
                .display_endpoints
                .iter()
                .map(|(&display, &addr)| DisplayEndpoint { display, addr })
                .collect(),
            save_frame: self.cfg.save_frame,
            compression: self.cfg.compression,
            windows: self.cfg.windows.clone(),
            data: self.cfg.data.clone(),
            // Particles whose attributes are all missing have no range: no legend then.
            particle_range: self
                .cfg
                .operator
                .particle_range
                .filter(|[lo, hi]| lo.is_finite() && hi.is_finite() && lo <= hi),
        })
        .expect("displays are checked against the wall, and for duplicates, when they join")
    }

    /// Sends a peer the session. Render nodes get it only once every display's address is
    /// known; displays and control clients at once.
    fn welcome(&mut self, peer: PeerId) {
        let node = match self.peers.get(&peer).map(|p| &p.role) {
            Some(PeerRole::Render { node, .. }) => Some(*node),
            Some(PeerRole::Display(_) | PeerRole::Control) => None,
            None => return,
        };
        let session = self.session();
        if let Some(p) = self.peers.get_mut(&peer) {
            p.welcomed = true;
        }
        let term = self.term;
        self.send(
            peer,
            ToNode::Welcome {
                node,
                session,
                term,
            },
        );
        if let Some(node) = node {
            self.send_holders(peer, node);
        }
    }

    fn all_displays_known(&self) -> bool {
        self.display_endpoints.len() == self.cfg.wall.display_count() as usize
    }

    /// A peer as log lines name it.
    pub(super) fn describe(&self, peer: PeerId) -> String {
        match self.peers.get(&peer).map(|p| (&p.role, &p.host)) {
            Some((PeerRole::Render { node, .. }, host)) => {
                format!("render node {} ({host})", node.0)
            }
            Some((PeerRole::Display(d), host)) => format!("display {} ({host})", d.0),
            Some((PeerRole::Control, host)) => format!("control client {} ({host})", peer.0),
            None => format!("peer {}", peer.0),
        }
    }
}
