//! `report.json`: what a run measured.

use serde::{Deserialize, Serialize};
use tessera_model::wall::WallLayout;
use tessera_protocol::pixels::Compression;
use tessera_protocol::{DisplayStats, RenderStats};

/// Everything a run measured, as `report.json` holds it.
#[derive(Serialize, Debug)]
pub struct Report {
    /// Frames presented: the swap barrier sent their `Present`.
    pub frames: u64,
    /// How tiles were packed on their way to the displays (`--compress`).
    pub compression: Compression,
    /// The wall the run had.
    pub wall: WallReport,
    /// Each display that sent its figures at shutdown, by id.
    pub displays: Vec<DisplayReport>,
    /// Each render node that sent its figures at shutdown, by id.
    pub render_nodes: Vec<RenderNodeReport>,
    /// Frames presented per second of rendering: the time frames were in flight, from the
    /// first frame start to the last present, less the time the wall rested at its final
    /// quality.
    pub fps: f64,
    /// Seconds the wall spent rendering (frames in flight); `elapsed_s` less its rests.
    #[serde(default)]
    pub rendering_s: f64,
    /// Time between consecutive presents (the first frame: from its start to its present).
    pub frame_ms: Percentiles,
    /// From a frame's start (camera applied) to its present on all displays.
    pub start_to_present_ms: Percentiles,
    /// Mean time between presents.
    pub frame_period_ms: f64,
    /// Camera change → present on every display, and present skew across displays.
    #[serde(flatten)]
    pub timing: super::timing::TimingSummary,
    /// Seconds from the first frame start to the last present (0 if no frame started).
    pub elapsed_s: f64,
    /// Render nodes that dropped out after the first frame started (left, broke the protocol
    /// or went silent); their tiles went to the others.
    pub render_nodes_lost: u32,
    /// Displays lost while the others went on (`--display-loss go-on`) or waited for them
    /// (`wait`).
    pub displays_lost: u32,
    /// Frames abandoned in flight and never shown: runaways (a newer state waited while they
    /// ran far longer than the frames before) and those still in flight after an interrupt's
    /// grace.
    #[serde(default)]
    pub frames_cancelled: u32,
    /// Refinement passes dropped in flight because a change made them stale (not counted in
    /// `frames_cancelled`).
    #[serde(default)]
    pub refinement_passes_dropped: u32,
    /// Times a render node or display was silent past the suspicion deadline and kept (its
    /// tiles copied to others); those that spoke again were simply back.
    #[serde(default)]
    pub nodes_suspected: u32,
    /// Times the master itself did not run when it meant to (stopped, or starved of CPU),
    /// and the longest (ms): silence in those times counted against no node.
    #[serde(default)]
    pub master_pauses: u32,
    /// The longest of [`Report::master_pauses`], in ms.
    #[serde(default)]
    pub longest_master_pause_ms: f64,
    /// Frames presented while some display was not showing them: every frame from a loss to
    /// the rejoin under `go-on`, at most the frames in flight at the loss under `wait`.
    pub frames_short_of_displays: u64,
    /// Each node counted in `render_nodes_lost` and `displays_lost`, named as the master's log
    /// names it, in the order they were lost.
    pub nodes_lost: Vec<LostNode>,
    /// Tiles given to a second render node because the first was late with them (past its
    /// lease): the price of not waiting on a slow, hung or dead node.
    pub tiles_speculated: u64,
    /// State changes (input events, control commands) the frame barrier applied.
    pub changes_applied: u64,
    /// Frames a control client had the displays save (`wall-frame-<K>.png`).
    pub snapshots: Vec<u64>,
    /// How render nodes held the scene: `replicated` or `dsm`.
    pub data: &'static str,
    /// A shared scene's reads over every render node (each node's own under its `dsm`).
    pub dsm: Option<DsmSummary>,
    /// Each time a standby master took the run over, in order (absent when none did).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub takeovers: Vec<Takeover>,
}

