//! `--reconnect`: what a render or display node does when its master is lost. These are the
//! flags; the loop that acts on them is `tessera_net::reconnect`.

use clap::Args;
use std::time::Duration;

/// Whether a node waits for a lost master to come back, and for how long.
#[derive(Args, Debug, Clone, Copy)]
pub struct ReconnectArgs {
    /// When the master is lost (killed, crashed, its host down), wait for a restarted master
    /// at the same address and rejoin it, instead of exiting; a node rejoins as often as the
    /// master comes back. Without it the node exits with status 1, saying so.
    #[arg(long)]
    pub reconnect: bool,
    /// With --reconnect: seconds to wait for the master each time it is lost before giving up
    /// (1 to 86400).
    #[arg(long, default_value_t = 60, requires = "reconnect",
          value_parser = clap::value_parser!(u64).range(1..=86_400))]
    pub reconnect_timeout: u64,
    /// With a list of masters (`--master A,B`): give a master silent this many ms up and join
    /// the next (50 to 60000). Give it the value of the standby's `serve --failover-after`, so
    /// that the node leaves when the standby takes over.
    #[arg(long, value_name = "MS", default_value_t = FAILOVER_AFTER_MS,
          value_parser = clap::value_parser!(u64).range(50..=60_000))]
    pub failover_after: u64,
}

/// `--failover-after`'s default: [`tessera_protocol::FAILOVER_AFTER`], in ms.
const FAILOVER_AFTER_MS: u64 = tessera_protocol::FAILOVER_AFTER.as_millis() as u64;

impl ReconnectArgs {
    /// How long to wait for a lost master, if the node waits at all.
    pub fn wait(&self) -> Option<Duration> {
        self.reconnect
            .then(|| Duration::from_secs(self.reconnect_timeout))
    }

    /// How long a master of a list may be silent before the node joins the next.
    pub fn failover_after(&self) -> Duration {
        Duration::from_millis(self.failover_after)
    }
}
