//! A time series in distributed shared memory: every step's bricks are blocks, one step after
//! the other, and every node holds each step's placement and min/max grid (`volume.bin`). A
//! node shows step `s` by reading its bricks through the same reader as any shared volume; the
//! bricks the same pixels read at the step before, taken to step `s` and to `s + 1`, are
//! fetched ahead into the cache while step `s` is shown (the streaming readers of TRex, here
//! fetching from the owners rather than from disk).
//!
//! A step is *late* on a node when rendering its frame idled the node's render threads waiting
//! for blocks that were not here: the prefetch did not bring them in time.
//! [`SharedSeries::stats`] counts, over the frames the node rendered tiles of, the steps on
//! time, the steps late and the seconds they were late by.

use crate::volume::{PreparedVolume, SeriesStats, SharedVolume};
use std::sync::{Arc, Mutex, MutexGuard};
use tessera_core::dsm::BlockId;

/// The steps of a shared series, the step shown, and how late steps were.
pub struct SharedSeries {
    steps: Vec<SharedVolume>,
    /// Each step's first brick block, and past the last step the end of the bricks.
    firsts: Vec<BlockId>,
    state: Mutex<Shown>,
}

/// The steps shown last, the frames still open and what they waited, and the tally of the
/// frames before them.
#[derive(Default)]
struct Shown {
    /// The last two steps asked for, the latest last: batches of two frames may alternate.
    recent: Vec<(usize, Arc<PreparedVolume>)>,
    /// Frames whose batches may still come, and the wall-clock seconds their batches idled
    /// waiting for blocks.
    open: std::collections::BTreeMap<u64, f64>,
    tally: SeriesStats,
}

/// Frames kept open: a batch of an older frame is counted as a frame of its own.
const OPEN_FRAMES: usize = 4;

impl SharedSeries {
    /// The series whose steps `volume.bin` held, its bricks from block `first_brick_block`.
    ///
    /// # Panics
    /// For no steps.
    pub fn new(steps: Vec<SharedVolume>, first_brick_block: BlockId) -> SharedSeries {
        assert!(!steps.is_empty(), "a series has at least one step");
        let mut firsts: Vec<BlockId> = steps
            .iter()
            .map(|s| first_brick_block + s.first_brick)
            .collect();
        let last = steps.last().expect("one step at least");
        firsts.push(firsts[steps.len() - 1] + last.brick_count() as BlockId);
        SharedSeries {
            steps,
            firsts,
            state: Mutex::new(Shown::default()),
        }
    }

    /// Steps in the series.
    pub fn len(&self) -> usize {
        self.steps.len()
    }

    /// Never: a series has a step at least.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// What a node holds of every step besides the bricks: their min/max grids, and the cell
    /// masks and tables of the two steps alive at once (the one shown and the one before it,
    /// while a batch still reads it).
    pub fn held_besides_bricks(&self) -> u64 {
        let summaries: u64 = self.steps.iter().map(|s| s.summary_bytes()).sum();
        let most = self
            .steps
            .iter()
            .map(|s| s.held_besides_bricks() - s.summary_bytes());
        summaries + 2 * most.max().unwrap_or(0)
    }

