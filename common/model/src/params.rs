//! Per-frame quality knobs, changed only at the frame barrier, and their bounds.
//!
//! Every knob that multiplies the rays of a pixel is bounded, so no setting, from the command
//! line or the network, makes a frame run for ever: [`MAX_AO_SAMPLES`] and [`MAX_SPP`] each,
//! and their product within [`MAX_RAYS_PER_PIXEL`].

use crate::cut::CutPlanes;
use crate::volume_params::{VolumeParams, VolumeParamsError};
use serde::{Deserialize, Serialize};

/// Most ambient-occlusion rays per hit. 256 is already a converged reference.
pub const MAX_AO_SAMPLES: u32 = 1024;
/// Most samples per pixel in one frame.
pub const MAX_SPP: u32 = 4096;
/// Most rays a pixel may ask for in one frame: samples × (1 + ambient-occlusion rays).
pub const MAX_RAYS_PER_PIXEL: u64 = 1 << 18;
/// Sample indices (progressive passes) stay below this, so that the random keys of every
/// sample and ambient-occlusion ray (`sample · ao_samples + k`, below 2³⁰) never wrap.
pub const MAX_SAMPLE_INDEX: u32 = 1 << 20;

/// The knobs of one frame; made by [`RenderParamsSpec::build`], which checks them.
///
/// # Examples
///
/// ```
/// use tessera_model::params::{ParamsError, RenderParams, RenderParamsSpec};
///
/// let params = RenderParamsSpec { ao_samples: 8, ..RenderParamsSpec::INTERACTIVE }.build()?;
/// assert_eq!(params.ao_samples(), 8);
/// assert!(params.shadows());
/// let err = RenderParamsSpec { ao_samples: 4_000_000_000, ..RenderParamsSpec::INTERACTIVE }
///     .build()
///     .unwrap_err();
/// assert!(err.to_string().contains("4000000000"));
/// # Ok::<(), ParamsError>(())
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(into = "RenderParamsSpec")]
pub struct RenderParams(RenderParamsSpec);

/// The fields of [`RenderParams`], unchecked.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RenderParamsSpec {
    /// Trace shadow rays towards the lights.
    pub shadows: bool,
    /// Ambient-occlusion rays per hit (0: none traced).
    pub ao_samples: u32,
    /// Reach of ambient-occlusion rays, as a fraction of the scene's bounding-box diagonal.
    pub ao_range: f32,
    /// Only particles whose attribute lies in this range are drawn (and cast shadows).
    pub crop: Option<(f32, f32)>,
    /// Half-spaces removed from the scene.
    pub cuts: CutPlanes,
    /// Samples per pixel: 1 traces the pixel centre; more average jittered sub-pixel samples.
    pub spp: u32,
    /// Index of the first sample, so that successive progressive passes draw new samples.
    pub first_sample: u32,
    /// How volumes are drawn (ignored by scenes without one).
    pub volume: VolumeParams,
    /// The colours of particles' attributes (ignored by scenes without particles).
    #[serde(default)]
    pub colormap: crate::colormap::ColorMap,
    /// How hits are lit: the full model, or only the eye light (as Embree's viewer shades).
    #[serde(default)]
    pub shading: Shading,
}

/// How a hit is lit.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum Shading {
    /// Headlight, the scene's lights with shadows, ambient occlusion, highlights, mirrors and
    /// transparency, as the other knobs ask.
    #[default]
    Full,
    /// Only a light at the eye: |N·D| times the surface's base colour, no other ray traced
    /// (the frame Embree's `viewer` and `viewer_stream` draw, for like-for-like timing).
    EyeLight,
}

impl Shading {
    /// Every mode, by the name [`Shading::name`] gives.
    pub const ALL: [Shading; 2] = [Shading::Full, Shading::EyeLight];

    /// The mode's name on the command line: `full` or `eyelight`.
    pub const fn name(self) -> &'static str {
        match self {
            Shading::Full => "full",
            Shading::EyeLight => "eyelight",
        }
    }
}

impl std::str::FromStr for Shading {
    type Err = String;

    fn from_str(name: &str) -> Result<Self, String> {
        Shading::ALL
            .into_iter()
            .find(|s| s.name() == name)
            .ok_or_else(|| {
                let name: String = name.chars().take(40).collect();
                format!("shading `{name}` is not one of full, eyelight")
            })
    }
}

