//! The raw transport limit: a plain bulk transfer over the same kind of links a wall uses (our
//! QUIC endpoints, mutual TLS, on this machine's loopback), one link per display, all at once.

use anyhow::{Context, Result};
use std::net::SocketAddr;
use std::path::Path;
use std::time::{Duration, Instant};
use tessera_net::cluster::{ClusterCa, NodeIdentity};
use tessera_net::quic;

/// What a bulk transfer achieved.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct Throughput {
    pub links: u32,
    pub seconds: f64,
    /// Payload bytes delivered per second, all links together.
    pub payload_bytes_per_s: f64,
    /// UDP bytes received per second (what a display's wire-byte counter counts).
    pub wire_bytes_per_s: f64,
}

/// One end of a link: its endpoint and the connection to the other end.
type End = (quinn::Endpoint, quinn::Connection);

/// Sends as fast as possible over `links` connections for about `seconds`, in streams of
/// `stream_bytes` (as render nodes send batches), and measures what arrives.
pub async fn bulk_throughput(links: u32, seconds: f64, stream_bytes: usize) -> Result<Throughput> {
    let certs = tempfile::Builder::new().prefix("tessera-bulk-").tempdir()?;
    let (receivers, senders) = connect_links(links, certs.path()).await?;
    let deadline = Instant::now() + Duration::from_secs_f64(seconds);
    let started = Instant::now();
    let tasks: Vec<_> = receivers
        .iter()
        .map(|(_, conn)| tokio::spawn(receive_all(conn.clone())))
        .collect();
    let payload = vec![0x5au8; stream_bytes];
    let mut sends = Vec::new();
    for (_, conn) in &senders {
        let (conn, payload) = (conn.clone(), payload.clone());
        sends.push(tokio::spawn(send_until(conn, payload, deadline)));
    }
    for s in sends {
        s.await??;
    }
    let elapsed = started.elapsed().as_secs_f64();
    let wire: u64 = receivers.iter().map(|(_, c)| c.stats().udp_rx.bytes).sum();
    for (_, conn) in &senders {
        conn.close(0u32.into(), b"done");
    }
    let mut payload_total = 0u64;
    for t in tasks {
        payload_total += t.await??;
    }
    for (endpoint, _) in receivers.iter().chain(&senders) {
        endpoint.close(0u32.into(), b"done");
    }
    Ok(Throughput {
        links,
        seconds: elapsed,
        payload_bytes_per_s: payload_total as f64 / elapsed,
        wire_bytes_per_s: wire as f64 / elapsed,
    })
}

/// `links` connected pairs of endpoints on the loopback, certificates from a new CA under
/// `certs`: the receiving ends, then the sending ends.
async fn connect_links(links: u32, certs: &Path) -> Result<(Vec<End>, Vec<End>)> {
    let ca = ClusterCa::open_or_create(&certs.join("ca"))?;
    let identity = |name: &str| -> Result<NodeIdentity> {
        let dir = certs.join(name);
        ca.issue(name, &dir, None)?;
        Ok(NodeIdentity::load(&dir)?)
    };
    let loopback: SocketAddr = "127.0.0.1:0".parse()?;
    let mut receivers = Vec::new();
    let mut senders = Vec::new();
    for link in 0..links {
        let rx = quic::endpoint(loopback, &identity(&format!("rx-{link}"))?, true)?;
        let tx = quic::endpoint(loopback, &identity(&format!("tx-{link}"))?, false)?;
        let addr = rx.local_addr()?;
        let accept = tokio::spawn({
            let rx = rx.clone();
            async move {
                rx.accept()
                    .await
                    .context("no connection")?
                    .await
                    .context("handshake")
            }
        });
        let out = quic::connect(&tx, addr, "the bulk receiver").await?;
        let inbound = accept.await??;
        receivers.push((rx, inbound));
        senders.push((tx, out));
    }
    Ok((receivers, senders))
}

/// Reads every stream `conn` is sent until it closes; the payload bytes read.
async fn receive_all(conn: quinn::Connection) -> Result<u64> {
    let mut total = 0u64;
    while let Ok(mut stream) = conn.accept_uni().await {
        match stream.read_to_end(usize::MAX).await {
            Ok(bytes) => total += bytes.len() as u64,
            Err(_) => break,
        }
    }
    Ok(total)
}

/// Sends `payload` a stream at a time over `conn` until `deadline`.
async fn send_until(conn: quinn::Connection, payload: Vec<u8>, deadline: Instant) -> Result<()> {
    while Instant::now() < deadline {
        let mut stream = conn.open_uni().await?;
        stream.write_all(&payload).await?;
        stream.finish()?;
        // Wait until the receiver has it all, as a render node does before it reports.
        stream.stopped().await.ok();
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn a_short_bulk_transfer_moves_bytes() {
        let t = bulk_throughput(2, 0.2, 64 * 1024).await.unwrap();
        assert!(t.payload_bytes_per_s > 0.0 && t.wire_bytes_per_s >= t.payload_bytes_per_s);
    }
}
