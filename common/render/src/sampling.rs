//! Deterministic random numbers keyed on (frame, pixel, sample), and hemisphere directions.
//!
//! A sample depends only on its key, never on which thread or node draws it, so a tile comes out
//! bit-identical wherever it is rendered. Directions are built from +, ×, and `sqrt` only (IEEE
//! exact), not `sin`/`cos`, whose results differ between libm versions across a wall's hosts.

use glam::Vec3;

/// SplitMix64 finalizer: a good 64-bit mix for hashing keys.
#[inline(always)]
fn mix(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// A stream of uniform numbers for one (frame, pixel, sample).
pub struct SampleStream(u64);

impl SampleStream {
    /// The stream keyed on frame `frame`, pixel `(x, y)` and sample key `sample`: the same numbers
    /// wherever it is drawn.
    pub fn new(frame: u64, x: u32, y: u32, sample: u32) -> Self {
        PixelSeed::new(frame, x, y).stream(sample)
    }

    /// Uniform in [0, 1), 24 bits.
    #[inline(always)]
    pub fn next_f32(&mut self) -> f32 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        (mix(self.0) >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
    }
}

/// What the streams of one (frame, pixel) share: drawing a pixel's many samples from it
/// hashes the frame and pixel once instead of once per sample (two of the three hashes that
/// start a stream; an ambient-occlusion pixel draws dozens).
#[derive(Clone, Copy, Debug)]
pub struct PixelSeed(u64);

impl PixelSeed {
    /// The seed of frame `frame`, pixel `(x, y)`.
    #[inline(always)]
    pub fn new(frame: u64, x: u32, y: u32) -> Self {
        let pixel = ((y as u64) << 32) | x as u64;
        PixelSeed(mix(mix(frame ^ 0x7e55_e7a0) ^ pixel))
    }

    /// The stream of sample key `sample`: the same numbers as
    /// `SampleStream::new(frame, x, y, sample)`.
    #[inline(always)]
    pub fn stream(self, sample: u32) -> SampleStream {
        SampleStream(self.0.wrapping_add(mix(sample as u64 + 1)))
    }
}

/// Cosine-weighted direction around unit `normal` (Malley: a uniform point on the unit disk,
/// lifted to the hemisphere). The disk point comes from bounded rejection sampling.
pub fn cosine_direction(normal: Vec3, stream: &mut SampleStream) -> Vec3 {
    Hemisphere::around(normal).cosine_direction(stream)
}

/// The frame of the hemisphere around a normal, made once for all the directions drawn
/// around it (an ambient-occlusion pixel draws dozens).
#[derive(Clone, Copy, Debug)]
pub struct Hemisphere {
    normal: Vec3,
    tangent: Vec3,
    bitangent: Vec3,
}

impl Hemisphere {
    /// The hemisphere around unit `normal`.
    pub fn around(normal: Vec3) -> Self {
        let (tangent, bitangent) = orthonormal_basis(normal);
        Hemisphere {
            normal,
            tangent,
            bitangent,
        }
    }

    /// [`cosine_direction`] around this hemisphere's normal: the same bits.
    pub fn cosine_direction(&self, stream: &mut SampleStream) -> Vec3 {
        let (dx, dy, dz) = disk_lift(stream);
        self.tangent * dx + self.bitangent * dy + self.normal * dz
    }
}

/// A cosine-distributed point of the unit hemisphere in its own frame.
#[inline(always)]
fn disk_lift(stream: &mut SampleStream) -> (f32, f32, f32) {
    let (mut dx, mut dy) = (0.0f32, 0.0f32);
    for _ in 0..32 {
        let x = 2.0 * stream.next_f32() - 1.0;
        let y = 2.0 * stream.next_f32() - 1.0;
        if x * x + y * y < 1.0 {
            (dx, dy) = (x, y);
            break;
        }
    }
    let dz = (1.0 - dx * dx - dy * dy).max(0.0).sqrt();
    (dx, dy, dz)
}

/// Two unit vectors completing `n` to an orthonormal basis (Duff et al. 2017, branch-free).
pub fn orthonormal_basis(n: Vec3) -> (Vec3, Vec3) {
    let sign = 1.0f32.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (
        Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
        Vec3::new(b, sign + n.y * n.y * a, -n.y),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_key_same_numbers_other_key_other_numbers() {
        let a: Vec<f32> = (0..8)
            .map({
                let mut s = SampleStream::new(3, 10, 20, 1);
                move |_| s.next_f32()
            })
            .collect();
        let b: Vec<f32> = (0..8)
            .map({
                let mut s = SampleStream::new(3, 10, 20, 1);
                move |_| s.next_f32()
            })
            .collect();
        let c: Vec<f32> = (0..8)
            .map({
                let mut s = SampleStream::new(3, 10, 20, 2);
                move |_| s.next_f32()
            })
            .collect();
        assert_eq!(a, b);
        assert_ne!(a, c);
        assert!(a.iter().all(|v| (0.0..1.0).contains(v)));
    }

    /// A pixel's seed makes the streams a key hashed whole made before it existed: pictures
    /// with ambient occlusion keep their bits.
    #[test]
    fn a_pixel_seed_starts_the_streams_the_whole_key_started() {
        for (frame, x, y, sample) in [(0, 0, 0, 0), (7, 1919, 1079, 63), (u64::MAX, 3, 9, 1 << 20)]
        {
            let pixel = ((y as u64) << 32) | x as u64;
            let whole = mix(mix(frame ^ 0x7e55_e7a0) ^ pixel).wrapping_add(mix(sample as u64 + 1));
            let seeded = PixelSeed::new(frame, x, y).stream(sample);
            assert_eq!(seeded.0, whole, "{frame} {x} {y} {sample}");
        }
    }

    #[test]
    fn cosine_directions_are_unit_and_in_the_hemisphere_with_cosine_mean() {
        let n = Vec3::new(0.3, -0.8, 0.52).normalize();
        let mut sum = 0.0;
        let count = 20_000;
        for i in 0..count {
            let mut s = SampleStream::new(1, i, 0, 0);
            let d = cosine_direction(n, &mut s);
            assert!((d.length() - 1.0).abs() < 1e-4);
            assert!(d.dot(n) >= -1e-6);
            sum += d.dot(n);
        }
        // E[cos θ] under a cosine-weighted distribution is 2/3.
        let mean = sum / count as f32;
        assert!((mean - 2.0 / 3.0).abs() < 0.01, "{mean}");
    }
}
