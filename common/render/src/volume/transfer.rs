//! A frame's transfer function as a table over the volume's range, with opacity corrected for
//! the marching step, and which macro-cells it makes visible.
//!
//! Opacities are given per reference step (the smallest voxel spacing); a sample taken every
//! `step` has `a' = 1 - (1 - a)^(step / step_ref)`, computed as `-expm1(r · ln_1p(-a))` in f64:
//! exact near `a = 0`, where `powf` on `1 - a` loses every digit, and exactly 1 at `a = 1`. The
//! f64 results are rounded to f32 once, so two CPUs whose libm differ in the last f64 bit still
//! agree on the table, and tiles stay byte-identical on any node.

use super::bricks::whole4;
use glam::Vec4;
use tessera_model::volume_params::{TransferDomain, TransferFunction};

/// Entries of the table; between them colour and opacity are interpolated linearly.
pub const TABLE_ENTRIES: usize = 4096;

/// Opacity of one sample `step` long, for an opacity `alpha` per `step_ref`.
pub fn corrected_opacity(alpha: f64, step_over_ref: f64) -> f64 {
    if alpha >= 1.0 {
        return 1.0;
    }
    -(step_over_ref * (-alpha).ln_1p()).exp_m1()
}

/// Premultiplied colour and corrected opacity at `TABLE_ENTRIES` (4096) values over the range.
#[derive(Clone, Debug)]
pub struct TransferTable {
    lo: f32,
    per_unit: f32,
    /// A fixed-size array, so that lookups need no bounds check.
    entries: Box<[[f32; 4]; TABLE_ENTRIES]>,
    /// How many entries below each index have a non-zero opacity: a value range is invisible
    /// iff the count does not change across it.
    visible_before: Vec<u32>,
    /// What a missing sample (NaN) shows: transparent, or an opaque colour.
    missing: [f32; 4],
}

impl TransferTable {
    /// The table of `tf` over the data range `(lo, hi)` for samples `step_over_ref` reference
    /// steps apart.
    pub fn new(tf: &TransferFunction, (lo, hi): (f32, f32), step_over_ref: f64) -> Self {
        let span = (hi - lo).max(f32::MIN_POSITIVE);
        let last = (TABLE_ENTRIES - 1) as f32;
        let entries: Vec<[f32; 4]> = (0..TABLE_ENTRIES)
            .map(|i| {
                let value = lo + span * (i as f32 / last);
                let x = match tf.domain() {
                    // A volume of one value shows it as the top of the range, not as nothing.
                    TransferDomain::Normalized if hi <= lo => 1.0,
                    TransferDomain::Normalized => (value - lo) / span,
                    TransferDomain::Data => value,
                };
                let (color, alpha) = tf.eval(x);
                let a = corrected_opacity(alpha as f64, step_over_ref) as f32;
                [color[0] * a, color[1] * a, color[2] * a, a]
            })
            .collect();
        let mut visible_before = Vec::with_capacity(TABLE_ENTRIES + 1);
        let mut count = 0;
        for e in &entries {
            visible_before.push(count);
            count += (e[3] > 0.0) as u32;
        }
        visible_before.push(count);
        let entries: Box<[[f32; 4]; TABLE_ENTRIES]> = entries
            .into_boxed_slice()
            .try_into()
            .expect("TABLE_ENTRIES entries");
        TransferTable {
            lo,
            // One value: every sample reads entry 0 (the whole table is that value's).
            per_unit: if hi > lo { last / span } else { 0.0 },
            entries,
            visible_before,
            missing: [0.0; 4],
        }
    }

    /// This table with missing samples drawn opaque in the linear colour `color` (None:
    /// transparent, as they are by default).
    pub fn with_missing(self, color: Option<[f32; 3]>) -> Self {
        let missing = color.map_or([0.0; 4], |[r, g, b]| [r, g, b, 1.0]);
        TransferTable { missing, ..self }
    }

    /// Whether a missing sample shows at all.
    pub fn shows_missing(&self) -> bool {
        self.missing[3] > 0.0
    }

    /// Where `value` falls in the table, clamped to it.
    #[inline]
    fn position(&self, value: f32) -> f32 {
        ((value - self.lo) * self.per_unit).clamp(0.0, (TABLE_ENTRIES - 1) as f32)
    }

