//! The flags of the master's subcommands, and what a wall run is configured with.

use crate::server::RunConfig;
use anyhow::{bail, Context, Result};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;
use tessera_cli::{CompressArg, QualityArgs, SceneArgs, WallArgs};
use tessera_core::balance::{BalanceConfig, DeathDetector, DEFAULT_ACCEPTABLE_PAUSE};
use tessera_core::master::MasterConfig;
use tessera_protocol::FrameId;
use tessera_render::scene::Scene;

/// Most render nodes `local` starts on one machine.
pub const MAX_LOCAL_RENDER_NODES: u32 = 256;

#[derive(clap::Args, Clone)]
pub struct RunArgs {
    #[command(flatten)]
    pub wall: WallArgs,
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Frames to render (serve: 0 runs until Ctrl-C).
    #[arg(long, default_value_t = 60)]
    pub frames: u64,
    /// Directory for report.json (and PNGs with --save-frame). The report is written for
    /// every run that started, a failed one too: its `outcome` says whether the run completed,
    /// was interrupted or failed (and why), with whatever figures the run had.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Each display saves frame K as DIR/display-<id>.png; the master writes DIR/wall.png.
    #[arg(long, requires = "out")]
    pub save_frame: Option<u64>,
    #[command(flatten)]
    pub quality: QualityArgs,
    #[command(flatten)]
    pub data: crate::dsm_data::DataArgs,
    /// How long to wait for all nodes to join, in seconds (1 to 86400). Loading the scene
    /// is not part of it (see --load-timeout).
    #[arg(long, default_value_t = 60, value_parser = clap::value_parser!(u64).range(1..=86_400))]
    pub join_timeout: u64,
    /// How long, once every node has joined, they have to load the scene and be ready, in
    /// seconds (1 to 86400): a scene of gigabytes may take minutes. Render nodes report how far
    /// they are in the master's log.
    #[arg(long, default_value_t = 600, value_parser = clap::value_parser!(u64).range(1..=86_400))]
    pub load_timeout: u64,
    /// A node silent this many ms (no heartbeat, no report) is suspected: a render node's
    /// tiles are copied to the others so the frame still completes, but it stays in the run
    /// and is back when it speaks again. Nodes beat every 50 ms; 150 to 60000.
    #[arg(long, default_value_t = 300, value_parser = clap::value_parser!(u64).range(150..=60_000))]
    pub node_deadline_ms: u64,
    /// Silence a node may show, on top of its usual heartbeat rhythm, before it is dead and
    /// its connection closed (a phi-accrual detector learns each node's rhythm): a stopped
    /// process, a starved machine or a network blip shorter than this costs nobody their
    /// place. Silence while the master itself did not run counts against nobody. 0 to 8000;
    /// default 3000 for a served wall, 6000 for `local` (every process shares the cores).
    #[arg(long, value_name = "MS", value_parser = clap::value_parser!(u64).range(0..=8_000))]
    pub acceptable_pause_ms: Option<u64>,
    /// Never give an idle render node copies of a late node's tiles: a late node then holds
    /// its tiles until it reports them or its deadline passes, and no tile is sent twice.
    #[arg(long)]
    pub no_speculation: bool,
    /// Keep two frames in flight while someone steers too (more frames a second, input shown
    /// a frame later). By default the next frame waits for the one in flight while changes
    /// keep coming, so that it carries the newest one.
    #[arg(long)]
    pub pipeline_while_steering: bool,
    /// What a display's loss (its connection closed, or silent past --node-deadline-ms) does:
    /// `go-on` presents on the other displays (the lost display's tiles are no longer
    /// rendered); `wait` pauses the wall, every screen holding its last frame, until the
    /// display rejoins, and ends the run with an error if it is not back within
    /// --join-timeout; `stop` ends the run with an error at once.
    #[arg(long, value_enum, default_value_t = DisplayLoss::GoOn)]
    pub display_loss: DisplayLoss,
    /// Displays present this many ms after the frame barrier, all at the same instant by
    /// their clocks (0: each presents when the message arrives, which lets them drift apart
    /// by however late each is scheduled).
    #[arg(long, default_value_t = 2.0)]
    pub present_margin_ms: f64,
    /// How render nodes pack each tile for its display: `lz4` trades render-node and display
    /// CPU for fewer bytes where the link, not rendering, limits the frame rate.
    #[arg(long, value_enum, default_value_t = CompressArg::None)]
    pub compress: CompressArg,
    /// Write what every frame is rendered with to FILE, a JSON line each time it changes
    /// (camera, quality, cuts, lights): a session to replay or to render any frame of.
    #[arg(long, value_name = "FILE")]
    pub record: Option<PathBuf>,
    /// Drive the wall from a recorded session: each recorded state lands on its frame. A
    /// camera path (a .toml file of keyframes, see docs/movies.md) moves the camera alone.
    #[arg(long, value_name = "FILE")]
    pub replay: Option<PathBuf>,
    /// Progressive refinement: once the camera has held still for --still-frames frames,
    /// each frame doubles the samples per pixel, with --final-ao rays, up to --final-spp;
    /// then nothing renders until something changes. `auto`: on for runs until Ctrl-C
    /// (`--frames 0`) that replay nothing.
    #[arg(long, value_enum, default_value_t = RefineArg::Auto)]
    pub refine: RefineArg,
    /// Play the scene's time series (`series` in a .scene.toml): one step a frame from
    /// --time-step, looping; each step is state, changed at the frame barrier.
    #[arg(long)]
    pub play: bool,
    /// Samples per pixel of the final quality.
    #[arg(long, default_value_t = 8)]
    pub final_spp: u32,
    /// Ambient-occlusion rays per hit of the final quality.
    #[arg(long, default_value_t = 8)]
    pub final_ao: u32,
    /// Frames a view must hold before refining starts.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u64).range(1..=1000))]
    pub still_frames: u64,
}

