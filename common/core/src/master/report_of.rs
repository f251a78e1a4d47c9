//! The run's report, from what the master recorded and what the nodes said at shutdown.

use super::report::{
    DisplayReport, DsmSummary, LostNode, Percentiles, RenderNodeReport, WallReport,
};
use super::*;

impl Master {
    /// The figures of the run so far: what [`Master::take_outcome`] gives for a run that
    /// completed, and for one that did not, what it measured until it ended (a failed run's
    /// report is written too). Nodes' own figures are only in it once they sent them at
    /// shutdown.
    pub fn report_so_far(&self) -> Report {
        self.report()
    }

    /// Closes a peer's connection with `close`, then drops it as [`Master::drop_noted`] does.
    pub(super) fn close_and_drop(
        &mut self,
        peer: PeerId,
        close: CloseReason,
        now: Now,
        reason: &str,
    ) {
        self.closes.push_back((peer, close));
        self.drop_noted(peer, now, reason);
    }

    /// Drops a peer (see `drop_peer`) and, if that counted it as lost, keeps its name for
    /// the report: a figure without the name would leave the reader to match log lines.
    pub(super) fn drop_noted(&mut self, peer: PeerId, now: Now, reason: &str) {
        let node = self.describe(peer);
        let counted = |r: &RunRecord| r.lost_render_nodes + r.lost_displays;
        let before = counted(&self.record);
        self.drop_peer(peer, now, reason);
        if counted(&self.record) > before {
            let reason = reason.to_string();
            self.record.lost.push(LostNode { node, reason });
        }
    }

    /// The render nodes' reads of a shared scene, together.
    fn dsm_summary(&self, nodes: &[RenderNodeReport], frames: u64) -> Option<DsmSummary> {
        let DataSpec::Dsm(spec) = &self.cfg.data else {
            return None;
        };
        let mut s = DsmSummary {
            block_bytes: spec.block_bytes,
            ranks: spec.ranks,
            replicas: spec.replicas,
            remote_read_min_us: f64::INFINITY,
            round_trip_us: f64::INFINITY,
            ..DsmSummary::default()
        };
        let (mut local, mut latency_sum, mut latency_count) = (0u64, 0.0, 0u64);
        let (mut waited_s, mut thread_s) = (0.0, 0.0);
        for n in nodes {
            s.max_rss_bytes = s.max_rss_bytes.max(n.stats.max_rss_bytes);
            let Some(d) = n.stats.dsm.as_deref() else {
                continue;
            };
            s.block_reads += d.block_reads;
            s.fetched += d.fetched;
            waited_s += d.fetch_wait_s;
            thread_s += n.stats.busy_s * d.render_threads as f64;
            s.parked += d.parked;
            s.read_locally += d.read_locally;
            local += d.local_reads;
            if d.latency_count > 0 {
                latency_sum += d.latency_avg_us * d.latency_count as f64;
                latency_count += d.latency_count;
                s.remote_read_min_us = s.remote_read_min_us.min(d.latency_min_us);
                s.remote_read_max_us = s.remote_read_max_us.max(d.latency_max_us);
                s.remote_read_p99_us = s.remote_read_p99_us.max(d.latency_p99_us);
            }
            if d.round_trip_us > 0.0 {
                s.round_trip_us = s.round_trip_us.min(d.round_trip_us);
            }
        }
        let share = |part: u64| {
            if s.block_reads > 0 {
                part as f64 * 100.0 / s.block_reads as f64
            } else {
                0.0
            }
        };
        s.miss_percent = share(s.fetched);
        s.local_percent = share(local);
        s.blocks_read_per_frame = s.block_reads as f64 / frames.max(1) as f64;
        s.remote_read_avg_us = if latency_count > 0 {
            latency_sum / latency_count as f64
        } else {
            0.0
        };
        if s.fetched > 0 {
            s.miss_wait_avg_us = waited_s * 1e6 / s.fetched as f64;
        }
        if thread_s > 0.0 {
            s.wait_percent = (waited_s * 100.0 / thread_s).min(100.0);
        }
        for v in [&mut s.remote_read_min_us, &mut s.round_trip_us] {
            if !v.is_finite() {
                *v = 0.0;
            }
        }
        Some(s)
    }

    pub(super) fn report(&self) -> Report {
        let record = &self.record;
        let elapsed = record.started.map_or(Duration::ZERO, |start| {
            let last = record.presents.last().map_or(start, |(_, t)| *t);
            last.duration_since(start)
        });
        let (frame_ms, start_to_present) = self.frame_times();
        let mut report = self.report_of_frames(elapsed, &frame_ms, &start_to_present);
        self.merge_prior(&mut report, &frame_ms, &start_to_present);
        report
    }

