//! A whole wall in one process, no sockets: the real [`Coordinator`], [`RenderWorker`]s and
//! [`FrameAssembler`]s exchanging the real messages through a simulated network with a virtual
//! clock, seeded latency and scripted render-node deaths.
//!
//! Pixels are a cheap function of (frame, tile, byte) instead of ray-traced, so hundreds of
//! virtual nodes run in milliseconds and every presented frame can be checked byte for byte.

use crate::assemble::FrameAssembler;
use crate::balance::{BalanceConfig, Coordinator, Output};
use crate::protocol::{FrameId, FromNode, RenderNodeId, ToNode};
use crate::render::{Camera, CameraMode, RenderParams};
use crate::wall::{DisplayId, TileGrid, TileId, WallLayout};
use crate::worker::RenderWorker;
use glam::Vec3;
use std::cmp::Reverse;
use std::collections::{BTreeMap, BinaryHeap};
use std::time::{Duration, Instant};

enum Event {
    FromRender(RenderNodeId, FromNode),
    FromDisplay(DisplayId, FromNode),
    ToRender(RenderNodeId, ToNode),
    ToDisplay(DisplayId, ToNode),
    Pixels {
        display: DisplayId,
        frame: FrameId,
        tile: TileId,
    },
    Rendered(RenderNodeId, FrameId, Vec<TileId>),
    Delivered(RenderNodeId, FrameId, Vec<TileId>),
    Kill(RenderNodeId),
}

struct SimNode {
    worker: RenderWorker,
    busy: bool,
    /// Virtual microseconds to render one tile.
    tile_us: u64,
}

/// The deterministic pixel bytes of `tile` in `frame`.
pub fn sim_pixels(grid: &TileGrid, frame: FrameId, tile: TileId) -> Vec<u8> {
    let t = grid.tile(tile).expect("tile of the grid");
    (0..t.pixel_count() * 3)
        .map(|i| {
            (i as u64)
                .wrapping_mul(31)
                .wrapping_add(tile.0 as u64 * 7 + frame.0 * 13) as u8
        })
        .collect()
}

pub struct SimWall {
    grid: TileGrid,
    coordinator: Coordinator,
    nodes: BTreeMap<RenderNodeId, SimNode>,
    displays: Vec<FrameAssembler>,
    presented: Vec<Vec<FrameId>>,
    /// Frames whose presented pixels differed from what was rendered.
    corrupt: Vec<(DisplayId, FrameId)>,
    events: BinaryHeap<Reverse<(u64, u64, usize)>>,
    slab: Vec<Option<Event>>,
    seq: u64,
    now_us: u64,
    base: Instant,
    rng: u64,
    /// One-way latency of every link, in virtual microseconds, before jitter.
    pub latency_us: u64,
    kills: Vec<(RenderNodeId, FrameId)>,
    link_clock: std::collections::HashMap<(u8, u32), u64>,
    /// Tiles a render node takes from its queue at once.
    pub batch: usize,
}

impl SimWall {
    /// A wall of `layout` with `render_nodes` nodes; node k renders a tile in `100 + 37k % 200` µs.
    pub fn new(seed: u64, layout: WallLayout, render_nodes: u32) -> Self {
        let grid = TileGrid::new(layout);
        let camera = CameraMode::Fixed(Camera {
            eye: Vec3::Z,
            target: Vec3::ZERO,
            up: Vec3::Y,
            fov_y_deg: 45.0,
        });
        let coordinator = Coordinator::new(
            grid.len() as u32,
            layout.display_count(),
            camera,
            RenderParams::interactive(),
            None,
            BalanceConfig::default(),
        );
        let displays = layout
            .screens()
            .map(|s| FrameAssembler::new(&grid, s))
            .collect();
        let mut sim = SimWall {
            coordinator,
            nodes: BTreeMap::new(),
            displays,
            presented: vec![Vec::new(); layout.display_count() as usize],
            corrupt: Vec::new(),
            events: BinaryHeap::new(),
            slab: Vec::new(),
            seq: 0,
            now_us: 0,
            base: Instant::now(),
            rng: seed | 1,
            latency_us: 50,
            kills: Vec::new(),
            link_clock: Default::default(),
            batch: 2,
            grid,
        };
        for k in 0..render_nodes {
            let id = RenderNodeId(k);
            sim.nodes.insert(
                id,
                SimNode {
                    worker: RenderWorker::new(4),
                    busy: false,
                    tile_us: 100 + (37 * k as u64) % 200,
                },
            );
        }
        sim
    }