/// Why render parameters were refused.
#[derive(Clone, Debug, thiserror::Error, PartialEq)]
pub enum ParamsError {
    /// More than [`MAX_AO_SAMPLES`] ambient-occlusion rays per hit were asked for.
    #[error("{0} ambient-occlusion rays per hit is more than the {MAX_AO_SAMPLES} supported")]
    TooManyAoSamples(u32),
    /// Samples per pixel were 0 or more than [`MAX_SPP`].
    #[error("{0} samples per pixel: must be from 1 to {MAX_SPP}")]
    BadSpp(u32),
    /// Samples per pixel times (1 + ambient-occlusion rays) is more than [`MAX_RAYS_PER_PIXEL`].
    #[error(
        "{spp} samples per pixel with {ao} ambient-occlusion rays each is {rays} rays per pixel, more than the {MAX_RAYS_PER_PIXEL} supported; lower --spp or --ao"
    )]
    TooManyRays {
        /// The samples per pixel asked for.
        spp: u32,
        /// The ambient-occlusion rays per hit asked for.
        ao: u32,
        /// Rays per pixel they add up to: `spp × (1 + ao)`.
        rays: u64,
    },
    /// The frame's samples would reach past [`MAX_SAMPLE_INDEX`]: too many progressive passes.
    #[error("samples {first}..{end} go past sample index {MAX_SAMPLE_INDEX}")]
    SampleIndex {
        /// Index of the first sample asked for.
        first: u32,
        /// One past the last sample's index: `first + spp`.
        end: u64,
    },
    /// The ambient-occlusion range is zero, negative, infinite or NaN.
    #[error("ambient-occlusion range {0} must be finite and above 0")]
    BadAoRange(f32),
    /// A particle crop range with a non-finite bound or its low bound above its high one.
    #[error("particle crop {0}..{1} must be finite with LO <= HI")]
    BadCrop(f32, f32),
    /// The volume parameters were refused.
    #[error(transparent)]
    Volume(#[from] VolumeParamsError),
}

impl RenderParamsSpec {
    /// What the interactive wall renders by default: shadows, no ambient occlusion.
    pub const INTERACTIVE: RenderParamsSpec = RenderParamsSpec {
        shadows: true,
        ao_samples: 0,
        ao_range: 0.1,
        crop: None,
        cuts: CutPlanes::EMPTY,
        spp: 1,
        first_sample: 0,
        volume: VolumeParams::DEFAULT,
        colormap: crate::colormap::ColorMap::Viridis,
        shading: Shading::Full,
    };

    /// Checks every knob.
    ///
    /// # Errors
    /// A knob out of its bounds (see the module documentation).
    pub fn build(self) -> Result<RenderParams, ParamsError> {
        if self.ao_samples > MAX_AO_SAMPLES {
            return Err(ParamsError::TooManyAoSamples(self.ao_samples));
        }
        if !(1..=MAX_SPP).contains(&self.spp) {
            return Err(ParamsError::BadSpp(self.spp));
        }
        let rays = self.spp as u64 * (1 + self.ao_samples as u64);
        if rays > MAX_RAYS_PER_PIXEL {
            return Err(ParamsError::TooManyRays {
                spp: self.spp,
                ao: self.ao_samples,
                rays,
            });
        }
        let end = self.first_sample as u64 + self.spp as u64;
        if end > MAX_SAMPLE_INDEX as u64 {
            return Err(ParamsError::SampleIndex {
                first: self.first_sample,
                end,
            });
        }
        if !(self.ao_range.is_finite() && self.ao_range > 0.0) {
            return Err(ParamsError::BadAoRange(self.ao_range));
        }
        if let Some((lo, hi)) = self.crop {
            if !(lo.is_finite() && hi.is_finite() && lo <= hi) {
                return Err(ParamsError::BadCrop(lo, hi));
            }
        }
        self.volume.check()?;
        Ok(RenderParams(self))
    }
}

impl TryFrom<RenderParamsSpec> for RenderParams {
    type Error = ParamsError;

    fn try_from(spec: RenderParamsSpec) -> Result<Self, ParamsError> {
        spec.build()
    }
}

impl From<RenderParams> for RenderParamsSpec {
    fn from(params: RenderParams) -> Self {
        params.0
    }
}

impl<'de> Deserialize<'de> for RenderParams {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        crate::checked::deserialize::<D, RenderParamsSpec, Self>(d)
    }
}

impl RenderParams {
    /// What the interactive wall renders by default: shadows, no ambient occlusion.
    pub const fn interactive() -> Self {
        RenderParams(RenderParamsSpec::INTERACTIVE)
    }

    /// A still worth waiting for: shadows and 16 ambient-occlusion rays per hit.
    pub const fn final_frame() -> Self {
        RenderParams(RenderParamsSpec {
            ao_samples: 16,
            ..RenderParamsSpec::INTERACTIVE
        })
    }

    /// Every preset, for tests that must hold for all of them.
    pub const PRESETS: [RenderParams; 2] = [Self::interactive(), Self::final_frame()];

    /// The knobs as plain fields, to change some and [`RenderParamsSpec::build`] again.
    pub const fn spec(&self) -> RenderParamsSpec {
        self.0
    }

    /// Whether shadow rays are traced towards the lights.
    #[inline]
    pub const fn shadows(&self) -> bool {
        self.0.shadows
    }

    /// Ambient-occlusion rays per hit, 0 to [`MAX_AO_SAMPLES`] (0: none traced).
    #[inline]
    pub const fn ao_samples(&self) -> u32 {
        self.0.ao_samples
    }

