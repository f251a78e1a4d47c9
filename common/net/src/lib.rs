//! Network glue shared by the three node crates: the cluster's certificates ([`cluster`]), QUIC
//! endpoints with mutual TLS ([`quic`]), length-prefixed control streams ([`framed`]), a
//! node's link to its master ([`link`]: handshake, receiving with "lost the master" handling,
//! shutdown, the tokio runtime), the one loop through which render and display nodes run a
//! master's sessions one after another and wait for a lost master (`--reconnect`,
//! [`reconnect`]), and systemd's readiness notification ([`sd_notify`]).
//!
//! It holds no protocol logic: what a message means is decided by the sans-IO state machines of
//! `tessera-core`, which never see a socket. It depends on `tessera-wire` for the messages and
//! on tokio, quinn and rustls (ring provider, set explicitly).

pub mod cluster;
pub mod framed;
pub mod link;
pub mod quic;
pub mod reconnect;
pub mod sd_notify;

use std::net::SocketAddr;
use tessera_wire::protocol::codec::CodecError;

/// What can go wrong on the network side.
#[derive(Debug, thiserror::Error)]
pub enum NetError {
    #[error(transparent)]
    Cert(#[from] cluster::CertError),
    #[error("cluster CA certificate is not usable: {0}")]
    BadCa(rustls::Error),
    #[error("node certificate and key do not match: {0}")]
    KeyMismatch(rustls::Error),
    #[error("TLS set-up failed: {0}")]
    Tls(String),
    #[error("cannot bind a UDP socket on {addr}")]
    Bind {
        addr: SocketAddr,
        source: std::io::Error,
    },
    #[error("no async runtime for QUIC")]
    NoRuntime,
    #[error("cannot connect to {what} at {addr}: {reason}")]
    Connect {
        what: String,
        addr: SocketAddr,
        reason: String,
    },
    #[error("cannot resolve address {addr}: {reason}")]
    Resolve { addr: String, reason: String },
    #[error("control stream closed: {0}")]
    StreamClosed(String),
    #[error("control stream broken: {0}")]
    StreamBroken(String),
    #[error(transparent)]
    Codec(#[from] CodecError),
}

/// Resolves HOST:PORT (names allowed) to the first address it names.
pub async fn resolve(addr: &str) -> Result<SocketAddr, NetError> {
    let failed = |reason: String| NetError::Resolve {
        addr: addr.to_string(),
        reason,
    };
    tokio::net::lookup_host(addr)
        .await
        .map_err(|e| failed(e.to_string()))?
        .next()
        .ok_or_else(|| failed("it names no address".into()))
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
