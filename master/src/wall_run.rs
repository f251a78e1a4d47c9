//! Running a wall: `local` (every node a child process on 127.0.0.1, started from this very
//! executable) and `serve` (nodes started by hand on other hosts), then the report and the
//! wall image.

use crate::args::{prepare_run, LocalArgs, RunArgs, ServeArgs};
use crate::launcher::{reap, spawn, watch, NodeKind, NodeProcess};
use crate::outcome::{exit_code, write_report, Ended};
use crate::report;
use crate::server::{bind, run_wall, RunSignals};
use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Duration;
use tessera_cli::png::PngFile;
use tessera_model::image::{compose_wall, RgbImage};
use tessera_model::wall::WallLayout;
use tessera_net::cluster::{CertRole, ClusterCa, NodeIdentity};

pub fn stop_on_ctrl_c() -> (tokio::sync::watch::Receiver<bool>, Arc<AtomicBool>) {
    let (tx, rx) = tokio::sync::watch::channel(false);
    let interrupted = Arc::new(AtomicBool::new(false));
    let flag = interrupted.clone();
    tokio::spawn(async move {
        let mut term =
            tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()).ok();
        tokio::select! {
            _ = tokio::signal::ctrl_c() => {}
            _ = async { match term.as_mut() { Some(t) => { t.recv().await; } None => std::future::pending().await } } => {}
        }
        flag.store(true, std::sync::atomic::Ordering::SeqCst);
        let _ = tx.send(true);
    });
    (rx, interrupted)
}

pub async fn local(args: LocalArgs) -> Result<ExitCode> {
    let run = run_local(&args, true).await?;
    finish_run(run.ended, &args.run, &run.wall)
}

/// What a local wall run gave: how it ended (its figures, its error, the node processes that
/// failed) and its wall.
pub struct LocalRun {
    pub ended: Ended,
    pub wall: WallLayout,
}

/// Starts the display and render nodes of `args` as child processes, runs the wall, and reaps
/// every child before returning.
pub async fn run_local(args: &LocalArgs, show_progress: bool) -> Result<LocalRun> {
    run_local_driven(args, show_progress, None).await
}

/// Something to run beside a local wall, as a control client would: it is given the master's
/// address and a control certificate's directory, and is stopped when the wall ends.
pub type Driver = Box<
    dyn FnOnce(
            String,
            PathBuf,
        ) -> std::pin::Pin<Box<dyn std::future::Future<Output = Result<()>> + Send>>
        + Send,
>;

/// How long a node of a local wall may pause past its rhythm before it is dead (see
/// `--acceptable-pause-ms`): twice a served wall's, as its processes share the cores.
const LOCAL_ACCEPTABLE_PAUSE: Duration = Duration::from_secs(6);

