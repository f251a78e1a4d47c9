//! Colour maps for particles' attributes: a value in 0..1 to a linear RGB colour, read by every
//! render node alike (pure functions of their input, the same on every CPU).

use serde::{Deserialize, Serialize};

/// A colour map, chosen per state (`--colormap`, `control colormap`, the console).
///
/// # Examples
/// ```
/// use tessera_model::colormap::ColorMap;
/// let map: ColorMap = "magma".parse()?;
/// assert_eq!(map.name(), "magma");
/// assert!(map.eval(0.0)[0] < map.eval(1.0)[0], "dark to light");
/// assert_eq!(ColorMap::Greys.eval(0.5), [0.5, 0.5, 0.5]);
/// # Ok::<(), tessera_model::colormap::UnknownColorMap>(())
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ColorMap {
    /// Dark blue through teal to yellow, perceptually ordered (close to matplotlib's).
    #[default]
    Viridis,
    /// Black through purple and orange to pale yellow.
    Magma,
    /// Blue through white to red: for values about a middle.
    Coolwarm,
    /// Black to white.
    Greys,
}

/// A colour map's name that is none of [`ColorMap::ALL`].
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
#[error("unknown colour map {0:?}: viridis, magma, coolwarm or greys")]
pub struct UnknownColorMap(pub String);

impl ColorMap {
    /// Every map, in the order help texts list them.
    pub const ALL: [ColorMap; 4] = [
        ColorMap::Viridis,
        ColorMap::Magma,
        ColorMap::Coolwarm,
        ColorMap::Greys,
    ];

    /// Its name, as flags and the API take it.
    pub fn name(self) -> &'static str {
        match self {
            ColorMap::Viridis => "viridis",
            ColorMap::Magma => "magma",
            ColorMap::Coolwarm => "coolwarm",
            ColorMap::Greys => "greys",
        }
    }

    /// Evenly spaced stops, linear RGB.
    fn stops(self) -> &'static [[f32; 3]] {
        match self {
            ColorMap::Viridis => &[
                [0.267, 0.005, 0.329],
                [0.230, 0.322, 0.546],
                [0.128, 0.567, 0.551],
                [0.369, 0.789, 0.383],
                [0.993, 0.906, 0.144],
            ],
            ColorMap::Magma => &[
                [0.001, 0.000, 0.014],
                [0.232, 0.060, 0.437],
                [0.550, 0.161, 0.506],
                [0.868, 0.288, 0.409],
                [0.987, 0.991, 0.750],
            ],
            ColorMap::Coolwarm => &[
                [0.230, 0.299, 0.754],
                [0.552, 0.690, 0.996],
                [0.865, 0.865, 0.865],
                [0.958, 0.604, 0.482],
                [0.706, 0.016, 0.150],
            ],
            ColorMap::Greys => &[[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]],
        }
    }

    /// The colour of `x`, clamped to 0..1 (not a number: 0).
    pub fn eval(self, x: f32) -> [f32; 3] {
        let stops = self.stops();
        let last = stops.len() - 1;
        let x = if x.is_finite() {
            x.clamp(0.0, 1.0)
        } else {
            0.0
        } * last as f32;
        let i = (x as usize).min(last - 1);
        let f = x - i as f32;
        let (a, b) = (stops[i], stops[i + 1]);
        [0, 1, 2].map(|k| a[k] + (b[k] - a[k]) * f)
    }
}

impl std::str::FromStr for ColorMap {
    type Err = UnknownColorMap;

    fn from_str(name: &str) -> Result<Self, UnknownColorMap> {
        ColorMap::ALL
            .into_iter()
            .find(|m| m.name() == name)
            .ok_or_else(|| UnknownColorMap(name.chars().take(40).collect()))
    }
}
