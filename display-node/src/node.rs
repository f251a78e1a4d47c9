//! The display node's driver loop: the only place in the display node with sockets and clock
//! reads. It feeds the sans-IO [`FrameAssembler`] the tiles the render nodes send and the
//! master's frame starts and presents, and carries out what it returns: presenting (headless
//! or in the window), saving frames, reporting presents and the person's input to the master.

use crate::overlay::{Overlay, TileInfo};
use crate::pixels_in::{accept_render_nodes, Intake};
use crate::present::wait_until;
use crate::window::{WindowCommand, WindowFrame, WindowSender};
use crate::{Cli, WALL_OVER};
use anyhow::{Context, Result};
use std::collections::{BTreeMap, VecDeque};
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tessera_core::assemble::FrameAssembler;
use tessera_net::cluster::NodeIdentity;
use tessera_net::link::{MasterLink, Welcome};
use tessera_net::quic;
use tessera_net::reconnect::Reconnect;
use tessera_net::sd_notify;
use tessera_wire::image::RgbImage;
use tessera_wire::input::InputEvent;
use tessera_wire::protocol::pixels::BatchSource;
use tessera_wire::protocol::{DisplayStats, FrameId, FromNode, NodeStats, Role, ToNode};
use tessera_wire::wall::{DisplayId, ScreenRect, TileGrid, TileId};
use tessera_wire::window::WindowPlacement;
use tokio::sync::mpsc;

/// What the window thread and the network side hand each other (see `run_with_window`).
pub struct WindowHandshake {
    /// The screen's size and the window's placement, once the master has said them.
    pub size: std::sync::mpsc::Sender<((u32, u32), WindowPlacement)>,
    /// The opened window.
    pub sender: std::sync::mpsc::Receiver<WindowSender>,
    /// (frame, clock) of each present the window really did.
    pub presents: mpsc::UnboundedReceiver<(u64, u64)>,
    /// (event, clock) of each key, drag and wheel turn in the window.
    pub inputs: mpsc::UnboundedReceiver<(InputEvent, u64)>,
}

/// A display's state between the master's messages.
struct Display {
    me: DisplayId,
    screen: ScreenRect,
    grid: Arc<TileGrid>,
    assembler: FrameAssembler,
    window: Option<WindowSender>,
    out: Option<std::path::PathBuf>,
    /// The session's frame to save as display-<id>.png.
    save_frame: Option<FrameId>,
    /// Frames a control client asked to keep, saved as they are presented.
    snapshots: Vec<FrameId>,
    presented: u64,
    overlay: bool,
    /// Who rendered each tile of the frames under assembly, for the overlay.
    sources: BTreeMap<FrameId, BTreeMap<TileId, BatchSource>>,
    /// When the last presents happened, for the overlay's frame rate.
    present_times: VecDeque<Instant>,
}

/// Reports the next frame to present complete to the master, once, when it is assembled.
async fn report_next_complete(assembler: &mut FrameAssembler, link: &mut MasterLink) -> Result<()> {
    if let Some(frame) = assembler.poll_complete() {
        link.send(&FromNode::FrameComplete { frame }).await?;
    }
    Ok(())
}

/// The window, once open: it outlives a session, so a display that rejoins a restarted master
/// keeps showing its last frame meanwhile.
struct OpenWindow {
    sender: WindowSender,
    presents: mpsc::UnboundedReceiver<(u64, u64)>,
    inputs: mpsc::UnboundedReceiver<(InputEvent, u64)>,
    size: (u32, u32),
}

/// The window a display presents in: to be opened (once the first master says its size),
/// open, or none (headless).
enum WindowState {
    ToOpen(WindowHandshake),
    Open(OpenWindow),
    Headless,
}

/// Aborts the task when a session ends, however it ends.
struct AbortOnDrop(tokio::task::JoinHandle<()>);

impl Drop for AbortOnDrop {
    fn drop(&mut self) {
        self.0.abort();
    }
}

/// Joins the master and shows frames until it shuts the wall down; with `--reconnect`, a lost
/// master is waited for (bounded) and rejoined, the window holding its last frame meanwhile.
pub async fn run(cli: Cli, window: Option<WindowHandshake>) -> Result<()> {
    let me = DisplayId(cli.display);
    let identity = NodeIdentity::load(&cli.cert_dir)?;
    let endpoint = quic::endpoint(cli.listen, &identity, true)?;
    let pixel_addr = cli.advertise.unwrap_or(endpoint.local_addr()?);
    let master_addr = tessera_net::resolve(&cli.master).await?;
    let reconnect = Reconnect {
        endpoint: endpoint.clone(),
        master: master_addr,
        role: Role::Display {
            display: me,
            pixel_addr,
        },
        wait: cli.reconnect.wait(),
        name: format!("display {}", me.0),
    };
    let first = reconnect
        .join()
        .await
        .with_context(|| format!("display {} could not join", me.0))
        .context("is tessera-master running there? see --help")?;
    let mut window = window.map_or(WindowState::Headless, WindowState::ToOpen);
    reconnect
        .run(first, async |link, welcome| {
            session(&cli, &endpoint, link, welcome, &mut window).await
        })
        .await
}

