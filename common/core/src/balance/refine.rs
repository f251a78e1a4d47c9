//! Progressive refinement: while the camera moves, frames render with the state's own
//! (interactive) knobs; once the state has held for a few frames, each new frame renders more
//! samples per pixel (doubling) with the final ambient-occlusion rays, until the final quality
//! is reached; then the wall renders nothing until something changes. Volumes in a moving view
//! are marched at twice the step, the still view's passes at the full step.
//!
//! Each pass renders its samples from scratch (sample 0 on) rather than adding to the last
//! pass's: pixels travel as 8-bit sRGB, and only a frame rendered in one go at the final
//! quality equals the single-process reference at that quality bit for bit. Doubling keeps
//! the cost of all passes under twice that of the last one.

use tessera_model::params::{ParamsError, RenderParams, RenderParamsSpec};
use tessera_model::volume_params::VolumeParams;

/// When and how far to refine.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Refinement {
    /// Frames a state must hold (camera still, nothing changed) before refining starts.
    pub still_frames: u64,
    /// Samples per pixel of the final quality.
    pub final_spp: u32,
    /// Ambient-occlusion rays per hit of the final quality.
    pub final_ao: u32,
}

impl Refinement {
    /// Refinement that starts once a state has held `still_frames` frames and ends at
    /// `final_spp` samples per pixel with `final_ao` ambient-occlusion rays.
    ///
    /// # Errors
    /// A final quality whose knobs are out of bounds on their own.
    pub fn new(still_frames: u64, final_spp: u32, final_ao: u32) -> Result<Self, ParamsError> {
        RenderParamsSpec {
            spp: final_spp,
            ao_samples: final_ao,
            ..RenderParamsSpec::INTERACTIVE
        }
        .build()?;
        Ok(Refinement {
            still_frames,
            final_spp,
            final_ao,
        })
    }

    /// What frame `age` frames after its state took effect renders with, and whether it is
    /// the last pass (the final quality). Knobs already above the final quality are kept.
    pub fn frame_params(&self, state: RenderParams, age: u64) -> (RenderParams, bool) {
        let target_spp = self.final_spp.max(state.spp());
        let target_ao = self.final_ao.max(state.ao_samples());
        let already_final = state.spp() == target_spp && state.ao_samples() == target_ao;
        if age < self.still_frames {
            return (moving(state), false);
        }
        if already_final {
            return (state, true);
        }
        let pass = (age - self.still_frames + 1).min(31) as u32;
        let spp = state.spp().saturating_mul(1u32 << pass).min(target_spp);
        let refined = RenderParamsSpec {
            spp,
            ao_samples: target_ao,
            first_sample: 0,
            ..state.spec()
        }
        .build()
        // The target's knobs build on their own; with the state's other knobs they may not
        // (the per-pixel budget): then the state's own knobs are the best there is.
        .unwrap_or(state);
        (refined, refined == state || spp == target_spp)
    }
}

/// Step factor of volumes while the view moves.
pub const MOVING_STEP_FACTOR: f32 = 2.0;

/// `state` as a moving view renders it: volumes marched at [`MOVING_STEP_FACTOR`] times the
/// step (their opacity corrected for it), everything else as it is.
fn moving(state: RenderParams) -> RenderParams {
    let mut spec = state.spec();
    spec.volume.coarsen = (spec.volume.coarsen * MOVING_STEP_FACTOR).min(VolumeParams::MAX_COARSEN);
    spec.build().unwrap_or(state)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn passes_double_the_samples_after_the_state_holds_and_end_at_the_final_quality() {
        let r = Refinement::new(2, 8, 4).unwrap();
        let base = RenderParams::interactive();
        let at = |age| {
            let (p, last) = r.frame_params(base, age);
            (p.spp(), p.ao_samples(), last)
        };
        assert_eq!(at(0), (1, 0, false), "moving: interactive");
        assert_eq!(at(1), (1, 0, false));
        assert_eq!(at(2), (2, 4, false), "first pass");
        assert_eq!(at(3), (4, 4, false));
        assert_eq!(at(4), (8, 4, true), "final quality reached");
        assert_eq!(at(50), (8, 4, true));
        assert_eq!(r.frame_params(base, 4).0.shadows(), base.shadows());
        // Volumes: twice the step while moving, the full step on every pass after.
        let coarsen = |age| r.frame_params(base, age).0.volume().coarsen;
        assert_eq!(
            (coarsen(0), coarsen(1)),
            (MOVING_STEP_FACTOR, MOVING_STEP_FACTOR)
        );
        assert_eq!((coarsen(2), coarsen(4)), (1.0, 1.0));
    }

    #[test]
    fn a_state_already_at_the_final_quality_is_final_once_it_holds() {
        let r = Refinement::new(1, 2, 0).unwrap();
        let base = RenderParamsSpec {
            spp: 4,
            ..RenderParamsSpec::INTERACTIVE
        }
        .build()
        .unwrap();
        assert_eq!(r.frame_params(base, 0), (moving(base), false));
        assert_eq!(r.frame_params(base, 1), (base, true));
        assert!(Refinement::new(1, 0, 0).is_err());
    }
}
