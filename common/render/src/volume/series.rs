//! Time-varying volumes: a series of volume files, one per time step, loaded by reader threads
//! ahead of the step being shown, within a memory budget.
//!
//! [`SeriesCache::get`] hands out a step's prepared volume, loading it there and then if it is
//! not ready (a miss, counted with the time it stalled), and asks the readers for the steps
//! after it. Steps are evicted farthest-behind first once the budget is full; the step in use
//! and the ones asked for stay. Every step keeps the render frame of step 0, so a series moves
//! in one world.

use super::{load, PreparedVolume, VolumeError};
use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::path::PathBuf;
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::Instant;
use tessera_model::local_origin::RenderFromWorld;

/// What the cache has done, for reports.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SeriesStats {
    /// Steps loaded (by readers or on demand), and the seconds each took to load and brick.
    pub load_seconds: Vec<f64>,
    /// `get`s that found their step ready.
    pub hits: u64,
    /// `get`s that had to wait for their step.
    pub misses: u64,
    /// Seconds those `get`s waited, in all.
    pub stall_seconds: f64,
}

struct State {
    ready: BTreeMap<usize, (Arc<PreparedVolume>, usize)>,
    loading: BTreeSet<usize>,
    wanted: VecDeque<usize>,
    failed: BTreeMap<usize, String>,
    bytes: usize,
    current: usize,
    stats: SeriesStats,
    shutdown: bool,
}

struct Shared {
    paths: Vec<PathBuf>,
    frame: RenderFromWorld,
    budget: usize,
    state: Mutex<State>,
    changed: Condvar,
}

/// A series of volumes with reader threads prefetching ahead of the step shown.
///
/// # Examples
///
/// ```no_run
/// use tessera_render::volume::SeriesCache;
/// use tessera_model::local_origin::RenderFromWorld;
/// let series = SeriesCache::new(vec!["t0.nrrd".into(), "t1.nrrd".into()],
///     RenderFromWorld::IDENTITY, 1 << 30, 2);
/// let step0 = series.get(0)?; // and the readers start on step 1
/// # Ok::<(), tessera_render::volume::VolumeError>(())
/// ```
pub struct SeriesCache {
    shared: Arc<Shared>,
    readers: Vec<std::thread::JoinHandle<()>>,
}

impl SeriesCache {
    /// A cache over `paths` (at least one) that prefetches as many steps as `budget` bytes of
    /// bricks hold (at least one), with `readers` reader threads (at least one).
    pub fn new(paths: Vec<PathBuf>, frame: RenderFromWorld, budget: usize, readers: usize) -> Self {
        assert!(!paths.is_empty(), "a series has at least one step");
        let shared = Arc::new(Shared {
            paths,
            frame,
            budget,
            state: Mutex::new(State {
                ready: BTreeMap::new(),
                loading: BTreeSet::new(),
                wanted: VecDeque::new(),
                failed: BTreeMap::new(),
                bytes: 0,
                current: 0,
                stats: SeriesStats::default(),
                shutdown: false,
            }),
            changed: Condvar::new(),
        });
        let readers = (0..readers.max(1))
            .map(|i| {
                let shared = shared.clone();
                std::thread::Builder::new()
                    .name(format!("volume-reader-{i}"))
                    .spawn(move || read_loop(&shared))
                    .expect("spawn a volume reader thread")
            })
            .collect();
        SeriesCache { shared, readers }
    }

    /// Steps in the series.
    pub fn len(&self) -> usize {
        self.shared.paths.len()
    }

    /// Always false: a series has at least one step.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// Step `step` (modulo the series' length), waiting for it if it is not loaded yet; then
    /// the readers go on with the steps after it, as many as the budget holds.
    ///
    /// # Errors
    /// The step's file could not be loaded (its error, naming the file).
    pub fn get(&self, step: usize) -> Result<Arc<PreparedVolume>, VolumeError> {
        let step = step % self.len();
        let shared = &self.shared;
        let mut state = shared.lock();
        state.current = step;
        let hit = state.ready.contains_key(&step);
        let started = Instant::now();
        if !hit {
            if !state.loading.contains(&step) {
                state.wanted.retain(|&s| s != step);
                state.wanted.push_front(step);
                shared.changed.notify_all();
            }
            while !state.ready.contains_key(&step) {
                if let Some(why) = state.failed.remove(&step) {
                    return Err(VolumeError::Io {
                        path: shared.paths[step].display().to_string(),
                        reason: std::io::Error::other(why),
                    });
                }
                state = shared
                    .changed
                    .wait(state)
                    .unwrap_or_else(|e| e.into_inner());
            }
        }
        if hit {
            state.stats.hits += 1;
        } else {
            state.stats.misses += 1;
            state.stats.stall_seconds += started.elapsed().as_secs_f64();
        }
        let volume = state.ready[&step].0.clone();
        shared.plan_prefetch(&mut state);
        Ok(volume)
    }

    /// What the cache has done so far.
    pub fn stats(&self) -> SeriesStats {
        self.shared.lock().stats.clone()
    }
}

