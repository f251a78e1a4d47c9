//! Light sources: those a scene brings, and the set a control client may put in their place
//! for a frame.

use glam::Vec3;
use serde::{Deserialize, Serialize};

/// A light source. Intensities are linear multipliers of the diffuse term.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum Light {
    /// Infinitely far: `towards` is the unit direction from the surface to the light.
    Directional {
        /// Unit vector from any surface point towards the light.
        towards: Vec3,
        /// Linear multiplier of the diffuse term, the same at every distance; 0 or more.
        intensity: f32,
    },
    /// A point light; falls off with the square of the distance.
    Point {
        /// Where the light is, in render coordinates (see [`crate::local_origin`]).
        position: Vec3,
        /// Linear multiplier of the diffuse term at distance 1, divided by the squared distance
        /// elsewhere; 0 or more.
        intensity: f32,
    },
}

/// Most lights a frame's light set may hold: shadow rays cost one ray per light per hit.
pub const MAX_LIGHTS: usize = 8;

/// Why a light was refused.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum LightError {
    /// More than [`MAX_LIGHTS`] lights were given; carries how many.
    #[error("at most {MAX_LIGHTS} lights are supported, got {0}")]
    TooMany(usize),
    /// The light at this index has a NaN or infinite position, direction or intensity.
    #[error("light {0} has a non-finite position, direction or intensity")]
    NotFinite(usize),
    /// The light at this index has an intensity below 0.
    #[error("light {0} has a negative intensity")]
    Negative(usize),
    /// The directional light at this index has a direction that is not of unit length (zero, when
    /// made by [`Light::directional`]).
    #[error("directional light {0} needs a non-zero direction")]
    NoDirection(usize),
}

impl Light {
    /// A directional light shining from `towards` (normalized here).
    pub fn directional(towards: Vec3, intensity: f32) -> Light {
        Light::Directional {
            towards: towards.normalize_or_zero(),
            intensity,
        }
    }

    /// Checks what shading relies on; `index` names the light in the error.
    pub fn check(&self, index: usize) -> Result<(), LightError> {
        let (v, intensity) = match *self {
            Light::Directional { towards, intensity } => {
                if towards.is_finite() && (towards.length() - 1.0).abs() > 1e-4 {
                    return Err(LightError::NoDirection(index));
                }
                (towards, intensity)
            }
            Light::Point {
                position,
                intensity,
            } => (position, intensity),
        };
        if !(v.is_finite() && intensity.is_finite()) {
            return Err(LightError::NotFinite(index));
        }
        if intensity < 0.0 {
            return Err(LightError::Negative(index));
        }
        Ok(())
    }
}

/// A set of up to [`MAX_LIGHTS`] lights that replaces a scene's own for a frame. Fixed-size so
/// that a frame's state stays `Copy`; checked on construction and on arrival.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(into = "Vec<Light>")]
pub struct Lights {
    lights: [Light; MAX_LIGHTS],
    count: u8,
}

impl Lights {
    /// A set of the given lights, in order.
    ///
    /// # Errors
    /// More than [`MAX_LIGHTS`] lights, or one that [`Light::check`] refuses.
    pub fn new(lights: &[Light]) -> Result<Lights, LightError> {
        if lights.len() > MAX_LIGHTS {
            return Err(LightError::TooMany(lights.len()));
        }
        let off = Light::Point {
            position: Vec3::ZERO,
            intensity: 0.0,
        };
        let mut out = Lights {
            lights: [off; MAX_LIGHTS],
            count: lights.len() as u8,
        };
        for (i, light) in lights.iter().enumerate() {
            light.check(i)?;
            out.lights[i] = *light;
        }
        Ok(out)
    }

    /// The lights in use, in the order given.
    pub fn as_slice(&self) -> &[Light] {
        &self.lights[..self.count as usize]
    }
}

impl TryFrom<Vec<Light>> for Lights {
    type Error = LightError;

    fn try_from(lights: Vec<Light>) -> Result<Self, LightError> {
        Lights::new(&lights)
    }
}

impl From<Lights> for Vec<Light> {
    fn from(lights: Lights) -> Self {
        lights.as_slice().to_vec()
    }
}

impl<'de> Deserialize<'de> for Lights {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        crate::checked::deserialize::<D, Vec<Light>, Self>(d)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lights_are_checked() {
        let sun = Light::directional(Vec3::new(1.0, 2.0, 3.0), 1.0);
        assert_eq!(Lights::new(&[sun]).unwrap().as_slice(), &[sun]);
        assert_eq!(Lights::new(&[sun; 9]).unwrap_err(), LightError::TooMany(9));
        let nan = Light::Point {
            position: Vec3::NAN,
            intensity: 1.0,
        };
        assert_eq!(Lights::new(&[sun, nan]), Err(LightError::NotFinite(1)));
        let dark = Light::Directional {
            towards: Vec3::ZERO,
            intensity: 1.0,
        };
        assert_eq!(Lights::new(&[dark]), Err(LightError::NoDirection(0)));
        let bytes = postcard::to_allocvec(&vec![nan]).unwrap();
        assert!(crate::checked::decode_for_test::<Lights>(&bytes).is_err());
    }
}
