//! Latency and present skew, measured on every run.
//!
//! Each display stamps its presents with its own clock; the master maps those stamps onto its
//! clock. A display on the master's own host (a local wall, network namespaces) reads the very
//! same clock, so its stamps are used as they are; for other hosts the offset is estimated
//! NTP-style from ping/pong round trips, keeping the fastest round trip (the least queuing, so
//! the tightest bound: the offset is known to within half of it). Cross-host figures are thus
//! only as good as that bound, which the report states per display.
//!
//! Latency of frame f: from the master issuing f's `FrameStart` (the barrier where the camera
//! changes) to the last display presenting f. Skew of f: last present minus first present.
//! Pure bookkeeping over timestamps in nanoseconds; the driver reads the clocks.

use super::report::Percentiles;
use serde::Serialize;
use std::collections::{BTreeMap, HashMap};
use tessera_model::wall::DisplayId;
use tessera_protocol::FrameId;

/// Pings sent to each display when it is ready; the fastest answer wins.
pub const PINGS: u32 = 16;

/// How one display's clock relates to the master's, from the fastest ping round trip.
#[derive(Clone, Copy, Debug, Serialize, PartialEq)]
pub struct ClockEstimate {
    /// Display clock minus master clock, in microseconds.
    pub offset_us: f64,
    /// Round trip of the ping the estimate comes from; the offset is within half of it.
    pub rtt_us: f64,
    /// On the master's host: the estimate is reported but stamps are used as they are.
    pub same_host: bool,
}

/// The timestamps of a run (pings, frame starts, presents, input stamps), from which
/// [`Timing::summary`] computes latency and skew.
#[derive(Default)]
pub struct Timing {
    pings: HashMap<(DisplayId, u32), u64>,
    clocks: BTreeMap<DisplayId, (u64, i64)>,
    same_host: std::collections::BTreeSet<DisplayId>,
    starts: HashMap<FrameId, u64>,
    presents: BTreeMap<FrameId, Vec<(DisplayId, u64)>>,
    /// Entry stamps (master clock) of the inputs and commands that a frame's state applied.
    inputs: BTreeMap<FrameId, Vec<u64>>,
    /// When each input or command (by its entry stamp) reached the master, master clock.
    arrivals: HashMap<u64, u64>,
}

/// Where input latency goes, each part over the inputs `input_latency_ms` measured.
#[derive(Debug, Default, Serialize)]
pub struct InputParts {
    /// Entry (the window or client, mapped onto the master's clock) → the master has it.
    pub entry_to_master_ms: Percentiles,
    /// The master has it → the barrier that applies it starts a frame.
    pub master_to_barrier_ms: Percentiles,
    /// That frame's start → presented on every display.
    pub barrier_to_present_ms: Percentiles,
}

/// The durations behind a [`TimingSummary`]'s percentiles, in ms.
#[derive(Debug, Default, Clone, PartialEq)]
pub struct TimingSamples {
    /// Each measured frame's latency.
    pub latency: Vec<f64>,
    /// Each measured frame's skew.
    pub skew: Vec<f64>,
    /// Each measured input's latency.
    pub input_latency: Vec<f64>,
    /// Each measured input's parts: entry → master, master → barrier, barrier → present.
    pub parts: [Vec<f64>; 3],
}

/// One frame's figures, for the per-frame CSV.
#[derive(Clone, Copy, Debug, Serialize, PartialEq)]
pub struct FrameTiming {
    /// The frame's number.
    pub frame: u64,
    /// From the frame's start to its last present, on the master's clock.
    pub latency_ms: f64,
    /// Last present minus first present, on the master's clock.
    pub skew_ms: f64,
}

