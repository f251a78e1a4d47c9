//! A node's link to its master, shared by render and display nodes: joining (connect, hello,
//! welcome or refusal), receiving the master's messages with one notion of "the master is
//! gone", and leaving (stats, finish, a bounded wait for the master to close). Joining again
//! after the master is lost is [`crate::reconnect`]'s.
//!
//! The messages' meaning stays with the nodes and their sans-IO state machines; this is the
//! plumbing every node would otherwise write again.

use crate::framed::{read_msg, spawn_reader, write_msg};
use crate::{hostname, quic, NetError};
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;
use tessera_protocol::{
    FromNode, Hello, NodeStats, RenderNodeId, Role, Session, ToNode, HEARTBEAT_DATAGRAM,
    HEARTBEAT_INTERVAL, PROTOCOL_VERSION,
};
use tokio::sync::mpsc;

/// How long a leaving node waits for the master to take its last message and close.
pub const GOODBYE_WAIT: Duration = Duration::from_secs(10);

/// The application code the master closes a node's connection with once its run is over,
/// completed or failed (`tessera_core::master::CloseReason::RunOver`): the node's part is done,
/// and it does not wait for that master to come back.
pub const RUN_OVER: u64 = 0;

/// Why a node lost, or never got, its place in the wall.
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    /// Joining failed on the network side: connecting (a lost master if
    /// [`NetError::Connect`]) or the hello and welcome.
    #[error(transparent)]
    Net(#[from] NetError),
    /// The master answered the hello with a refusal; it holds the master's reason.
    #[error("the master refused this node: {0}")]
    Refused(String),
    /// The master answered the hello with something else than a welcome, shown here.
    #[error("expected a welcome from the master, got {0}")]
    NoWelcome(String),
    /// The master finished the stream before it answered the hello.
    #[error("the master closed the connection during the handshake")]
    ClosedInHandshake,
    /// The master finished the control stream (or its reader ended) without a shutdown.
    #[error("the master ended the session without a shutdown")]
    Ended,
    /// The control stream or the connection broke once joined, or the master sent a
    /// malformed message.
    #[error("lost the master: {0}")]
    Lost(NetError),
    /// With `--reconnect`: the master was lost and not back within this wait.
    #[error("the master did not come back within {} s (--reconnect-timeout)", .0.as_secs())]
    NotBack(Duration),
    /// The master's welcome carried a term older than one this node followed: it is an old
    /// primary that a standby replaced (the text says the terms). The node told it so and
    /// tries the next master of its list.
    #[error("{0}")]
    StaleMaster(String),
}

impl LinkError {
    /// Whether the master is gone or not there (killed, crashed, its host down, not started
    /// yet), rather than refusing this node or breaking the protocol: what a node started with
    /// `--reconnect` waits out.
    pub fn is_lost_master(&self) -> bool {
        match self {
            LinkError::Lost(e) => !is_run_over(e),
            LinkError::Ended | LinkError::ClosedInHandshake | LinkError::StaleMaster(_) => true,
            LinkError::Net(e) => matches!(e, NetError::Connect { .. }),
            _ => false,
        }
    }

    /// Whether the master closed the connection because its run is over (see [`RUN_OVER`]):
    /// it failed, or ended without telling this node to shut down.
    pub fn is_run_over(&self) -> bool {
        matches!(self, LinkError::Lost(e) | LinkError::Net(e) if is_run_over(e))
    }

