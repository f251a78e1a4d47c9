//! One batch on the render threads: the volume step it needs loaded, its tiles traced, and
//! their pixels packed for the wire. Runs on a blocking thread, never on the driver's loop.

use rayon::prelude::*;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, RwLock, RwLockReadGuard, RwLockWriteGuard};
use std::time::{Duration, Instant};
use tessera_core::node::render::{BatchDone, BatchOrder};
use tessera_model::state::StateId;
use tessera_model::wall::{TileGrid, TileId};
use tessera_protocol::pixels::Compression;
use tessera_protocol::FrameId;
use tessera_render::dsm::series::SharedSeries;
use tessera_render::volume::{PreparedVolume, SeriesCache, SeriesStats, VolumeError};
use tessera_render::{render_tiles_footprints, Cancel, FrameView, PreparedScene, RayCounts};

pub(crate) fn read(scene: &RwLock<PreparedScene>) -> RwLockReadGuard<'_, PreparedScene> {
    scene.read().unwrap_or_else(|e| e.into_inner())
}

fn write(scene: &RwLock<PreparedScene>) -> RwLockWriteGuard<'_, PreparedScene> {
    scene.write().unwrap_or_else(|e| e.into_inner())
}

/// What a batch renders with, shared by every batch of a session.
#[derive(Clone)]
pub(crate) struct Renderer {
    /// Batches render one at a time: the lock is taken for writing only between them, when
    /// a time series moves to another step.
    pub prepared: Arc<RwLock<PreparedScene>>,
    pub series: Option<Series>,
    /// The step of the series `prepared` holds, kept across sessions with the scene.
    pub shown_step: Arc<AtomicUsize>,
    pub grid: Arc<TileGrid>,
    pub pool: Arc<rayon::ThreadPool>,
    pub compression: Compression,
}

/// A time series' steps: read from their files by each node ahead of the step shown, or
/// shared, their bricks fetched ahead into the cache.
#[derive(Clone)]
pub(crate) enum Series {
    Files(Arc<SeriesCache>),
    Shared(Arc<SharedSeries>),
}

impl Series {
    /// Steps in the series.
    pub fn len(&self) -> usize {
        match self {
            Series::Files(files) => files.len(),
            Series::Shared(shared) => shared.len(),
        }
    }

    /// Step `step`, to be shown (see [`SeriesCache::get`], [`SharedSeries::get`]).
    fn get(&self, step: usize) -> Result<Arc<PreparedVolume>, VolumeError> {
        match self {
            Series::Files(files) => files.get(step),
            Series::Shared(shared) => Ok(shared.get(step)),
        }
    }

    /// Steps on time and late (for files: loaded in time or waited for), and the wait.
    pub fn stats(&self) -> SeriesStats {
        match self {
            Series::Files(files) => files.stats(),
            Series::Shared(shared) => shared.stats(),
        }
    }
}

/// A batch the render threads finished.
pub(crate) struct Rendered {
    pub frame: FrameId,
    pub state: StateId,
    pub tiles: Vec<TileId>,
    /// Each tile's payload, packed as the session's compression says.
    pub payloads: Vec<Vec<u8>>,
    pub rays: RayCounts,
    /// Rendering alone.
    pub took: Duration,
    /// Rendering and packing: what sizes the next batch.
    pub batch_took: Duration,
    /// For a shared scene, the other nodes' blocks each tile read.
    pub footprints: Vec<Vec<u32>>,
}

impl Rendered {
    /// What the session needs to know of it.
    pub fn done(&self) -> BatchDone {
        BatchDone {
            tiles: self.tiles.len(),
            rays: self.rays.total(),
            took: self.took,
            batch_took: self.batch_took,
        }
    }
}

impl Renderer {
    /// Renders `order`; blocks for as long as that takes, or until `cancel` is cancelled:
    /// then within a sample of a packet, returning `None` (a cancelled batch did nothing).
    ///
    /// # Errors
    /// The volume step the batch needs cannot be loaded.
    pub fn render(
        &self,
        order: BatchOrder,
        cancel: &Cancel,
    ) -> Result<Option<Rendered>, VolumeError> {
        let BatchOrder {
            start,
            tiles,
            volume_step,
            ..
        } = order;
        let t0 = Instant::now();
        let view = FrameView::of_start(&start, self.grid.layout());
        if let (Some(step), Some(series)) = (volume_step, &self.series) {
            self.shown_step.store(step, Ordering::Relaxed);
            let volume = series.get(step)?;
            write(&self.prepared).set_volume(volume);
        }
        let prepared = read(&self.prepared);
        let waited_before = prepared.shared.as_ref().map(|t| t.stats().fetch_wait_s);
        let geometry: Vec<_> = tiles
            .iter()
            .map(|t| {
                *self
                    .grid
                    .tile(*t)
                    .expect("the worker checked every assigned tile")
            })
            .collect();
        let traced = self
            .pool
            .install(|| render_tiles_footprints(&prepared, &view, &geometry, cancel));
        let Some((pixels, rays, footprints)) = traced else {
            return Ok(None);
        };
        // Rendering time alone, so rays/s does not depend on the compression.
        let took = t0.elapsed();
        if let (Some(Series::Shared(series)), Some(before), Some(tree)) =
            (&self.series, waited_before, &prepared.shared)
        {
            // Thread-seconds of idling, as wall-clock seconds of the batch.
            let threads = self.pool.current_num_threads().max(1) as f64;
            let waited = (tree.stats().fetch_wait_s - before) / threads;
            series.note_batch(start.frame.0, waited);
        }
        let compression = self.compression;
        let payloads = self.pool.install(|| {
            pixels
                .into_par_iter()
                .map(|rgb| compression.encode_tile(rgb))
                .collect()
        });
        Ok(Some(Rendered {
            frame: start.frame,
            state: start.state,
            tiles,
            payloads,
            rays,
            took,
            batch_took: t0.elapsed(),
            footprints,
        }))
    }
}
