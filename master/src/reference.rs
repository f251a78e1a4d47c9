//! `tessera-master render`: one frame of the wall in this process, no network, the reference
//! that the wall must equal pixel for pixel, with optional per-pixel outputs (AOVs).

use crate::args::{Aov, RenderArgs};
use crate::camera_path::Replay;
use crate::record::Session;
use anyhow::{bail, Context, Result};
use std::time::Instant;
use tessera_cli::png::PngFile;
use tessera_model::image::RgbImage;
use tessera_model::params::RenderParams;
use tessera_model::state::WallState;
use tessera_model::wall::{TileGrid, WallLayout};
use tessera_render::aov::{primary_aovs, write_pfm, write_pfm_rgb};
use tessera_render::scene::Scene;
use tessera_render::{render_wall, render_wall_linear, FrameView, PreparedScene};

/// Renders what `args` asks: one frame into `--out DIR/wall.png` (and its AOVs), or with
/// `--frames` a movie (see [`crate::movie`]).
pub fn render_reference(args: RenderArgs) -> Result<()> {
    if args.frames.is_some() {
        return crate::movie::render_movie(args);
    }
    let setup = Setup::load(&args, args.frame)?;
    let state = setup.state_at(args.frame)?;
    let t0 = Instant::now();
    let prepared = prepare(&setup.scene, &state.params)?;
    let built = t0.elapsed();
    let view = view_of(args.frame, &state, &setup.wall);
    let (image, rendered) = render_timed(&prepared, &view, &setup.wall, args.repeat);
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create --out {}", args.out.display()))?;
    let path = args.out.join("wall.png");
    image.save_png(&path)?;
    write_aovs(&args, &prepared, &view, &setup.wall)?;
    eprintln!(
        "rendered frame {} of a {} ({}): prepare {:.2} s, render {:.3} s; wrote {}",
        args.frame,
        setup.wall_size(),
        setup.scene_size(),
        built.as_secs_f64(),
        rendered,
        path.display()
    );
    Ok(())
}

/// What `render` renders with: the wall, the scene, and where each frame's state comes from.
pub(crate) struct Setup {
    pub wall: WallLayout,
    pub scene: Scene,
    /// Frames a second the replayed file was made for, where it says (a camera path).
    pub fps: Option<u32>,
    states: States,
}

/// Where a frame's camera, quality and lights come from.
enum States {
    /// A recorded session, or a camera path made one.
    Replayed(Session),
    /// The flags: their camera mode (fixed, or the orbit, which moves with the frame) and
    /// quality, the scene's lights.
    Flags(Box<WallState>),
}

impl Setup {
    /// Checks the flags and the replayed file, that it has a state for frame `first`, and
    /// only then loads the scene (which can take long).
    ///
    /// # Errors
    /// A bad flag, a replayed file that cannot be read or starts after `first`, a scene that
    /// cannot be loaded, a camera path with a frame that is no camera.
    pub fn load(args: &RenderArgs, first: u64) -> Result<Setup> {
        let wall = args.wall.layout()?;
        // The cutting planes are moved into the scene's frame once it is loaded.
        args.quality
            .params(&tessera_model::local_origin::RenderFromWorld::IDENTITY)?;
        let replay = args.replay.as_deref().map(Replay::load).transpose()?;
        if let (Some(replay), Some(path)) = (&replay, &args.replay) {
            if replay.first_frame() > first {
                bail!(
                    "--replay {} starts at frame {}, after frame {first}",
                    path.display(),
                    replay.first_frame()
                );
            }
        }
        let scene = crate::args::load_scene(&args.scene)?;
        let params = args.quality.params(&scene.render_from_world)?;
        crate::args::refuse_what_does_not_apply(&args.quality, &scene, &args.scene.scene)?;
        let fps = replay.as_ref().and_then(Replay::fps);
        let states = match replay {
            Some(replay) => States::Replayed(replay.session(&scene.render_from_world, params)?),
            None => States::Flags(Box::new(WallState {
                camera: args
                    .scene
                    .camera_mode(&scene.render_from_world, |fov| scene.orbit(fov))?,
                params,
                lights: None,
            })),
        };
        Ok(Setup {
            wall,
            scene,
            fps,
            states,
        })
    }