/// [`run_local`], with `driver` steering the wall while it runs.
pub async fn run_local_driven(
    args: &LocalArgs,
    show_progress: bool,
    driver: Option<Driver>,
) -> Result<LocalRun> {
    if args.render_nodes == 0 {
        bail!("--render-nodes must be at least 1");
    }
    let mut cfg = prepare_run(&args.run, args.render_nodes, show_progress)?;
    if cfg.master.windows.is_empty() {
        // One desktop holds every window of a local wall: side by side, not on top.
        cfg.master.windows = tessera_model::window::side_by_side(
            &cfg.master.wall,
            args.window_origin,
            args.fullscreen_all,
        );
    }
    if args.run.acceptable_pause_ms.is_none() {
        // Every process of a local wall shares this machine's cores: pauses are the norm.
        cfg.master.balance.death.acceptable_pause = LOCAL_ACCEPTABLE_PAUSE;
    }
    // Every node runs from this very executable (`tessera-master display-node|render-node`),
    // so whatever built the master is enough for a local wall.
    let this = std::env::current_exe().context("cannot locate the running executable")?;
    let certs = LocalCerts::new()?;
    let identity = NodeIdentity::load(&certs.issue("master", CertRole::Master)?)?;
    let endpoint = bind("127.0.0.1:0".parse()?, &identity)?;
    let master_addr = endpoint.local_addr()?.to_string();
    // The control interface of this run: the same endpoint, with a certificate of its own.
    let control_dir = certs.issue("control", CertRole::Control)?;
    // Tests and scripts read this line for the explicit form; a person uses the shorter one
    // `start_console` prints next.
    eprintln!(
        "tessera-master: control with `tessera-master control --connect {master_addr} --cert-dir {}` (while the wall runs)",
        control_dir.display()
    );
    let (console, _written) = start_console(args, &cfg, &certs, &master_addr).await?;
    let nodes = Nodes {
        args,
        this: &this,
        master_addr: &master_addr,
        certs: &certs,
    };
    let mut children = nodes.spawn_displays(cfg.master.wall.display_count())?;
    children.extend(nodes.spawn_render_nodes()?);

    let (stop, interrupted) = stop_on_ctrl_c();
    let signals = RunSignals::default();
    let mut lost = Vec::new();
    let wall = cfg.master.wall.clone();
    let driving = driver.map(|d| tokio::spawn(d(master_addr.clone(), control_dir.clone())));
    let watching = watch(&mut children, signals.clone(), &mut lost);
    let end = run_wall(endpoint, cfg, signals, stop, watching, console).await;
    if let Some(task) = driving {
        task.abort();
    }
    // Windows stay up for --linger after the run; only then is a display late to exit.
    let grace = Duration::from_secs(5) + Duration::from_secs_f64(args.linger);
    let failures = reap(&mut children, grace).await;
    tracing::info!("every node process has exited");
    let interrupted = interrupted.load(std::sync::atomic::Ordering::SeqCst);
    let mut ended = Ended::of(end, interrupted);
    ended.processes_failed = lost.into_iter().chain(failures).collect();
    Ok(LocalRun { ended, wall })
}

/// A local wall's console (unless --no-console), and the file that lets a second terminal
/// find the wall, removed when the guard drops. A file that cannot be written is a warning:
/// the wall runs anyway, its control command printed in full.
async fn start_console(
    args: &LocalArgs,
    cfg: &crate::server::RunConfig,
    certs: &LocalCerts,
    master_addr: &str,
) -> Result<(
    Option<crate::console::Bridge>,
    Option<crate::console::credentials::Written>,
)> {
    use crate::console::{self, credentials};
    let (bridge, url, token) = if args.no_console {
        (None, None, None)
    } else {
        let token = console::new_token()?;
        let (bridge, addr) = console::start(
            console::ConsoleConfig {
                bind: args.console,
                token: token.clone(),
                out: args.run.out.clone(),
                histogram: cfg.histogram.clone(),
                wall: cfg.master.wall.clone(),
                home: cfg.master.camera,
            },
            None,
        )
        .await?;
        let url = format!("http://{addr}/?token={token}");
        eprintln!("tessera-master: console at {url}");
        (Some(bridge), Some(url), Some(token))
    };
    let written = credentials::local_paths().and_then(|(_, dir)| {
        certs.ca.issue("control", &dir, Some(CertRole::Control))?;
        credentials::LocalWall {
            connect: master_addr.to_string(),
            cert_dir: dir,
            console_url: url,
            token,
            pid: std::process::id(),
        }
        .write()
    });
    match written {
        Ok(w) => {
            eprintln!(
                "tessera-master: steer it from another terminal with `tessera-master control state` (it finds the wall in {})",
                w.path.display()
            );
            Ok((bridge, Some(w)))
        }
        Err(e) => {
            eprintln!("tessera-master: {e:#}: the control command needs --connect and --cert-dir");
            Ok((bridge, None))
        }
    }
}

/// A local wall's certificates: a new CA in a temporary directory, removed when dropped.
struct LocalCerts {
    dir: tempfile::TempDir,
    ca: ClusterCa,
}

impl LocalCerts {
    fn new() -> Result<LocalCerts> {
        let dir = tempfile::Builder::new()
            .prefix("tessera-local-")
            .tempdir()?;
        let ca = ClusterCa::open_or_create(&dir.path().join("ca"))?;
        Ok(LocalCerts { dir, ca })
    }

