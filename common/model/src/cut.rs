//! Cutting planes: half-spaces removed from the scene, to look inside a mesh or a volume.
//!
//! The kept region is the intersection of half-spaces `n·p ≤ d`, which is convex, so along any
//! ray it is one interval `[t_enter, t_exit]`. Every ray — primary, shadow, ambient, reflected —
//! is simply clipped to that interval: removed geometry neither shows nor casts shadows, and the
//! traversal needs nothing but a per-ray `t_min` and `t_max`.

use glam::{Vec3, Vec4};
use serde::{Deserialize, Serialize};

/// At most this many planes; enough for a slab (2) or a corner cut-out (3) plus one.
pub const MAX_CUTS: usize = 4;

/// Up to [`MAX_CUTS`] planes, each removing the points with `normal·p > offset`. Fixed-size so
/// that render parameters stay `Copy`. On the wire it is the list of used planes, each
/// `[nx, ny, nz, d]` with a unit normal; a list that claims more than [`MAX_CUTS`] planes or
/// holds a degenerate one is refused when it is read, so a `CutPlanes` is always usable.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
#[serde(into = "Vec<[f32; 4]>")]
pub struct CutPlanes {
    planes: [Vec4; MAX_CUTS],
    count: u8,
}

/// Why a set of cutting planes was refused.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum CutError {
    /// More than [`MAX_CUTS`] planes were given; carries how many.
    #[error("at most {MAX_CUTS} cutting planes are supported, got {0}")]
    TooMany(usize),
    /// The plane at this index has a zero or non-finite normal, or a non-finite offset.
    #[error("cutting plane {0} needs a finite, non-zero normal and a finite offset")]
    Degenerate(usize),
    /// The plane at this index arrived (deserialized) with a normal that is not of unit length:
    /// the sender must normalize; carries the index and the length.
    #[error("cutting plane {0} arrived with a normal of length {1}, not 1")]
    NotNormalized(usize, f32),
}

/// Planes as sent: already normalized by [`CutPlanes::new`] on the sending side, so they are
/// checked, never normalized again (that could change their bits, and a render node must cut
/// exactly where the reference does).
impl TryFrom<Vec<[f32; 4]>> for CutPlanes {
    type Error = CutError;

    fn try_from(planes: Vec<[f32; 4]>) -> Result<Self, CutError> {
        if planes.len() > MAX_CUTS {
            return Err(CutError::TooMany(planes.len()));
        }
        let mut out = CutPlanes::default();
        for (i, p) in planes.iter().enumerate() {
            let plane = Vec4::from_array(*p);
            if !plane.is_finite() {
                return Err(CutError::Degenerate(i));
            }
            let length = plane.truncate().length();
            if (length - 1.0).abs() > 1e-5 {
                return Err(CutError::NotNormalized(i, length));
            }
            out.planes[i] = plane;
        }
        out.count = planes.len() as u8;
        Ok(out)
    }
}

impl<'de> Deserialize<'de> for CutPlanes {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        crate::checked::deserialize::<D, Vec<[f32; 4]>, Self>(d)
    }
}

impl From<CutPlanes> for Vec<[f32; 4]> {
    fn from(cuts: CutPlanes) -> Self {
        cuts.planes().iter().map(|p| p.to_array()).collect()
    }
}

impl CutPlanes {
    /// No planes: nothing is cut away. The same as [`CutPlanes::default`], usable in `const`s.
    pub const EMPTY: CutPlanes = CutPlanes {
        planes: [Vec4::ZERO; MAX_CUTS],
        count: 0,
    };

    /// Planes as (normal, offset): each removes the side its normal points to. Normals are
    /// normalized here, so offsets are distances from the origin along the normal.
    pub fn new(planes: &[(Vec3, f32)]) -> Result<Self, CutError> {
        if planes.len() > MAX_CUTS {
            return Err(CutError::TooMany(planes.len()));
        }
        let mut out = CutPlanes::default();
        for (i, &(normal, offset)) in planes.iter().enumerate() {
            let length = normal.length();
            if !(length.is_finite() && length > 0.0 && offset.is_finite()) {
                return Err(CutError::Degenerate(i));
            }
            out.planes[i] = (normal / length).extend(offset / length);
        }
        out.count = planes.len() as u8;
        Ok(out)
    }