impl Drop for SeriesCache {
    fn drop(&mut self) {
        self.shared.lock().shutdown = true;
        self.shared.changed.notify_all();
        for reader in self.readers.drain(..) {
            let _ = reader.join();
        }
    }
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Keeps the current step and as many after it as the budget holds (at least the next
    /// one), asks the readers for those not loaded yet, and drops the rest.
    fn plan_prefetch(&self, state: &mut State) {
        let n = self.paths.len();
        let per_step = state
            .ready
            .values()
            .map(|(_, bytes)| *bytes)
            .max()
            .unwrap_or(1)
            .max(1);
        let ahead = (self.budget / per_step).clamp(1, n.saturating_sub(1).max(1));
        let keep: Vec<usize> = (0..=ahead).map(|k| (state.current + k) % n).collect();
        let evict: Vec<usize> = state
            .ready
            .keys()
            .copied()
            .filter(|s| !keep.contains(s))
            .collect();
        for step in evict {
            if let Some((_, bytes)) = state.ready.remove(&step) {
                state.bytes -= bytes;
            }
        }
        state.wanted.clear();
        for &step in &keep[1..] {
            if !state.ready.contains_key(&step) && !state.loading.contains(&step) {
                state.wanted.push_back(step);
            }
        }
        self.changed.notify_all();
    }

    /// Waits until `step` is loaded, at most `limit`.
    #[cfg(test)]
    fn wait_ready(&self, step: usize, limit: std::time::Duration) -> bool {
        let state = self.lock();
        let (state, _) = self
            .changed
            .wait_timeout_while(state, limit, |s| !s.ready.contains_key(&step))
            .unwrap_or_else(|e| e.into_inner());
        state.ready.contains_key(&step)
    }
}

fn read_loop(shared: &Shared) {
    loop {
        let step = {
            let mut state = shared.lock();
            loop {
                if state.shutdown {
                    return;
                }
                if let Some(step) = state.wanted.pop_front() {
                    state.loading.insert(step);
                    break step;
                }
                state = shared
                    .changed
                    .wait(state)
                    .unwrap_or_else(|e| e.into_inner());
            }
        };
        let started = Instant::now();
        let loaded = load(&shared.paths[step]).map(|v| PreparedVolume::new(&v, &shared.frame));
        let seconds = started.elapsed().as_secs_f64();
        let mut state = shared.lock();
        state.loading.remove(&step);
        match loaded {
            Ok(volume) => {
                let bytes = volume.bricks().bytes();
                state.bytes += bytes;
                state.stats.load_seconds.push(seconds);
                state.ready.insert(step, (Arc::new(volume), bytes));
            }
            Err(e) => {
                state.failed.insert(step, e.to_string());
            }
        }
        shared.changed.notify_all();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write_steps(dir: &std::path::Path, n: usize) -> Vec<PathBuf> {
        (0..n)
            .map(|i| {
                let raw = dir.join(format!("t{i}.raw"));
                std::fs::write(&raw, vec![i as u8 * 10; 64]).unwrap();
                let side = dir.join(format!("t{i}.vol.toml"));
                std::fs::write(
                    &side,
                    format!("data = \"t{i}.raw\"\ndims = [4, 4, 4]\ntype = \"u8\"\nspacing = [1.0, 1.0, 1.0]\n"),
                )
                .unwrap();
                side
            })
            .collect()
    }

    #[test]
    fn playing_in_order_hits_what_the_readers_fetched_ahead() {
        let dir = tempfile::tempdir().unwrap();
        let cache = SeriesCache::new(
            write_steps(dir.path(), 4),
            RenderFromWorld::IDENTITY,
            1 << 20,
            2,
        );
        let first = cache.get(0).unwrap();
        assert_eq!(first.value_at(glam::Vec3::splat(1.0)), Some(0.0));
        // Each step is waited for (with a bound) before it is asked for: a player whose readers
        // keep up.
        for step in 1..8 {
            let limit = std::time::Duration::from_secs(10);
            assert!(
                cache.shared.wait_ready(step % 4, limit),
                "step {step} never loaded"
            );
            let v = cache.get(step).unwrap();
            assert_eq!(
                v.value_at(glam::Vec3::splat(1.0)),
                Some((step % 4) as f32 * 10.0)
            );
        }
        let stats = cache.stats();
        assert_eq!((stats.misses, stats.hits), (1, 7), "{stats:?}");
        assert_eq!(
            stats.load_seconds.len(),
            4,
            "each step loaded once: {stats:?}"
        );
    }

    #[test]
    fn a_small_budget_keeps_only_what_is_next_and_a_bad_step_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let mut paths = write_steps(dir.path(), 5);
        paths[3] = dir.path().join("missing.vol.toml");
        // Room for about one step: at most the one in use and the next stay.
        let cache = SeriesCache::new(paths, RenderFromWorld::IDENTITY, 300, 1);
        for step in 0..3 {
            cache.get(step).unwrap();
            assert!(cache.shared.lock().ready.len() <= 3);
        }
        let Err(err) = cache.get(3) else {
            panic!("a missing step loaded");
        };
        let err = err.to_string();
        assert!(err.contains("missing.vol.toml"), "{err}");
        assert_eq!(cache.get(4).unwrap().value_at(glam::Vec3::ZERO), Some(40.0));
    }
}
