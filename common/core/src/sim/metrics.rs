//! What a simulated run measured: balance efficiency, frames completed, what the network cost.

use serde::Serialize;

/// Per-node accounting kept while the run goes.
#[derive(Clone, Debug, Default)]
pub(super) struct NodeClock {
    /// Virtual microseconds spent rendering, including a batch cut short by the node's death.
    pub busy_us: u64,
    /// When the batch in hand started, if the node is rendering.
    pub busy_since: Option<u64>,
    pub died_at: Option<u64>,
    /// Virtual microseconds to render one full tile.
    pub tile_us: u64,
}

/// Min, percentiles and max of a set of fractions.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Spread {
    /// The smallest value.
    pub min: f64,
    /// The 10th percentile.
    pub p10: f64,
    /// The median.
    pub p50: f64,
    /// The 90th percentile.
    pub p90: f64,
    /// The largest value.
    pub max: f64,
}

impl Spread {
    /// The spread of `values`; all 0 for no values.
    pub fn of(values: &[f64]) -> Spread {
        if values.is_empty() {
            return Spread::default();
        }
        let mut v = values.to_vec();
        v.sort_by(f64::total_cmp);
        let at = |q: f64| v[((v.len() - 1) as f64 * q).round() as usize];
        Spread {
            min: v[0],
            p10: at(0.1),
            p50: at(0.5),
            p90: at(0.9),
            max: v[v.len() - 1],
        }
    }
}

/// The figures of one simulated run, all in virtual time.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SimReport {
    /// Render nodes over the run, those that joined it late included.
    pub render_nodes: u32,
    /// Of those, the nodes killed (see [`SimWall::kill_at`](crate::sim::SimWall::kill_at)).
    pub render_nodes_killed: u32,
    /// Displays of the wall.
    pub displays: u32,
    /// Tiles of the whole wall.
    pub tiles_per_frame: u32,
    /// Frames the run was asked for.
    pub frames_requested: u64,
    /// Frames presented, in order, on every display.
    pub frames_completed: u64,
    /// Load-balance efficiency: each render node's busy time over the time it was alive
    /// within the frames' span, averaged over render nodes.
    pub efficiency: f64,
    /// The least efficient render node.
    pub efficiency_min: f64,
    /// Busy fractions of the render nodes (min, p10, median, p90, max).
    pub busy_fraction: Spread,
    /// From the first frame's start to the last frame's last tile reported rendered: the time
    /// render nodes could have been working.
    pub span_s: f64,
    /// From the first frame's start to the last present on every display.
    pub elapsed_s: f64,
    /// Frames completed per second of virtual time.
    pub fps: f64,
    /// One-way latency of every link, in virtual microseconds, before jitter.
    pub latency_us: u64,
    /// Probability that one transmission of a message is lost.
    pub loss: f64,
    /// Messages sent (control messages, pixel batches, acknowledgements).
    pub messages: u64,
    /// Retransmissions that loss made necessary.
    pub retransmissions: u64,
    /// Pixel batches whose retransmission never happened because their sender died.
    pub pixel_batches_lost_with_sender: u64,
    /// Tiles that reached a display twice (re-rendered after their first renderer died).
    pub duplicate_tiles: u64,
    /// Tiles that reached a display after it presented their frame.
    pub late_tiles: u64,
    /// Of `late_tiles`, those sent by a live render node (counted as duplicates by the display,
    /// which must not take them for a fault of that node).
    pub late_tiles_from_live_nodes: u64,
    /// (display, frame) pairs whose presented pixels differed from the rendered ones.
    pub corrupt_frames: u64,
    /// Events the simulator processed.
    pub events: u64,
}

/// Busy fraction of each node over its part of `[start, end]`, skipping nodes that died
/// before the span began.
pub(super) fn busy_fractions(nodes: &[NodeClock], start: u64, end: u64) -> Vec<f64> {
    nodes
        .iter()
        .filter_map(|n| {
            let until = n.died_at.map_or(end, |d| d.min(end));
            let alive = until.checked_sub(start).filter(|&a| a > 0)?;
            Some((n.busy_us as f64 / alive as f64).min(1.0))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spread_of_known_values() {
        let v: Vec<f64> = (0..=10).map(|i| i as f64 / 10.0).collect();
        let s = Spread::of(&v);
        assert_eq!(
            (s.min, s.p10, s.p50, s.p90, s.max),
            (0.0, 0.1, 0.5, 0.9, 1.0)
        );
        assert_eq!(Spread::of(&[]), Spread::default());
    }

    #[test]
    fn a_dead_node_is_measured_over_its_life_only() {
        let node = |busy_us, died_at| NodeClock {
            busy_us,
            died_at,
            ..NodeClock::default()
        };
        let f = busy_fractions(
            &[node(50, None), node(40, Some(50)), node(0, Some(0))],
            0,
            100,
        );
        assert_eq!(f, vec![0.5, 0.8]);
    }
}
