//! Network glue shared by the three node crates: cluster certificates, QUIC endpoints and
//! control-message streams. It lives in `common` so the binaries do not each grow a copy; the
//! protocol logic itself stays in the sans-IO modules.

pub mod cluster;
pub mod framed;
pub mod quic;

use anyhow::{Context, Result};
use std::net::SocketAddr;

/// Resolves the master's HOST:PORT (names allowed) to the first address it names.
pub async fn resolve_master(addr: &str) -> Result<SocketAddr> {
    tokio::net::lookup_host(addr)
        .await
        .with_context(|| format!("cannot resolve master address {addr}"))?
        .next()
        .with_context(|| format!("master address {addr} resolves to nothing"))
}

/// Nanoseconds since the Unix epoch: the clock that display nodes stamp presents with and the
/// master maps onto its own (see `tessera-master`'s clock sync). A clock read, so only the
/// drivers call it.
pub fn unix_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

/// This host's name, for the hello message and the master's log lines.
pub fn hostname() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map_or_else(|_| "unknown".into(), |h| h.trim().to_string())
}
