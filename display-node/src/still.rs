//! What a display does with the frame it shows now, rather than with a frame to come: a still
//! wall renders nothing more, yet its operator still snapshots it, turns its overlay on and
//! pictures it in the console.

use tessera_model::image::RgbImage;
use tessera_protocol::{FrameId, Thumbnail, MAX_THUMBNAIL_BYTES, MAX_THUMBNAIL_FACTOR};

/// `image` shrunk `factor` times across and down, each pixel the mean of the block it covers
/// (blocks at the right and bottom edges clipped), or of at most 2×2 evenly spaced pixels of
/// it for a larger block: a thumbnail costs at most four reads a pixel, whatever the screen,
/// since the display's loop waits for it. `factor` is raised if the result would be over
/// [`MAX_THUMBNAIL_BYTES`].
///
/// # Examples
/// ```
/// use tessera_model::image::RgbImage;
/// use tessera_protocol::FrameId;
/// let image = RgbImage { width: 4, height: 2, rgb: [[0u8, 0, 0], [255, 255, 255]].repeat(4).concat() };
/// let t = tessera_display_node::still::thumbnail(FrameId(3), &image, 2);
/// assert_eq!((t.frame, t.width, t.height), (FrameId(3), 2, 1));
/// assert_eq!(t.rgb, [128, 128, 128, 128, 128, 128]);
/// ```
pub fn thumbnail(frame: FrameId, image: &RgbImage, factor: u32) -> Thumbnail {
    let mut factor = factor.clamp(1, MAX_THUMBNAIL_FACTOR);
    let size = |f: u32| (image.width.div_ceil(f), image.height.div_ceil(f));
    while factor < MAX_THUMBNAIL_FACTOR && {
        let (w, h) = size(factor);
        w as usize * h as usize * 3 > MAX_THUMBNAIL_BYTES
    } {
        factor += 1;
    }
    let (width, height) = size(factor);
    let mut rgb = Vec::with_capacity(width as usize * height as usize * 3);
    // The same columns for every row: chosen once.
    let columns: Vec<Vec<u32>> = (0..width)
        .map(|tx| samples(tx * factor, ((tx + 1) * factor).min(image.width)))
        .collect();
    for ty in 0..height {
        let rows = samples(ty * factor, ((ty + 1) * factor).min(image.height));
        for cols in &columns {
            let mut sum = [0u64; 3];
            for &y in &rows {
                for &x in cols {
                    let at = (y as usize * image.width as usize + x as usize) * 3;
                    for (s, &v) in sum.iter_mut().zip(&image.rgb[at..at + 3]) {
                        *s += v as u64;
                    }
                }
            }
            let count = rows.len() as u64 * cols.len() as u64;
            rgb.extend(sum.map(|s| ((s + count / 2) / count) as u8));
        }
    }
    Thumbnail {
        frame,
        width,
        height,
        rgb,
    }
}

/// The pixels of `start..end` a thumbnail reads: all of one or two, else two a quarter of the
/// way in from each end.
fn samples(start: u32, end: u32) -> Vec<u32> {
    match end - start {
        0..=2 => (start..end).collect(),
        n => vec![start + n / 4, end - 1 - n / 4],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_large_screen_is_shrunk_within_the_bound_and_edges_average_what_they_cover() {
        let image = RgbImage {
            width: 5,
            height: 3,
            rgb: (0..15).flat_map(|i| [i as u8 * 10; 3]).collect(),
        };
        let t = thumbnail(FrameId(1), &image, 2);
        assert_eq!((t.width, t.height), (3, 2));
        // The bottom right pixel covers only (4, 2): value 140.
        assert_eq!(t.rgb[t.rgb.len() - 3..], [140, 140, 140]);
        let big = RgbImage::black(3840, 2160);
        let t = thumbnail(FrameId(0), &big, 1);
        assert!(t.rgb.len() <= MAX_THUMBNAIL_BYTES, "{}", t.rgb.len());
        assert_eq!(t.rgb.len(), t.width as usize * t.height as usize * 3);
    }
}
