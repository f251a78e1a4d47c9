//! `tessera-master control`: the control interface's client, for operators and scripts. It
//! joins a running wall over QUIC with a control certificate (`issue-cert --role control`),
//! maps its clock onto the master's so that each command's stamp is on the master's clock,
//! sends its request and prints the answer (JSON for queries).

use anyhow::{bail, Context, Result};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;
use tessera_cli::transfer_file::transfer_function;
use tessera_cli::{parse_plane, parse_range, parse_vec3};
use tessera_model::camera::{Camera, CameraMode};
use tessera_model::cut::CutPlanes;
use tessera_model::light::{Light, Lights};
use tessera_model::state::{StateChange, WallState};
use tessera_model::volume_params::VolumeParams;
use tessera_net::cluster::NodeIdentity;
use tessera_net::link::MasterLink;
use tessera_protocol::control::{ControlReply, ControlRequest, Playback, ViewName};
use tessera_protocol::{FromNode, Role, ToNode};

#[derive(clap::Args, Debug)]
pub struct ControlArgs {
    /// The master's address, HOST:PORT. Without it (and --cert-dir), the local wall running
    /// on this machine is found from the file `local` writes in the state folder
    /// ($TESSERA_STATE_DIR, $XDG_STATE_HOME/tessera or ~/.local/state/tessera).
    #[arg(long, requires = "cert_dir")]
    connect: Option<String>,
    /// A control certificate's directory (`tessera-master issue-cert --role control`).
    #[arg(long, requires = "connect")]
    cert_dir: Option<PathBuf>,
    #[command(subcommand)]
    command: Command,
}

