//! Where each display's window goes on its host's desktop: a position, a size (the screen's
//! own resolution unless said otherwise) or borderless full screen on a monitor. A wall file
//! may say it for every display in `[[window]]` tables, and it travels in the session, so
//! that three windows of a desk wall open side by side instead of on top of each other.
//!
//! ```toml
//! columns = 3
//! rows = 1
//! screen_width = 640
//! screen_height = 360
//!
//! [[window]]
//! display = 1
//! x = 640
//! y = 0
//! ```

use crate::wall::{WallError, WallLayout, WallSpec};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Largest window side and position offset accepted, in pixels.
pub const MAX_WINDOW_SIDE: u32 = 1 << 15;
/// Monitors a full-screen window may name (0 is the first).
pub const MAX_MONITOR: u32 = 63;

/// One display's window.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct WindowPlacement {
    /// Top-left corner on the desktop, pixels; `None` leaves it to the window manager.
    pub position: Option<(i32, i32)>,
    /// Inner size; `None` is the screen's resolution (no scaling).
    pub size: Option<(u32, u32)>,
    /// Borderless full screen on monitor N (the frame is scaled to the monitor).
    pub fullscreen: Option<u32>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct WindowPlacementRaw {
    position: Option<(i32, i32)>,
    size: Option<(u32, u32)>,
    fullscreen: Option<u32>,
}

impl WindowPlacement {
    /// Checks the placement's bounds.
    ///
    /// # Errors
    /// A position or size beyond [`MAX_WINDOW_SIDE`], an empty size, a monitor past
    /// [`MAX_MONITOR`].
    pub fn check(&self) -> Result<(), PlacementError> {
        let limit = MAX_WINDOW_SIDE as i32;
        if let Some((x, y)) = self.position {
            if x.abs() > limit || y.abs() > limit {
                return Err(PlacementError::Position { x, y });
            }
        }
        if let Some((w, h)) = self.size {
            if w == 0 || h == 0 || w > MAX_WINDOW_SIDE || h > MAX_WINDOW_SIDE {
                return Err(PlacementError::Size { w, h });
            }
        }
        if let Some(m) = self.fullscreen.filter(|&m| m > MAX_MONITOR) {
            return Err(PlacementError::Monitor(m));
        }
        Ok(())
    }
}

/// Why a window placement was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum PlacementError {
    /// The window's corner is more than [`MAX_WINDOW_SIDE`] pixels from the desktop's origin on
    /// either axis.
    #[error("window position {x},{y} is beyond ±{MAX_WINDOW_SIDE}")]
    Position {
        /// Left edge asked for, in desktop pixels.
        x: i32,
        /// Top edge asked for, in desktop pixels.
        y: i32,
    },
    /// The window's size is 0 or more than [`MAX_WINDOW_SIDE`] pixels on a side.
    #[error("window size {w}x{h} must be from 1 to {MAX_WINDOW_SIDE} on each side")]
    Size {
        /// Inner width asked for, in pixels.
        w: u32,
        /// Inner height asked for, in pixels.
        h: u32,
    },
    /// A full-screen window names a monitor past [`MAX_MONITOR`].
    #[error("monitor {0} is past the last one accepted ({MAX_MONITOR})")]
    Monitor(u32),
}

impl TryFrom<WindowPlacementRaw> for WindowPlacement {
    type Error = PlacementError;

    fn try_from(raw: WindowPlacementRaw) -> Result<Self, PlacementError> {
        let placement = WindowPlacement {
            position: raw.position,
            size: raw.size,
            fullscreen: raw.fullscreen,
        };
        placement.check()?;
        Ok(placement)
    }
}

impl<'de> Deserialize<'de> for WindowPlacement {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        crate::checked::deserialize::<D, WindowPlacementRaw, Self>(d)
    }
}

/// A `[[window]]` table of a wall file.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct WindowEntry {
    display: u32,
    x: Option<i32>,
    y: Option<i32>,
    width: Option<u32>,
    height: Option<u32>,
    fullscreen: Option<u32>,
}

