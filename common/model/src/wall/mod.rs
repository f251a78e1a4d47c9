//! Wall geometry: which pixels each display owns, what each shows, and the tile grid that the
//! load balancer hands out.
//!
//! A wall is a grid of screens seen as one virtual image (the shorthand `--wall CxR --screen
//! WxH --bezel B`, or a grid wall file), or a set of physical screens, each a rectangle in
//! millimetres with a resolution of its own and an off-axis frustum from the viewer (see
//! [`crate::screens`]). Either may be stereo (see [`crate::stereo`]). The grid's virtual image
//! includes the bezels (mullions) so that the picture lines up across them the way a window
//! frame hides part of a view; pixels behind a bezel belong to no display and are never
//! rendered nor sent. A wall of screens has no one image: its displays' framebuffers are laid
//! side by side in an atlas, rows of them, which is only where their pixels are numbered.
//! Tiles are cut per viewport (one eye's view in one display), so a tile never straddles two
//! screens nor two eyes.

use crate::screens::{PhysicalSpec, Viewer};
use crate::stereo::{viewports_of, Eye, Stereo, StereoMode, ViewSource, Viewport};
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// Identifies one display (one screen) of the wall, row-major from the top-left screen.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub struct DisplayId(pub u32);

/// Identifies one tile of the wall's tile grid.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub struct TileId(pub u32);

/// Default edge length of a tile in pixels: large enough that per-tile overhead (one header,
/// one scheduling decision) is small, small enough that a 480×270 screen still has 40 tiles to
/// balance.
pub const DEFAULT_TILE_SIZE: u32 = 64;

/// Largest wall accepted, in pixels per side of the virtual image; beyond this, u16 tile
/// coordinates and 32-bit pixel counts would be at risk and it is almost surely a typo.
pub const MAX_WALL_SIDE: u32 = 1 << 16;

/// Most displays a wall may have. The largest walls built have a few hundred screens; the
/// session that lists every display's address must fit one control message
/// (`tessera_protocol::codec::MAX_CONTROL_BODY`) with room to spare.
pub const MAX_DISPLAYS: u32 = 4096;

/// Most tiles a wall may be cut into: a 65536×65536 wall in 64-pixel tiles. Tile ids are
/// `u32`, and the load balancer and every display keep a little state per tile.
pub const MAX_TILES: u64 = 1 << 20;

/// The fields of a wall as written in a wall file or on the command line, not yet checked.
/// [`WallSpec::build`] turns it into a [`WallLayout`], the only way to get one.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WallSpec {
    /// Screens per row.
    pub columns: u32,
    /// Rows of screens.
    pub rows: u32,
    /// Width of one screen in pixels.
    pub screen_width: u32,
    /// Height of one screen in pixels.
    pub screen_height: u32,
    /// Pixels hidden between two neighbouring screens (horizontally and vertically).
    #[serde(default)]
    pub bezel: u32,
    /// Edge length of the square tiles that screens are cut into.
    #[serde(default = "default_tile_size")]
    pub tile_size: u32,
}

pub(crate) fn default_tile_size() -> u32 {
    DEFAULT_TILE_SIZE
}

impl WallSpec {
    /// `columns × rows` screens of `screen_width × screen_height`, no bezel, default tiles.
    pub const fn grid(columns: u32, rows: u32, screen_width: u32, screen_height: u32) -> Self {
        WallSpec {
            columns,
            rows,
            screen_width,
            screen_height,
            bezel: 0,
            tile_size: DEFAULT_TILE_SIZE,
        }
    }

    /// The same grid with `bezel` pixels hidden between neighbouring screens.
    pub const fn bezel(mut self, bezel: u32) -> Self {
        self.bezel = bezel;
        self
    }

    /// The same grid cut into tiles of `tile_size` pixels a side.
    pub const fn tile_size(mut self, tile_size: u32) -> Self {
        self.tile_size = tile_size;
        self
    }

    /// Checks every field and the sizes they add up to.
    ///
    /// # Errors
    /// A zero field, a virtual image over [`MAX_WALL_SIDE`], more than [`MAX_DISPLAYS`]
    /// screens or more than [`MAX_TILES`] tiles.
    pub fn build(self) -> Result<WallLayout, WallError> {
        self.build_stereo(Stereo::default())
    }