#[derive(clap::Subcommand, Debug, Clone)]
pub enum Command {
    /// Set the camera: --eye and --target (with --up and --fov), or --orbit.
    Camera {
        /// Camera position X,Y,Z, in render coordinates (as `state` shows them).
        #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true, requires = "target")]
        eye: Option<glam::Vec3>,
        /// Point the camera looks at, X,Y,Z, in render coordinates.
        #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true, requires = "eye")]
        target: Option<glam::Vec3>,
        /// Up direction X,Y,Z (keeps the others if alone).
        #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
        up: Option<glam::Vec3>,
        /// Vertical field of view of the whole wall, degrees (keeps the others if alone).
        #[arg(long)]
        fov: Option<f32>,
        /// Back to the orbit the wall started with.
        #[arg(long, conflicts_with_all = ["eye", "target"])]
        orbit: bool,
    },
    /// Frame the whole scene: a fixed camera looking at its middle from where it looks now.
    Fit,
    /// Set quality knobs; those not given stay as they are.
    Quality {
        /// Shadow rays: on or off.
        #[arg(long, value_parser = parse_on_off)]
        shadows: Option<bool>,
        /// Ambient-occlusion rays per hit.
        #[arg(long)]
        ao: Option<u32>,
        /// Samples per pixel.
        #[arg(long)]
        spp: Option<u32>,
        /// How hits are lit: `full` (lights, shadows, AO, as the other knobs ask) or
        /// `eyelight` (|N·D| times the base colour, no other ray: Embree's viewers' frame).
        #[arg(long, value_parser = tessera_cli::parse_shading)]
        shading: Option<tessera_model::params::Shading>,
    },
    /// Set the cutting planes (NX,NY,NZ,D, up to 4), or --clear them. In render coordinates,
    /// as `state` shows them: a file's mesh is centred on its middle.
    Cut {
        /// A plane NX,NY,NZ,D: cuts away what lies where N·p > D. Repeat for more planes.
        #[arg(long = "plane", value_parser = parse_plane, allow_hyphen_values = true)]
        planes: Vec<(glam::Vec3, f64)>,
        /// Remove every cutting plane.
        #[arg(long, conflicts_with = "planes")]
        clear: bool,
    },
    /// Colour particles' attributes with this map: viridis, magma, coolwarm or greys.
    Colormap {
        /// The map's name.
        #[arg(value_parser = tessera_cli::parse_colormap)]
        map: tessera_model::colormap::ColorMap,
    },
    /// Draw only particles whose attribute is in LO,HI, or --off.
    Crop {
        /// The attribute's range kept, LO,HI.
        #[arg(value_parser = parse_range, allow_hyphen_values = true, required_unless_present = "off")]
        range: Option<(f32, f32)>,
        /// Draw every particle again.
        #[arg(long)]
        off: bool,
    },
    /// Replace the scene's lights (up to 8), or go back to them with --scene.
    Lights {
        /// A sun from direction X,Y,Z with intensity I: X,Y,Z,I.
        #[arg(long, value_parser = parse_light_dir, allow_hyphen_values = true)]
        directional: Vec<Light>,
        /// A point light at X,Y,Z with intensity I: X,Y,Z,I.
        #[arg(long, value_parser = parse_light_point, allow_hyphen_values = true)]
        point: Vec<Light>,
        /// Back to the scene's own lights.
        #[arg(long, conflicts_with_all = ["directional", "point"])]
        scene: bool,
    },
    /// How volumes are drawn; what is not given stays as it is. --iso replaces the iso-values
    /// (repeat for up to 4), --no-iso goes back to the transfer function.
    Volume {
        /// Draw the iso-surface at this value, in the data's own units, with an optional
        /// colour (a name or R,G,B) and opacity, as the wall's --iso takes them.
        #[arg(long = "iso", value_name = "VALUE[:COLOUR[:OPACITY]]", value_parser = tessera_cli::iso_arg::parse_iso, allow_hyphen_values = true)]
        iso: Vec<tessera_cli::iso_arg::IsoArg>,
        /// Drop the iso-values: back to the transfer function.
        #[arg(long, conflicts_with = "iso")]
        no_iso: bool,
        /// Ray-marching step in world units (0: half the smallest voxel spacing).
        #[arg(long)]
        step: Option<f32>,
        /// A transfer-function preset (ramp, ct-bone, ct-skin) or TOML file.
        #[arg(long)]
        transfer: Option<String>,
        /// Which step of a time series to show (from 0).
        #[arg(long)]
        time_step: Option<u32>,
    },
    /// Play the time series (at --speed steps per second; by default a step each frame).
    Play {
        /// Steps per second, 0.1 to 60.
        #[arg(long)]
        speed: Option<f32>,
    },
    /// Pause the time series.
    Pause,
    /// Move the time series BY steps (default 1; negative goes back) and pause.
    Step {
        /// Steps to move by.
        #[arg(default_value_t = 1, allow_hyphen_values = true)]
        by: i32,
    },
    /// Print the wall's state as JSON: camera, quality, cuts, lights, views, and the volume
    /// and particles where the scene has them (what the console's /api/status answers).
    State,
    /// Print live figures (fps, frame time, per node) as JSON.
    Figures,
    /// Keep the current camera as a named view.
    SaveView {
        /// The view's name.
        name: String,
    },
    /// Go back to a named view.
    View {
        /// The view's name, as saved with `save-view`.
        name: String,
    },
    /// List the saved views.
    Views,
    /// Show or hide the displays' overlay.
    Overlay {
        /// on or off.
        #[arg(value_parser = parse_on_off, action = clap::ArgAction::Set)]
        on: bool,
    },
    /// Have the displays save the wall as it shows it now (a still wall) or its next frame,
    /// as display-<id>-frame-<K>.png in their --out folder; prints K.
    Snapshot {
        /// First refine to the final quality (the camera must hold still), then save.
        #[arg(long = "final")]
        final_quality: bool,
    },
    /// Print the volume's value and world position under wall pixel X Y (of the whole wall,
    /// bezels included, 0,0 at the top left) as JSON: null where the pixel shows no volume.
    Probe {
        /// Pixel column, from the wall's left edge.
        x: u32,
        /// Pixel row, from the wall's top edge.
        y: u32,
    },
    /// Run control commands from FILE (`-`: standard input), one per line, as written after
    /// `control ... ` on the command line; blank lines and lines starting with # are skipped.
    Script {
        /// The script's path, or `-`.
        file: PathBuf,
    },
}

fn parse_on_off(text: &str) -> Result<bool, String> {
    match text {
        "on" | "true" | "1" => Ok(true),
        "off" | "false" | "0" => Ok(false),
        _ => Err(format!("`{text}` is not on or off")),
    }
}

fn parse_light(text: &str) -> Result<(glam::Vec3, f32), String> {
    let (xyz, intensity) = parse_plane(text).map_err(|e| {
        format!(
            "{}; a light is X,Y,Z,INTENSITY",
            e.to_string().replace("NX,NY,NZ,D", "X,Y,Z,I")
        )
    })?;
    Ok((xyz, intensity as f32))
}

fn parse_light_dir(text: &str) -> Result<Light, String> {
    let (towards, intensity) = parse_light(text)?;
    Ok(Light::directional(towards, intensity))
}

