//! Whole-wall images: composing screens into the virtual image (bezels black), PNG in and out.

use crate::render::{render_tiles, FrameView, PreparedScene};
use crate::wall::{ScreenRect, TileGrid, WallLayout};
use anyhow::{bail, Context, Result};
use std::path::Path;

/// An RGB8 image, row-major, row 0 at the top.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RgbImage {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<u8>,
}

impl RgbImage {
    pub fn black(width: u32, height: u32) -> Self {
        RgbImage {
            width,
            height,
            rgb: vec![0; width as usize * height as usize * 3],
        }
    }

    /// Copies `src` into this image with its top-left corner at `(x, y)`.
    pub fn blit(&mut self, src: &RgbImage, x: u32, y: u32) {
        let row = src.width as usize * 3;
        for r in 0..src.height as usize {
            let dst = ((y as usize + r) * self.width as usize + x as usize) * 3;
            self.rgb[dst..dst + row].copy_from_slice(&src.rgb[r * row..(r + 1) * row]);
        }
    }

    /// The `screen`'s part of a whole-wall image.
    pub fn crop(&self, screen: &ScreenRect) -> RgbImage {
        let mut out = RgbImage::black(screen.width, screen.height);
        let row = screen.width as usize * 3;
        for r in 0..screen.height as usize {
            let src = ((screen.y as usize + r) * self.width as usize + screen.x as usize) * 3;
            out.rgb[r * row..(r + 1) * row].copy_from_slice(&self.rgb[src..src + row]);
        }
        out
    }

    pub fn save_png(&self, path: &Path) -> Result<()> {
        image::save_buffer(
            path,
            &self.rgb,
            self.width,
            self.height,
            image::ColorType::Rgb8,
        )
        .with_context(|| format!("cannot write {}", path.display()))
    }

    pub fn load_png(path: &Path) -> Result<RgbImage> {
        let img = image::open(path)
            .with_context(|| format!("cannot read image {}", path.display()))?
            .to_rgb8();
        Ok(RgbImage {
            width: img.width(),
            height: img.height(),
            rgb: img.into_raw(),
        })
    }
}

/// Puts each display's image at its place on the wall; bezels stay black.
pub fn compose_wall(layout: &WallLayout, screens: &[(ScreenRect, RgbImage)]) -> Result<RgbImage> {
    let mut wall = RgbImage::black(layout.width(), layout.height());
    for (screen, image) in screens {
        if (image.width, image.height) != (screen.width, screen.height) {
            bail!(
                "display {} image is {}x{}, but its screen is {}x{}",
                screen.id.0,
                image.width,
                image.height,
                screen.width,
                screen.height
            );
        }
        wall.blit(image, screen.x, screen.y);
    }
    Ok(wall)
}

/// The reference: every tile of the wall rendered in this process, bezels black.
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