/// A standby master took the run over.
#[derive(Serialize, Deserialize, Debug, Clone, PartialEq)]
pub struct Takeover {
    /// The term of the master that took over.
    pub term: u64,
    /// The first frame it could start (frames from the snapshot's on to this one were
    /// started by no one, or by the old master and never shown).
    pub frame: u64,
    /// When it took over, in ns since the Unix epoch on its clock.
    pub at_unix_ns: u64,
    /// How long the wall was dark: from the last present of the old master that the driver
    /// knows of to the first present of the new one, as the driver measured it (`None`
    /// until it said, see [`super::Master::record_takeover_dark`]).
    pub dark_ms: Option<f64>,
}

/// A node lost while the wall ran.
#[derive(Serialize, Deserialize, Debug, Clone, PartialEq, Eq)]
pub struct LostNode {
    /// The node as log lines name it: `render node 2 (host)`, `display 1 (host)`.
    pub node: String,
    /// Why it was lost: its connection closed (as the transport said), it broke the protocol,
    /// or it was silent past the deadline.
    pub reason: String,
}

/// The render nodes' reads of a shared scene, together.
#[derive(Serialize, Debug, Default, Clone, Copy)]
pub struct DsmSummary {
    /// Size of one block of the scene's data, in bytes.
    pub block_bytes: u32,
    /// Render nodes that hold blocks.
    pub ranks: u32,
    /// Owners of each block.
    pub replicas: u32,
    /// Blocks traversals moved into, over all nodes, and per frame.
    pub block_reads: u64,
    /// `block_reads` over the frames presented.
    pub blocks_read_per_frame: f64,
    /// Blocks fetched from other nodes (cache misses), and their share of the reads.
    pub fetched: u64,
    /// `fetched` as a percentage of `block_reads`.
    pub miss_percent: f64,
    /// Of the reads, those of blocks the reading node held itself.
    pub local_percent: f64,
    /// Remote reads, from the request to the block's arrival, of every block asked of
    /// another node, those fetched ahead included: over every node (the p99 is the largest
    /// node's p99, an upper bound).
    pub remote_read_avg_us: f64,
    /// The fastest remote read of any node (0: none).
    pub remote_read_min_us: f64,
    /// The slowest remote read of any node.
    pub remote_read_max_us: f64,
    /// The largest of the nodes' 99th percentiles.
    pub remote_read_p99_us: f64,
    /// How long a render thread waited, on average, for a block it missed (a block fetched
    /// ahead waits behind the misses, so this is the stall the threads saw).
    pub miss_wait_avg_us: f64,
    /// The share of the render threads' time, over all nodes, spent waiting for blocks with
    /// nothing else to trace, in percent (thread-seconds waited over threads times the time
    /// each node rendered).
    pub wait_percent: f64,
    /// Packets set aside for a missing block and traced again once it landed, over all nodes.
    pub parked: u64,
    /// The fastest round trip of an empty request between render nodes, measured in the same
    /// run: the transport's floor under a remote read.
    pub round_trip_us: f64,
    /// Blocks read from the prepared files because no owner was left.
    pub read_locally: u64,
    /// The largest peak resident memory of a render node.
    pub max_rss_bytes: u64,
}

/// The wall's shape, as the report gives it.
#[derive(Clone, Serialize, Debug, PartialEq)]
pub struct WallReport {
    /// Width in pixels of the image the wall's pixels are numbered in (a grid's virtual
    /// image, bezels included).
    pub width: u32,
    /// Height in pixels of that image.
    pub height: u32,
    /// A grid's screens per row (0 for a wall of screens).
    pub columns: u32,
    /// A grid's rows of screens (0 for a wall of screens).
    pub rows: u32,
    /// A grid's bezel in pixels (0 for a wall of screens).
    pub bezel: u32,
    /// Edge length of the square tiles that screens are cut into, in pixels.
    pub tile_size: u32,
    /// Each display's screen, in display id order.
    pub displays: Vec<DisplayRect>,
}

/// One display's screen in the wall's image, in pixels.
#[derive(Clone, Serialize, Debug, PartialEq)]
pub struct DisplayRect {
    /// The display's id.
    pub id: u32,
    /// The screen's left edge.
    pub x: u32,
    /// The screen's top edge.
    pub y: u32,
    /// The screen's width.
    pub width: u32,
    /// The screen's height.
    pub height: u32,
}

