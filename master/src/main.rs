//! `tessera-master`: balances the wall's work, runs the frame barrier, and can launch a whole
//! local wall or render the single-process reference image.

mod bench;
mod launcher;
mod peers;
mod report;
mod server;
mod simulate;
mod timing;

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand};
use launcher::{reap, sibling_binary, spawn, watch};
use server::{bind, run_wall, RunConfig};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tessera_common::cli::{QualityArgs, SceneArgs, WallArgs};
use tessera_common::image_io::{compose_wall, render_wall, RgbImage};
use tessera_common::net::cluster::{ClusterCa, NodeIdentity};
use tessera_common::protocol::pixels::Compression;
use tessera_common::protocol::FrameId;
use tessera_common::render::aov::{primary_aovs, write_pfm};
use tessera_common::render::{FrameView, PreparedScene};
use tessera_common::scene::Scene;
use tessera_common::wall::{TileGrid, WallLayout};

/// Tessera's master: hands image tiles to render nodes over QUIC and makes every display
/// present each frame at the same moment.
#[derive(Parser)]
#[command(version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run a whole wall on this machine: display and render nodes as processes on 127.0.0.1.
    Local(LocalArgs),
    /// Wait for the wall's nodes on an address and run it (a real wall over several hosts).
    Serve(ServeArgs),
    /// Render one frame of the wall in this process, no network: the reference image.
    Render(RenderArgs),
    /// Run a measurement experiment on a local wall: max-fps, latency, scaling or
    /// error-vs-time; writes report.json, a CSV and an SVG plot into --out DIR.
    Bench(bench::BenchArgs),
    /// Write a node certificate signed by the cluster CA (creating the CA on first use).
    IssueCert(IssueCertArgs),
    /// Simulate a wall in this process on a virtual clock (the real load balancer and frame
    /// barrier, virtual nodes and network): prints balance efficiency and frames completed.
    Simulate(simulate::SimulateArgs),
}

#[derive(clap::Args, Clone)]
struct RunArgs {
    #[command(flatten)]
    wall: WallArgs,
    #[command(flatten)]
    scene: SceneArgs,
    /// Frames to render (serve: 0 runs until Ctrl-C).
    #[arg(long, default_value_t = 60)]
    frames: u64,
    /// Directory for report.json (and PNGs with --save-frame).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Each display saves frame K as DIR/display-<id>.png; the master writes DIR/wall.png.
    #[arg(long, requires = "out")]
    save_frame: Option<u64>,
    #[command(flatten)]
    quality: QualityArgs,
    /// How long to wait for all nodes to join, in seconds.
    #[arg(long, default_value_t = 60)]
    join_timeout: u64,
    /// Displays present this many ms after the frame barrier, all at the same instant by
    /// their clocks (0: each presents when the message arrives, which lets them drift apart
    /// by however late each is scheduled).
    #[arg(long, default_value_t = 2.0)]
    present_margin_ms: f64,
    /// How render nodes pack each tile for its display: `lz4` trades render-node and display
    /// CPU for fewer bytes where the link, not rendering, limits the frame rate.
    #[arg(long, value_enum, default_value_t = Compression::None)]
    compress: Compression,
}

#[derive(clap::Args, Clone)]
struct LocalArgs {
    #[command(flatten)]
    run: RunArgs,
    /// Render node processes to start.
    #[arg(long, default_value_t = 2)]
    render_nodes: u32,
    /// Threads per render node (default: this machine's cores shared among the render nodes).
    #[arg(long)]
    threads: Option<u32>,
    /// Show each display in a window (needs a display server); otherwise headless.
    #[arg(long)]
    window: bool,
    /// With --window, keep the last frame on screen this many seconds before closing.
    #[arg(long, default_value_t = 0.0)]
    linger: f64,
}

#[derive(clap::Args)]
struct ServeArgs {
    #[command(flatten)]
    run: RunArgs,
    /// Address to listen on for nodes.
    #[arg(long, default_value = "0.0.0.0:7400")]
    listen: SocketAddr,
    /// Render nodes to wait for before the first frame (more may join later).
    #[arg(long, default_value_t = 1)]
    render_nodes: u32,
    /// Cluster directory: the CA (created on first start) and the master's certificate.
    #[arg(long, default_value = "tessera-cluster")]
    cluster_dir: PathBuf,
}

#[derive(clap::Args)]
struct RenderArgs {
    #[command(flatten)]
    wall: WallArgs,
    #[command(flatten)]
    scene: SceneArgs,
    /// Frame number (selects the orbit camera's position).
    #[arg(long, default_value_t = 0)]
    frame: u64,
    /// Output directory; wall.png is written there.
    #[arg(long)]
    out: PathBuf,
    #[command(flatten)]
    quality: QualityArgs,
    /// Also write an output value per pixel: `depth` → DIR/depth.pfm (distance along the ray,
    /// +inf for none), `prim` → DIR/prim.pfm (triangle index, -1 for none). Repeatable.
    #[arg(long, value_enum)]
    aov: Vec<Aov>,
}