/// Latency and skew over a run, for the report.
#[derive(Debug, Default, Serialize)]
pub struct TimingSummary {
    /// A frame's start (the barrier where the camera changes) → its present on every display.
    pub latency_ms: Percentiles,
    /// Input event or control command entering the wall (stamped where it entered, mapped to
    /// the master's clock) → the first frame with it presented on every display.
    pub input_latency_ms: Percentiles,
    /// Inputs and commands that `input_latency_ms` measured.
    pub inputs_measured: u64,
    /// Each frame's last present minus its first, across the displays.
    pub skew_ms: Percentiles,
    /// Frames every display reported a present for (a window may coalesce frames).
    pub frames_measured: u64,
    /// Each display's clock estimate, by display id (none for a display that answered no
    /// ping).
    pub clocks: BTreeMap<u32, ClockEstimate>,
    /// Where input latency goes.
    pub input_parts: InputParts,
    /// The figures of each frame measured, in frame order (for the CSV, not the report).
    #[serde(skip)]
    pub per_frame: Vec<FrameTiming>,
    /// Each measured input's frame and its input latency in ms, in frame order (for plots).
    #[serde(skip)]
    pub per_input: Vec<(u64, f64)>,
}

impl Timing {
    /// The display runs on the master's host, so it reads the same clock.
    pub fn same_host(&mut self, display: DisplayId) {
        self.same_host.insert(display);
    }

    /// Display clock minus master clock, in ns, as well as it is known.
    pub fn offset(&self, display: DisplayId) -> i64 {
        if self.same_host.contains(&display) {
            return 0;
        }
        self.clocks.get(&display).map_or(0, |c| c.1)
    }

    /// Ping `seq` left for `display` at `master_ns` (master clock).
    pub fn ping_sent(&mut self, display: DisplayId, seq: u32, master_ns: u64) {
        self.pings.insert((display, seq), master_ns);
    }

    /// The answer to ping `seq` came back at `master_ns`, saying the display's clock read
    /// `display_ns`; it replaces the estimate if its round trip is the fastest yet. An answer
    /// to no ping sent, or a second one, is ignored.
    pub fn pong(&mut self, display: DisplayId, seq: u32, display_ns: u64, master_ns: u64) {
        let Some(sent) = self.pings.remove(&(display, seq)) else {
            return;
        };
        let rtt = master_ns.saturating_sub(sent);
        let midpoint = sent as i128 + rtt as i128 / 2;
        let offset = (display_ns as i128 - midpoint) as i64;
        let best = self.clocks.entry(display).or_insert((u64::MAX, 0));
        if rtt < best.0 {
            *best = (rtt, offset);
        }
    }

    /// The state of `frame` applied the inputs and commands stamped `stamps` (0: unstamped,
    /// as replayed changes are; not measured).
    pub fn inputs_applied(&mut self, frame: FrameId, stamps: &[u64]) {
        let stamped: Vec<u64> = stamps.iter().copied().filter(|&s| s > 0).collect();
        if !stamped.is_empty() {
            self.inputs.entry(frame).or_default().extend(stamped);
        }
    }

    /// The input or command stamped `stamp` reached the master at `master_ns`.
    pub fn input_arrived(&mut self, stamp: u64, master_ns: u64) {
        if stamp > 0 {
            self.arrivals.insert(stamp, master_ns);
        }
    }

    /// `frame` started at `master_ns` (master clock).
    pub fn frame_started(&mut self, frame: FrameId, master_ns: u64) {
        self.starts.insert(frame, master_ns);
    }

    /// `display` presented `frame` at `display_ns`, on its own clock.
    pub fn presented(&mut self, display: DisplayId, frame: FrameId, display_ns: u64) {
        self.presents
            .entry(frame)
            .or_default()
            .push((display, display_ns));
    }

    /// When the last of `displays` presented `frame`, on the master's clock; `None` until
    /// every one did.
    fn last_present(&self, frame: FrameId, displays: u32) -> Option<i128> {
        let presents = self.presents.get(&frame)?;
        if presents.len() < displays as usize {
            return None;
        }
        presents
            .iter()
            .map(|&(d, ns)| ns as i128 - self.offset(d) as i128)
            .max()
    }

    /// Input → present on every display, ms, for each stamped input whose frame every display
    /// presented.
    fn input_latencies(&self, displays: u32) -> Vec<(u64, f64)> {
        let mut out = Vec::new();
        for (frame, stamps) in &self.inputs {
            let Some(last) = self.last_present(*frame, displays) else {
                continue;
            };
            out.extend(
                stamps
                    .iter()
                    .map(|&s| (frame.0, (last - s as i128) as f64 / 1e6)),
            );
        }
        out
    }

