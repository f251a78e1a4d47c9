//! The console's picture of the whole wall: each display's thumbnail placed where its screen
//! sits in the wall's image, bezels dark, shrunk by one factor for all.

use tessera_model::wall::{DisplayId, WallLayout};
use tessera_protocol::Thumbnail;

/// The colour of bezels and of screens that sent nothing yet.
const BEZEL: [u8; 3] = [24, 24, 28];

/// The wall pictured from its displays' thumbnails.
pub struct WallPicture {
    factor: u32,
    width: u32,
    height: u32,
    rgb: Vec<u8>,
    /// Where each screen's thumbnail goes, in picture pixels.
    screens: Vec<(DisplayId, u32, u32)>,
    /// Bumped by each thumbnail placed.
    version: u64,
}

impl WallPicture {
    /// A blank picture of `wall`, `factor` times smaller across and down.
    pub fn new(wall: &WallLayout, factor: u32) -> WallPicture {
        let factor = factor.max(1);
        let width = wall.width().div_ceil(factor).max(1);
        let height = wall.height().div_ceil(factor).max(1);
        WallPicture {
            factor,
            width,
            height,
            rgb: BEZEL.repeat(width as usize * height as usize),
            screens: wall
                .screens()
                .map(|s| (s.id, s.x / factor, s.y / factor))
                .collect(),
            version: 0,
        }
    }

    /// Screen pixels per picture pixel.
    pub fn factor(&self) -> u32 {
        self.factor
    }

    /// How many thumbnails were placed: the picture's version.
    pub fn version(&self) -> u64 {
        self.version
    }

    /// Puts `display`'s thumbnail in place, clipped to the picture.
    pub fn place(&mut self, display: DisplayId, thumbnail: &Thumbnail) {
        let Some(&(_, x0, y0)) = self.screens.iter().find(|s| s.0 == display) else {
            return;
        };
        let columns = thumbnail.width.min(self.width.saturating_sub(x0)) as usize;
        for row in 0..thumbnail.height.min(self.height.saturating_sub(y0)) {
            let from = (row * thumbnail.width) as usize * 3;
            let to = ((y0 + row) * self.width + x0) as usize * 3;
            self.rgb[to..to + columns * 3]
                .copy_from_slice(&thumbnail.rgb[from..from + columns * 3]);
        }
        self.version += 1;
    }

    /// The heatmap of the same size: each tile in the colour of the render node that rendered
    /// it last (the displays' overlay colours), black where none has, bezels dark.
    pub fn heatmap(&self, wall: &WallLayout, owners: &[u32]) -> WallPicture {
        let mut map = WallPicture::new(wall, self.factor);
        let grid = tessera_model::wall::TileGrid::new(wall.clone());
        let f = self.factor;
        for tile in grid.tiles() {
            let colour = match owners.get(tile.id.0 as usize) {
                Some(&node) if node != tessera_protocol::control::NO_OWNER => {
                    tessera_display_node::overlay::node_colour(node)
                }
                _ => [0, 0, 0],
            };
            let (x0, y0) = (tile.x / f, tile.y / f);
            let x1 = (tile.x + tile.width).div_ceil(f).min(map.width);
            let y1 = (tile.y + tile.height).div_ceil(f).min(map.height);
            for y in y0..y1 {
                for x in x0..x1 {
                    let at = (y * map.width + x) as usize * 3;
                    map.rgb[at..at + 3].copy_from_slice(&colour);
                }
            }
        }
        map
    }

    /// The picture as PNG bytes.
    pub fn png(&self) -> Vec<u8> {
        use image::ImageEncoder;
        let mut out = Vec::new();
        let encoder = image::codecs::png::PngEncoder::new_with_quality(
            &mut out,
            image::codecs::png::CompressionType::Fast,
            image::codecs::png::FilterType::Sub,
        );
        encoder
            .write_image(
                &self.rgb,
                self.width,
                self.height,
                image::ExtendedColorType::Rgb8,
            )
            .expect("an RGB8 buffer of its own size encodes");
        out
    }

    /// Width and height in pixels, and the RGB8 rows.
    #[cfg(test)]
    pub fn pixels(&self) -> (u32, u32, &[u8]) {
        (self.width, self.height, &self.rgb)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_model::wall::WallSpec;
    use tessera_protocol::FrameId;

    #[test]
    fn thumbnails_land_where_their_screens_are_and_bezels_stay_dark() {
        let wall = WallSpec::grid(2, 1, 8, 4)
            .bezel(2)
            .tile_size(4)
            .build()
            .unwrap();
        let mut picture = WallPicture::new(&wall, 2);
        assert_eq!(picture.pixels().0, wall.width().div_ceil(2));
        let white = Thumbnail {
            frame: FrameId(1),
            width: 4,
            height: 2,
            rgb: vec![255; 4 * 2 * 3],
        };
        picture.place(DisplayId(1), &white);
        let (w, _, rgb) = picture.pixels();
        let at = |x: u32, y: u32| &rgb[((y * w + x) * 3) as usize..][..3];
        assert_eq!(at(0, 0), BEZEL, "display 0 sent nothing");
        let x1 = wall.screen(DisplayId(1)).unwrap().x / 2;
        assert_eq!(at(x1, 1), [255, 255, 255]);
        assert_eq!(picture.version(), 1);
        assert!(picture.png().starts_with(b"\x89PNG"));
    }
}