#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum RefineArg {
    Auto,
    On,
    Off,
}

impl RunArgs {
    /// The refinement this run does, if any.
    ///
    /// # Errors
    /// A final quality out of bounds, or refining a replayed session (it was recorded with
    /// its passes; refining again would render other frames than it holds).
    pub fn refinement(&self) -> Result<Option<tessera_core::balance::Refinement>> {
        let on = match self.refine {
            RefineArg::Off => false,
            RefineArg::Auto => self.frames == 0 && self.replay.is_none(),
            RefineArg::On => {
                if self.replay.is_some() {
                    bail!("--refine on cannot go with --replay: the session holds its own passes");
                }
                true
            }
        };
        if !on {
            return Ok(None);
        }
        let r = tessera_core::balance::Refinement::new(
            self.still_frames,
            self.final_spp,
            self.final_ao,
        )
        .context("--final-spp / --final-ao")?;
        Ok(Some(r))
    }
}

#[derive(clap::Args, Clone)]
pub struct LocalArgs {
    #[command(flatten)]
    pub run: RunArgs,
    /// Render node processes to start (1 to 256).
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u32).range(1..=MAX_LOCAL_RENDER_NODES as i64))]
    pub render_nodes: u32,
    /// Threads per render node (default: this machine's cores shared among the render nodes).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=tessera_render_node::MAX_THREADS as i64))]
    pub threads: Option<u32>,
    /// Memory per render node for the steps of a time-varying volume read ahead of the one
    /// shown, in MiB (default: the render node's own, 2048).
    #[arg(long, value_name = "MIB")]
    pub volume_cache_mb: Option<usize>,
    /// Show each display in a window (needs a display server); otherwise headless.
    #[arg(long)]
    pub window: bool,
    /// With --window, keep the last frame on screen this many seconds before closing (0 to
    /// 3600).
    #[arg(long, default_value_t = 0.0, value_parser = tessera_display_node::parse_linger)]
    pub linger: f64,
    /// With --window, where the wall's top-left window goes on the desktop, X,Y; the others
    /// follow side by side as the screens lie in the wall (unless the wall file places them).
    #[arg(long, default_value = "0,0", value_name = "X,Y", value_parser = tessera_display_node::parse_position, allow_hyphen_values = true)]
    pub window_origin: (i32, i32),
    /// With --window, display N full screen on monitor N instead of side by side.
    #[arg(long)]
    pub fullscreen_all: bool,
    /// Serve the operator's console (a web page and a REST/JSON API) on this address; its
    /// URL, with a token, is printed at start. Port 0 picks a free one. Anything but
    /// loopback lets other hosts in (the token still guards it).
    #[arg(long, default_value = "127.0.0.1:0", value_name = "ADDR")]
    pub console: SocketAddr,
    /// Serve no console.
    #[arg(long)]
    pub no_console: bool,
}

