//! One master's sessions after another: the loop that render and display nodes share.
//!
//! A node joins its master and runs a session until the master shuts the wall down. Started
//! with `--reconnect` (the flags are `tessera-cli`'s), a node whose master is lost (killed,
//! crashed, its host down) waits, bounded, for a master at the same address, joins it again
//! and runs the next session, as often as the master is lost. A refusal, a broken protocol or
//! a failure of the node's own ends the node whatever the flags say: waiting would not mend
//! them. A master that closes the connection because its run is over (it failed, or ended
//! without a shutdown) ends the node as a shutdown does: its part is done.

use crate::link::{LinkError, MasterLink, Welcome};
use std::error::Error;
use std::fmt::Display;
use std::net::SocketAddr;
use std::time::Duration;
use tessera_protocol::Role;

/// How often a node that waits for its master to come back knocks again.
pub const REJOIN_INTERVAL: Duration = Duration::from_millis(250);

/// Where a node's master is, as whom the node joins it, and whether it waits for it when lost.
#[derive(Clone, Debug)]
pub struct Reconnect {
    /// The node's endpoint: every session's link to the master goes through it.
    pub endpoint: quinn::Endpoint,
    /// The master's address.
    pub master: SocketAddr,
    /// What the node says it is in its hello.
    pub role: Role,
    /// With `--reconnect`: how long to wait for a lost master each time, before giving up.
    pub wait: Option<Duration>,
    /// The node as its log lines name it (`render node`, `display 2`).
    pub name: String,
}

impl Reconnect {
    /// Joins the master the first time (see [`MasterLink::join`]).
    ///
    /// # Errors
    /// No master there, a refusal (its reason), or anything but a welcome.
    pub async fn join(&self) -> Result<(MasterLink, Welcome), LinkError> {
        MasterLink::join(&self.endpoint, self.master, self.role.clone()).await
    }

    /// Joins a master that may not be up yet (one restarting after a crash): tries again
    /// every [`REJOIN_INTERVAL`] while the master is not there, for at most `within`.
    ///
    /// # Errors
    /// [`LinkError::NotBack`] once `within` has passed; a refusal or a broken handshake at
    /// once.
    pub async fn rejoin(&self, within: Duration) -> Result<(MasterLink, Welcome), LinkError> {
        let give_up = tokio::time::Instant::now() + within;
        // A `Type=notify` unit stays active meanwhile; its status says why frames stopped.
        crate::sd_notify::status(&format!(
            "waiting up to {} s for the master at {} to come back",
            within.as_secs(),
            self.master
        ));
        let attempts = async {
            loop {
                match self.join().await {
                    Err(e) if e.is_lost_master() => {
                        tracing::debug!("the master is not back yet: {e}");
                        tokio::time::sleep(REJOIN_INTERVAL).await;
                    }
                    joined => return joined,
                }
            }
        };
        tokio::time::timeout_at(give_up, attempts)
            .await
            .unwrap_or(Err(LinkError::NotBack(within)))
    }

    /// Runs `session` on the link `first` joined, and, while the master is lost and the node
    /// waits for it, on each link [`Reconnect::rejoin`] makes, until a session ends well.
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
        sessions(
            &self.name,
            self.wait,
            first,
            async |(link, welcome)| session(link, welcome).await,
            async |within| self.rejoin(within).await,
        )
        .await
    }
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
    use crate::NetError;

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
    async fn rejoining_a_master_that_never_answers_gives_up_at_its_bound() {
        let dir = tempfile::tempdir().unwrap();
        let ca = ClusterCa::open_or_create(&dir.path().join("ca")).unwrap();
        ca.issue("node", &dir.path().join("node"), Some(CertRole::Render))
            .unwrap();
        let id = NodeIdentity::load(&dir.path().join("node")).unwrap();
        let endpoint = crate::quic::endpoint("127.0.0.1:0".parse().unwrap(), &id, false).unwrap();
        // A socket that takes datagrams and answers none: a master host that is down.
        let silent = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
        let reconnect = Reconnect {
            endpoint,
            master: silent.local_addr().unwrap(),
            role: Role::Render { cores: 1 },
            wait: Some(Duration::from_millis(300)),
            name: "test node".into(),
        };
        let t = std::time::Instant::now();
        let Err(e) = reconnect.rejoin(Duration::from_millis(300)).await else {
            panic!("joined a master that is not there");
        };
        assert!(matches!(e, LinkError::NotBack(_)), "{e}");
        assert!(t.elapsed() < Duration::from_secs(5), "{:?}", t.elapsed());
    }
}
