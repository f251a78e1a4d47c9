//! The console over HTTPS, for a served wall: the master's cluster certificate on the server
//! side, and a client's control certificate, when it shows one, admitting it without the
//! token. Handshakes run on tasks of their own (each bounded), so a slow or silent client
//! never holds the next one up.

use anyhow::{Context, Result};
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;
use tessera_net::cluster::{cert_roles, CertRole, NodeIdentity};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::mpsc;
use tokio_rustls::server::TlsStream;

/// Longest a client may take over its TLS handshake.
const HANDSHAKE: Duration = Duration::from_secs(10);

/// Who is at the other end of an HTTPS connection.
#[derive(Clone, Debug)]
pub struct TlsPeer {
    /// Its address.
    pub addr: SocketAddr,
    /// Whether it showed a control certificate the cluster CA signed.
    pub control: bool,
}

/// Connections whose handshake is done, for `axum::serve`.
pub struct TlsListener {
    done: mpsc::Receiver<(TlsStream<TcpStream>, TlsPeer)>,
    local: SocketAddr,
}

/// Accepts HTTPS connections on `tcp` with `identity`'s certificate.
///
/// # Errors
/// A certificate or key rustls refuses.
pub fn listen(tcp: TcpListener, identity: &NodeIdentity) -> Result<TlsListener> {
    let config = tessera_net::quic::https_server_config(identity)
        .context("cannot set up the console's HTTPS")?;
    let acceptor = tokio_rustls::TlsAcceptor::from(Arc::new(config));
    let local = tcp.local_addr()?;
    let (tx, done) = mpsc::channel(64);
    tokio::spawn(async move {
        loop {
            let Ok((stream, addr)) = tcp.accept().await else {
                // Out of descriptors, say: try again shortly rather than spin.
                tokio::time::sleep(Duration::from_millis(50)).await;
                continue;
            };
            let (acceptor, tx) = (acceptor.clone(), tx.clone());
            tokio::spawn(async move {
                let Ok(Ok(tls)) = tokio::time::timeout(HANDSHAKE, acceptor.accept(stream)).await
                else {
                    return;
                };
                let control = tls
                    .get_ref()
                    .1
                    .peer_certificates()
                    .and_then(|c| c.first())
                    .is_some_and(|c| cert_roles(c).contains(&CertRole::Control));
                let _ = tx.send((tls, TlsPeer { addr, control })).await;
            });
        }
    });
    Ok(TlsListener { done, local })
}

impl axum::serve::Listener for TlsListener {
    type Io = TlsStream<TcpStream>;
    type Addr = TlsPeer;

    async fn accept(&mut self) -> (Self::Io, Self::Addr) {
        match self.done.recv().await {
            Some(connection) => connection,
            // The accepting task never ends while the listener lives.
            None => std::future::pending().await,
        }
    }

    fn local_addr(&self) -> std::io::Result<Self::Addr> {
        Ok(TlsPeer {
            addr: self.local,
            control: false,
        })
    }
}

impl axum::extract::connect_info::Connected<axum::serve::IncomingStream<'_, TlsListener>>
    for TlsPeer
{
    fn connect_info(stream: axum::serve::IncomingStream<'_, TlsListener>) -> Self {
        stream.remote_addr().clone()
    }
}
