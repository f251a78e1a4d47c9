//! How volumes are drawn, per frame: the ray-marching step, the iso-values of direct
//! iso-surfaces, and the transfer function. All of it is frame state, changed at the barrier
//! like the camera, so the iso-value or the colours can change at any frame with no rebuild.
//!
//! Fixed-size and `Copy` like the rest of [`crate::params::RenderParams`]; on the wire each list
//! is the used entries only, checked when it is read.

use serde::{Deserialize, Serialize};

/// Most iso-surfaces drawn at once.
pub const MAX_ISO_VALUES: usize = 4;
/// Most control points of a transfer function.
pub const MAX_TRANSFER_POINTS: usize = 16;

/// Why volume parameters were refused.
#[derive(Clone, Debug, thiserror::Error, PartialEq)]
pub enum VolumeParamsError {
    /// More than [`MAX_ISO_VALUES`] iso-values were given; carries how many.
    #[error("at most {MAX_ISO_VALUES} iso-values are supported, got {0}")]
    TooManyIso(usize),
    /// An iso-value is NaN or infinite.
    #[error("iso-value {0} is not a finite number")]
    BadIso(f32),
    /// The ray-marching step is negative, infinite or NaN.
    #[error("the volume step {0} must be finite and above 0 (or 0 for the default)")]
    BadStep(f32),
    /// The step factor [`VolumeParams::coarsen`] is outside 1 to [`VolumeParams::MAX_COARSEN`].
    #[error("the step factor {0} must be from 1 to 16")]
    BadCoarsen(f32),
    /// An iso-surface's colour has a component outside 0 to 1, or its opacity is outside 0
    /// to 1.
    #[error("iso-surface {index}: {why}")]
    BadIsoLook {
        /// Which iso-value, from 0.
        index: usize,
        /// What is wrong with its look.
        why: String,
    },
    /// The colour of missing data has a component that is negative or not finite.
    #[error("the missing-data colour {0:?} needs finite components of 0 or more")]
    BadMissingColor([f32; 3]),
    /// A transfer function has no points or more than [`MAX_TRANSFER_POINTS`]; carries how many.
    #[error("a transfer function needs 1 to {MAX_TRANSFER_POINTS} points, got {0}")]
    TransferPointCount(usize),
    /// A transfer-function point has a non-finite value or one below the previous point's, a
    /// negative or non-finite colour, or an opacity outside 0 to 1.
    #[error("transfer function point {index}: {why}")]
    BadTransferPoint {
        /// Which point, from 0.
        index: usize,
        /// What is wrong with it, for the message.
        why: String,
    },
}

/// Up to [`MAX_ISO_VALUES`] iso-values, in the data's own units.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
#[serde(into = "Vec<f32>")]
pub struct IsoValues {
    values: [f32; MAX_ISO_VALUES],
    count: u8,
}

impl IsoValues {
    /// No iso-values: volumes are drawn through their transfer function.
    pub const NONE: IsoValues = IsoValues {
        values: [0.0; MAX_ISO_VALUES],
        count: 0,
    };

    /// The given iso-values, in order.
    ///
    /// # Errors
    /// More than [`MAX_ISO_VALUES`] values, or one that is not finite.
    pub fn new(values: &[f32]) -> Result<Self, VolumeParamsError> {
        if values.len() > MAX_ISO_VALUES {
            return Err(VolumeParamsError::TooManyIso(values.len()));
        }
        let mut out = IsoValues::NONE;
        for (slot, &v) in out.values.iter_mut().zip(values) {
            if !v.is_finite() {
                return Err(VolumeParamsError::BadIso(v));
            }
            *slot = v;
        }
        out.count = values.len() as u8;
        Ok(out)
    }

    /// The iso-values in use, in the order given.
    pub fn as_slice(&self) -> &[f32] {
        &self.values[..self.count as usize]
    }

    /// Whether there are none, so that volumes are drawn through their transfer function.
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }
}

impl TryFrom<Vec<f32>> for IsoValues {
    type Error = VolumeParamsError;
    fn try_from(values: Vec<f32>) -> Result<Self, VolumeParamsError> {
        IsoValues::new(&values)
    }
}

impl From<IsoValues> for Vec<f32> {
    fn from(iso: IsoValues) -> Self {
        iso.as_slice().to_vec()
    }
}

impl<'de> Deserialize<'de> for IsoValues {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        crate::checked::deserialize::<D, Vec<f32>, Self>(d)
    }
}