    /// Render node `node` dies shortly after frame `frame` starts, with tiles of it in hand.
    pub fn kill_at(&mut self, node: RenderNodeId, frame: FrameId) {
        self.kills.push((node, frame));
    }

    /// Frames presented by each display, in order.
    pub fn presented(&self, display: DisplayId) -> &[FrameId] {
        &self.presented[display.0 as usize]
    }

    pub fn corrupt_frames(&self) -> &[(DisplayId, FrameId)] {
        &self.corrupt
    }

    pub fn live_render_nodes(&self) -> usize {
        self.nodes.len()
    }

    pub fn virtual_time(&self) -> Duration {
        Duration::from_micros(self.now_us)
    }

    fn now(&self) -> Instant {
        self.base + Duration::from_micros(self.now_us)
    }

    fn jitter(&mut self) -> u64 {
        // xorshift64: deterministic per seed.
        self.rng ^= self.rng << 13;
        self.rng ^= self.rng >> 7;
        self.rng ^= self.rng << 17;
        self.rng % (self.latency_us / 2 + 1)
    }

    fn schedule(&mut self, delay_us: u64, event: Event) {
        self.slab.push(Some(event));
        self.events.push(Reverse((
            self.now_us + delay_us,
            self.seq,
            self.slab.len() - 1,
        )));
        self.seq += 1;
    }

    /// Sends over a link with latency and jitter but, like a QUIC stream, in order: an event
    /// never overtakes an earlier one on the same link.
    fn send(&mut self, event: Event) {
        let link = match &event {
            Event::FromRender(n, _) | Event::ToRender(n, _) => (0, n.0),
            Event::FromDisplay(d, _) | Event::ToDisplay(d, _) => (1, d.0),
            // Each pixel batch is its own stream: they may overtake each other.
            _ => (2, self.seq as u32),
        };
        let at = self.now_us + self.latency_us + self.jitter();
        let last = self.link_clock.entry(link).or_insert(0);
        let at = at.max(*last);
        *last = at;
        self.schedule(at - self.now_us, event);
    }

    /// Runs until nothing is left to happen (the last `Present` delivered) or a bound on
    /// simulated events is hit. Returns the number of frames presented.
    pub fn run_frames(&mut self, frames: u64) -> u64 {
        self.coordinator.set_frame_limit(Some(frames));
        let now = self.now();
        let ids: Vec<RenderNodeId> = self.nodes.keys().copied().collect();
        for id in ids {
            self.coordinator.handle_render_joined(id, now);
        }
        self.coordinator.start(now);
        self.pump();
        let budget = 200 * frames * (self.grid.len() as u64 + 10) * (self.nodes.len() as u64 + 1);
        let mut steps = 0;
        while let Some(Reverse((at, _, slot))) = self.events.pop() {
            steps += 1;
            if steps > budget {
                break;
            }
            self.now_us = at;
            let event = self.slab[slot].take().expect("each event runs once");
            self.handle(event);
            self.pump();
        }
        self.coordinator.presented()
    }

