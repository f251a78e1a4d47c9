//! One master's sessions after another: the loop that render and display nodes share.
//!
//! A node joins its master and runs a session until the master shuts the wall down. Started
//! with `--reconnect` (the flags are `tessera-cli`'s), a node whose master is lost (killed,
//! crashed, its host down) waits, bounded, for a master at the same address, joins it again
//! and runs the next session, as often as the master is lost. A refusal, a broken protocol or
//! a failure of the node's own ends the node whatever the flags say: waiting would not mend
//! them. A master that closes the connection because its run is over (it failed, or ended
//! without a shutdown) ends the node as a shutdown does: its part is done.
//!
//! A node given a list of masters (`--master A,B`: a primary and its standby) joins the first
//! that answers, gives a master silent for [`FAILOVER_SILENCE`] up, and rejoins the next of the
//! list, round it: the standby that took the wall over. Which master's term it follows is the
//! node's (`tessera_core::node::term::MasterTerm`, from [`Welcome::term`]).

use crate::link::{LinkError, MasterLink, Welcome, FAILOVER_SILENCE};
use crate::NetError;
use std::error::Error;
use std::fmt::Display;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Duration;
use tessera_protocol::Role;

/// How often a node that waits for its master to come back knocks again.
pub const REJOIN_INTERVAL: Duration = Duration::from_millis(250);

/// How long a node with a list of masters started without `--reconnect` waits for one of
/// them when it lost its master (`--reconnect-timeout`'s default).
pub const FAILOVER_WAIT: Duration = Duration::from_secs(60);

/// Where a node's masters are, as whom the node joins them, and whether it waits for one
/// when lost.
#[derive(Clone, Debug)]
pub struct Reconnect {
    /// The node's endpoint: every session's link to a master goes through it.
    pub endpoint: quinn::Endpoint,
    /// The masters' addresses (`--master A,B`), never empty: the node joins the first that
    /// answers, and after losing one tries the next, round the list (a primary and its
    /// standbys, see `tessera_core::master::standby`).
    pub masters: Vec<SocketAddr>,
    /// What the node says it is in its hello.
    pub role: Role,
    /// With `--reconnect`: how long to wait for a lost master each time, before giving up.
    pub wait: Option<Duration>,
    /// The node as its log lines name it (`render node`, `display 2`).
    pub name: String,
    /// With more than one master: a master silent this long is given up on for the next
    /// (`--failover-after`; [`FAILOVER_SILENCE`] unless set). Its standby's `serve
    /// --failover-after` should be the same, so that the node leaves when the standby acts.
    pub failover_after: Duration,
    /// The index in `masters` of the master joined last.
    current: Arc<AtomicUsize>,
}

impl Reconnect {
    /// A node that joins `masters` (see the fields).
    ///
    /// # Panics
    /// `masters` is empty.
    pub fn new(
        endpoint: quinn::Endpoint,
        masters: Vec<SocketAddr>,
        role: Role,
        wait: Option<Duration>,
        name: String,
    ) -> Reconnect {
        assert!(!masters.is_empty(), "a node needs a master's address");
        Reconnect {
            endpoint,
            masters,
            role,
            wait,
            name,
            failover_after: FAILOVER_SILENCE,
            current: Arc::new(AtomicUsize::new(0)),
        }
    }

    /// The address of the master joined last (the first before any join).
    pub fn master(&self) -> SocketAddr {
        self.masters[self.current.load(Ordering::Relaxed) % self.masters.len()]
    }

    /// Joins the master at index `at` of the list (see [`MasterLink::join`]).
    async fn join_at(&self, at: usize) -> Result<(MasterLink, Welcome), LinkError> {
        let at = at % self.masters.len();
        let joined = MasterLink::join(&self.endpoint, self.masters[at], self.role.clone()).await;
        if joined.is_ok() {
            self.current.store(at, Ordering::Relaxed);
        }
        joined
    }

    /// Joins a master the first time: the first of the list that is there (see
    /// [`MasterLink::join`]).
    ///
    /// # Errors
    /// No master there (the last one's error), a refusal (its reason), or anything but a
    /// welcome.
    pub async fn join(&self) -> Result<(MasterLink, Welcome), LinkError> {
        let mut at = 0;
        loop {
            match self.join_at(at).await {
                Err(e) if e.is_lost_master() && at + 1 < self.masters.len() => {
                    tracing::warn!("{}: {e}; trying the next master", self.name);
                    at += 1;
                }
                joined => return joined,
            }
        }
    }

