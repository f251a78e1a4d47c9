//! `tessera-display-node`: receives the pixels of its own screen from the render nodes,
//! assembles each frame, and presents it only when the master says so (the swap barrier).

mod pixels_in;
mod window;

use anyhow::{bail, Context, Result};
use clap::Parser;
use pixels_in::{accept_render_nodes, Intake};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;
use tessera_common::assemble::FrameAssembler;
use tessera_common::image_io::RgbImage;
use tessera_common::net::cluster::NodeIdentity;
use tessera_common::net::framed::{read_msg, spawn_reader, write_msg};
use tessera_common::net::quic;
use tessera_common::protocol::{
    DisplayStats, FrameId, FromNode, Hello, NodeStats, Role, ToNode, PROTOCOL_VERSION,
};
use tessera_common::wall::{DisplayId, TileGrid};
use tokio::sync::mpsc;
use window::{window_presenter, WindowCommand, WindowFrame, WindowSender};

/// Tessera display node: shows one screen of the wall.
#[derive(Parser, Clone)]
#[command(version, about, long_about = None)]
struct Cli {
    /// The master's address, HOST:PORT.
    #[arg(long)]
    master: String,
    /// Which screen of the wall this node shows (row-major from the top left, from 0).
    #[arg(long)]
    display: u32,
    /// This node's certificate directory (node.pem, node.key, ca.pem) from `tessera-master issue-cert`.
    #[arg(long)]
    cert_dir: PathBuf,
    /// Address to accept render nodes' pixels on (port 0: any free port).
    #[arg(long, default_value = "0.0.0.0:0")]
    listen: SocketAddr,
    /// Address render nodes should use to reach this node, if not the one the master sees.
    #[arg(long)]
    advertise: Option<SocketAddr>,
    /// Present in a window (needs a display server); otherwise headless.
    #[arg(long)]
    window: bool,
    /// With --window, seconds to keep the last frame on screen after the run.
    #[arg(long, default_value_t = 0.0)]
    linger: f64,
    /// Directory for display-<id>.png when the master asks to save a frame.
    #[arg(long)]
    out: Option<PathBuf>,
}

