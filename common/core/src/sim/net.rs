//! The simulated network: latency with seeded jitter, seeded loss repaired by retransmission,
//! and in-order delivery per stream (see the module doc of [`super`] for the model).

use std::collections::HashMap;

/// Deterministic pseudo-random numbers (xorshift64): the same seed replays the same run.
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    /// A generator from `seed` (seeds that differ only in their lowest bit give the same
    /// numbers).
    pub fn new(seed: u64) -> Self {
        Rng(seed | 1)
    }

    /// A second generator from the same seed whose numbers do not track this one's, so that
    /// turning loss on does not change the jitter every message gets.
    pub fn derived(seed: u64, stream: u64) -> Self {
        // splitmix64 finaliser: neighbouring seeds and streams give unrelated starting states.
        let mut z = seed ^ stream.wrapping_mul(0x9E37_79B9_7F4A_7C15);
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        Rng::new(z ^ (z >> 31))
    }

    /// The next number, uniform over `u64` except 0.
    pub fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }

    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// An ordered byte stream of the real system: a message never overtakes an earlier one on it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub(super) enum Stream {
    ToRender(u32),
    FromRender(u32),
    ToDisplay(u32),
    FromDisplay(u32),
    FromControl(u32),
    /// A stream of its own (one pixel batch, one acknowledgement): nothing queues behind it.
    Own,
}

/// When a message arrives, and when it last left its sender.
#[derive(Clone, Copy, Debug)]
pub(super) struct Delivery {
    pub at: u64,
    /// The transmission that got through; a sender that died before it never made it.
    pub last_tx: u64,
}

/// Doublings of the retransmission timeout before it stops growing. QUIC's backoff is
/// unbounded but its idle timeout ends the connection first; the cap keeps virtual times finite
/// when a run asks for loss close to 1.
const MAX_BACKOFF_DOUBLINGS: u32 = 6;

pub(super) struct Network {
    latency_us: u64,
    loss: f64,
    jitter: Rng,
    coins: Rng,
    /// Arrival time of the last message on each stream.
    clock: HashMap<Stream, u64>,
    pub messages: u64,
    pub retransmissions: u64,
}

impl Network {
    pub fn new(seed: u64, latency_us: u64, loss: f64) -> Self {
        Network {
            latency_us,
            loss,
            jitter: Rng::new(seed),
            coins: Rng::derived(seed, 1),
            clock: HashMap::new(),
            messages: 0,
            retransmissions: 0,
        }
    }

    pub fn latency_us(&self) -> u64 {
        self.latency_us
    }

    pub fn loss(&self) -> f64 {
        self.loss
    }

    /// The first retransmission timeout: QUIC's probe timeout is about 1.5 round trips once it
    /// has measured the path, i.e. three one-way latencies.
    pub fn rto_us(&self) -> u64 {
        3 * self.latency_us.max(1)
    }

    /// Sends a message at `sent_at` on `stream`.
    pub fn deliver(&mut self, sent_at: u64, stream: Stream) -> Delivery {
        self.messages += 1;
        let mut last_tx = sent_at;
        if self.loss > 0.0 {
            let mut doublings = 0;
            while self.coins.unit() < self.loss {
                last_tx += self.rto_us() << doublings;
                doublings = (doublings + 1).min(MAX_BACKOFF_DOUBLINGS);
                self.retransmissions += 1;
            }
        }
        let jitter = self.jitter.next_u64() % (self.latency_us / 2 + 1);
        let mut at = last_tx + self.latency_us + jitter;
        if stream != Stream::Own {
            // Head-of-line blocking: a retransmitted message holds back the rest of its stream.
            let last = self.clock.entry(stream).or_insert(0);
            at = at.max(*last);
            *last = at;
        }
        Delivery { at, last_tx }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn without_loss_a_message_takes_latency_plus_at_most_half_of_it_in_jitter() {
        let mut net = Network::new(5, 40, 0.0);
        for t in 0..200 {
            let d = net.deliver(t * 10, Stream::Own);
            assert!((t * 10 + 40..=t * 10 + 60).contains(&d.at), "{d:?}");
            assert_eq!(d.last_tx, t * 10);
        }
        assert_eq!(net.retransmissions, 0);
    }

    #[test]
    fn lost_messages_arrive_late_but_arrive_and_a_stream_keeps_its_order() {
        let mut net = Network::new(9, 40, 0.3);
        let mut last = 0;
        let mut late = 0;
        for t in 0..500 {
            let d = net.deliver(t, Stream::ToRender(3));
            assert!(d.at >= last, "stream reordered");
            last = d.at;
            if d.last_tx > t {
                late += 1;
                assert!(d.at >= t + net.rto_us() + 40);
            }
        }
        assert_eq!(late as u64 > 0, net.retransmissions > 0);
        // About 0.3 / 0.7 retransmissions per message; a wide band, the seed is fixed.
        let per_message = net.retransmissions as f64 / 500.0;
        assert!((0.3..0.6).contains(&per_message), "{per_message}");
    }

    #[test]
    fn separate_streams_do_not_block_each_other() {
        let mut net = Network::new(2, 40, 0.0);
        let a = net.deliver(1000, Stream::ToRender(1));
        let b = net.deliver(0, Stream::ToRender(2));
        assert!(b.at < a.at);
        let c = net.deliver(0, Stream::ToRender(1));
        assert!(c.at >= a.at);
    }
}
