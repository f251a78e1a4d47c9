//! QUIC endpoints with mutual TLS against the cluster CA (ring provider, TLS 1.3 only).

use crate::cluster::{cert_roles, CertRole, NodeIdentity, CLUSTER_SERVER_NAME};
use crate::NetError;
use quinn::crypto::rustls::{QuicClientConfig, QuicServerConfig};
use rustls::server::WebPkiClientVerifier;
use rustls::RootCertStore;
use rustls_pki_types::CertificateDer;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;
use tessera_protocol::ALPN;

type Result<T, E = NetError> = std::result::Result<T, E>;

fn provider() -> Arc<rustls::crypto::CryptoProvider> {
    Arc::new(rustls::crypto::ring::default_provider())
}

fn roots(id: &NodeIdentity) -> Result<Arc<RootCertStore>> {
    let mut roots = RootCertStore::empty();
    roots.add(id.ca.clone()).map_err(NetError::BadCa)?;
    Ok(Arc::new(roots))
}

/// The largest UDP payload a Tessera endpoint accepts and MTU discovery probes for: a 9000-byte
/// jumbo frame less the IPv4 and UDP headers. Each QUIC packet costs about 40 bytes of header,
/// AEAD tag and frame header, 2.6% of quinn's default 1452-byte ceiling and 0.45% of this.
/// Probing above what a path carries is safe: a probe that is too big is lost (or refused by the
/// kernel) and discovery settles on the largest size that got through, ~1452 bytes on a
/// 1500-byte Ethernet. Loopback would carry 64 KiB, but the probes' padding costs more than the
/// bigger packets save: ~0.9 MB per connection at each discovery, against ~0.08 MB up to here.
pub const MAX_UDP_PAYLOAD: u16 = 8972;

/// Socket buffers asked for (the kernel caps them at net.core.rmem_max / wmem_max). A display
/// receives a frame's pixels from every render node at once; datagrams that overflow a small
/// receive buffer are lost, resent, and, several large ones in a row, taken by quinn for an MTU
/// black hole that drops the packet size to 1200 bytes.
const SOCKET_BUFFER: usize = 16 << 20;

/// A connection silent this long is closed: the transport's last word on a peer that died
/// without a goodbye. It is longer than any pause the master accepts of a node
/// (`--acceptable-pause-ms`, at most 8 s, plus a few spreads of its rhythm), so that the
/// master's failure detector, not the transport, decides who is dead, and a node or master
/// stopped for seconds (a busy machine, SIGSTOP, a network blip) keeps its connections. Nodes
/// notice a silent master sooner, by their own watch over what arrives (`link`). Keep-alives
/// come from quinn's own task, so a node busy loading or rendering still sends them.
pub const IDLE_TIMEOUT: Duration = Duration::from_secs(12);
const KEEP_ALIVE: Duration = Duration::from_millis(250);

/// Window sizes sized for pixel traffic: a 4K screen's frame is 25 MB, and a window much smaller
/// than bandwidth × RTT caps throughput.
fn transport() -> Arc<quinn::TransportConfig> {
    let mut t = base_transport();
    t.max_concurrent_uni_streams(4096u32.into())
        .stream_receive_window((32u32 << 20).into())
        .receive_window((256u32 << 20).into())
        .send_window(256 << 20);
    Arc::new(t)
}

/// Windows for render nodes' block traffic (distributed shared memory), which counts against a
/// memory budget: what a peer may send before it is read, and what a node keeps unacknowledged,
/// stay a few MiB (with the pixel windows a node under load buffered 30 MiB of blocks). 8 MiB
/// is a thousand 8 KB blocks in flight, far more than a node's misses of a moment.
pub const BLOCK_WINDOW: u32 = 8 << 20;

fn block_transport() -> Arc<quinn::TransportConfig> {
    let mut t = base_transport();
    t.max_concurrent_bidi_streams(1024u32.into())
        .stream_receive_window((1u32 << 20).into())
        .receive_window(BLOCK_WINDOW.into())
        .send_window(BLOCK_WINDOW as u64);
    Arc::new(t)
}