fn parse_light_point(text: &str) -> Result<Light, String> {
    let (position, intensity) = parse_light(text)?;
    Ok(Light::Point {
        position,
        intensity,
    })
}

/// A control connection to a running wall.
pub struct ControlClient {
    link: MasterLink,
    next_id: u32,
    /// Master clock minus this host's clock, ns.
    offset_ns: i64,
    /// The orbit the wall started with, for `camera --orbit`.
    home: Option<CameraMode>,
    /// The wall, as the master's welcome said it.
    wall: tessera_model::wall::WallLayout,
    endpoint: quinn::Endpoint,
}

impl ControlClient {
    /// Connects to the master at `master` with the control certificate in `cert_dir`, and
    /// maps this host's clock onto the master's from the fastest of a few round trips.
    pub async fn connect(master: &str, cert_dir: &std::path::Path) -> Result<ControlClient> {
        let identity = NodeIdentity::load(cert_dir)?;
        let addr = tessera_net::resolve(master).await?;
        let bind: SocketAddr = if addr.is_ipv6() {
            "[::]:0"
        } else {
            "0.0.0.0:0"
        }
        .parse()?;
        let endpoint = tessera_net::quic::endpoint(bind, &identity, false)?;
        let (link, welcome) = MasterLink::join(&endpoint, addr, Role::Control)
            .await
            .context("is the wall running there? see --help")?;
        let mut client = ControlClient {
            link,
            next_id: 0,
            offset_ns: 0,
            home: None,
            wall: welcome.session.wall().clone(),
            endpoint,
        };
        client.sync_clock().await?;
        if let ControlReply::State { current, .. } = client.ask(ControlRequest::State).await? {
            client.home = current
                .camera
                .fixed_camera()
                .is_none()
                .then_some(current.camera);
        }
        Ok(client)
    }

    async fn sync_clock(&mut self) -> Result<()> {
        let mut best: Option<(u64, i64)> = None;
        for _ in 0..8 {
            let sent = tessera_net::unix_ns();
            let ControlReply::Clock { master_ns } = self.ask(ControlRequest::Clock).await? else {
                bail!("the master answered a clock request with something else");
            };
            let back = tessera_net::unix_ns();
            let rtt = back.saturating_sub(sent);
            let offset = master_ns as i64 - (sent + rtt / 2) as i64;
            if best.is_none_or(|(r, _)| rtt < r) {
                best = Some((rtt, offset));
            }
        }
        self.offset_ns = best.map_or(0, |(_, o)| o);
        Ok(())
    }

    /// Sends one request, stamped now on the master's clock, and waits (bounded) for its answer.
    pub async fn ask(&mut self, request: ControlRequest) -> Result<ControlReply> {
        let id = self.next_id;
        self.next_id = self.next_id.wrapping_add(1);
        let stamp_ns = (tessera_net::unix_ns() as i64 + self.offset_ns).max(1) as u64;
        // A snapshot is answered once its files are written, which may take a final pass.
        let limit = match request {
            ControlRequest::Snapshot { .. } => Duration::from_secs(300),
            _ => Duration::from_secs(10),
        };
        self.link
            .send(&FromNode::Control {
                id,
                request,
                stamp_ns,
            })
            .await?;
        let wait = async {
            loop {
                match self.link.recv().await? {
                    ToNode::ControlReply { id: got, reply } if got == id => return Ok(reply),
                    ToNode::ControlReply { .. } => {}
                    ToNode::Shutdown => bail!("the wall shut down"),
                    other => bail!(
                        "the master sent a control client a {} message",
                        other.kind()
                    ),
                }
            }
        };
        tokio::time::timeout(limit, wait)
            .await
            .with_context(|| format!("the master did not answer within {} s", limit.as_secs()))?
    }

