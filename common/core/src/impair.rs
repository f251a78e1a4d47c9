//! A network's faults as a state machine: what becomes of each datagram a relay is handed.
//!
//! The kernel here has no `sch_netem`, so tests impair traffic with a UDP relay between nodes
//! (`tessera-master relay`); this is its model, with no socket or clock: the relay asks
//! [`Impairment::handle_datagram`] with the time since it started and sends each copy it is
//! told to, after the delay it is told. Loss, delay with jitter (which reorders datagrams),
//! explicit reordering (a datagram held back longer), duplication, and a partition that drops
//! everything for a while and then heals.
//!
//! ```
//! use std::time::Duration;
//! use tessera_core::impair::{Faults, Impairment};
//!
//! let faults = Faults { loss: 0.5, delay: Duration::from_millis(20), ..Faults::NONE };
//! let mut relay = Impairment::new(faults, 7);
//! let sent: usize = (0..1000).map(|_| relay.handle_datagram(Duration::ZERO).len()).sum();
//! assert!((400..600).contains(&sent));
//! assert_eq!(relay.stats().dropped as usize, 1000 - sent);
//! ```

use crate::sim::Rng;
use std::time::Duration;

/// What the relay does to the traffic through it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Faults {
    /// Chance that a datagram is dropped (0..1).
    pub loss: f64,
    /// Every datagram's delay, before jitter.
    pub delay: Duration,
    /// A uniform extra delay in 0..jitter, drawn per datagram (so datagrams overtake each other).
    pub jitter: Duration,
    /// Chance that a datagram is held back a further `reorder_by` behind those after it.
    pub reorder: f64,
    /// How much longer a datagram chosen by `reorder` is held back.
    pub reorder_by: Duration,
    /// Chance that a datagram is sent twice.
    pub duplicate: f64,
    /// From `start` for `length`, nothing gets through; then the partition heals.
    pub partition: Option<(Duration, Duration)>,
}

impl Faults {
    /// A clean network: every datagram goes through at once, once. Other faults are written
    /// as `Faults { loss: 0.1, ..Faults::NONE }`.
    pub const NONE: Faults = Faults {
        loss: 0.0,
        delay: Duration::ZERO,
        jitter: Duration::ZERO,
        reorder: 0.0,
        reorder_by: Duration::ZERO,
        duplicate: 0.0,
        partition: None,
    };
}

/// What the relay did, counted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct RelayStats {
    /// Datagrams handed to the relay.
    pub received: u64,
    /// Copies sent on (duplicates included).
    pub forwarded: u64,
    /// Datagrams of which no copy was sent: lost, or cut off by the partition.
    pub dropped: u64,
    /// Of the dropped: during the partition.
    pub partitioned: u64,
    /// Datagrams sent twice.
    pub duplicated: u64,
    /// Copies held back a further [`Faults::reorder_by`].
    pub reordered: u64,
}

/// The relay's decisions, from a seed: the same seed and the same arrivals give the same faults.
pub struct Impairment {
    faults: Faults,
    rng: Rng,
    stats: RelayStats,
}

impl Impairment {
    /// A relay that applies `faults`, its random draws seeded with `seed`.
    pub fn new(faults: Faults, seed: u64) -> Self {
        Impairment {
            faults,
            rng: Rng::new(seed),
            stats: RelayStats::default(),
        }
    }

    /// A datagram arrived `since_start` after the relay started: the delays after which to
    /// send each copy of it (none: dropped).
    pub fn handle_datagram(&mut self, since_start: Duration) -> Vec<Duration> {
        let f = self.faults;
        self.stats.received += 1;
        if let Some((start, length)) = f.partition {
            if since_start >= start && since_start < start + length {
                self.stats.dropped += 1;
                self.stats.partitioned += 1;
                return Vec::new();
            }
        }
        if self.rng.unit() < f.loss {
            self.stats.dropped += 1;
            return Vec::new();
        }
        let copies = if self.rng.unit() < f.duplicate {
            self.stats.duplicated += 1;
            2
        } else {
            1
        };
        let delays: Vec<Duration> = (0..copies)
            .map(|_| {
                let mut d = f.delay + f.jitter.mul_f64(self.rng.unit());
                if self.rng.unit() < f.reorder {
                    self.stats.reordered += 1;
                    d += f.reorder_by;
                }
                d
            })
            .collect();
        self.stats.forwarded += delays.len() as u64;
        delays
    }

    /// What the relay did since it was made.
    pub fn stats(&self) -> RelayStats {
        self.stats
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_fault_happens_at_its_rate_and_the_partition_heals() {
        let ms = Duration::from_millis;
        let faults = Faults {
            loss: 0.02,
            delay: ms(20),
            jitter: ms(5),
            reorder: 0.01,
            reorder_by: ms(30),
            duplicate: 0.01,
            partition: Some((ms(1000), ms(500))),
        };
        let mut relay = Impairment::new(faults, 3);
        let mut delays = Vec::new();
        for i in 0..20_000u64 {
            // Arrivals spread over 2 s: a quarter of them fall in the partition.
            delays.extend(relay.handle_datagram(ms(i / 10)));
        }
        let s = relay.stats();
        assert_eq!(s.received, 20_000);
        assert_eq!(s.partitioned, 5_000);
        let outside = 15_000.0;
        let lost = (s.dropped - s.partitioned) as f64 / outside;
        assert!((0.015..0.025).contains(&lost), "loss {lost}");
        assert!((100..200).contains(&s.duplicated), "{s:?}");
        assert!((100..220).contains(&s.reordered), "{s:?}");
        assert_eq!(s.forwarded as usize, delays.len());
        assert!(delays.iter().all(|d| *d >= ms(20) && *d < ms(55)));
        // The same seed, the same faults.
        let mut again = Impairment::new(faults, 3);
        let replay: Vec<Duration> = (0..20_000u64)
            .flat_map(|i| again.handle_datagram(ms(i / 10)))
            .collect();
        assert_eq!(replay, delays);
    }
}
