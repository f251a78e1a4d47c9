//! The display node: receives the pixels of its own screen from the render nodes, assembles
//! each frame, and presents it only when the master says so (the swap barrier), headless or in
//! a window.
//!
//! What it does with each message and tile of a session is the sans-IO
//! [`tessera_core::node::display::DisplaySession`] (frames assembled by
//! [`tessera_core::assemble::FrameAssembler`]); the driver loop (`node`) only moves bytes and
//! reads clocks for it, and the loop that rejoins a lost master is `tessera_net::reconnect`.
//!
//! A library with a thin binary, so that `tessera-master` can run the same node from its own
//! executable (`tessera-master display-node ...`, what `local` starts) and the installed
//! `tessera-display-node` stays for display hosts. It never compiles the renderer: a test in
//! `tests/` checks that `tessera-render` is not in its dependency tree.

#![warn(missing_docs)]

mod legend;
mod node;
pub mod overlay;
mod pixels_in;
mod present;
pub mod still;
pub mod window;

use anyhow::{bail, Result};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use tessera_model::input::InputEvent;
use tessera_model::window::WindowPlacement;
use tokio::sync::mpsc;
use window::{window_presenter, WindowCallbacks, WindowSender};

/// Tessera display node: shows one screen of the wall.
#[derive(clap::Parser, Clone, Debug)]
#[command(version, about, long_about = None)]
pub struct Cli {
    /// The master's address, HOST:PORT; or a comma-separated list, A,B: a primary and its
    /// standby (`tessera-master serve --standby-of`). The node joins the first that answers;
    /// a master lost or silent for --failover-after is left for the next of the list, round
    /// it, for up to --reconnect-timeout (a list waits so without --reconnect too), and one of
    /// an older term than the node has followed is refused. The window keeps the last frame
    /// meanwhile.
    #[arg(long, value_name = "ADDR[,ADDR...]")]
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
    /// With --window, seconds to keep the last frame on screen after the run (0 to 3600).
    #[arg(long, default_value_t = 0.0, value_parser = parse_linger)]
    linger: f64,
    /// With --window, where its top-left corner goes on the desktop, X,Y (default: the wall
    /// file's placement, else the window manager's choice).
    #[arg(long, value_parser = parse_position, allow_hyphen_values = true)]
    window_pos: Option<(i32, i32)>,
    /// With --window, its inner size WxH; the frame is scaled to it (default: the screen's
    /// resolution, pixel for pixel).
    #[arg(long, value_parser = parse_window_size)]
    window_size: Option<(u32, u32)>,
    /// With --window, borderless full screen on monitor N (0: the first), the frame scaled.
    #[arg(long, num_args = 0..=1, default_missing_value = "0")]
    fullscreen: Option<u32>,
    /// Directory for `display-<id>.png` when the master asks to save a frame.
    #[arg(long)]
    out: Option<PathBuf>,
    #[command(flatten)]
    reconnect: tessera_cli::reconnect::ReconnectArgs,
}

/// Longest `--linger`: an hour is a demo; more is a typo.
pub const MAX_LINGER_S: f64 = 3600.0;

/// Parses `--linger` seconds, 0 to [`MAX_LINGER_S`].
pub fn parse_linger(text: &str) -> Result<f64, String> {
    match text.trim().parse::<f64>() {
        Ok(s) if (0.0..=MAX_LINGER_S).contains(&s) => Ok(s),
        _ => Err(format!(
            "`{text}` is not a number of seconds from 0 to {MAX_LINGER_S}"
        )),
    }
}

/// Parses a window position `X,Y` (whole numbers, negative allowed).
pub fn parse_position(text: &str) -> Result<(i32, i32), String> {
    let bad = || format!("`{text}` is not X,Y (two whole numbers)");
    let (x, y) = text.split_once(',').ok_or_else(bad)?;
    Ok((
        x.trim().parse().map_err(|_| bad())?,
        y.trim().parse().map_err(|_| bad())?,
    ))
}

fn parse_window_size(text: &str) -> Result<(u32, u32), String> {
    tessera_model::wall::parse_size(text).map_err(|e| e.to_string())
}

impl Cli {
    /// The window's placement: these flags, else the session's (from the wall file).
    fn placement(&self, from_session: Option<WindowPlacement>) -> Result<WindowPlacement> {
        let base = from_session.unwrap_or_default();
        let placement = WindowPlacement {
            position: self.window_pos.or(base.position),
            size: self.window_size.or(base.size),
            fullscreen: self.fullscreen.or(base.fullscreen),
        };
        placement.check()?;
        Ok(placement)
    }
}

/// Runs the display node and turns the outcome into the process's exit code, printing the
/// error (with its causes) if there is one.
pub fn main(cli: Cli) -> ExitCode {
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("tessera-display-node: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// Runs the display node until the master shuts the wall down.
///
/// With `--window` this must be called on the main thread: winit allows one event loop per
/// process, there.
///
/// # Errors
/// A master that cannot be reached, refuses the display or is lost; a window that closes
/// while the wall runs.
pub fn run(cli: Cli) -> Result<()> {
    if cli.window {
        run_with_window(cli)
    } else {
        tessera_net::link::node_runtime()?.block_on(node::run(cli, None))
    }
}

/// Set when the run is over and the network side itself closes the window.
static WALL_OVER: AtomicBool = AtomicBool::new(false);

/// winit wants the main thread, so the network side runs on a thread of its own.
fn run_with_window(cli: Cli) -> Result<()> {
    // The window is sized and placed once the master says how big a screen is and where the
    // wall file puts it, so the network side goes first and hands that over.
    let (size_tx, size_rx) = std::sync::mpsc::channel::<((u32, u32), WindowPlacement)>();
    let (sender_tx, sender_rx) = std::sync::mpsc::channel::<WindowSender>();
    // Presents are stamped on the main thread right after softbuffer's present(), and input as
    // it happens; the stamps travel to the network side, which reports them to the master.
    let (presented_tx, presented_rx) = mpsc::unbounded_channel::<(u64, u64)>();
    let (input_tx, input_rx) = mpsc::unbounded_channel::<(InputEvent, u64)>();
    let display = cli.display;
    let net = std::thread::spawn(move || -> Result<()> {
        let rt = tessera_net::link::node_runtime()?;
        rt.block_on(node::run(
            cli,
            Some(node::WindowHandshake {
                size: size_tx,
                sender: sender_rx,
                presents: presented_rx,
                inputs: input_rx,
            }),
        ))
    });
    let Ok((size, placement)) = size_rx.recv() else {
        return net
            .join()
            .map_err(|_| anyhow::anyhow!("network thread panicked"))?;
    };
    let (sender, runner) = window_presenter(
        format!("Tessera display {display}"),
        size,
        placement,
        WindowCallbacks {
            on_presented: Box::new(move |frame| {
                let _ = presented_tx.send((frame, tessera_net::unix_ns()));
            }),
            on_input: Box::new(move |event| {
                let _ = input_tx.send((event, tessera_net::unix_ns()));
            }),
        },
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