/// A wall file: the wall, and where its displays' windows go.
#[derive(Clone, Debug, PartialEq)]
pub struct WallFile {
    /// The wall the file describes.
    pub layout: WallLayout,
    /// Each `[[window]]` table's placement, by display id; displays without a table are absent.
    pub windows: BTreeMap<u32, WindowPlacement>,
}

impl WallFile {
    /// Reads a wall file from TOML text; `origin` names the source in errors.
    pub fn from_toml(text: &str, origin: &str) -> Result<WallFile, WallError> {
        let file_error = |message: String| WallError::File {
            path: origin.to_string(),
            message,
        };
        let mut table: toml::Table =
            toml::from_str(text).map_err(|e| file_error(e.to_string().trim_end().to_string()))?;
        let windows = table.remove("window");
        let toml_error = |e: toml::de::Error| file_error(e.to_string().trim_end().to_string());
        // A wall of physical screens has a viewer; a grid has none.
        let physical = ["screen", "ring", "viewer"]
            .iter()
            .any(|k| table.contains_key(*k));
        let layout = if physical {
            let spec: crate::screens::PhysicalSpec = table.try_into().map_err(toml_error)?;
            WallLayout::new(crate::wall::WallDescription::Screens(spec))
        } else {
            let stereo: crate::stereo::Stereo = match table.remove("stereo") {
                Some(v) => v.try_into().map_err(|e: toml::de::Error| {
                    file_error(format!("[stereo]: {}", e.to_string().trim_end()))
                })?,
                None => Default::default(),
            };
            let spec: WallSpec = table.try_into().map_err(toml_error)?;
            spec.build_stereo(stereo)
        }
        .map_err(|e| match e {
            // A section's error ([viewer], [ring]) is part of this file's, not a second file.
            WallError::File { path, message } => file_error(format!("{path}: {message}")),
            e => file_error(e.to_string()),
        })?;
        let entries: Vec<WindowEntry> = match windows {
            None => Vec::new(),
            Some(value) => value.try_into().map_err(|e: toml::de::Error| {
                file_error(format!("[[window]]: {}", e.to_string().trim_end()))
            })?,
        };
        let mut windows = BTreeMap::new();
        for e in entries {
            if e.display >= layout.display_count() {
                return Err(file_error(format!(
                    "[[window]] display {} is not one of the {} displays",
                    e.display,
                    layout.display_count()
                )));
            }
            let size = match (e.width, e.height) {
                (Some(w), Some(h)) => Some((w, h)),
                (None, None) => None,
                _ => {
                    return Err(file_error(format!(
                        "[[window]] display {}: give width and height together",
                        e.display
                    )))
                }
            };
            let placement = WindowPlacement {
                position: (e.x.is_some() || e.y.is_some())
                    .then(|| (e.x.unwrap_or(0), e.y.unwrap_or(0))),
                size,
                fullscreen: e.fullscreen,
            };
            placement
                .check()
                .map_err(|m| file_error(format!("[[window]] display {}: {m}", e.display)))?;
            if windows.insert(e.display, placement).is_some() {
                return Err(file_error(format!(
                    "[[window]] display {} is placed twice",
                    e.display
                )));
            }
        }
        Ok(WallFile { layout, windows })
    }
}

