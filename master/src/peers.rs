//! One task per connecting node: TLS handshake and hello, then a reader that forwards the
//! node's messages to the driver loop, a reader of its heartbeat datagrams, and a writer that
//! sends what the loop queues for it, so a slow node never blocks the loop.

use std::time::Duration;
use tessera_net::framed::{read_msg, write_msg};
use tessera_protocol::{FromNode, Hello, ToNode, HEARTBEAT_DATAGRAM};
use tokio::sync::mpsc;

pub use tessera_core::master::PeerId;

/// Messages queued for one peer's writer. Bounded: a peer that stops reading fills its queue
/// and is closed, rather than growing the master's memory (a wall sends each node a few
/// messages a frame, so a full queue is a peer that is gone or hostile, not a slow one).
pub type PeerSender = mpsc::Sender<ToNode>;

/// Messages one peer may have waiting before it counts as not reading.
pub const PEER_QUEUE: usize = 4096;

/// Events from all peers that may wait for the driver loop. Bounded: a peer that sends faster
/// than the master handles (a flood, a hostile client) is slowed down, not buffered.
pub const EVENT_QUEUE: usize = 4096;

/// What a peer's task tells the driver loop.
pub enum Event {
    /// The peer passed the TLS handshake and said hello; the master has yet to take it in.
    Joined {
        /// Its number, in the order connections came.
        peer: PeerId,
        /// What it says it is.
        hello: Hello,
        /// Its connection, from which its certificate's roles are read.
        conn: quinn::Connection,
        /// Its writer's queue.
        tx: PeerSender,
    },
    /// A message from a joined peer.
    Msg(PeerId, FromNode),
    /// A joined peer's stream or connection ended; the text says why.
    Closed(PeerId, String),
    /// A standby master connected (it negotiated the standby ALPN); its certificate is yet to
    /// be checked.
    Standby(quinn::Connection),
    /// The standby of this generation acknowledged a replica.
    StandbyAck(u64, tessera_core::master::standby::ReplicaAck),
    /// The standby of this generation is gone; the text says why.
    StandbyClosed(u64, String),
}

/// How long a connecting peer has for the TLS handshake, and then for its hello.
const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(10);

/// The task of one connecting peer: handshake and hello (a peer that fails them is logged and
/// dropped, never reported), then `Joined`, each message and `Closed` on `events`, while a
/// writer task of its own sends what the driver queues for it.
pub async fn accept_peer(incoming: quinn::Incoming, peer: PeerId, events: mpsc::Sender<Event>) {
    let remote = incoming.remote_address();
    let Some(conn) = handshake(incoming, remote).await else {
        return;
    };
    if tessera_net::quic::is_standby(&conn) {
        // No hello: the driver replicates to it (`standby_link`).
        let _ = events.send(Event::Standby(conn)).await;
        return;
    }
    let Some((send, recv, hello)) = read_hello(&conn, remote).await else {
        return;
    };
    let tx = spawn_writer(send);
    if events
        .send(Event::Joined {
            peer,
            hello,
            conn: conn.clone(),
            tx,
        })
        .await
        .is_err()
    {
        return;
    }
    let beats = tokio::spawn(read_beats(conn.clone(), peer, events.clone()));
    let closed = forward(&conn, recv, peer, &events).await;
    beats.abort();
    if let Some(reason) = closed {
        let _ = events.send(Event::Closed(peer, reason)).await;
    }
}

/// The TLS handshake of a connecting node, bounded; None (logged) if it fails.
async fn handshake(
    incoming: quinn::Incoming,
    remote: std::net::SocketAddr,
) -> Option<quinn::Connection> {
    match tokio::time::timeout(HANDSHAKE_TIMEOUT, incoming).await {
        Ok(Ok(conn)) => Some(conn),
        Ok(Err(e)) => {
            let text = e.to_string();
            let hint = if text.contains("expired") {
                "issue the node a new certificate with `tessera-master issue-cert`"
            } else {
                "is its certificate from this cluster's CA?"
            };
            tracing::warn!("refused a connection from {remote}: {text} ({hint})");
            None
        }
        Err(_) => {
            tracing::warn!("refused a connection from {remote}: TLS handshake timed out");
            None
        }
    }
}