    /// [`WallSpec::build`], the wall shown in `stereo`.
    ///
    /// # Errors
    /// As [`WallSpec::build`].
    pub fn build_stereo(self, stereo: Stereo) -> Result<WallLayout, WallError> {
        WallLayout::new(WallDescription::Grid { spec: self, stereo })
    }
}

/// The grid's limits, checked before anything is laid out.
fn check_grid(spec: &WallSpec) -> Result<(), WallError> {
    {
        let s = spec;
        for (field, value) in [
            ("columns", s.columns),
            ("rows", s.rows),
            ("screen_width", s.screen_width),
            ("screen_height", s.screen_height),
            ("tile_size", s.tile_size),
        ] {
            if value == 0 {
                return Err(WallError::Zero { field, value });
            }
        }
        // In u64, so that no product of u32 fields can wrap before it is compared.
        let displays = s.columns as u64 * s.rows as u64;
        if displays > MAX_DISPLAYS as u64 {
            return Err(WallError::TooManyDisplays {
                displays,
                max: MAX_DISPLAYS,
            });
        }
        let (w, h) = (
            extent(s.columns, s.screen_width, s.bezel),
            extent(s.rows, s.screen_height, s.bezel),
        );
        if w > MAX_WALL_SIDE as u64 || h > MAX_WALL_SIDE as u64 {
            return Err(WallError::TooLarge {
                width: w,
                height: h,
                max: MAX_WALL_SIDE,
            });
        }
        let t = s.tile_size as u64;
        let tiles =
            displays * (s.screen_width as u64).div_ceil(t) * (s.screen_height as u64).div_ceil(t);
        if tiles > MAX_TILES {
            return Err(WallError::TooManyTiles {
                tiles,
                tile_size: s.tile_size,
                max: MAX_TILES,
            });
        }
    }
    Ok(())
}

/// Pixels along one side of the virtual image: `count` screens of `size`, `bezel` apart.
fn extent(count: u32, size: u32, bezel: u32) -> u64 {
    count as u64 * size as u64 + count.saturating_sub(1) as u64 * bezel as u64
}

/// How a wall was described: the grid shorthand (or a grid wall file), or physical screens.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum WallDescription {
    /// A grid of equal screens seen as one virtual image.
    Grid {
        /// The grid's size, its screens' resolution, bezels and tiles.
        spec: WallSpec,
        /// How the grid shows the two eyes, if at all.
        stereo: Stereo,
    },
    /// Physical screens in millimetres, each with its own resolution and frustum.
    Screens(PhysicalSpec),
}

/// A wall: its displays' pixels, what each shows, and its tiles' size.
///
/// Only [`WallLayout::new`] (from [`WallSpec::build`], a wall file, or deserializing) makes
/// one, so every `WallLayout` is within the limits above and its sizes and counts fit their
/// types. Cloning is cheap (it is shared).
///
/// # Examples
///
/// ```
/// use tessera_model::wall::{DisplayId, TileGrid, WallLayout, WallSpec};
///
/// // Two screens side by side with a 16-pixel bezel between them.
/// let wall = WallSpec::grid(2, 1, 480, 270).bezel(16).build()?;
/// assert_eq!((wall.width(), wall.height()), (976, 270));
/// let right = wall.screen(DisplayId(1)).unwrap();
/// assert_eq!(right.x, 480 + 16);
///
/// // Tiles never straddle two screens: 8 × 5 tiles of up to 64 pixels per screen.
/// let grid = TileGrid::new(wall.clone());
/// assert_eq!(grid.display_tiles(DisplayId(0)).len(), 8 * 5);
///
/// // A wall file says the same in TOML, and a bad field is named in the error.
/// let file = WallLayout::from_toml("columns = 2\nrows = 1\nscreen_width = 480\n\
///                                   screen_height = 270\nbezel = 16\n", "wall.toml")?;
/// assert_eq!(file, wall);
/// let err = WallSpec::grid(2, 0, 480, 270).build().unwrap_err();
/// assert!(err.to_string().contains("rows"));
/// # Ok::<(), tessera_model::wall::WallError>(())
/// ```
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(into = "WallDescription")]
pub struct WallLayout(Arc<Layout>);

