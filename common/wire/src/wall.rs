//! Wall geometry: a grid of screens seen as one virtual image, which pixels each display owns,
//! and the tile grid that the load balancer hands out.
//!
//! The virtual image includes the bezels (mullions) so that the picture lines up across them the
//! way a window frame hides part of a view; pixels behind a bezel belong to no display and are
//! never rendered nor sent. Tiles are cut per screen, so a tile never straddles two screens.

use serde::{Deserialize, Serialize};
use std::path::Path;

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
/// ([`crate::protocol::codec::MAX_CONTROL_BODY`]) with room to spare.
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

fn default_tile_size() -> u32 {
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

    pub const fn bezel(mut self, bezel: u32) -> Self {
        self.bezel = bezel;
        self
    }

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
        for (field, value) in [
            ("columns", self.columns),
            ("rows", self.rows),
            ("screen_width", self.screen_width),
            ("screen_height", self.screen_height),
            ("tile_size", self.tile_size),
        ] {
            if value == 0 {
                return Err(WallError::Zero { field, value });
            }
        }
        // In u64, so that no product of u32 fields can wrap before it is compared.
        let displays = self.columns as u64 * self.rows as u64;
        if displays > MAX_DISPLAYS as u64 {
            return Err(WallError::TooManyDisplays {
                displays,
                max: MAX_DISPLAYS,
            });
        }
        let (w, h) = (
            extent(self.columns, self.screen_width, self.bezel),
            extent(self.rows, self.screen_height, self.bezel),
        );
        if w > MAX_WALL_SIDE as u64 || h > MAX_WALL_SIDE as u64 {
            return Err(WallError::TooLarge {
                width: w,
                height: h,
                max: MAX_WALL_SIDE,
            });
        }
        let t = self.tile_size as u64;
        let tiles = displays
            * (self.screen_width as u64).div_ceil(t)
            * (self.screen_height as u64).div_ceil(t);
        if tiles > MAX_TILES {
            return Err(WallError::TooManyTiles {
                tiles,
                tile_size: self.tile_size,
                max: MAX_TILES,
            });
        }
        Ok(WallLayout { spec: self })
    }
}

/// Pixels along one side of the virtual image: `count` screens of `size`, `bezel` apart.
fn extent(count: u32, size: u32, bezel: u32) -> u64 {
    count as u64 * size as u64 + count.saturating_sub(1) as u64 * bezel as u64
}

/// A wall: `columns × rows` screens of `screen_width × screen_height` pixels, `bezel` apart.
///
/// Only [`WallSpec::build`] (or deserializing, which calls it) makes one, so every
/// `WallLayout` is within the limits above and its sizes and counts fit their types.
///
/// # Examples
///
/// ```
/// use tessera_wire::wall::{DisplayId, TileGrid, WallLayout, WallSpec};
///
/// // Two screens side by side with a 16-pixel bezel between them.
/// let wall = WallSpec::grid(2, 1, 480, 270).bezel(16).build()?;
/// assert_eq!((wall.width(), wall.height()), (976, 270));
/// let right = wall.screen(DisplayId(1)).unwrap();
/// assert_eq!(right.x, 480 + 16);
///
/// // Tiles never straddle two screens: 8 × 5 tiles of up to 64 pixels per screen.
/// let grid = TileGrid::new(wall);
/// assert_eq!(grid.display_tiles(DisplayId(0)).len(), 8 * 5);
///
/// // A wall file says the same in TOML, and a bad field is named in the error.
/// let file = WallLayout::from_toml("columns = 2\nrows = 1\nscreen_width = 480\n\
///                                   screen_height = 270\nbezel = 16\n", "wall.toml")?;
/// assert_eq!(file, wall);
/// let err = WallSpec::grid(2, 0, 480, 270).build().unwrap_err();
/// assert!(err.to_string().contains("rows"));
/// # Ok::<(), tessera_wire::wall::WallError>(())
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(into = "WallSpec")]
pub struct WallLayout {
    spec: WallSpec,
}

