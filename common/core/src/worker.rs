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

use std::collections::{BTreeMap, VecDeque};
use std::time::{Duration, Instant};
use tessera_model::wall::TileId;
use tessera_protocol::{to_ranges, FrameId, FrameStart, FromNode, TileRange, ToNode};

/// A message from the master that makes no sense to a render node.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum WorkerError {
    /// Tiles of a frame whose `FrameStart` this node never received (or long forgot).
    #[error("the master assigned tiles of frame {0:?} before starting it")]
    AssignBeforeStart(FrameId),
    /// A range of tiles that runs past the wall's.
    #[error("the master assigned tiles {start}..{end}, but the wall has {tiles}")]
    NoSuchTiles {
        /// The range's first tile.
        start: u32,
        /// The range's end, exclusive.
        end: u32,
        /// How many tiles the wall has.
        tiles: u32,
    },
    /// A message only displays or the handshake take; the message's kind.
    #[error(
        "the master sent a render node a {0} message, which only displays or the handshake take"
    )]
    NotForRenderNodes(&'static str),
}

/// A render node's queue of tiles, and when to ask the master for more.
///
/// # Examples
///
/// ```
/// use std::time::Instant;
/// use glam::Vec3;
/// use tessera_core::worker::RenderWorker;
/// use tessera_model::camera::Camera;
/// use tessera_model::params::RenderParams;
/// use tessera_protocol::{FrameId, FrameStart, FromNode, TileRange, ToNode};
/// use tessera_model::state::StateId;
///
/// let now = Instant::now();
/// // A wall of 100 tiles; ask for more below 4 queued tiles.
/// let mut worker = RenderWorker::new(100, 4);
/// let camera = Camera::new(Vec3::Z, Vec3::ZERO, Vec3::Y, 45.0).unwrap();
/// let start = FrameStart::new(FrameId(0), StateId(0), camera, RenderParams::interactive());
/// worker.handle_message(&ToNode::FrameStart(start), now)?;
/// // The static share: tiles 0..6.
/// let share = ToNode::Assign { frame: FrameId(0), tiles: vec![TileRange::new(0, 6).unwrap()] };
/// worker.handle_message(&share, now)?;
///
/// let (frame_start, tiles) = worker.next_batch(3).unwrap();
/// assert_eq!((frame_start.frame, tiles.len()), (FrameId(0), 3));
/// // Rendered and delivered: the report asks for more, since only 3 tiles are left queued.
/// let report = worker.handle_delivered(FrameId(0), &tiles, now);
/// assert!(matches!(report, FromNode::TilesDone { want_more: true, .. }));
///
/// // Tiles the wall does not have are refused, naming them.
/// let bogus = ToNode::Assign { frame: FrameId(0), tiles: vec![TileRange::new(90, 200).unwrap()] };
/// assert!(worker.handle_message(&bogus, now).unwrap_err().to_string().contains("90..200"));
/// # Ok::<(), tessera_core::worker::WorkerError>(())
/// ```
pub struct RenderWorker {
    /// Tiles of the wall: assignments beyond are refused.
    tile_count: u32,
    queue: VecDeque<(FrameId, TileId)>,
    frames: BTreeMap<FrameId, FrameStart>,
    request_outstanding: bool,
    starved: bool,
    /// A `FrameStart` arrived and its static share has not.
    awaiting_share: bool,
    low_water: usize,
    /// When the outstanding request went out.
    request_sent: Option<Instant>,
    /// Request to answer, smoothed: how long a node waits for work it asks for.
    round_trip: Option<Duration>,
}

impl RenderWorker {
    /// A worker for a wall of `tile_count` tiles; `low_water`: ask for more when fewer tiles
    /// than this are queued.
    pub fn new(tile_count: u32, low_water: usize) -> Self {
        RenderWorker {
            tile_count,
            queue: VecDeque::new(),
            frames: BTreeMap::new(),
            request_outstanding: false,
            starved: false,
            awaiting_share: false,
            low_water,
            request_sent: None,
            round_trip: None,
        }
    }

    /// Ask for more when fewer than `low_water` tiles are queued; follows the batch size, so a
    /// node taking large batches asks early enough to hide the round trip behind one of them.
    pub fn set_low_water(&mut self, low_water: usize) {
        self.low_water = low_water;
    }

    /// Tiles queued and not yet taken by [`RenderWorker::next_batch`].
    pub fn queued(&self) -> usize {
        self.queue.len()
    }