#[derive(clap::ValueEnum, Clone, Copy, PartialEq, Eq, Debug)]
enum Aov {
    Depth,
    Prim,
}

#[derive(clap::Args)]
struct IssueCertArgs {
    /// Cluster directory holding the CA (created if missing).
    #[arg(long, default_value = "tessera-cluster")]
    cluster_dir: PathBuf,
    /// Name of the node (appears in its certificate and the master's logs).
    #[arg(long)]
    name: String,
    /// Directory to write node.pem, node.key and ca.pem into; give it to the node's --cert-dir.
    #[arg(long)]
    out: PathBuf,
}

fn main() -> ExitCode {
    tessera_common::logging::init();
    match run(Cli::parse()) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("tessera-master: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> Result<ExitCode> {
    match cli.command {
        Command::Render(args) => render_reference(args).map(|()| ExitCode::SUCCESS),
        Command::IssueCert(args) => {
            let ca = ClusterCa::open_or_create(&args.cluster_dir)?;
            ca.issue(&args.name, &args.out)?;
            println!(
                "wrote the certificate of `{}` to {} (give it to the node with --cert-dir)",
                args.name,
                args.out.display()
            );
            Ok(ExitCode::SUCCESS)
        }
        Command::Local(args) => runtime()?.block_on(local(args)),
        Command::Serve(args) => runtime()?.block_on(serve(args)),
        Command::Simulate(args) => simulate::simulate(args),
        Command::Bench(args) => runtime()?.block_on(bench::bench(args)),
    }
}

fn runtime() -> Result<tokio::runtime::Runtime> {
    Ok(tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?)
}

/// Loads what the master itself needs of the scene: its bounds (for the orbit) and its hash.
fn prepare_run(run: &RunArgs, render_nodes: u32, show_progress: bool) -> Result<RunConfig> {
    let wall = run.wall.layout()?;
    let spec = run.scene.spec()?;
    let scene = Scene::load(&spec)?;
    if let Some(dir) = &run.out {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("cannot create --out {}", dir.display()))?;
    }
    if let Some(k) = run.save_frame {
        if run.frames != 0 && k >= run.frames {
            bail!(
                "--save-frame {k} is not one of the {} frames (0..{})",
                run.frames,
                run.frames
            );
        }
    }
    Ok(RunConfig {
        wall,
        camera: run.scene.camera_mode(&scene)?,
        scene_hash: scene.content_hash(),
        scene: spec,
        params: run.quality.params()?,
        frames: (run.frames > 0).then_some(run.frames),
        render_nodes,
        save_frame: run.save_frame.map(FrameId),
        compression: run.compress,
        join_timeout: Duration::from_secs(run.join_timeout),
        show_progress,
        present_margin: Duration::try_from_secs_f64(run.present_margin_ms / 1000.0)
            .ok()
            .filter(|m| *m <= Duration::from_secs(1))
            .context("--present-margin-ms must be between 0 and 1000")?,
    })
}

