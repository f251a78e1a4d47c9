//! The wire between a primary master and its standby (`serve --standby-of`): a QUIC
//! connection with the cluster's mutual TLS and the standby ALPN
//! ([`tessera_net::quic::STANDBY_ALPN`]), a `master` certificate on both ends. The primary
//! opens one bidirectional stream and sends [`ToStandby`] messages on it (replicas and
//! heartbeats); the standby answers each replica with a [`ReplicaAck`]. Each message is a
//! 4-byte big-endian length and its postcard bytes (`tessera_core::master::standby`).
//!
//! The decisions are the sans-IO [`Standby`]'s and [`tessera_core::master::Master`]'s; this
//! moves their bytes and reads the clock.

use crate::peers::Event;
use anyhow::{bail, Context, Result};
use std::net::SocketAddr;
use std::time::{Duration, Instant};
use tessera_core::master::standby::{
    decode, encode, MasterSnapshot, ReplicaAck, Standby, StandbyConfig, StandbyEvent, ToStandby,
    MAX_REPLICA_BYTES,
};
use tessera_net::cluster::NodeIdentity;
use tokio::sync::mpsc;

/// The application code a primary closes its standby's connection with once its run is over:
/// the standby leaves without taking over. Any other end (a crash, a SIGKILL, a silence past
/// the failure bound) is a primary gone, which the standby replaces.
pub const RUN_OVER: u32 = 0;

/// The code a primary closes its standby's connection with when the standby acknowledged
/// nothing for a while (`server::STANDBY_ACK_BOUND`, 2 s): the primary goes on without it, and the
/// standby, if it hears this, leaves rather than take over a wall whose primary is alive.
pub const DROPPED: u32 = 2;

/// The code a standby closes its connection to the primary with when it takes over.
const TAKING_OVER: u32 = 9;

/// Writes one message: its length, then its bytes.
async fn write_frame<T: serde::Serialize>(send: &mut quinn::SendStream, msg: &T) -> Result<()> {
    let bytes = encode(msg)?;
    let len = u32::try_from(bytes.len()).context("a replica message over 4 GiB")?;
    send.write_all(&len.to_be_bytes()).await?;
    send.write_all(&bytes).await?;
    Ok(())
}

/// Reads one message; `None` when the stream ended cleanly between messages.
async fn read_frame<T: for<'de> serde::Deserialize<'de>>(
    recv: &mut quinn::RecvStream,
) -> Result<Option<T>> {
    let mut prefix = [0u8; 4];
    match recv.read_exact(&mut prefix).await {
        Ok(()) => {}
        Err(quinn::ReadExactError::FinishedEarly(0)) => return Ok(None),
        Err(e) => return Err(e.into()),
    }
    let len = u32::from_be_bytes(prefix) as usize;
    if len > MAX_REPLICA_BYTES {
        bail!("a replica message of {len} bytes is over the {MAX_REPLICA_BYTES}-byte limit");
    }
    let mut body = vec![0u8; len];
    recv.read_exact(&mut body)
        .await
        .context("a replica message cut short")?;
    Ok(Some(decode(&body)?))
}

/// The primary's side of an attached standby: its connection and its writer's queue.
pub struct StandbyPeer {
    /// Which standby this is (a later one replaces it); its events carry it.
    pub generation: u64,
    /// The standby's connection.
    pub conn: quinn::Connection,
    /// What the writer task sends, in order.
    pub tx: mpsc::UnboundedSender<ToStandby>,
}

/// Serves the standby on `conn` for the primary: opens the stream, writes what is queued on
/// the returned peer's `tx` (the first replica is `first`), and reports each ack and the end
/// of the connection on `events`.
pub fn serve_standby(
    conn: quinn::Connection,
    generation: u64,
    first: ToStandby,
    events: mpsc::Sender<Event>,
) -> StandbyPeer {
    let (tx, mut rx) = mpsc::unbounded_channel::<ToStandby>();
    let _ = tx.send(first);
    let peer = StandbyPeer {
        generation,
        conn: conn.clone(),
        tx,
    };
    tokio::spawn(async move {
        let why = async {
            let (mut send, mut recv) = conn.open_bi().await?;
            let acks = {
                let events = events.clone();
                tokio::spawn(async move {
                    while let Ok(Some(ack)) = read_frame::<ReplicaAck>(&mut recv).await {
                        if events
                            .send(Event::StandbyAck(generation, ack))
                            .await
                            .is_err()
                        {
                            return;
                        }
                    }
                })
            };
            while let Some(msg) = rx.recv().await {
                if let Err(e) = write_frame(&mut send, &msg).await {
                    acks.abort();
                    return Err(e);
                }
            }
            acks.abort();
            anyhow::Ok(())
        }
        .await;
        let reason = match (why, conn.close_reason()) {
            (_, Some(reason)) => reason.to_string(),
            (Err(e), None) => format!("{e:#}"),
            (Ok(()), None) => "the primary let it go".to_string(),
        };
        let _ = events.send(Event::StandbyClosed(generation, reason)).await;
    });
    peer
}

/// How following a primary ended.
pub enum Followed {
    /// The primary is gone: take over from this snapshot. `last_heard` is when the primary
    /// last spoke, from which the wall's dark time is measured.
    TakeOver {
        /// What the primary last replicated.
        snapshot: Box<MasterSnapshot>,
        /// When the primary last spoke.
        last_heard: Instant,
    },
    /// The primary ended its run: nothing to take over.
    RunOver,
}

