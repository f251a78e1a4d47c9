//! The display node's driver loop: the only place in the display node with sockets and clock
//! reads. It moves bytes and reads clocks: the master's messages and the tiles the render
//! nodes send go to the sans-IO [`DisplaySession`], and the driver carries out what it
//! returns: messages to the master, presents (at their deadline, headless or in the window),
//! saved frames, answers to clock probes, the shutdown. It forwards the window's presents and
//! the person's input to the master. Heartbeats are the link's, sent whatever this loop is
//! doing. Losing the master and joining it again is `tessera_net::reconnect`'s loop.

use crate::pixels_in::{accept_render_nodes, IncomingTile, Intake};
use crate::present::wait_until;
use crate::window::{WindowCommand, WindowFrame, WindowSender};
use crate::{Cli, WALL_OVER};
use anyhow::{Context, Result};
use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tessera_cli::png::PngFile;
use tessera_core::node::display::{DisplayEvent, DisplaySession, PresentOrder};
use tessera_core::node::term::MasterTerm;
use tessera_model::image::RgbImage;
use tessera_model::input::InputEvent;
use tessera_model::wall::{DisplayId, ScreenRect, TileGrid};
use tessera_model::window::WindowPlacement;
use tessera_net::cluster::NodeIdentity;
use tessera_net::link::{LinkError, MasterLink, Welcome};
use tessera_net::quic;
use tessera_net::reconnect::Reconnect;
use tessera_net::sd_notify;
use tessera_protocol::{DisplayStats, FrameId, FromNode, NodeStats, Role, ToNode};
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
    let masters = tessera_net::reconnect::resolve_masters(&cli.master).await?;
    let mut reconnect = Reconnect::new(
        endpoint.clone(),
        masters,
        Role::Display {
            display: me,
            pixel_addr,
        },
        cli.reconnect.wait(),
        format!("display {}", me.0),
    );
    reconnect.failover_after = cli.reconnect.failover_after();
    let first = reconnect
        .join()
        .await
        .with_context(|| format!("display {} could not join", me.0))
        .context("is tessera-master running there? see --help")?;
    let mut window = window.map_or(WindowState::Headless, WindowState::ToOpen);
    let mut term = MasterTerm::default();
    reconnect
        .run(first, async |link, welcome| {
            if let Err(stale) = term.admit(welcome.term) {
                tracing::warn!("display {}: {stale}; trying the next master", me.0);
                link.refuse_stale(&stale.message()).await;
                return Err(LinkError::StaleMaster(stale.to_string()).into());
            }
            session(&cli, &endpoint, link, welcome, &mut window).await
        })
        .await
}

/// Opens the window at the first session's screen size; a later master must give the same.
async fn open_window(
    cli: &Cli,
    state: &mut WindowState,
    session: &tessera_protocol::Session,
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
    let (window, window_io) = match window_state {
        WindowState::Open(open) => (
            Some(open.sender.clone()),
            Some((&mut open.presents, &mut open.inputs)),
        ),
        _ => (None, None),
    };
    let grid = Arc::new(TileGrid::new(session.wall().clone()));
    let intake = Arc::new(Intake::default());
    let (tiles_tx, tiles) = mpsc::channel(1024);
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
    let mut driver = Driver {
        session: DisplaySession::new(grid, screen, session.save_frame())
            .with_particle_range(session.particle_range()),
        me,
        window,
        out: cli.out.clone(),
        last_shown: None,
        started: false,
    };
    driver.drive(&mut link, tiles, window_io).await?;
    let stats = DisplayStats {
        pixel_bytes_received: intake.pixel_bytes.load(Ordering::Relaxed),
        wire_bytes_received: intake.wire_bytes(),
        stream_bytes_received: intake.stream_bytes.load(Ordering::Relaxed),
        ..driver.session.stats()
    };
    link.finish(NodeStats::Display(stats)).await?;
    if let Some(w) = &driver.window {
        tokio::time::sleep(Duration::from_secs_f64(cli.linger)).await;
        WALL_OVER.store(true, Ordering::SeqCst);
        w.send(WindowCommand::Close);
    }
    endpoint.close(0u32.into(), b"done");
    let presented = driver.session.presented();
    tracing::info!("display {}: done, {presented} frames presented", me.0);
    Ok(())
}