/// What every connection shares: MTU discovery, keep-alives and the idle timeout.
fn base_transport() -> quinn::TransportConfig {
    let mut t = quinn::TransportConfig::default();
    let mut mtu = quinn::MtuDiscoveryConfig::default();
    // A burst of congestion losses also reads as a black hole; look again soon rather than
    // send small packets for the default minute.
    mtu.upper_bound(MAX_UDP_PAYLOAD)
        .black_hole_cooldown(Duration::from_secs(5));
    t.mtu_discovery_config(Some(mtu));
    t.keep_alive_interval(Some(KEEP_ALIVE))
        .max_idle_timeout(Some(IDLE_TIMEOUT.try_into().expect("12 s fits")))
        // Heartbeats travel as datagrams (`link`); quinn enables them by default, and a
        // peer that advertised no buffer could not be sent one, so this says so here.
        .datagram_receive_buffer_size(Some(DATAGRAM_BUFFER));
    t
}

/// What a connection buffers of received datagrams not yet read: a heartbeat is a few bytes,
/// so this holds seconds of a stalled reader's beats.
const DATAGRAM_BUFFER: usize = 64 << 10;

/// The server side of control and pixel connections, with windows for pixel traffic: it
/// accepts only peers whose certificate the cluster CA signed.
pub fn server_config(id: &NodeIdentity) -> Result<quinn::ServerConfig> {
    // A master's endpoint also takes its standby (see [`STANDBY_ALPN`]); the role is the
    // driver's to check, from the certificate.
    server_config_with(id, transport(), &[ALPN, STANDBY_ALPN])
}

/// The server side of render nodes' block connections (see [`BLOCK_WINDOW`]).
pub fn block_server_config(id: &NodeIdentity) -> Result<quinn::ServerConfig> {
    server_config_with(id, block_transport(), &[ALPN])
}

/// The client side of render nodes' block connections (see [`BLOCK_WINDOW`]).
pub fn block_client_config(id: &NodeIdentity) -> Result<quinn::ClientConfig> {
    let mut config = client_config(id)?;
    config.transport_config(block_transport());
    Ok(config)
}

fn server_config_with(
    id: &NodeIdentity,
    transport: Arc<quinn::TransportConfig>,
    alpns: &[&[u8]],
) -> Result<quinn::ServerConfig> {
    let verifier = WebPkiClientVerifier::builder_with_provider(roots(id)?, provider())
        .build()
        .map_err(|e| NetError::Tls(format!("cannot build the client certificate verifier: {e}")))?;
    let mut tls = rustls::ServerConfig::builder_with_provider(provider())
        .with_protocol_versions(&[&rustls::version::TLS13])
        .map_err(|e| NetError::Tls(e.to_string()))?
        .with_client_cert_verifier(verifier)
        .with_single_cert(vec![id.cert.clone()], id.key.clone_key())
        .map_err(NetError::KeyMismatch)?;
    tls.alpn_protocols = alpns.iter().map(|a| a.to_vec()).collect();
    let crypto = QuicServerConfig::try_from(tls).map_err(|e| NetError::Tls(e.to_string()))?;
    let mut config = quinn::ServerConfig::with_crypto(Arc::new(crypto));
    config.transport_config(transport);
    Ok(config)
}

/// The server side of the operator's console over HTTPS: `id`'s certificate, and a client
/// certificate asked for but not required (a browser has none and shows the console's token;
/// one the cluster CA signed is verified, and the console reads its role).
pub fn https_server_config(id: &NodeIdentity) -> Result<rustls::ServerConfig> {
    let verifier = WebPkiClientVerifier::builder_with_provider(roots(id)?, provider())
        .allow_unauthenticated()
        .build()
        .map_err(|e| NetError::Tls(format!("cannot build the client certificate verifier: {e}")))?;
    let mut tls = rustls::ServerConfig::builder_with_provider(provider())
        .with_safe_default_protocol_versions()
        .map_err(|e| NetError::Tls(e.to_string()))?
        .with_client_cert_verifier(verifier)
        .with_single_cert(vec![id.cert.clone()], id.key.clone_key())
        .map_err(NetError::KeyMismatch)?;
    tls.alpn_protocols = vec![b"http/1.1".to_vec()];
    Ok(tls)
}

