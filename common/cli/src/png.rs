//! Wall and screen images as PNG files: what the displays save, the master's `wall.png` and
//! the reference image. Written beside their path and renamed into place, so whoever waits
//! for a file (a script, a test, a viewer) never reads half of it.

use std::path::Path;
use tessera_model::image::RgbImage;

/// Why an image file could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum PngError {
    /// The image could not be written to `path`.
    #[error("cannot write {path}")]
    Write {
        /// The file that was to be written.
        path: String,
        /// What the encoder or the file system said.
        source: image::ImageError,
    },
    /// The file at `path` could not be read as an image.
    #[error("cannot read image {path}")]
    Read {
        /// The file that was to be read.
        path: String,
        /// What the decoder or the file system said.
        source: image::ImageError,
    },
}

/// PNG files of [`RgbImage`]s.
pub trait PngFile: Sized {
    /// Writes the image as PNG, atomically (see the module documentation).
    ///
    /// # Errors
    /// The file cannot be written or renamed into place.
    fn save_png(&self, path: &Path) -> Result<(), PngError>;

    /// Reads a PNG (or any image the `image` crate reads) as RGB8.
    ///
    /// # Errors
    /// The file cannot be read or decoded.
    fn load_png(path: &Path) -> Result<Self, PngError>;
}

impl PngFile for RgbImage {
    fn save_png(&self, path: &Path) -> Result<(), PngError> {
        let error = |source| PngError::Write {
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

    fn load_png(path: &Path) -> Result<RgbImage, PngError> {
        let img = image::open(path)
            .map_err(|source| PngError::Read {
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_image_comes_back_from_its_png_as_it_was() {
        let dir = std::env::temp_dir().join(format!("tessera-png-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("round.png");
        let mut image = RgbImage::black(3, 2);
        image.rgb[4] = 200;
        image.save_png(&path).unwrap();
        assert_eq!(RgbImage::load_png(&path).unwrap(), image);
        assert!(!dir.join(".round.png.partial").exists());
        let missing = RgbImage::load_png(&dir.join("missing.png")).unwrap_err();
        assert!(missing.to_string().contains("missing.png"), "{missing}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