    /// Request to answer, smoothed; `None` before the first answer.
    pub fn round_trip(&self) -> Option<Duration> {
        self.round_trip
    }

    fn request(&mut self, now: Instant) {
        self.request_outstanding = true;
        self.request_sent = Some(now);
    }

    fn answered(&mut self, now: Instant) {
        self.request_outstanding = false;
        if let Some(sent) = self.request_sent.take() {
            let sample = now.saturating_duration_since(sent);
            // Up at once, down slowly: a queue that runs dry costs more than one that is long.
            self.round_trip = Some(match self.round_trip {
                Some(old) if sample < old => old.mul_f64(0.75) + sample.mul_f64(0.25),
                _ => sample,
            });
        }
    }

    /// Takes a message from the master.
    ///
    /// # Errors
    /// Messages that make no sense to a render node: an assignment for a frame it was never
    /// told about, or of tiles the wall does not have. The worker's state is unchanged.
    pub fn handle_message(&mut self, msg: &ToNode, now: Instant) -> Result<(), WorkerError> {
        if let ToNode::Assign { tiles, .. } = msg {
            if let Some(r) = tiles.iter().find(|r| r.end() > self.tile_count) {
                return Err(WorkerError::NoSuchTiles {
                    start: r.start(),
                    end: r.end(),
                    tiles: self.tile_count,
                });
            }
        }
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
                    self.answered(now);
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
                    return Err(WorkerError::AssignBeforeStart(*frame));
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
            ToNode::Cancel { frame } => {
                // Nothing of those frames is wanted any more; ask for later work afresh.
                self.queue.retain(|(f, _)| f > frame);
                self.frames.retain(|f, _| f > frame);
                self.starved = false;
            }
            // The driver handles the shutdown; the rest is for displays or the handshake,
            // and a master that sends it to a render node is broken.
            ToNode::Shutdown => {}
            other => return Err(WorkerError::NotForRenderNodes(other.kind())),
        }
        Ok(())
    }

    /// The tiles queued to render next, in order, without taking them (to fetch what they
    /// will read ahead of them).
    pub fn upcoming(&self) -> impl Iterator<Item = TileId> + '_ {
        self.queue.iter().map(|&(_, t)| t)
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
    pub fn handle_delivered(&mut self, frame: FrameId, tiles: &[TileId], now: Instant) -> FromNode {
        let want_more = self.should_request();
        if want_more {
            self.request(now);
        }
        FromNode::TilesDone {
            frame,
            tiles: to_ranges(tiles.iter().copied()),
            want_more,
        }
    }

    /// A request for more work on its own, when the queue ran low without a delivery to carry it.
    pub fn poll_request(&mut self, now: Instant) -> Option<FromNode> {
        if !self.should_request() {
            return None;
        }
        self.request(now);
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

/// How many tiles a render node takes per batch.
///
/// Every batch pays a fixed cost whatever it holds: a hand-off to the render threads, a stream
/// per display, a report to the master. Two tiles per batch (one per thread) suit scenes whose
/// tiles take milliseconds; on a cheap scene (a backdrop, a sky) those fixed costs were most of
/// the work and held an empty-scene wall to a fifth of its link's frame rate. So a batch takes
/// as many tiles as fit in [`BatchSizer::TARGET`] at the measured cost per tile, but never fewer
/// than one per thread (and two). The estimate rises at once when tiles get dearer (the camera turning
/// from the sky to a dense mesh must not be stuck with a huge batch for long) and falls slowly.
#[derive(Clone, Debug)]
pub struct BatchSizer {
    threads: usize,
    seconds_per_tile: Option<f64>,
}

impl BatchSizer {
    /// Wall time one batch should take: large against the per-batch cost (about 0.1 ms), small
    /// against a frame, since a node finishing a frame's last batch holds up the swap barrier.
    /// On the empty-scene wall 0.5, 1 and 2 ms gave the same frame rate within the noise; on the
    /// knot scene, whose sky tiles are cheap and knot tiles dear, 2 ms lengthened the frame by
    /// 5–10 %, 0.5 ms did not.
    pub const TARGET: Duration = Duration::from_micros(500);
    /// Bounds the first batch after a scene that cost next to nothing.
    pub const MAX_TILES: usize = 1024;

    /// A sizer for a node with `threads` render threads, with no cost per tile measured yet:
    /// until one is, a batch is one tile per thread, and at least two.
    pub fn new(threads: usize) -> Self {
        BatchSizer {
            threads: threads.max(1),
            seconds_per_tile: None,
        }
    }

    /// A batch of `tiles` took `took` from hand-off to encoded pixels.
    pub fn record(&mut self, tiles: usize, took: Duration) {
        if tiles == 0 {
            return;
        }
        let sample = took.as_secs_f64() / tiles as f64;
        self.seconds_per_tile = Some(match self.seconds_per_tile {
            Some(old) if sample < old => 0.75 * old + 0.25 * sample,
            _ => sample,
        });
    }

    /// Tiles to take next.
    pub fn batch(&self) -> usize {
        let Some(per_tile) = self.seconds_per_tile else {
            return self.floor();
        };
        let fit = Self::TARGET.as_secs_f64() / per_tile.max(1e-9);
        (fit.min(Self::MAX_TILES as f64).round() as usize).max(self.floor())
    }

    /// Two tiles even for one thread: a node with a single-tile batch paid the per-batch cost
    /// twice as often for no gain in balance (measured on the latency experiment).
    fn floor(&self) -> usize {
        self.threads.max(2)
    }

    /// The queue length below which to ask the master for more: two tiles per thread, as many
    /// as a batch where batches are larger, and enough to keep rendering for one `round_trip`
    /// on top of a batch, so the answer arrives before the queue runs dry. Asking earlier than
    /// that for dear tiles would hoard them and leave the frame's tail unbalanced.
    pub fn low_water(&self, round_trip: Option<Duration>) -> usize {
        let covering = match (round_trip, self.seconds_per_tile) {
            (Some(rtt), Some(per_tile)) => {
                let tiles = rtt.as_secs_f64() / per_tile.max(1e-9);
                self.batch() + tiles.min(Self::MAX_TILES as f64).floor() as usize
            }
            _ => 0,
        };
        (2 * self.threads).max(self.batch()).max(covering)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;
    use tessera_model::camera::Camera;
    use tessera_model::params::RenderParams;
    use tessera_model::state::StateId;

    /// Tiles of the wall the tests' assignments come from.
    const TILES: u32 = 1000;

    fn now() -> Instant {
        // One instant for the tests that are not about time.
        static BASE: std::sync::OnceLock<Instant> = std::sync::OnceLock::new();
        *BASE.get_or_init(Instant::now)
    }

    #[test]
    fn assignments_of_tiles_the_wall_lacks_are_refused() {
        let mut w = RenderWorker::new(TILES, 4);
        w.handle_message(&start(0), now()).unwrap();
        let err = w
            .handle_message(&assign(0, TILES - 1, TILES + 5), now())
            .unwrap_err();
        assert_eq!(
            err,
            WorkerError::NoSuchTiles {
                start: TILES - 1,
                end: TILES + 5,
                tiles: TILES
            }
        );
        assert_eq!(w.queued(), 0, "nothing of a refused assignment is queued");
        assert_eq!(
            w.handle_message(&assign(1, 0, 2), now()),
            Err(WorkerError::AssignBeforeStart(FrameId(1)))
        );
    }

    #[test]
    fn messages_for_displays_are_refused_not_ignored() {
        let mut w = RenderWorker::new(TILES, 4);
        let present = ToNode::Present { frame: FrameId(0) };
        assert_eq!(
            w.handle_message(&present, now()),
            Err(WorkerError::NotForRenderNodes("present"))
        );
        assert!(w.handle_message(&ToNode::Shutdown, now()).is_ok());
    }

    fn start(frame: u64) -> ToNode {
        ToNode::FrameStart(FrameStart::new(
            FrameId(frame),
            StateId(0),
            Camera::new(Vec3::Z, Vec3::ZERO, Vec3::Y, 45.0).unwrap(),
            RenderParams::interactive(),
        ))
    }

    fn assign(frame: u64, start: u32, end: u32) -> ToNode {
        ToNode::Assign {
            frame: FrameId(frame),
            tiles: if start == end {
                Vec::new()
            } else {
                vec![TileRange::new(start, end).unwrap()]
            },
        }
    }

    #[test]
    fn no_request_between_a_frame_start_and_its_share() {
        let mut w = RenderWorker::new(TILES, 4);
        w.handle_message(&start(0), now()).unwrap();
        assert_eq!(w.poll_request(now()), None);
        w.handle_message(&assign(0, 0, 6), now()).unwrap();
        assert_eq!(
            w.poll_request(now()),
            None,
            "six queued tiles are above the low water"
        );
        let _ = w.next_batch(3);
        assert!(w.poll_request(now()).is_some());
    }

    #[test]
    fn an_empty_share_is_not_an_empty_pool_but_an_empty_answer_is() {
        let mut w = RenderWorker::new(TILES, 4);
        w.handle_message(&start(0), now()).unwrap();
        w.handle_message(&assign(0, 0, 0), now()).unwrap();
        assert!(w.poll_request(now()).is_some());
        w.handle_message(&assign(0, 0, 0), now()).unwrap();
        assert_eq!(w.poll_request(now()), None, "the pool is drained");
        w.handle_message(&start(1), now()).unwrap();
        w.handle_message(&assign(1, 0, 0), now()).unwrap();
        assert!(
            w.poll_request(now()).is_some(),
            "a new frame has a new pool"
        );
    }

    #[test]
    fn tiles_of_an_older_frame_are_rendered_before_a_newer_frames_share() {
        let mut w = RenderWorker::new(TILES, 1);
        w.handle_message(&start(0), now()).unwrap();
        w.handle_message(&assign(0, 0, 2), now()).unwrap();
        w.handle_message(&start(1), now()).unwrap();
        w.handle_message(&assign(1, 10, 12), now()).unwrap();
        // Tiles of frame 0 given back by a node that died.
        w.handle_message(&assign(0, 5, 6), now()).unwrap();
        let order: Vec<(u64, Vec<u32>)> = std::iter::from_fn(|| w.next_batch(8))
            .map(|(s, tiles)| (s.frame.0, tiles.iter().map(|t| t.0).collect()))
            .collect();
        assert_eq!(order, vec![(0, vec![0, 1, 5]), (1, vec![10, 11])]);
    }

    #[test]
    fn batches_grow_on_cheap_tiles_and_shrink_at_once_on_dear_ones() {
        use std::time::Duration;
        let mut b = BatchSizer::new(2);
        assert_eq!(
            b.batch(),
            2,
            "one tile per thread until a batch was measured"
        );
        assert_eq!(b.low_water(None), 4);
        // Tiles of 10 µs: a 0.5 ms batch holds 50.
        b.record(2, Duration::from_micros(20));
        assert_eq!(b.batch(), 50);
        assert_eq!(b.low_water(None), 50);
        // The camera turns to a dense mesh: 5 ms per tile, back to one tile per thread.
        b.record(200, Duration::from_secs(1));
        assert_eq!(b.batch(), 2);
        // Cheap again: the estimate falls over several batches, not at once.
        b.record(2, Duration::from_micros(20));
        let after_one = b.batch();
        assert!(after_one < 50, "{after_one}");
        for _ in 0..60 {
            b.record(2, Duration::from_micros(20));
        }
        assert_eq!(b.batch(), 50);
        // A batch that took no measurable time is capped, not infinite.
        b.record(10, Duration::ZERO);
        for _ in 0..60 {
            b.record(10, Duration::ZERO);
        }
        assert_eq!(b.batch(), BatchSizer::MAX_TILES);
    }

    #[test]
    fn the_queue_is_refilled_a_round_trip_ahead() {
        let mut w = RenderWorker::new(TILES, 4);
        let t0 = now();
        w.handle_message(&start(0), t0).unwrap();
        w.handle_message(&assign(0, 0, 0), t0).unwrap();
        assert!(w.poll_request(t0).is_some());
        w.handle_message(&assign(0, 0, 2), t0 + Duration::from_millis(1))
            .unwrap();
        assert_eq!(w.round_trip(), Some(Duration::from_millis(1)));
        let mut b = BatchSizer::new(1);
        b.record(2, Duration::from_micros(500));
        // 250 µs tiles: a batch of 2 (0.5 ms), and 4 more to render while 1 ms goes by.
        assert_eq!(b.batch(), 2);
        assert_eq!(b.low_water(None), 2);
        assert_eq!(b.low_water(w.round_trip()), 6);
        // Dear tiles against a short round trip: no hoarding beyond two per thread.
        b.record(2, Duration::from_millis(20));
        assert_eq!(b.low_water(Some(Duration::from_micros(100))), 2);
    }
}
