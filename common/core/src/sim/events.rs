//! What each simulated event does: the virtual nodes' side of the protocol, the pixels'
//! journey to the assemblers, and the master's outputs turned into events.

use super::peers::STEERING_CLIENT;
use super::*;

impl SimWall {
    pub(super) fn handle(&mut self, event: Event) {
        match event {
            Event::Kill(node) => self.kill(node),
            Event::DisplayBeat(display) => self.display_beat(display),
            Event::DisplayLeaves(display) => self.display_leaves(display),
            Event::DisplayJoins(display) => self.join_display(display),
            Event::RenderJoins => self.join_render_node(),
            Event::FromControl(client, msg) => self.control_said(client, msg),
            Event::Heartbeat(node) => {
                // A dead node's timer dies with it; a finished run needs no more.
                if self.nodes.contains_key(&node) && !self.master.frames_over() {
                    self.send(Event::FromRender(node, FromNode::Heartbeat));
                    let next = self.now_us + self.beat_delay_us();
                    self.schedule_at(next, Event::Heartbeat(node));
                }
            }
            Event::FromRender(node, msg) => {
                // A dead node's connection is gone, and with it what it sent.
                if let (true, Some(peer)) =
                    (self.nodes.contains_key(&node), self.peers.render(node))
                {
                    self.master.handle_message(peer, msg, self.master_now());
                }
            }
            Event::FromDisplay(peer, _, msg) => {
                if self.peers.who(peer).is_some() {
                    self.master.handle_message(peer, msg, self.master_now());
                }
            }
            Event::ToRender(node, msg) => self.render_node_receives(node, msg),
            Event::ToDisplay(peer, display, msg) => self.display_receives(peer, display, msg),
            Event::Pixels {
                from,
                last_tx,
                display,
                frame,
                state,
                tiles,
            } => self.handle_pixels(from, last_tx, display, (frame, state), &tiles),
            Event::Rendered(node, frame, state, tiles) => {
                self.rendered(node, (frame, state), tiles)
            }
            Event::Delivered(node, frame, tiles) => {
                let now = self.now();
                let Some(n) = self.nodes.get_mut(&node) else {
                    return;
                };
                let report = n.worker.handle_delivered(frame, &tiles, now);
                self.send(Event::FromRender(node, report));
            }
        }
    }

    /// Render node `node` dies: its clock stops, and what it sends from now on is lost.
    fn kill(&mut self, node: RenderNodeId) {
        if self.nodes.remove(&node).is_some() {
            let clock = &mut self.clocks[node.0 as usize];
            if let Some(since) = clock.busy_since.take() {
                clock.busy_us += self.now_us - since;
            }
            clock.died_at = Some(self.now_us);
        }
    }

    /// A render node receives a message of the master's.
    fn render_node_receives(&mut self, node: RenderNodeId, msg: ToNode) {
        let now = self.now();
        let Some(n) = self.nodes.get_mut(&node) else {
            return;
        };
        if matches!(msg, ToNode::Shutdown) {
            let stats = Self::stats_of(peers::Who::Render(node));
            self.send(Event::FromRender(node, stats.expect("a render node's")));
            return;
        }
        n.worker
            .handle_message(&msg, now)
            .expect("valid assignment");
        self.start_rendering(node);
    }

    /// A display receives a message of the master's on connection `peer` (one that closed
    /// receives nothing).
    fn display_receives(&mut self, peer: PeerId, display: DisplayId, msg: ToNode) {
        if self.peers.who(peer).is_none() {
            return;
        }
        let d = display.0 as usize;
        match msg {
            ToNode::StartAt { frame } => self.displays[d].start_at(frame),
            ToNode::Shutdown => {
                let stats = Self::stats_of(peers::Who::Display(display));
                let stats = stats.expect("a display's");
                self.send(Event::FromDisplay(peer, display, stats));
            }
            ToNode::FrameStart(start) => {
                self.displays[d]
                    .handle_frame_start(start.frame, start.state)
                    .expect("the master starts at most two frames ahead");
                self.states.insert(start.frame, start.state);
            }
            ToNode::Present { frame } | ToNode::PresentAt { frame, .. } => {
                self.present(peer, display, frame)
            }
            ToNode::Cancel { frame } => {
                let assembler = &mut self.displays[d];
                assembler.cancel_up_to(frame);
                if let Some(frame) = assembler.poll_complete() {
                    let msg = FromNode::FrameComplete { frame };
                    self.send(Event::FromDisplay(peer, display, msg));
                }
            }
            _ => {}
        }
    }