    /// Premultiplied colour and opacity of a sample of `value`; a missing one (NaN: its cell
    /// touches missing data) is transparent, or the missing-data colour
    /// ([`TransferTable::with_missing`]).
    #[inline]
    pub fn lookup(&self, value: f32) -> [f32; 4] {
        if value.is_nan() {
            return self.missing;
        }
        let x = self.position(value);
        let i = (x as usize).min(TABLE_ENTRIES - 2);
        let f = x - i as f32;
        let (a, b) = (self.entries[i], self.entries[i + 1]);
        std::array::from_fn(|c| a[c] + (b[c] - a[c]) * f)
    }

    /// [`TransferTable::lookup`] of four values, as four `[r, g, b, a]` vectors; each is what
    /// `lookup` gives, bit for bit.
    #[inline(always)]
    pub fn lookup4(&self, values: Vec4) -> [Vec4; 4] {
        let missing = values.to_array().map(f32::is_nan);
        let last = (TABLE_ENTRIES - 1) as f32;
        let x =
            ((values - Vec4::splat(self.lo)) * self.per_unit).clamp(Vec4::ZERO, Vec4::splat(last));
        // The table index of each lane (x >= 0, so truncation is floor).
        let whole = whole4(x.trunc());
        let x = x.to_array();
        std::array::from_fn(|lane| {
            if missing[lane] {
                return Vec4::from_array(self.missing);
            }
            let i = (whole[lane] as usize).min(TABLE_ENTRIES - 2);
            let f = x[lane] - i as f32;
            let (a, b) = (
                Vec4::from_array(self.entries[i]),
                Vec4::from_array(self.entries[i + 1]),
            );
            a + (b - a) * f
        })
    }

    /// Whether any value in `lo..=hi` has a non-zero opacity (conservatively: the entries
    /// around both ends count, one more each side than interpolation reads, against a value
    /// interpolated an ulp outside its corners).
    pub fn any_visible(&self, (lo, hi): (f32, f32)) -> bool {
        let first = (self.position(lo) as usize).saturating_sub(1);
        let last = (self.position(hi) as usize + 2).min(TABLE_ENTRIES - 1);
        self.visible_before[last + 1] > self.visible_before[first]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_model::volume_params::TransferPoint;

    #[test]
    fn opacity_correction_is_exact_at_the_ends_and_composes() {
        assert_eq!(corrected_opacity(0.0, 3.0), 0.0);
        assert_eq!(corrected_opacity(1.0, 0.01), 1.0);
        // A tiny opacity keeps its digits (through 1 - a, f32 would have none left).
        let tiny = corrected_opacity(1e-12, 0.5);
        assert!((tiny - (5e-13 + 1e-24 / 8.0)).abs() < 1e-27, "{tiny:e}");
        // Two half steps let through what one whole step does.
        let a = 0.3;
        let half = corrected_opacity(a, 0.5);
        assert!(((1.0 - half) * (1.0 - half) - (1.0 - a)).abs() < 1e-15);
        // Near 1 it stays below 1 and finite.
        let near_one = corrected_opacity(1.0 - 1e-12, 0.25);
        assert!(near_one < 1.0 && near_one > 0.999);
    }

    #[test]
    fn the_table_follows_the_function_and_knows_what_is_invisible() {
        let p = |value, opacity| TransferPoint {
            value,
            color: [1.0, 0.5, 0.0],
            opacity,
        };
        let tf = TransferFunction::new(
            TransferDomain::Data,
            &[p(0.0, 0.0), p(50.0, 0.0), p(100.0, 1.0)],
        )
        .unwrap();
        let table = TransferTable::new(&tf, (0.0, 100.0), 1.0);
        let e = table.lookup(75.0);
        assert!(
            (e[3] - 0.5).abs() < 1e-3 && (e[1] - 0.25).abs() < 1e-3,
            "{e:?}"
        );
        assert_eq!(table.lookup(-10.0)[3], 0.0);
        assert!(!table.any_visible((0.0, 49.0)));
        assert!(table.any_visible((40.0, 60.0)));
        assert!(table.any_visible((99.0, 100.0)));
    }
}