    /// Reach of ambient-occlusion rays, as a fraction of the scene's bounding-box diagonal.
    #[inline]
    pub const fn ao_range(&self) -> f32 {
        self.0.ao_range
    }

    /// The range `(lo, hi)` of attribute values whose particles are drawn; `None` draws them all.
    #[inline]
    pub const fn crop(&self) -> Option<(f32, f32)> {
        self.0.crop
    }

    /// Half-spaces removed from the scene.
    #[inline]
    pub const fn cuts(&self) -> &CutPlanes {
        &self.0.cuts
    }

    /// Samples per pixel, 1 to [`MAX_SPP`].
    #[inline]
    pub const fn spp(&self) -> u32 {
        self.0.spp
    }

    /// Index of the frame's first sample, so that successive progressive passes draw new samples.
    #[inline]
    pub const fn first_sample(&self) -> u32 {
        self.0.first_sample
    }

    /// How volumes are drawn (ignored by scenes without one).
    #[inline]
    pub const fn volume(&self) -> &VolumeParams {
        &self.0.volume
    }

    /// The colours of particles' attributes.
    #[inline]
    pub const fn colormap(&self) -> crate::colormap::ColorMap {
        self.0.colormap
    }

    /// How hits are lit.
    #[inline]
    pub const fn shading(&self) -> Shading {
        self.0.shading
    }

    /// Whether hits are lit by the eye light alone: no shadow, ambient-occlusion, reflected or
    /// transmitted ray is traced, whatever the other knobs say.
    #[inline]
    pub const fn eye_light(&self) -> bool {
        matches!(self.0.shading, Shading::EyeLight)
    }
}

impl Default for RenderParams {
    fn default() -> Self {
        Self::interactive()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn with(change: impl FnOnce(&mut RenderParamsSpec)) -> Result<RenderParams, ParamsError> {
        let mut spec = RenderParamsSpec::INTERACTIVE;
        change(&mut spec);
        spec.build()
    }

    #[test]
    fn presets_are_valid() {
        for preset in RenderParams::PRESETS {
            assert_eq!(preset.spec().build(), Ok(preset));
        }
    }

    #[test]
    fn four_billion_ao_rays_are_refused_rather_than_run_for_ever() {
        let err = with(|s| s.ao_samples = 4_000_000_000).unwrap_err();
        assert_eq!(err, ParamsError::TooManyAoSamples(4_000_000_000));
        assert!(with(|s| s.ao_samples = MAX_AO_SAMPLES).is_ok());
    }

    #[test]
    fn samples_per_pixel_are_bounded_alone_and_with_ao() {
        assert!(matches!(with(|s| s.spp = 0), Err(ParamsError::BadSpp(0))));
        assert!(with(|s| s.spp = MAX_SPP + 1).is_err());
        assert!(with(|s| s.spp = MAX_SPP).is_ok());
        let err = with(|s| {
            s.spp = MAX_SPP;
            s.ao_samples = MAX_AO_SAMPLES;
        })
        .unwrap_err();
        assert!(matches!(err, ParamsError::TooManyRays { .. }), "{err}");
        // The error-vs-time reference (256 AO rays, 64 samples) stays allowed.
        assert!(with(|s| {
            s.spp = 64;
            s.ao_samples = 256;
        })
        .is_ok());
    }

    #[test]
    fn sample_keys_cannot_wrap() {
        assert!(with(|s| s.first_sample = u32::MAX).is_err());
        assert!(with(|s| s.first_sample = MAX_SAMPLE_INDEX - 1).is_ok());
    }

    #[test]
    fn ranges_must_be_finite() {
        assert!(with(|s| s.ao_range = f32::NAN).is_err());
        assert!(with(|s| s.ao_range = 0.0).is_err());
        assert!(with(|s| s.crop = Some((2.0, 1.0))).is_err());
        assert!(with(|s| s.crop = Some((f32::NEG_INFINITY, 1.0))).is_err());
    }

    #[test]
    fn shading_names_round_trip_and_unknown_ones_are_named() {
        for shading in Shading::ALL {
            assert_eq!(shading.name().parse::<Shading>(), Ok(shading));
        }
        let err = "eye".parse::<Shading>().unwrap_err();
        assert!(err.contains("`eye`"), "{err}");
    }

    #[test]
    fn deserializing_checks_the_knobs() {
        let bad = RenderParamsSpec {
            ao_samples: 4_000_000_000,
            ..RenderParamsSpec::INTERACTIVE
        };
        let bytes = postcard::to_allocvec(&bad).unwrap();
        let err = crate::checked::decode_for_test::<RenderParams>(&bytes).unwrap_err();
        assert!(err.to_string().contains("4000000000"), "{err}");
        let good = RenderParams::final_frame();
        let bytes = postcard::to_allocvec(&good).unwrap();
        assert_eq!(postcard::from_bytes::<RenderParams>(&bytes).unwrap(), good);
    }
}