/// One control point: at data value `value`, colour `color` (linear RGB, not premultiplied)
/// and opacity `opacity` per reference step (the volume's smallest voxel spacing).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TransferPoint {
    /// The data value the point sits at, in the function's [`TransferDomain`].
    pub value: f32,
    /// Linear RGB colour, not premultiplied, each component 0 or more.
    pub color: [f32; 3],
    /// Opacity per reference step (the volume's smallest voxel spacing), 0 to 1.
    pub opacity: f32,
}

/// Whether transfer-function values are the data's own units or fractions of its range.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum TransferDomain {
    /// 0 is the volume's smallest value, 1 its largest: one function fits any volume.
    #[default]
    Normalized,
    /// The data's own units (Hounsfield units for CT).
    Data,
}

/// A piecewise-linear map from data value to colour and opacity; constant beyond its ends.
///
/// # Examples
///
/// ```
/// use tessera_model::volume_params::{TransferFunction, TransferPoint, TransferDomain};
///
/// let ramp = TransferFunction::ramp();
/// assert_eq!(ramp.domain(), TransferDomain::Normalized);
/// let p = |value, opacity| TransferPoint { value, color: [1.0; 3], opacity };
/// assert!(TransferFunction::new(TransferDomain::Data, &[p(1.0, 0.5), p(0.0, 0.5)]).is_err());
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(into = "TransferSpec")]
pub struct TransferFunction {
    domain: TransferDomain,
    points: [TransferPoint; MAX_TRANSFER_POINTS],
    count: u8,
}

/// [`TransferFunction`] as it travels: the used points only.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TransferSpec {
    /// Whether the points' values are fractions of the data's range or its own units.
    pub domain: TransferDomain,
    /// The control points, 1 to [`MAX_TRANSFER_POINTS`], in order of increasing value.
    pub points: Vec<TransferPoint>,
}

impl TransferFunction {
    /// The function through `points`, in order of increasing value, read in `domain`.
    ///
    /// # Errors
    /// No points or more than [`MAX_TRANSFER_POINTS`]; a value that is not finite or smaller
    /// than the one before; a colour that is negative or not finite; an opacity outside 0..1.
    pub fn new(
        domain: TransferDomain,
        points: &[TransferPoint],
    ) -> Result<Self, VolumeParamsError> {
        if points.is_empty() || points.len() > MAX_TRANSFER_POINTS {
            return Err(VolumeParamsError::TransferPointCount(points.len()));
        }
        let bad = |index, why: String| VolumeParamsError::BadTransferPoint { index, why };
        for (index, p) in points.iter().enumerate() {
            if !p.value.is_finite() {
                return Err(bad(index, format!("value {} is not finite", p.value)));
            }
            if index > 0 && p.value < points[index - 1].value {
                return Err(bad(
                    index,
                    format!(
                        "value {} is below the previous point's {}",
                        p.value,
                        points[index - 1].value
                    ),
                ));
            }
            if !p.color.iter().all(|c| c.is_finite() && *c >= 0.0) {
                return Err(bad(
                    index,
                    format!("colour {:?} is not finite and >= 0", p.color),
                ));
            }
            if !(0.0..=1.0).contains(&p.opacity) {
                return Err(bad(index, format!("opacity {} is outside 0..1", p.opacity)));
            }
        }
        let mut out = TransferFunction {
            domain,
            points: [TransferPoint::default(); MAX_TRANSFER_POINTS],
            count: points.len() as u8,
        };
        out.points[..points.len()].copy_from_slice(points);
        Ok(out)
    }

    /// Whether the points' values are fractions of the data's range or its own units.
    pub fn domain(&self) -> TransferDomain {
        self.domain
    }

    /// The control points, in order of increasing value.
    pub fn points(&self) -> &[TransferPoint] {
        &self.points[..self.count as usize]
    }

    /// Colour and opacity at `x` (in the function's domain): linear between points, the end
    /// points' beyond them.
    pub fn eval(&self, x: f32) -> ([f32; 3], f32) {
        let points = self.points();
        let first = points[0];
        if x <= first.value {
            return (first.color, first.opacity);
        }
        for pair in points.windows(2) {
            let (a, b) = (pair[0], pair[1]);
            if x <= b.value {
                let span = b.value - a.value;
                let f = if span > 0.0 {
                    (x - a.value) / span
                } else {
                    1.0
                };
                let color = std::array::from_fn(|c| a.color[c] + (b.color[c] - a.color[c]) * f);
                return (color, a.opacity + (b.opacity - a.opacity) * f);
            }
        }
        let last = points[points.len() - 1];
        (last.color, last.opacity)
    }

