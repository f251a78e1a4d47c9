//! The figures of a run that a standby carries over a takeover, so that the report of a
//! taken-over run covers the whole run: counters, and the distributions behind the report's
//! percentiles as histograms that merge (percentiles do not).

use super::report::{LostNode, Percentiles, Report};
use super::*;
use serde::{Deserialize, Serialize};

/// Significant digits of the report's histograms (as [`Percentiles::of_ms`] keeps them).
const SIGFIGS: u8 = 3;
/// The largest duration the histograms hold, in ns: an hour.
const MAX_NS: u64 = 3_600_000_000_000;

/// A distribution of durations as an HDR histogram's buckets: `(ns, count)` for each bucket
/// that holds samples, a bucket named by the highest value it holds. Its size is bounded by
/// the histogram's buckets, however many samples it holds.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Samples(Vec<(u64, u64)>);

fn histogram() -> hdrhistogram::Histogram<u64> {
    hdrhistogram::Histogram::new_with_bounds(1, MAX_NS, SIGFIGS).expect("valid histogram bounds")
}

impl Samples {
    /// Durations in milliseconds.
    pub fn of_ms(ms: &[f64]) -> Samples {
        let mut hist = histogram();
        record_ms(&mut hist, ms);
        Samples::of_histogram(&hist)
    }

    fn of_histogram(hist: &hdrhistogram::Histogram<u64>) -> Samples {
        Samples(
            hist.iter_recorded()
                .map(|v| (v.value_iterated_to(), v.count_at_value()))
                .collect(),
        )
    }

    /// The samples of both.
    pub fn merged(&self, other: &Samples) -> Samples {
        let mut hist = self.histogram();
        other.record_into(&mut hist);
        Samples::of_histogram(&hist)
    }

    /// Samples held.
    pub fn count(&self) -> u64 {
        self.0.iter().map(|&(_, n)| n).sum()
    }

    fn histogram(&self) -> hdrhistogram::Histogram<u64> {
        let mut hist = histogram();
        self.record_into(&mut hist);
        hist
    }

    fn record_into(&self, hist: &mut hdrhistogram::Histogram<u64>) {
        for &(ns, count) in &self.0 {
            // Saturating, as `Percentiles::of_ms` records; a bucket's highest value lies in it.
            let _ = hist.record_n(ns.clamp(1, MAX_NS), count);
        }
    }

    /// These samples and the durations `ms` together, as the report gives them.
    pub fn percentiles_with(&self, ms: &[f64]) -> Percentiles {
        let mut hist = self.histogram();
        record_ms(&mut hist, ms);
        Percentiles::of_histogram(&hist)
    }
}

fn record_ms(hist: &mut hdrhistogram::Histogram<u64>, ms: &[f64]) {
    for &ms in ms {
        hist.saturating_record((ms * 1e6).round().max(0.0) as u64);
    }
}

/// The distributions behind the report's percentiles.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct RunSamples {
    /// `frame_ms`.
    pub frame_ms: Samples,
    /// `start_to_present_ms`.
    pub start_to_present_ms: Samples,
    /// `latency_ms`.
    pub latency_ms: Samples,
    /// `skew_ms`.
    pub skew_ms: Samples,
    /// `input_latency_ms`.
    pub input_latency_ms: Samples,
    /// `input_parts`: entry → master, master → barrier, barrier → present.
    pub input_parts: [Samples; 3],
}

/// The report's counters of a run so far.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Figures {
    /// Frames presented.
    pub frames: u64,
    /// Seconds of rendering (see [`Report::rendering_s`]).
    pub rendering_s: f64,
    /// Seconds from the first frame start to the last present, over every master of the run
    /// (the dark time of a takeover included).
    pub elapsed_s: f64,
    /// [`Report::render_nodes_lost`].
    pub render_nodes_lost: u32,
    /// [`Report::displays_lost`].
    pub displays_lost: u32,
    /// [`Report::frames_cancelled`].
    pub frames_cancelled: u32,
    /// [`Report::refinement_passes_dropped`].
    pub refinement_passes_dropped: u32,
    /// [`Report::nodes_suspected`].
    pub nodes_suspected: u32,
    /// [`Report::master_pauses`].
    pub master_pauses: u32,
    /// [`Report::longest_master_pause_ms`].
    pub longest_master_pause_ms: f64,
    /// [`Report::frames_short_of_displays`].
    pub frames_short_of_displays: u64,
    /// [`Report::nodes_lost`].
    pub nodes_lost: Vec<LostNode>,
    /// [`Report::tiles_speculated`].
    pub tiles_speculated: u64,
    /// [`Report::changes_applied`].
    pub changes_applied: u64,
    /// [`Report::snapshots`].
    pub snapshots: Vec<u64>,
}

impl Master {
    /// This master's counters, with those of the masters before it (after a takeover).
    pub(super) fn figures_so_far(&self) -> Figures {
        let own = self.report_counters();
        let Some(prior) = &self.prior else {
            return own;
        };
        let mut f = prior.figures.clone();
        f.frames += own.frames;
        f.rendering_s += own.rendering_s;
        f.elapsed_s += self.dark().as_secs_f64() + own.elapsed_s;
        f.render_nodes_lost += own.render_nodes_lost;
        f.displays_lost += own.displays_lost;
        f.frames_cancelled += own.frames_cancelled;
        f.refinement_passes_dropped += own.refinement_passes_dropped;
        f.nodes_suspected += own.nodes_suspected;
        f.master_pauses += own.master_pauses;
        f.longest_master_pause_ms = f.longest_master_pause_ms.max(own.longest_master_pause_ms);
        f.frames_short_of_displays += own.frames_short_of_displays;
        f.nodes_lost.extend(own.nodes_lost);
        f.tiles_speculated += own.tiles_speculated;
        f.changes_applied += own.changes_applied;
        f.snapshots.extend(own.snapshots);
        f
    }