#[derive(clap::Args)]
pub struct ServeArgs {
    #[command(flatten)]
    pub run: RunArgs,
    /// Address to listen on for nodes.
    #[arg(long, default_value = "0.0.0.0:7400")]
    pub listen: SocketAddr,
    /// Render nodes to wait for before the first frame (more may join later).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..))]
    pub render_nodes: u32,
    /// Cluster directory: the CA (created on first start) and the master's certificate.
    #[arg(long, default_value = "tessera-cluster")]
    pub cluster_dir: PathBuf,
    /// Serve the operator's console over HTTPS on this address (the master's cluster
    /// certificate; a browser shows the printed token, a script may show a control
    /// certificate instead). Loopback keeps it on this host; 0.0.0.0:PORT opens it to the
    /// wall's network.
    #[arg(long, value_name = "ADDR")]
    pub console: Option<SocketAddr>,
    /// Start as the standby of the master at ADDR (HOST:PORT, the primary's --listen): join
    /// it over the cluster's mutual TLS with this --cluster-dir's master certificate, follow
    /// its run (every change of the wall's state, the frames started, the report so far) and,
    /// once the primary is gone (its connection closes, or it is silent for
    /// --failover-after), take the wall over on --listen: nodes started with `--master
    /// PRIMARY,STANDBY` rejoin it and frames resume with the next state, the camera where it
    /// was. Give it the primary's run flags (scene, wall, --frames). It exits, as the primary
    /// does, when the primary's run ends without it.
    #[arg(long, value_name = "ADDR")]
    pub standby_of: Option<String>,
    /// With --standby-of: the primary is gone once silent this many ms (its heartbeats come
    /// every 50 ms; 100 to 60000). Give the nodes the same `--failover-after`. The default
    /// lets a LAN's wall present again within a second of its primary's death; a standby that
    /// acts on a live primary's stall does no harm (the nodes stay with the primary).
    #[arg(long, value_name = "MS", requires = "standby_of",
          default_value_t = tessera_protocol::FAILOVER_AFTER.as_millis() as u64,
          value_parser = clap::value_parser!(u64).range(100..=60_000))]
    pub failover_after: u64,
}

#[derive(clap::Args)]
pub struct RenderArgs {
    #[command(flatten)]
    pub wall: WallArgs,
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Frame number (selects the orbit camera's position).
    #[arg(long, default_value_t = 0)]
    pub frame: u64,
    /// Render every frame of A..B (B left out; A..=B includes it) into DIR/frame-000123.png,
    /// numbered by frame, in place of one --frame into wall.png: a movie of the orbit, of a
    /// --replay session or of a camera path. The scene is prepared once.
    #[arg(long, value_name = "A..B", value_parser = crate::movie::parse_frames,
          allow_hyphen_values = true, conflicts_with_all = ["frame", "aov", "repeat"])]
    pub frames: Option<crate::movie::FrameRange>,
    /// With --frames: encode the frames into FILE, an H.264 MP4, with ffmpeg from the PATH
    /// (checked before anything renders).
    #[arg(long, value_name = "FILE", requires = "frames")]
    pub mp4: Option<PathBuf>,
    /// Frames a second of the --mp4 movie (1 to 1000; default: a camera path's `fps`, else 30).
    #[arg(long, value_name = "N", requires = "mp4", value_parser = clap::value_parser!(u32).range(1..=1000))]
    pub fps: Option<u32>,
    /// Output directory; wall.png (or with --frames, frame-NNNNNN.png) is written there.
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub quality: QualityArgs,
    /// Also write an output value per pixel: `depth` → DIR/depth.pfm (distance along the ray,
    /// +inf for none), `prim` → DIR/prim.pfm (triangle index, -1 for none), `color` →
    /// DIR/color.pfm (linear RGB, what wall.png encodes, for error measurements). Repeatable.
    #[arg(long, value_enum)]
    pub aov: Vec<Aov>,
    /// Render --frame K of a recorded session (`--record`): its camera, quality and lights
    /// at that frame, in place of the camera and quality flags. A camera path (a .toml file
    /// of keyframes, see docs/movies.md) gives the camera alone; the quality is the flags'.
    #[arg(long, value_name = "FILE")]
    pub replay: Option<PathBuf>,
    /// Render the frame this many times and report the median and fastest render time (for
    /// benchmarks: the first render also fills the frame's tables).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=1000))]
    pub repeat: u32,
}

#[derive(clap::ValueEnum, Clone, Copy, PartialEq, Eq, Debug)]
pub enum Aov {
    Depth,
    Prim,
    Color,
}