fn main() -> ExitCode {
    tessera_common::logging::init();
    let cli = Cli::parse();
    let result = if cli.window {
        run_with_window(cli)
    } else {
        runtime().and_then(|rt| rt.block_on(run(cli, None)))
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("tessera-display-node: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn runtime() -> Result<tokio::runtime::Runtime> {
    Ok(tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?)
}

/// winit wants the main thread, so the network side runs on a thread of its own.
fn run_with_window(cli: Cli) -> Result<()> {
    // The window is sized once the master says how big a screen is, so the network side goes
    // first and hands the size over.
    let (size_tx, size_rx) = std::sync::mpsc::channel::<(u32, u32)>();
    let (sender_tx, sender_rx) = std::sync::mpsc::channel::<WindowSender>();
    // Presents are stamped on the main thread right after softbuffer's present(), and the
    // stamps travel to the network side, which reports them to the master.
    let (presented_tx, presented_rx) = mpsc::unbounded_channel::<(u64, u64)>();
    let display = cli.display;
    let net = std::thread::spawn(move || -> Result<()> {
        let rt = runtime()?;
        rt.block_on(run(cli, Some((size_tx, sender_rx, presented_rx))))
    });
    let Ok((width, height)) = size_rx.recv() else {
        return net
            .join()
            .map_err(|_| anyhow::anyhow!("network thread panicked"))?;
    };
    let (sender, runner) = window_presenter(
        format!("Tessera display {display}"),
        width,
        height,
        Box::new(move |frame| {
            let _ = presented_tx.send((frame, tessera_common::net::unix_ns()));
        }),
    )?;
    let _ = sender_tx.send(sender);
    let shown = runner.run();
    if !net.is_finished() && !WALL_OVER.load(Ordering::SeqCst) {
        // The window went away while the wall is still running (closed by the user, or the
        // display server died): this screen leaves the wall, and the master says so.
        shown?;
        bail!("the window of display {display} was closed while the wall was running");
    }
    let net = net
        .join()
        .map_err(|_| anyhow::anyhow!("network thread panicked"))?;
    net.and(shown)
}

/// Reports the next frame to present complete to the master, once, when it is assembled.
async fn report_next_complete(
    assembler: &mut FrameAssembler,
    send: &mut quinn::SendStream,
) -> Result<()> {
    if let Some(frame) = assembler.poll_complete() {
        write_msg(send, &FromNode::FrameComplete { frame }).await?;
    }
    Ok(())
}

/// Sleeps until the clock (ns since the Unix epoch) reads `at`: the last stretch is spun, since
/// a sleeping thread wakes up to tens of microseconds late. A deadline more than a second away
/// means clocks that disagree; waiting for it would stall the wall, so it is not waited for.
fn wait_until(at: u64) {
    const SPIN: Duration = Duration::from_micros(200);
    for _ in 0..100_000_000u64 {
        let now = tessera_common::net::unix_ns();
        let Some(left) = at.checked_sub(now).filter(|&l| l > 0) else {
            return;
        };
        let left = Duration::from_nanos(left);
        if left > Duration::from_secs(1) {
            tracing::warn!("a present deadline {left:?} away: clocks disagree; presenting now");
            return;
        }
        if left > SPIN {
            std::thread::sleep(left - SPIN);
        } else {
            std::hint::spin_loop();
        }
    }
}

/// Set when the run is over and the network side itself closes the window.
static WALL_OVER: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

type WindowHandshake = (
    std::sync::mpsc::Sender<(u32, u32)>,
    std::sync::mpsc::Receiver<WindowSender>,
    mpsc::UnboundedReceiver<(u64, u64)>,
);

async fn run(cli: Cli, window: Option<WindowHandshake>) -> Result<()> {
    let me = DisplayId(cli.display);
    let identity = NodeIdentity::load(&cli.cert_dir)?;
    let endpoint = quic::endpoint(cli.listen, &identity, true)?;
    let pixel_addr = cli.advertise.unwrap_or(endpoint.local_addr()?);
    let master_addr = tessera_common::net::resolve_master(&cli.master).await?;
    let conn = quic::connect(&endpoint, master_addr, "the master")
        .await
        .context("is tessera-master running there? see --help")?;
    let (mut send, mut recv) = conn.open_bi().await?;
    let host = tessera_common::net::hostname();
    write_msg(
        &mut send,
        &FromNode::Hello(Hello {
            version: PROTOCOL_VERSION,
            role: Role::Display {
                display: me,
                pixel_addr,
            },
            host,
        }),
    )
    .await?;
    let session = match read_msg::<ToNode>(&mut recv).await? {
        Some(ToNode::Welcome { session, .. }) => session,
        Some(ToNode::Refused { reason }) => bail!("the master refused display {}: {reason}", me.0),
        Some(other) => bail!("expected a welcome from the master, got {other:?}"),
        None => bail!("the master closed the connection during the handshake"),
    };
    session.wall.validate()?;
    let screen = session
        .wall
        .screen(me)
        .with_context(|| format!("the wall has no display {}", me.0))?;
    let (window, mut window_presents) = match window {
        Some((size_tx, sender_rx, presents)) => {
            size_tx
                .send((screen.width, screen.height))
                .context("window thread is gone")?;
            let sender = tokio::task::spawn_blocking(move || sender_rx.recv())
                .await?
                .context("cannot open the window")?;
            (Some(sender), Some(presents))
        }
        None => (None, None),
    };
    let grid = Arc::new(TileGrid::new(session.wall));
    let mut assembler = FrameAssembler::new(&grid, screen);
    let intake = Arc::new(Intake::default());
    let (tiles_tx, mut tiles) = mpsc::channel(1024);
    tokio::spawn(accept_render_nodes(
        endpoint.clone(),
        grid.clone(),
        me,
        session.compression,
        intake.clone(),
        tiles_tx,
    ));
    write_msg(&mut send, &FromNode::Ready).await?;
    tracing::info!(
        "display {}: ready, {}x{} pixels at {}",
        me.0,
        screen.width,
        screen.height,
        pixel_addr
    );

    let mut presented = 0u64;
    let mut control = spawn_reader::<ToNode>(recv);
    loop {
        tokio::select! {
            // The master's messages first: a Present waiting behind a burst of tiles would let
            // tiles of later frames be judged against a stale frame count, and refused.
            biased;
            msg = control.recv() => match msg.unwrap_or(Ok(None)) {
                Ok(Some(msg @ (ToNode::Present { .. } | ToNode::PresentAt { .. }))) => {
                    let (frame, deadline) = match msg {
                        ToNode::PresentAt { frame, clock_ns } => (frame, Some(clock_ns)),
                        ToNode::Present { frame } => (frame, None),
                        _ => unreachable!("matched above"),
                    };
                    let shown = assembler.handle_present(frame).map_err(|e| anyhow::anyhow!("the master broke the swap barrier: {e}"))?;
                    presented += 1;
                    report_next_complete(&mut assembler, &mut send).await?;
                    let saved = (session.save_frame == Some(frame)).then(|| RgbImage { width: shown.width, height: shown.height, rgb: shown.rgb.clone() });
                    if let Some(at) = deadline {
                        // A precise wait (tokio's timer has 1 ms steps), kept off the async
                        // workers' queue so pixel intake goes on meanwhile.
                        tokio::task::block_in_place(|| wait_until(at));
                    }
                    if let Some(w) = &window {
                        // Reported once the window has really presented it (below).
                        w.send(WindowCommand::Show(WindowFrame { frame: frame.0, width: shown.width, height: shown.height, rgb: shown.rgb }));
                    } else {
                        let clock_ns = tessera_common::net::unix_ns();
                        write_msg(&mut send, &FromNode::Presented { frame, clock_ns }).await?;
                    }
                    if let (Some(image), Some(dir)) = (saved, &cli.out) {
                        let path = dir.join(format!("display-{}.png", me.0));
                        tokio::task::spawn_blocking(move || image.save_png(&path)).await??;
                    }
                }
                Ok(Some(ToNode::Ping { seq })) => {
                    let clock_ns = tessera_common::net::unix_ns();
                    write_msg(&mut send, &FromNode::Pong { seq, clock_ns }).await?;
                }
                Ok(Some(ToNode::Shutdown)) => {
                    let stats = DisplayStats {
                        pixels_owned: screen.width as u64 * screen.height as u64,
                        pixel_bytes_received: intake.pixel_bytes.load(Ordering::Relaxed),
                        wire_bytes_received: intake.wire_bytes(),
                        stream_bytes_received: intake.stream_bytes.load(Ordering::Relaxed),
                        frames_presented: presented,
                        duplicate_tiles: assembler.duplicates(),
                    };
                    write_msg(&mut send, &FromNode::Stats(NodeStats::Display(stats))).await?;
                    let _ = send.finish();
                    let _ = tokio::time::timeout(Duration::from_secs(10), conn.closed()).await;
                    if let Some(w) = &window {
                        tokio::time::sleep(Duration::from_secs_f64(cli.linger.max(0.0))).await;
                        WALL_OVER.store(true, Ordering::SeqCst);
                        w.send(WindowCommand::Close);
                    }
                    endpoint.close(0u32.into(), b"done");
                    tracing::info!("display {}: done, {presented} frames presented", me.0);
                    return Ok(());
                }
                Ok(Some(_)) => {}
                Ok(None) => bail!("the master ended the session without a shutdown"),
                Err(e) => bail!("lost the master: {e:#}"),
            },
            Some((frame, clock_ns)) = async { window_presents.as_mut()?.recv().await } => {
                write_msg(&mut send, &FromNode::Presented { frame: FrameId(frame), clock_ns }).await?;
            }
            Some(tile) = tiles.recv() => {
                match assembler.handle_tile(tile.frame, tile.tile, &tile.rgb) {
                    Ok(Some(_)) => report_next_complete(&mut assembler, &mut send).await?,
                    Ok(None) => {}
                    Err(e) => {
                        tracing::error!("display {}: closing a render node's connection: {e}", me.0);
                        tile.conn.close(3u32.into(), b"bad tile");
                    }
                }
            }
        }
    }
}
