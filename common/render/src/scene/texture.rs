//! Colour textures: an image read once at load into a chain of box-filtered mip levels, and
//! sampled bilinearly at the level that matches a ray's footprint.
//!
//! Texels are kept as 8-bit display values and decoded by squaring, the inverse of the
//! renderer's own encoding (`shade::encode_srgb_ish`, a square root): a texture lit at full
//! strength comes out as its own bytes, and decoding takes only multiplications, the same bits
//! on every CPU (an sRGB curve would need `powf`, which the C library may compute differently
//! from one CPU to another, and tiles must be identical on any node).

use glam::{Vec2, Vec3};
use std::path::Path;
use std::sync::Arc;

/// A texture's mip chain: level 0 is the image, each next level half the size (rounded up)
/// down to 1×1.
#[derive(Clone)]
pub struct Texture {
    /// Where the texture came from (a file, or a glTF image), for messages.
    pub name: String,
    levels: Arc<[MipLevel]>,
}

struct MipLevel {
    width: u32,
    height: u32,
    /// Display-encoded RGB, row-major from the image's top row.
    texels: Vec<[u8; 3]>,
}

impl std::fmt::Debug for Texture {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (w, h) = self.size();
        write!(
            f,
            "Texture({}, {w}x{h}, {} levels)",
            self.name,
            self.levels.len()
        )
    }
}

/// `c` (0..=255, display-encoded) as linear light: `(c / 255)²`, see the module's note.
#[inline]
pub fn decode(c: u8) -> f32 {
    let x = c as f32 * (1.0 / 255.0);
    x * x
}

/// Linear light as a display-encoded byte (square root, rounded): the inverse of [`decode`].
#[inline]
pub fn encode(linear: f32) -> u8 {
    (linear.clamp(0.0, 1.0).sqrt() * 255.0 + 0.5) as u8
}

impl Texture {
    /// A texture of `width × height` display-encoded RGB texels (row-major, top row first),
    /// with its mip levels built.
    ///
    /// # Panics
    /// If `texels` does not hold `width × height` texels or either size is zero.
    pub fn new(name: impl Into<String>, width: u32, height: u32, texels: Vec<[u8; 3]>) -> Self {
        assert!(width > 0 && height > 0 && texels.len() == (width * height) as usize);
        let mut levels = vec![MipLevel {
            width,
            height,
            texels,
        }];
        while let Some(next) = levels.last().and_then(MipLevel::halved) {
            levels.push(next);
        }
        Texture {
            name: name.into(),
            levels: levels.into(),
        }
    }

    /// Decodes an image file's bytes (PNG or JPEG); `name` is what messages call it.
    ///
    /// # Errors
    /// The decoder's message, when the bytes are no image it reads.
    pub fn decode_image(name: &str, bytes: &[u8]) -> Result<Texture, String> {
        let image = image::load_from_memory(bytes).map_err(|e| e.to_string())?;
        let rgb = image.to_rgb8();
        let (w, h) = rgb.dimensions();
        if w == 0 || h == 0 {
            return Err("the image is empty".into());
        }
        let texels = rgb.pixels().map(|p| p.0).collect();
        Ok(Texture::new(name, w, h, texels))
    }

    /// Reads the image file at `path`.
    ///
    /// # Errors
    /// Why it could not be read or decoded.
    pub fn open(path: &Path) -> Result<Texture, String> {
        let bytes = std::fs::read(path).map_err(|e| e.to_string())?;
        Self::decode_image(&path.display().to_string(), &bytes)
    }

    /// Width and height of level 0.
    pub fn size(&self) -> (u32, u32) {
        (self.levels[0].width, self.levels[0].height)
    }

    /// How many mip levels the chain has.
    pub fn level_count(&self) -> usize {
        self.levels.len()
    }

    /// Bytes of the texels of every level (for memory reports and hashing).
    pub fn texel_bytes(&self) -> usize {
        self.levels.iter().map(|l| l.texels.len() * 3).sum()
    }

    /// Feeds level 0 and its size to `hasher`: the levels after it follow from it.
    pub(crate) fn hash_into(&self, hasher: &mut blake3::Hasher) {
        let base = &self.levels[0];
        hasher.update(&base.width.to_le_bytes());
        hasher.update(&base.height.to_le_bytes());
        hasher.update(bytemuck::cast_slice(&base.texels));
    }

    /// The level whose texels are about `footprint` level-0 texels wide: the level at which a
    /// pixel covers about one texel, so a distant texture neither shimmers nor aliases.
    ///
    /// `floor(log2(footprint · √2))`, read from the float's exponent bits: the nearest level
    /// in log scale, exact and the same on every CPU. Clamped to the chain.
    pub fn level_for(&self, footprint: f32) -> usize {
        let x = footprint * std::f32::consts::SQRT_2;
        if x.is_nan() || x < 2.0 {
            // Below 2 (or NaN): the full-resolution level.
            return 0;
        }
        let exponent = ((x.min(f32::MAX).to_bits() >> 23) & 0xff) as usize - 127;
        exponent.min(self.levels.len() - 1)
    }