    /// The default: transparent at the bottom of the data's range, a warm grey ramp in colour
    /// and opacity to its top, so that any volume shows its structure.
    pub const fn ramp() -> Self {
        Self::preset(
            TransferDomain::Normalized,
            &[
                point(0.0, [0.0, 0.0, 0.0], 0.0),
                point(0.1, [0.2, 0.25, 0.5], 0.0),
                point(0.5, [0.9, 0.6, 0.3], 0.05),
                point(1.0, [1.0, 1.0, 0.95], 0.4),
            ],
        )
    }

    /// CT bone, in Hounsfield units: soft tissue transparent, bone from about 200 HU opaque
    /// and ivory.
    pub const fn ct_bone() -> Self {
        Self::preset(
            TransferDomain::Data,
            &[
                point(150.0, [0.6, 0.3, 0.2], 0.0),
                point(250.0, [0.9, 0.75, 0.6], 0.3),
                point(600.0, [1.0, 0.95, 0.85], 0.8),
                point(2000.0, [1.0, 1.0, 1.0], 0.95),
            ],
        )
    }

    /// CT skin, in Hounsfield units: a faint skin surface (about -500..0 HU) over opaque bone.
    pub const fn ct_skin() -> Self {
        Self::preset(
            TransferDomain::Data,
            &[
                point(-600.0, [0.9, 0.6, 0.5], 0.0),
                point(-400.0, [0.95, 0.7, 0.6], 0.08),
                point(100.0, [0.9, 0.55, 0.45], 0.02),
                point(250.0, [0.95, 0.85, 0.7], 0.5),
                point(1000.0, [1.0, 1.0, 0.95], 0.9),
            ],
        )
    }

    /// The preset named `name` (`ramp`, `ct-bone`, `ct-skin`).
    pub fn preset_named(name: &str) -> Option<Self> {
        match name {
            "ramp" => Some(Self::ramp()),
            "ct-bone" => Some(Self::ct_bone()),
            "ct-skin" => Some(Self::ct_skin()),
            _ => None,
        }
    }

    /// The names [`TransferFunction::preset_named`] knows.
    pub const PRESET_NAMES: [&'static str; 3] = ["ramp", "ct-bone", "ct-skin"];

    const fn preset(domain: TransferDomain, points: &[TransferPoint]) -> Self {
        let mut out = TransferFunction {
            domain,
            points: [point(0.0, [0.0; 3], 0.0); MAX_TRANSFER_POINTS],
            count: points.len() as u8,
        };
        let mut i = 0;
        while i < points.len() {
            out.points[i] = points[i];
            i += 1;
        }
        out
    }
}

const fn point(value: f32, color: [f32; 3], opacity: f32) -> TransferPoint {
    TransferPoint {
        value,
        color,
        opacity,
    }
}

impl Default for TransferFunction {
    fn default() -> Self {
        Self::ramp()
    }
}

impl TryFrom<TransferSpec> for TransferFunction {
    type Error = VolumeParamsError;
    fn try_from(spec: TransferSpec) -> Result<Self, VolumeParamsError> {
        TransferFunction::new(spec.domain, &spec.points)
    }
}

impl From<TransferFunction> for TransferSpec {
    fn from(tf: TransferFunction) -> Self {
        TransferSpec {
            domain: tf.domain,
            points: tf.points().to_vec(),
        }
    }
}

impl<'de> Deserialize<'de> for TransferFunction {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        crate::checked::deserialize::<D, TransferSpec, Self>(d)
    }
}

/// The volume knobs of a frame.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct VolumeParams {
    /// Ray-marching step in world units (those of the volume's spacing); 0 picks half the
    /// smallest voxel spacing.
    pub step: f32,
    /// Iso-values of direct iso-surfaces; none draws the volume through its transfer function.
    pub iso: IsoValues,
    /// Colour and opacity of each data value, when there are no iso-values.
    pub transfer: TransferFunction,
    /// Factor on the step: progressive refinement renders frames of a moving view with a
    /// larger step (opacity correction keeps their look) and the still view with the full
    /// step, 1.
    pub coarsen: f32,
    /// Which volume of a time series is shown (modulo the series' length; a single volume
    /// ignores it).
    pub time_step: u32,
    /// What missing data (NaN) is drawn as: `None`, transparent; a linear RGB colour, opaque
    /// in that colour (`--nan-color`). Particles with a missing attribute take it too (grey
    /// without it).
    pub missing_color: Option<[f32; 3]>,
    /// How each iso-surface looks, by its place in [`VolumeParams::iso`]; what is not given
    /// is [`VolumeParams::iso_look`]'s default. (Absent from sessions recorded before it.)
    #[serde(default)]
    pub iso_looks: [IsoLook; MAX_ISO_VALUES],
}