#[derive(Debug, PartialEq)]
struct Layout {
    description: WallDescription,
    /// The image its pixels are numbered in: a grid's virtual image, a wall of screens' atlas.
    width: u32,
    height: u32,
    tile_size: u32,
    /// Each display's framebuffer in that image.
    screens: Vec<ScreenRect>,
    /// What the displays show, in display order.
    viewports: Vec<Viewport>,
}

impl<'de> Deserialize<'de> for WallLayout {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        crate::checked::deserialize::<D, WallDescription, Self>(d)
    }
}

impl TryFrom<WallDescription> for WallLayout {
    type Error = WallError;

    fn try_from(description: WallDescription) -> Result<Self, WallError> {
        WallLayout::new(description)
    }
}

impl From<WallLayout> for WallDescription {
    fn from(wall: WallLayout) -> WallDescription {
        wall.0.description.clone()
    }
}

/// Why a wall description was refused.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum WallError {
    /// A grid's count, screen size or tile size, or a wall of screens' tile size, is 0.
    #[error("wall field `{field}` must be at least 1, got {value}")]
    Zero {
        /// The field's name as written in a wall file: `columns`, `rows`, `screen_width`,
        /// `screen_height` or `tile_size`.
        field: &'static str,
        /// The value given (0).
        value: u32,
    },
    /// The grid's virtual image, or the atlas of a wall of screens, would be more than
    /// [`MAX_WALL_SIDE`] pixels on a side.
    #[error("wall is {width}x{height} pixels, larger than the {max}x{max} limit")]
    TooLarge {
        /// Width the image would have, in pixels.
        width: u64,
        /// Height the image would have, in pixels.
        height: u64,
        /// The limit on each side, [`MAX_WALL_SIDE`].
        max: u32,
    },
    /// The wall would have more than [`MAX_DISPLAYS`] displays.
    #[error("wall has {displays} screens (columns x rows), more than the {max} supported")]
    TooManyDisplays {
        /// Displays the wall would have.
        displays: u64,
        /// The limit, [`MAX_DISPLAYS`].
        max: u32,
    },
    /// The wall would be cut into more than [`MAX_TILES`] tiles.
    #[error(
        "wall cut into {tile_size}-pixel tiles has {tiles} tiles, more than the {max} supported; use larger tiles"
    )]
    TooManyTiles {
        /// Tiles the wall would be cut into.
        tiles: u64,
        /// The tile edge, in pixels.
        tile_size: u32,
        /// The limit, [`MAX_TILES`].
        max: u64,
    },
    /// Text given to [`parse_size`] is not two numbers joined by `x`.
    #[error("`{text}` is not a size like 2x2 or 480x270")]
    BadSize {
        /// The text as given.
        text: String,
    },
    /// A wall file is not valid TOML, has an unknown or ill-typed field, a bad `[[window]]`,
    /// `[viewer]` or `[ring]`, or describes a wall that is refused (the message says why).
    #[error("wall file {path}: {message}")]
    File {
        /// The file as named to the reader (its path, or the name of the section at fault, such
        /// as `[ring]`).
        path: String,
        /// What is wrong: the TOML parser's message, or the check that failed.
        message: String,
    },
    /// A `[[screen]]` of a wall of screens (or one of its ring's) has a bad field.
    #[error("screen {screen}: `{field}` {message}")]
    Screen {
        /// Which screen, from 0, in the order of the `[[screen]]` tables then the ring's.
        screen: usize,
        /// The field at fault, as written in the wall file.
        field: &'static str,
        /// What is wrong with it.
        message: String,
    },
}

/// One screen's rectangle in the virtual image.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ScreenRect {
    /// The display that owns these pixels.
    pub id: DisplayId,
    /// Left edge in the wall's image (a grid's virtual image, a wall of screens' atlas), in
    /// pixels.
    pub x: u32,
    /// Top edge in the wall's image, in pixels (row 0 at the top).
    pub y: u32,
    /// Width in pixels: the display's framebuffer width.
    pub width: u32,
    /// Height in pixels: the display's framebuffer height.
    pub height: u32,
}

impl ScreenRect {
    /// Bytes of one full RGB8 frame of this screen.
    pub fn rgb_bytes(&self) -> usize {
        self.width as usize * self.height as usize * 3
    }
}

