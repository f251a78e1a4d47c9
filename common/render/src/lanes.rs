//! The per-pixel loops of a frame around its traversal, the eye light's colours and the
//! 8-bit encoding, with SIMD builds (`isa_builds!`). Compiled for the baseline they ran four
//! lanes at a time, a tenth of an eye-light frame; the builds run the same operations in the
//! same order, so every one gives the bits of the portable one (the tests check it).

use crate::isa::{isa_builds, Build};
use crate::packet::{lane_mask, LaneMask, PACKET_RAYS};
use crate::shade::{encode_channel, BACKDROP};

isa_builds! {
    /// Encodes each of `linear`, divided by `spp`, as [`encode_channel`] does, into `out`
    /// (as many as the shorter of the two), on the build `isa`.
    pub(crate) fn encode_channels<>(linear: &[f32], spp: f32, out: &mut [u8])
        = encode_kernel on [Avx2, Avx512];
}

#[inline(always)]
fn encode_kernel<B: Build>(_: B, linear: &[f32], spp: f32, out: &mut [u8]) {
    // One sample (interactive frames) divides by 1, which changes no bit: skipped, as the
    // division and the square root each had the vector unit to themselves.
    if spp == 1.0 {
        for (o, &c) in out.iter_mut().zip(linear) {
            *o = encode_channel(c);
        }
        return;
    }
    for (o, &c) in out.iter_mut().zip(linear) {
        *o = encode_channel(c / spp);
    }
}

/// The eye light's inputs for one packet, one array per axis or channel and one lane per ray.
pub(crate) struct EyeLightLanes {
    /// Each hit's triangle normal, unnormalised (anything where the ray missed).
    pub normals: [[f32; PACKET_RAYS]; 3],
    /// Each hit's base colour.
    pub albedo: [[f32; PACKET_RAYS]; 3],
    /// All ones where the ray hit, zero where it missed.
    pub hit: [LaneMask; PACKET_RAYS],
}

isa_builds! {
    /// Adds each lane's eye-light colour to `sum` (RGB per lane), on the build `isa`: the
    /// albedo times `|N̂·D|` where the ray hit ([`crate::shade::eye_light`], the normal
    /// normalised as `Vec3::normalize_or_zero` does, 0 for one of zero length), the backdrop
    /// ([`crate::shade::background`]) where it missed; operation for operation those
    /// functions', so the bits are the same. Every lane is added, those past a packet's
    /// length too (their sums are never read). Adding here, in the SIMD build, spares a
    /// transpose of the colours into the RGB sums compiled for the baseline: 3 % of an
    /// eye-light frame.
    pub(crate) fn eye_light_colors_on<>(
        lanes: &EyeLightLanes,
        dirs: &[[f32; PACKET_RAYS]; 3],
        sum: &mut [[f32; 3]; PACKET_RAYS],
    ) = colors_kernel on [Avx2, Avx512];
}

#[inline(always)]
fn colors_kernel<B: Build>(
    _: B,
    lanes: &EyeLightLanes,
    dirs: &[[f32; PACKET_RAYS]; 3],
    sum: &mut [[f32; 3]; PACKET_RAYS],
) {
    let [low, high] = BACKDROP.map(|c| c.to_array());
    for i in 0..PACKET_RAYS {
        let [x, y, z] = [0, 1, 2].map(|axis| lanes.normals[axis][i]);
        let rcp = 1.0 / (x * x + y * y + z * z).sqrt();
        let dot = (x * rcp) * dirs[0][i] + (y * rcp) * dirs[1][i] + (z * rcp) * dirs[2][i];
        // `normalize_or_zero`'s `rcp.is_finite() && rcp > 0.0`, as a mask of compares SIMD
        // has (written as a branch, the loop did not vectorize).
        let keep = (rcp > 0.0) & (rcp < f32::INFINITY);
        let cosine = f32::from_bits(dot.abs().to_bits() & lane_mask(keep));
        // `Vec3::lerp`: `low * (1 - t) + high * t`.
        let t = 0.5 + 0.5 * dirs[1][i];
        for c in 0..3 {
            let lit = (lanes.albedo[c][i] * cosine).to_bits();
            let backdrop = (low[c] * (1.0 - t) + high[c] * t).to_bits();
            let hit = lanes.hit[i];
            sum[i][c] += f32::from_bits((lit & hit) | (backdrop & !hit));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::isa::Isa;
    use crate::shade::{background, eye_light};
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
    fn every_build_gives_the_eye_light_and_the_backdrop_of_the_scalar_shading_bit_for_bit() {
        let floats = awkward_floats();
        let pick = |k: usize| floats[k * 7919 % floats.len()];
        let mut lanes = EyeLightLanes {
            normals: [[0.0; 64]; 3],
            albedo: [[0.0; 64]; 3],
            hit: [0; 64],
        };
        let mut dirs = [[0.0f32; 64]; 3];
        for round in 0..200 {
            for i in 0..64 {
                let k0 = (round * 64 + i) * 3;
                // One lane in five missed.
                lanes.hit[i] = if k0 % 5 == 0 { 0 } else { u32::MAX };
                for axis in 0..3 {
                    let k = k0 + axis;
                    // The special floats first (infinite, NaN, huge and subnormal normals),
                    // then awkward, zero and ordinary ones.
                    lanes.normals[axis][i] = match k % 4 {
                        _ if round == 0 && axis == i % 3 && i < 48 => floats[i / 3],
                        0 => pick(k),
                        1 => 0.0,
                        _ => (k % 13) as f32 * 0.37 - 2.0,
                    };
                    lanes.albedo[axis][i] = (k % 7) as f32 * 0.15;
                    dirs[axis][i] = (k % 11) as f32 * 0.19 - 1.0;
                }
            }
            let expected: [Vec3; 64] = std::array::from_fn(|i| {
                let axes = |a: &[[f32; PACKET_RAYS]; 3]| Vec3::new(a[0][i], a[1][i], a[2][i]);
                let (n, d) = (axes(&lanes.normals), axes(&dirs));
                if lanes.hit[i] == 0 {
                    background(d)
                } else {
                    eye_light(d, n.normalize_or_zero(), axes(&lanes.albedo))
                }
            });
            for isa in Isa::available() {
                // Added to sums already there, as over a frame's samples.
                let before = |i: usize| Vec3::splat(i as f32 * 0.125);
                let mut sum: [[f32; 3]; 64] = std::array::from_fn(|i| before(i).to_array());
                eye_light_colors_on(isa, &lanes, &dirs, &mut sum);
                for (i, want) in expected.iter().enumerate() {
                    let (got, want) = (Vec3::from_array(sum[i]), before(i) + *want);
                    assert_eq!(
                        got.to_array().map(f32::to_bits),
                        want.to_array().map(f32::to_bits),
                        "{isa:?} lane {i}: normal {:?}, hit {}",
                        [0, 1, 2].map(|a| lanes.normals[a][i]),
                        lanes.hit[i]
                    );
                }
            }
        }
    }
}
