//! The wall's state: everything a person can change, applied only at a frame barrier.
//!
//! A state has an id; every frame is rendered with exactly one state, every pixel stream says
//! which, and a display refuses to present a frame whose tiles disagree (see
//! `tessera_core::assemble`). Changes are field by field ([`StateChange`]), so that two
//! controllers changing different knobs between two barriers never undo each other, and they
//! are checked against the state they will apply to when they are queued, so a refusal reaches
//! the one who asked at once rather than at the barrier.

use crate::camera::CameraMode;
use crate::cut::CutPlanes;
use crate::light::Lights;
use crate::params::{ParamsError, RenderParams};
use crate::volume_params::VolumeParams;
use serde::{Deserialize, Serialize};

/// Identifies a state of the wall; a new one is made at each barrier where something changed.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize,
)]
pub struct StateId(pub u64);

/// Everything a frame is rendered with, besides its number and the scene.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct WallState {
    /// The fixed camera or the orbit; the frame's camera follows from it and the frame number.
    pub camera: CameraMode,
    /// The quality knobs: shadows, ambient occlusion, samples, cuts, crop, volume.
    pub params: RenderParams,
    /// Lights in place of the scene's own, if any were set.
    pub lights: Option<Lights>,
}

/// One change of the wall's state. Every value inside is already valid on its own (the types
/// see to it); [`WallState::apply`] checks the combination.
// `All` and `Volume` carry a transfer function of 16 points; changes are queued a handful a
// frame, and staying `Copy` is worth more than the bytes boxing would save.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum StateChange {
    /// A fixed camera, or the orbit.
    Camera(CameraMode),
    /// Shadow rays on or off.
    Shadows(bool),
    /// Ambient-occlusion rays per hit.
    AoSamples(u32),
    /// Samples per pixel.
    Spp(u32),
    /// The cutting planes, in place of the current ones (empty: nothing cut).
    Cuts(CutPlanes),
    /// Draw only the particles whose attribute lies in this range (`None`: all).
    Crop(Option<(f32, f32)>),
    /// Lights in place of the scene's own (`None`: the scene's again).
    Lights(Option<Lights>),
    /// How volumes are drawn: step, iso-values, transfer function.
    Volume(VolumeParams),
    /// The colour map of particles' attributes.
    ColorMap(crate::colormap::ColorMap),
    /// A whole state at once (a replayed session, a saved view).
    All(WallState),
    /// How hits are lit: the full shading, or the eye light alone (last, so that the wire
    /// numbers of the changes before it stay as they were).
    Shading(crate::params::Shading),
}

impl WallState {
    /// The state after `change`.
    ///
    /// # Errors
    /// A combination of knobs out of bounds, e.g. samples × ambient-occlusion rays over the
    /// per-pixel budget; the state is then unchanged.
    pub fn apply(&self, change: &StateChange) -> Result<WallState, ParamsError> {
        let mut next = *self;
        let mut spec = self.params.spec();
        match *change {
            StateChange::Camera(mode) => next.camera = mode,
            StateChange::Shadows(on) => spec.shadows = on,
            StateChange::AoSamples(n) => spec.ao_samples = n,
            StateChange::Spp(n) => spec.spp = n,
            StateChange::Cuts(cuts) => spec.cuts = cuts,
            StateChange::Crop(crop) => spec.crop = crop,
            StateChange::Lights(lights) => next.lights = lights,
            StateChange::Volume(volume) => spec.volume = volume,
            StateChange::ColorMap(map) => spec.colormap = map,
            StateChange::All(state) => return Ok(state),
            StateChange::Shading(shading) => spec.shading = shading,
        }
        next.params = spec.build()?;
        Ok(next)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Camera;
    use glam::Vec3;

    fn state() -> WallState {
        WallState {
            camera: CameraMode::orbit(Vec3::ZERO, 1.0, 45.0).unwrap(),
            params: RenderParams::interactive(),
            lights: None,
        }
    }

    #[test]
    fn changes_of_different_knobs_keep_each_other() {
        let s = state()
            .apply(&StateChange::AoSamples(8))
            .unwrap()
            .apply(&StateChange::Shadows(false))
            .unwrap();
        assert_eq!(s.params.ao_samples(), 8);
        assert!(!s.params.shadows());
        let fixed = CameraMode::fixed(Camera::new(Vec3::Z, Vec3::ZERO, Vec3::Y, 30.0).unwrap());
        let s = s.apply(&StateChange::Camera(fixed)).unwrap();
        assert_eq!((s.camera, s.params.ao_samples()), (fixed, 8));
    }

    #[test]
    fn a_combination_over_the_budget_is_refused_and_changes_nothing() {
        let eye = state()
            .apply(&StateChange::Shading(crate::params::Shading::EyeLight))
            .unwrap();
        assert!(eye.params.eye_light() && !state().params.eye_light());
        let s = state().apply(&StateChange::Spp(4096)).unwrap();
        assert!(s.apply(&StateChange::AoSamples(1024)).is_err());
        assert!(matches!(
            state().apply(&StateChange::Spp(0)),
            Err(ParamsError::BadSpp(0))
        ));
    }
}