    /// Each measured input's entry → master, master → barrier and barrier → present, ms.
    fn input_parts(&self, displays: u32) -> InputParts {
        let mut parts: [Vec<f64>; 3] = Default::default();
        self.each_input_part(displays, |i, ms| parts[i].push(ms));
        InputParts {
            entry_to_master_ms: Percentiles::of_ms(&parts[0]),
            master_to_barrier_ms: Percentiles::of_ms(&parts[1]),
            barrier_to_present_ms: Percentiles::of_ms(&parts[2]),
        }
    }

    /// Calls `part(i, ms)` with each measured input's part `i` (0: entry → master, 1: master →
    /// barrier, 2: barrier → present).
    fn each_input_part(&self, displays: u32, mut part: impl FnMut(usize, f64)) {
        for (frame, stamps) in &self.inputs {
            let (Some(last), Some(&start)) =
                (self.last_present(*frame, displays), self.starts.get(frame))
            else {
                continue;
            };
            for s in stamps {
                let Some(&arrived) = self.arrivals.get(s) else {
                    continue;
                };
                let ms = |a: i128, b: i128| (b - a) as f64 / 1e6;
                part(0, ms(*s as i128, arrived as i128));
                part(1, ms(arrived as i128, start as i128));
                part(2, ms(start as i128, last));
            }
        }
    }

    /// The durations behind [`Timing::summary`]'s percentiles, in ms: what a standby carries
    /// over a takeover, where percentiles would not merge.
    pub fn samples(&self, displays: u32) -> TimingSamples {
        let per_frame = self.per_frame(displays);
        let mut parts: [Vec<f64>; 3] = Default::default();
        self.each_input_part(displays, |i, ms| parts[i].push(ms));
        TimingSamples {
            latency: per_frame.iter().map(|f| f.latency_ms).collect(),
            skew: per_frame.iter().map(|f| f.skew_ms).collect(),
            input_latency: self.input_latencies(displays).iter().map(|p| p.1).collect(),
            parts,
        }
    }

    /// Each frame's figures, over the frames that every one of `displays` presented.
    fn per_frame(&self, displays: u32) -> Vec<FrameTiming> {
        let mut per_frame = Vec::new();
        for (frame, presents) in &self.presents {
            let Some(&start) = self.starts.get(frame) else {
                continue;
            };
            if presents.len() < displays as usize {
                continue;
            }
            let on_master: Vec<i128> = presents
                .iter()
                .map(|&(d, ns)| ns as i128 - self.offset(d) as i128)
                .collect();
            let first = *on_master.iter().min().expect("at least one present");
            let last = *on_master.iter().max().expect("at least one present");
            per_frame.push(FrameTiming {
                frame: frame.0,
                latency_ms: (last - start as i128) as f64 / 1e6,
                skew_ms: (last - first) as f64 / 1e6,
            });
        }
        per_frame
    }

