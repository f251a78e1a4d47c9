//! Which nodes still show signs of life, by the coordinator's own clock.
//!
//! A node that dies without closing its connection (killed, its host gone, its cable pulled)
//! is otherwise noticed only when the transport's idle timeout fires: ten seconds in which its
//! tiles stay assigned and every display waits on them. Render nodes send a heartbeat every
//! [`HEARTBEAT_INTERVAL`](tessera_protocol::HEARTBEAT_INTERVAL); anything a node sends
//! counts, and a node silent for the deadline is declared gone, so its tiles go elsewhere after
//! the deadline and not after the transport's timeout.

use std::collections::{BTreeMap, BTreeSet};
use std::time::{Duration, Instant};

/// The last time each node (a render node's or a display's id) was heard from, and how long a
/// silence is allowed.
#[derive(Debug)]
pub(super) struct Liveness<K> {
    deadline: Duration,
    last_heard: BTreeMap<K, Instant>,
    /// The same, quietest first: the timer asks for the quietest after every event, and a
    /// scan of every node each time was most of a 2,048-node simulation.
    by_time: BTreeSet<(Instant, K)>,
}

impl<K: Ord + Copy> Liveness<K> {
    pub fn new(deadline: Duration) -> Self {
        Liveness {
            deadline,
            last_heard: BTreeMap::new(),
            by_time: BTreeSet::new(),
        }
    }

    /// `node` said something at `now` (a later message never moves the clock back).
    pub fn heard(&mut self, node: K, now: Instant) {
        let last = self.last_heard.entry(node).or_insert(now);
        self.by_time.remove(&(*last, node));
        *last = (*last).max(now);
        self.by_time.insert((*last, node));
    }

    pub fn forget(&mut self, node: K) {
        if let Some(t) = self.last_heard.remove(&node) {
            self.by_time.remove(&(t, node));
        }
    }

    /// When the quietest node's silence reaches the deadline.
    pub fn next_deadline(&self) -> Option<Instant> {
        self.by_time.first().map(|&(t, _)| t + self.deadline)
    }

    /// The nodes silent for the deadline or longer at `now`, with how long each was silent.
    pub fn expired(&self, now: Instant) -> Vec<(K, Duration)> {
        self.by_time
            .iter()
            .take_while(|(t, _)| now.saturating_duration_since(*t) >= self.deadline)
            .map(|&(t, node)| (node, now.saturating_duration_since(t)))
            .collect()
    }
}
