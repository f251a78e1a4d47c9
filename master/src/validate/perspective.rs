//! A wall of physical screens drawn two ways: in perspective from behind and above the viewer,
//! so a screen turned towards the viewer looks turned, over a floor grid of known squares; and
//! in plan from above, to scale, with a scale bar. The viewer is in both, and each screen is
//! labelled with its display and its own resolution as it hangs.

use super::{points, COLOURS, MAX_DRAWN_TILES};
use std::fmt::Write as _;
use tessera_model::screens::ScreenGeometry;
use tessera_model::stereo::{Eye, ViewSource};
use tessera_model::wall::{Tile, TileGrid, WallLayout};

type V = [f64; 3];

fn sub(a: V, b: V) -> V {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn add(a: V, b: V) -> V {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
fn scale(a: V, s: f64) -> V {
    [a[0] * s, a[1] * s, a[2] * s]
}
fn dot(a: V, b: V) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn cross(a: V, b: V) -> V {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
fn unit(a: V) -> V {
    scale(a, 1.0 / dot(a, a).sqrt().max(1e-12))
}

/// Width of the drawing, in SVG pixels.
const WIDTH: f64 = 1200.0;
/// Height of the perspective panel.
const PERSPECTIVE_HEIGHT: f64 = 600.0;
/// The most screens labelled: a ring of hundreds would be all labels.
const MAX_LABELLED: usize = 48;

/// One screen to draw: the first viewport shown on its geometry (stereo's other eye is the
/// same rectangle).
pub(super) struct Screen {
    viewport: usize,
    display: u32,
    eye: Eye,
    geometry: ScreenGeometry,
    /// The viewport's pixels: where it starts in the wall's image, and its size.
    first: (u32, u32),
    size: (u32, u32),
}

pub(super) fn screens(wall: &WallLayout) -> Vec<Screen> {
    let mut out: Vec<Screen> = Vec::new();
    for (i, v) in wall.viewports().iter().enumerate() {
        let ViewSource::Screen(geometry) = v.view else {
            continue;
        };
        if out.iter().any(|s| s.geometry == geometry) {
            continue;
        }
        out.push(Screen {
            viewport: i,
            display: v.display.0,
            eye: v.eye,
            geometry,
            first: (v.x, v.y),
            size: (v.width, v.height),
        });
    }
    out
}

impl Screen {
    /// The point of the screen under pixel `(px, py)` of the wall's image.
    fn at(&self, px: f64, py: f64) -> V {
        let u = (px - self.first.0 as f64) / self.size.0 as f64;
        let v = (py - self.first.1 as f64) / self.size.1 as f64;
        let g = &self.geometry;
        add(g.origin, add(scale(g.across, u), scale(g.down, v)))
    }

    /// Its label: display and eye, then its pixels as the viewer sees them (a panel turned 90°
    /// is taller than wide), then the panel's own if it is turned.
    pub(super) fn label(&self) -> [String; 2] {
        let eye = match self.eye {
            Eye::Centre => "",
            Eye::Left => " L",
            Eye::Right => " R",
        };
        let (w, h) = self.size;
        let across = self.geometry.across;
        let turned = across[1].abs() > 0.7 * dot(across, across).sqrt();
        let pixels = if turned {
            format!("{h}x{w} px (panel {w}x{h}, turned)")
        } else {
            format!("{w}x{h} px")
        };
        [format!("display {}{eye}", self.display), pixels]
    }
}

/// A pinhole camera behind, above and to the right of the viewer, looking at the middle of
/// the wall and viewer, far enough off that all of them are in front of it.
pub(super) struct Camera {
    eye: V,
    forward: V,
    right: V,
    up: V,
}

impl Camera {
    pub(super) fn behind(viewer: V, screens: &[Screen]) -> Camera {
        let corners: Vec<V> = screens.iter().flat_map(|s| s.geometry.corners()).collect();
        let n = corners.len().max(1) as f64;
        let wall_centre = corners
            .iter()
            .fold([0.0; 3], |a, &c| add(a, scale(c, 1.0 / n)));
        let all = corners.iter().chain([&viewer]);
        let centre = scale(add(wall_centre, viewer), 0.5);
        let radius = all
            .map(|&p| dot(sub(p, centre), sub(p, centre)).sqrt())
            .fold(1.0, f64::max);
        // Behind the viewer, seen from the wall; straight back (+z) when the viewer stands in
        // the middle of a ring.
        let mut back = sub(viewer, wall_centre);
        back[1] = 0.0;
        let back = if dot(back, back).sqrt() < 0.2 * radius {
            [0.0, 0.0, 1.0]
        } else {
            unit(back)
        };
        let side = cross([0.0, 1.0, 0.0], back);
        let towards = unit(add(back, add([0.0, 0.6, 0.0], scale(side, 0.45))));
        // Half a field of view of 22°: everything within `radius` of the centre is in view.
        let eye = add(centre, scale(towards, radius / 22f64.to_radians().sin()));
        let forward = unit(sub(centre, eye));
        let right = unit(cross(forward, [0.0, 1.0, 0.0]));
        Camera {
            eye,
            forward,
            right,
            up: cross(right, forward),
        }
    }

    /// Where `p` falls on the picture: right and down, in units of the focal length.
    pub(super) fn project(&self, p: V) -> (f64, f64) {
        let d = sub(p, self.eye);
        let z = dot(d, self.forward).max(1e-9);
        (dot(d, self.right) / z, -dot(d, self.up) / z)
    }

    fn depth(&self, p: V) -> f64 {
        dot(sub(p, self.eye), self.forward)
    }
}

/// Maps points into a box of the drawing: the same scale on both axes, centred.
struct Fit {
    scale: f64,
    offset: (f64, f64),
}

impl Fit {
    fn new(pts: &[(f64, f64)], at: (f64, f64), size: (f64, f64)) -> Fit {
        let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
        for &(x, y) in pts {
            (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x), y1.max(y));
        }
        let (w, h) = ((x1 - x0).max(1e-9), (y1 - y0).max(1e-9));
        let scale = (size.0 / w).min(size.1 / h);
        let offset = (
            at.0 + (size.0 - w * scale) / 2.0 - x0 * scale,
            at.1 + (size.1 - h * scale) / 2.0 - y0 * scale,
        );
        Fit { scale, offset }
    }

    fn map(&self, p: (f64, f64)) -> (f64, f64) {
        (
            self.offset.0 + p.0 * self.scale,
            self.offset.1 + p.1 * self.scale,
        )
    }
}

/// A step of 1, 2 or 5 × 10^k near `span / parts`.
fn nice(span: f64, parts: f64) -> f64 {
    let rough = (span / parts).max(1e-9);
    let decade = 10f64.powf(rough.log10().floor());
    [1.0, 2.0, 5.0, 10.0]
        .into_iter()
        .map(|m| m * decade)
        .find(|s| *s >= rough)
        .unwrap_or(10.0 * decade)
}

/// A length as a label: whole millimetres without decimals.
fn whole(mm: f64) -> String {
    if mm.fract() == 0.0 {
        format!("{mm:.0}")
    } else {
        format!("{mm}")
    }
}

/// The drawing of a wall of screens seen by `viewer` (wall millimetres).
pub(super) fn svg(wall: &WallLayout, grid: &TileGrid, viewer: V) -> String {
    let screens = screens(wall);
    let plan_height = plan_height(&screens, viewer);
    let mut out = String::new();
    let height = 40.0 + PERSPECTIVE_HEIGHT + 40.0 + plan_height + 20.0;
    let _ = writeln!(
        out,
        r##"<svg xmlns="http://www.w3.org/2000/svg" viewBox="0 0 {WIDTH} {height:.0}" width="{WIDTH}" height="{height:.0}" font-family="sans-serif"><rect width="100%" height="100%" fill="white"/>"##
    );
    let _ = writeln!(
        out,
        r#"<text x="16" y="26" font-size="17">in perspective, from behind and above the viewer (wall millimetres, x right, y up, z towards the viewer)</text>"#
    );
    perspective(&mut out, &screens, grid, viewer);
    let top = 40.0 + PERSPECTIVE_HEIGHT;
    let _ = writeln!(
        out,
        r#"<text x="16" y="{:.0}" font-size="17">plan, from above, to scale (x to the right, z down the page)</text>"#,
        top + 26.0
    );
    plan(&mut out, &screens, viewer, top + 40.0, plan_height);
    out.push_str("</svg>\n");
    out
}

/// The plan's height at the drawing's width, bounded so a deep ring stays on the page.
fn plan_height(screens: &[Screen], viewer: V) -> f64 {
    let (x, z) = plan_extent(screens, viewer);
    ((WIDTH - 80.0) * (z.1 - z.0) / (x.1 - x.0).max(1.0)).clamp(220.0, 900.0)
}

/// The x and z ranges of the screens and viewer, a little wider.
fn plan_extent(screens: &[Screen], viewer: V) -> ((f64, f64), (f64, f64)) {
    let pts = screens
        .iter()
        .flat_map(|s| s.geometry.corners())
        .chain([viewer]);
    let (mut x, mut z) = ((f64::MAX, f64::MIN), (f64::MAX, f64::MIN));
    for p in pts {
        x = (x.0.min(p[0]), x.1.max(p[0]));
        z = (z.0.min(p[2]), z.1.max(p[2]));
    }
    let margin = 0.05 * (x.1 - x.0).max(z.1 - z.0).max(1.0);
    ((x.0 - margin, x.1 + margin), (z.0 - margin, z.1 + margin))
}

/// The perspective panel: floor grid, screens far to near with their tiles, the viewer, the
/// labels.
fn perspective(out: &mut String, screens: &[Screen], grid: &TileGrid, viewer: V) {
    let camera = Camera::behind(viewer, screens);
    let floor = screens
        .iter()
        .flat_map(|s| s.geometry.corners())
        .map(|c| c[1])
        .fold(viewer[1], f64::min);
    let (xs, zs) = plan_extent(screens, viewer);
    let step = nice((xs.1 - xs.0).max(zs.1 - zs.0), 8.0);
    let floor_at = |x: f64, z: f64| camera.project([x, floor, z]);
    let mut pts: Vec<(f64, f64)> = screens
        .iter()
        .flat_map(|s| s.geometry.corners())
        .chain([viewer, [viewer[0], floor, viewer[2]]])
        .map(|p| camera.project(p))
        .collect();
    pts.extend(
        [(xs.0, zs.0), (xs.1, zs.0), (xs.0, zs.1), (xs.1, zs.1)].map(|(x, z)| floor_at(x, z)),
    );
    let fit = Fit::new(
        &pts,
        (20.0, 50.0),
        (WIDTH - 40.0, PERSPECTIVE_HEIGHT - 30.0),
    );
    let to = |p: V| fit.map(camera.project(p));
    floor_grid(out, &to, (xs, zs), floor, step);
    let mut order: Vec<&Screen> = screens.iter().collect();
    order.sort_by(|a, b| {
        let depth = |s: &Screen| camera.depth(s.geometry.centre());
        depth(b).total_cmp(&depth(a))
    });
    let tiles = tiles_by_viewport(grid);
    for s in &order {
        let facing = dot(s.geometry.normal(), sub(camera.eye, s.geometry.centre())) > 0.0;
        let outline = if screens.len() > MAX_LABELLED {
            0.5
        } else {
            2.0
        };
        screen_in_perspective(out, s, &tiles, facing, outline, &to);
    }
    viewer_in_perspective(out, screens, viewer, floor, &to);
    if screens.len() <= MAX_LABELLED {
        for s in screens {
            let (x, y) = to(s.geometry.centre());
            let [name, pixels] = s.label();
            let _ = writeln!(
                out,
                r##"<text x="{x:.1}" y="{y:.1}" font-size="13" text-anchor="middle" fill="black" stroke="white" stroke-width="3" paint-order="stroke">{name}<tspan x="{x:.1}" dy="16">{pixels}</tspan></text>"##
            );
        }
    }
}

/// Each viewport's tiles, or none when there are too many to draw.
fn tiles_by_viewport(grid: &TileGrid) -> Vec<Vec<&Tile>> {
    let mut by = vec![Vec::new(); grid.layout().viewports().len()];
    if grid.len() <= MAX_DRAWN_TILES {
        for t in grid.tiles() {
            by[t.viewport as usize].push(t);
        }
    }
    by
}

/// A floor of `step`-millimetre squares under the wall and viewer, for scale and depth.
fn floor_grid(
    out: &mut String,
    to: &dyn Fn(V) -> (f64, f64),
    (xs, zs): ((f64, f64), (f64, f64)),
    floor: f64,
    step: f64,
) {
    // Lines at whole steps, inside the floor's extent, so the grid stays in its panel.
    let (x0, x1) = ((xs.0 / step).ceil() as i64, (xs.1 / step).floor() as i64);
    let (z0, z1) = ((zs.0 / step).ceil() as i64, (zs.1 / step).floor() as i64);
    let line = |out: &mut String, a: V, b: V| {
        let (p, q) = (to(a), to(b));
        let _ = writeln!(
            out,
            r##"<line x1="{:.1}" y1="{:.1}" x2="{:.1}" y2="{:.1}" stroke="#ccc" stroke-width="1"/>"##,
            p.0, p.1, q.0, q.1
        );
    };
    for i in x0..=x1 {
        let x = i as f64 * step;
        line(out, [x, floor, zs.0], [x, floor, zs.1]);
    }
    for k in z0..=z1 {
        let z = k as f64 * step;
        line(out, [xs.0, floor, z], [xs.1, floor, z]);
    }
    let _ = writeln!(
        out,
        r##"<text x="24" y="{:.0}" font-size="13" fill="#666">floor grid: {} mm squares</text>"##,
        40.0 + PERSPECTIVE_HEIGHT - 8.0,
        whole(step)
    );
}

/// A screen's tiles (if it faces the camera) and its outline.
fn screen_in_perspective(
    out: &mut String,
    s: &Screen,
    tiles: &[Vec<&Tile>],
    facing: bool,
    outline: f64,
    to: &dyn Fn(V) -> (f64, f64),
) {
    let corners = s.geometry.corners().map(to);
    if !facing {
        // Its back: the camera is behind it.
        let _ = writeln!(
            out,
            r##"<polygon points="{}" fill="#bbb" fill-opacity="0.5" stroke="#888" stroke-width="1"/>"##,
            points(&corners)
        );
        return;
    }
    let colour = COLOURS[s.display as usize % COLOURS.len()];
    // Dark behind the tiles, whose gaps show it; in the display's colour when the wall has too
    // many tiles to draw.
    let fill = if tiles[s.viewport].is_empty() {
        colour
    } else {
        "#333"
    };
    let _ = writeln!(
        out,
        r##"<polygon points="{}" fill="{fill}"/>"##,
        points(&corners)
    );
    for t in &tiles[s.viewport] {
        let (x, y, w, h) = (t.x as f64, t.y as f64, t.width as f64, t.height as f64);
        let poly =
            [(x, y), (x + w, y), (x + w, y + h), (x, y + h)].map(|(px, py)| to(s.at(px, py)));
        let _ = writeln!(
            out,
            r#"<polygon points="{}" fill="{colour}" fill-opacity="0.75" stroke="white" stroke-width="0.5"/>"#,
            points(&poly)
        );
    }
    let _ = writeln!(
        out,
        r#"<polygon points="{}" fill="none" stroke="black" stroke-width="{outline}"/>"#,
        points(&corners)
    );
}

/// The viewer's eyes, a line down to the floor, and their sight lines to each screen's middle.
fn viewer_in_perspective(
    out: &mut String,
    screens: &[Screen],
    viewer: V,
    floor: f64,
    to: &dyn Fn(V) -> (f64, f64),
) {
    let (x, y) = to(viewer);
    if screens.len() <= 16 {
        for s in screens {
            let (cx, cy) = to(s.geometry.centre());
            let _ = writeln!(
                out,
                r##"<line x1="{x:.1}" y1="{y:.1}" x2="{cx:.1}" y2="{cy:.1}" stroke="#888" stroke-dasharray="4 4"/>"##
            );
        }
    }
    let (fx, fy) = to([viewer[0], floor, viewer[2]]);
    let _ = writeln!(
        out,
        r##"<line x1="{x:.1}" y1="{y:.1}" x2="{fx:.1}" y2="{fy:.1}" stroke="#444" stroke-dasharray="2 3"/><circle cx="{x:.1}" cy="{y:.1}" r="7" fill="#e6a800" stroke="black"/><text x="{:.1}" y="{:.1}" font-size="14">viewer</text>"##,
        x + 10.0,
        y + 5.0
    );
}

/// The plan: each screen's top edge from above, the viewer and their sight lines to each
/// screen's ends, and a scale bar, all at one scale.
fn plan(out: &mut String, screens: &[Screen], viewer: V, top: f64, height: f64) {
    let (xs, zs) = plan_extent(screens, viewer);
    let corners = [(xs.0, zs.0), (xs.1, zs.1)];
    let fit = Fit::new(&corners, (40.0, top), (WIDTH - 80.0, height));
    let to = |p: V| fit.map((p[0], p[2]));
    let (vx, vy) = to(viewer);
    for s in screens {
        let c = s.geometry.corners();
        let colour = COLOURS[s.display as usize % COLOURS.len()];
        let ends = [to(c[0]), to(c[1]), to(c[2]), to(c[3])];
        if screens.len() <= 16 {
            for e in [ends[0], ends[1], ends[2], ends[3]] {
                let _ = writeln!(
                    out,
                    r##"<line x1="{vx:.1}" y1="{vy:.1}" x2="{:.1}" y2="{:.1}" stroke="#bbb" stroke-dasharray="3 4"/>"##,
                    e.0, e.1
                );
            }
        }
        let _ = writeln!(
            out,
            r#"<polygon points="{}" fill="{colour}" stroke="{colour}" stroke-width="5" stroke-linejoin="round"/>"#,
            points(&ends)
        );
        if screens.len() <= MAX_LABELLED {
            // Behind the screen, seen from the viewer: off its line and its sight lines.
            let n = s.geometry.normal();
            let (mx, my) = to(s.geometry.centre());
            let (nx, nz) = (n[0], n[2]);
            let len = nx.hypot(nz).max(1e-9);
            let (lx, ly) = (mx - 16.0 * nx / len, my - 16.0 * nz / len + 4.0);
            let _ = writeln!(
                out,
                r#"<text x="{lx:.1}" y="{ly:.1}" font-size="13" text-anchor="middle">display {}</text>"#,
                s.display
            );
        }
    }
    let _ = writeln!(
        out,
        r##"<circle cx="{vx:.1}" cy="{vy:.1}" r="7" fill="#e6a800" stroke="black"/><text x="{:.1}" y="{:.1}" font-size="14">viewer</text>"##,
        vx + 10.0,
        vy + 5.0
    );
    scale_bar(out, &fit, xs.1 - xs.0, top + height - 6.0);
}

/// A bar of a round number of millimetres at the plan's scale, bottom left.
fn scale_bar(out: &mut String, fit: &Fit, span_mm: f64, y: f64) {
    let mm = nice(span_mm, 5.0);
    let length = mm * fit.scale;
    let _ = writeln!(
        out,
        r#"<path d="M 40 {:.1} v 6 h {length:.1} v -6" fill="none" stroke="black" stroke-width="2"/><text x="{:.1}" y="{:.1}" font-size="13">{} mm</text>"#,
        y - 6.0,
        48.0 + length,
        y + 1.0,
        whole(mm)
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mixed() -> (WallLayout, String) {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../deploy/walls/mixed.toml");
        let text = std::fs::read_to_string(path).unwrap();
        let wall = WallLayout::from_toml(&text, path).unwrap();
        let viewer = wall.viewer().unwrap().position_mm;
        let svg = svg(&wall, &TileGrid::new(wall.clone()), viewer);
        (wall, svg)
    }

    #[test]
    fn validate_labels_each_screen_with_its_own_resolution_as_it_hangs() {
        let (wall, svg) = mixed();
        let labels: Vec<String> = screens(&wall)
            .iter()
            .map(|s| s.label()[1].clone())
            .collect();
        assert_eq!(
            labels,
            [
                "640x360 px",
                "270x480 px (panel 480x270, turned)",
                "400x225 px"
            ]
        );
        for label in &labels {
            assert!(svg.contains(label.as_str()), "{label}");
        }
    }

    #[test]
    fn validate_draws_the_angled_screen_in_perspective_not_flat() {
        let (wall, _) = mixed();
        let screens = screens(&wall);
        let camera = Camera::behind(wall.viewer().unwrap().position_mm, &screens);
        // Right edge over left edge, as drawn: corners are origin (top left), top right,
        // bottom right, bottom left.
        let ratio = |c: [V; 4]| {
            let p = c.map(|c| camera.project(c));
            let edge = |a: (f64, f64), b: (f64, f64)| (a.0 - b.0).hypot(a.1 - b.1);
            edge(p[1], p[2]) / edge(p[0], p[3])
        };
        let angled = screens[2].geometry.corners();
        // The same screen turned back flat against the wall (z = 0).
        let mut flat = angled;
        let width = angled[1][0] - angled[0][0];
        let width = width.hypot(angled[1][2] - angled[0][2]);
        for k in [1, 2] {
            flat[k] = [angled[0][0] + width, angled[k][1], 0.0];
        }
        assert!(
            ratio(angled) > 1.03 * ratio(flat),
            "the edge turned 200 mm towards the viewer is drawn no longer: {} vs {}",
            ratio(angled),
            ratio(flat)
        );
    }

    #[test]
    fn validate_draws_the_viewer_and_the_plan_at_one_scale_with_a_scale_bar() {
        let (_, svg) = mixed();
        assert_eq!(svg.matches(">viewer</text>").count(), 2, "{svg}");
        assert!(svg.contains("floor grid: 200 mm squares"), "{svg}");
        // The scale bar: `h LENGTH` pixels for `N mm`.
        let bar: f64 = svg
            .split(" h ")
            .nth(1)
            .unwrap()
            .split(' ')
            .next()
            .unwrap()
            .parse()
            .unwrap();
        let mm: f64 = svg
            .split("\" font-size=\"13\">")
            .find_map(|t| t.split(" mm</text>").next()?.parse().ok())
            .unwrap();
        // Display 0's plan: 597 mm wide, drawn at the same pixels per mm.
        let plan = svg
            .lines()
            .find(|l| l.contains("stroke=\"#1f77b4\" stroke-width=\"5\""))
            .unwrap();
        let xs: Vec<f64> = plan
            .split("points=\"")
            .nth(1)
            .unwrap()
            .split('"')
            .next()
            .unwrap()
            .split(' ')
            .map(|p| p.split(',').next().unwrap().parse().unwrap())
            .collect();
        let drawn = xs.iter().cloned().fold(f64::MIN, f64::max)
            - xs.iter().cloned().fold(f64::MAX, f64::min);
        assert!(
            ((drawn / 597.0) / (bar / mm) - 1.0).abs() < 0.01,
            "{drawn} px for 597 mm, {bar} px for {mm} mm"
        );
    }
}