    fn lock(&self) -> MutexGuard<'_, Shown> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Step `step` (modulo the series' length), to be shown: the same volume while the step
    /// stays (or comes back at once), so its tables and cell masks are made once.
    pub fn get(&self, step: usize) -> Arc<PreparedVolume> {
        let step = step % self.len();
        let mut shown = self.lock();
        if let Some((_, volume)) = shown.recent.iter().find(|(at, _)| *at == step) {
            return volume.clone();
        }
        let volume = Arc::new(PreparedVolume::shared(self.steps[step].clone()));
        if shown.recent.len() == 2 {
            shown.recent.remove(0);
        }
        shown.recent.push((step, volume.clone()));
        volume
    }

    /// A batch of frame `frame` (showing a step) idled its render threads `waited_s` seconds
    /// (wall clock) for blocks that were not here.
    pub fn note_batch(&self, frame: u64, waited_s: f64) {
        let mut shown = self.lock();
        *shown.open.entry(frame).or_default() += waited_s;
        while shown.open.len() > OPEN_FRAMES {
            let (_, waited) = shown.open.pop_first().expect("more than none open");
            close_step(&mut shown.tally, waited);
        }
    }

    /// Frames of steps this node rendered: on time (`hits`), late (`misses`) and the seconds
    /// they were late by in all (`stall_seconds`); nothing is loaded from files.
    pub fn stats(&self) -> SeriesStats {
        let shown = self.lock();
        let mut tally = shown.tally.clone();
        for &waited in shown.open.values() {
            close_step(&mut tally, waited);
        }
        tally
    }

    /// Block `k` of some step's bricks taken to step `to`: the same brick there, if `k` is a
    /// brick block and step `to` has as many bricks.
    pub fn same_brick_at(&self, k: BlockId, to: usize) -> Option<BlockId> {
        let (first, end) = (self.firsts[0], *self.firsts.last()?);
        if !(first..end).contains(&k) {
            return None;
        }
        let from = self.firsts.partition_point(|&f| f <= k) - 1;
        let index = k - self.firsts[from];
        let to = to % self.len();
        let target = self.firsts[to] + index;
        (target < self.firsts[to + 1]).then_some(target)
    }
}

/// Adds a step that idled `waited_s` seconds to `tally`: on time if it never idled.
fn close_step(tally: &mut SeriesStats, waited_s: f64) {
    if waited_s > 0.0 {
        tally.misses += 1;
        tally.stall_seconds += waited_s;
    } else {
        tally.hits += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn steps(n: u32, field: fn(glam::Vec3) -> f32) -> Vec<SharedVolume> {
        let volume = crate::volume::render_tests::field(40, field);
        let one = PreparedVolume::new(&volume, &Default::default()).to_shared();
        let bricks = one.brick_count() as u32;
        (0..n)
            .map(|s| SharedVolume {
                first_brick: s * bricks,
                ..one.clone()
            })
            .collect()
    }

    #[test]
    fn a_brick_maps_to_the_same_brick_of_another_step_and_late_steps_are_counted() {
        let series = SharedSeries::new(steps(3, |p| p.x), 100);
        // 40 samples an axis: 2 bricks an axis, 8 a step.
        assert_eq!(series.same_brick_at(100 + 3, 1), Some(100 + 8 + 3));
        assert_eq!(series.same_brick_at(100 + 8 + 7, 2), Some(100 + 16 + 7));
        assert_eq!(
            series.same_brick_at(100 + 16 + 1, 3),
            Some(100 + 1),
            "step 3 is step 0"
        );
        assert_eq!(series.same_brick_at(99, 1), None, "not a brick");
        assert_eq!(series.same_brick_at(100 + 24, 1), None, "past the bricks");
        let shown = series.get(0);
        assert!(
            Arc::ptr_eq(&shown, &series.get(3)),
            "the same step, the same volume"
        );
        assert_eq!(shown.bricks().first_shared(), 0);
        assert_eq!(series.get(1).bricks().first_shared(), 8);
        assert!(Arc::ptr_eq(&shown, &series.get(0)), "the step before, kept");
        // Frames 0-6, batches of frames 1 and 2 alternating; 1 and 6 waited.
        for (frame, waited) in [(0, 0.0), (1, 0.25), (2, 0.0), (1, 0.0), (3, 0.0), (4, 0.0)] {
            series.note_batch(frame, waited);
        }
        for (frame, waited) in [(5, 0.0), (6, 0.5), (6, 0.0)] {
            series.note_batch(frame, waited);
        }
        let stats = series.stats();
        assert_eq!((stats.hits, stats.misses), (5, 2));
        assert!((stats.stall_seconds - 0.75).abs() < 1e-9);
        assert!(stats.load_seconds.is_empty());
    }
}