/// Opens the window at the first session's screen size; a later master must give the same.
async fn open_window(
    cli: &Cli,
    state: &mut WindowState,
    session: &tessera_wire::protocol::Session,
    screen: ScreenRect,
) -> Result<()> {
    let size = (screen.width, screen.height);
    match std::mem::replace(state, WindowState::Headless) {
        WindowState::ToOpen(handshake) => {
            let placement = cli.placement(session.window(DisplayId(cli.display)))?;
            handshake
                .size
                .send((size, placement))
                .context("window thread is gone")?;
            let opened = handshake.sender;
            let sender = tokio::task::spawn_blocking(move || opened.recv())
                .await?
                .context("cannot open the window")?;
            *state = WindowState::Open(OpenWindow {
                sender,
                presents: handshake.presents,
                inputs: handshake.inputs,
                size,
            });
        }
        WindowState::Open(open) => {
            let was = open.size;
            *state = WindowState::Open(open);
            if was != size {
                anyhow::bail!(
                    "the master's wall gives display {} {}x{} pixels; its window shows {}x{} (restart the display for a wall of another shape)",
                    cli.display, size.0, size.1, was.0, was.1
                );
            }
        }
        WindowState::Headless => {}
    }
    Ok(())
}

/// One master's wall, from the welcome to its shutdown (or the master's loss).
async fn session(
    cli: &Cli,
    endpoint: &quinn::Endpoint,
    mut link: MasterLink,
    welcome: Welcome,
    window_state: &mut WindowState,
) -> Result<()> {
    let me = DisplayId(cli.display);
    let pixel_addr = cli.advertise.unwrap_or(endpoint.local_addr()?);
    let session = welcome.session;
    let screen = session
        .wall()
        .screen(me)
        .with_context(|| format!("the wall has no display {}", me.0))?;
    open_window(cli, window_state, &session, screen).await?;
    let (window, mut window_presents, mut window_inputs) = match window_state {
        WindowState::Open(open) => (
            Some(open.sender.clone()),
            Some(&mut open.presents),
            Some(&mut open.inputs),
        ),
        _ => (None, None, None),
    };
    let grid = Arc::new(TileGrid::new(session.wall().clone()));
    let intake = Arc::new(Intake::default());
    let (tiles_tx, mut tiles) = mpsc::channel(1024);
    let _acceptor = AbortOnDrop(tokio::spawn(accept_render_nodes(
        endpoint.clone(),
        grid.clone(),
        me,
        session.compression(),
        intake.clone(),
        tiles_tx,
    )));
    link.send(&FromNode::Ready).await?;
    sd_notify::ready(&format!("display {}: showing the wall's frames", me.0));
    tracing::info!(
        "display {}: ready, {}x{} pixels at {}",
        me.0,
        screen.width,
        screen.height,
        pixel_addr
    );

    let mut display = Display {
        me,
        screen,
        assembler: FrameAssembler::new(&grid, screen),
        grid,
        window,
        out: cli.out.clone(),
        save_frame: session.save_frame(),
        snapshots: Vec::new(),
        presented: 0,
        overlay: false,
        sources: BTreeMap::new(),
        present_times: VecDeque::new(),
    };
    // The master goes on without a display silent past its deadline: beat, whatever the
    // window and the tiles are doing.
    let mut heartbeat = tokio::time::interval(tessera_wire::protocol::HEARTBEAT_INTERVAL);
    heartbeat.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tokio::select! {
            // The master's messages first: a Present waiting behind a burst of tiles would let
            // tiles of later frames be judged against a stale frame count, and refused.
            biased;
            msg = link.recv() => match msg? {
                ToNode::PresentAt { frame, clock_ns } => display.present(frame, Some(clock_ns), &mut link).await?,
                ToNode::Present { frame } => display.present(frame, None, &mut link).await?,
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
                        frames_presented: display.presented,
                        duplicate_tiles: display.assembler.duplicates(),
                    };
                    link.finish(NodeStats::Display(stats)).await?;
                    if let Some(w) = &display.window {
                        tokio::time::sleep(Duration::from_secs_f64(cli.linger)).await;
                        WALL_OVER.store(true, Ordering::SeqCst);
                        w.send(WindowCommand::Close);
                    }
                    endpoint.close(0u32.into(), b"done");
                    let presented = display.presented;
                    tracing::info!("display {}: done, {presented} frames presented", me.0);
                    return Ok(());
                }
                // The frame's state: every tile of the frame must have been rendered with it.
                ToNode::FrameStart(start) => display
                    .assembler
                    .handle_frame_start(start.frame, start.state)
                    .map_err(|e| anyhow::anyhow!("the master broke the frame barrier: {e}"))?,
                ToNode::StartAt { frame } => display.assembler.start_at(frame),
                ToNode::Overlay { on } => display.overlay = on,
                ToNode::SaveFrame { frame } => display.snapshots.push(frame),
                other @ (ToNode::Assign { .. } | ToNode::Welcome { .. } | ToNode::Refused { .. } | ToNode::ControlReply { .. } | ToNode::DisplayAt { .. } | ToNode::BlockHolders { .. }) => {
                    anyhow::bail!("the master broke the protocol: it sent a display a {} message", other.kind())
                }
            },
            _ = heartbeat.tick() => link.send(&FromNode::Heartbeat).await?,
            Some((frame, clock_ns)) = async { window_presents.as_mut()?.recv().await } => {
                link.send(&FromNode::Presented { frame: FrameId(frame), clock_ns }).await?;
            }
            Some((event, clock_ns)) = async { window_inputs.as_mut()?.recv().await } => {
                tracing::debug!("display {}: input {event:?} to the master", me.0);
                link.send(&FromNode::Input { event, clock_ns }).await?;
            }
            Some(tile) = tiles.recv() => {
                match display.assembler.handle_tile(tile.frame, tile.state, tile.tile, &tile.rgb) {
                    Ok(done) => {
                        display.sources.entry(tile.frame).or_default().insert(tile.tile, tile.source);
                        if done.is_some() {
                            report_next_complete(&mut display.assembler, &mut link).await?;
                        }
                    }
                    Err(e) => {
                        tracing::error!("display {}: closing a render node's connection: {e}", me.0);
                        tile.conn.close(3u32.into(), b"bad tile");
                    }
                }
            }
        }
    }
}