    /// The directory of a new certificate for `name` in `role`.
    fn issue(&self, name: &str, role: CertRole) -> Result<PathBuf> {
        let dir = self.dir.path().join(name);
        self.ca.issue(name, &dir, Some(role))?;
        Ok(dir)
    }

    /// The directory of a new certificate for display `display`.
    fn issue_display(&self, display: u32) -> Result<PathBuf> {
        let dir = self.dir.path().join(format!("display-{display}"));
        self.ca
            .issue_display(&format!("display-{display}"), &dir, display)?;
        Ok(dir)
    }
}

/// What starting a local wall's node processes takes.
struct Nodes<'a> {
    args: &'a LocalArgs,
    this: &'a Path,
    master_addr: &'a str,
    certs: &'a LocalCerts,
}

impl Nodes<'_> {
    /// Every child rejoins the master when it loses it, as a served wall's nodes started with
    /// `--reconnect` do: a child paused or starved long enough to be dropped (a busy machine,
    /// SIGSTOP) comes back instead of exiting. It waits as long as a node may take to join;
    /// a master that dies takes its children along anyway (`PR_SET_PDEATHSIG`).
    fn reconnect(&self) -> [String; 3] {
        [
            "--reconnect".into(),
            "--reconnect-timeout".into(),
            self.args.run.join_timeout.to_string(),
        ]
    }

    /// Starts display nodes 0..`displays`.
    fn spawn_displays(&self, displays: u32) -> Result<Vec<NodeProcess>> {
        let args = self.args;
        let mut children = Vec::new();
        for d in 0..displays {
            let mut a = vec![
                "display-node".into(),
                "--master".into(),
                self.master_addr.to_string(),
                "--display".into(),
                d.to_string(),
                "--cert-dir".into(),
                self.certs.issue_display(d)?.display().to_string(),
                "--listen".into(),
                "127.0.0.1:0".into(),
            ];
            a.extend(self.reconnect());
            if let Some(out) = &args.run.out {
                a.extend(["--out".into(), out.display().to_string()]);
            }
            if args.window {
                a.push("--window".into());
                a.extend(["--linger".into(), args.linger.to_string()]);
            }
            // Essential only if losing it ends the run.
            let essential = args.run.display_loss == crate::args::DisplayLoss::Stop;
            children.push(spawn(NodeKind::Display(d), essential, self.this, &a)?);
        }
        Ok(children)
    }

    /// Starts --render-nodes render nodes, the machine's cores shared among them unless
    /// --threads says otherwise.
    fn spawn_render_nodes(&self) -> Result<Vec<NodeProcess>> {
        let args = self.args;
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get() as u32);
        let threads = args.threads.unwrap_or((cores / args.render_nodes).max(1));
        let mut children = Vec::new();
        for r in 0..args.render_nodes {
            let name = format!("render-{r}");
            let mut a = vec![
                "render-node".into(),
                "--master".into(),
                self.master_addr.to_string(),
                "--cert-dir".into(),
                self.certs
                    .issue(&name, CertRole::Render)?
                    .display()
                    .to_string(),
                "--threads".into(),
                threads.to_string(),
            ];
            a.extend(self.reconnect());
            if let Some(mb) = args.volume_cache_mb {
                a.extend(["--volume-cache-mb".into(), mb.to_string()]);
            }
            let kind = NodeKind::Render { slot: r };
            children.push(spawn(kind, false, self.this, &a)?);
        }
        Ok(children)
    }
}

/// Writes the report (a failed run's too, with its error) and the wall image, and turns how
/// the run ended into an exit code: 0 for a run that completed, nodes lost on the way or not;
/// 130 interrupted; 1 for a run that did not complete or whose report could not be written.
pub(crate) fn finish_run(ended: Ended, run: &RunArgs, wall: &WallLayout) -> Result<ExitCode> {
    let outcome = ended.outcome();
    if let Some(report) = &ended.report {
        print_summary(report);
    }
    for problem in &outcome.processes_failed {
        eprintln!("tessera-master: {problem}");
    }
    let mut written = Ok(());
    if let Some(dir) = &run.out {
        match write_report(dir, &outcome, ended.report.as_ref()) {
            Ok(path) => eprintln!("wrote {}", path.display()),
            Err(e) => written = Err(e),
        }
        if ended.error.is_none() {
            if let Some(report) = &ended.report {
                write_images(dir, run, wall, report)?;
            }
        }
    }
    exit_code(&outcome, ended.error, written)
}

