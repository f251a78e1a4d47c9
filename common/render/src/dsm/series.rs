//! A time series in distributed shared memory: every step's bricks are blocks, one step after
//! the other, and every node holds each step's placement and min/max grid (`volume.bin`). A
//! node shows step `s` by reading its bricks through the same reader as any shared volume; the
//! bricks the same pixels read at the step before, taken to step `s` and to `s + 1`, are
//! fetched ahead into the cache while step `s` is shown (the streaming readers of TRex, here
//! fetching from the owners rather than from disk).
//!
//! A step is *late* when rendering it idled a render thread waiting for blocks that were not
//! here: the prefetch did not bring them in time. [`SharedSeries::stats`] counts late steps
//! and the seconds they were late by.

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

/// The step shown and what its frames waited, and the tally of the steps shown before.
#[derive(Default)]
struct Shown {
    current: Option<(usize, Arc<PreparedVolume>)>,
    /// Wall-clock seconds the current step's frames idled waiting for blocks.
    waited_s: f64,
    tally: SeriesStats,
}

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
        let cells = last.placement.cells();
        let bricks: usize = cells
            .iter()
            .map(|c| c.div_ceil(crate::volume::BRICK_CELLS))
            .product();
        firsts.push(firsts[steps.len() - 1] + bricks as BlockId);
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

    /// Step `step` (modulo the series' length), to be shown from now on: the same volume while
    /// the step stays, so its tables and cell masks are made once.
    pub fn get(&self, step: usize) -> Arc<PreparedVolume> {
        let step = step % self.len();
        let mut shown = self.lock();
        if let Some((at, volume)) = &shown.current {
            if *at == step {
                return volume.clone();
            }
        }
        let waited = std::mem::take(&mut shown.waited_s);
        if shown.current.is_some() {
            close_step(&mut shown.tally, waited);
        }
        let volume = Arc::new(PreparedVolume::shared(self.steps[step].clone()));
        shown.current = Some((step, volume.clone()));
        volume
    }

    /// The render threads of a frame of the step shown idled `waited_s` seconds (wall clock)
    /// for blocks that were not here.
    pub fn note_wait(&self, waited_s: f64) {
        self.lock().waited_s += waited_s;
    }

    /// Steps on time (`hits`), late (`misses`) and the seconds they were late by in all
    /// (`stall_seconds`), the step shown now included; nothing is loaded from files.
    pub fn stats(&self) -> SeriesStats {
        let shown = self.lock();
        let mut tally = shown.tally.clone();
        if shown.current.is_some() {
            close_step(&mut tally, shown.waited_s);
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
        let bricks = crate::volume::Bricks::shared(one.placement.dims(), 0).count() as u32;
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
        series.note_wait(0.25);
        assert_eq!(series.get(1).bricks().first_shared(), 8);
        series.get(2);
        series.note_wait(0.5);
        let stats = series.stats();
        assert_eq!((stats.hits, stats.misses), (1, 2));
        assert!((stats.stall_seconds - 0.75).abs() < 1e-9);
        assert!(stats.load_seconds.is_empty());
    }
}