/// The node's control stream and its hello, bounded; None (logged, connection closed) if it
/// sends anything else or nothing in time.
async fn read_hello(
    conn: &quinn::Connection,
    remote: std::net::SocketAddr,
) -> Option<(quinn::SendStream, quinn::RecvStream, Hello)> {
    let opened = tokio::time::timeout(HANDSHAKE_TIMEOUT, async {
        let (send, mut recv) = conn.accept_bi().await?;
        let hello = read_msg::<FromNode>(&mut recv).await?;
        anyhow::Ok((send, recv, hello))
    })
    .await;
    match opened {
        Ok(Ok((s, r, Some(FromNode::Hello(hello))))) => Some((s, r, hello)),
        Ok(Ok((_, _, other))) => {
            tracing::warn!("closing {remote}: expected a hello, got {other:?}");
            conn.close(1u32.into(), b"expected hello");
            None
        }
        Ok(Err(e)) => {
            tracing::warn!("closing {remote}: {e:#}");
            conn.close(1u32.into(), b"bad handshake");
            None
        }
        Err(_) => {
            tracing::warn!("closing {remote}: no hello within {HANDSHAKE_TIMEOUT:?}");
            conn.close(1u32.into(), b"handshake timeout");
            None
        }
    }
}

/// The peer's writer: a task that sends what is queued on the returned sender, and finishes
/// the stream after a refusal or when the queue closes.
fn spawn_writer(mut send: quinn::SendStream) -> PeerSender {
    let (tx, mut rx) = mpsc::channel::<ToNode>(PEER_QUEUE);
    tokio::spawn(async move {
        while let Some(msg) = rx.recv().await {
            let refused = matches!(msg, ToNode::Refused { .. });
            if write_msg(&mut send, &msg).await.is_err() || refused {
                break;
            }
        }
        let _ = send.finish();
    });
    tx
}

/// Forwards the peer's heartbeat datagrams to the driver loop as [`FromNode::Heartbeat`]
/// until its connection closes. Apart from its control stream: a beat never waits for a
/// stream's retransmissions, nor for the messages before it to be read.
async fn read_beats(conn: quinn::Connection, peer: PeerId, events: mpsc::Sender<Event>) {
    while let Ok(datagram) = conn.read_datagram().await {
        if datagram[..] != *HEARTBEAT_DATAGRAM {
            // Nothing else travels as a datagram; one that is not a beat changes nothing.
            tracing::debug!("peer {}: ignored a datagram that is no heartbeat", peer.0);
            continue;
        }
        if events
            .send(Event::Msg(peer, FromNode::Heartbeat))
            .await
            .is_err()
        {
            return;
        }
    }
}

/// Forwards the peer's messages to the driver loop until the peer goes: why it went, or None
/// if the driver loop is gone.
async fn forward(
    conn: &quinn::Connection,
    mut recv: quinn::RecvStream,
    peer: PeerId,
    events: &mpsc::Sender<Event>,
) -> Option<String> {
    loop {
        match read_msg::<FromNode>(&mut recv).await {
            Ok(Some(FromNode::Heartbeat)) => {
                // Heartbeats come as datagrams only: one on the stream is from an older
                // protocol, or forged to keep a node alive that has stopped beating.
                conn.close(2u32.into(), b"heartbeat on the control stream");
                return Some("sent a heartbeat on its control stream".to_string());
            }
            Ok(Some(msg)) => {
                // Waits while the driver is behind: the peer's stream stops being read, and
                // QUIC's flow control holds the peer back instead of the master's memory.
                events.send(Event::Msg(peer, msg)).await.ok()?;
            }
            Ok(None) => return Some("closed its control stream".to_string()),
            Err(e) => {
                return Some(match conn.close_reason() {
                    Some(reason) => reason.to_string(),
                    None => {
                        // A malformed or oversized message: this peer is not to be trusted.
                        conn.close(2u32.into(), b"malformed message");
                        format!("{e:#}")
                    }
                });
            }
        }
    }
}