    /// Whether `error`, somewhere in its chain, is a run that is over (see
    /// [`LinkError::is_run_over`]).
    pub fn run_over_in(error: &(dyn std::error::Error + 'static)) -> bool {
        in_chain(error, LinkError::is_run_over)
    }

    /// Whether `error`, somewhere in its chain, is a lost master (see
    /// [`LinkError::is_lost_master`]).
    pub fn lost_master_in(error: &(dyn std::error::Error + 'static)) -> bool {
        in_chain(error, LinkError::is_lost_master)
    }
}

/// Whether some [`LinkError`] in `error`'s chain of causes is `what`.
fn in_chain(error: &(dyn std::error::Error + 'static), what: fn(&LinkError) -> bool) -> bool {
    let mut cause = Some(error);
    while let Some(e) = cause {
        if e.downcast_ref::<LinkError>().is_some_and(what) {
            return true;
        }
        cause = e.source();
    }
    false
}

fn is_run_over(e: &NetError) -> bool {
    matches!(e, NetError::ClosedByPeer { code, .. } if *code == RUN_OVER)
}

/// What the master said when it took the node in.
#[derive(Debug)]
pub struct Welcome {
    /// The node's id: render nodes have one, displays and control clients none.
    pub node: Option<RenderNodeId>,
    /// The session the node is to run: the wall, the scene and the displays' addresses.
    pub session: Session,
    /// The master's term (see `tessera_core::node::term::MasterTerm`): a node with a list of
    /// masters follows none older than one it followed.
    pub term: u64,
}

/// A master this long without a packet (its keep-alives come every 250 ms) is suspected: a
/// render node stops tracing for it until it speaks again, so a dead master's nodes stop
/// within 1.5 s of its death (this, the watch's period and the last keep-alive's age), while
/// a master stopped for seconds keeps its wall (the connection closes only after
/// [`quic::IDLE_TIMEOUT`]). Holding is harmless for a master that was only paused.
pub const MASTER_SILENCE: Duration = Duration::from_millis(1000);

/// A master silent this long is given up on by a node with a list of masters (`--master
/// A,B`) unless its `--failover-after` says otherwise: its standby takes the wall over after
/// the same silence (the default failure bound of `tessera_core::master::standby::
/// StandbyConfig`), so the node goes to find it rather than wait out [`quic::IDLE_TIMEOUT`].
pub const FAILOVER_SILENCE: Duration = tessera_protocol::FAILOVER_AFTER;

/// The application code a node closes a silent master's connection with (see
/// [`MasterLink::give_up_when_silent`]).
pub const MASTER_SILENT: u32 = 7;

/// How often the watch looks at what arrived from the master.
const WATCH_EVERY: Duration = Duration::from_millis(100);

/// The control stream to the master, once joined.
pub struct MasterLink {
    conn: quinn::Connection,
    send: quinn::SendStream,
    control: mpsc::Receiver<Result<Option<ToNode>, NetError>>,
    silent: Arc<AtomicBool>,
    /// The watch over the master's packets, and the heartbeat (render nodes and displays):
    /// tasks that hold the connection, stopped with the link so that a connection given up
    /// on is not kept open by them (quinn closes it when its last handle goes).
    tasks: Vec<tokio::task::JoinHandle<()>>,
}

impl Drop for MasterLink {
    fn drop(&mut self) {
        for task in &self.tasks {
            task.abort();
        }
    }
}

/// Tells the master on `conn` that this node is alive, every [`HEARTBEAT_INTERVAL`], as a
/// QUIC datagram, from a task of its own until the connection closes.
///
/// A datagram is sent at once whatever the control stream holds (a stream's bytes wait
/// behind its lost packets' retransmissions), and this task needs nothing of the node's
/// driver loop: it beats while the node loads a scene, builds a BVH or waits on its window.
/// It runs on the node's tokio runtime, whose workers do no heavy work (tracing and loading
/// run on rayon and blocking threads); so does quinn's own connection task, which puts the
/// datagram on the wire, so an OS thread of its own would not make a beat any surer.
fn beat(conn: quinn::Connection) -> tokio::task::JoinHandle<()> {
    tokio::spawn(async move {
        let mut every = tokio::time::interval(HEARTBEAT_INTERVAL);
        // A beat late after a stall is followed by one an interval later, not by a burst: a
        // burst says nothing one beat does not.
        every.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            every.tick().await;
            match conn.send_datagram(bytes::Bytes::from_static(HEARTBEAT_DATAGRAM)) {
                Ok(()) => {}
                Err(quinn::SendDatagramError::ConnectionLost(_)) => return,
                Err(e) => {
                    // The master takes no datagrams: it would find this node silent soon.
                    tracing::error!("cannot send heartbeats to the master: {e}");
                    return;
                }
            }
        }
    })
}

/// Watches what arrives from the master on `conn`, from a task of its own so that a node's
/// busy driver cannot delay it: `silent` is set while nothing arrived for [`MASTER_SILENCE`].
fn watch_master(conn: quinn::Connection, silent: Arc<AtomicBool>) -> tokio::task::JoinHandle<()> {
    tokio::spawn(async move {
        let mut last = conn.stats().udp_rx.datagrams;
        let mut heard = tokio::time::Instant::now();
        while conn.close_reason().is_none() {
            tokio::time::sleep(WATCH_EVERY).await;
            let now = conn.stats().udp_rx.datagrams;
            if now != last {
                (last, heard) = (now, tokio::time::Instant::now());
                if silent.swap(false, Ordering::AcqRel) {
                    tracing::info!("the master speaks again");
                }
            } else if heard.elapsed() >= MASTER_SILENCE && !silent.swap(true, Ordering::AcqRel) {
                tracing::warn!(
                    "the master has been silent for {} ms: work for it stops until it speaks (the connection closes after {} s of silence)",
                    heard.elapsed().as_millis(),
                    quic::IDLE_TIMEOUT.as_secs()
                );
            }
        }
    })
}

impl MasterLink {
    /// Connects `endpoint` to the master at `master`, says hello as `role` and waits for the
    /// welcome (each step bounded: the connection by [`quic::CONNECT_TIMEOUT`], the answer by
    /// the master's own handshake timeout, after which it closes the connection).
    ///
    /// # Errors
    /// No master there, a refusal (its reason), or anything but a welcome.
    pub async fn join(
        endpoint: &quinn::Endpoint,
        master: SocketAddr,
        role: Role,
    ) -> Result<(MasterLink, Welcome), LinkError> {
        let conn = quic::connect(endpoint, master, "the master").await?;
        let (mut send, mut recv) = conn
            .open_bi()
            .await
            .map_err(|e| LinkError::Lost(NetError::StreamBroken(e.to_string())))?;
        let beats = !matches!(role, Role::Control);
        let hello = Hello {
            version: PROTOCOL_VERSION,
            role,
            host: hostname(),
        };
        write_msg(&mut send, &FromNode::Hello(hello)).await?;
        let welcome = match read_msg::<ToNode>(&mut recv).await? {
            Some(ToNode::Welcome {
                node,
                session,
                term,
            }) => Welcome {
                node,
                session,
                term,
            },
            Some(ToNode::Refused { reason }) => return Err(LinkError::Refused(reason)),
            Some(other) => return Err(LinkError::NoWelcome(format!("{other:?}"))),
            None => return Err(LinkError::ClosedInHandshake),
        };
        let silent = Arc::new(AtomicBool::new(false));
        let mut tasks = vec![watch_master(conn.clone(), silent.clone())];
        // From the welcome on, loading included: the master times a node only once it is
        // ready, but a beat costs nothing and a node loading is then seen to be alive.
        tasks.extend(beats.then(|| beat(conn.clone())));
        let link = MasterLink {
            conn,
            send,
            control: spawn_reader::<ToNode>(recv),
            silent,
            tasks,
        };
        Ok((link, welcome))
    }

    /// Closes the connection once nothing arrived from the master for `bound`: the session
    /// then ends as with a lost master, and the node joins the next of its masters.
    pub fn give_up_when_silent(&mut self, bound: Duration) {
        let conn = self.conn.clone();
        self.tasks.push(tokio::spawn(async move {
            let mut last = conn.stats().udp_rx.datagrams;
            let mut heard = tokio::time::Instant::now();
            while conn.close_reason().is_none() {
                tokio::time::sleep(WATCH_EVERY).await;
                let now = conn.stats().udp_rx.datagrams;
                if now != last {
                    (last, heard) = (now, tokio::time::Instant::now());
                } else if heard.elapsed() >= bound {
                    tracing::warn!(
                        "the master at {} has been silent for {} ms: giving it up for the next master",
                        conn.remote_address(),
                        heard.elapsed().as_millis()
                    );
                    conn.close(MASTER_SILENT.into(), b"the master is silent");
                    return;
                }
            }
        }));
    }

    /// Tells a stale master so (the node follows a newer one) and closes its connection.
    pub async fn refuse_stale(mut self, msg: &FromNode) {
        let _ = write_msg(&mut self.send, msg).await;
        let _ = self.send.finish();
        let _ = tokio::time::timeout(Duration::from_secs(1), self.send.stopped()).await;
        self.conn.close(MASTER_SILENT.into(), b"stale master");
    }

    /// Set while the master has been silent for [`MASTER_SILENCE`] or longer (see
    /// [`MASTER_SILENCE`]); what a render node's tracing checks between packets.
    pub fn master_silent(&self) -> Arc<AtomicBool> {
        self.silent.clone()
    }

    /// Sends `msg` to the master.
    ///
    /// # Errors
    /// [`LinkError::Lost`] if the stream or connection broke.
    pub async fn send(&mut self, msg: &FromNode) -> Result<(), LinkError> {
        write_msg(&mut self.send, msg)
            .await
            .map_err(LinkError::Lost)
    }

    /// The master's next message. Cancel-safe (it reads from a channel that a task of its own
    /// fills), so driver loops can `select!` on it.
    ///
    /// # Errors
    /// [`LinkError::Ended`] if the master closed the stream without a shutdown,
    /// [`LinkError::Lost`] if the stream or connection broke or a message was malformed.
    pub async fn recv(&mut self) -> Result<ToNode, LinkError> {
        match self.control.recv().await {
            Some(Ok(Some(msg))) => Ok(msg),
            Some(Ok(None)) | None => Err(LinkError::Ended),
            Some(Err(e)) => Err(LinkError::Lost(e)),
        }
    }

    /// Tells the master this node cannot go on and waits, bounded, until the message is
    /// acknowledged, so the master logs the reason rather than a lost connection.
    pub async fn fail(mut self, message: String) {
        let _ = write_msg(&mut self.send, &FromNode::Failed { message }).await;
        let _ = self.send.finish();
        let _ = tokio::time::timeout(Duration::from_secs(2), self.send.stopped()).await;
    }

    /// Leaves now, saying so, so that the master logs a client that left rather than one
    /// that timed out; waits (at most a second) for the close to reach it.
    pub async fn leave(mut self, endpoint: &quinn::Endpoint) {
        let _ = self.send.finish();
        self.conn.close(0u32.into(), b"done");
        let _ = tokio::time::timeout(Duration::from_secs(1), endpoint.wait_idle()).await;
    }

    /// Leaves after the master's shutdown: sends this node's stats, finishes the stream and
    /// waits (at most [`GOODBYE_WAIT`]) for the master to close, which it does once it has
    /// every node's stats.
    pub async fn finish(mut self, stats: NodeStats) -> Result<(), LinkError> {
        crate::sd_notify::stopping("the master ended the wall; leaving");
        self.send(&FromNode::Stats(stats)).await?;
        let _ = self.send.finish();
        let _ = tokio::time::timeout(GOODBYE_WAIT, self.conn.closed()).await;
        Ok(())
    }
}

/// The tokio runtime a node's driver loop runs on: two workers, since the heavy work (ray
/// tracing, PNG writing) runs on rayon or blocking threads and the loop only moves messages.
pub fn node_runtime() -> std::io::Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cluster::{CertRole, ClusterCa, NodeIdentity};
    use tessera_model::scene_spec::SceneSpec;
    use tessera_model::wall::WallLayout;
    use tessera_protocol::{dsm::DataSpec, pixels::Compression, SessionSpec};

    /// A master that welcomes one render node and then only counts its heartbeat datagrams,
    /// and that node's link, whose driver never runs: it stands for a node busy loading.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_joined_node_beats_as_datagrams_while_its_driver_does_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let ca = ClusterCa::open_or_create(&dir.path().join("ca")).unwrap();
        for (name, role) in [("master", CertRole::Master), ("node", CertRole::Render)] {
            ca.issue(name, &dir.path().join(name), Some(role)).unwrap();
        }
        let load = |name: &str| NodeIdentity::load(&dir.path().join(name)).unwrap();
        let any = "127.0.0.1:0".parse().unwrap();
        let server = quic::endpoint(any, &load("master"), true).unwrap();
        let client = quic::endpoint(any, &load("node"), false).unwrap();
        let addr = server.local_addr().unwrap();
        let master = tokio::spawn(async move {
            let conn = server.accept().await.unwrap().await.unwrap();
            let (mut send, mut recv) = conn.accept_bi().await.unwrap();
            let hello = read_msg::<FromNode>(&mut recv).await.unwrap();
            assert!(matches!(hello, Some(FromNode::Hello(_))), "{hello:?}");
            let session = Session::new(SessionSpec {
                wall: WallLayout::grid(1, 1, 64, 64).unwrap(),
                scene: SceneSpec::Empty,
                scene_hash: [0; 32],
                displays: Vec::new(),
                save_frame: None,
                compression: Compression::None,
                windows: Default::default(),
                data: DataSpec::Replicated,
                particle_range: None,
            })
            .unwrap();
            let welcome = ToNode::Welcome {
                node: Some(RenderNodeId(0)),
                session,
                term: 0,
            };
            write_msg(&mut send, &welcome).await.unwrap();
            let mut beats = 0;
            while beats < 10 {
                let datagram = conn.read_datagram().await.unwrap();
                assert_eq!(&datagram[..], HEARTBEAT_DATAGRAM);
                beats += 1;
            }
            (conn, send)
        });
        let t0 = std::time::Instant::now();
        let (link, _) = MasterLink::join(&client, addr, Role::Render { cores: 1 })
            .await
            .unwrap();
        let (conn, _send) = tokio::time::timeout(Duration::from_secs(10), master)
            .await
            .expect("ten beats well within 10 s")
            .unwrap();
        // Ten beats 50 ms apart, the first at once: about 450 ms.
        assert!(t0.elapsed() >= 9 * HEARTBEAT_INTERVAL, "{:?}", t0.elapsed());
        drop(link);
        conn.close(0u32.into(), b"done");
    }
}