/// The window's reports: (frame, clock) of each present it did, (event, clock) of each input.
type WindowIo<'a> = (
    &'a mut mpsc::UnboundedReceiver<(u64, u64)>,
    &'a mut mpsc::UnboundedReceiver<(InputEvent, u64)>,
);

/// A session's sockets, window and files around its [`DisplaySession`].
struct Driver {
    session: DisplaySession,
    me: DisplayId,
    window: Option<WindowSender>,
    /// Where frames are saved.
    out: Option<PathBuf>,
    /// The frame shown now: what a still wall's snapshot, overlay and thumbnail are of.
    last_shown: Option<(FrameId, RgbImage)>,
    /// Whether a frame started in this session.
    started: bool,
}

impl Driver {
    /// Moves messages, tiles, window reports and timers between the session and the world
    /// until the master shuts the wall down.
    async fn drive(
        &mut self,
        link: &mut MasterLink,
        mut tiles: mpsc::Receiver<IncomingTile>,
        window: Option<WindowIo<'_>>,
    ) -> Result<()> {
        let (mut presents, mut inputs) = window.unzip();
        loop {
            self.transmit(link).await?;
            if self.events(link).await? {
                return Ok(());
            }
            tokio::select! {
                // The master's messages first: a Present waiting behind a burst of tiles would
                // let tiles of later frames be judged against a stale frame count, and refused.
                biased;
                msg = link.recv() => self.message(msg?)?,
                Some((frame, clock_ns)) = async { presents.as_mut()?.recv().await } => {
                    link.send(&FromNode::Presented { frame: FrameId(frame), clock_ns }).await?;
                }
                Some((event, clock_ns)) = async { inputs.as_mut()?.recv().await } => {
                    tracing::debug!("display {}: input {event:?} to the master", self.me.0);
                    link.send(&FromNode::Input { event, clock_ns }).await?;
                }
                Some(tile) = tiles.recv() => self.tile(tile),
            }
        }
    }

    /// Hands the master's message to the session. A session's first frame need not be 0: a
    /// standby that took the wall over starts at its horizon, so the first `FrameStart` of a
    /// session is where this display starts.
    fn message(&mut self, msg: ToNode) -> Result<()> {
        if let ToNode::FrameStart(start) = &msg {
            if !self.started {
                self.started = true;
                let frame = start.frame;
                self.session.handle_message(ToNode::StartAt { frame })?;
            }
        }
        self.session.handle_message(msg)?;
        Ok(())
    }

    fn tile(&mut self, tile: IncomingTile) {
        let IncomingTile {
            frame,
            state,
            source,
            tile: id,
            rgb,
            conn,
        } = tile;
        if let Err(e) = self.session.handle_tile(frame, state, id, &rgb, source) {
            tracing::error!(
                "display {}: closing a render node's connection: {e}",
                self.me.0
            );
            conn.close(3u32.into(), b"bad tile");
        }
    }

    async fn transmit(&mut self, link: &mut MasterLink) -> Result<(), LinkError> {
        while let Some(msg) = self.session.poll_transmit() {
            link.send(&msg).await?;
        }
        Ok(())
    }

