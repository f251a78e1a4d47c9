//! Network glue shared by the three node crates: the cluster's certificates ([`cluster`]), QUIC
//! endpoints with mutual TLS ([`quic`]), length-prefixed control streams ([`framed`]), a
//! node's link to its master ([`link`]: handshake, receiving with "lost the master" handling,
//! shutdown, the tokio runtime), the one loop through which render and display nodes run a
//! master's sessions one after another and wait for a lost master (`--reconnect`,
//! [`reconnect`]), and systemd's readiness notification ([`sd_notify`]).
//!
//! It holds no protocol logic: what a message means is decided by the sans-IO state machines of
//! `tessera-core`, which never see a socket. It depends on `tessera-protocol` for the messages
//! and on tokio, quinn and rustls (ring provider, set explicitly).

#![warn(missing_docs)]

pub mod cluster;
pub mod framed;
pub mod link;
pub mod quic;
pub mod reconnect;
pub mod sd_notify;

use std::net::SocketAddr;
use tessera_protocol::codec::CodecError;

/// What can go wrong on the network side.
#[derive(Debug, thiserror::Error)]
pub enum NetError {
    /// The node's certificates could not be read (or the CA's made).
    #[error(transparent)]
    Cert(#[from] cluster::CertError),
    /// The `ca.pem` of the node's directory is no CA certificate rustls can trust.
    #[error("cluster CA certificate is not usable: {0}")]
    BadCa(rustls::Error),
    /// `node.pem` and `node.key` are not one certificate and its key.
    #[error("node certificate and key do not match: {0}")]
    KeyMismatch(rustls::Error),
    /// rustls or quinn refused the TLS configuration; the text says which step.
    #[error("TLS set-up failed: {0}")]
    Tls(String),
    /// The endpoint's UDP socket could not be bound (address in use, not this host's).
    #[error("cannot bind a UDP socket on {addr}")]
    Bind {
        /// The address the endpoint was to listen on.
        addr: SocketAddr,
        /// The operating system's reason.
        source: std::io::Error,
    },
    /// An endpoint was made outside a tokio runtime.
    #[error("no async runtime for QUIC")]
    NoRuntime,
    /// A peer did not answer, refused the handshake, or did not answer within
    /// [`quic::CONNECT_TIMEOUT`]; for a node's master, a lost master (see
    /// [`link::LinkError::is_lost_master`]).
    #[error("cannot connect to {what} at {addr}: {reason}")]
    Connect {
        /// The peer, for the message: `the master`, `display 3`.
        what: String,
        /// Where it was looked for.
        addr: SocketAddr,
        /// quinn's reason, or the timeout.
        reason: String,
    },
    /// A HOST:PORT did not resolve to any address.
    #[error("cannot resolve address {addr}: {reason}")]
    Resolve {
        /// The address as given.
        addr: String,
        /// The resolver's reason.
        reason: String,
    },
    /// A message could not be written: the stream or its connection is closed.
    #[error("control stream closed: {0}")]
    StreamClosed(String),
    /// A message could not be read whole: the stream or its connection broke.
    #[error("control stream broken: {0}")]
    StreamBroken(String),
    /// The peer closed the connection on purpose, with an application code and reason: the
    /// master closes a node's with [`link::RUN_OVER`] once its run is over (completed or
    /// failed), with another code when it drops the node.
    #[error("the peer closed the connection: {reason} (code {code})")]
    ClosedByPeer {
        /// The application error code it closed with.
        code: u64,
        /// Its reason phrase.
        reason: String,
    },
    /// A message could not be encoded, or the bytes read are no message (bad length prefix,
    /// malformed body).
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