    /// Figures over the frames that every one of `displays` presented.
    pub fn summary(&self, displays: u32) -> TimingSummary {
        let per_frame = self.per_frame(displays);
        let latency: Vec<f64> = per_frame.iter().map(|f| f.latency_ms).collect();
        let skew: Vec<f64> = per_frame.iter().map(|f| f.skew_ms).collect();
        let per_input = self.input_latencies(displays);
        let input_latency: Vec<f64> = per_input.iter().map(|p| p.1).collect();
        TimingSummary {
            latency_ms: Percentiles::of_ms(&latency),
            input_latency_ms: Percentiles::of_ms(&input_latency),
            inputs_measured: input_latency.len() as u64,
            skew_ms: Percentiles::of_ms(&skew),
            input_parts: self.input_parts(displays),
            frames_measured: per_frame.len() as u64,
            clocks: self
                .clocks
                .iter()
                .map(|(d, &(rtt, offset))| {
                    (
                        d.0,
                        ClockEstimate {
                            offset_us: offset as f64 / 1e3,
                            rtt_us: rtt as f64 / 1e3,
                            same_host: self.same_host.contains(d),
                        },
                    )
                })
                .collect(),
            per_frame,
            per_input,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn offsets_come_from_the_fastest_ping_and_map_presents_onto_the_master_clock() {
        let mut t = Timing::default();
        let (a, b) = (DisplayId(0), DisplayId(1));
        // Display b's clock runs 5 ms ahead. A slow ping (queued on the way back) would
        // suggest 9 ms; the fast one must win.
        t.ping_sent(b, 0, 1_000_000);
        t.pong(b, 0, 1_000_000 + 5_000_000 + 100_000, 1_000_000 + 8_000_000);
        t.ping_sent(b, 1, 2_000_000);
        t.pong(b, 1, 2_000_000 + 5_000_000 + 50_000, 2_000_000 + 100_000);
        t.ping_sent(a, 0, 0);
        t.pong(a, 0, 50_000, 100_000);
        t.pong(a, 7, 0, 0); // an answer to no ping is ignored
                            // Frame 3 starts at 10 ms; a presents at 14 ms, b at 14.5 ms (its clock: 19.5 ms).
        t.frame_started(FrameId(3), 10_000_000);
        t.presented(a, FrameId(3), 14_000_000);
        t.presented(b, FrameId(3), 19_500_000);
        // Frame 4 reached only one display: not measured.
        t.frame_started(FrameId(4), 20_000_000);
        t.presented(a, FrameId(4), 25_000_000);
        let s = t.summary(2);
        assert_eq!(s.frames_measured, 1);
        assert_eq!(
            s.per_frame,
            vec![FrameTiming {
                frame: 3,
                latency_ms: 4.5,
                skew_ms: 0.5
            }]
        );
        assert_eq!(s.clocks[&1].offset_us, 5000.0);
        assert_eq!(s.clocks[&1].rtt_us, 100.0);
        assert!((s.latency_ms.max - 4.5).abs() < 0.01);

        // On the master's host the stamps are taken as they are, whatever the estimate.
        t.same_host(b);
        t.presented(b, FrameId(4), 25_200_000);
        let s = t.summary(2);
        assert_eq!(s.per_frame[1].skew_ms, 0.2);
        assert!(s.clocks[&1].same_host);
    }

    #[test]
    fn input_latency_runs_from_each_stamp_to_the_last_display_present() {
        let mut t = Timing::default();
        let (a, b) = (DisplayId(0), DisplayId(1));
        t.same_host(a);
        t.same_host(b);
        // Two inputs (at 1 ms and 3 ms) and a replayed change (0) land in frame 7.
        t.inputs_applied(FrameId(7), &[1_000_000, 3_000_000, 0]);
        t.input_arrived(1_000_000, 1_500_000);
        t.input_arrived(3_000_000, 3_200_000);
        t.frame_started(FrameId(7), 4_000_000);
        t.presented(a, FrameId(7), 9_000_000);
        let s = t.summary(2);
        assert_eq!(s.inputs_measured, 0, "not on every display yet");
        t.presented(b, FrameId(7), 10_000_000);
        let s = t.summary(2);
        assert_eq!(s.inputs_measured, 2);
        // Each input at its frame, for the latency plot.
        assert_eq!(s.per_input, [(7, 9.0), (7, 7.0)]);
        assert!(
            (s.input_latency_ms.max - 9.0).abs() < 0.01,
            "{:?}",
            s.input_latency_ms
        );
        assert!(
            (s.input_latency_ms.p50 - 7.0).abs() < 0.05,
            "{:?}",
            s.input_latency_ms
        );
        // The parts: 0.5 and 0.2 ms to reach the master, then to the barrier at 4 ms, then
        // 6 ms to the last present.
        let p = &s.input_parts;
        assert!((p.entry_to_master_ms.max - 0.5).abs() < 0.01, "{p:?}");
        assert!((p.master_to_barrier_ms.max - 2.5).abs() < 0.01, "{p:?}");
        assert!((p.barrier_to_present_ms.p50 - 6.0).abs() < 0.01, "{p:?}");
    }
}