    /// Each present's time since the one before (the first: since the start), and each
    /// frame's from its start to its present, in ms.
    pub(super) fn frame_times(&self) -> (Vec<f64>, Vec<f64>) {
        let record = &self.record;
        let Some(start) = record.started else {
            return (Vec::new(), Vec::new());
        };
        let mut previous = start;
        let mut frame_ms = Vec::new();
        let mut start_to_present = Vec::new();
        for (frame, at) in &record.presents {
            let mut gap = at.duration_since(previous);
            previous = *at;
            if let Some(s) = record.frame_started.get(frame) {
                let took = at.duration_since(*s);
                start_to_present.push(took.as_secs_f64() * 1000.0);
                // A frame started after the wall rested took its own time, not the rest.
                gap = gap.min(took);
            }
            frame_ms.push(gap.as_secs_f64() * 1000.0);
        }
        (frame_ms, start_to_present)
    }

    /// The report of a run whose frames took `elapsed` from the first start to the last
    /// present, with these frame times.
    fn report_of_frames(
        &self,
        elapsed: Duration,
        frame_ms: &[f64],
        start_to_present: &[f64],
    ) -> Report {
        let elapsed = elapsed.as_secs_f64();
        let record = &self.record;
        let last = record.presents.last().map(|(_, at)| *at);
        let rendering = last.map_or(0.0, |at| self.rendering_time(at).as_secs_f64());
        let displays = self.display_reports();
        let render_nodes = self.render_node_reports();
        let frames = record.presents.len() as u64;
        let dsm = self.dsm_summary(&render_nodes, frames);
        Report {
            frames,
            compression: self.cfg.compression,
            wall: WallReport::of(&self.cfg.wall),
            displays,
            render_nodes,
            fps: if rendering > 0.0 {
                frames as f64 / rendering
            } else {
                0.0
            },
            rendering_s: rendering,
            frame_ms: Percentiles::of_ms(frame_ms),
            start_to_present_ms: Percentiles::of_ms(start_to_present),
            frame_period_ms: if frames > 0 {
                elapsed * 1000.0 / frames as f64
            } else {
                0.0
            },
            timing: record.timing.summary(self.cfg.wall.display_count()),
            elapsed_s: elapsed,
            render_nodes_lost: record.lost_render_nodes,
            displays_lost: record.lost_displays,
            frames_cancelled: record.frames_cancelled,
            refinement_passes_dropped: record.refinement_passes_dropped,
            nodes_suspected: record.suspicions,
            master_pauses: record.master_pauses,
            longest_master_pause_ms: record.longest_master_pause.as_secs_f64() * 1000.0,
            frames_short_of_displays: record.frames_short_of_displays,
            nodes_lost: record.lost.clone(),
            tiles_speculated: self.coordinator.speculated_tiles(),
            changes_applied: record.changes_applied,
            snapshots: self.live.snapshots.iter().map(|f| f.0).collect(),
            data: match self.cfg.data {
                DataSpec::Replicated => "replicated",
                DataSpec::Dsm(_) => "dsm",
            },
            dsm,
            takeovers: Vec::new(),
        }
    }

    /// What each display said at shutdown, by id.
    fn display_reports(&self) -> Vec<DisplayReport> {
        let mut displays: Vec<DisplayReport> = self
            .peers
            .values()
            .filter_map(|p| match (&p.role, &p.stats) {
                (PeerRole::Display(d), Some(NodeStats::Display(s))) => {
                    let owned = s.pixels_owned as f64 * 3.0 * s.frames_presented as f64;
                    Some(DisplayReport {
                        id: d.0,
                        host: p.host.clone(),
                        stats: s.clone(),
                        wire_bytes_per_pixel_byte: if owned > 0.0 {
                            s.wire_bytes_received as f64 / owned
                        } else {
                            0.0
                        },
                    })
                }
                _ => None,
            })
            .collect();
        displays.sort_by_key(|d| d.id);
        displays
    }

    /// What each render node said at shutdown, by id.
    fn render_node_reports(&self) -> Vec<RenderNodeReport> {
        let mut render_nodes: Vec<RenderNodeReport> = self
            .peers
            .values()
            .filter_map(|p| match (&p.role, &p.stats) {
                (PeerRole::Render { node, cores }, Some(NodeStats::Render(s))) => {
                    let budget = s.dsm.as_ref().map(|d| d.memory_budget).filter(|&b| b > 0);
                    Some(RenderNodeReport {
                        id: node.0,
                        host: p.host.clone(),
                        cores: *cores,
                        memory_budget: budget,
                        within_budget: budget.map(|b| s.max_rss_bytes <= b),
                        stats: s.clone(),
                        rays_per_s: if s.busy_s > 0.0 {
                            s.rays as f64 / s.busy_s
                        } else {
                            0.0
                        },
                    })
                }
                _ => None,
            })
            .collect();
        render_nodes.sort_by_key(|r| r.id);
        render_nodes
    }
}