    fn handle(&mut self, event: Event) {
        let now = self.now();
        match event {
            Event::Kill(node) => {
                if self.nodes.remove(&node).is_some() {
                    self.coordinator.handle_render_left(node, now);
                }
            }
            Event::FromRender(node, msg) => {
                if !self.nodes.contains_key(&node) {
                    return;
                }
                if let FromNode::TilesDone {
                    frame,
                    tiles,
                    want_more,
                } = msg
                {
                    self.coordinator
                        .handle_tiles_done(node, frame, &tiles, want_more, now)
                        .expect("render nodes only report their own tiles");
                }
            }
            Event::FromDisplay(display, msg) => {
                if let FromNode::FrameComplete { frame } = msg {
                    self.coordinator
                        .handle_frame_complete(display, frame, now)
                        .expect("displays report frames in flight");
                }
            }
            Event::ToRender(node, msg) => {
                let Some(n) = self.nodes.get_mut(&node) else {
                    return;
                };
                n.worker.handle_message(&msg).expect("valid assignment");
                self.start_rendering(node);
            }
            Event::ToDisplay(display, msg) => {
                if let ToNode::Present { frame } = msg {
                    let shown = self.displays[display.0 as usize]
                        .handle_present(frame)
                        .expect("present only complete frames");
                    let screen = self.grid.layout().screen(display).expect("display");
                    if !self.frame_matches(screen, frame, &shown.rgb) {
                        self.corrupt.push((display, frame));
                    }
                    self.presented[display.0 as usize].push(frame);
                }
            }
            Event::Pixels {
                display,
                frame,
                tile,
            } => {
                let rgb = sim_pixels(&self.grid, frame, tile);
                let done = self.displays[display.0 as usize]
                    .handle_tile(frame, tile, &rgb)
                    .expect("tiles go to their own display");
                if let Some(frame) = done {
                    self.send(Event::FromDisplay(
                        display,
                        FromNode::FrameComplete { frame },
                    ));
                }
            }
            Event::Rendered(node, frame, tiles) => {
                let Some(n) = self.nodes.get_mut(&node) else {
                    return;
                };
                n.busy = false;
                for &tile in &tiles {
                    let display = self.grid.tile(tile).expect("tile").display;
                    self.send(Event::Pixels {
                        display,
                        frame,
                        tile,
                    });
                }
                // The display's acknowledgement comes back after a round trip.
                let rtt = 2 * self.latency_us;
                self.schedule(rtt, Event::Delivered(node, frame, tiles));
                self.start_rendering(node);
            }
            Event::Delivered(node, frame, tiles) => {
                let Some(n) = self.nodes.get_mut(&node) else {
                    return;
                };
                let report = n.worker.handle_delivered(frame, &tiles);
                self.send(Event::FromRender(node, report));
            }
        }
    }

    fn start_rendering(&mut self, node: RenderNodeId) {
        let batch = self.batch;
        let Some(n) = self.nodes.get_mut(&node) else {
            return;
        };
        if n.busy {
            return;
        }
        let request = n.worker.poll_request();
        let Some((start, tiles)) = n.worker.next_batch(batch) else {
            if let Some(r) = request {
                self.send(Event::FromRender(node, r));
            }
            return;
        };
        n.busy = true;
        let cost = n.tile_us * tiles.len() as u64;
        self.schedule(cost, Event::Rendered(node, start.frame, tiles));
        if let Some(r) = request {
            self.send(Event::FromRender(node, r));
        }
    }

    fn pump(&mut self) {
        while let Some(out) = self.coordinator.poll_output() {
            match out {
                Output::ToRender(node, msg) => self.send(Event::ToRender(node, msg)),
                Output::ToDisplays(msg) => {
                    for d in 0..self.displays.len() as u32 {
                        self.send(Event::ToDisplay(DisplayId(d), msg.clone()));
                    }
                }
                Output::FrameStarted(frame) => {
                    let doomed: Vec<RenderNodeId> = self
                        .kills
                        .iter()
                        .filter(|(_, f)| *f == frame)
                        .map(|(n, _)| *n)
                        .collect();
                    for node in doomed {
                        // Late enough that it holds tiles, early enough that they are unfinished.
                        let at = self.latency_us * 2 + 150;
                        self.schedule(at, Event::Kill(node));
                    }
                }
                Output::FrameRendered(_)
                | Output::FramePresented(_)
                | Output::Finished
                | Output::Stalled => {}
            }
        }
    }

    fn frame_matches(&self, screen: crate::wall::ScreenRect, frame: FrameId, rgb: &[u8]) -> bool {
        self.grid.display_tiles(screen.id).iter().all(|t| {
            let expected = sim_pixels(&self.grid, frame, t.id);
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
