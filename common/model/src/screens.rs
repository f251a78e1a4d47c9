//! A wall of physical screens: each a rectangle in millimetres with a resolution of its own,
//! on one plane or at angles to each other (CAVE-like), seen from a viewer; each screen gets
//! its own off-axis frustum, so a straight line of the scene stays straight across the gaps
//! between screens (as the corner coordinates of Equalizer's `.eqc` walls and nDisplay's
//! positioned rectangles do).
//!
//! Wall coordinates are millimetres: x to the right, y up, z towards the viewer; a screen on
//! the plane z = 0 may be given by its bottom-left corner and size (`x_mm`, `y_mm`,
//! `width_mm`, `height_mm`), any screen by three corners (`bottom_left_mm`,
//! `bottom_right_mm`, `top_left_mm`). `rotation` (0, 90, 180, 270 degrees clockwise, as the
//! panel is mounted) turns the framebuffer on the screen: a landscape panel hung as a portrait
//! screen is `resolution = [1920, 1080]`, `rotation = 90`. A `[ring]` table places screens
//! around the viewer in rows (the Reality Deck's 416 screens).

use crate::stereo::Stereo;
use crate::wall::WallError;
use serde::{Deserialize, Serialize};

/// A wall of physical screens as a wall file gives it, not yet checked.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PhysicalSpec {
    /// Edge length of the square tiles each viewport is cut into, in pixels (default 64).
    #[serde(default = "crate::wall::default_tile_size")]
    pub tile_size: u32,
    /// The `[viewer]` table: where the viewer's eyes are and the scene's scale. Required.
    pub viewer: Viewer,
    /// The `[stereo]` table; mono when absent.
    #[serde(default)]
    pub stereo: Stereo,
    /// The `[[screen]]` tables, in display order (two displays a screen in `displays` stereo).
    #[serde(default, rename = "screen")]
    pub screens: Vec<ScreenSpec>,
    /// Screens placed around the viewer, after those of `screens`.
    #[serde(default)]
    pub ring: Option<RingSpec>,
}

/// Where the viewer's eyes are, and how the wall's millimetres map to the scene.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Viewer {
    /// The point between the eyes, wall millimetres. It is where the camera's eye is, looking
    /// along the camera: wall x is the camera's right, y its up, -z its forward.
    pub position_mm: [f64; 3],
    /// Scene units per metre of the wall (1: a scene in metres), for the eyes' separation.
    #[serde(default = "one")]
    pub scene_units_per_m: f64,
}

fn one() -> f64 {
    1.0
}

/// One screen as a wall file gives it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScreenSpec {
    /// Its framebuffer, WIDTH and HEIGHT in pixels, as the panel has them (before rotation).
    pub resolution: [u32; 2],
    /// Left edge of a screen on the plane z = 0, in wall millimetres; given with `y_mm`,
    /// `width_mm` and `height_mm` instead of the three corners.
    pub x_mm: Option<f64>,
    /// Bottom edge of a screen on the plane z = 0, in millimetres.
    pub y_mm: Option<f64>,
    /// Width of a screen on the plane z = 0 as it hangs (after rotation), in millimetres.
    pub width_mm: Option<f64>,
    /// Height of a screen on the plane z = 0 as it hangs (after rotation), in millimetres.
    pub height_mm: Option<f64>,
    /// Bottom-left corner as the viewer sees the screen hang, `[x, y, z]` in millimetres; given
    /// with `bottom_right_mm` and `top_left_mm`, for a screen at any angle.
    pub bottom_left_mm: Option<[f64; 3]>,
    /// Bottom-right corner, `[x, y, z]` in millimetres: the bottom edge runs from
    /// `bottom_left_mm` to it.
    pub bottom_right_mm: Option<[f64; 3]>,
    /// Top-left corner, `[x, y, z]` in millimetres; the left edge must be at right angles to the
    /// bottom edge.
    pub top_left_mm: Option<[f64; 3]>,
    /// Degrees clockwise the panel is turned as mounted: 0, 90, 180 or 270.
    #[serde(default)]
    pub rotation: u32,
}

