//! The per-pixel loops of a frame around its traversal, the eye light's cosines and the
//! 8-bit encoding, with SIMD builds (`isa_builds!`). Compiled for the baseline they ran four
//! lanes at a time, a tenth of an eye-light frame; the builds run the same operations in the
//! same order, so every one gives the bits of the portable one (the tests check it).

use crate::isa::{isa_builds, Build};
use crate::shade::encode_channel;

isa_builds! {
    /// Encodes each of `linear`, divided by `spp`, as [`encode_channel`] does, into `out`
    /// (as many as the shorter of the two), on the build `isa`.
    pub(crate) fn encode_channels<>(linear: &[f32], spp: f32, out: &mut [u8])
        = encode_kernel on [Avx2, Avx512];
}

#[inline(always)]
fn encode_kernel<B: Build>(_: B, linear: &[f32], spp: f32, out: &mut [u8]) {
    for (o, &c) in out.iter_mut().zip(linear) {
        *o = encode_channel(c / spp);
    }
}

isa_builds! {
    /// Per lane, `|N̂·D|` for the unnormalised normals `normals` and directions `dirs` (one
    /// array per axis), on the build `isa`: what [`crate::shade::eye_light`] multiplies the
    /// albedo by, with the normal normalised as `Vec3::normalize_or_zero` does, operation for
    /// operation, so the bits are the same (0 for a normal of zero length).
    pub(crate) fn eye_light_cosines_on<>(
        normals: &[[f32; 64]; 3],
        dirs: &[[f32; 64]; 3],
        cosines: &mut [f32; 64],
    ) = cosines_kernel on [Avx2, Avx512];
}

#[inline(always)]
fn cosines_kernel<B: Build>(
    _: B,
    normals: &[[f32; 64]; 3],
    dirs: &[[f32; 64]; 3],
    cosines: &mut [f32; 64],
) {
    for (i, cosine) in cosines.iter_mut().enumerate() {
        let (x, y, z) = (normals[0][i], normals[1][i], normals[2][i]);
        let rcp = 1.0 / (x * x + y * y + z * z).sqrt();
        let dot = (x * rcp) * dirs[0][i] + (y * rcp) * dirs[1][i] + (z * rcp) * dirs[2][i];
        // `normalize_or_zero`'s `rcp.is_finite() && rcp > 0.0`, as a mask of compares SIMD
        // has (written as a branch, the loop did not vectorize).
        let keep = (rcp > 0.0) & (rcp < f32::INFINITY);
        *cosine = f32::from_bits(dot.abs().to_bits() & u32::from(keep).wrapping_neg());
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::isa::Isa;
    use crate::shade::eye_light;
    use glam::Vec3;

    /// Floats of every kind: zeros, subnormals, the edges of 0..=1, huge, infinite, NaN, and
    /// a spread of bit patterns.
    fn awkward_floats() -> Vec<f32> {
        let mut v = vec![
            0.0,
            -0.0,
            f32::MIN_POSITIVE,
            1e-45,
            -1e-45,
            1.0,
            1.0 - f32::EPSILON,
            1.0 + f32::EPSILON,
            0.5,
            -1.0,
            f32::MAX,
            f32::MIN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
            -f32::NAN,
        ];
        v.extend((0..u32::MAX).step_by(65_537).map(f32::from_bits));
        v
    }

    #[test]
    fn every_build_encodes_as_the_one_channel_encoding_does() {
        let linear = awkward_floats();
        for spp in [1.0, 3.0] {
            let expected: Vec<u8> = linear.iter().map(|&c| encode_channel(c / spp)).collect();
            for isa in Isa::available() {
                let mut out = vec![7u8; linear.len()];
                encode_channels(isa, &linear, spp, &mut out);
                assert_eq!(out, expected, "{isa:?}, spp {spp}");
            }
        }
    }

    #[test]
    fn the_encoding_is_the_clamped_square_root_and_black_for_non_finite_values() {
        // The formula the encoding had before it was written for SIMD.
        let plain = |c: f32| {
            if c.is_finite() {
                (c.clamp(0.0, 1.0).sqrt() * 255.0 + 0.5) as u8
            } else {
                0
            }
        };
        for c in awkward_floats() {
            assert_eq!(encode_channel(c), plain(c), "{c:e} ({:#x})", c.to_bits());
        }
    }

    #[test]
    fn every_build_gives_the_cosines_of_the_eye_light_bit_for_bit() {
        let floats = awkward_floats();
        let pick = |k: usize| floats[k * 7919 % floats.len()];
        let mut normals = [[0.0f32; 64]; 3];
        let mut dirs = [[0.0f32; 64]; 3];
        for round in 0..200 {
            for i in 0..64 {
                for axis in 0..3 {
                    let k = (round * 64 + i) * 3 + axis;
                    // The special floats first (infinite, NaN, huge and subnormal normals),
                    // then awkward, zero and ordinary ones.
                    normals[axis][i] = match k % 4 {
                        _ if round == 0 && axis == i % 3 && i < 48 => floats[i / 3],
                        0 => pick(k),
                        1 => 0.0,
                        _ => (k % 13) as f32 * 0.37 - 2.0,
                    };
                    dirs[axis][i] = (k % 11) as f32 * 0.19 - 1.0;
                }
            }
            let expected: [f32; 64] = std::array::from_fn(|i| {
                let n = Vec3::new(normals[0][i], normals[1][i], normals[2][i]);
                let d = Vec3::new(dirs[0][i], dirs[1][i], dirs[2][i]);
                eye_light(d, n.normalize_or_zero(), Vec3::ONE).x
            });
            for isa in Isa::available() {
                let mut cosines = [f32::NAN; 64];
                eye_light_cosines_on(isa, &normals, &dirs, &mut cosines);
                for i in 0..64 {
                    assert_eq!(
                        cosines[i].to_bits(),
                        expected[i].to_bits(),
                        "{isa:?} lane {i}: normal {:?}",
                        [normals[0][i], normals[1][i], normals[2][i]]
                    );
                }
            }
        }
    }
}