impl<'de> Deserialize<'de> for WallLayout {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        crate::checked::deserialize::<D, WallSpec, Self>(d)
    }
}

impl TryFrom<WallSpec> for WallLayout {
    type Error = WallError;

    fn try_from(spec: WallSpec) -> Result<Self, WallError> {
        spec.build()
    }
}

impl From<WallLayout> for WallSpec {
    fn from(wall: WallLayout) -> WallSpec {
        wall.spec
    }
}

/// Why a wall description was refused.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum WallError {
    #[error("wall field `{field}` must be at least 1, got {value}")]
    Zero { field: &'static str, value: u32 },
    #[error("wall is {width}x{height} pixels, larger than the {max}x{max} limit")]
    TooLarge { width: u64, height: u64, max: u32 },
    #[error("wall has {displays} screens (columns x rows), more than the {max} supported")]
    TooManyDisplays { displays: u64, max: u32 },
    #[error(
        "wall cut into {tile_size}-pixel tiles has {tiles} tiles, more than the {max} supported; use larger tiles"
    )]
    TooManyTiles {
        tiles: u64,
        tile_size: u32,
        max: u64,
    },
    #[error("`{text}` is not a size like 2x2 or 480x270")]
    BadSize { text: String },
    #[error("wall file {path}: {message}")]
    File { path: String, message: String },
}

/// One screen's rectangle in the virtual image.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ScreenRect {
    pub id: DisplayId,
    pub x: u32,
    pub y: u32,
    pub width: u32,
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
    pub id: TileId,
    pub display: DisplayId,
    /// Left edge in virtual-image pixels.
    pub x: u32,
    /// Top edge in virtual-image pixels (row 0 at the top).
    pub y: u32,
    pub width: u32,
    pub height: u32,
}

impl Tile {
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

    /// The fields this wall was built from.
    pub fn spec(&self) -> WallSpec {
        self.spec
    }

    /// Reads a wall from TOML text (a wall file, whose `[[window]]` tables are read and
    /// checked but not kept: see [`crate::window::WallFile`]); `origin` names the source.
    pub fn from_toml(text: &str, origin: &str) -> Result<Self, WallError> {
        crate::window::WallFile::from_toml(text, origin).map(|f| f.layout)
    }

    /// Reads a wall file (see `deploy/walls/*.toml` for examples).
    pub fn from_file(path: &Path) -> Result<Self, WallError> {
        crate::window::WallFile::from_file(path).map(|f| f.layout)
    }

    pub fn columns(&self) -> u32 {
        self.spec.columns
    }

    pub fn rows(&self) -> u32 {
        self.spec.rows
    }

    pub fn screen_width(&self) -> u32 {
        self.spec.screen_width
    }

    pub fn screen_height(&self) -> u32 {
        self.spec.screen_height
    }

    pub fn bezel(&self) -> u32 {
        self.spec.bezel
    }

    pub fn tile_size(&self) -> u32 {
        self.spec.tile_size
    }

    /// Width of the virtual image, bezels included.
    pub fn width(&self) -> u32 {
        extent(self.spec.columns, self.spec.screen_width, self.spec.bezel) as u32
    }

    /// Height of the virtual image, bezels included.
    pub fn height(&self) -> u32 {
        extent(self.spec.rows, self.spec.screen_height, self.spec.bezel) as u32
    }

    pub fn display_count(&self) -> u32 {
        self.spec.columns * self.spec.rows
    }

    /// The screen of display `id`, or `None` if the wall has no such display.
    pub fn screen(&self, id: DisplayId) -> Option<ScreenRect> {
        if id.0 >= self.display_count() {
            return None;
        }
        let s = &self.spec;
        let (col, row) = (id.0 % s.columns, id.0 / s.columns);
        Some(ScreenRect {
            id,
            x: col * (s.screen_width + s.bezel),
            y: row * (s.screen_height + s.bezel),
            width: s.screen_width,
            height: s.screen_height,
        })
    }

