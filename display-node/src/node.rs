//! The display node's driver loop: the only place in the display node with sockets and clock
//! reads. It feeds the sans-IO [`FrameAssembler`] the tiles the render nodes send and the
//! master's presents, and carries out what it returns.

use crate::pixels_in::{accept_render_nodes, Intake};
use crate::present::wait_until;
use crate::window::{WindowCommand, WindowFrame, WindowSender};
use crate::{Cli, WALL_OVER};
use anyhow::{Context, Result};
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;
use tessera_core::assemble::FrameAssembler;
use tessera_net::cluster::NodeIdentity;
use tessera_net::link::MasterLink;
use tessera_net::quic;
use tessera_wire::image::RgbImage;
use tessera_wire::protocol::{DisplayStats, FrameId, FromNode, NodeStats, Role, ToNode};
use tessera_wire::wall::{DisplayId, TileGrid};
use tokio::sync::mpsc;

/// What the window thread and the network side hand each other (see `run_with_window`).
pub struct WindowHandshake {
    /// The screen's size, once the master has said it.
    pub size: std::sync::mpsc::Sender<(u32, u32)>,
    /// The opened window.
    pub sender: std::sync::mpsc::Receiver<WindowSender>,
    /// (frame, clock) of each present the window really did.
    pub presents: mpsc::UnboundedReceiver<(u64, u64)>,
}

/// Reports the next frame to present complete to the master, once, when it is assembled.
async fn report_next_complete(assembler: &mut FrameAssembler, link: &mut MasterLink) -> Result<()> {
    if let Some(frame) = assembler.poll_complete() {
        link.send(&FromNode::FrameComplete { frame }).await?;
    }
    Ok(())
}