/// An HTTPS client of the console (for scripts and tests): it trusts only the cluster CA of
/// `id`, and presents `id`'s certificate if `present`.
pub fn https_client_config(id: &NodeIdentity, present: bool) -> Result<rustls::ClientConfig> {
    let builder = rustls::ClientConfig::builder_with_provider(provider())
        .with_safe_default_protocol_versions()
        .map_err(|e| NetError::Tls(e.to_string()))?
        .with_root_certificates(roots(id)?);
    let mut tls = if present {
        builder
            .with_client_auth_cert(vec![id.cert.clone()], id.key.clone_key())
            .map_err(NetError::KeyMismatch)?
    } else {
        builder.with_no_client_auth()
    };
    tls.alpn_protocols = vec![b"http/1.1".to_vec()];
    Ok(tls)
}

/// ALPN of a standby master's connection to its primary (`serve --standby-of`): the same
/// mutual TLS as nodes, with a `master` certificate, but the primary replicates its state on
/// it instead of taking a hello.
pub const STANDBY_ALPN: &[u8] = b"tessera-standby/1";

/// Whether `conn` is a standby master's (it negotiated [`STANDBY_ALPN`]).
pub fn is_standby(conn: &quinn::Connection) -> bool {
    conn.handshake_data()
        .and_then(|d| d.downcast::<quinn::crypto::rustls::HandshakeData>().ok())
        .and_then(|d| d.protocol)
        .is_some_and(|p| p == STANDBY_ALPN)
}

/// The client side of a standby master's connection to its primary (see [`STANDBY_ALPN`]).
pub fn standby_client_config(id: &NodeIdentity) -> Result<quinn::ClientConfig> {
    client_config_alpn(id, STANDBY_ALPN)
}

/// The client side of control and pixel connections: it presents `id`'s certificate and trusts
/// only servers whose certificate the cluster CA signed.
pub fn client_config(id: &NodeIdentity) -> Result<quinn::ClientConfig> {
    client_config_alpn(id, ALPN)
}

fn client_config_alpn(id: &NodeIdentity, alpn: &[u8]) -> Result<quinn::ClientConfig> {
    let mut tls = rustls::ClientConfig::builder_with_provider(provider())
        .with_protocol_versions(&[&rustls::version::TLS13])
        .map_err(|e| NetError::Tls(e.to_string()))?
        .with_root_certificates(roots(id)?)
        .with_client_auth_cert(vec![id.cert.clone()], id.key.clone_key())
        .map_err(NetError::KeyMismatch)?;
    tls.alpn_protocols = vec![alpn.to_vec()];
    let crypto = QuicClientConfig::try_from(tls).map_err(|e| NetError::Tls(e.to_string()))?;
    let mut config = quinn::ClientConfig::new(Arc::new(crypto));
    config.transport_config(transport());
    Ok(config)
}

/// An endpoint bound to `bind` that accepts cluster peers (if `accept`) and connects to them.
pub fn endpoint(bind: SocketAddr, id: &NodeIdentity, accept: bool) -> Result<quinn::Endpoint> {
    let server = if accept {
        Some(server_config(id)?)
    } else {
        None
    };
    let socket =
        std::net::UdpSocket::bind(bind).map_err(|source| NetError::Bind { addr: bind, source })?;
    let sock = socket2::SockRef::from(&socket);
    if let Err(e) = sock
        .set_recv_buffer_size(SOCKET_BUFFER)
        .and_then(|()| sock.set_send_buffer_size(SOCKET_BUFFER))
    {
        tracing::warn!("cannot enlarge the UDP socket buffers on {bind}: {e}");
    }
    tracing::debug!(
        "UDP socket buffers on {bind}: receive {:?}, send {:?} bytes",
        sock.recv_buffer_size(),
        sock.send_buffer_size()
    );
    let runtime = quinn::default_runtime().ok_or(NetError::NoRuntime)?;
    // The peer's MTU discovery stops at the max_udp_payload_size this endpoint advertises.
    let mut config = quinn::EndpointConfig::default();
    config
        .max_udp_payload_size(MAX_UDP_PAYLOAD)
        .expect("MAX_UDP_PAYLOAD is within QUIC's bounds");
    let mut endpoint = quinn::Endpoint::new(config, server, socket, runtime)
        .map_err(|source| NetError::Bind { addr: bind, source })?;
    endpoint.set_default_client_config(client_config(id)?);
    Ok(endpoint)
}