/// One iso-surface's colour and opacity as given (`--iso VALUE:COLOUR:OPACITY`); `None` takes
/// the default.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct IsoLook {
    /// Linear RGB, each from 0 to 1.
    pub color: Option<[f32; 3]>,
    /// 1 is opaque; below 1 what lies inside shows through.
    pub opacity: Option<f32>,
}

/// The default colours of iso-surfaces, by their place in the list of iso-values: bone, skin,
/// and two that tell further surfaces apart.
pub const ISO_PALETTE: [[f32; 3]; MAX_ISO_VALUES] = [
    [0.9, 0.86, 0.78],
    [0.85, 0.55, 0.45],
    [0.35, 0.55, 0.9],
    [0.45, 0.8, 0.45],
];

/// The default opacity of every iso-surface but the one of the highest value, when there are
/// several: in a CT, as in most data, higher values lie inside lower ones (bone in skin), so
/// the inner surface shows through the outer ones.
pub const OUTER_ISO_OPACITY: f32 = 0.4;

impl VolumeParams {
    /// Half-voxel steps, no iso-surface, the [`TransferFunction::ramp`], full step, the first
    /// volume of a series.
    pub const DEFAULT: VolumeParams = VolumeParams {
        step: 0.0,
        iso: IsoValues::NONE,
        transfer: TransferFunction::ramp(),
        coarsen: 1.0,
        time_step: 0,
        missing_color: None,
        iso_looks: [IsoLook {
            color: None,
            opacity: None,
        }; MAX_ISO_VALUES],
    };

    /// Most [`VolumeParams::coarsen`] allowed.
    pub const MAX_COARSEN: f32 = 16.0;

    /// Checks the step and the coarsening (the iso-values and the transfer function were
    /// checked when they were made).
    ///
    /// # Errors
    /// A step that is negative or not finite, a coarsening outside 1..=16, or a missing-data
    /// colour with a negative or non-finite component.
    pub fn check(&self) -> Result<(), VolumeParamsError> {
        for (index, look) in self.iso_looks.iter().enumerate() {
            let bad = |why: String| Err(VolumeParamsError::BadIsoLook { index, why });
            if let Some(c) = look
                .color
                .filter(|c| !c.iter().all(|v| (0.0..=1.0).contains(v)))
            {
                return bad(format!("colour {c:?} needs components from 0 to 1"));
            }
            if let Some(o) = look.opacity.filter(|o| !(0.0..=1.0).contains(o)) {
                return bad(format!("opacity {o} is not from 0 to 1"));
            }
        }
        if let Some(c) = self.missing_color {
            if !c.iter().all(|v| v.is_finite() && *v >= 0.0) {
                return Err(VolumeParamsError::BadMissingColor(c));
            }
        }
        if !(self.step.is_finite() && self.step >= 0.0) {
            return Err(VolumeParamsError::BadStep(self.step));
        }
        if !(1.0..=Self::MAX_COARSEN).contains(&self.coarsen) {
            return Err(VolumeParamsError::BadCoarsen(self.coarsen));
        }
        Ok(())
    }
}

impl VolumeParams {
    /// The colour (linear RGB) and opacity iso-surface `index` is drawn with: as given in
    /// [`VolumeParams::iso_looks`], else the [`ISO_PALETTE`] colour of its rank from the highest
    /// value down (bone, then skin) and, with several surfaces, [`OUTER_ISO_OPACITY`] for all
    /// but the highest value's.
    pub fn iso_look(&self, index: usize) -> ([f32; 3], f32) {
        let look = self.iso_looks.get(index).copied().unwrap_or_default();
        let values = self.iso.as_slice();
        let value = values.get(index).copied().unwrap_or(f32::INFINITY);
        // Ties keep the order given, so equal values still get colours of their own.
        let rank = values
            .iter()
            .enumerate()
            .filter(|&(i, &v)| v > value || (v == value && i < index))
            .count();
        let opacity = look
            .opacity
            .unwrap_or(if rank == 0 { 1.0 } else { OUTER_ISO_OPACITY });
        let color = look.color.unwrap_or(ISO_PALETTE[rank % ISO_PALETTE.len()]);
        (color, opacity)
    }
}