/// Windows for every display of `layout` on one desktop, none on top of another: each at
/// `origin` plus its screen's place in the wall's image (a grid's screens side by side, the
/// bezels as gaps), or, with `fullscreen_all`, display N full screen on monitor N. What `local`
/// gives a wall whose file says nothing of windows.
///
/// # Examples
/// ```
/// use tessera_model::wall::WallSpec;
/// use tessera_model::window::side_by_side;
///
/// let wall = WallSpec::grid(3, 1, 640, 360).build().unwrap();
/// let windows = side_by_side(&wall, (0, 0), false);
/// let xs: Vec<_> = windows.values().map(|w| w.position.unwrap().0).collect();
/// assert_eq!(xs, [0, 640, 1280]);
/// ```
pub fn side_by_side(
    layout: &WallLayout,
    origin: (i32, i32),
    fullscreen_all: bool,
) -> BTreeMap<u32, WindowPlacement> {
    layout
        .screens()
        .map(|screen| {
            let placement = if fullscreen_all {
                WindowPlacement {
                    fullscreen: Some(screen.id.0.min(MAX_MONITOR)),
                    ..WindowPlacement::default()
                }
            } else {
                let at = |o: i32, p: u32| o.saturating_add(i32::try_from(p).unwrap_or(i32::MAX));
                WindowPlacement {
                    position: Some((at(origin.0, screen.x), at(origin.1, screen.y))),
                    ..WindowPlacement::default()
                }
            };
            (screen.id.0, placement)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    const DESK: &str = "columns = 3\nrows = 1\nscreen_width = 640\nscreen_height = 360\n";

    #[test]
    fn grid_windows_go_side_by_side_from_the_origin_or_one_per_monitor() {
        let wall = WallSpec::grid(3, 2, 640, 360).bezel(10).build().unwrap();
        let windows = side_by_side(&wall, (100, -20), false);
        let at = |d: u32| windows[&d].position.unwrap();
        assert_eq!(at(0), (100, -20));
        assert_eq!(
            at(1),
            (100 + 650, -20),
            "the bezel is a gap between windows"
        );
        assert_eq!(
            at(4),
            (100 + 650, -20 + 370),
            "the second row below the first"
        );
        let positions: std::collections::BTreeSet<_> =
            windows.values().map(|w| w.position).collect();
        assert_eq!(positions.len(), 6, "no two windows on top of each other");
        let full = side_by_side(&wall, (0, 0), true);
        assert_eq!(full[&5].fullscreen, Some(5));
        assert_eq!(full[&5].position, None);
    }

    #[test]
    fn windows_are_read_and_checked() {
        let text = format!(
            "{DESK}[[window]]\ndisplay = 1\nx = 640\ny = 0\n[[window]]\ndisplay = 2\nfullscreen = 1\n"
        );
        let file = WallFile::from_toml(&text, "desk.toml").unwrap();
        assert_eq!(file.layout, WallLayout::grid(3, 1, 640, 360).unwrap());
        assert_eq!(file.windows[&1].position, Some((640, 0)));
        assert_eq!(file.windows[&2].fullscreen, Some(1));
        assert!(!file.windows.contains_key(&0));
        for (bad, why) in [
            ("[[window]]\ndisplay = 3\n", "not one of the 3"),
            ("[[window]]\ndisplay = 0\nwidth = 10\n", "together"),
            (
                "[[window]]\ndisplay = 0\n[[window]]\ndisplay = 0\n",
                "twice",
            ),
            ("[[window]]\ndisplay = 0\nfullscreen = 99\n", "monitor 99"),
            ("[[window]]\ndisplay = 0\nwidht = 10\n", "widht"),
        ] {
            let err = WallFile::from_toml(&format!("{DESK}{bad}"), "desk.toml")
                .unwrap_err()
                .to_string();
            assert!(err.contains(why) && err.contains("desk.toml"), "{err}");
        }
    }

    #[test]
    fn a_bad_section_is_named_within_its_file_once() {
        // Said "wall file w.toml: wall file [viewer]: ...", as if [viewer] were a second file.
        let text = "[viewer]\nposition_mm = [0.0, 0.0, nan]\n[[screen]]\nresolution = [64, 64]\nx_mm = 0.0\ny_mm = 0.0\nwidth_mm = 100.0\nheight_mm = 100.0\n";
        let err = WallFile::from_toml(text, "w.toml").unwrap_err().to_string();
        assert!(err.starts_with("wall file w.toml: [viewer]: "), "{err}");
        assert_eq!(err.matches("wall file").count(), 1, "{err}");
    }
}
