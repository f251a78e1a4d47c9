//! Which nodes still show signs of life, by the coordinator's own clock: suspicion and death.
//!
//! A node that dies without closing its connection (killed, its host gone, its cable pulled)
//! is otherwise noticed only when the transport's idle timeout fires. But silence is not
//! death: a busy machine, a paused process or a short network blip also silences a node, and
//! dropping a healthy node for it cost whole runs. So silence has two thresholds:
//!
//! * **Suspicion**, after a short fixed deadline ([`BalanceConfig::node_deadline`], a few
//!   heartbeats): the coordinator stops counting on the node (its tiles are copied to others),
//!   but it stays connected, and a suspected node that speaks again is simply back.
//! * **Death**, by a phi-accrual detector (Hayashibara et al. 2004, as Akka and Cassandra use
//!   it): each node's inter-arrival times are learnt, and the node is dead once the chance of
//!   a silence this long, for a node that beats as it has, falls below `10^-phi_threshold`.
//!   An acceptable pause is added to the learnt mean, so a node that beats every 50 ms is not
//!   dead after 0.6 s of a stopped process; a node whose beats jitter gets a longer deadline.
//!
//! Silence the master could not observe (its own process did not run) is credited to every
//! node with [`Liveness::credit`].
//!
//! [`BalanceConfig::node_deadline`]: super::BalanceConfig::node_deadline

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::time::{Duration, Instant};

/// Inter-arrival times kept per node: enough for a stable mean, few enough that a node whose
/// rhythm changed (it finished loading) is relearnt within seconds.
const HISTORY: usize = 200;

/// How death is decided: the phi-accrual detector's knobs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DeathDetector {
    /// A node is dead once phi reaches this (8: a one-in-10^8 chance that a live node was
    /// silent this long, as Akka's cluster default).
    pub phi_threshold: f64,
    /// Silence a live node may show on top of its usual rhythm (a stopped process, a blip).
    pub acceptable_pause: Duration,
    /// The spread of inter-arrival times is taken as at least this: a node that beat like a
    /// clock so far must not die of its first late beat.
    pub min_std_dev: Duration,
    /// The rhythm assumed before a node has beaten twice.
    pub expected_interval: Duration,
}

impl Default for DeathDetector {
    fn default() -> Self {
        DeathDetector {
            phi_threshold: 8.0,
            acceptable_pause: super::DEFAULT_ACCEPTABLE_PAUSE,
            min_std_dev: Duration::from_millis(100),
            expected_interval: tessera_protocol::HEARTBEAT_INTERVAL,
        }
    }
}

impl DeathDetector {
    /// Phi of a silence of `elapsed` for a node whose beats come every `mean` with spread
    /// `std` (seconds): `-log10` of the chance that a beat still comes.
    pub fn phi(&self, elapsed: f64, mean: f64, std: f64) -> f64 {
        let mean = mean + self.acceptable_pause.as_secs_f64();
        let std = std.max(self.min_std_dev.as_secs_f64());
        phi_of_spreads((elapsed - mean) / std)
    }

