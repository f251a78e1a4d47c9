//! Whole-wall images: composing screens into the virtual image (bezels black), PNG in and out.

use crate::wall::{ScreenRect, WallLayout};
use std::path::Path;

/// An RGB8 image, row-major, row 0 at the top.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RgbImage {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<u8>,
}

/// Why an image could not be read, written or put together.
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    #[error("cannot write {path}")]
    Write {
        path: String,
        source: image::ImageError,
    },
    #[error("cannot read image {path}")]
    Read {
        path: String,
        source: image::ImageError,
    },
    #[error("display {display} image is {got:?}, but its screen is {want:?}")]
    WrongSize {
        display: u32,
        got: (u32, u32),
        want: (u32, u32),
    },
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

    /// Writes the image as PNG. It is written beside `path` and renamed into place, so whoever
    /// waits for the file (a script, a test, a viewer) never reads half of it.
    pub fn save_png(&self, path: &Path) -> Result<(), ImageError> {
        let error = |source| ImageError::Write {
            path: path.display().to_string(),
            source,
        };
        let name = path
            .file_name()
            .map_or_else(|| "image".into(), |n| n.to_string_lossy().into_owned());
        let partial = path.with_file_name(format!(".{name}.partial"));
        image::save_buffer_with_format(
            &partial,
            &self.rgb,
            self.width,
            self.height,
            image::ColorType::Rgb8,
            image::ImageFormat::Png,
        )
        .map_err(error)?;
        std::fs::rename(&partial, path).map_err(|e| error(image::ImageError::IoError(e)))
    }

    pub fn load_png(path: &Path) -> Result<RgbImage, ImageError> {
        let img = image::open(path)
            .map_err(|source| ImageError::Read {
                path: path.display().to_string(),
                source,
            })?
            .to_rgb8();
        Ok(RgbImage {
            width: img.width(),
            height: img.height(),
            rgb: img.into_raw(),
        })
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
