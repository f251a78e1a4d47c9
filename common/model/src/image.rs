//! Whole-wall images: composing screens into the virtual image (bezels black). Reading and
//! writing them as PNG files is `tessera-cli`'s (`png`): this crate does no file I/O.

use crate::wall::{ScreenRect, WallLayout};

/// An RGB8 image, row-major, row 0 at the top.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RgbImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// The pixels, three bytes (red, green, blue) each, `width * height * 3` bytes in all.
    pub rgb: Vec<u8>,
}

/// Why screens' images could not be put together.
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    /// A display's image is not the size of its screen rectangle on the wall.
    #[error("display {display} image is {got:?}, but its screen is {want:?}")]
    WrongSize {
        /// The display whose image it is.
        display: u32,
        /// The image's `(width, height)`, in pixels.
        got: (u32, u32),
        /// The screen's `(width, height)`, in pixels.
        want: (u32, u32),
    },
}

impl RgbImage {
    /// An all-black image of `width` × `height` pixels.
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
}

/// Puts each display's image at its place on the wall; bezels stay black.
pub fn compose_wall(
    layout: &WallLayout,
    screens: &[(ScreenRect, RgbImage)],
) -> Result<RgbImage, ImageError> {
    let mut wall = RgbImage::black(layout.width(), layout.height());
    for (screen, image) in screens {
        if (image.width, image.height) != (screen.width, screen.height) {
            return Err(ImageError::WrongSize {
                display: screen.id.0,
                got: (image.width, image.height),
                want: (screen.width, screen.height),
            });
        }
        wall.blit(image, screen.x, screen.y);
    }
    Ok(wall)
}