    /// The state frame `frame` renders with.
    ///
    /// # Errors
    /// A replayed session that starts after `frame`.
    pub fn state_at(&self, frame: u64) -> Result<WallState> {
        match &self.states {
            States::Replayed(session) => session.state_at(frame),
            States::Flags(state) => Ok(**state),
        }
    }

    /// The wall's size in pixels, for messages.
    pub fn wall_size(&self) -> String {
        format!("{}x{} wall", self.wall.width(), self.wall.height())
    }

    /// What the scene holds, for messages.
    pub fn scene_size(&self) -> String {
        let volume = self.scene.volume.as_ref().map_or(String::new(), |v| {
            let d = v.dims();
            format!(", a {}x{}x{} volume", d[0], d[1], d[2])
        });
        format!("{} triangles{volume}", self.scene.triangles.len())
    }
}

/// Frame `frame` of `wall` as `state` renders it: its camera there, its quality, its lights.
pub(crate) fn view_of(frame: u64, state: &WallState, wall: &WallLayout) -> FrameView {
    let camera = state.camera.camera_for_frame(frame);
    FrameView {
        lights: state.lights,
        ..FrameView::for_wall(frame, &camera, state.params, wall)
    }
}

/// The scene ready to trace, with the step of its volume series that `shown` selects.
pub(crate) fn prepare(scene: &Scene, shown: &RenderParams) -> Result<PreparedScene> {
    let mut prepared = PreparedScene::new(scene);
    if let Some(step) = series_step(scene, shown) {
        let volume = tessera_render::volume::load(&scene.series[step])?;
        // Placed in the series' frame (its first step's).
        prepared.set_volume(std::sync::Arc::new(
            tessera_render::volume::PreparedVolume::new(&volume, &scene.render_from_world),
        ));
    }
    Ok(prepared)
}

/// The step of the scene's volume series that `shown` selects, if it has a series: all of
/// the prepared scene that depends on the frame's state.
pub(crate) fn series_step(scene: &Scene, shown: &RenderParams) -> Option<usize> {
    (!scene.series.is_empty()).then(|| shown.volume().time_step as usize % scene.series.len())
}

/// The frame rendered `repeat` times (at least once): the last image and the first render's
/// seconds; the spread of the times is reported where there are several.
fn render_timed(
    prepared: &PreparedScene,
    view: &FrameView,
    wall: &WallLayout,
    repeat: u32,
) -> (RgbImage, f64) {
    let mut times = Vec::with_capacity(repeat as usize);
    let mut image = None;
    for _ in 0..repeat {
        let start = Instant::now();
        image = Some(render_wall(prepared, view, &TileGrid::new(wall.clone())));
        times.push(start.elapsed().as_secs_f64());
    }
    let image = image.expect("--repeat is at least 1");
    if repeat > 1 {
        let mut sorted = times.clone();
        sorted.sort_by(f64::total_cmp);
        eprintln!(
            "render times over {} runs: median {:.4} s, fastest {:.4} s, first {:.4} s",
            repeat,
            sorted[sorted.len() / 2],
            sorted[0],
            times[0]
        );
    }
    (image, times[0])
}

/// Writes the per-pixel outputs --aov asks for into --out.
fn write_aovs(
    args: &RenderArgs,
    prepared: &PreparedScene,
    view: &FrameView,
    wall: &WallLayout,
) -> Result<()> {
    if args.aov.contains(&Aov::Color) {
        let p = args.out.join("color.pfm");
        let colors = render_wall_linear(prepared, view, &TileGrid::new(wall.clone()));
        write_pfm_rgb(&p, wall.width(), wall.height(), &colors)
            .with_context(|| format!("cannot write {}", p.display()))?;
        eprintln!("wrote {}", p.display());
    }
    if args.aov.iter().any(|a| *a != Aov::Color) {
        let aovs = primary_aovs(prepared, view, &TileGrid::new(wall.clone()));
        for aov in &args.aov {
            let (name, values) = match aov {
                Aov::Depth => ("depth.pfm", &aovs.depth),
                Aov::Prim => ("prim.pfm", &aovs.prim),
                Aov::Color => continue,
            };
            let p = args.out.join(name);
            write_pfm(&p, aovs.width, aovs.height, values)
                .with_context(|| format!("cannot write {}", p.display()))?;
            eprintln!("wrote {}", p.display());
        }
    }
    Ok(())
}