/// The run's figures in a few lines, and the nodes it lost and went on without.
fn print_summary(report: &report::Report) {
    eprintln!(
        "{} frames in {:.2} s: {:.1} fps, frame time p50 {:.1} ms, p95 {:.1} ms",
        report.frames, report.elapsed_s, report.fps, report.frame_ms.p50, report.frame_ms.p95
    );
    for d in &report.displays {
        eprintln!(
            "display {}: {} pixel bytes, {} wire bytes ({:.4} per pixel byte), {} frames presented",
            d.id,
            d.stats.pixel_bytes_received,
            d.stats.wire_bytes_received,
            d.wire_bytes_per_pixel_byte,
            d.stats.frames_presented
        );
    }
    for lost in &report.nodes_lost {
        eprintln!("lost {} during the run ({})", lost.node, lost.reason);
    }
}

/// The wall images of a run: the saved frame's, and each snapshot's.
fn write_images(
    dir: &Path,
    run: &RunArgs,
    wall: &WallLayout,
    report: &report::Report,
) -> Result<()> {
    if run.save_frame.is_some() {
        write_wall_png(dir, wall, "", "wall.png", false)?;
    }
    for &frame in &report.snapshots {
        // Put together as soon as the displays wrote theirs, when the console asked for it.
        if !dir.join(format!("wall-frame-{frame}.png")).exists() {
            write_snapshot_png(dir, wall, frame)?;
        }
    }
    Ok(())
}

/// A snapshot's `wall-frame-<frame>.png` from the displays' images, if any display saved one:
/// a snapshot of a frame the run never presented (it ended first) has no images; one that a
/// display away at the time (lost, or rejoining) did not show has a black screen.
pub(crate) fn write_snapshot_png(
    dir: &Path,
    wall: &WallLayout,
    frame: u64,
) -> Result<Option<PathBuf>> {
    let shown = |id: u32| dir.join(format!("display-{id}-frame-{frame}.png")).exists();
    if !wall.screens().any(|s| shown(s.id.0)) {
        return Ok(None);
    }
    let suffix = format!("-frame-{frame}");
    let name = format!("wall{suffix}.png");
    write_wall_png(dir, wall, &suffix, &name, true)?;
    Ok(Some(dir.join(name)))
}

/// `name`: the displays' saved images `display-<id><suffix>.png` put together, bezels black.
/// With `away_ok`, a display's missing image is a black screen (it did not show the frame),
/// said on stderr; without, it is an error.
fn write_wall_png(
    dir: &Path,
    wall: &WallLayout,
    suffix: &str,
    name: &str,
    away_ok: bool,
) -> Result<()> {
    let mut screens = Vec::new();
    for screen in wall.screens() {
        let path = dir.join(format!("display-{}{suffix}.png", screen.id.0));
        if !path.exists() && away_ok {
            eprintln!(
                "display {} did not show this frame (it was away): its screen is black in {name}",
                screen.id.0
            );
            screens.push((screen, RgbImage::black(screen.width, screen.height)));
            continue;
        }
        if !path.exists() {
            bail!(
                "{} is missing: {name} can only be assembled where the displays' --out directory is shared",
                path.display()
            );
        }
        screens.push((screen, RgbImage::load_png(&path)?));
    }
    let path = dir.join(name);
    compose_wall(wall, &screens)?.save_png(&path)?;
    eprintln!("wrote {}", path.display());
    Ok(())
}

/// A served wall's console, over HTTPS with the master's cluster certificate.
async fn serve_console(
    bind: std::net::SocketAddr,
    cfg: &crate::server::RunConfig,
    identity: &NodeIdentity,
    ca: &ClusterCa,
) -> Result<crate::console::Bridge> {
    use crate::console;
    let token = console::new_token()?;
    let config = console::ConsoleConfig {
        bind,
        token: token.clone(),
        out: None,
        histogram: cfg.histogram.clone(),
        wall: cfg.master.wall.clone(),
        home: cfg.master.camera,
    };
    let (bridge, addr) = console::start(config, Some(identity)).await?;
    eprintln!(
        "tessera-master: console at https://{addr}/?token={token} (its certificate is signed by the cluster CA in {}: import it in the browser, or accept the warning; a control certificate needs no token)",
        ca.dir().display()
    );
    Ok(bridge)
}