impl WallReport {
    /// The report's view of `layout`.
    pub fn of(layout: &WallLayout) -> Self {
        WallReport {
            width: layout.width(),
            height: layout.height(),
            columns: layout.columns(),
            rows: layout.rows(),
            bezel: layout.bezel(),
            tile_size: layout.tile_size(),
            displays: layout
                .screens()
                .map(|s| DisplayRect {
                    id: s.id.0,
                    x: s.x,
                    y: s.y,
                    width: s.width,
                    height: s.height,
                })
                .collect(),
        }
    }
}

/// One display's figures.
#[derive(Serialize, Debug)]
pub struct DisplayReport {
    /// The display's id.
    pub id: u32,
    /// The host name its hello gave.
    pub host: String,
    /// What it counted, as it sent them at shutdown.
    #[serde(flatten)]
    pub stats: DisplayStats,
    /// Wire bytes (UDP payloads, see [`DisplayStats::wire_bytes_received`]) over the pixel bytes
    /// this display owns for the frames it presented, at 3 bytes per pixel: QUIC's overhead,
    /// less what compression saves.
    pub wire_bytes_per_pixel_byte: f64,
}

/// One render node's figures.
#[derive(Serialize, Debug)]
pub struct RenderNodeReport {
    /// The render node's id.
    pub id: u32,
    /// The host name its hello gave.
    pub host: String,
    /// Threads it rendered with.
    pub cores: u32,
    /// What it counted, as it sent them at shutdown.
    #[serde(flatten)]
    pub stats: RenderStats,
    /// Rays traced per second of rendering ([`RenderStats::busy_s`]); 0 if it never rendered.
    pub rays_per_s: f64,
    /// For a shared scene under a memory budget: the budget, in bytes.
    pub memory_budget: Option<u64>,
    /// For a shared scene under a memory budget: whether its peak resident memory
    /// (`max_rss_bytes`) stayed within it.
    pub within_budget: Option<bool>,
}

/// A distribution of durations, in milliseconds; all 0 when there were no samples.
#[derive(Serialize, Debug, Default, Clone, Copy)]
pub struct Percentiles {
    /// The median.
    pub p50: f64,
    /// The 95th percentile.
    pub p95: f64,
    /// The 99th percentile.
    pub p99: f64,
    /// The largest sample.
    pub max: f64,
}

impl Percentiles {
    /// Percentiles of durations in milliseconds, to three significant digits and nanosecond
    /// resolution: the present skew of displays on one host can be well under a microsecond.
    pub fn of_ms(samples: &[f64]) -> Self {
        // Bounds up to an hour; `saturating_record` clamps instead of growing the histogram.
        let mut hist = hdrhistogram::Histogram::<u64>::new_with_bounds(1, 3_600_000_000_000, 3)
            .expect("valid histogram bounds");
        for &ms in samples {
            hist.saturating_record((ms * 1e6).round().max(0.0) as u64);
        }
        Percentiles::of_histogram(&hist)
    }

    /// Percentiles of a histogram of durations in ns.
    pub(super) fn of_histogram(hist: &hdrhistogram::Histogram<u64>) -> Self {
        if hist.is_empty() {
            return Percentiles::default();
        }
        let ms = |ns: u64| ns as f64 / 1e6;
        Percentiles {
            p50: ms(hist.value_at_quantile(0.5)),
            p95: ms(hist.value_at_quantile(0.95)),
            p99: ms(hist.value_at_quantile(0.99)),
            max: ms(hist.max()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_of_known_samples() {
        let samples: Vec<f64> = (1..=100).map(|i| f64::from(i) * 10.0).collect();
        let p = Percentiles::of_ms(&samples);
        assert!((p.p50 - 500.0).abs() < 0.5, "{p:?}");
        assert!((p.p95 - 950.0).abs() < 1.0, "{p:?}");
        assert!((p.max - 1000.0).abs() < 1.0, "{p:?}");
        assert_eq!(Percentiles::of_ms(&[]).max, 0.0);
        let sub_microsecond = Percentiles::of_ms(&[0.0003, 0.0004]);
        assert!(
            sub_microsecond.p50 > 0.0 && sub_microsecond.max < 0.001,
            "{sub_microsecond:?}"
        );
    }
}