    /// Turns a command into its request (reading the state where a change keeps what it does
    /// not name) and asks it.
    pub async fn run(&mut self, command: &Command) -> Result<ControlReply> {
        let change = |c: StateChange| ControlRequest::Change(vec![c]);
        let request = match command {
            Command::Camera {
                eye,
                target,
                up,
                fov,
                orbit,
            } => change(StateChange::Camera(
                self.camera(*eye, *target, *up, *fov, *orbit).await?,
            )),
            Command::Quality {
                shadows,
                ao,
                spp,
                shading,
            } => quality(*shadows, *ao, *spp, *shading)?,
            Command::Cut { planes, clear } => change(cuts(planes, *clear)?),
            Command::Colormap { map } => change(StateChange::ColorMap(*map)),
            Command::Crop { range, off } => {
                change(StateChange::Crop(if *off { None } else { *range }))
            }
            Command::Lights {
                directional,
                point,
                scene,
            } => change(lights(directional, point, *scene)?),
            Command::Volume {
                iso,
                no_iso,
                step,
                transfer,
                time_step,
            } => change(StateChange::Volume(
                self.volume(iso, *no_iso, *step, transfer.as_deref(), *time_step)
                    .await?,
            )),
            Command::State => ControlRequest::Status,
            Command::Figures => ControlRequest::Figures,
            Command::SaveView { name } => ControlRequest::SaveView(ViewName::new(name)?),
            Command::View { name } => ControlRequest::GotoView(ViewName::new(name)?),
            Command::Views => ControlRequest::Views,
            Command::Overlay { on } => ControlRequest::Overlay(*on),
            Command::Snapshot { final_quality } => ControlRequest::Snapshot {
                final_quality: *final_quality,
            },
            Command::Fit => ControlRequest::Fit,
            Command::Play { speed } => ControlRequest::Playback(Playback {
                playing: Some(true),
                steps_per_second: *speed,
                step_by: None,
            }),
            Command::Pause => ControlRequest::Playback(Playback {
                playing: Some(false),
                ..Playback::default()
            }),
            Command::Step { by } => ControlRequest::Playback(Playback {
                step_by: Some(*by),
                ..Playback::default()
            }),
            Command::Probe { x, y } => ControlRequest::Probe { x: *x, y: *y },
            Command::Script { .. } => bail!("a script cannot run a script"),
        };
        self.ask(request).await
    }

    /// The volume settings after the next barrier, changed as the `volume` command's flags say.
    async fn volume(
        &mut self,
        iso: &[tessera_cli::iso_arg::IsoArg],
        no_iso: bool,
        step: Option<f32>,
        transfer: Option<&str>,
        time_step: Option<u32>,
    ) -> Result<VolumeParams> {
        let mut volume = *self.state_and_frame().await?.0.params.volume();
        if let Some(t) = time_step {
            volume.time_step = t;
        }
        if !iso.is_empty() || no_iso {
            (volume.iso, volume.iso_looks) =
                tessera_cli::iso_arg::iso_params(iso).context("--iso")?;
        }
        if let Some(step) = step {
            volume.step = step;
        }
        if let Some(name) = transfer {
            volume.transfer = transfer_function(name).context("--transfer")?;
        }
        volume.check().context("volume")?;
        Ok(volume)
    }

    /// The wall's state after the next barrier, and the frame it is at.
    async fn state_and_frame(&mut self) -> Result<(WallState, u64)> {
        let ControlReply::State { next, frame, .. } = self.ask(ControlRequest::State).await? else {
            bail!("the master answered a state request with something else");
        };
        Ok((next, frame))
    }

    async fn camera(
        &mut self,
        eye: Option<glam::Vec3>,
        target: Option<glam::Vec3>,
        up: Option<glam::Vec3>,
        fov: Option<f32>,
        orbit: bool,
    ) -> Result<CameraMode> {
        if orbit {
            return self
                .home
                .context("the wall started with a fixed camera: there is no orbit to go back to");
        }
        if eye.is_none() && up.is_none() && fov.is_none() {
            anyhow::bail!(
                "camera: give --eye and --target, --up, --fov or --orbit (nothing to change); \
                 `fit` frames the scene, `state` shows the camera now"
            );
        }
        // What is not given is kept from the camera on the wall now.
        let (next, frame) = self.state_and_frame().await?;
        let now = next.camera.camera_for_frame(frame);
        let camera = Camera::new(
            eye.unwrap_or(now.eye()),
            target.unwrap_or(now.target()),
            up.unwrap_or(now.up()),
            fov.unwrap_or(now.fov_y_deg()),
        )
        .context("camera")?;
        Ok(CameraMode::fixed(camera))
    }
}

/// The `quality` command's request: a change for each knob given.
pub(crate) fn quality(
    shadows: Option<bool>,
    ao: Option<u32>,
    spp: Option<u32>,
    shading: Option<tessera_model::params::Shading>,
) -> Result<ControlRequest> {
    let mut changes = Vec::new();
    changes.extend(shadows.map(StateChange::Shadows));
    changes.extend(ao.map(StateChange::AoSamples));
    changes.extend(spp.map(StateChange::Spp));
    changes.extend(shading.map(StateChange::Shading));
    if changes.is_empty() {
        bail!("quality: give --shadows, --ao, --spp or --shading");
    }
    Ok(ControlRequest::Change(changes))
}