/// One tile: a rectangle inside exactly one screen.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Tile {
    /// The tile's place in the [`TileGrid`].
    pub id: TileId,
    /// The display whose pixels it covers.
    pub display: DisplayId,
    /// The viewport it is in (an index of [`WallLayout::viewports`]): whose rays it traces.
    pub viewport: u32,
    /// Left edge in virtual-image pixels.
    pub x: u32,
    /// Top edge in virtual-image pixels (row 0 at the top).
    pub y: u32,
    /// Width in pixels: the tile size, or less at a viewport's right edge.
    pub width: u32,
    /// Height in pixels: the tile size, or less at a viewport's bottom edge.
    pub height: u32,
}

impl Tile {
    /// Pixels in the tile: `width × height`.
    pub fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }
}

/// Parses `AxB` (e.g. `2x2`, `480x270`) into two numbers.
pub fn parse_size(text: &str) -> Result<(u32, u32), WallError> {
    let bad = || WallError::BadSize {
        text: text.to_string(),
    };
    let (a, b) = text.split_once(['x', 'X']).ok_or_else(bad)?;
    let a: u32 = a.trim().parse().map_err(|_| bad())?;
    let b: u32 = b.trim().parse().map_err(|_| bad())?;
    Ok((a, b))
}

impl WallLayout {
    /// A wall of `columns × rows` screens, each `screen_width × screen_height`, no bezel.
    ///
    /// # Errors
    /// As [`WallSpec::build`].
    pub fn grid(
        columns: u32,
        rows: u32,
        screen_width: u32,
        screen_height: u32,
    ) -> Result<Self, WallError> {
        WallSpec::grid(columns, rows, screen_width, screen_height).build()
    }

    /// The wall a description describes, checked.
    ///
    /// # Errors
    /// A grid's limits (see [`WallSpec::build`]), a screen's bad field (see
    /// [`PhysicalSpec::resolve`]), more than [`MAX_DISPLAYS`] displays or [`MAX_TILES`] tiles.
    pub fn new(description: WallDescription) -> Result<Self, WallError> {
        let layout = match &description {
            WallDescription::Grid { spec, stereo } => grid_layout(spec, *stereo)?,
            WallDescription::Screens(spec) => screens_layout(spec)?,
        };
        let displays = layout.screens.len() as u64;
        if displays > MAX_DISPLAYS as u64 {
            return Err(WallError::TooManyDisplays {
                displays,
                max: MAX_DISPLAYS,
            });
        }
        let t = layout.tile_size as u64;
        let tiles: u64 = layout
            .viewports
            .iter()
            .map(|v| (v.width as u64).div_ceil(t) * (v.height as u64).div_ceil(t))
            .sum();
        if tiles > MAX_TILES {
            return Err(WallError::TooManyTiles {
                tiles,
                tile_size: layout.tile_size,
                max: MAX_TILES,
            });
        }
        Ok(WallLayout(Arc::new(Layout {
            description,
            ..layout
        })))
    }

    /// What this wall was built from.
    pub fn description(&self) -> &WallDescription {
        &self.0.description
    }

    /// The grid's fields, for a grid wall.
    pub fn grid_spec(&self) -> Option<WallSpec> {
        match &self.0.description {
            WallDescription::Grid { spec, .. } => Some(*spec),
            WallDescription::Screens(_) => None,
        }
    }

    /// Reads a wall from TOML text (a wall file, whose `[[window]]` tables are read and
    /// checked but not kept: see [`crate::window::WallFile`]); `origin` names the source.
    pub fn from_toml(text: &str, origin: &str) -> Result<Self, WallError> {
        crate::window::WallFile::from_toml(text, origin).map(|f| f.layout)
    }

    /// A grid's screens per row (0 for a wall of screens).
    pub fn columns(&self) -> u32 {
        self.grid_spec().map_or(0, |s| s.columns)
    }

    /// A grid's rows of screens (0 for a wall of screens).
    pub fn rows(&self) -> u32 {
        self.grid_spec().map_or(0, |s| s.rows)
    }

    /// A grid's screen width in pixels (0 for a wall of screens).
    pub fn screen_width(&self) -> u32 {
        self.grid_spec().map_or(0, |s| s.screen_width)
    }

    /// A grid's screen height in pixels (0 for a wall of screens).
    pub fn screen_height(&self) -> u32 {
        self.grid_spec().map_or(0, |s| s.screen_height)
    }