    /// A display presents `frame`: what it shows is checked against what was rendered.
    fn present(&mut self, peer: PeerId, display: DisplayId, frame: FrameId) {
        let assembler = &mut self.displays[display.0 as usize];
        let shown = assembler
            .handle_present(frame)
            .expect("present only complete frames");
        if let Some(frame) = assembler.poll_complete() {
            let msg = FromNode::FrameComplete { frame };
            self.send(Event::FromDisplay(peer, display, msg));
        }
        let screen = self.pixel_grid.layout().screen(display).expect("display");
        if !self.frame_matches(screen, frame, self.states[&frame], &shown.rgb) {
            self.corrupt.push((display, frame));
        }
        self.presented[display.0 as usize].push(frame);
        self.last_present_us = self.now_us;
    }

    /// Render node `node` finished a batch: its pixels leave for their displays, one batch per
    /// display as the real node batches its writes, and it takes its next batch.
    fn rendered(
        &mut self,
        node: RenderNodeId,
        (frame, state): (FrameId, StateId),
        tiles: Vec<TileId>,
    ) {
        let Some(n) = self.nodes.get_mut(&node) else {
            return;
        };
        n.busy = false;
        let clock = &mut self.clocks[node.0 as usize];
        if let Some(since) = clock.busy_since.take() {
            clock.busy_us += self.now_us - since;
            if let Some(sizer) = &mut n.sizer {
                sizer.record(tiles.len(), Duration::from_micros(self.now_us - since));
                n.worker
                    .set_low_water(sizer.low_water(n.worker.round_trip()));
            }
        }
        let mut arrived = self.now_us;
        let mut rest = &tiles[..];
        while let Some(first) = rest.first() {
            let display = self.grid.tile(*first).expect("tile").display;
            let n = rest
                .iter()
                .take_while(|t| self.grid.tile(**t).expect("tile").display == display)
                .count();
            let d = self.net.deliver(self.now_us, Stream::Own);
            arrived = arrived.max(d.at);
            let pixels = Event::Pixels {
                from: node,
                last_tx: d.last_tx,
                display,
                frame,
                state,
                tiles: rest[..n].to_vec(),
            };
            self.schedule_at(d.at, pixels);
            rest = &rest[n..];
        }
        // The node learns its pixels arrived from the displays' acknowledgements.
        let ack = self.net.deliver(arrived, Stream::Own).at;
        self.schedule_at(ack, Event::Delivered(node, frame, tiles));
        self.start_rendering(node);
    }

    fn handle_pixels(
        &mut self,
        from: RenderNodeId,
        last_tx: u64,
        display: DisplayId,
        (frame, state): (FrameId, StateId),
        tiles: &[TileId],
    ) {
        let alive = self.nodes.contains_key(&from);
        if self.clocks[from.0 as usize]
            .died_at
            .is_some_and(|d| d < last_tx)
        {
            self.lost_with_sender += 1;
            return;
        }
        for &tile in tiles {
            // A re-rendered copy of a tile whose first copy completed the frame.
            if frame < self.displays[display.0 as usize].next_present() {
                self.late_tiles += 1;
                if alive {
                    self.late_from_live += 1;
                }
            }
            let rgb = sim_pixels(&self.pixel_grid, frame, state, tile);
            let assembler = &mut self.displays[display.0 as usize];
            if let Err(e) = assembler.handle_tile(frame, state, tile, &rgb) {
                panic!("display {} refused a tile: {e}", display.0);
            }
            if let Some(frame) = assembler.poll_complete() {
                // A display that left takes its frames with it.
                if let Some(peer) = self.peers.display(display) {
                    let msg = FromNode::FrameComplete { frame };
                    self.send(Event::FromDisplay(peer, display, msg));
                }
            }
        }
    }

