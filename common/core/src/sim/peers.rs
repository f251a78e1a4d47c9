//! The simulated wall's peers as the [`Master`] sees them: each node joins with a hello and a
//! certificate for its role, says it is ready, and may leave and join again; control clients
//! send requests and keep the answers. Scripted events happen as chosen frames start.

use super::*;
use std::collections::HashMap;
use std::net::SocketAddr;
use tessera_protocol::{NodeStats, PROTOCOL_VERSION};

/// The control client that steers the wall when every frame has a state of its own
/// ([`SimConfig::change_every_frame`]); numbered apart from the clients a test scripts.
pub(super) const STEERING_CLIENT: u32 = 1 << 31;

/// The Unix clock of the simulated master at virtual time zero (any fixed time after the
/// epoch: a stamp of 0 means "no stamp" to the master).
const UNIX_EPOCH_NS: u64 = 1_700_000_000_000_000_000;

/// Virtual time `us` microseconds after `base`, on both of the master's clocks.
pub(super) fn now_at(base: Instant, us: u64) -> Now {
    Now {
        instant: base + Duration::from_micros(us),
        unix_ns: UNIX_EPOCH_NS + us * 1000,
    }
}

/// Who a peer of the master is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Who {
    Render(RenderNodeId),
    Display(DisplayId),
    Control(u32),
}

/// What is scripted to happen when a frame starts.
#[derive(Clone, Debug)]
pub(super) enum Scripted {
    /// The display's connection closes; it joins again `back_after_us` later, if ever.
    DisplayLeaves {
        display: DisplayId,
        back_after_us: Option<u64>,
    },
    /// A control client sends a request.
    Control {
        client: u32,
        request: ControlRequest,
    },
    /// A new render node joins.
    RenderJoins,
}

/// A control client's answer from the master.
#[derive(Clone, Debug, PartialEq)]
pub struct ControlAnswer {
    /// The client the answer went to, as the script numbered it.
    pub client: u32,
    /// The id of the request it answers: requests are numbered from 0 as they are sent,
    /// across every client.
    pub id: u32,
    /// What the master answered.
    pub reply: ControlReply,
}

/// The peers the master knows now, and what they were told.
pub(super) struct Peers {
    who: HashMap<PeerId, Who>,
    display_peer: BTreeMap<DisplayId, PeerId>,
    render_peer: BTreeMap<RenderNodeId, PeerId>,
    control_peer: BTreeMap<u32, PeerId>,
    next: u64,
    batching: Batching,
    /// Displays whose heartbeat timer runs.
    beating: std::collections::BTreeSet<DisplayId>,
    /// The rank each render node was last told it holds.
    pub(super) ranks: BTreeMap<RenderNodeId, Option<u32>>,
    pub(super) answers: Vec<ControlAnswer>,
    next_request: u32,
}

impl Peers {
    pub(super) fn new(batching: Batching) -> Peers {
        Peers {
            who: HashMap::new(),
            display_peer: BTreeMap::new(),
            render_peer: BTreeMap::new(),
            control_peer: BTreeMap::new(),
            next: 0,
            batching,
            beating: Default::default(),
            ranks: BTreeMap::new(),
            answers: Vec::new(),
            next_request: 0,
        }
    }

    fn add(&mut self, who: Who) -> PeerId {
        self.next += 1;
        let peer = PeerId(self.next);
        self.who.insert(peer, who);
        match who {
            Who::Render(node) => self.render_peer.insert(node, peer),
            Who::Display(d) => self.display_peer.insert(d, peer),
            Who::Control(c) => self.control_peer.insert(c, peer),
        };
        peer
    }

    pub(super) fn who(&self, peer: PeerId) -> Option<Who> {
        self.who.get(&peer).copied()
    }

    pub(super) fn display(&self, display: DisplayId) -> Option<PeerId> {
        self.display_peer.get(&display).copied()
    }

    pub(super) fn render(&self, node: RenderNodeId) -> Option<PeerId> {
        self.render_peer.get(&node).copied()
    }
}

fn hello(role: Role) -> Hello {
    Hello {
        version: PROTOCOL_VERSION,
        role,
        host: "sim".to_string(),
    }
}

fn address(port: u32) -> SocketAddr {
    SocketAddr::from(([127, 0, 0, 1], (10_000 + port % 50_000) as u16))
}

impl SimWall {
    fn join(&mut self, peer: PeerId, role: Role, port: u32) {
        let join = Join {
            peer,
            credentials: Credentials::for_role(&role),
            hello: hello(role),
            remote: address(port),
        };
        let now = self.master_now();
        self.master.handle_join(join, now);
    }

    /// Display `display` (started anew) joins and is ready; its frames start from scratch.
    pub(super) fn join_display(&mut self, display: DisplayId) {
        let screen = self.pixel_grid.layout().screen(display).expect("display");
        self.displays[display.0 as usize] = FrameAssembler::new(&self.pixel_grid, screen);
        let peer = self.peers.add(Who::Display(display));
        let pixel_addr = address(display.0);
        self.join(
            peer,
            Role::Display {
                display,
                pixel_addr,
            },
            display.0,
        );
        let now = self.master_now();
        self.master.handle_message(peer, FromNode::Ready, now);
        if self.peers.beating.insert(display) {
            self.schedule_at(self.now_us + HEARTBEAT_US, Event::DisplayBeat(display));
        }
    }

