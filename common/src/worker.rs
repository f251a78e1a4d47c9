//! The render node's sans-IO scheduling: which tiles to render next, when to ask for more.
//!
//! A node keeps its queue from running dry by asking for the next batch while it still has
//! `low_water` tiles left, so the round trip to the master hides behind rendering. At most one
//! request is outstanding; an empty answer means the frame's pool is drained, and the node stays
//! quiet until the master sends it something new.
//!
//! Every `FrameStart` is followed by the node's static share of that frame (possibly empty).
//! The node waits for that share before it asks for more: a request sent between the two
//! would be answered from the pool on top of the share, so at frame start every node, slow or
//! fast, would take a slice of the pool the guided schedule keeps for whoever runs dry first.
//! An empty share is not an empty pool (with no static fraction the pool is the whole frame),
//! so it does not starve the node.

use crate::protocol::{to_ranges, FrameId, FrameStart, FromNode, TileRange, ToNode};
use crate::wall::TileId;
use std::collections::{BTreeMap, VecDeque};

pub struct RenderWorker {
    queue: VecDeque<(FrameId, TileId)>,
    frames: BTreeMap<FrameId, FrameStart>,
    request_outstanding: bool,
    starved: bool,
    /// A `FrameStart` arrived and its static share has not.
    awaiting_share: bool,
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
            awaiting_share: false,
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
                self.awaiting_share = true;
            }
            ToNode::Assign { frame, tiles } => {
                let share = std::mem::take(&mut self.awaiting_share);
                if !share {
                    self.request_outstanding = false;
                }
                if tiles.is_empty() {
                    // An empty answer means the pool is drained; an empty share says nothing
                    // about the pool.
                    if !share {
                        self.starved = true;
                    }
                    return Ok(());
                }
                if !self.frames.contains_key(frame) {
                    return Err(format!("assignment for frame {} before its start", frame.0));
                }
                self.starved = false;
                // Older frames first: tiles of frame f given back by a node that died arrive
                // after this node's share of f+1, and f holds up the swap barrier.
                let at = self.queue.partition_point(|(f, _)| f <= frame);
                let mut later = self.queue.split_off(at);
                self.queue
                    .extend(tiles.iter().flat_map(|r| r.tiles()).map(|t| (*frame, t)));
                self.queue.append(&mut later);
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
            && !self.awaiting_share
            && self.queue.len() < self.low_water
            && !self.frames.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::{Camera, RenderParams};
    use glam::Vec3;

    fn start(frame: u64) -> ToNode {
        ToNode::FrameStart(FrameStart {
            frame: FrameId(frame),
            camera: Camera {
                eye: Vec3::Z,
                target: Vec3::ZERO,
                up: Vec3::Y,
                fov_y_deg: 45.0,
            },
            params: RenderParams::interactive(),
        })
    }

    fn assign(frame: u64, start: u32, end: u32) -> ToNode {
        ToNode::Assign {
            frame: FrameId(frame),
            tiles: if start == end {
                Vec::new()
            } else {
                vec![TileRange { start, end }]
            },
        }
    }

    #[test]
    fn no_request_between_a_frame_start_and_its_share() {
        let mut w = RenderWorker::new(4);
        w.handle_message(&start(0)).unwrap();
        assert_eq!(w.poll_request(), None);
        w.handle_message(&assign(0, 0, 6)).unwrap();
        assert_eq!(
            w.poll_request(),
            None,
            "six queued tiles are above the low water"
        );
        let _ = w.next_batch(3);
        assert!(w.poll_request().is_some());
    }

    #[test]
    fn an_empty_share_is_not_an_empty_pool_but_an_empty_answer_is() {
        let mut w = RenderWorker::new(4);
        w.handle_message(&start(0)).unwrap();
        w.handle_message(&assign(0, 0, 0)).unwrap();
        assert!(w.poll_request().is_some());
        w.handle_message(&assign(0, 0, 0)).unwrap();
        assert_eq!(w.poll_request(), None, "the pool is drained");
        w.handle_message(&start(1)).unwrap();
        w.handle_message(&assign(1, 0, 0)).unwrap();
        assert!(w.poll_request().is_some(), "a new frame has a new pool");
    }

    #[test]
    fn tiles_of_an_older_frame_are_rendered_before_a_newer_frames_share() {
        let mut w = RenderWorker::new(1);
        w.handle_message(&start(0)).unwrap();
        w.handle_message(&assign(0, 0, 2)).unwrap();
        w.handle_message(&start(1)).unwrap();
        w.handle_message(&assign(1, 10, 12)).unwrap();
        // Tiles of frame 0 given back by a node that died.
        w.handle_message(&assign(0, 5, 6)).unwrap();
        let order: Vec<(u64, Vec<u32>)> = std::iter::from_fn(|| w.next_batch(8))
            .map(|(s, tiles)| (s.frame.0, tiles.iter().map(|t| t.0).collect()))
            .collect();
        assert_eq!(order, vec![(0, vec![0, 1, 5]), (1, vec![10, 11])]);
    }
}