    /// Whether there are no planes, so that the whole scene is kept.
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// The planes in use, each `(nx, ny, nz, d)` with a unit normal: it removes the points with
    /// `n·p > d`.
    pub fn planes(&self) -> &[Vec4] {
        &self.planes[..self.count as usize]
    }

    /// Whether a point is kept (not cut away).
    pub fn keeps(&self, point: Vec3) -> bool {
        self.planes().iter().all(|p| p.truncate().dot(point) <= p.w)
    }

    /// The part `[t_min, t_max]` of `t ≥ 0` along `origin + t·dir` that lies in the kept
    /// region; `t_min > t_max` when there is none.
    pub fn interval(&self, origin: Vec3, dir: Vec3) -> (f32, f32) {
        let (mut t_min, mut t_max) = (0.0f32, f32::INFINITY);
        for p in self.planes() {
            let normal = p.truncate();
            let outside = normal.dot(origin) - p.w;
            let towards = normal.dot(dir);
            if towards > 0.0 {
                t_max = t_max.min(-outside / towards);
            } else if towards < 0.0 {
                t_min = t_min.max(-outside / towards);
            } else if outside > 0.0 {
                return (f32::INFINITY, f32::NEG_INFINITY);
            }
        }
        if t_min > t_max || t_min.is_nan() || t_max.is_nan() {
            return (f32::INFINITY, f32::NEG_INFINITY);
        }
        (t_min, t_max)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_slab_keeps_the_middle_of_a_ray() {
        let cuts = CutPlanes::new(&[(Vec3::X, 1.0), (-Vec3::X * 2.0, 2.0)]).unwrap();
        // The second plane, normalized, keeps x ≥ -1.
        assert_eq!(
            cuts.interval(Vec3::new(-5.0, 0.0, 0.0), Vec3::X),
            (4.0, 6.0)
        );
        assert_eq!(cuts.interval(Vec3::ZERO, Vec3::X), (0.0, 1.0));
        let (a, b) = cuts.interval(Vec3::new(5.0, 0.0, 0.0), Vec3::X);
        assert!(a > b, "a ray leaving the slab sees nothing");
        let (a, b) = cuts.interval(Vec3::new(5.0, 0.0, 0.0), Vec3::Y);
        assert!(a > b, "parallel outside");
        assert_eq!(cuts.interval(Vec3::ZERO, Vec3::Y), (0.0, f32::INFINITY));
        assert!(cuts.keeps(Vec3::new(0.5, 9.0, 9.0)) && !cuts.keeps(Vec3::new(1.5, 0.0, 0.0)));
    }

    #[test]
    fn bad_planes_are_refused() {
        assert_eq!(
            CutPlanes::new(&[(Vec3::ZERO, 1.0)]),
            Err(CutError::Degenerate(0))
        );
        assert_eq!(
            CutPlanes::new(&[(Vec3::X, f32::NAN)]),
            Err(CutError::Degenerate(0))
        );
        assert_eq!(
            CutPlanes::new(&[(Vec3::X, 0.0); 5]),
            Err(CutError::TooMany(5))
        );
        assert!(CutPlanes::default().is_empty());
    }

    #[test]
    fn planes_survive_the_wire_bit_for_bit() {
        let cuts = CutPlanes::new(&[(Vec3::new(1.0, 2.0, 3.0), 0.7), (-Vec3::Y, 2.0)]).unwrap();
        let bytes = postcard::to_allocvec(&cuts).unwrap();
        assert_eq!(postcard::from_bytes::<CutPlanes>(&bytes).unwrap(), cuts);
    }

    #[test]
    fn more_than_four_planes_from_the_wire_are_refused_not_a_panic() {
        // A FrameStart that claims five planes used to build a CutPlanes whose planes()
        // panicked on the slice [..5] of a 4-plane array.
        let five = vec![[1.0f32, 0.0, 0.0, 0.0]; 5];
        let bytes = postcard::to_allocvec(&five).unwrap();
        let err = crate::checked::decode_for_test::<CutPlanes>(&bytes).unwrap_err();
        assert!(err.to_string().contains("at most 4"), "{err}");
        let skewed = vec![[3.0f32, 0.0, 0.0, 0.0]];
        let bytes = postcard::to_allocvec(&skewed).unwrap();
        assert!(postcard::from_bytes::<CutPlanes>(&bytes).is_err());
    }
}