/// Screens in rows around the viewer, facing it, side by side with a gap between them.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RingSpec {
    /// Screens in each row, spread evenly around the full circle; 3 or more.
    pub screens_around: u32,
    /// Rows of screens, stacked upwards from `bottom_mm`; 1 or more.
    pub rows: u32,
    /// Each screen's framebuffer, `[width, height]` in pixels.
    pub resolution: [u32; 2],
    /// Width of each screen, in millimetres.
    pub screen_width_mm: f64,
    /// Height of each screen, in millimetres.
    pub screen_height_mm: f64,
    /// Between neighbouring screens, around and up.
    #[serde(default)]
    pub gap_mm: f64,
    /// Height of the lowest row's bottom edge.
    #[serde(default)]
    pub bottom_mm: f64,
}

/// A screen's rectangle as its framebuffer lies on it: `origin` is the corner where the
/// framebuffer's first row starts, `across` runs along that row to its end, `down` down the
/// first column (whole lengths, wall millimetres).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ScreenGeometry {
    /// The corner where the framebuffer's first row starts, in wall millimetres.
    pub origin: [f64; 3],
    /// From `origin` to the end of the first row: the framebuffer's x axis, full width.
    pub across: [f64; 3],
    /// From `origin` to the end of the first column: the framebuffer's y axis, full height.
    pub down: [f64; 3],
}

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
fn length(a: V) -> f64 {
    dot(a, a).sqrt()
}

impl ScreenGeometry {
    /// The side facing the viewer: a unit vector out of the screen's front.
    pub fn normal(&self) -> [f64; 3] {
        let n = cross(self.down, self.across);
        scale(n, 1.0 / length(n))
    }

    /// The screen's centre, in wall millimetres.
    pub fn centre(&self) -> [f64; 3] {
        add(self.origin, scale(add(self.across, self.down), 0.5))
    }

    /// The four corners, framebuffer order: origin, along the row, the far one, down.
    pub fn corners(&self) -> [[f64; 3]; 4] {
        let o = self.origin;
        [
            o,
            add(o, self.across),
            add(add(o, self.across), self.down),
            add(o, self.down),
        ]
    }
}

/// A screen's framebuffer size and where it lies, checked.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Screen {
    /// Framebuffer width in pixels, as the panel has it (before rotation).
    pub width: u32,
    /// Framebuffer height in pixels, as the panel has it (before rotation).
    pub height: u32,
    /// Where the framebuffer lies on the wall, as the panel is turned.
    pub geometry: ScreenGeometry,
}

fn screen_error(screen: usize, field: &'static str, message: impl Into<String>) -> WallError {
    WallError::Screen {
        screen,
        field,
        message: message.into(),
    }
}

impl ScreenSpec {
    /// Screen `index` checked and placed.
    fn resolve(&self, index: usize, viewer: V) -> Result<Screen, WallError> {
        let [w, h] = self.resolution;
        let max = crate::wall::MAX_WALL_SIDE;
        if w == 0 || h == 0 || w > max || h > max {
            return Err(screen_error(
                index,
                "resolution",
                format!("{w}x{h} is not 1 to {max} pixels a side"),
            ));
        }
        let (bl, br, tl) = self.corners(index)?;
        let geometry = self.turned(index, bl, br, tl)?;
        if dot(sub(viewer, geometry.centre()), geometry.normal()) <= 0.0 {
            // A screen placed by x_mm faces +z: only the viewer can be on the wrong side.
            if self.is_flat() {
                return Err(WallError::File {
                    path: "[viewer]".into(),
                    message: format!("position_mm is behind screen {index}, which is on the plane z = 0 facing +z: the viewer needs a z of more than 0"),
                });
            }
            return Err(screen_error(
                index,
                "bottom_left_mm",
                "faces away from the viewer, who is behind its plane and cannot see it (swap bottom_left_mm and bottom_right_mm to turn it round)",
            ));
        }
        Ok(Screen {
            width: w,
            height: h,
            geometry,
        })
    }