    fn start_rendering(&mut self, node: RenderNodeId) {
        let now = self.now();
        let Some(n) = self.nodes.get_mut(&node) else {
            return;
        };
        if n.busy {
            return;
        }
        let batch = n.sizer.as_ref().map_or(self.batch, BatchSizer::batch);
        let request = n.worker.poll_request(now);
        let Some((start, tiles)) = n.worker.next_batch(batch) else {
            if let Some(r) = request {
                self.send(Event::FromRender(node, r));
            }
            return;
        };
        n.busy = true;
        let clock = &mut self.clocks[node.0 as usize];
        clock.busy_since = Some(self.now_us);
        let full = u64::from(self.grid.layout().tile_size()).pow(2).max(1);
        let cost: u64 = tiles
            .iter()
            .map(|t| {
                let pixels = self.grid.tile(*t).expect("tile").pixel_count() as u64;
                (clock.tile_us * pixels).div_ceil(full)
            })
            .sum();
        self.schedule_at(
            self.now_us + cost,
            Event::Rendered(node, start.frame, start.state, tiles),
        );
        if let Some(r) = request {
            self.send(Event::FromRender(node, r));
        }
    }

    /// Carries out what the master said: messages over the network, its events here.
    pub(super) fn pump(&mut self) {
        loop {
            if let Some(t) = self.master.poll_transmit() {
                self.route(t.peer, t.msg);
            } else if let Some(event) = self.master.poll_event() {
                self.on_master_event(event);
            } else if let Some((peer, _)) = self.master.poll_close() {
                // Noted: a live node's connection closed is a false death.
                self.note_close(peer);
            } else {
                return;
            }
        }
    }

    /// A message from the master to one of its peers.
    fn route(&mut self, peer: PeerId, msg: ToNode) {
        match self.peers.who(peer) {
            Some(peers::Who::Render(node)) => match msg {
                ToNode::BlockHolders { rank, .. } => {
                    self.peers.ranks.insert(node, rank);
                }
                ToNode::FrameStart(_) | ToNode::Assign { .. } | ToNode::Shutdown => {
                    self.send(Event::ToRender(node, msg))
                }
                // The handshake and where displays are: the simulated network knows.
                _ => {}
            },
            Some(peers::Who::Display(d)) => self.send(Event::ToDisplay(peer, d, msg)),
            Some(peers::Who::Control(client)) => {
                if let ToNode::ControlReply { id, reply } = msg {
                    let answer = ControlAnswer { client, id, reply };
                    self.peers.answers.push(answer);
                }
            }
            None => {}
        }
    }

    fn on_master_event(&mut self, event: MasterEvent) {
        match event {
            MasterEvent::FrameStarted(started) => {
                let frame = started.0.frame;
                if frame.0 == 0 {
                    self.span.0 = Some(self.now_us);
                }
                if self.change_every_frame {
                    let spp = 1 + (frame.0 % 2) as u32;
                    let peer = self.join_control(STEERING_CLIENT);
                    let msg = FromNode::Control {
                        id: frame.0 as u32,
                        request: ControlRequest::Change(vec![StateChange::Spp(spp)]),
                        stamp_ns: self.master_now().unix_ns,
                    };
                    self.master.handle_message(peer, msg, self.master_now());
                }
                let doomed: Vec<RenderNodeId> = self
                    .kills
                    .iter()
                    .filter(|(_, f)| *f == frame)
                    .map(|(n, _)| *n)
                    .collect();
                for node in doomed {
                    // Late enough that it holds tiles, early enough that they are unfinished.
                    let at = self.now_us + self.net.latency_us() * 2 + 150;
                    self.schedule_at(at, Event::Kill(node));
                }
                self.run_script(frame);
            }
            MasterEvent::FrameRendered(frame) => {
                if frame.0 + 1 == self.frames {
                    self.span.1 = Some(self.now_us);
                }
            }
            MasterEvent::Started | MasterEvent::FramePresented(_) => {}
        }
    }

    fn frame_matches(
        &self,
        screen: ScreenRect,
        frame: FrameId,
        state: StateId,
        rgb: &[u8],
    ) -> bool {
        self.pixel_grid.display_tiles(screen.id).iter().all(|t| {
            let expected = sim_pixels(&self.pixel_grid, frame, state, t.id);
            let row = t.width as usize * 3;
            (0..t.height as usize).all(|r| {
                let at = (((t.y - screen.y) as usize + r) * screen.width as usize
                    + (t.x - screen.x) as usize)
                    * 3;
                rgb[at..at + row] == expected[r * row..(r + 1) * row]
            })
        })
    }
}