    /// Carries out what the session asks besides messages; true once the master shut the
    /// wall down.
    async fn events(&mut self, link: &mut MasterLink) -> Result<bool> {
        while let Some(event) = self.session.poll_event() {
            match event {
                DisplayEvent::Present(order) => self.present(order, link).await?,
                DisplayEvent::Pong { seq } => {
                    let clock_ns = tessera_net::unix_ns();
                    link.send(&FromNode::Pong { seq, clock_ns }).await?;
                }
                DisplayEvent::Shutdown => return Ok(true),
                DisplayEvent::SaveShown { frame, name } => {
                    let ok = match &self.last_shown {
                        Some((_, image)) => self.save(image.clone(), vec![name]).await,
                        None => false,
                    };
                    link.send(&FromNode::Saved { frame, ok }).await?;
                }
                DisplayEvent::Thumbnail { factor } => {
                    let thumbnail = match &self.last_shown {
                        Some((frame, image)) => crate::still::thumbnail(*frame, image, factor),
                        None => Default::default(),
                    };
                    link.send(&FromNode::Thumbnail(thumbnail)).await?;
                }
                DisplayEvent::Redraw => self.redraw(),
            }
        }
        Ok(false)
    }

    /// The swap barrier: shows the frame (at the deadline, if the master gave one), saves it
    /// where asked, and reports the present.
    async fn present(&mut self, order: PresentOrder, link: &mut MasterLink) -> Result<()> {
        if let Some(at) = order.deadline {
            // A precise wait (tokio's timer has 1 ms steps), kept off the async workers' queue
            // so pixel intake goes on meanwhile.
            tokio::task::block_in_place(|| wait_until(at));
        }
        let overlay = self.session.handle_shown(&order, Instant::now());
        let (shown, names, snapshot) = (order.shown, order.save_as, order.snapshot);
        let frame = shown.frame;
        // Kept as the frame shown now (a still wall's snapshot, overlay and thumbnail): the
        // window gets a copy, a headless display none.
        let image = RgbImage {
            width: shown.width,
            height: shown.height,
            rgb: shown.rgb,
        };
        if let Some(w) = &self.window {
            // Reported once the window has really presented it.
            w.send(WindowCommand::Show(WindowFrame {
                frame: frame.0,
                width: image.width,
                height: image.height,
                rgb: image.rgb.clone(),
                overlay,
                status: self.session.status_of(frame),
            }));
        } else {
            let clock_ns = tessera_net::unix_ns();
            link.send(&FromNode::Presented { frame, clock_ns }).await?;
        }
        if !names.is_empty() {
            let ok = self.save(image.clone(), names).await;
            if snapshot {
                link.send(&FromNode::Saved { frame, ok }).await?;
            }
        }
        self.last_shown = Some((frame, image));
        Ok(())
    }

    /// Saves `image` under each of `names` in the `--out` folder; whether every file was
    /// written (a failure is logged: the wall goes on).
    async fn save(&self, image: RgbImage, names: Vec<String>) -> bool {
        let Some(dir) = &self.out else {
            tracing::warn!(
                "display {}: asked to save {names:?}, but it was started without --out",
                self.me.0
            );
            return false;
        };
        let paths: Vec<_> = names.iter().map(|n| dir.join(n)).collect();
        let written =
            tokio::task::spawn_blocking(move || paths.iter().try_for_each(|p| image.save_png(p)))
                .await;
        match written {
            Ok(Ok(())) => true,
            Ok(Err(e)) => {
                tracing::error!("display {}: cannot save {names:?}: {e}", self.me.0);
                false
            }
            Err(e) => {
                tracing::error!("display {}: saving {names:?} failed: {e}", self.me.0);
                false
            }
        }
    }

    /// Shows the frame shown now again, with the overlay as it is now.
    fn redraw(&self) {
        let (Some(w), Some((frame, image))) = (&self.window, &self.last_shown) else {
            return;
        };
        w.send(WindowCommand::Show(WindowFrame {
            frame: frame.0,
            width: image.width,
            height: image.height,
            rgb: image.rgb.clone(),
            overlay: self.session.overlay_now(Instant::now()),
            status: self.session.status_of(*frame),
        }));
    }
}