impl Default for VolumeParams {
    fn default() -> Self {
        Self::DEFAULT
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p(value: f32, opacity: f32) -> TransferPoint {
        point(value, [0.5; 3], opacity)
    }

    #[test]
    fn presets_are_valid_transfer_functions() {
        for name in TransferFunction::PRESET_NAMES {
            let tf = TransferFunction::preset_named(name).unwrap();
            assert_eq!(TransferFunction::new(tf.domain(), tf.points()), Ok(tf));
        }
    }

    #[test]
    fn eval_is_piecewise_linear_and_constant_beyond_the_ends() {
        let tf = TransferFunction::new(TransferDomain::Data, &[p(0.0, 0.0), p(10.0, 1.0)]).unwrap();
        assert_eq!(tf.eval(-5.0).1, 0.0);
        assert_eq!(tf.eval(2.5).1, 0.25);
        assert_eq!(tf.eval(50.0).1, 1.0);
        // A step (two points at one value) is allowed and jumps there.
        let step = TransferFunction::new(
            TransferDomain::Data,
            &[p(0.0, 0.0), p(1.0, 0.0), p(1.0, 1.0), p(2.0, 1.0)],
        )
        .unwrap();
        assert_eq!(step.eval(0.999).1, 0.0);
        assert_eq!(step.eval(1.001).1, 1.0);
    }

    #[test]
    fn bad_points_are_refused_by_index() {
        let err = TransferFunction::new(TransferDomain::Data, &[p(0.0, 0.5), p(1.0, 1.5)]);
        assert!(matches!(
            err,
            Err(VolumeParamsError::BadTransferPoint { index: 1, .. })
        ));
        assert!(TransferFunction::new(TransferDomain::Data, &[]).is_err());
        assert!(TransferFunction::new(TransferDomain::Data, &[p(f32::NAN, 0.5)]).is_err());
        assert!(IsoValues::new(&[1.0; 5]).is_err());
        assert!(IsoValues::new(&[f32::INFINITY]).is_err());
    }

    #[test]
    fn deserializing_checks_the_lists() {
        let bad = TransferSpec {
            domain: TransferDomain::Data,
            points: vec![p(2.0, 0.5), p(1.0, 0.5)],
        };
        let bytes = postcard::to_allocvec(&bad).unwrap();
        let err = crate::checked::decode_for_test::<TransferFunction>(&bytes).unwrap_err();
        assert!(err.to_string().contains("below the previous"), "{err}");
        let bytes = postcard::to_allocvec(&vec![1.0f32; 9]).unwrap();
        assert!(crate::checked::decode_for_test::<IsoValues>(&bytes).is_err());
        let good = VolumeParams {
            step: 0.5,
            iso: IsoValues::new(&[100.0, 300.0]).unwrap(),
            transfer: TransferFunction::ct_bone(),
            coarsen: 2.0,
            time_step: 3,
            missing_color: Some([1.0, 0.0, 1.0]),
            iso_looks: [
                IsoLook {
                    color: Some([0.2, 0.3, 0.4]),
                    opacity: Some(0.5),
                },
                IsoLook::default(),
                IsoLook::default(),
                IsoLook::default(),
            ],
        };
        let bytes = postcard::to_allocvec(&good).unwrap();
        assert_eq!(postcard::from_bytes::<VolumeParams>(&bytes).unwrap(), good);
        // Sessions recorded before iso looks still read, with the defaults.
        let mut old = serde_json::to_value(good).unwrap();
        old.as_object_mut().unwrap().remove("iso_looks");
        let read: VolumeParams = serde_json::from_value(old).unwrap();
        assert_eq!(read.iso_looks, [IsoLook::default(); MAX_ISO_VALUES]);
    }

    #[test]
    fn two_iso_surfaces_differ_in_colour_and_the_outer_one_is_translucent() {
        let two = VolumeParams {
            iso: IsoValues::new(&[-300.0, 400.0]).unwrap(),
            ..VolumeParams::DEFAULT
        };
        let (skin, skin_opacity) = two.iso_look(0);
        let (bone, bone_opacity) = two.iso_look(1);
        assert_ne!(skin, bone);
        assert_eq!(bone, ISO_PALETTE[0], "the highest value gets bone");
        assert_eq!((skin_opacity, bone_opacity), (OUTER_ISO_OPACITY, 1.0));
        let one = VolumeParams {
            iso: IsoValues::new(&[-300.0]).unwrap(),
            ..VolumeParams::DEFAULT
        };
        assert_eq!(one.iso_look(0).1, 1.0, "a single surface is opaque");
        let given = VolumeParams {
            iso_looks: [IsoLook {
                color: Some([1.0, 0.0, 0.0]),
                opacity: Some(0.7),
            }; MAX_ISO_VALUES],
            ..two
        };
        assert_eq!(given.iso_look(1), ([1.0, 0.0, 0.0], 0.7));
        let bad = VolumeParams {
            iso_looks: [IsoLook {
                color: None,
                opacity: Some(1.5),
            }; MAX_ISO_VALUES],
            ..two
        };
        assert!(bad.check().unwrap_err().to_string().contains("opacity 1.5"));
    }
}