fn stop_on_ctrl_c() -> (tokio::sync::watch::Receiver<bool>, Arc<AtomicBool>) {
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

async fn local(args: LocalArgs) -> Result<ExitCode> {
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
struct LocalRun {
    outcome: Result<report::Report>,
    wall: WallLayout,
    interrupted: bool,
    lost: Vec<String>,
    failures: Vec<String>,
}

/// Starts the display and render nodes of `args` as child processes, runs the wall, and reaps
/// every child before returning.
async fn run_local(args: &LocalArgs, show_progress: bool) -> Result<LocalRun> {
    if args.render_nodes == 0 {
        bail!("--render-nodes must be at least 1");
    }
    let cfg = prepare_run(&args.run, args.render_nodes, show_progress)?;
    let display_bin = sibling_binary("tessera-display-node")?;
    let render_bin = sibling_binary("tessera-render-node")?;
    let certs = tempfile::Builder::new()
        .prefix("tessera-local-")
        .tempdir()?;
    let ca = ClusterCa::open_or_create(&certs.path().join("ca"))?;
    let cert_dir = |name: &str| -> Result<PathBuf> {
        let dir = certs.path().join(name);
        ca.issue(name, &dir)?;
        Ok(dir)
    };
    let identity = NodeIdentity::load(&cert_dir("master")?)?;
    let endpoint = bind("127.0.0.1:0".parse()?, &identity)?;
    let master_addr = endpoint.local_addr()?.to_string();
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get() as u32);
    let threads = args.threads.unwrap_or((cores / args.render_nodes).max(1));

    let mut children = Vec::new();
    for d in 0..cfg.wall.display_count() {
        let name = format!("display-{d}");
        let mut a = vec![
            "--master".into(),
            master_addr.clone(),
            "--display".into(),
            d.to_string(),
            "--cert-dir".into(),
            cert_dir(&name)?.display().to_string(),
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
        children.push(spawn(format!("display node {d}"), true, &display_bin, &a)?);
    }
    for r in 0..args.render_nodes {
        let name = format!("render-{r}");
        let a = vec![
            "--master".into(),
            master_addr.clone(),
            "--cert-dir".into(),
            cert_dir(&name)?.display().to_string(),
            "--threads".into(),
            threads.to_string(),
        ];
        children.push(spawn(format!("render node {r}"), false, &render_bin, &a)?);
    }

    let (stop, interrupted) = stop_on_ctrl_c();
    let started = Arc::new(AtomicBool::new(false));
    let mut lost = Vec::new();
    let wall = cfg.wall;
    let outcome = {
        let run = run_wall(endpoint, cfg, started.clone(), stop);
        tokio::pin!(run);
        tokio::select! {
            report = &mut run => report,
            err = watch(&mut children, started.clone(), &mut lost) => Err(err),
        }
    };
    // Windows stay up for --linger after the run; only then is a display late to exit.
    let grace = Duration::from_secs(5) + Duration::from_secs_f64(args.linger.max(0.0));
    let failures = reap(&mut children, grace).await;
    Ok(LocalRun {
        outcome,
        wall,
        interrupted: interrupted.load(std::sync::atomic::Ordering::SeqCst),
        lost,
        failures,
    })
}

/// Writes the report and wall image and turns the run's outcome into an exit code.
fn finish_run(
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
            write_wall_png(dir, wall)?;
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

/// `wall.png`: the displays' saved images put together, bezels black.
fn write_wall_png(dir: &Path, wall: &WallLayout) -> Result<()> {
    let mut screens = Vec::new();
    for screen in wall.screens() {
        let path = dir.join(format!("display-{}.png", screen.id.0));
        if !path.exists() {
            bail!(
                "{} is missing: wall.png can only be assembled where the displays' --out directory is shared",
                path.display()
            );
        }
        screens.push((screen, RgbImage::load_png(&path)?));
    }
    let path = dir.join("wall.png");
    compose_wall(wall, &screens)?.save_png(&path)?;
    eprintln!("wrote {}", path.display());
    Ok(())
}

async fn serve(args: ServeArgs) -> Result<ExitCode> {
    let cfg = prepare_run(&args.run, args.render_nodes, true)?;
    let ca = ClusterCa::open_or_create(&args.cluster_dir)?;
    let master_dir = args.cluster_dir.join("master");
    if !master_dir.join("node.pem").exists() {
        ca.issue("master", &master_dir)?;
    }
    let identity = NodeIdentity::load(&master_dir)?;
    let endpoint = bind(args.listen, &identity)?;
    let (stop, interrupted) = stop_on_ctrl_c();
    let wall = cfg.wall;
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

fn render_reference(args: RenderArgs) -> Result<()> {
    let wall = args.wall.layout()?;
    let scene = Scene::load(&args.scene.spec()?)?;
    let camera = args.scene.camera_mode(&scene)?.camera_for_frame(args.frame);
    let t0 = Instant::now();
    let prepared = PreparedScene::new(&scene);
    let built = t0.elapsed();
    let view = FrameView::new(
        args.frame,
        &camera,
        args.quality.params()?,
        wall.width(),
        wall.height(),
    );
    let image = render_wall(&prepared, &view, &TileGrid::new(wall));
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create --out {}", args.out.display()))?;
    let path = args.out.join("wall.png");
    image.save_png(&path)?;
    if !args.aov.is_empty() {
        let aovs = primary_aovs(&prepared, &view, &TileGrid::new(wall));
        for aov in &args.aov {
            let (name, values) = match aov {
                Aov::Depth => ("depth.pfm", &aovs.depth),
                Aov::Prim => ("prim.pfm", &aovs.prim),
            };
            let p = args.out.join(name);
            write_pfm(&p, aovs.width, aovs.height, values)
                .with_context(|| format!("cannot write {}", p.display()))?;
            eprintln!("wrote {}", p.display());
        }
    }
    eprintln!(
        "rendered frame {} of a {}x{} wall ({} triangles): BVH {:.2} s, render {:.2} s; wrote {}",
        args.frame,
        wall.width(),
        wall.height(),
        scene.triangles.len(),
        built.as_secs_f64(),
        (t0.elapsed() - built).as_secs_f64(),
        path.display()
    );
    Ok(())
}