#[derive(clap::Args)]
pub struct IssueCertArgs {
    /// Cluster directory holding the CA (created if missing).
    #[arg(long, default_value = "tessera-cluster")]
    pub cluster_dir: PathBuf,
    /// Name of the node (appears in its certificate and the master's logs).
    #[arg(long)]
    pub name: String,
    /// Directory to write node.pem, node.key and ca.pem into; give it to the node's --cert-dir.
    #[arg(long)]
    pub out: PathBuf,
    /// What the certificate lets its holder be: `render`, `display` (with --display), `control`
    /// (a control client) or `master`. The master refuses a peer whose certificate does not
    /// name the role it joins as, and a display whose certificate is for another display.
    #[arg(long, value_enum)]
    pub role: RoleArg,
    /// With --role display: the display id the certificate is for (the one it may join as).
    #[arg(long, value_name = "ID", required_if_eq("role", "display"))]
    pub display: Option<u32>,
    /// Days the certificate is valid for; the master refuses it once it has expired.
    #[arg(long, default_value_t = 3650, value_parser = clap::value_parser!(i64).range(1..=36_500))]
    pub valid_days: i64,
}

/// What the wall does when it loses a display.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum DisplayLoss {
    GoOn,
    Wait,
    Stop,
}

impl From<DisplayLoss> for tessera_core::master::DisplayLoss {
    fn from(policy: DisplayLoss) -> Self {
        match policy {
            DisplayLoss::GoOn => Self::GoOn,
            DisplayLoss::Wait => Self::Wait,
            DisplayLoss::Stop => Self::Stop,
        }
    }
}

#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum RoleArg {
    Render,
    Display,
    Control,
    Master,
}

impl RoleArg {
    pub fn cert_role(self) -> tessera_net::cluster::CertRole {
        use tessera_net::cluster::CertRole;
        match self {
            RoleArg::Render => CertRole::Render,
            RoleArg::Display => CertRole::Display,
            RoleArg::Control => CertRole::Control,
            RoleArg::Master => CertRole::Master,
        }
    }
}

/// The load balancer's knobs from the run's flags.
fn balance_config(run: &RunArgs) -> BalanceConfig {
    BalanceConfig {
        node_deadline: Duration::from_millis(run.node_deadline_ms),
        death: DeathDetector {
            acceptable_pause: run
                .acceptable_pause_ms
                .map_or(DEFAULT_ACCEPTABLE_PAUSE, Duration::from_millis),
            ..DeathDetector::default()
        },
        speculate: !run.no_speculation,
        hold_while_steering: !run.pipeline_while_steering,
        ..BalanceConfig::default()
    }
}

/// Loads the scene `args` name, refusing one with missing data under `--nan refuse`.
pub fn load_scene(args: &SceneArgs) -> Result<Scene> {
    let scene = Scene::load(&args.spec()?)?;
    if args.nan == tessera_cli::NanPolicy::Refuse {
        if let Some(what) = scene.first_missing() {
            bail!("scene {}: {what}, and --nan refuse was given", args.scene);
        }
    }
    Ok(scene)
}

/// `--play` needs a series, `--out` a folder it can create, `--save-frame` a frame the run has.
fn check_run_outputs(run: &RunArgs, scene: &Scene) -> Result<()> {
    if run.play && scene.series.is_empty() {
        bail!("--play needs a scene with a time series (`series` in a .scene.toml)");
    }
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
    Ok(())
}

/// Refuses quality flags the loaded scene has nothing for, naming the flag and why: volume
/// flags without a volume, a time step outside the series, particle flags without particles.
/// Silently ignoring them would leave a person wondering why `--iso 300` shows nothing.
pub fn refuse_what_does_not_apply(
    quality: &tessera_cli::QualityArgs,
    scene: &Scene,
    name: &str,
) -> Result<()> {
    let volume_flags = [
        ("--iso", !quality.iso.is_empty()),
        ("--transfer", quality.transfer != "ramp"),
        ("--volume-step", quality.volume_step != 0.0),
    ];
    if scene.volume.is_none() {
        if let Some((flag, _)) = volume_flags.iter().find(|(_, given)| *given) {
            bail!("{flag} applies to volumes, and scene {name} has none");
        }
    }
    let steps = scene.series.len().max(usize::from(scene.volume.is_some())) as u32;
    if quality.time_step > 0 && quality.time_step >= steps {
        match steps {
            0 => bail!("--time-step applies to volumes, and scene {name} has none"),
            1 => bail!(
                "--time-step {}: scene {name} is one volume, not a series (only 0)",
                quality.time_step
            ),
            n => bail!(
                "--time-step {} is outside the series' {n} steps (0 to {})",
                quality.time_step,
                n - 1
            ),
        }
    }
    let particle_flags = [
        ("--crop", quality.crop.is_some()),
        (
            "--colormap",
            quality.colormap != tessera_model::colormap::ColorMap::default(),
        ),
    ];
    if scene.particles.is_empty() {
        if let Some((flag, _)) = particle_flags.iter().find(|(_, given)| *given) {
            bail!("{flag} applies to particles, and scene {name} has none");
        }
    }
    Ok(())
}

