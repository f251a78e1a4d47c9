//! QUIC endpoints with mutual TLS against the cluster CA (ring provider, TLS 1.3 only).

use super::cluster::{NodeIdentity, CLUSTER_SERVER_NAME};
use crate::protocol::ALPN;
use anyhow::{Context, Result};
use quinn::crypto::rustls::{QuicClientConfig, QuicServerConfig};
use rustls::server::WebPkiClientVerifier;
use rustls::RootCertStore;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

fn provider() -> Arc<rustls::crypto::CryptoProvider> {
    Arc::new(rustls::crypto::ring::default_provider())
}

fn roots(id: &NodeIdentity) -> Result<Arc<RootCertStore>> {
    let mut roots = RootCertStore::empty();
    roots
        .add(id.ca.clone())
        .context("cluster CA certificate is not usable")?;
    Ok(Arc::new(roots))
}

/// Window sizes sized for pixel traffic: a 4K screen's frame is 25 MB, and a window much smaller
/// than bandwidth × RTT caps throughput.
fn transport() -> Arc<quinn::TransportConfig> {
    let mut t = quinn::TransportConfig::default();
    t.max_concurrent_uni_streams(4096u32.into())
        .stream_receive_window((32u32 << 20).into())
        .receive_window((256u32 << 20).into())
        .send_window(256 << 20)
        .keep_alive_interval(Some(Duration::from_secs(1)))
        .max_idle_timeout(Some(Duration::from_secs(10).try_into().expect("10 s fits")));
    Arc::new(t)
}

pub fn server_config(id: &NodeIdentity) -> Result<quinn::ServerConfig> {
    let verifier = WebPkiClientVerifier::builder_with_provider(roots(id)?, provider())
        .build()
        .context("cannot build the client certificate verifier")?;
    let mut tls = rustls::ServerConfig::builder_with_provider(provider())
        .with_protocol_versions(&[&rustls::version::TLS13])?
        .with_client_cert_verifier(verifier)
        .with_single_cert(vec![id.cert.clone()], id.key.clone_key())
        .context("node certificate and key do not match")?;
    tls.alpn_protocols = vec![ALPN.to_vec()];
    let mut config = quinn::ServerConfig::with_crypto(Arc::new(QuicServerConfig::try_from(tls)?));
    config.transport_config(transport());
    Ok(config)
}

pub fn client_config(id: &NodeIdentity) -> Result<quinn::ClientConfig> {
    let mut tls = rustls::ClientConfig::builder_with_provider(provider())
        .with_protocol_versions(&[&rustls::version::TLS13])?
        .with_root_certificates(roots(id)?)
        .with_client_auth_cert(vec![id.cert.clone()], id.key.clone_key())
        .context("node certificate and key do not match")?;
    tls.alpn_protocols = vec![ALPN.to_vec()];
    let mut config = quinn::ClientConfig::new(Arc::new(QuicClientConfig::try_from(tls)?));
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
    let mut endpoint = match server {
        Some(server) => quinn::Endpoint::server(server, bind),
        None => quinn::Endpoint::client(bind),
    }
    .with_context(|| format!("cannot bind a UDP socket on {bind}"))?;
    endpoint.set_default_client_config(client_config(id)?);
    Ok(endpoint)
}

/// Connects to a cluster peer, with a bounded wait.
pub async fn connect(
    endpoint: &quinn::Endpoint,
    addr: SocketAddr,
    what: &str,
) -> Result<quinn::Connection> {
    let connecting = endpoint
        .connect(addr, CLUSTER_SERVER_NAME)
        .with_context(|| format!("cannot connect to {what} at {addr}"))?;
    match tokio::time::timeout(Duration::from_secs(10), connecting).await {
        Ok(Ok(conn)) => Ok(conn),
        Ok(Err(e)) => Err(e).with_context(|| format!("cannot connect to {what} at {addr}")),
        Err(_) => anyhow::bail!("timed out connecting to {what} at {addr}"),
    }
}
