//! The operator's console: a web page and a REST/JSON API served by the master, over the
//! same control path as `tessera-master control` (each request becomes a `ControlRequest`
//! answered by the sans-IO master in its driver loop, checked the same way).
//!
//! The driver and the web server share a [`Bridge`]: requests go to the driver through a
//! bounded queue, each with its answer's channel; what the browser watches (status, figures,
//! the wall's picture) comes back through `watch` channels, which keep only the newest value,
//! so a slow or dead browser never holds the wall up.

mod api;
pub mod credentials;
pub mod json;
mod openapi;
mod picture;
pub mod tls;

use anyhow::{Context, Result};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tessera_core::master::ConsoleEvent;
use tessera_model::camera::CameraMode;
use tessera_model::wall::WallLayout;
use tessera_protocol::control::{ControlReply, ControlRequest, LiveFigures};
use tokio::sync::{broadcast, mpsc, oneshot, watch};

pub use picture::WallPicture;

/// Requests waiting for the driver at most; more are refused with 503.
const CALL_QUEUE: usize = 64;

/// Widest the console's picture of the whole wall is, in pixels.
pub const PICTURE_WIDTH: u32 = 1280;

/// How often the driver publishes the status and figures, and asks for thumbnails.
pub const TICK: Duration = Duration::from_millis(250);

/// A volume's histogram, computed once when the scene is loaded.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Histogram {
    /// The smallest and largest finite value.
    pub range: [f32; 2],
    /// Voxels in each of the equal bins between them.
    pub counts: Vec<u64>,
}

impl Histogram {
    /// The histogram of `values` in `bins` bins; NaN and infinite values are left out.
    pub fn of(values: &[f32], bins: usize) -> Option<Histogram> {
        let finite = values.iter().copied().filter(|v| v.is_finite());
        let (lo, hi) = finite.fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
        if lo > hi || bins == 0 {
            return None;
        }
        let mut counts = vec![0u64; bins];
        let scale = if hi > lo {
            bins as f64 / (hi as f64 - lo as f64)
        } else {
            0.0
        };
        for v in values.iter().filter(|v| v.is_finite()) {
            let bin = ((*v as f64 - lo as f64) * scale) as usize;
            counts[bin.min(bins - 1)] += 1;
        }
        Some(Histogram {
            range: [lo, hi],
            counts,
        })
    }
}

/// What a console serves besides the wall itself.
#[derive(Clone, Debug)]
pub struct ConsoleConfig {
    /// Where it listens.
    pub bind: SocketAddr,
    /// The secret a browser or script shows (in the page's address once, then a cookie, or
    /// as `Authorization: Bearer`).
    pub token: String,
    /// Where the displays save snapshots and the master puts them together.
    pub out: Option<PathBuf>,
    /// The volume's histogram, if there is a volume.
    pub histogram: Option<Histogram>,
    /// The wall.
    pub wall: WallLayout,
    /// The camera the wall started with, for "orbit".
    pub home: CameraMode,
}

/// A new random token: 32 hex digits from the system's random source.
pub fn new_token() -> Result<String> {
    use std::io::Read;
    let mut bytes = [0u8; 16];
    std::fs::File::open("/dev/urandom")
        .and_then(|mut f| f.read_exact(&mut bytes))
        .context("cannot read /dev/urandom for the console's token")?;
    Ok(bytes.iter().map(|b| format!("{b:02x}")).collect())
}

/// A request for the driver, and where its answer goes.
pub struct Call {
    pub request: ControlRequest,
    pub reply: oneshot::Sender<ControlReply>,
}

/// A recording to start (into `start`) or stop (`None`), and where its answer goes: the
/// file being written, or why not.
pub struct RecordCall {
    pub start: Option<PathBuf>,
    pub reply: oneshot::Sender<Result<Option<PathBuf>, String>>,
}

/// What the browser watches, published by the driver every [`TICK`].
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Live {
    pub status: Option<json::StatusView>,
    pub figures: Option<LiveFigures>,
}

/// A snapshot every display wrote (or failed to), and the files there are.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SnapshotDone {
    pub frame: u64,
    pub files: Vec<PathBuf>,
    pub failed_displays: Vec<u32>,
}

/// What the web server's handlers share.
#[derive(Clone)]
pub struct Shared {
    calls: mpsc::Sender<Call>,
    records: mpsc::Sender<RecordCall>,
    live: watch::Receiver<Live>,
    picture: Arc<Mutex<WallPicture>>,
    picture_frame: watch::Receiver<u64>,
    snapshots: broadcast::Sender<SnapshotDone>,
    cfg: Arc<ConsoleConfig>,
    /// Where recordings go and replayed sessions come from.
    sessions: PathBuf,
}

/// The driver's side of the console.
pub struct Bridge {
    /// Requests from the web server.
    calls: mpsc::Receiver<Call>,
    /// Recordings to start or stop.
    records: mpsc::Receiver<RecordCall>,
    live: watch::Sender<Live>,
    picture: Arc<Mutex<WallPicture>>,
    picture_frame: watch::Sender<u64>,
    snapshots: broadcast::Sender<SnapshotDone>,
    cfg: Arc<ConsoleConfig>,
    /// Frames presented when thumbnails were last asked for, and when.
    asked: Option<(u64, bool, Instant)>,
}