    pub fn screens(&self) -> impl Iterator<Item = ScreenRect> + '_ {
        (0..self.display_count()).filter_map(|i| self.screen(DisplayId(i)))
    }

    /// Pixels owned by displays (the virtual image minus the bezels).
    pub fn visible_pixels(&self) -> u64 {
        self.display_count() as u64 * self.spec.screen_width as u64 * self.spec.screen_height as u64
    }
}

/// The wall cut into tiles: screen by screen, row-major inside each screen, so that the tiles of
/// one display are contiguous ids and a contiguous range of ids is a compact region.
#[derive(Clone, Debug)]
pub struct TileGrid {
    layout: WallLayout,
    tiles: Vec<Tile>,
    /// `display_first[d]..display_first[d + 1]` are the ids of display d's tiles.
    display_first: Vec<u32>,
}

impl TileGrid {
    pub fn new(layout: WallLayout) -> Self {
        let t = layout.tile_size();
        let mut tiles = Vec::new();
        let mut display_first = Vec::with_capacity(layout.display_count() as usize + 1);
        for screen in layout.screens() {
            display_first.push(tiles.len() as u32);
            for ty in (0..screen.height).step_by(t as usize) {
                for tx in (0..screen.width).step_by(t as usize) {
                    tiles.push(Tile {
                        id: TileId(tiles.len() as u32),
                        display: screen.id,
                        x: screen.x + tx,
                        y: screen.y + ty,
                        width: t.min(screen.width - tx),
                        height: t.min(screen.height - ty),
                    });
                }
            }
        }
        display_first.push(tiles.len() as u32);
        TileGrid {
            layout,
            tiles,
            display_first,
        }
    }

    pub fn layout(&self) -> &WallLayout {
        &self.layout
    }

    pub fn len(&self) -> usize {
        self.tiles.len()
    }

    pub fn is_empty(&self) -> bool {
        self.tiles.is_empty()
    }

    pub fn tile(&self, id: TileId) -> Option<&Tile> {
        self.tiles.get(id.0 as usize)
    }

    pub fn tiles(&self) -> &[Tile] {
        &self.tiles
    }