/// What operators see of `scene` (its ranges, its series), and whether it plays from the start.
fn operator_config(scene: &Scene, play: bool) -> tessera_core::master::OperatorConfig {
    tessera_core::master::OperatorConfig {
        series_steps: (!scene.series.is_empty()).then_some(scene.series.len() as u32),
        play,
        volume_range: scene.volume.as_ref().map(|v| {
            let (lo, hi) = v.range();
            [lo, hi]
        }),
        particle_range: (!scene.particles.is_empty()).then(|| {
            let (lo, hi) = scene.attribute_range();
            [lo, hi]
        }),
        picture_width: crate::console::PICTURE_WIDTH,
    }
}

/// Loads what the master itself needs of the scene: its bounds (for the orbit) and its hash.
pub fn prepare_run(run: &RunArgs, render_nodes: u32, show_progress: bool) -> Result<RunConfig> {
    // Every flag is checked before the scene, which can take long to load.
    let wall_file = run.wall.wall_file()?;
    let wall = wall_file.layout;
    let spec = run.scene.spec()?;
    // Checked here; the cutting planes are moved into the scene's frame once it is loaded.
    run.quality
        .params(&tessera_model::local_origin::RenderFromWorld::IDENTITY)?;
    let refinement = run.refinement()?;
    let scene = load_scene(&run.scene)?;
    let params = run.quality.params(&scene.render_from_world)?;
    refuse_what_does_not_apply(&run.quality, &scene, &run.scene.scene)?;
    check_run_outputs(run, &scene)?;
    // A camera path (.toml) becomes a session in the scene's frame, with the run's quality.
    let replay = run
        .replay
        .as_deref()
        .map(|path| {
            crate::camera_path::Replay::load(path)?.session(&scene.render_from_world, params)
        })
        .transpose()?;
    let bounds = scene.bounds();
    let (pivot, scene_size) = if bounds.center().is_finite() {
        (bounds.center(), bounds.diagonal().length() * 0.5)
    } else {
        (glam::Vec3::ZERO, 1.0)
    };
    let histogram = scene
        .volume
        .as_ref()
        .and_then(|v| crate::console::Histogram::of(v.values(), 256));
    let master = MasterConfig {
        operator: operator_config(&scene, run.play),
        probe: crate::probe::Prober::of_scene(&scene)
            .map(|p| p as std::sync::Arc<dyn tessera_core::master::VolumeProbe>),
        wall,
        refinement,
        windows: wall_file.windows,
        pivot,
        scene_size,
        replay: replay.map_or_else(Vec::new, |session| session.changes()),
        camera: run
            .scene
            .camera_mode(&scene.render_from_world, |fov| scene.orbit(fov))?,
        scene_hash: scene.content_hash(),
        data: crate::dsm_data::data_spec(&run.data, &scene, render_nodes, show_progress)?,
        scene: spec,
        params,
        frames: (run.frames > 0).then_some(run.frames),
        render_nodes,
        save_frame: run.save_frame.map(FrameId),
        compression: run.compress.into(),
        join_timeout: Duration::from_secs(run.join_timeout),
        load_timeout: Duration::from_secs(run.load_timeout),
        balance: balance_config(run),
        display_loss: run.display_loss.into(),
        present_margin: Duration::try_from_secs_f64(run.present_margin_ms / 1000.0)
            .ok()
            .filter(|m| *m <= Duration::from_secs(1))
            .context("--present-margin-ms must be between 0 and 1000")?,
    };
    Ok(RunConfig {
        histogram,
        master,
        show_progress,
        record: run.record.clone(),
        takeover: None,
    })
}
