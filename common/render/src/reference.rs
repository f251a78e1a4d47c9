//! The single-process reference image that the wall must equal pixel for pixel.

use crate::frame::{render_tiles, FrameView, PreparedScene};
use tessera_wire::image::RgbImage;
use tessera_wire::wall::TileGrid;

/// Every tile of the wall rendered in this process, bezels black.
pub fn render_wall(scene: &PreparedScene, view: &FrameView, grid: &TileGrid) -> RgbImage {
    let layout = grid.layout();
    let mut wall = RgbImage::black(layout.width(), layout.height());
    let (tiles, _) = render_tiles(scene, view, grid.tiles());
    for (tile, rgb) in grid.tiles().iter().zip(tiles) {
        wall.blit(
            &RgbImage {
                width: tile.width,
                height: tile.height,
                rgb,
            },
            tile.x,
            tile.y,
        );
    }
    wall
}
