//! The run's report, from what the driver recorded and what the nodes said at shutdown.

use super::*;

impl Wall {
    pub(super) fn report(&self) -> Report {
        let start = self.started.unwrap_or_else(Instant::now);
        let last = self.presents.last().map_or(start, |(_, t)| *t);
        let elapsed = last.duration_since(start).as_secs_f64();
        let mut previous = start;
        let mut frame_ms = Vec::new();
        let mut start_to_present = Vec::new();
        for (frame, at) in &self.presents {
            frame_ms.push(at.duration_since(previous).as_secs_f64() * 1000.0);
            previous = *at;
            if let Some(s) = self.frame_started.get(frame) {
                start_to_present.push(at.duration_since(*s).as_secs_f64() * 1000.0);
            }
        }
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
        let mut render_nodes: Vec<RenderNodeReport> = self
            .peers
            .values()
            .filter_map(|p| match (&p.role, &p.stats) {
                (PeerRole::Render { node, cores }, Some(NodeStats::Render(s))) => {
                    Some(RenderNodeReport {
                        id: node.0,
                        host: p.host.clone(),
                        cores: *cores,
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
        let frames = self.presents.len() as u64;
        Report {
            frames,
            compression: self.cfg.compression,
            wall: WallReport::of(&self.cfg.wall),
            displays,
            render_nodes,
            fps: if elapsed > 0.0 {
                frames as f64 / elapsed
            } else {
                0.0
            },
            frame_ms: Percentiles::of_ms(&frame_ms),
            start_to_present_ms: Percentiles::of_ms(&start_to_present),
            frame_period_ms: if frames > 0 {
                elapsed * 1000.0 / frames as f64
            } else {
                0.0
            },
            timing: self.timing.summary(self.cfg.wall.display_count()),
            elapsed_s: elapsed,
            render_nodes_lost: self.lost_render_nodes,
            displays_lost: self.lost_displays,
            frames_short_of_displays: self.frames_short_of_displays,
            tiles_speculated: self.coordinator.speculated_tiles(),
            changes_applied: self.changes_applied,
            snapshots: self.live.snapshots.iter().map(|f| f.0).collect(),
        }
    }
}