/// Whether the peer's certificate was issued for display `display`.
pub fn peer_is_display(conn: &quinn::Connection, display: u32) -> bool {
    conn.peer_identity()
        .and_then(|id| id.downcast::<Vec<CertificateDer<'static>>>().ok())
        .and_then(|certs| {
            certs
                .first()
                .map(|c| crate::cluster::cert_is_for_display(c, display))
        })
        .unwrap_or(false)
}

/// The roles the certificate a connected peer presented names (see [`cert_roles`]); empty if
/// it presented none, which mutual TLS does not let happen.
pub fn peer_roles(conn: &quinn::Connection) -> Vec<CertRole> {
    conn.peer_identity()
        .and_then(|id| id.downcast::<Vec<CertificateDer<'static>>>().ok())
        .and_then(|certs| certs.first().map(|c| cert_roles(c)))
        .unwrap_or_default()
}

/// How long a connection attempt may take before it is given up.
pub const CONNECT_TIMEOUT: Duration = Duration::from_secs(10);

/// Connects to a cluster peer, with a bounded wait.
pub async fn connect(
    endpoint: &quinn::Endpoint,
    addr: SocketAddr,
    what: &str,
) -> Result<quinn::Connection> {
    connect_with(endpoint, None, addr, what).await
}

/// [`connect`] with a client configuration of its own (`None`: the endpoint's).
pub async fn connect_with(
    endpoint: &quinn::Endpoint,
    config: Option<quinn::ClientConfig>,
    addr: SocketAddr,
    what: &str,
) -> Result<quinn::Connection> {
    let failed = |reason: String| NetError::Connect {
        what: what.to_string(),
        addr,
        reason,
    };
    let connecting = match config {
        Some(config) => endpoint.connect_with(config, addr, CLUSTER_SERVER_NAME),
        None => endpoint.connect(addr, CLUSTER_SERVER_NAME),
    }
    .map_err(|e| failed(e.to_string()))?;
    match tokio::time::timeout(CONNECT_TIMEOUT, connecting).await {
        Ok(Ok(conn)) => Ok(conn),
        Ok(Err(e)) => Err(failed(e.to_string())),
        Err(_) => Err(failed(format!("no answer within {CONNECT_TIMEOUT:?}"))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cluster::{CertRole, ClusterCa};

    #[tokio::test]
    async fn an_expired_certificate_is_refused_naming_the_expiry() {
        let dir = tempfile::tempdir().unwrap();
        let ca = ClusterCa::open_or_create(&dir.path().join("ca")).unwrap();
        ca.issue("master", &dir.path().join("master"), Some(CertRole::Master))
            .unwrap();
        let ca = ca.valid_for(-2);
        ca.issue("old", &dir.path().join("old"), Some(CertRole::Render))
            .unwrap();
        let master = NodeIdentity::load(&dir.path().join("master")).unwrap();
        let old = NodeIdentity::load(&dir.path().join("old")).unwrap();
        let server = endpoint("127.0.0.1:0".parse().unwrap(), &master, true).unwrap();
        let client = endpoint("127.0.0.1:0".parse().unwrap(), &old, false).unwrap();
        let addr = server.local_addr().unwrap();
        let accepted = tokio::spawn(async move {
            let incoming = server.accept().await.expect("a connection attempt");
            incoming.await.map(|_| ()).map_err(|e| e.to_string())
        });
        let dialled = connect(&client, addr, "master").await;
        let seen = accepted.await.unwrap();
        let server_error = seen.expect_err("the master refuses an expired certificate");
        assert!(
            server_error.contains("certificate expired"),
            "{server_error}"
        );
        // The node may see the refusal at once or once it uses the connection; either way it
        // never gets a working link.
        if let Ok(conn) = dialled {
            let closed = tokio::time::timeout(Duration::from_secs(5), conn.closed()).await;
            assert!(closed.is_ok(), "the refused connection stays open");
        }
    }
}
