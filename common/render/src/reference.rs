//! The single-process reference image that the wall must equal pixel for pixel.

use crate::frame::{render_tiles, render_tiles_linear};
use crate::prepared::{FrameView, PreparedScene};
use glam::Vec3;
use tessera_model::image::RgbImage;
use tessera_model::wall::TileGrid;

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

/// The wall as linear colour (before the 8-bit encoding of [`render_wall`]), row-major, bezels
/// black: for `--aov color` and error measurements.
pub fn render_wall_linear(scene: &PreparedScene, view: &FrameView, grid: &TileGrid) -> Vec<Vec3> {
    let layout = grid.layout();
    let width = layout.width() as usize;
    let mut wall = vec![Vec3::ZERO; width * layout.height() as usize];
    let (tiles, _) = render_tiles_linear(scene, view, grid.tiles());
    for (tile, colors) in grid.tiles().iter().zip(tiles) {
        for (row, line) in colors.chunks(tile.width as usize).enumerate() {
            let at = (tile.y as usize + row) * width + tile.x as usize;
            wall[at..at + line.len()].copy_from_slice(line);
        }
    }
    wall
}
