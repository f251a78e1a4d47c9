//! Running a wall: `local` (every node a child process on 127.0.0.1, started from this very
//! executable) and `serve` (nodes started by hand on other hosts), then the report and the
//! wall image.

use crate::args::{prepare_run, LocalArgs, RunArgs, ServeArgs};
use crate::launcher::{reap, spawn, watch, NodeProcess};
use crate::report;
use crate::server::{bind, run_wall};
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
    finish_run(
        run.outcome,
        &args.run,
        &run.wall,
        run.interrupted,
        run.lost,
        run.failures,
    )
}

/// What a local wall run gave: the report (or why there is none) and which nodes failed.
pub struct LocalRun {
    pub outcome: Result<report::Report>,
    pub wall: WallLayout,
    pub interrupted: bool,
    pub lost: Vec<String>,
    pub failures: Vec<String>,
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
    eprintln!(
        "tessera-master: control with `tessera-master control --connect {master_addr} --cert-dir {}` (while the wall runs)",
        control_dir.display()
    );
    let nodes = Nodes {
        args,
        this: &this,
        master_addr: &master_addr,
        certs: &certs,
    };
    let mut children = nodes.spawn_displays(cfg.master.wall.display_count())?;
    children.extend(nodes.spawn_render_nodes()?);

    let (stop, interrupted) = stop_on_ctrl_c();
    let started = Arc::new(AtomicBool::new(false));
    let mut lost = Vec::new();
    let wall = cfg.master.wall.clone();
    let driving = driver.map(|d| tokio::spawn(d(master_addr.clone(), control_dir.clone())));
    let outcome = {
        let run = run_wall(endpoint, cfg, started.clone(), stop);
        tokio::pin!(run);
        tokio::select! {
            report = &mut run => report,
            err = watch(&mut children, started.clone(), &mut lost) => Err(err),
        }
    };
    if let Some(task) = driving {
        task.abort();
    }
    // Windows stay up for --linger after the run; only then is a display late to exit.
    let grace = Duration::from_secs(5) + Duration::from_secs_f64(args.linger);
    let failures = reap(&mut children, grace).await;
    tracing::info!("every node process has exited");
    Ok(LocalRun {
        outcome,
        wall,
        interrupted: interrupted.load(std::sync::atomic::Ordering::SeqCst),
        lost,
        failures,
    })
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
            if let Some(out) = &args.run.out {
                a.extend(["--out".into(), out.display().to_string()]);
            }
            if args.window {
                a.push("--window".into());
                a.extend(["--linger".into(), args.linger.to_string()]);
            }
            // Essential only if losing it ends the run.
            let essential = args.run.display_loss == crate::args::DisplayLoss::Stop;
            children.push(spawn(
                format!("display node {d}"),
                essential,
                self.this,
                &a,
            )?);
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
            if let Some(mb) = args.volume_cache_mb {
                a.extend(["--volume-cache-mb".into(), mb.to_string()]);
            }
            children.push(spawn(format!("render node {r}"), false, self.this, &a)?);
        }
        Ok(children)
    }
}

/// Writes the report and wall image and turns the run's outcome into an exit code.
pub(crate) fn finish_run(
    outcome: Result<report::Report>,
    run: &RunArgs,
    wall: &WallLayout,
    interrupted: bool,
    lost: Vec<String>,
    failures: Vec<String>,
) -> Result<ExitCode> {
    let report = outcome?;
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
    if let Some(dir) = &run.out {
        let path = dir.join("report.json");
        std::fs::write(&path, serde_json::to_string_pretty(&report)?)
            .with_context(|| format!("cannot write {}", path.display()))?;
        eprintln!("wrote {}", path.display());
        if run.save_frame.is_some() {
            write_wall_png(dir, wall, "", "wall.png")?;
        }
        for frame in &report.snapshots {
            // A snapshot of a frame the run never presented (it ended first) has no images.
            if dir.join(format!("display-0-frame-{frame}.png")).exists() {
                let suffix = format!("-frame-{frame}");
                write_wall_png(dir, wall, &suffix, &format!("wall{suffix}.png"))?;
            }
        }
    }
    if interrupted {
        eprintln!("tessera-master: interrupted");
        return Ok(ExitCode::from(130));
    }
    let problems: Vec<String> = lost.into_iter().chain(failures).collect();
    if !problems.is_empty() {
        bail!(
            "the run completed, but nodes failed: {}",
            problems.join("; ")
        );
    }
    Ok(ExitCode::SUCCESS)
}

/// `name`: the displays' saved images `display-<id><suffix>.png` put together, bezels black.
fn write_wall_png(dir: &Path, wall: &WallLayout, suffix: &str, name: &str) -> Result<()> {
    let mut screens = Vec::new();
    for screen in wall.screens() {
        let path = dir.join(format!("display-{}{suffix}.png", screen.id.0));
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
    let (stop, interrupted) = stop_on_ctrl_c();
    let wall = cfg.master.wall.clone();
    let outcome = run_wall(endpoint, cfg, Arc::new(AtomicBool::new(false)), stop).await;
    finish_run(
        outcome,
        &args.run,
        &wall,
        interrupted.load(std::sync::atomic::Ordering::SeqCst),
        Vec::new(),
        Vec::new(),
    )
}
