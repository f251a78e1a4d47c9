//! `tessera-master relay`: a UDP relay that impairs what passes through it (loss, delay,
//! jitter, reordering, duplication, a partition that heals), for testing a wall on a network
//! worse than loopback where the kernel has no `sch_netem`. Nodes are pointed at the relay
//! (`--master RELAY` for the master's traffic, a display's `--advertise RELAY` for pixels);
//! each client gets its own upstream socket, so the far side sees one peer per client.
//!
//! The decisions are [`tessera_core::impair::Impairment`]'s; this is only its sockets.

use anyhow::{Context, Result};
use std::collections::HashMap;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tessera_core::impair::{Faults, Impairment};
use tokio::net::UdpSocket;

#[derive(clap::Args)]
pub struct RelayArgs {
    /// Address to receive datagrams on (port 0: any free port; the relay prints which).
    #[arg(long, default_value = "127.0.0.1:0")]
    listen: SocketAddr,
    /// Where to send them on.
    #[arg(long)]
    to: SocketAddr,
    /// Share of datagrams dropped, each way (0 to 1).
    #[arg(long, default_value_t = 0.0, value_parser = unit)]
    loss: f64,
    /// Delay of every datagram, each way, in ms.
    #[arg(long, default_value_t = 0.0, value_parser = millis)]
    delay_ms: f64,
    /// Extra delay drawn per datagram from 0 to this, in ms (it reorders datagrams).
    #[arg(long, default_value_t = 0.0, value_parser = millis)]
    jitter_ms: f64,
    /// Share of datagrams held back a further --reorder-ms.
    #[arg(long, default_value_t = 0.0, value_parser = unit)]
    reorder: f64,
    /// How much longer, in ms, a datagram --reorder holds back waits.
    #[arg(long, default_value_t = 30.0, value_parser = millis)]
    reorder_ms: f64,
    /// Share of datagrams sent twice.
    #[arg(long, default_value_t = 0.0, value_parser = unit)]
    duplicate: f64,
    /// A partition: nothing gets through from START seconds after the relay starts, for
    /// LENGTH seconds; then it heals. START:LENGTH.
    #[arg(long, value_parser = partition)]
    partition: Option<(Duration, Duration)>,
    /// Seed of the faults: the same seed and traffic give the same faults.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Write the counts (received, forwarded, dropped, ...) here as JSON on exit.
    #[arg(long)]
    stats: Option<PathBuf>,
}

fn unit(text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(x) if (0.0..=1.0).contains(&x) => Ok(x),
        _ => Err(format!("`{text}` is not a share from 0 to 1")),
    }
}

fn millis(text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(x) if (0.0..=60_000.0).contains(&x) => Ok(x),
        _ => Err(format!("`{text}` is not a number of ms from 0 to 60000")),
    }
}

fn partition(text: &str) -> Result<(Duration, Duration), String> {
    let bad = || format!("`{text}` is not START:LENGTH in seconds");
    let (a, b) = text.split_once(':').ok_or_else(bad)?;
    let secs = |s: &str| {
        s.parse::<f64>()
            .ok()
            .and_then(|x| Duration::try_from_secs_f64(x).ok())
            .ok_or_else(bad)
    };
    Ok((secs(a)?, secs(b)?))
}

/// The relay's state shared by its directions: one model, one clock origin.
struct Shared {
    model: Mutex<Impairment>,
    started: Instant,
}

impl Shared {
    /// Sends `bytes` on `socket` (to `to`, or its connected peer) as the model says.
    fn pass(self: &Arc<Self>, socket: &Arc<UdpSocket>, to: Option<SocketAddr>, bytes: Vec<u8>) {
        let delays = self
            .model
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .handle_datagram(self.started.elapsed());
        for delay in delays {
            let (socket, bytes) = (socket.clone(), bytes.clone());
            tokio::spawn(async move {
                if !delay.is_zero() {
                    tokio::time::sleep(delay).await;
                }
                let _ = match to {
                    Some(addr) => socket.send_to(&bytes, addr).await,
                    None => socket.send(&bytes).await,
                };
            });
        }
    }
}

pub async fn relay(args: RelayArgs) -> Result<std::process::ExitCode> {
    let faults = Faults {
        loss: args.loss,
        delay: Duration::from_secs_f64(args.delay_ms / 1000.0),
        jitter: Duration::from_secs_f64(args.jitter_ms / 1000.0),
        reorder: args.reorder,
        reorder_by: Duration::from_secs_f64(args.reorder_ms / 1000.0),
        duplicate: args.duplicate,
        partition: args.partition,
    };
    let front = Arc::new(
        UdpSocket::bind(args.listen)
            .await
            .with_context(|| format!("cannot listen on {}", args.listen))?,
    );
    let shared = Arc::new(Shared {
        model: Mutex::new(Impairment::new(faults, args.seed)),
        started: Instant::now(),
    });
    // Tests and scripts read this line for the address.
    eprintln!(
        "relay: listening on {} for {}",
        front.local_addr()?,
        args.to
    );
    let mut upstreams: HashMap<SocketAddr, Arc<UdpSocket>> = HashMap::new();
    let mut buf = vec![0u8; 65_536];
    let bind_any: SocketAddr = if args.to.is_ipv6() {
        "[::]:0"
    } else {
        "0.0.0.0:0"
    }
    .parse()?;
    loop {
        tokio::select! {
            received = front.recv_from(&mut buf) => {
                let (n, client) = received.context("the relay's socket failed")?;
                let upstream = match upstreams.get(&client) {
                    Some(u) => u.clone(),
                    None => {
                        let u = Arc::new(UdpSocket::bind(bind_any).await?);
                        u.connect(args.to).await?;
                        upstreams.insert(client, u.clone());
                        // The way back: what the far side answers goes to this client.
                        let (u2, front2, shared2) = (u.clone(), front.clone(), shared.clone());
                        tokio::spawn(async move {
                            let mut back = vec![0u8; 65_536];
                            while let Ok(n) = u2.recv(&mut back).await {
                                shared2.pass(&front2, Some(client), back[..n].to_vec());
                            }
                        });
                        u
                    }
                };
                shared.pass(&upstream, None, buf[..n].to_vec());
            }
            _ = tokio::signal::ctrl_c() => break,
        }
    }
    let stats = shared
        .model
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .stats();
    eprintln!("relay: {stats:?}");
    if let Some(path) = &args.stats {
        std::fs::write(path, serde_json::to_vec_pretty(&stats)?)
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    Ok(std::process::ExitCode::SUCCESS)
}
