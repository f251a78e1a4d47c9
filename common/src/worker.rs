//! The render node's sans-IO scheduling: which tiles to render next, when to ask for more.
//!
//! A node keeps its queue from running dry by asking for the next batch while it still has
//! `low_water` tiles left, so the round trip to the master hides behind rendering. At most one
//! request is outstanding; an empty answer means the frame's pool is drained, and the node stays
//! quiet until the master sends it something new.

use crate::protocol::{to_ranges, FrameId, FrameStart, FromNode, TileRange, ToNode};
use crate::wall::TileId;
use std::collections::{BTreeMap, VecDeque};

pub struct RenderWorker {
    queue: VecDeque<(FrameId, TileId)>,
    frames: BTreeMap<FrameId, FrameStart>,
    request_outstanding: bool,
    starved: bool,
    low_water: usize,
}

impl RenderWorker {
    /// `low_water`: ask for more when fewer tiles than this are queued.
    pub fn new(low_water: usize) -> Self {
        RenderWorker {
            queue: VecDeque::new(),
            frames: BTreeMap::new(),
            request_outstanding: false,
            starved: false,
            low_water,
        }
    }

    pub fn queued(&self) -> usize {
        self.queue.len()
    }

    /// Takes a message from the master. Returns an error text for messages that make no sense
    /// to a render node (an assignment for a frame it was never told about).
    pub fn handle_message(&mut self, msg: &ToNode) -> Result<(), String> {
        match msg {
            ToNode::FrameStart(start) => {
                self.frames.insert(start.frame, *start);
                // The master keeps at most two frames in flight; older starts are history.
                while self.frames.len() > 4 {
                    self.frames.pop_first();
                }
                self.starved = false;
            }
            ToNode::Assign { frame, tiles } => {
                self.request_outstanding = false;
                if tiles.is_empty() {
                    self.starved = true;
                    return Ok(());
                }
                if !self.frames.contains_key(frame) {
                    return Err(format!("assignment for frame {} before its start", frame.0));
                }
                self.starved = false;
                self.queue
                    .extend(tiles.iter().flat_map(|r| r.tiles()).map(|t| (*frame, t)));
            }
            _ => {}
        }
        Ok(())
    }

    /// The next tiles to render: up to `max` queued tiles of one frame, with that frame's state.
    pub fn next_batch(&mut self, max: usize) -> Option<(FrameStart, Vec<TileId>)> {
        let &(frame, _) = self.queue.front()?;
        let start = *self.frames.get(&frame)?;
        let mut tiles = Vec::new();
        while tiles.len() < max {
            match self.queue.front() {
                Some(&(f, t)) if f == frame => {
                    tiles.push(t);
                    self.queue.pop_front();
                }
                _ => break,
            }
        }
        Some((start, tiles))
    }

    fn latest_frame(&self) -> FrameId {
        self.frames
            .keys()
            .next_back()
            .copied()
            .unwrap_or(FrameId(0))
    }

    /// Tiles reached their displays: the report to the master, asking for more if low.
    pub fn handle_delivered(&mut self, frame: FrameId, tiles: &[TileId]) -> FromNode {
        let want_more = self.should_request();
        if want_more {
            self.request_outstanding = true;
        }
        FromNode::TilesDone {
            frame,
            tiles: to_ranges(tiles.iter().copied()),
            want_more,
        }
    }

    /// A request for more work on its own, when the queue ran low without a delivery to carry it.
    pub fn poll_request(&mut self) -> Option<FromNode> {
        if !self.should_request() {
            return None;
        }
        self.request_outstanding = true;
        let frame = self.latest_frame();
        Some(FromNode::TilesDone {
            frame,
            tiles: Vec::<TileRange>::new(),
            want_more: true,
        })
    }

    fn should_request(&self) -> bool {
        !self.request_outstanding
            && !self.starved
            && self.queue.len() < self.low_water
            && !self.frames.is_empty()
    }
}