    /// How many spreads past `mean + acceptable_pause` phi reaches the threshold: phi grows
    /// with the silence, so a bisection finds it.
    fn deadline_in_spreads(&self) -> f64 {
        let (mut lo, mut hi) = (-64.0, 64.0);
        for _ in 0..100 {
            let mid = 0.5 * (lo + hi);
            if phi_of_spreads(mid) >= self.phi_threshold {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        hi
    }
}

/// Phi of a silence `y` spreads past the expected arrival, with the logistic approximation
/// of the normal tail that Akka uses (monotonic in `y`).
fn phi_of_spreads(y: f64) -> f64 {
    let e = (-y * (1.5976 + 0.070566 * y * y)).exp();
    if y > 0.0 {
        -(e / (1.0 + e)).log10()
    } else {
        -(1.0 - 1.0 / (1.0 + e)).log10()
    }
}

/// One node's rhythm: when it was last heard and the gaps between what it said.
#[derive(Debug)]
struct Rhythm {
    last: Instant,
    gaps: VecDeque<f64>,
    sum: f64,
    sum_sq: f64,
}

impl Rhythm {
    fn mean_std(&self, expected: Duration) -> (f64, f64) {
        if self.gaps.len() < 2 {
            let mean = expected.as_secs_f64();
            return (mean, mean / 4.0);
        }
        let n = self.gaps.len() as f64;
        let mean = self.sum / n;
        let var = (self.sum_sq / n - mean * mean).max(0.0);
        (mean, var.sqrt())
    }

    fn push_gap(&mut self, gap: f64) {
        if self.gaps.len() == HISTORY {
            let old = self.gaps.pop_front().unwrap_or(0.0);
            self.sum -= old;
            self.sum_sq -= old * old;
        }
        self.gaps.push_back(gap);
        self.sum += gap;
        self.sum_sq += gap * gap;
    }
}

/// What [`Liveness::expired`] found at a given instant.
#[derive(Debug, Default, PartialEq)]
pub(super) struct Expired<K> {
    /// Newly suspected, with how long each was silent.
    pub suspected: Vec<(K, Duration)>,
    /// Dead, with how long each was silent: forgotten already.
    pub dead: Vec<(K, Duration)>,
}

/// The rhythm of each node (a render node's or a display's id), who is suspected, and when
/// each would be suspected or dead.
#[derive(Debug)]
pub(super) struct Liveness<K> {
    suspect_after: Duration,
    detector: DeathDetector,
    /// `detector.deadline_in_spreads()`, computed once.
    spreads: f64,
    rhythms: BTreeMap<K, Rhythm>,
    /// When each node not yet suspected would be: the timer asks for the first after every
    /// event, and a scan of every node each time was most of a 2,048-node simulation.
    suspect_at: BTreeSet<(Instant, K)>,
    /// When each node would be dead, by its rhythm.
    dead_at: BTreeSet<(Instant, K)>,
    due: BTreeMap<K, (Option<Instant>, Instant)>,
    suspected: BTreeSet<K>,
}

impl<K: Ord + Copy> Liveness<K> {
    pub fn new(suspect_after: Duration, detector: DeathDetector) -> Self {
        Liveness {
            suspect_after,
            detector,
            spreads: detector.deadline_in_spreads(),
            rhythms: BTreeMap::new(),
            suspect_at: BTreeSet::new(),
            dead_at: BTreeSet::new(),
            due: BTreeMap::new(),
            suspected: BTreeSet::new(),
        }
    }

    /// `node` said something at `now` (a later message never moves the clock back). If it
    /// was suspected, it is back: how long it had been silent.
    pub fn heard(&mut self, node: K, now: Instant) -> Option<Duration> {
        let rhythm = self.rhythms.entry(node).or_insert(Rhythm {
            last: now,
            gaps: VecDeque::new(),
            sum: 0.0,
            sum_sq: 0.0,
        });
        let silent = now.saturating_duration_since(rhythm.last);
        if now > rhythm.last {
            rhythm.push_gap(silent.as_secs_f64());
            rhythm.last = now;
        }
        let back = self.suspected.remove(&node).then_some(silent);
        self.reschedule(node);
        back
    }

    /// When `node` would be suspected (none if it is) and dead, from its rhythm.
    fn reschedule(&mut self, node: K) {
        if let Some((suspect, dead)) = self.due.remove(&node) {
            if let Some(s) = suspect {
                self.suspect_at.remove(&(s, node));
            }
            self.dead_at.remove(&(dead, node));
        }
        let Some(rhythm) = self.rhythms.get(&node) else {
            return;
        };
        let (mean, std) = rhythm.mean_std(self.detector.expected_interval);
        let std = std.max(self.detector.min_std_dev.as_secs_f64());
        let pause = self.detector.acceptable_pause.as_secs_f64();
        let dead_after = Duration::from_secs_f64((mean + pause + self.spreads * std).max(0.0));
        let dead = rhythm.last + dead_after.max(self.suspect_after);
        let suspect = (!self.suspected.contains(&node)).then(|| rhythm.last + self.suspect_after);
        if let Some(s) = suspect {
            self.suspect_at.insert((s, node));
        }
        self.dead_at.insert((dead, node));
        self.due.insert(node, (suspect, dead));
    }

    pub fn forget(&mut self, node: K) {
        if let Some((suspect, dead)) = self.due.remove(&node) {
            if let Some(s) = suspect {
                self.suspect_at.remove(&(s, node));
            }
            self.dead_at.remove(&(dead, node));
        }
        self.rhythms.remove(&node);
        self.suspected.remove(&node);
    }

    /// Whether `node` is suspected now.
    pub fn is_suspected(&self, node: K) -> bool {
        self.suspected.contains(&node)
    }

    /// The nodes suspected now.
    pub fn suspected(&self) -> impl Iterator<Item = K> + '_ {
        self.suspected.iter().copied()
    }

    /// When the next node would be suspected or dead.
    pub fn next_deadline(&self) -> Option<Instant> {
        let suspect = self.suspect_at.first().map(|&(t, _)| t);
        let dead = self.dead_at.first().map(|&(t, _)| t);
        suspect.into_iter().chain(dead).min()
    }

    /// How long `node` has been silent at `now`.
    fn silence(&self, node: K, now: Instant) -> Duration {
        self.rhythms
            .get(&node)
            .map_or(Duration::ZERO, |r| now.saturating_duration_since(r.last))
    }

    /// The nodes newly suspected and those dead at `now`; the dead are forgotten.
    pub fn expired(&mut self, now: Instant) -> Expired<K> {
        let mut found = Expired {
            suspected: Vec::new(),
            dead: Vec::new(),
        };
        for node in due(&self.dead_at, now) {
            found.dead.push((node, self.silence(node, now)));
            self.forget(node);
        }
        for node in due(&self.suspect_at, now) {
            found.suspected.push((node, self.silence(node, now)));
            self.suspected.insert(node);
            self.reschedule(node);
        }
        found
    }

    /// The master did not run for `blind` up to `now`: what nobody could have been heard in
    /// counts against nobody, so every node's silence restarts that much later (never after
    /// `now`). The gap is not a rhythm either: no inter-arrival time is learnt from it.
    pub fn credit(&mut self, blind: Duration, now: Instant) {
        let nodes: Vec<K> = self.rhythms.keys().copied().collect();
        for node in nodes {
            if let Some(r) = self.rhythms.get_mut(&node) {
                r.last = (r.last + blind).min(now);
            }
            self.reschedule(node);
        }
    }
}

/// The nodes whose time in `schedule` has come at `now`.
fn due<K: Copy>(schedule: &BTreeSet<(Instant, K)>, now: Instant) -> Vec<K> {
    schedule
        .iter()
        .take_while(|&&(t, _)| t <= now)
        .map(|&(_, k)| k)
        .collect()
}