    /// A new render node joins and is ready (the first ones in the order of their speeds).
    pub(super) fn join_render_node(&mut self) {
        let k = self.peers.render_peer.len() as u64;
        if k as usize >= self.clocks.len() {
            self.clocks.push(NodeClock {
                tile_us: 100 + (37 * k) % 200,
                ..NodeClock::default()
            });
        }
        let node = RenderNodeId(k as u32);
        let (sizer, low_water) = match self.peers.batching {
            Batching::Fixed { low_water, .. } => (None, low_water),
            Batching::Measured => {
                let sizer = BatchSizer::new(1);
                let low_water = sizer.low_water(None);
                (Some(sizer), low_water)
            }
        };
        let sim_node = SimNode {
            worker: RenderWorker::new(self.grid.len() as u32, low_water),
            busy: false,
            sizer,
        };
        self.nodes.insert(node, sim_node);
        let peer = self.peers.add(Who::Render(node));
        self.join(peer, Role::Render { cores: 1 }, 1000 + node.0);
        assert_eq!(
            self.master.render_node_of(peer),
            Some(node),
            "the master numbers render nodes in the order they join"
        );
        let now = self.master_now();
        self.master.handle_message(peer, FromNode::Ready, now);
        self.schedule_at(self.now_us + HEARTBEAT_US, Event::Heartbeat(node));
    }

    pub(super) fn join_control(&mut self, client: u32) -> PeerId {
        if let Some(&peer) = self.peers.control_peer.get(&client) {
            return peer;
        }
        let peer = self.peers.add(Who::Control(client));
        self.join(peer, Role::Control, client.wrapping_add(2000));
        peer
    }

    /// Sends control client `client`'s request over the network.
    pub(super) fn control(&mut self, client: u32, request: ControlRequest) {
        self.join_control(client);
        let id = self.peers.next_request;
        self.peers.next_request += 1;
        let stamp_ns = self.master_now().unix_ns;
        let msg = FromNode::Control {
            id,
            request,
            stamp_ns,
        };
        self.send(Event::FromControl(client, msg));
    }

    pub(super) fn control_said(&mut self, client: u32, msg: FromNode) {
        if let Some(peer) = self.peers.control_peer.get(&client).copied() {
            let now = self.master_now();
            self.master.handle_message(peer, msg, now);
        }
    }

    /// Display `display`'s connection closes.
    pub(super) fn display_leaves(&mut self, display: DisplayId) {
        let Some(peer) = self.peers.display_peer.remove(&display) else {
            return;
        };
        self.peers.who.remove(&peer);
        let now = self.master_now();
        self.master.handle_closed(peer, "the display left", now);
    }

    /// A display heartbeat timer fired: it beats while it is connected.
    pub(super) fn display_beat(&mut self, display: DisplayId) {
        match self.peers.display(display) {
            Some(peer) if !self.master.frames_over() => {
                self.send(Event::FromDisplay(peer, display, FromNode::Heartbeat));
                let next = self.now_us + self.beat_delay_us();
                self.schedule_at(next, Event::DisplayBeat(display));
            }
            _ => {
                self.peers.beating.remove(&display);
            }
        }
    }

    /// What was scripted for `frame` happens now.
    pub(super) fn run_script(&mut self, frame: FrameId) {
        let due: Vec<Scripted> = self
            .script
            .iter()
            .filter(|(f, _)| *f == frame)
            .map(|(_, s)| s.clone())
            .collect();
        for scripted in due {
            match scripted {
                Scripted::DisplayLeaves {
                    display,
                    back_after_us,
                } => {
                    // Mid-frame, as a process that dies does.
                    let at = self.now_us + self.net.latency_us() * 2 + 150;
                    self.schedule_at(at, Event::DisplayLeaves(display));
                    if let Some(after) = back_after_us {
                        self.schedule_at(at + after, Event::DisplayJoins(display));
                    }
                }
                Scripted::Control { client, request } => self.control(client, request),
                Scripted::RenderJoins => {
                    let at = self.now_us + self.net.latency_us();
                    self.schedule_at(at, Event::RenderJoins);
                }
            }
        }
    }

    /// A node answers the master's shutdown with its figures.
    pub(super) fn stats_of(who: Who) -> Option<FromNode> {
        match who {
            Who::Render(_) => Some(FromNode::Stats(NodeStats::Render(Default::default()))),
            Who::Display(_) => Some(FromNode::Stats(NodeStats::Display(Default::default()))),
            Who::Control(_) => None,
        }
    }

    /// Display `display` leaves as frame `frame` starts, and joins again `back_after_us` later
    /// (never, if `None`), as a display process that is restarted does.
    pub fn display_leaves_at(
        &mut self,
        display: DisplayId,
        frame: FrameId,
        back_after_us: Option<u64>,
    ) {
        let scripted = Scripted::DisplayLeaves {
            display,
            back_after_us,
        };
        self.script.push((frame, scripted));
    }

    /// Control client `client` (joined on first use) sends `request` as frame `frame` starts.
    pub fn control_at(&mut self, frame: FrameId, client: u32, request: ControlRequest) {
        self.script
            .push((frame, Scripted::Control { client, request }));
    }

    /// A new render node joins the running wall as frame `frame` starts.
    pub fn render_node_joins_at(&mut self, frame: FrameId) {
        self.script.push((frame, Scripted::RenderJoins));
    }

    /// Every answer the control clients received, in order.
    pub fn control_answers(&self) -> &[ControlAnswer] {
        &self.peers.answers
    }

    /// The rank each render node was last told it holds (a shared scene only).
    pub fn ranks(&self) -> &BTreeMap<RenderNodeId, Option<u32>> {
        &self.peers.ranks
    }

    /// The master, to ask about the run's state.
    pub fn master(&self) -> &Master {
        &self.master
    }

    /// The run's report, or what ended it, once the run is over.
    pub fn take_outcome(
        &mut self,
    ) -> Option<Result<crate::master::report::Report, crate::master::RunError>> {
        self.master.take_outcome()
    }
}