    /// Whether the screen is placed on the plane z = 0 by `x_mm`, `y_mm`, `width_mm` and
    /// `height_mm` rather than by its corners.
    fn is_flat(&self) -> bool {
        [self.x_mm, self.y_mm, self.width_mm, self.height_mm]
            .iter()
            .any(Option::is_some)
    }

    /// The field that places the screen, as the file gave it: where it is wrong, that is the
    /// field to name.
    fn place_field(&self) -> &'static str {
        if self.is_flat() {
            "x_mm"
        } else {
            "bottom_left_mm"
        }
    }

    /// The bottom-left, bottom-right and top-left corners of screen `index`, from whichever
    /// of the two sets of fields it gives, checked to make a rectangle; an error names the
    /// fields the file used.
    fn corners(&self, index: usize) -> Result<(V, V, V), WallError> {
        let flat = [self.x_mm, self.y_mm, self.width_mm, self.height_mm];
        let corners = [self.bottom_left_mm, self.bottom_right_mm, self.top_left_mm];
        let (points, names) = match (
            flat.iter().all(Option::is_some),
            self.is_flat(),
            corners.iter().all(Option::is_some),
        ) {
            (true, _, false) if corners.iter().all(Option::is_none) => {
                (self.flat_corners(index)?, ["x_mm", "width_mm", "height_mm"])
            }
            (false, false, true) => (
                corners.map(|c| c.unwrap_or_default()),
                ["bottom_left_mm", "bottom_right_mm", "top_left_mm"],
            ),
            _ => {
                return Err(screen_error(
                    index,
                    self.place_field(),
                    "give x_mm, y_mm, width_mm and height_mm, or bottom_left_mm, bottom_right_mm and top_left_mm, one set whole",
                ))
            }
        };
        if let Some(i) = points.iter().position(|p| p.iter().any(|v| !v.is_finite())) {
            return Err(screen_error(
                index,
                names[i],
                "holds a value that is not finite",
            ));
        }
        let [bl, br, tl] = points;
        let (right, up) = (sub(br, bl), sub(tl, bl));
        for (field, edge) in [(names[1], right), (names[2], up)] {
            if length(edge) < 1e-6 {
                let why = if self.is_flat() {
                    "is too small to tell apart at that x_mm and y_mm: a screen needs a size"
                } else {
                    "is on bottom_left_mm: a screen needs a size"
                };
                return Err(screen_error(index, field, why));
            }
        }
        if dot(right, up).abs() > 1e-3 * length(right) * length(up) {
            return Err(screen_error(
                index,
                "top_left_mm",
                "makes the screen a parallelogram: its edges must be at right angles",
            ));
        }
        Ok((bl, br, tl))
    }

    /// The corners of a screen given by `x_mm`, `y_mm`, `width_mm` and `height_mm`, each
    /// number checked on its own.
    fn flat_corners(&self, index: usize) -> Result<[V; 3], WallError> {
        let [x, y, width, height] =
            [self.x_mm, self.y_mm, self.width_mm, self.height_mm].map(|v| v.unwrap_or_default());
        for (field, v) in [("x_mm", x), ("y_mm", y)] {
            if !v.is_finite() {
                return Err(screen_error(
                    index,
                    field,
                    format!("is {v}: not a finite number of millimetres"),
                ));
            }
        }
        for (field, v) in [("width_mm", width), ("height_mm", height)] {
            if !(v > 0.0 && v.is_finite()) {
                return Err(screen_error(
                    index,
                    field,
                    format!("is {v}: a screen needs a size"),
                ));
            }
        }
        Ok([[x, y, 0.0], [x + width, y, 0.0], [x, y + height, 0.0]])
    }

    /// Where the framebuffer's first row starts, and which way its rows and columns run, as
    /// the panel is turned.
    fn turned(&self, index: usize, bl: V, br: V, tl: V) -> Result<ScreenGeometry, WallError> {
        let (right, up) = (sub(br, bl), sub(tl, bl));
        let tr = add(tl, right);
        let down = scale(up, -1.0);
        let left = scale(right, -1.0);
        let (origin, across, down) = match self.rotation {
            0 => (tl, right, down),
            90 => (tr, down, left),
            180 => (br, left, up),
            270 => (bl, up, right),
            r => {
                return Err(screen_error(
                    index,
                    "rotation",
                    format!("is {r}: 0, 90, 180 or 270 degrees"),
                ))
            }
        };
        Ok(ScreenGeometry {
            origin,
            across,
            down,
        })
    }
}

