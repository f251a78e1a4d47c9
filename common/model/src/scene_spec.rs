//! What to render, as named on the command line and sent in the session.
//!
//! A render node loads the scene itself from this name, so it is checked like every other wire
//! value: a knot too large to build, or a path no file system holds, is refused on arrival
//! instead of exhausting the node's memory or failing deep inside a loader.

use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// Most triangles of a procedural knot (2 × segments × sides): about 10 GB of triangles and
/// BVH, the size of the largest real meshes we test with.
pub const MAX_KNOT_TRIANGLES: u64 = 1 << 27;
/// Longest scene path accepted, in bytes (Linux's `PATH_MAX`).
pub const MAX_PATH_BYTES: usize = 4096;

/// A scene, by name. Made by [`SceneSpec::from_arg`] or the variants' constructors, checked by
/// [`SceneSpec::check`] wherever one arrives from outside.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub enum SceneSpec {
    /// The default procedural scene: a bumpy torus-knot tube over a ground plane.
    Knot {
        /// Rings of quads along the tube, 3 to 65536.
        segments: u32,
        /// Quads around each ring, 3 to 65536.
        sides: u32,
    },
    /// The knot in a small gallery that shows every material: a glossy (Phong) knot, a mirror
    /// wall behind it and a pane of tinted glass in front.
    Gallery,
    /// Nothing at all: a flat backdrop that costs no tracing, for measuring the transport
    /// (the `max-fps` experiment).
    Empty,
    /// A file at this path on the node that loads it: a mesh (OBJ, PLY, glTF, GLB, STL, VTK
    /// `.vtk` / `.vtp` / `.vtu`), particles or a point cloud (CSV, `.tpart`, a PLY without
    /// faces), a volume (NRRD, NIfTI, `.vti`, DICOM, `.vol.toml`) or a `.scene.toml`.
    File(PathBuf),
}

/// The same variants, unchecked, as they arrive.
#[derive(Deserialize)]
enum SceneSpecRaw {
    Knot { segments: u32, sides: u32 },
    Gallery,
    Empty,
    File(PathBuf),
}

/// Why a scene name was refused.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum SceneSpecError {
    /// A `knot:` name that is not `knot:SEGMENTS:SIDES`, or a knot with a count outside 3 to 65536.
    #[error("`{text}`: expected knot:SEGMENTS:SIDES with two numbers from 3 to 65536")]
    BadKnot {
        /// The scene name as given (or rebuilt from an arriving knot).
        text: String,
    },
    /// A knot with more than [`MAX_KNOT_TRIANGLES`] triangles.
    #[error(
        "a knot of {segments}x{sides} has {triangles} triangles, more than the {MAX_KNOT_TRIANGLES} supported"
    )]
    KnotTooLarge {
        /// Rings of quads along the tube.
        segments: u32,
        /// Quads around each ring.
        sides: u32,
        /// Triangles they make: 2 × segments × sides.
        triangles: u64,
    },
    /// A file scene with an empty path.
    #[error("the scene path is empty")]
    EmptyPath,
    /// A file scene whose path is longer than [`MAX_PATH_BYTES`]; carries its length in bytes.
    #[error(
        "the scene path is {0} bytes long, more than the {MAX_PATH_BYTES} a file system takes"
    )]
    PathTooLong(usize),
}

impl Default for SceneSpec {
    fn default() -> Self {
        // 1536 × 128 quads = 393,216 triangles: a real BVH workload that still builds in well
        // under a second per node.
        SceneSpec::Knot {
            segments: 1536,
            sides: 128,
        }
    }
}

