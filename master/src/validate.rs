//! `tessera-master validate WALL [--out FILE.svg]`: checks a wall file (the same checks every
//! node makes when it reads one: fields, sizes, screens that overlap or face away from the
//! viewer, each error naming the screen and field) and draws the wall: a grid as the viewer
//! faces it with its gaps (bezels), a wall of physical screens in perspective and in plan
//! (see [`perspective`]); each with its tiles and which display owns what.

mod perspective;

use anyhow::{Context, Result};
use std::fmt::Write as _;
use std::path::PathBuf;
use tessera_model::screens::ScreenGeometry;
use tessera_model::stereo::{Eye, ViewSource};
use tessera_model::wall::{TileGrid, WallLayout};

#[derive(clap::Args)]
pub struct ValidateArgs {
    /// The wall file to check.
    wall: PathBuf,
    /// Draw the wall into this SVG file.
    #[arg(long)]
    out: Option<PathBuf>,
}

pub fn validate(args: ValidateArgs) -> Result<()> {
    let wall = tessera_cli::wall_file::read_layout(&args.wall)?;
    let grid = TileGrid::new(wall.clone());
    let stereo = wall.stereo();
    println!(
        "{}: {} displays, {} viewports ({:?}), {} tiles of {} pixels, {} pixels shown",
        args.wall.display(),
        wall.display_count(),
        wall.viewports().len(),
        stereo.mode,
        grid.len(),
        wall.tile_size(),
        wall.visible_pixels()
    );
    if let Some(out) = &args.out {
        std::fs::write(out, svg(&wall, &grid))
            .with_context(|| format!("cannot write {}", out.display()))?;
        println!("wrote {}", out.display());
    }
    Ok(())
}

/// Most tiles drawn.
const MAX_DRAWN_TILES: usize = 20_000;

/// One colour per display, cycled.
const COLOURS: [&str; 8] = [
    "#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#17becf", "#8c564b", "#e377c2",
];

/// A 2D outline of each viewport, as the viewer sees the wall from the front (wall x right, y
/// up: the millimetres of a wall of screens; a grid's image pixels), and the tiles in it.
struct Shape {
    display: u32,
    eye: Eye,
    /// Corners, framebuffer order, in drawing units (y down).
    corners: [(f64, f64); 4],
    /// The viewport's pixel size, to place its tiles.
    size: (f64, f64),
    first: (u32, u32),
}

fn shapes(wall: &WallLayout) -> Vec<Shape> {
    wall.viewports()
        .iter()
        .map(|v| {
            let corners = match v.view {
                ViewSource::Image([x, y, w, h]) => [(x, y), (x + w, y), (x + w, y + h), (x, y + h)],
                ViewSource::Screen(g) => front_view(&g),
            };
            Shape {
                display: v.display.0,
                eye: v.eye,
                corners,
                size: (v.width as f64, v.height as f64),
                first: (v.x, v.y),
            }
        })
        .collect()
}

/// A screen's corners seen from the front (y flipped for drawing): screens at an angle show
/// narrower, as they do to the viewer.
fn front_view(g: &ScreenGeometry) -> [(f64, f64); 4] {
    g.corners().map(|p| (p[0], -p[1]))
}

/// Where pixel `(px, py)` of a shape's viewport is drawn.
fn at(s: &Shape, px: f64, py: f64) -> (f64, f64) {
    let (u, v) = (
        (px - s.first.0 as f64) / s.size.0,
        (py - s.first.1 as f64) / s.size.1,
    );
    let [o, a, _, d] = s.corners;
    (
        o.0 + (a.0 - o.0) * u + (d.0 - o.0) * v,
        o.1 + (a.1 - o.1) * u + (d.1 - o.1) * v,
    )
}

fn svg(wall: &WallLayout, grid: &TileGrid) -> String {
    match wall.viewer() {
        Some(viewer) => perspective::svg(wall, grid, viewer.position_mm),
        None => flat_svg(wall, grid),
    }
}

/// A grid wall as its one image: screens, bezels and tiles in the image's pixels.
fn flat_svg(wall: &WallLayout, grid: &TileGrid) -> String {
    let shapes = shapes(wall);
    let pts = shapes.iter().flat_map(|s| s.corners);
    let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
    for (x, y) in pts {
        (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x), y1.max(y));
    }
    let (w, h) = ((x1 - x0).max(1.0), (y1 - y0).max(1.0));
    let margin = 0.04 * w.max(h);
    let stroke = 0.002 * w.max(h);
    let mut out = String::new();
    let _ = writeln!(
        out,
        r#"<svg xmlns="http://www.w3.org/2000/svg" viewBox="{} {} {} {}" width="1200" height="{:.0}">"#,
        x0 - margin,
        y0 - margin,
        w + 2.0 * margin,
        h + 2.0 * margin,
        1200.0 * (h + 2.0 * margin) / (w + 2.0 * margin)
    );
    // The wall behind the screens: what shows between them is bezel (or nothing).
    let _ = writeln!(
        out,
        r##"<rect x="{x0}" y="{y0}" width="{w}" height="{h}" fill="#333"/>"##
    );
    // A wall of hundreds of screens draws its screens alone: its tiles would be a smear.
    let tiles = if grid.len() <= MAX_DRAWN_TILES {
        grid.tiles()
    } else {
        &[]
    };
    for tile in tiles {
        let s = &shapes[tile.viewport as usize];
        let (x, y, tw, th) = (
            tile.x as f64,
            tile.y as f64,
            tile.width as f64,
            tile.height as f64,
        );
        let poly = [
            at(s, x, y),
            at(s, x + tw, y),
            at(s, x + tw, y + th),
            at(s, x, y + th),
        ];
        let _ = writeln!(
            out,
            r#"<polygon points="{}" fill="{}" fill-opacity="{}" stroke="white" stroke-width="{:.3}"/>"#,
            points(&poly),
            COLOURS[s.display as usize % COLOURS.len()],
            if s.eye == Eye::Right { 0.45 } else { 0.75 },
            stroke * 0.5
        );
    }
    for s in &shapes {
        let (cx, cy) = s
            .corners
            .iter()
            .fold((0.0, 0.0), |a, p| (a.0 + p.0 / 4.0, a.1 + p.1 / 4.0));
        let eye = match s.eye {
            Eye::Centre => "",
            Eye::Left => " L",
            Eye::Right => " R",
        };
        let _ = writeln!(
            out,
            r#"<polygon points="{}" fill="none" stroke="black" stroke-width="{:.3}"/><text x="{cx:.1}" y="{cy:.1}" font-size="{:.1}" text-anchor="middle" fill="white">display {}{eye} ({}x{})</text>"#,
            points(&s.corners),
            stroke * 2.0,
            0.04 * h.min(w),
            s.display,
            s.size.0,
            s.size.1
        );
    }
    out.push_str("</svg>\n");
    out
}

fn points(p: &[(f64, f64)]) -> String {
    p.iter()
        .map(|(x, y)| format!("{x:.2},{y:.2}"))
        .collect::<Vec<_>>()
        .join(" ")
}