    /// A grid's bezel in pixels (0 for a wall of screens).
    pub fn bezel(&self) -> u32 {
        self.grid_spec().map_or(0, |s| s.bezel)
    }

    /// Edge length of the square tiles the wall is cut into, in pixels.
    pub fn tile_size(&self) -> u32 {
        self.0.tile_size
    }

    /// Width of the image the wall's pixels are numbered in (a grid's virtual image, bezels
    /// included; a wall of screens' atlas).
    pub fn width(&self) -> u32 {
        self.0.width
    }

    /// Height of that image.
    pub fn height(&self) -> u32 {
        self.0.height
    }

    /// For a grid wall, the size of the camera's one image, bezels included (the same as
    /// [`WallLayout::width`] × [`WallLayout::height`] unless its stereo displays are laid
    /// out apart); `None` for a wall of screens, which has no one image.
    pub fn image_size(&self) -> Option<(u32, u32)> {
        let spec = self.grid_spec()?;
        Some((
            extent(spec.columns, spec.screen_width, spec.bezel) as u32,
            extent(spec.rows, spec.screen_height, spec.bezel) as u32,
        ))
    }

    /// The viewer of a wall of screens.
    pub fn viewer(&self) -> Option<Viewer> {
        match &self.0.description {
            WallDescription::Screens(spec) => Some(spec.viewer),
            WallDescription::Grid { .. } => None,
        }
    }

    /// How the wall shows the two eyes (mono by default).
    pub fn stereo(&self) -> Stereo {
        match &self.0.description {
            WallDescription::Screens(spec) => spec.stereo,
            WallDescription::Grid { stereo, .. } => *stereo,
        }
    }

    /// What the displays show: one viewport a display, or two (side-by-side and top-bottom
    /// stereo), in display order.
    pub fn viewports(&self) -> &[Viewport] {
        &self.0.viewports
    }

    /// Whether every viewport is the centre eye's view of its own pixels of one image: then
    /// one camera frustum over the whole image traces every pixel.
    pub fn is_one_image(&self) -> bool {
        let one = self.image_size() == Some((self.width(), self.height()));
        one && self.0.viewports.iter().all(|v| {
            v.eye == Eye::Centre
                && v.view == ViewSource::Image([v.x, v.y, v.width, v.height].map(|n| n as f64))
        })
    }

    /// How many displays the wall has; their ids are `0..display_count()`.
    pub fn display_count(&self) -> u32 {
        self.0.screens.len() as u32
    }

    /// The framebuffer of display `id` in the wall's image, or `None` if the wall has no such
    /// display.
    pub fn screen(&self, id: DisplayId) -> Option<ScreenRect> {
        self.0.screens.get(id.0 as usize).copied()
    }

    /// Every display's framebuffer in the wall's image, in display order.
    pub fn screens(&self) -> impl Iterator<Item = ScreenRect> + '_ {
        self.0.screens.iter().copied()
    }

    /// Pixels owned by displays (the image minus the bezels and the atlas's gaps).
    pub fn visible_pixels(&self) -> u64 {
        self.0
            .screens
            .iter()
            .map(|s| s.width as u64 * s.height as u64)
            .sum()
    }
}

/// A layout under construction: everything but its description.
fn partial(width: u32, height: u32, tile_size: u32) -> Layout {
    Layout {
        description: WallDescription::Grid {
            spec: WallSpec::grid(1, 1, 1, 1),
            stereo: Stereo::default(),
        },
        width,
        height,
        tile_size,
        screens: Vec::new(),
        viewports: Vec::new(),
    }
}