pub async fn run(cli: Cli, window: Option<WindowHandshake>) -> Result<()> {
    let me = DisplayId(cli.display);
    let identity = NodeIdentity::load(&cli.cert_dir)?;
    let endpoint = quic::endpoint(cli.listen, &identity, true)?;
    let pixel_addr = cli.advertise.unwrap_or(endpoint.local_addr()?);
    let master_addr = tessera_net::resolve(&cli.master).await?;
    let role = Role::Display {
        display: me,
        pixel_addr,
    };
    let (mut link, welcome) = MasterLink::join(&endpoint, master_addr, role)
        .await
        .with_context(|| format!("display {} could not join", me.0))
        .context("is tessera-master running there? see --help")?;
    let session = welcome.session;
    let screen = session
        .wall()
        .screen(me)
        .with_context(|| format!("the wall has no display {}", me.0))?;
    let (window, mut window_presents) = match window {
        Some(handshake) => {
            handshake
                .size
                .send((screen.width, screen.height))
                .context("window thread is gone")?;
            let opened = handshake.sender;
            let sender = tokio::task::spawn_blocking(move || opened.recv())
                .await?
                .context("cannot open the window")?;
            (Some(sender), Some(handshake.presents))
        }
        None => (None, None),
    };
    let grid = Arc::new(TileGrid::new(*session.wall()));
    let mut assembler = FrameAssembler::new(&grid, screen);
    let intake = Arc::new(Intake::default());
    let (tiles_tx, mut tiles) = mpsc::channel(1024);
    tokio::spawn(accept_render_nodes(
        endpoint.clone(),
        grid.clone(),
        me,
        session.compression(),
        intake.clone(),
        tiles_tx,
    ));
    link.send(&FromNode::Ready).await?;
    tracing::info!(
        "display {}: ready, {}x{} pixels at {}",
        me.0,
        screen.width,
        screen.height,
        pixel_addr
    );

    let mut presented = 0u64;
    // Drawn once the overlay is implemented in the presenter; kept so the toggle is not lost.
    let mut _overlay = false;
    // Frames a control client asked to keep, saved as they are presented.
    let mut snapshots: Vec<FrameId> = Vec::new();
    loop {
        tokio::select! {
            // The master's messages first: a Present waiting behind a burst of tiles would let
            // tiles of later frames be judged against a stale frame count, and refused.
            biased;
            msg = link.recv() => match msg? {
                msg @ (ToNode::Present { .. } | ToNode::PresentAt { .. }) => {
                    let (frame, deadline) = match msg {
                        ToNode::PresentAt { frame, clock_ns } => (frame, Some(clock_ns)),
                        ToNode::Present { frame } => (frame, None),
                        _ => unreachable!("matched above"),
                    };
                    let shown = assembler.handle_present(frame).map_err(|e| anyhow::anyhow!("the master broke the swap barrier: {e}"))?;
                    presented += 1;
                    report_next_complete(&mut assembler, &mut link).await?;
                    let mut names = Vec::new();
                    if session.save_frame() == Some(frame) {
                        names.push(format!("display-{}.png", me.0));
                    }
                    if let Some(i) = snapshots.iter().position(|&f| f == frame) {
                        snapshots.swap_remove(i);
                        names.push(format!("display-{}-frame-{}.png", me.0, frame.0));
                    }
                    let saved = (!names.is_empty()).then(|| RgbImage { width: shown.width, height: shown.height, rgb: shown.rgb.clone() });
                    if let Some(at) = deadline {
                        // A precise wait (tokio's timer has 1 ms steps), kept off the async
                        // workers' queue so pixel intake goes on meanwhile.
                        tokio::task::block_in_place(|| wait_until(at));
                    }
                    if let Some(w) = &window {
                        // Reported once the window has really presented it (below).
                        w.send(WindowCommand::Show(WindowFrame { frame: frame.0, width: shown.width, height: shown.height, rgb: shown.rgb }));
                    } else {
                        let clock_ns = tessera_net::unix_ns();
                        link.send(&FromNode::Presented { frame, clock_ns }).await?;
                    }
                    if let (Some(image), Some(dir)) = (saved, &cli.out) {
                        let paths: Vec<_> = names.iter().map(|n| dir.join(n)).collect();
                        tokio::task::spawn_blocking(move || {
                            paths.iter().try_for_each(|path| image.save_png(path))
                        })
                        .await??;
                    }
                }
                ToNode::Ping { seq } => {
                    let clock_ns = tessera_net::unix_ns();
                    link.send(&FromNode::Pong { seq, clock_ns }).await?;
                }
                ToNode::Shutdown => {
                    let stats = DisplayStats {
                        pixels_owned: screen.width as u64 * screen.height as u64,
                        pixel_bytes_received: intake.pixel_bytes.load(Ordering::Relaxed),
                        wire_bytes_received: intake.wire_bytes(),
                        stream_bytes_received: intake.stream_bytes.load(Ordering::Relaxed),
                        frames_presented: presented,
                        duplicate_tiles: assembler.duplicates(),
                    };
                    link.finish(NodeStats::Display(stats)).await?;
                    if let Some(w) = &window {
                        tokio::time::sleep(Duration::from_secs_f64(cli.linger)).await;
                        WALL_OVER.store(true, Ordering::SeqCst);
                        w.send(WindowCommand::Close);
                    }
                    endpoint.close(0u32.into(), b"done");
                    tracing::info!("display {}: done, {presented} frames presented", me.0);
                    return Ok(());
                }
                // The frame's state: every tile of the frame must have been rendered with it.
                ToNode::FrameStart(start) => assembler
                    .handle_frame_start(start.frame, start.state)
                    .map_err(|e| anyhow::anyhow!("the master broke the frame barrier: {e}"))?,
                ToNode::Overlay { on } => _overlay = on,
                ToNode::SaveFrame { frame } => snapshots.push(frame),
                other @ (ToNode::Assign { .. } | ToNode::Welcome { .. } | ToNode::Refused { .. } | ToNode::ControlReply { .. }) => {
                    anyhow::bail!("the master broke the protocol: it sent a display a {} message", other.kind())
                }
            },
            Some((frame, clock_ns)) = async { window_presents.as_mut()?.recv().await } => {
                link.send(&FromNode::Presented { frame: FrameId(frame), clock_ns }).await?;
            }
            Some(tile) = tiles.recv() => {
                match assembler.handle_tile(tile.frame, tile.state, tile.tile, &tile.rgb) {
                    Ok(Some(_)) => report_next_complete(&mut assembler, &mut link).await?,
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