impl RingSpec {
    /// The ring's screens, row by row from the bottom, each row around from straight ahead
    /// (-z from the viewer) to the right.
    fn screens(&self, viewer: V) -> Result<Vec<ScreenSpec>, WallError> {
        let n = self.screens_around;
        let fine = n >= 3
            && self.rows >= 1
            && self.screen_width_mm > 0.0
            && self.screen_height_mm > 0.0
            && self.screen_width_mm.is_finite()
            && self.screen_height_mm.is_finite()
            && self.gap_mm >= 0.0
            && self.gap_mm.is_finite()
            && self.bottom_mm.is_finite();
        if !fine {
            return Err(WallError::File {
                path: "[ring]".into(),
                message:
                    "needs at least 3 screens around, a row, positive sizes and a gap of 0 or more"
                        .into(),
            });
        }
        let count = n as u64 * self.rows as u64;
        if count > crate::wall::MAX_DISPLAYS as u64 {
            return Err(WallError::TooManyDisplays {
                displays: count,
                max: crate::wall::MAX_DISPLAYS,
            });
        }
        let step = std::f64::consts::TAU / n as f64;
        // Close enough that neighbours' edges are one gap apart.
        let radius = (self.screen_width_mm + self.gap_mm) / (2.0 * (step / 2.0).tan());
        let (w, h) = (self.screen_width_mm, self.screen_height_mm);
        let mut out = Vec::new();
        for row in 0..self.rows {
            let bottom = self.bottom_mm + row as f64 * (h + self.gap_mm);
            for k in 0..n {
                let angle = k as f64 * step;
                let (s, c) = angle.sin_cos();
                let centre = [viewer[0] + s * radius, bottom, viewer[2] - c * radius];
                let right = [c, 0.0, s];
                let bl = sub(centre, scale(right, w / 2.0));
                out.push(ScreenSpec {
                    resolution: self.resolution,
                    bottom_left_mm: Some(bl),
                    bottom_right_mm: Some(add(bl, scale(right, w))),
                    top_left_mm: Some(add(bl, [0.0, h, 0.0])),
                    ..ScreenSpec::default()
                });
            }
        }
        Ok(out)
    }
}

impl PhysicalSpec {
    /// Every screen, checked and placed, the ring's after the listed ones.
    ///
    /// # Errors
    /// A screen's bad field (named, with the screen's index), a viewer that is not finite,
    /// no screen at all, or two screens of one plane that overlap.
    pub fn resolve(&self) -> Result<Vec<Screen>, WallError> {
        let viewer = self.viewer.position_mm;
        if !(viewer.iter().all(|v| v.is_finite())
            && self.viewer.scene_units_per_m.is_finite()
            && self.viewer.scene_units_per_m > 0.0)
        {
            return Err(WallError::File {
                path: "[viewer]".into(),
                message: "position_mm and scene_units_per_m must be finite, the scale positive"
                    .into(),
            });
        }
        if self.screens.len() > crate::wall::MAX_DISPLAYS as usize {
            return Err(WallError::TooManyDisplays {
                displays: self.screens.len() as u64,
                max: crate::wall::MAX_DISPLAYS,
            });
        }
        let mut specs = self.screens.clone();
        if let Some(ring) = &self.ring {
            specs.extend(ring.screens(viewer)?);
        }
        if specs.is_empty() {
            return Err(WallError::File {
                path: "[[screen]]".into(),
                message: "a wall of screens needs at least one [[screen]] or a [ring]".into(),
            });
        }
        let screens = specs
            .iter()
            .enumerate()
            .map(|(i, s)| s.resolve(i, viewer))
            .collect::<Result<Vec<_>, _>>()?;
        if let Some((a, b)) = overlapping(&screens) {
            return Err(match self.screens.get(b) {
                Some(listed) => {
                    screen_error(b, listed.place_field(), format!("overlaps screen {a}"))
                }
                // The ring's screens are placed by the ring, not by fields of their own.
                None => WallError::File {
                    path: "[ring]".into(),
                    message: format!("its screen {b} overlaps screen {a}"),
                },
            });
        }
        Ok(screens)
    }
}