/// A grid wall: its screens where they are in the virtual image; for stereo displays, the
/// two eyes' displays of each screen laid side by side in an atlas instead.
fn grid_layout(spec: &WallSpec, stereo: Stereo) -> Result<Layout, WallError> {
    check_grid(spec)?;
    let (w, h) = (
        extent(spec.columns, spec.screen_width, spec.bezel) as u32,
        extent(spec.rows, spec.screen_height, spec.bezel) as u32,
    );
    let in_image: Vec<(u32, u32)> = (0..spec.columns * spec.rows)
        .map(|i| {
            let (col, row) = (i % spec.columns, i / spec.columns);
            (
                col * (spec.screen_width + spec.bezel),
                row * (spec.screen_height + spec.bezel),
            )
        })
        .collect();
    let size = (spec.screen_width, spec.screen_height);
    let (frames, (aw, ah)) = if stereo.mode == StereoMode::Displays {
        pack(&vec![size; in_image.len() * 2])?
    } else {
        (in_image.clone(), (w, h))
    };
    let mut layout = partial(aw, ah, spec.tile_size);
    for (d, &(x, y)) in frames.iter().enumerate() {
        let per = stereo.mode.displays_per_screen() as usize;
        let (sx, sy) = in_image[d / per];
        let eye = display_eye(stereo.mode, d);
        let view = |_| ViewSource::Image([sx, sy, size.0, size.1].map(|n| n as f64));
        add_display(&mut layout, (x, y, size.0, size.1), stereo.mode, eye, view);
    }
    Ok(layout)
}

/// The eye display `d` shows in `mode` (only passive stereo gives a display one eye).
fn display_eye(mode: StereoMode, d: usize) -> Eye {
    match (mode, d % 2) {
        (StereoMode::Displays, 0) => Eye::Left,
        (StereoMode::Displays, _) => Eye::Right,
        _ => Eye::Centre,
    }
}

fn add_display(
    layout: &mut Layout,
    (x, y, w, h): (u32, u32, u32, u32),
    mode: StereoMode,
    eye: Eye,
    view: impl Fn(Eye) -> ViewSource,
) {
    let id = DisplayId(layout.screens.len() as u32);
    layout.screens.push(ScreenRect {
        id,
        x,
        y,
        width: w,
        height: h,
    });
    let viewports = viewports_of(id, (x, y, w, h), mode, eye, view);
    layout.viewports.extend(viewports);
}

/// A wall of physical screens: each display's framebuffer in the atlas, and the screen it
/// shows, to one eye or both.
fn screens_layout(spec: &PhysicalSpec) -> Result<Layout, WallError> {
    if spec.tile_size == 0 {
        return Err(WallError::Zero {
            field: "tile_size",
            value: 0,
        });
    }
    let screens = spec.resolve()?;
    let per = spec.stereo.mode.displays_per_screen() as usize;
    let sizes: Vec<(u32, u32)> = screens
        .iter()
        .flat_map(|s| std::iter::repeat_n((s.width, s.height), per))
        .collect();
    if sizes.len() as u64 > MAX_DISPLAYS as u64 {
        return Err(WallError::TooManyDisplays {
            displays: sizes.len() as u64,
            max: MAX_DISPLAYS,
        });
    }
    let (frames, (w, h)) = pack(&sizes)?;
    let mut layout = partial(w, h, spec.tile_size);
    for (d, &(x, y)) in frames.iter().enumerate() {
        let screen = &screens[d / per];
        let eye = display_eye(spec.stereo.mode, d);
        let view = |_| ViewSource::Screen(screen.geometry);
        add_display(
            &mut layout,
            (x, y, screen.width, screen.height),
            spec.stereo.mode,
            eye,
            view,
        );
    }
    Ok(layout)
}

/// Where each framebuffer's corner is in the atlas, and the atlas's size.
type Packed = (Vec<(u32, u32)>, (u32, u32));

/// Framebuffers of `sizes` laid left to right in rows no wider than [`MAX_WALL_SIDE`], each
/// row as tall as its tallest: their corners, and the atlas's size.
fn pack(sizes: &[(u32, u32)]) -> Result<Packed, WallError> {
    let max = MAX_WALL_SIDE as u64;
    let (mut x, mut y, mut row_h, mut width) = (0u64, 0u64, 0u64, 0u64);
    let mut corners = Vec::with_capacity(sizes.len());
    for &(w, h) in sizes {
        if x + w as u64 > max {
            (x, y, row_h) = (0, y + row_h, 0);
        }
        corners.push((x as u32, y as u32));
        x += w as u64;
        row_h = row_h.max(h as u64);
        width = width.max(x);
        if y + row_h > max {
            return Err(WallError::TooLarge {
                width,
                height: y + row_h,
                max: MAX_WALL_SIDE,
            });
        }
    }
    Ok((corners, (width as u32, (y + row_h) as u32)))
}

mod tile_grid;
pub use tile_grid::TileGrid;

#[cfg(test)]
mod tests;