/// Follows the primary at `primary` as its standby (`serve --standby-of`) until it is gone:
/// the run to take over, or `None` when the primary's run ended without it.
async fn standby_of(
    primary: &str,
    endpoint: &quinn::Endpoint,
    identity: &NodeIdentity,
    failover_after: Duration,
) -> Result<Option<crate::server::TakeoverFrom>> {
    use crate::standby_link::{follow, Followed};
    let addr = tessera_net::resolve(primary)
        .await
        .with_context(|| format!("--standby-of {primary}"))?;
    eprintln!("tessera-master: standby of the master at {addr}");
    let cfg = tessera_core::master::standby::StandbyConfig {
        failure_bound: failover_after,
        ..Default::default()
    };
    match follow(endpoint, identity, addr, cfg).await? {
        Followed::RunOver => {
            eprintln!("tessera-master: the primary's run is over; the standby leaves");
            Ok(None)
        }
        Followed::TakeOver {
            snapshot,
            last_heard,
        } => {
            eprintln!("tessera-master: the primary at {addr} is gone; taking the wall over");
            Ok(Some(crate::server::TakeoverFrom {
                snapshot,
                last_heard,
            }))
        }
    }
}

pub async fn serve(args: ServeArgs) -> Result<ExitCode> {
    let cfg = prepare_run(&args.run, args.render_nodes, true)?;
    let ca = ClusterCa::open_or_create(&args.cluster_dir)?;
    let master_dir = args.cluster_dir.join("master");
    if !master_dir.join("node.pem").exists() {
        ca.issue("master", &master_dir, Some(CertRole::Master))?;
    }
    let identity = NodeIdentity::load(&master_dir)?;
    let endpoint = bind(args.listen, &identity)?;
    // Read back, not echoed: with port 0 the kernel picks the port, and scripts and tests
    // wait for this line to learn it.
    eprintln!("tessera-master: listening on {}", endpoint.local_addr()?);
    let mut cfg = cfg;
    if let Some(primary) = &args.standby_of {
        let bound = Duration::from_millis(args.failover_after);
        match standby_of(primary, &endpoint, &identity, bound).await? {
            Some(takeover) => cfg.takeover = Some(takeover),
            None => return Ok(ExitCode::SUCCESS),
        }
    }
    let console = match args.console {
        Some(bind) => Some(serve_console(bind, &cfg, &identity, &ca).await?),
        None => None,
    };
    let (stop, interrupted) = stop_on_ctrl_c();
    let wall = cfg.master.wall.clone();
    let signals = RunSignals::default();
    let end = run_wall(
        endpoint,
        cfg,
        signals,
        stop,
        std::future::pending(),
        console,
    )
    .await;
    let interrupted = interrupted.load(std::sync::atomic::Ordering::SeqCst);
    let ended = Ended::of(end, interrupted);
    finish_run(ended, &args.run, &wall)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_snapshot_a_display_missed_has_its_screen_black_and_wall_png_stays_strict() {
        let dir = tempfile::tempdir().unwrap();
        let wall = tessera_model::wall::WallSpec::grid(2, 1, 8, 4)
            .tile_size(4)
            .build()
            .unwrap();
        let shown = dir.path().join("display-0-frame-5.png");
        RgbImage::black(8, 4).save_png(&shown).unwrap();
        // Display 1 was away for frame 5 (lost, or rejoining): its screen is black.
        write_wall_png(dir.path(), &wall, "-frame-5", "wall-frame-5.png", true).unwrap();
        assert!(dir.path().join("wall-frame-5.png").exists());
        // The run's saved frame still needs every display's image.
        let strict = write_wall_png(dir.path(), &wall, "-frame-5", "wall.png", false);
        assert!(strict
            .unwrap_err()
            .to_string()
            .contains("display-1-frame-5.png is missing"));
    }
}
