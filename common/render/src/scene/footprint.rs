//! What a replicated scene will take in a render node's memory, estimated before any of it is
//! loaded, so that a scene that does not fit is refused with the sizes instead of aborting
//! the node part-way through an allocation.
//!
//! The estimate is counts known ahead times a cost per element at the load's peak (the
//! loaded scene, the BVH build's working arrays and the prepared copy for rendering are alive
//! together for a moment):
//!
//! - a built-in knot: its triangles and vertices, from its segments and sides;
//! - a volume: its voxels from the header where it declares them (NRRD, a raw sidecar),
//!   otherwise half its bytes on disk (16-bit samples, what CT and MR data mostly are);
//! - a mesh or a particle file: its bytes on disk times what a byte of such a file becomes
//!   in memory (a compressed file is under-estimated).
//!
//! A composite `.scene.toml` is not estimated: its parts are named inside it.

use std::path::Path;
use tessera_model::scene_spec::SceneSpec;

/// Bytes per triangle at the load's peak: its indices and material (14), its share of the
/// BVH's nodes (two per leaf triangle, 32 bytes each) and of the build's bounds, centroids
/// and Morton codes, and the prepared triangle the traversal reads.
pub const TRIANGLE_BYTES: u64 = 160;
/// Bytes per vertex: its position, and its normal while the mesh is prepared.
pub const VERTEX_BYTES: u64 = 32;
/// Bytes per voxel: the samples as `f32`, their bricks (with a one-voxel apron) and the
/// decoded file's bytes while both are held.
pub const VOXEL_BYTES: u64 = 12;
/// Bytes in memory per byte of a mesh file (a triangle is some 20 to 35 bytes of OBJ or PLY,
/// [`TRIANGLE_BYTES`] and half a vertex in memory).
pub const MESH_FILE_FACTOR: u64 = 6;
/// Bytes in memory per byte of a particle file (a `.tpart` record is 20 bytes; a particle
/// and its share of the sphere BVH some 120).
pub const PARTICLE_FILE_FACTOR: u64 = 6;

/// A scene's estimated size in memory, and what it was estimated from (for messages).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Footprint {
    /// Bytes at the load's peak.
    pub bytes: u64,
    /// What the figure rests on, such as `134217728 triangles`.
    pub basis: String,
}

/// The footprint of the scene `spec` names, from what is known before loading it; `None`
/// where nothing is (a composite scene file, a file that cannot be read: the load reports
/// that).
///
/// # Examples
///
/// ```
/// use tessera_model::scene_spec::SceneSpec;
/// use tessera_render::scene::footprint::{estimate, TRIANGLE_BYTES, VERTEX_BYTES};
///
/// let knot = SceneSpec::Knot { segments: 1000, sides: 100 };
/// let f = estimate(&knot).unwrap();
/// assert_eq!(f.bytes, 200_000 * TRIANGLE_BYTES + 100_000 * VERTEX_BYTES);
/// ```
pub fn estimate(spec: &SceneSpec) -> Option<Footprint> {
    match spec {
        SceneSpec::Knot { segments, sides } => {
            let vertices = u64::from((*segments).max(3)) * u64::from((*sides).max(3));
            let triangles = 2 * vertices;
            Some(Footprint {
                bytes: triangles * TRIANGLE_BYTES + vertices * VERTEX_BYTES,
                basis: format!("{triangles} triangles"),
            })
        }
        // Built in and small: a few thousand triangles.
        SceneSpec::Gallery | SceneSpec::Empty => Some(Footprint {
            bytes: 0,
            basis: "a built-in scene".into(),
        }),
        SceneSpec::File(path) => of_file(path),
    }
}

fn of_file(path: &Path) -> Option<Footprint> {
    if super::composite::is_scene_file(path) {
        return None;
    }
    if crate::volume::is_volume_path(path) {
        let (voxels, basis) = match crate::volume::declared_voxels(path) {
            Some(n) => (n, format!("{n} voxels")),
            None => {
                let n = bytes_on_disk(path)? / 2;
                (n, format!("about {n} voxels, from its size on disk"))
            }
        };
        return Some(Footprint {
            bytes: voxels.saturating_mul(VOXEL_BYTES),
            basis,
        });
    }
    let on_disk = bytes_on_disk(path)?;
    let factor = if super::particles::is_particle_file(path) {
        PARTICLE_FILE_FACTOR
    } else {
        MESH_FILE_FACTOR
    };
    Some(Footprint {
        bytes: on_disk.saturating_mul(factor),
        basis: format!("{on_disk} bytes on disk"),
    })
}

