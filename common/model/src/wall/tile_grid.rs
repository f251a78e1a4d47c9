//! The tiles of a wall: where each is, which display owns it, and each display's tiles.

use super::*;

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
    /// `layout` cut into tiles of its tile size.
    pub fn new(layout: WallLayout) -> Self {
        let t = layout.tile_size();
        let mut tiles = Vec::new();
        let mut display_first = Vec::with_capacity(layout.display_count() as usize + 1);
        for (i, v) in layout.viewports().iter().enumerate() {
            // Viewports come in display order: a display's first starts its tiles.
            if display_first.len() <= v.display.0 as usize {
                display_first.push(tiles.len() as u32);
            }
            for ty in (0..v.height).step_by(t as usize) {
                for tx in (0..v.width).step_by(t as usize) {
                    tiles.push(Tile {
                        id: TileId(tiles.len() as u32),
                        display: v.display,
                        viewport: i as u32,
                        x: v.x + tx,
                        y: v.y + ty,
                        width: t.min(v.width - tx),
                        height: t.min(v.height - ty),
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

    /// The wall this grid cuts.
    pub fn layout(&self) -> &WallLayout {
        &self.layout
    }

    /// How many tiles there are; their ids are `0..len()`.
    pub fn len(&self) -> usize {
        self.tiles.len()
    }

    /// Whether the grid has no tiles at all.
    pub fn is_empty(&self) -> bool {
        self.tiles.is_empty()
    }

    /// The tile `id`, or `None` if the grid has no such tile.
    pub fn tile(&self, id: TileId) -> Option<&Tile> {
        self.tiles.get(id.0 as usize)
    }

    /// Every tile, in id order.
    pub fn tiles(&self) -> &[Tile] {
        &self.tiles
    }

    /// A wall with a pixel for each of this grid's tiles, cut into one-pixel tiles: the same
    /// displays with the same tiles in the same order, each display a strip of its tiles, for
    /// a simulation that checks every tile arrives without drawing its pixels.
    ///
    /// # Errors
    /// A display of more tiles than a strip may be long ([`MAX_WALL_SIDE`]).
    pub fn thumbnail(&self) -> Result<WallLayout, WallError> {
        let screens = (0..self.layout.display_count())
            .map(|d| {
                let n = self.display_tiles(DisplayId(d)).len() as u32;
                crate::screens::ScreenSpec {
                    resolution: [n.max(1), 1],
                    x_mm: Some(d as f64 * (MAX_WALL_SIDE as f64 + 1.0)),
                    y_mm: Some(0.0),
                    width_mm: Some(n.max(1) as f64),
                    height_mm: Some(1.0),
                    ..Default::default()
                }
            })
            .collect();
        WallLayout::new(WallDescription::Screens(PhysicalSpec {
            tile_size: 1,
            viewer: Viewer {
                position_mm: [0.0, 0.0, 1.0],
                scene_units_per_m: 1.0,
            },
            stereo: Stereo::default(),
            screens,
            ring: None,
        }))
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