impl Display {
    /// The swap barrier: shows `frame` (at the deadline, if the master gave one), saves it
    /// where asked, and reports the present.
    async fn present(
        &mut self,
        frame: FrameId,
        deadline: Option<u64>,
        link: &mut MasterLink,
    ) -> Result<()> {
        let shown = self
            .assembler
            .handle_present(frame)
            .map_err(|e| anyhow::anyhow!("the master broke the swap barrier: {e}"))?;
        self.presented += 1;
        report_next_complete(&mut self.assembler, link).await?;
        let sources = self.sources.remove(&frame).unwrap_or_default();
        self.sources.retain(|f, _| *f > frame);
        let names = self.save_names(frame);
        let saved = (!names.is_empty()).then(|| RgbImage {
            width: shown.width,
            height: shown.height,
            rgb: shown.rgb.clone(),
        });
        if let Some(at) = deadline {
            // A precise wait (tokio's timer has 1 ms steps), kept off the async workers' queue
            // so pixel intake goes on meanwhile.
            tokio::task::block_in_place(|| wait_until(at));
        }
        let now = Instant::now();
        if let Some(w) = &self.window {
            let overlay = self.overlay.then(|| self.overlay_of(&sources, now));
            // Reported once the window has really presented it.
            w.send(WindowCommand::Show(WindowFrame {
                frame: frame.0,
                width: shown.width,
                height: shown.height,
                rgb: shown.rgb,
                overlay,
            }));
        } else {
            let clock_ns = tessera_net::unix_ns();
            link.send(&FromNode::Presented { frame, clock_ns }).await?;
        }
        self.present_times.push_back(now);
        while self.present_times.len() > 64 {
            self.present_times.pop_front();
        }
        if let (Some(image), Some(dir)) = (saved, &self.out) {
            let paths: Vec<_> = names.iter().map(|n| dir.join(n)).collect();
            tokio::task::spawn_blocking(move || paths.iter().try_for_each(|p| image.save_png(p)))
                .await??;
        }
        Ok(())
    }

    /// The files `frame` is saved as: the session's frame, and snapshots asked for.
    fn save_names(&mut self, frame: FrameId) -> Vec<String> {
        let mut names = Vec::new();
        if self.save_frame == Some(frame) {
            names.push(format!("display-{}.png", self.me.0));
        }
        if let Some(i) = self.snapshots.iter().position(|&f| f == frame) {
            self.snapshots.swap_remove(i);
            names.push(format!("display-{}-frame-{}.png", self.me.0, frame.0));
        }
        names
    }

    fn overlay_of(&self, sources: &BTreeMap<TileId, BatchSource>, now: Instant) -> Overlay {
        let last = self.present_times.back().copied();
        let frame_ms = last.map_or(0.0, |t| now.duration_since(t).as_secs_f32() * 1000.0);
        let window = self.present_times.front().map(|t| now.duration_since(*t));
        let fps = match window {
            Some(span) if !span.is_zero() => self.present_times.len() as f32 / span.as_secs_f32(),
            _ => 0.0,
        };
        let tiles = sources
            .iter()
            .filter_map(|(id, source)| {
                let t = self.grid.tile(*id)?;
                Some(TileInfo {
                    x: t.x - self.screen.x,
                    y: t.y - self.screen.y,
                    width: t.width,
                    height: t.height,
                    node: source.node.0,
                    ms: source.render_us as f32 / 1000.0,
                })
            })
            .collect();
        Overlay {
            fps,
            frame_ms,
            tiles,
        }
    }
}