    /// Joins a master that may not be up yet (one restarting after a crash, or a standby
    /// taking the wall over): tries the masters after the one lost, round the list, one every
    /// [`REJOIN_INTERVAL`] while none is there, for at most `within`.
    ///
    /// # Errors
    /// [`LinkError::NotBack`] once `within` has passed; a refusal or a broken handshake at
    /// once.
    pub async fn rejoin(&self, within: Duration) -> Result<(MasterLink, Welcome), LinkError> {
        let give_up = tokio::time::Instant::now() + within;
        let lost = self.current.load(Ordering::Relaxed);
        // A `Type=notify` unit stays active meanwhile; its status says why frames stopped.
        crate::sd_notify::status(&format!(
            "waiting up to {} s for a master of {:?} to come back",
            within.as_secs(),
            self.masters
        ));
        let attempts = async {
            for attempt in 1.. {
                match self.join_at(lost + attempt).await {
                    Err(e) if e.is_lost_master() => {
                        tracing::debug!("no master back yet: {e}");
                        tokio::time::sleep(REJOIN_INTERVAL).await;
                    }
                    joined => return joined,
                }
            }
            unreachable!("attempts are counted in usize")
        };
        tokio::time::timeout_at(give_up, attempts)
            .await
            .unwrap_or(Err(LinkError::NotBack(within)))
    }

    /// Runs `session` on the link `first` joined, and, while the master is lost and the node
    /// waits for it, on each link [`Reconnect::rejoin`] makes, until a session ends well.
    /// With more than one master, a master silent for [`Reconnect::failover_after`] is given
    /// up on (see [`MasterLink::give_up_when_silent`]), and a lost master is waited for (up to
    /// [`FAILOVER_WAIT`] without `--reconnect`).
    ///
    /// # Errors
    /// The first session error that is not a lost master (anywhere in its chain), or a lost
    /// master without `--reconnect`; a master that did not come back in time
    /// ([`LinkError::NotBack`]) or refused the node on its return.
    pub async fn run<E>(
        &self,
        first: (MasterLink, Welcome),
        mut session: impl AsyncFnMut(MasterLink, Welcome) -> Result<(), E>,
    ) -> Result<(), E>
    where
        E: From<LinkError> + AsRef<dyn Error + Send + Sync + 'static> + Display,
    {
        let failover = self.masters.len() > 1;
        // A list of masters is there to be failed over to, `--reconnect` or not.
        let wait = self.wait.or(failover.then_some(FAILOVER_WAIT));
        sessions(
            &self.name,
            wait,
            first,
            async |(mut link, welcome): (MasterLink, Welcome)| {
                if failover {
                    link.give_up_when_silent(self.failover_after);
                }
                session(link, welcome).await
            },
            async |within| self.rejoin(within).await,
        )
        .await
    }
}

/// Reads a node's `--master` value: one address, or a comma-separated list of them (a primary
/// and its standbys), each HOST:PORT, resolved in order.
///
/// # Errors
/// An empty list or entry, or an address that does not resolve (it is named).
pub async fn resolve_masters(list: &str) -> Result<Vec<SocketAddr>, NetError> {
    let mut masters = Vec::new();
    for entry in list.split(',').map(str::trim) {
        if entry.is_empty() {
            return Err(NetError::Resolve {
                addr: list.to_string(),
                reason: "an empty entry in the list of masters".into(),
            });
        }
        masters.push(crate::resolve(entry).await?);
    }
    Ok(masters)
}

/// What to do once a session has ended.
#[derive(Debug)]
enum Next<E> {
    /// The master shut the wall down: the node is done.
    Done,
    /// The master ended its run (see [`LinkError::is_run_over`]): the node is done too.
    Over(E),
    /// The master is lost and the node waits for it this long.
    Rejoin(E, Duration),
    /// The node ends with this error.
    Fail(E),
}

fn next<E>(outcome: Result<(), E>, wait: Option<Duration>) -> Next<E>
where
    E: AsRef<dyn Error + Send + Sync + 'static>,
{
    match (outcome, wait) {
        (Ok(()), _) => Next::Done,
        (Err(e), _) if LinkError::run_over_in(e.as_ref()) => Next::Over(e),
        (Err(e), Some(within)) if LinkError::lost_master_in(e.as_ref()) => Next::Rejoin(e, within),
        (Err(e), _) => Next::Fail(e),
    }
}

