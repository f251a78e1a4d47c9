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
use tessera_common::net::framed::{read_msg, write_msg};
use tessera_common::net::quic;
use tessera_common::protocol::{
    DisplayStats, FromNode, Hello, NodeStats, Role, ToNode, PROTOCOL_VERSION,
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
    let display = cli.display;
    let net = std::thread::spawn(move || -> Result<()> {
        let rt = runtime()?;
        rt.block_on(run(cli, Some((size_tx, sender_rx))))
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
        Box::new(|_| {}),
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

/// Set when the run is over and the network side itself closes the window.
static WALL_OVER: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

type WindowHandshake = (
    std::sync::mpsc::Sender<(u32, u32)>,
    std::sync::mpsc::Receiver<WindowSender>,
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
    let window = match window {
        Some((size_tx, sender_rx)) => {
            size_tx
                .send((screen.width, screen.height))
                .context("window thread is gone")?;
            let sender = tokio::task::spawn_blocking(move || sender_rx.recv())
                .await?
                .context("cannot open the window")?;
            Some(sender)
        }
        None => None,
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
    loop {
        tokio::select! {
            msg = read_msg::<ToNode>(&mut recv) => match msg {
                Ok(Some(ToNode::Present { frame })) => {
                    let shown = assembler.handle_present(frame).map_err(|e| anyhow::anyhow!("the master broke the swap barrier: {e}"))?;
                    presented += 1;
                    if session.save_frame == Some(frame) {
                        if let Some(dir) = &cli.out {
                            let path = dir.join(format!("display-{}.png", me.0));
                            let image = RgbImage { width: shown.width, height: shown.height, rgb: shown.rgb.clone() };
                            tokio::task::spawn_blocking(move || image.save_png(&path)).await??;
                        }
                    }
                    if let Some(w) = &window {
                        w.send(WindowCommand::Show(WindowFrame { frame: frame.0, width: shown.width, height: shown.height, rgb: shown.rgb }));
                    }
                    write_msg(&mut send, &FromNode::Presented { frame }).await?;
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
            Some(tile) = tiles.recv() => {
                match assembler.handle_tile(tile.frame, tile.tile, &tile.rgb) {
                    Ok(Some(frame)) => write_msg(&mut send, &FromNode::FrameComplete { frame }).await?,
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
