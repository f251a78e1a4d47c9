//! `tessera-master render`: one frame of the wall in this process, no network, the reference
//! that the wall must equal pixel for pixel, with optional per-pixel outputs (AOVs).

use crate::args::{Aov, RenderArgs};
use anyhow::{Context, Result};
use std::time::Instant;
use tessera_cli::png::PngFile;
use tessera_model::image::RgbImage;
use tessera_model::params::RenderParams;
use tessera_model::wall::{TileGrid, WallLayout};
use tessera_render::aov::{primary_aovs, write_pfm, write_pfm_rgb};
use tessera_render::scene::Scene;
use tessera_render::{orbit_of, render_wall, render_wall_linear, FrameView, PreparedScene};

pub fn render_reference(args: RenderArgs) -> Result<()> {
    let wall = args.wall.layout()?;
    // Checked before the (long) load; the cutting planes are then moved into the scene's frame.
    args.quality
        .params(&tessera_model::local_origin::RenderFromWorld::IDENTITY)?;
    let replayed = args
        .replay
        .as_deref()
        .map(|path| crate::record::Session::load(path)?.state_at(args.frame))
        .transpose()?;
    let scene = crate::args::load_scene(&args.scene)?;
    let params = args.quality.params(&scene.render_from_world)?;
    let camera = match &replayed {
        Some(state) => state.camera,
        None => args.scene.camera_mode(&scene.render_from_world, |fov| {
            orbit_of(&scene.bounds(), fov)
        })?,
    }
    .camera_for_frame(args.frame);
    let t0 = Instant::now();
    let shown = replayed.as_ref().map_or(params, |state| state.params);
    let prepared = prepare(&scene, &shown)?;
    let built = t0.elapsed();
    let view = match replayed {
        Some(state) => FrameView {
            lights: state.lights,
            ..FrameView::for_wall(args.frame, &camera, state.params, &wall)
        },
        None => FrameView::for_wall(args.frame, &camera, params, &wall),
    };
    let (image, rendered) = render_timed(&prepared, &view, &wall, args.repeat);
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create --out {}", args.out.display()))?;
    let path = args.out.join("wall.png");
    image.save_png(&path)?;
    write_aovs(&args, &prepared, &view, &wall)?;
    eprintln!(
        "rendered frame {} of a {}x{} wall ({} triangles{}): prepare {:.2} s, render {:.3} s; wrote {}",
        args.frame,
        wall.width(),
        wall.height(),
        scene.triangles.len(),
        scene.volume.as_ref().map_or(String::new(), |v| {
            let d = v.dims();
            format!(", a {}x{}x{} volume", d[0], d[1], d[2])
        }),
        built.as_secs_f64(),
        rendered,
        path.display()
    );
    Ok(())
}

/// The scene ready to trace, with the step of its volume series that `shown` selects.
fn prepare(scene: &Scene, shown: &RenderParams) -> Result<PreparedScene> {
    let mut prepared = PreparedScene::new(scene);
    if !scene.series.is_empty() {
        let step = shown.volume().time_step as usize % scene.series.len();
        let volume = tessera_render::volume::load(&scene.series[step])?;
        // Placed in the series' frame (its first step's).
        prepared.set_volume(std::sync::Arc::new(
            tessera_render::volume::PreparedVolume::new(&volume, &scene.render_from_world),
        ));
    }
    Ok(prepared)
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