    /// Bilinear sample at `uv` (u across, v down from the image's top row; both repeat
    /// outside 0..1) of mip `level`, as linear light.
    pub fn sample(&self, uv: Vec2, level: usize) -> Vec3 {
        let l = &self.levels[level.min(self.levels.len() - 1)];
        let wrap = |x: f32| if x.is_finite() { x - x.floor() } else { 0.0 };
        // Texel centres at (i + 0.5) / width.
        let x = wrap(uv.x) * l.width as f32 - 0.5;
        let y = wrap(uv.y) * l.height as f32 - 0.5;
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let col = |i: f32| (i as i64).rem_euclid(l.width as i64) as usize;
        let row = |j: f32| (j as i64).rem_euclid(l.height as i64) as usize * l.width as usize;
        let (c0, c1, r0, r1) = (col(x0), col(x0 + 1.0), row(y0), row(y0 + 1.0));
        let texel = |at: usize| Vec3::from_array(l.texels[at].map(decode));
        let top = texel(r0 + c0).lerp(texel(r0 + c1), fx);
        let bottom = texel(r1 + c0).lerp(texel(r1 + c1), fx);
        top.lerp(bottom, fy)
    }
}

impl MipLevel {
    /// The next level: each texel the linear mean of the (up to) 2×2 texels it covers; None
    /// for a 1×1 level.
    fn halved(&self) -> Option<MipLevel> {
        if self.width == 1 && self.height == 1 {
            return None;
        }
        let (w, h) = (self.width.div_ceil(2), self.height.div_ceil(2));
        let mut texels = Vec::with_capacity((w * h) as usize);
        for y in 0..h {
            for x in 0..w {
                let xs = [2 * x, (2 * x + 1).min(self.width - 1)];
                let ys = [2 * y, (2 * y + 1).min(self.height - 1)];
                let mut sum = Vec3::ZERO;
                for &sy in &ys {
                    for &sx in &xs {
                        let t = self.texels[(sy * self.width + sx) as usize];
                        sum += Vec3::from_array(t.map(decode));
                    }
                }
                texels.push((sum * 0.25).to_array().map(encode));
            }
        }
        Some(MipLevel {
            width: w,
            height: h,
            texels,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const RED: [u8; 3] = [255, 0, 0];
    const BLUE: [u8; 3] = [0, 0, 255];

    /// 2×2: red, blue on the top row; blue, red below.
    fn checker() -> Texture {
        Texture::new("checker", 2, 2, vec![RED, BLUE, BLUE, RED])
    }

    #[test]
    fn bilinear_sampling_hits_texel_centres_and_blends_between_them() {
        let t = checker();
        assert_eq!(t.sample(Vec2::new(0.25, 0.25), 0), Vec3::X);
        assert_eq!(t.sample(Vec2::new(0.75, 0.25), 0), Vec3::Z);
        assert_eq!(t.sample(Vec2::new(0.25, 0.75), 0), Vec3::Z);
        // Half-way between the two top texels: an even blend.
        let mid = t.sample(Vec2::new(0.5, 0.25), 0);
        assert!((mid - Vec3::new(0.5, 0.0, 0.5)).length() < 1e-6, "{mid}");
        // Coordinates repeat: 1.25 is 0.25, and -0.75 too.
        assert_eq!(t.sample(Vec2::new(1.25, -0.75), 0), Vec3::X);
        // A corner blends across the wrap: all four texels equally.
        let corner = t.sample(Vec2::ZERO, 0);
        assert!((corner - Vec3::new(0.5, 0.0, 0.5)).length() < 1e-6);
        assert!(t.sample(Vec2::splat(f32::NAN), 0).is_finite());
    }

    #[test]
    fn mip_levels_box_filter_in_linear_light_down_to_one_texel() {
        let t = Texture::new("odd", 5, 3, vec![[255, 255, 255]; 15]);
        assert_eq!(t.level_count(), 4, "5x3, 3x2, 2x1, 1x1");
        let t = checker();
        assert_eq!(t.level_count(), 2);
        // Half red, half blue in light: each channel's linear mean is 0.5, not byte 128's.
        let mean = t.sample(Vec2::splat(0.5), 1);
        assert!((mean - Vec3::new(0.5, 0.0, 0.5)).length() < 0.01, "{mean}");
        assert_eq!(t.levels[1].texels[0], [encode(0.5), 0, encode(0.5)]);
    }

    #[test]
    fn the_level_follows_the_footprint_in_texels() {
        let t = Texture::new("big", 64, 64, vec![[9, 9, 9]; 64 * 64]);
        assert_eq!(t.level_count(), 7);
        assert_eq!(t.level_for(0.1), 0);
        assert_eq!(t.level_for(1.0), 0);
        assert_eq!(t.level_for(1.5), 1, "nearer 2 than 1 in log scale");
        assert_eq!(t.level_for(2.0), 1);
        assert_eq!(t.level_for(4.0), 2);
        assert_eq!(t.level_for(5.0), 2);
        assert_eq!(t.level_for(6.0), 3);
        assert_eq!(t.level_for(1e30), 6, "clamped to the 1x1 level");
        assert_eq!(t.level_for(f32::INFINITY), 6);
        assert_eq!(t.level_for(f32::NAN), 0);
    }

    #[test]
    fn decoding_inverts_the_renderers_encoding() {
        for c in 0..=255u8 {
            assert_eq!(encode(decode(c)), c);
            assert_eq!(crate::shade::encode_channel(decode(c)), c);
        }
    }

    #[test]
    fn png_bytes_decode_to_texels() {
        let mut png = Vec::new();
        let image =
            image::RgbImage::from_fn(2, 1, |x, _| image::Rgb(if x == 0 { RED } else { BLUE }));
        image
            .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .unwrap();
        let t = Texture::decode_image("two.png", &png).unwrap();
        assert_eq!(t.size(), (2, 1));
        assert_eq!(t.sample(Vec2::new(0.25, 0.5), 0), Vec3::X);
        assert!(Texture::decode_image("junk.png", b"not an image").is_err());
    }
}