/// The loop of [`Reconnect::run`], over any kind of link, so that its decisions are tested
/// without a master.
async fn sessions<J, E>(
    name: &str,
    wait: Option<Duration>,
    first: J,
    mut session: impl AsyncFnMut(J) -> Result<(), E>,
    mut rejoin: impl AsyncFnMut(Duration) -> Result<J, LinkError>,
) -> Result<(), E>
where
    E: From<LinkError> + AsRef<dyn Error + Send + Sync + 'static> + Display,
{
    let mut joined = first;
    loop {
        let within = match next(session(joined).await, wait) {
            Next::Done => return Ok(()),
            Next::Over(e) => {
                tracing::info!("{name}: {e:#}; the master's run is over, leaving");
                return Ok(());
            }
            Next::Fail(e) => return Err(e),
            Next::Rejoin(e, within) => {
                tracing::warn!(
                    "{name}: {e:#}; waiting up to {} s for it to come back (--reconnect)",
                    within.as_secs()
                );
                within
            }
        };
        joined = rejoin(within).await?;
        tracing::info!("{name}: the master is back; rejoined");
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cluster::{CertRole, ClusterCa, NodeIdentity};

    type BoxError = Box<dyn Error + Send + Sync>;

    fn lost() -> BoxError {
        LinkError::Ended.into()
    }

    /// A lost master that the node's own error wraps, as `anyhow`'s context does.
    #[derive(Debug, thiserror::Error)]
    #[error("the session ended")]
    struct Wrapped(#[source] LinkError);

    #[test]
    fn only_a_lost_master_is_waited_for_and_only_with_reconnect() {
        let wait = Some(Duration::from_secs(3));
        assert!(matches!(next::<BoxError>(Ok(()), wait), Next::Done));
        assert!(
            matches!(next(Err(lost()), wait), Next::Rejoin(_, d) if d == Duration::from_secs(3))
        );
        assert!(matches!(next(Err(lost()), None), Next::Fail(_)));
        let wrapped: BoxError =
            Wrapped(LinkError::Lost(NetError::StreamClosed("reset".into()))).into();
        assert!(matches!(next(Err(wrapped), wait), Next::Rejoin(..)));
        let refused: BoxError = LinkError::Refused("full".into()).into();
        assert!(matches!(next(Err(refused), wait), Next::Fail(_)));
        let own: BoxError = "cannot load the volume's time step".into();
        assert!(matches!(next(Err(own), wait), Next::Fail(_)));
    }

    #[test]
    fn a_node_dropped_by_its_master_rejoins_and_one_whose_run_is_over_leaves() {
        let closed = |code| {
            let reason = "why".to_string();
            let e: BoxError =
                Wrapped(LinkError::Lost(NetError::ClosedByPeer { code, reason })).into();
            e
        };
        let wait = Some(Duration::from_secs(3));
        // Code 5: silent past the deadline, as a paused node is.
        assert!(matches!(next(Err(closed(5)), wait), Next::Rejoin(..)));
        assert!(matches!(next(Err(closed(5)), None), Next::Fail(_)));
        for wait in [wait, None] {
            let over = next(Err(closed(crate::link::RUN_OVER)), wait);
            assert!(matches!(over, Next::Over(_)), "{over:?}");
        }
    }

    #[tokio::test]
    async fn each_rejoined_link_runs_a_session_until_one_ends_well() {
        let mut ran = Vec::new();
        let mut rejoins = 0;
        let outcome: Result<(), BoxError> = sessions(
            "test node",
            Some(Duration::from_secs(1)),
            0u32,
            async |link| {
                ran.push(link);
                if link < 2 {
                    Err(lost())
                } else {
                    Ok(())
                }
            },
            async |_| {
                rejoins += 1;
                Ok(rejoins)
            },
        )
        .await;
        assert!(outcome.is_ok());
        assert_eq!(ran, vec![0, 1, 2]);
    }

    #[tokio::test]
    async fn a_master_that_does_not_come_back_ends_the_node_naming_the_wait() {
        let mut sessions_run = 0;
        let outcome: Result<(), BoxError> = sessions(
            "test node",
            Some(Duration::from_secs(1)),
            (),
            async |()| {
                sessions_run += 1;
                Err(lost())
            },
            async |within| Err(LinkError::NotBack(within)),
        )
        .await;
        let e = outcome.unwrap_err().to_string();
        assert!(e.contains("did not come back within 1 s"), "{e}");
        assert_eq!(sessions_run, 1);
    }

    #[tokio::test]
    async fn a_list_of_masters_resolves_in_order_and_an_empty_entry_is_named() {
        let masters = resolve_masters("127.0.0.1:7400, 127.0.0.1:7401")
            .await
            .unwrap();
        let want: Vec<SocketAddr> = vec![
            "127.0.0.1:7400".parse().unwrap(),
            "127.0.0.1:7401".parse().unwrap(),
        ];
        assert_eq!(masters, want);
        let one = resolve_masters("127.0.0.1:7400").await.unwrap();
        assert_eq!(one, want[..1]);
        let e = resolve_masters("127.0.0.1:7400,,127.0.0.1:7401")
            .await
            .unwrap_err()
            .to_string();
        assert!(e.contains("127.0.0.1:7400,,127.0.0.1:7401"), "{e}");
        assert!(e.contains("empty entry"), "{e}");
    }

    /// A master at `server` that welcomes one node and holds its connection until the
    /// returned task is dropped.
    fn welcoming_master(server: quinn::Endpoint) -> tokio::task::JoinHandle<()> {
        use crate::framed::{read_msg, write_msg};
        use tessera_model::scene_spec::SceneSpec;
        use tessera_model::wall::WallLayout;
        use tessera_protocol::{dsm::DataSpec, pixels::Compression, FromNode, Session};
        use tessera_protocol::{RenderNodeId, SessionSpec, ToNode};
        tokio::spawn(async move {
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
            let node = Some(RenderNodeId(0));
            let welcome = ToNode::Welcome {
                node,
                session,
                term: 1,
            };
            write_msg(&mut send, &welcome).await.unwrap();
            conn.closed().await;
        })
    }

    /// Regression: a node knew one master only, so the standby that took the wall over was
    /// never joined. One that lost the first of its list tries the next first (a dead master
    /// would hold each attempt for the whole connect timeout).
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_node_that_lost_its_master_joins_the_next_of_its_list_first() {
        let dir = tempfile::tempdir().unwrap();
        let ca = ClusterCa::open_or_create(&dir.path().join("ca")).unwrap();
        for (name, role) in [("master", CertRole::Master), ("node", CertRole::Render)] {
            ca.issue(name, &dir.path().join(name), Some(role)).unwrap();
        }
        let load = |name: &str| NodeIdentity::load(&dir.path().join(name)).unwrap();
        let any = "127.0.0.1:0".parse().unwrap();
        let server = crate::quic::endpoint(any, &load("master"), true).unwrap();
        let standby = server.local_addr().unwrap();
        let master = welcoming_master(server);
        // The lost primary: a socket that takes datagrams and answers none.
        let dead = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
        let endpoint = crate::quic::endpoint(any, &load("node"), false).unwrap();
        let reconnect = Reconnect::new(
            endpoint,
            vec![dead.local_addr().unwrap(), standby],
            Role::Render { cores: 1 },
            Some(Duration::from_secs(60)),
            "test node".into(),
        );
        assert_eq!(reconnect.master(), dead.local_addr().unwrap());
        let within = crate::quic::CONNECT_TIMEOUT / 2;
        let (link, welcome) = reconnect.rejoin(within).await.expect("joined the standby");
        assert_eq!(reconnect.master(), standby);
        assert_eq!(welcome.term, 1);
        drop(link);
        master.abort();
    }

    #[tokio::test]
    async fn rejoining_a_master_that_never_answers_gives_up_at_its_bound() {
        let dir = tempfile::tempdir().unwrap();
        let ca = ClusterCa::open_or_create(&dir.path().join("ca")).unwrap();
        ca.issue("node", &dir.path().join("node"), Some(CertRole::Render))
            .unwrap();
        let id = NodeIdentity::load(&dir.path().join("node")).unwrap();
        let endpoint = crate::quic::endpoint("127.0.0.1:0".parse().unwrap(), &id, false).unwrap();
        // A socket that takes datagrams and answers none: a master host that is down.
        let silent = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
        let reconnect = Reconnect::new(
            endpoint,
            vec![silent.local_addr().unwrap()],
            Role::Render { cores: 1 },
            Some(Duration::from_millis(300)),
            "test node".into(),
        );
        let t = std::time::Instant::now();
        let Err(e) = reconnect.rejoin(Duration::from_millis(300)).await else {
            panic!("joined a master that is not there");
        };
        assert!(matches!(e, LinkError::NotBack(_)), "{e}");
        assert!(t.elapsed() < Duration::from_secs(5), "{:?}", t.elapsed());
    }
}