/// A file's size, or the sum of a folder's files (a DICOM series).
fn bytes_on_disk(path: &Path) -> Option<u64> {
    let meta = std::fs::metadata(path).ok()?;
    if !meta.is_dir() {
        return Some(meta.len());
    }
    let entries = std::fs::read_dir(path).ok()?;
    Some(
        entries
            .filter_map(|e| e.ok()?.metadata().ok())
            .filter(|m| m.is_file())
            .map(|m| m.len())
            .sum(),
    )
}

/// Why a replicated scene is refused before it is loaded.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
#[error("the scene needs about {} in memory here ({}), more than {budget_name} of {}: {hint}", mib(.needed.bytes), .needed.basis, mib(*.budget))]
pub struct TooLarge {
    /// The scene's estimate.
    pub needed: Footprint,
    /// The budget it was held against, in bytes.
    pub budget: u64,
    /// What the budget is, such as `this node's --memory-budget`.
    pub budget_name: String,
    /// What to do about it.
    pub hint: String,
}

/// `bytes` as MiB, for messages.
fn mib(bytes: u64) -> String {
    format!("{:.1} MiB", bytes as f64 / f64::from(1 << 20))
}

/// Holds `needed` against `budget` (named `budget_name` in the refusal).
///
/// # Errors
/// [`TooLarge`], naming both sizes, when the estimate exceeds the budget.
pub fn check_fits(
    needed: Footprint,
    budget: u64,
    budget_name: &str,
    hint: &str,
) -> Result<(), TooLarge> {
    if needed.bytes <= budget {
        return Ok(());
    }
    Err(TooLarge {
        needed,
        budget,
        budget_name: budget_name.into(),
        hint: hint.into(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_knot_that_aborted_a_node_is_refused_by_a_16_mib_budget_naming_both_sizes() {
        // 2^27 triangles: its triangle array alone was the failed 6 GiB allocation.
        let knot = SceneSpec::Knot {
            segments: 65536,
            sides: 1024,
        };
        let needed = estimate(&knot).unwrap();
        assert_eq!(needed.basis, "134217728 triangles");
        assert!(needed.bytes > 6 << 30, "{needed:?}");
        let err = check_fits(needed, 16 << 20, "the --memory-budget", "raise it").unwrap_err();
        let text = err.to_string();
        assert!(text.contains("16.0 MiB"), "{text}");
        assert!(text.contains("22528.0 MiB"), "{text}");
        assert!(
            text.contains("--memory-budget") && text.contains("raise it"),
            "{text}"
        );
    }

    #[test]
    fn a_small_scene_fits_and_a_built_in_one_costs_nothing_of_note() {
        let small = estimate(&SceneSpec::Knot {
            segments: 64,
            sides: 8,
        })
        .unwrap();
        assert!(check_fits(small, 16 << 20, "b", "h").is_ok());
        assert_eq!(estimate(&SceneSpec::Gallery).unwrap().bytes, 0);
    }

    #[test]
    fn a_volume_is_counted_from_its_header_and_a_mesh_from_its_size() {
        let dir = tempfile::tempdir().unwrap();
        let nrrd = dir.path().join("big.nrrd");
        let header = "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 602 740 632\nencoding: raw\n\n";
        std::fs::write(&nrrd, header).unwrap();
        let f = estimate(&SceneSpec::File(nrrd)).unwrap();
        assert_eq!(f.bytes, 602 * 740 * 632 * VOXEL_BYTES);
        assert_eq!(f.basis, "281543360 voxels");
        let obj = dir.path().join("m.obj");
        std::fs::write(&obj, vec![b' '; 1000]).unwrap();
        let f = estimate(&SceneSpec::File(obj)).unwrap();
        assert_eq!(f.bytes, 1000 * MESH_FILE_FACTOR);
        assert_eq!(
            estimate(&SceneSpec::File(dir.path().join("none.obj"))),
            None
        );
    }
}