impl SceneSpec {
    /// `builtin` (or `knot`) names the default scene, `knot:SEGMENTS:SIDES` a knot of
    /// 2 × SEGMENTS × SIDES triangles (for benchmarks of any size); anything else is a path.
    pub fn from_arg(text: &str) -> Result<Self, SceneSpecError> {
        let spec = if let Some(rest) = text.strip_prefix("knot:") {
            let bad = || SceneSpecError::BadKnot {
                text: text.to_string(),
            };
            let (a, b) = rest.split_once(':').ok_or_else(bad)?;
            let segments: u32 = a.parse().map_err(|_| bad())?;
            let sides: u32 = b.parse().map_err(|_| bad())?;
            SceneSpec::Knot { segments, sides }
        } else {
            match text {
                "builtin" | "knot" | "default" => SceneSpec::default(),
                "gallery" => SceneSpec::Gallery,
                "empty" => SceneSpec::Empty,
                path => SceneSpec::File(PathBuf::from(path)),
            }
        };
        spec.check()?;
        Ok(spec)
    }

    /// Checks the sizes a render node would have to honour.
    ///
    /// # Errors
    /// A knot outside 3..=65536 per side or over [`MAX_KNOT_TRIANGLES`]; an empty path or one
    /// over [`MAX_PATH_BYTES`].
    pub fn check(&self) -> Result<(), SceneSpecError> {
        match self {
            &SceneSpec::Knot { segments, sides } => {
                if !(3..=65536).contains(&segments) || !(3..=65536).contains(&sides) {
                    return Err(SceneSpecError::BadKnot {
                        text: format!("knot:{segments}:{sides}"),
                    });
                }
                let triangles = 2 * segments as u64 * sides as u64;
                if triangles > MAX_KNOT_TRIANGLES {
                    return Err(SceneSpecError::KnotTooLarge {
                        segments,
                        sides,
                        triangles,
                    });
                }
            }
            SceneSpec::File(path) => {
                let bytes = path.as_os_str().len();
                if bytes == 0 {
                    return Err(SceneSpecError::EmptyPath);
                }
                if bytes > MAX_PATH_BYTES {
                    return Err(SceneSpecError::PathTooLong(bytes));
                }
            }
            SceneSpec::Gallery | SceneSpec::Empty => {}
        }
        Ok(())
    }
}

impl TryFrom<SceneSpecRaw> for SceneSpec {
    type Error = SceneSpecError;

    fn try_from(raw: SceneSpecRaw) -> Result<Self, SceneSpecError> {
        let spec = match raw {
            SceneSpecRaw::Knot { segments, sides } => SceneSpec::Knot { segments, sides },
            SceneSpecRaw::Gallery => SceneSpec::Gallery,
            SceneSpecRaw::Empty => SceneSpec::Empty,
            SceneSpecRaw::File(path) => SceneSpec::File(path),
        };
        spec.check()?;
        Ok(spec)
    }
}

impl<'de> Deserialize<'de> for SceneSpec {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        crate::checked::deserialize::<D, SceneSpecRaw, Self>(d)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_parse() {
        assert_eq!(SceneSpec::from_arg("builtin"), Ok(SceneSpec::default()));
        assert_eq!(
            SceneSpec::from_arg("knot:64:8"),
            Ok(SceneSpec::Knot {
                segments: 64,
                sides: 8
            })
        );
        assert_eq!(
            SceneSpec::from_arg("a.obj"),
            Ok(SceneSpec::File("a.obj".into()))
        );
        for bad in ["knot:2:8", "knot:8", "knot:a:b", "knot:8:70000"] {
            assert!(SceneSpec::from_arg(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn a_knot_of_billions_of_triangles_is_refused_before_it_is_built() {
        let err = SceneSpec::from_arg("knot:65536:65536").unwrap_err();
        assert!(matches!(err, SceneSpecError::KnotTooLarge { .. }), "{err}");
        // The same from the network: a render node never starts building it.
        let bytes = postcard::to_allocvec(&SceneSpec::Knot {
            segments: 65536,
            sides: 65536,
        })
        .unwrap();
        assert!(crate::checked::decode_for_test::<SceneSpec>(&bytes).is_err());
    }

    #[test]
    fn absurd_paths_are_refused() {
        let long = "x".repeat(MAX_PATH_BYTES + 1);
        assert_eq!(
            SceneSpec::from_arg(&long),
            Err(SceneSpecError::PathTooLong(MAX_PATH_BYTES + 1))
        );
        assert_eq!(SceneSpec::from_arg(""), Err(SceneSpecError::EmptyPath));
    }
}