    /// The tiles of one display, in id order.
    pub fn display_tiles(&self, display: DisplayId) -> &[Tile] {
        let d = display.0 as usize;
        if d + 1 >= self.display_first.len() {
            return &[];
        }
        &self.tiles[self.display_first[d] as usize..self.display_first[d + 1] as usize]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bezels_widen_the_virtual_image_but_own_no_pixels() {
        let wall = WallSpec::grid(2, 2, 480, 270).bezel(16).build().unwrap();
        assert_eq!((wall.width(), wall.height()), (976, 556));
        assert_eq!(wall.visible_pixels(), 4 * 480 * 270);
        let s3 = wall.screen(DisplayId(3)).unwrap();
        assert_eq!((s3.x, s3.y), (496, 286));
        assert!(wall.screen(DisplayId(4)).is_none());
    }

    #[test]
    fn tiles_cover_each_screen_exactly_once_and_never_straddle() {
        let wall = WallSpec::grid(3, 2, 200, 130)
            .bezel(7)
            .tile_size(64)
            .build()
            .unwrap();
        let grid = TileGrid::new(wall);
        let mut owner = vec![None; (wall.width() * wall.height()) as usize];
        for tile in grid.tiles() {
            let screen = wall.screen(tile.display).unwrap();
            assert!(tile.x >= screen.x && tile.x + tile.width <= screen.x + screen.width);
            assert!(tile.y >= screen.y && tile.y + tile.height <= screen.y + screen.height);
            for y in tile.y..tile.y + tile.height {
                for x in tile.x..tile.x + tile.width {
                    let slot = &mut owner[(y * wall.width() + x) as usize];
                    assert!(slot.is_none(), "pixel {x},{y} in two tiles");
                    *slot = Some(tile.display);
                }
            }
        }
        for screen in wall.screens() {
            for y in screen.y..screen.y + screen.height {
                for x in screen.x..screen.x + screen.width {
                    assert_eq!(owner[(y * wall.width() + x) as usize], Some(screen.id));
                }
            }
        }
        let covered = owner.iter().filter(|o| o.is_some()).count() as u64;
        assert_eq!(covered, wall.visible_pixels());
        for screen in wall.screens() {
            let tiles = grid.display_tiles(screen.id);
            assert!(tiles.iter().all(|t| t.display == screen.id));
            let pixels: usize = tiles.iter().map(Tile::pixel_count).sum();
            assert_eq!(pixels, (screen.width * screen.height) as usize);
        }
    }

    #[test]
    fn shorthand_sizes_parse_and_reject_garbage() {
        assert_eq!(parse_size("2x2").unwrap(), (2, 2));
        assert_eq!(parse_size("480X270").unwrap(), (480, 270));
        for bad in ["2", "x2", "2x", "axb", "-1x2", ""] {
            assert!(parse_size(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn wall_file_errors_name_the_field() {
        let err = WallLayout::from_toml(
            "columns = 2\nrows = 2\nscreen_width = 0\nscreen_height = 270\n",
            "w.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("screen_width") && err.contains("w.toml"),
            "{err}"
        );
        let err = WallLayout::from_toml("columns = 2\nrows = 2\nscreen_width = 4\n", "w.toml")
            .unwrap_err()
            .to_string();
        assert!(err.contains("screen_height"), "{err}");
        let err = WallLayout::from_toml(
            "columns = 2\nrows = 2\nscreen_width = 4\nscreen_height = 4\nbezzel = 3\n",
            "w.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("bezzel"), "{err}");
        let err = WallLayout::from_toml(
            "columns = \"two\"\nrows = 2\nscreen_width = 4\nscreen_height = 4\n",
            "w.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("columns"), "{err}");
    }

    #[test]
    fn file_and_shorthand_describe_the_same_wall() {
        let file = WallLayout::from_toml(
            "columns = 2\nrows = 2\nscreen_width = 480\nscreen_height = 270\nbezel = 16\n",
            "w.toml",
        )
        .unwrap();
        assert_eq!(
            file,
            WallSpec::grid(2, 2, 480, 270).bezel(16).build().unwrap()
        );
    }

    #[test]
    fn absurd_walls_are_refused() {
        assert!(matches!(
            WallLayout::grid(40, 1, 1920, 1080),
            Err(WallError::TooLarge { .. })
        ));
    }

    #[test]
    fn walls_whose_display_count_overflows_are_refused() {
        // 65536 × 65536 screens is 2^32 displays: a u32 count wraps to 0.
        let err = WallLayout::grid(65536, 65536, 1, 1).unwrap_err();
        assert!(
            matches!(err, WallError::TooManyDisplays { displays, .. } if displays == 1 << 32),
            "{err}"
        );
        assert!(err.to_string().contains("4294967296"), "{err}");
        assert!(WallLayout::grid(64, 64, 16, 16).is_ok());
        assert!(WallLayout::grid(65, 64, 16, 16).is_err());
    }

    #[test]
    fn walls_whose_tile_count_overflows_are_refused() {
        // One screen of 65536 × 65536 pixels in 1-pixel tiles: 2^32 tile ids.
        let err = WallSpec::grid(1, 1, 65536, 65536)
            .tile_size(1)
            .build()
            .unwrap_err();
        assert!(matches!(err, WallError::TooManyTiles { .. }), "{err}");
        assert!(err.to_string().contains("larger tiles"), "{err}");
        // The same screen in the default 64-pixel tiles is exactly the limit.
        let wall = WallLayout::grid(1, 1, 65536, 65536).unwrap();
        assert_eq!(TileGrid::new(wall).len() as u64, MAX_TILES);
    }

    #[test]
    fn deserializing_a_wall_checks_it() {
        let bad = WallSpec::grid(3, 0, 10, 10);
        let json = serde_json::to_string(&bad).unwrap();
        assert!(serde_json::from_str::<WallLayout>(&json).is_err());
        let good = WallLayout::grid(3, 1, 10, 10).unwrap();
        let json = serde_json::to_string(&good).unwrap();
        assert_eq!(serde_json::from_str::<WallLayout>(&json).unwrap(), good);
    }
}