    /// This master's own counters: O(1).
    fn report_counters(&self) -> Figures {
        let r = &self.record;
        let last = r.presents.last().map(|&(_, at)| at);
        let elapsed = match (r.started, last) {
            (Some(start), Some(last)) => last.duration_since(start).as_secs_f64(),
            _ => 0.0,
        };
        Figures {
            frames: r.presents.len() as u64,
            rendering_s: last.map_or(0.0, |at| self.rendering_time(at).as_secs_f64()),
            elapsed_s: elapsed,
            render_nodes_lost: r.lost_render_nodes,
            displays_lost: r.lost_displays,
            frames_cancelled: r.frames_cancelled,
            refinement_passes_dropped: r.refinement_passes_dropped,
            nodes_suspected: r.suspicions,
            master_pauses: r.master_pauses,
            longest_master_pause_ms: r.longest_master_pause.as_secs_f64() * 1000.0,
            frames_short_of_displays: r.frames_short_of_displays,
            nodes_lost: r.lost.clone(),
            tiles_speculated: self.coordinator.speculated_tiles(),
            changes_applied: r.changes_applied,
            snapshots: self.live.snapshots.iter().map(|f| f.0).collect(),
        }
    }

    /// This master's distributions with those of the masters before it: O(frames), so a
    /// primary refreshes them only every [`super::standby::SAMPLES_EVERY`] presents.
    pub(super) fn samples_so_far(&self) -> RunSamples {
        let (frame_ms, start_to_present) = self.frame_times();
        let t = self.record.timing.samples(self.cfg.wall.display_count());
        let empty = RunSamples::default();
        let p = self.prior.as_ref().map_or(&empty, |p| &p.samples);
        let m = |prior: &Samples, ms: &[f64]| prior.merged(&Samples::of_ms(ms));
        RunSamples {
            frame_ms: m(&p.frame_ms, &frame_ms),
            start_to_present_ms: m(&p.start_to_present_ms, &start_to_present),
            latency_ms: m(&p.latency_ms, &t.latency),
            skew_ms: m(&p.skew_ms, &t.skew),
            input_latency_ms: m(&p.input_latency_ms, &t.input_latency),
            input_parts: [0, 1, 2].map(|i| m(&p.input_parts[i], &t.parts[i])),
        }
    }

    /// A report of this master's own frames, made one of the whole run: the figures of the
    /// masters before it are added, and its percentiles are over every frame.
    pub(super) fn merge_prior(&self, report: &mut Report, frame_ms: &[f64], stp: &[f64]) {
        let Some(prior) = &self.prior else {
            return;
        };
        let f = self.figures_so_far();
        let p = &prior.samples;
        let t = self.record.timing.samples(self.cfg.wall.display_count());
        report.frames = f.frames;
        report.rendering_s = f.rendering_s;
        report.fps = if f.rendering_s > 0.0 {
            f.frames as f64 / f.rendering_s
        } else {
            0.0
        };
        report.elapsed_s = f.elapsed_s;
        report.frame_period_ms = if f.frames > 0 {
            f.elapsed_s * 1000.0 / f.frames as f64
        } else {
            0.0
        };
        report.frame_ms = p.frame_ms.percentiles_with(frame_ms);
        report.start_to_present_ms = p.start_to_present_ms.percentiles_with(stp);
        let timing = &mut report.timing;
        timing.latency_ms = p.latency_ms.percentiles_with(&t.latency);
        timing.skew_ms = p.skew_ms.percentiles_with(&t.skew);
        timing.input_latency_ms = p.input_latency_ms.percentiles_with(&t.input_latency);
        // One latency (and one skew) per frame measured, one input latency per input.
        timing.frames_measured += p.latency_ms.count();
        timing.inputs_measured += p.input_latency_ms.count();
        let parts = &mut timing.input_parts;
        parts.entry_to_master_ms = p.input_parts[0].percentiles_with(&t.parts[0]);
        parts.master_to_barrier_ms = p.input_parts[1].percentiles_with(&t.parts[1]);
        parts.barrier_to_present_ms = p.input_parts[2].percentiles_with(&t.parts[2]);
        report.render_nodes_lost = f.render_nodes_lost;
        report.displays_lost = f.displays_lost;
        report.frames_cancelled = f.frames_cancelled;
        report.refinement_passes_dropped = f.refinement_passes_dropped;
        report.nodes_suspected = f.nodes_suspected;
        report.master_pauses = f.master_pauses;
        report.longest_master_pause_ms = f.longest_master_pause_ms;
        report.frames_short_of_displays = f.frames_short_of_displays;
        report.nodes_lost = f.nodes_lost;
        report.tiles_speculated = f.tiles_speculated;
        report.changes_applied = f.changes_applied;
        report.snapshots = f.snapshots;
        report.takeovers = self.takeovers.clone();
    }
}
