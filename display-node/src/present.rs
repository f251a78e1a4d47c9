//! Waiting for a present deadline precisely.

use std::time::Duration;

/// Sleeps until the clock (ns since the Unix epoch) reads `at`: the last stretch is spun, since
/// a sleeping thread wakes up to tens of microseconds late. A deadline more than a second away
/// means clocks that disagree; waiting for it would stall the wall, so it is not waited for.
pub fn wait_until(at: u64) {
    const SPIN: Duration = Duration::from_micros(200);
    for _ in 0..100_000_000u64 {
        let now = tessera_net::unix_ns();
        let Some(left) = at.checked_sub(now).filter(|&l| l > 0) else {
            return;
        };
        let left = Duration::from_nanos(left);
        if left > Duration::from_secs(1) {
            tracing::warn!("a present deadline {left:?} away: clocks disagree; presenting now");
            return;
        }
        if left > SPIN {
            std::thread::sleep(left - SPIN);
        } else {
            std::hint::spin_loop();
        }
    }
}