/// Connects to the primary at `primary` as its standby and follows it (see the module docs)
/// until it is gone or its run is over.
///
/// # Errors
/// The primary cannot be reached or does not take the standby, or it is gone before it sent
/// a snapshot.
pub async fn follow(
    endpoint: &quinn::Endpoint,
    identity: &NodeIdentity,
    primary: SocketAddr,
    cfg: StandbyConfig,
) -> Result<Followed> {
    let config = tessera_net::quic::standby_client_config(identity)?;
    let conn = tessera_net::quic::connect_with(endpoint, Some(config), primary, "the primary")
        .await
        .context("the standby cannot reach its primary (--standby-of)")?;
    let opened = tokio::time::timeout(Duration::from_secs(10), conn.accept_bi())
        .await
        .context("the primary opened no replication stream within 10 s")?;
    let (mut send, recv) = match opened {
        Ok(stream) => stream,
        Err(_) if primary_run_over(&conn) => return Ok(Followed::RunOver),
        Err(e) => bail!("the primary closed the connection ({e}): is this a master certificate?"),
    };
    tracing::info!("standby of the primary at {primary}: following its run");
    let mut messages = spawn_reader(recv);
    let mut standby = Standby::new(cfg, Instant::now());
    let mut last_heard = Instant::now();
    loop {
        let timer = standby.poll_timeout().unwrap_or_else(Instant::now);
        tokio::select! {
            msg = messages.recv() => {
                let now = Instant::now();
                match msg {
                    Some(Ok(ToStandby::Replica(replica))) => {
                        last_heard = now;
                        standby.handle_replica(*replica, now)?;
                    }
                    Some(Ok(ToStandby::Heartbeat)) => {
                        last_heard = now;
                        standby.handle_heartbeat(now);
                    }
                    Some(Err(_)) | None => {
                        if primary_run_over(&conn) {
                            return Ok(Followed::RunOver);
                        }
                        if closed_with(&conn, DROPPED) {
                            bail!("the primary dropped this standby: it acknowledged nothing for 2 s (an overloaded standby host, or a slow link?)");
                        }
                        tracing::warn!("the primary's connection closed: {:?}", conn.close_reason());
                        standby.handle_primary_closed(now);
                    }
                }
            }
            () = tokio::time::sleep_until(timer.into()) => standby.handle_timeout(Instant::now()),
        }
        while let Some(ack) = standby.poll_ack() {
            // A primary that stopped reading is judged by its silence, not by this write.
            let _ = tokio::time::timeout(cfg.failure_bound, write_frame(&mut send, &ack)).await;
        }
        if let Some(StandbyEvent::TakeOver(snapshot)) = standby.poll_event() {
            conn.close(TAKING_OVER.into(), b"the standby takes the wall over");
            return Ok(Followed::TakeOver {
                snapshot,
                last_heard,
            });
        }
        if standby.is_done() {
            bail!("the primary at {primary} is gone before it sent a snapshot");
        }
    }
}

/// Whether the primary closed the connection because its run is over (see [`RUN_OVER`]).
fn primary_run_over(conn: &quinn::Connection) -> bool {
    closed_with(conn, RUN_OVER)
}

/// Whether the peer closed `conn` with the application code `code`.
fn closed_with(conn: &quinn::Connection, code: u32) -> bool {
    matches!(
        conn.close_reason(),
        Some(quinn::ConnectionError::ApplicationClosed(c)) if c.error_code == code.into()
    )
}

/// Reads the primary's messages in a task of its own (a half-read message must never be lost
/// to the other branch of a `select!`).
fn spawn_reader(mut recv: quinn::RecvStream) -> mpsc::Receiver<Result<ToStandby>> {
    let (tx, rx) = mpsc::channel(64);
    tokio::spawn(async move {
        loop {
            let msg = match read_frame::<ToStandby>(&mut recv).await {
                Ok(Some(msg)) => Ok(msg),
                Ok(None) => return,
                Err(e) => Err(e),
            };
            let last = msg.is_err();
            if tx.send(msg).await.is_err() || last {
                return;
            }
        }
    });
    rx
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_net::cluster::{CertRole, ClusterCa};

    /// A primary side that sends a heartbeat and then closes with [`RUN_OVER`]: the standby
    /// leaves without taking over; one that closes with another code is gone, here before it
    /// sent a snapshot, which the standby says.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_standby_leaves_a_run_that_is_over_and_names_a_primary_gone_without_a_snapshot() {
        let dir = tempfile::tempdir().unwrap();
        let ca = ClusterCa::open_or_create(&dir.path().join("ca")).unwrap();
        ca.issue("master", &dir.path().join("master"), Some(CertRole::Master))
            .unwrap();
        let id = NodeIdentity::load(&dir.path().join("master")).unwrap();
        let any = "127.0.0.1:0".parse().unwrap();
        let primary = tessera_net::quic::endpoint(any, &id, true).unwrap();
        let standby = tessera_net::quic::endpoint(any, &id, false).unwrap();
        let addr = primary.local_addr().unwrap();
        let cfg = StandbyConfig::default();
        for code in [RUN_OVER, 5] {
            let server = primary.clone();
            let side = tokio::spawn(async move {
                let conn = server.accept().await.unwrap().await.unwrap();
                assert!(tessera_net::quic::is_standby(&conn));
                let (mut send, _recv) = conn.open_bi().await.unwrap();
                write_frame(&mut send, &ToStandby::Heartbeat).await.unwrap();
                conn.close(code.into(), b"bye");
            });
            let followed = follow(&standby, &id, addr, cfg).await;
            side.await.unwrap();
            match (code, followed) {
                (RUN_OVER, Ok(Followed::RunOver)) => {}
                // Gone before or after its stream reached the standby, never taken over.
                (5, Err(e)) => {
                    let e = e.to_string();
                    assert!(e.contains("before it sent") || e.contains("closed"), "{e}");
                }
                (code, Ok(_)) => panic!("code {code}: an unexpected way to end"),
                (code, Err(e)) => panic!("code {code}: {e:#}"),
            }
        }
    }
}