/// A console listening on `cfg.bind`, over HTTPS with `tls`'s certificate if given: its
/// bridge for the driver, and the address it got.
///
/// # Errors
/// The address cannot be bound, or the certificate cannot serve HTTPS.
pub async fn start(
    cfg: ConsoleConfig,
    tls: Option<&tessera_net::cluster::NodeIdentity>,
) -> Result<(Bridge, SocketAddr)> {
    let listener = tokio::net::TcpListener::bind(cfg.bind)
        .await
        .with_context(|| format!("cannot listen for the console on {}", cfg.bind))?;
    let addr = listener.local_addr()?;
    let cfg = Arc::new(cfg);
    let (calls_tx, calls) = mpsc::channel(CALL_QUEUE);
    let (records_tx, records) = mpsc::channel(4);
    let (live_tx, live_rx) = watch::channel(Live::default());
    let (frame_tx, frame_rx) = watch::channel(0);
    let (snapshots, _) = broadcast::channel(16);
    let picture = Arc::new(Mutex::new(WallPicture::new(&cfg.wall, 1)));
    let shared = Shared {
        calls: calls_tx,
        records: records_tx,
        live: live_rx,
        picture: picture.clone(),
        picture_frame: frame_rx,
        snapshots: snapshots.clone(),
        sessions: cfg.out.clone().unwrap_or_else(|| PathBuf::from(".")),
        cfg: cfg.clone(),
    };
    let app = api::router(shared);
    match tls {
        Some(identity) => {
            let listener = tls::listen(listener, identity)?;
            let service = app.into_make_service_with_connect_info::<tls::TlsPeer>();
            tokio::spawn(async move {
                if let Err(e) = axum::serve(listener, service).await {
                    tracing::error!("the console stopped serving: {e}");
                }
            });
        }
        None => {
            tokio::spawn(async move {
                if let Err(e) = axum::serve(listener, app).await {
                    tracing::error!("the console stopped serving: {e}");
                }
            });
        }
    }
    let bridge = Bridge {
        calls,
        records,
        live: live_tx,
        picture,
        picture_frame: frame_tx,
        snapshots,
        cfg,
        asked: None,
    };
    Ok((bridge, addr))
}

/// A request of the web server for the driver.
pub enum Incoming {
    /// A control request.
    Call(Call),
    /// A recording to start or stop.
    Record(RecordCall),
}

impl Bridge {
    /// The next request of the web server; `None` once it is gone.
    pub async fn next(&mut self) -> Option<Incoming> {
        tokio::select! {
            Some(call) = self.calls.recv() => Some(Incoming::Call(call)),
            Some(call) = self.records.recv() => Some(Incoming::Record(call)),
            else => None,
        }
    }

    /// Publishes the status and figures; whether to ask the displays for thumbnails now
    /// (something new was presented, or the wall just came to rest, or a while has passed).
    pub fn publish(&mut self, status: ControlReply, figures: ControlReply) -> bool {
        let status = match status {
            ControlReply::Status(s) => Some(json::StatusView::of(&s, &self.cfg.wall)),
            _ => None,
        };
        let figures = match figures {
            ControlReply::Figures(f) => Some(f),
            _ => None,
        };
        let presented = figures.as_ref().map_or(0, |f| f.frames_presented);
        let idle = figures.as_ref().is_some_and(|f| f.idle);
        let live = Live { status, figures };
        self.live.send_if_modified(|old| {
            let changed = *old != live;
            *old = live;
            changed
        });
        let now = Instant::now();
        let ask = match self.asked {
            None => presented > 0,
            Some((p, i, at)) => p != presented || i != idle || now - at > Duration::from_secs(5),
        };
        if ask {
            self.asked = Some((presented, idle, now));
        }
        ask
    }

    /// Carries out a console event of the master: a thumbnail into the picture, a snapshot
    /// put together as `wall-frame-<K>.png` and announced.
    pub fn handle(&mut self, event: ConsoleEvent, factor: u32) {
        match event {
            ConsoleEvent::Thumbnail(display, thumbnail) => {
                let frame = {
                    let mut picture = self.picture.lock().unwrap_or_else(|e| e.into_inner());
                    if picture.factor() != factor {
                        *picture = WallPicture::new(&self.cfg.wall, factor);
                    }
                    picture.place(display, &thumbnail);
                    picture.version()
                };
                self.picture_frame.send_replace(frame);
            }
            ConsoleEvent::SnapshotSaved { frame, displays } => {
                let cfg = self.cfg.clone();
                let snapshots = self.snapshots.clone();
                tokio::task::spawn_blocking(move || {
                    let done = assemble(&cfg, frame.0, &displays);
                    let _ = snapshots.send(done);
                });
            }
        }
    }
}

/// Puts a snapshot's display images together, where they are on this host.
fn assemble(
    cfg: &ConsoleConfig,
    frame: u64,
    displays: &[(tessera_model::wall::DisplayId, bool)],
) -> SnapshotDone {
    let failed_displays: Vec<u32> = displays.iter().filter(|d| !d.1).map(|d| d.0 .0).collect();
    let mut files = Vec::new();
    if let Some(dir) = &cfg.out {
        for (d, _) in displays.iter().filter(|d| d.1) {
            let path = dir.join(format!("display-{}-frame-{frame}.png", d.0));
            if path.exists() {
                files.push(path);
            }
        }
        match crate::wall_run::write_snapshot_png(dir, &cfg.wall, frame) {
            Ok(Some(path)) => files.push(path),
            Ok(None) => {}
            Err(e) => tracing::error!("cannot put snapshot {frame} together: {e:#}"),
        }
    }
    SnapshotDone {
        frame,
        files,
        failed_displays,
    }
}