/// The `cut` command's change: its planes, or none with --clear.
pub(crate) fn cuts(planes: &[(glam::Vec3, f64)], clear: bool) -> Result<StateChange> {
    let planes: Vec<(glam::Vec3, f32)> = if clear {
        Vec::new()
    } else {
        planes.iter().map(|&(n, d)| (n, d as f32)).collect()
    };
    Ok(StateChange::Cuts(
        CutPlanes::new(&planes).context("--plane")?,
    ))
}

/// The `lights` command's change: its lights, or the scene's with --scene.
fn lights(directional: &[Light], point: &[Light], scene: bool) -> Result<StateChange> {
    let lights: Vec<Light> = directional.iter().chain(point).copied().collect();
    let set = if scene {
        None
    } else {
        Some(Lights::new(&lights).context("lights")?)
    };
    Ok(StateChange::Lights(set))
}

/// Prints an answer: queries as JSON on stdout, what a command did on stderr, refusals on
/// stderr. Whether it was refused.
fn print(reply: &ControlReply, wall: &tessera_model::wall::WallLayout) -> Result<bool> {
    match reply {
        ControlReply::Refused(why) => {
            eprintln!("tessera-master control: refused: {why}");
            return Ok(true);
        }
        ControlReply::Status(s) => json(&crate::console::json::StatusView::of(s, wall))?,
        ControlReply::State { .. }
        | ControlReply::Figures(_)
        | ControlReply::Views(_)
        | ControlReply::TileOwners(_) => json(reply)?,
        ControlReply::Snapshot { frame, shown } => {
            println!("{frame}");
            eprintln!(
                "snapshot of frame {frame} ({}): display-<id>-frame-{frame}.png in the displays' --out, wall-frame-{frame}.png in the master's",
                if *shown { "as shown" } else { "rendered" }
            );
        }
        ControlReply::Probe(hit) => json(hit)?,
        ControlReply::Queued {
            changes,
            state_id,
            frame,
        } => eprintln!(
            "queued {changes} change{}: state {} from frame {frame} on",
            if *changes == 1 { "" } else { "s" },
            state_id.0
        ),
        ControlReply::Done => eprintln!("done"),
        ControlReply::Clock { .. } => {}
    }
    Ok(false)
}

/// Prints `value` as pretty JSON on stdout.
fn json(value: &impl serde::Serialize) -> Result<()> {
    println!("{}", serde_json::to_string_pretty(value)?);
    Ok(())
}

/// The lines of a script, each parsed as a command.
fn script(file: &std::path::Path) -> Result<Vec<Command>> {
    use clap::Parser;
    #[derive(clap::Parser)]
    #[command(no_binary_name = true)]
    struct Line {
        #[command(subcommand)]
        command: Command,
    }
    let text = if file == std::path::Path::new("-") {
        std::io::read_to_string(std::io::stdin()).context("cannot read standard input")?
    } else {
        std::fs::read_to_string(file).with_context(|| format!("cannot read {}", file.display()))?
    };
    let mut commands = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let parsed = Line::try_parse_from(line.split_whitespace())
            .map_err(|e| anyhow::anyhow!("{}:{}: {}", file.display(), n + 1, e.render()))?;
        commands.push(parsed.command);
    }
    Ok(commands)
}

pub async fn control(args: ControlArgs) -> Result<ExitCode> {
    // A script is read whole before connecting, so a typo on line 900 fails before line 1 runs.
    let commands = match &args.command {
        Command::Script { file } => script(file)?,
        other => vec![other.clone()],
    };
    let (connect, cert_dir) = match (args.connect, args.cert_dir) {
        (Some(c), Some(d)) => (c, d),
        _ => {
            let local = crate::console::credentials::LocalWall::read()?;
            (local.connect, local.cert_dir)
        }
    };
    let mut client = ControlClient::connect(&connect, &cert_dir).await?;
    let mut refused = 0;
    for command in &commands {
        if print(&client.run(command).await?, &client.wall)? {
            refused += 1;
        }
    }
    client.link.leave(&client.endpoint).await;
    Ok(if refused == 0 {
        ExitCode::SUCCESS
    } else {
        if commands.len() > 1 {
            eprintln!(
                "tessera-master control: {refused} of {} commands refused",
                commands.len()
            );
        }
        ExitCode::FAILURE
    })
}