/// The first two screens of one plane whose rectangles overlap (touching is not overlapping).
fn overlapping(screens: &[Screen]) -> Option<(usize, usize)> {
    for (b, sb) in screens.iter().enumerate() {
        for (a, sa) in screens.iter().enumerate().take(b) {
            let (ga, gb) = (&sa.geometry, &sb.geometry);
            let n = ga.normal();
            let coplanar =
                dot(n, gb.normal()) > 1.0 - 1e-9 && dot(sub(gb.origin, ga.origin), n).abs() < 1e-3;
            if !coplanar {
                continue;
            }
            // In a's own axes on the plane.
            let (u, v) = (ga.across, ga.down);
            let (lu, lv) = (dot(u, u), dot(v, v));
            let span = |g: &ScreenGeometry| {
                let pts = g.corners().map(|p| {
                    let d = sub(p, ga.origin);
                    (dot(d, u) / lu, dot(d, v) / lv)
                });
                let lo =
                    |f: fn(&(f64, f64)) -> f64| pts.iter().map(f).fold(f64::INFINITY, f64::min);
                let hi =
                    |f: fn(&(f64, f64)) -> f64| pts.iter().map(f).fold(f64::NEG_INFINITY, f64::max);
                (lo(|p| p.0), hi(|p| p.0), lo(|p| p.1), hi(|p| p.1))
            };
            let (a0, a1, a2, a3) = span(ga);
            let (b0, b1, b2, b3) = span(gb);
            let eps = 1e-6;
            if a0 < b1 - eps && b0 < a1 - eps && a2 < b3 - eps && b2 < a3 - eps {
                return Some((a, b));
            }
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(screens: Vec<ScreenSpec>) -> PhysicalSpec {
        PhysicalSpec {
            tile_size: 64,
            viewer: Viewer {
                position_mm: [500.0, 300.0, 1500.0],
                scene_units_per_m: 1.0,
            },
            stereo: Stereo::default(),
            screens,
            ring: None,
        }
    }

    fn flat(x: f64, y: f64, w: f64, h: f64, res: [u32; 2]) -> ScreenSpec {
        ScreenSpec {
            resolution: res,
            x_mm: Some(x),
            y_mm: Some(y),
            width_mm: Some(w),
            height_mm: Some(h),
            ..ScreenSpec::default()
        }
    }

    #[test]
    fn a_portrait_panel_turns_its_framebuffer_on_the_screen() {
        let mut portrait = flat(0.0, 0.0, 300.0, 500.0, [1920, 1080]);
        portrait.rotation = 90;
        let s = spec(vec![portrait]).resolve().unwrap();
        let g = s[0].geometry;
        // The first row starts at the top-right corner and runs down the screen.
        assert_eq!(g.origin, [300.0, 500.0, 0.0]);
        assert_eq!(g.across, [0.0, -500.0, 0.0]);
        assert_eq!(g.down, [-300.0, 0.0, 0.0]);
        assert_eq!(g.normal(), [0.0, 0.0, 1.0]);
    }

    #[test]
    fn each_kind_of_broken_screen_is_refused_naming_screen_and_field() {
        let ok = flat(0.0, 0.0, 500.0, 300.0, [640, 360]);
        let cases: Vec<(ScreenSpec, &str)> = vec![
            (
                ScreenSpec {
                    resolution: [0, 360],
                    ..ok
                },
                "resolution",
            ),
            (
                ScreenSpec {
                    width_mm: Some(0.0),
                    ..ok
                },
                "width_mm",
            ),
            (
                ScreenSpec {
                    height_mm: None,
                    ..ok
                },
                "x_mm",
            ),
            (ScreenSpec { rotation: 45, ..ok }, "rotation"),
            (
                ScreenSpec {
                    bottom_left_mm: Some([0.0; 3]),
                    ..ok
                },
                "x_mm",
            ),
        ];
        for (bad, field) in cases {
            let err = spec(vec![ok, bad]).resolve().unwrap_err().to_string();
            assert!(err.contains("screen 1") && err.contains(field), "{err}");
        }
        // Facing away: corners given right to left as seen from the viewer.
        let away = ScreenSpec {
            resolution: [640, 360],
            bottom_left_mm: Some([500.0, 0.0, 0.0]),
            bottom_right_mm: Some([0.0, 0.0, 0.0]),
            top_left_mm: Some([500.0, 300.0, 0.0]),
            ..ScreenSpec::default()
        };
        let err = spec(vec![away]).resolve().unwrap_err().to_string();
        assert!(
            err.contains("screen 0") && err.contains("faces away"),
            "{err}"
        );
        // Overlapping on one plane, and merely touching.
        let err = spec(vec![ok, flat(400.0, 0.0, 500.0, 300.0, [640, 360])])
            .resolve()
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("screen 1") && err.contains("overlaps screen 0"),
            "{err}"
        );
        assert!(spec(vec![ok, flat(500.0, 0.0, 500.0, 300.0, [640, 360])])
            .resolve()
            .is_ok());
    }

    #[test]
    fn an_error_names_the_fields_the_screen_was_given_by() {
        // A bad x_mm, an overlap and a viewer behind the wall were all blamed on
        // bottom_left_mm, a field the file did not use.
        let ok = flat(0.0, 0.0, 500.0, 300.0, [640, 360]);
        let cases = [
            (
                flat(f64::NAN, 0.0, 500.0, 300.0, [640, 360]),
                "`x_mm` is NaN",
            ),
            (
                flat(0.0, f64::INFINITY, 500.0, 300.0, [640, 360]),
                "`y_mm` is inf",
            ),
            (
                flat(1e308, 0.0, 500.0, 300.0, [640, 360]),
                "`width_mm` is too small",
            ),
            (
                flat(400.0, 0.0, 500.0, 300.0, [640, 360]),
                "`x_mm` overlaps screen 0",
            ),
        ];
        for (bad, said) in cases {
            let err = spec(vec![ok, bad]).resolve().unwrap_err().to_string();
            assert!(err.contains(&format!("screen 1: {said}")), "{err}");
            assert!(!err.contains("bottom_left_mm"), "{err}");
        }
        let mut behind = spec(vec![ok]);
        behind.viewer.position_mm[2] = -100.0;
        let err = behind.resolve().unwrap_err().to_string();
        assert!(
            err.contains("[viewer]") && err.contains("position_mm is behind screen 0"),
            "{err}"
        );
        let angled = ScreenSpec {
            resolution: [640, 360],
            bottom_left_mm: Some([0.0; 3]),
            bottom_right_mm: Some([500.0, 0.0, 0.0]),
            top_left_mm: Some([0.0, f64::NAN, 0.0]),
            ..ScreenSpec::default()
        };
        let err = spec(vec![angled]).resolve().unwrap_err().to_string();
        assert!(err.contains("`top_left_mm` holds a value"), "{err}");
    }

    #[test]
    fn a_ring_surrounds_the_viewer_with_screens_facing_it_edge_to_edge() {
        let mut s = spec(vec![]);
        s.ring = Some(RingSpec {
            screens_around: 104,
            rows: 4,
            resolution: [2560, 1440],
            screen_width_mm: 597.0,
            screen_height_mm: 336.0,
            gap_mm: 10.0,
            bottom_mm: 0.0,
        });
        let screens = s.resolve().unwrap();
        assert_eq!(screens.len(), 416);
        let viewer = s.viewer.position_mm;
        let (a, b) = (&screens[0].geometry, &screens[1].geometry);
        // Neighbours one gap apart at their near edges, each seen from the front.
        let gap = length(sub(add(a.origin, a.across), b.origin));
        assert!((gap - 10.0).abs() < 0.5, "{gap}");
        for sc in &screens {
            let g = &sc.geometry;
            assert!(dot(sub(viewer, g.centre()), g.normal()) > 0.0);
        }
    }
}
