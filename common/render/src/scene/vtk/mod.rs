//! VTK files: legacy `.vtk` (ASCII or BINARY, `POLYDATA` and `UNSTRUCTURED_GRID`) in
//! [`legacy`], and XML PolyData `.vtp` and UnstructuredGrid `.vtu` in [`xml`] (which also reads
//! the `.vti` image data that [`crate::volume`] loads as a volume).
//!
//! Written here rather than taken from `vtkio`: its last release (0.6.3) dates from 2021 with
//! only release candidates since, its errors name neither line nor element, and a loader that
//! render nodes run on files from anywhere must refuse a bad count before allocating for it.
//!
//! Surfaces are what the renderer draws: triangles, quads, polygons, pixels and triangle
//! strips become triangles; of the solid cells (tetrahedra, hexahedra, voxels, wedges,
//! pyramids) the faces no other cell shares, the mesh's boundary; vertices and lines are
//! skipped (counted in the log).

pub(super) mod legacy;
pub(crate) mod xml;

use super::files::{file_error, in_range};
use super::{Mesh, SceneError};
use glam::DVec3;
use std::collections::HashMap;
use std::path::Path;

/// Reads a legacy `.vtk` file's surface.
///
/// # Errors
/// A [`SceneError`] naming the file and the line, section or cell at fault.
pub(super) fn load_legacy(path: &Path) -> Result<Mesh, SceneError> {
    let bytes = std::fs::read(path).map_err(|e| file_error(path, e))?;
    legacy::parse(&bytes).map_err(|why| file_error(path, why))
}

/// Reads an XML `.vtp` or `.vtu` file's surface.
///
/// # Errors
/// A [`SceneError`] naming the file and the element (with its line) at fault.
pub(super) fn load_xml(path: &Path) -> Result<Mesh, SceneError> {
    let bytes = std::fs::read(path).map_err(|e| file_error(path, e))?;
    xml::surface(&bytes).map_err(|why| file_error(path, why))
}

/// VTK's cell type numbers for the linear cells read here.
pub(crate) mod cell {
    pub const VERTEX: i64 = 1;
    pub const POLY_VERTEX: i64 = 2;
    pub const LINE: i64 = 3;
    pub const POLY_LINE: i64 = 4;
    pub const TRIANGLE: i64 = 5;
    pub const TRIANGLE_STRIP: i64 = 6;
    pub const POLYGON: i64 = 7;
    pub const PIXEL: i64 = 8;
    pub const QUAD: i64 = 9;
    pub const TETRA: i64 = 10;
    pub const VOXEL: i64 = 11;
    pub const HEXAHEDRON: i64 = 12;
    pub const WEDGE: i64 = 13;
    pub const PYRAMID: i64 = 14;
}

/// The faces of each solid cell, in VTK's point order for it (outward, as VTK lists them).
fn solid_faces(kind: i64) -> Option<(usize, &'static [&'static [usize]])> {
    Some(match kind {
        cell::TETRA => (4, &[&[0, 1, 3], &[1, 2, 3], &[2, 0, 3], &[0, 2, 1]]),
        cell::VOXEL => (
            8,
            &[
                &[0, 4, 6, 2],
                &[1, 3, 7, 5],
                &[0, 1, 5, 4],
                &[2, 6, 7, 3],
                &[0, 2, 3, 1],
                &[4, 5, 7, 6],
            ],
        ),
        cell::HEXAHEDRON => (
            8,
            &[
                &[0, 4, 7, 3],
                &[1, 2, 6, 5],
                &[0, 1, 5, 4],
                &[3, 7, 6, 2],
                &[0, 3, 2, 1],
                &[4, 5, 6, 7],
            ],
        ),
        cell::WEDGE => (
            6,
            &[
                &[0, 1, 2],
                &[3, 5, 4],
                &[0, 3, 4, 1],
                &[1, 4, 5, 2],
                &[2, 5, 3, 0],
            ],
        ),
        cell::PYRAMID => (
            5,
            &[
                &[0, 3, 2, 1],
                &[0, 1, 4],
                &[1, 2, 4],
                &[2, 3, 4],
                &[3, 0, 4],
            ],
        ),
        _ => return None,
    })
}

/// A surface built cell by cell: polygons go straight to triangles; solid cells' faces are
/// counted, and those used once (the boundary) are added by [`Surface::finish`].
#[derive(Default)]
pub(crate) struct Surface {
    positions: Vec<DVec3>,
    triangles: Vec<[u32; 3]>,
    /// Each distinct solid face (by its sorted points, padded with `u32::MAX`): its index in
    /// `faces`. A Vec beside the map keeps the output in file order on every node.
    face_index: HashMap<[u32; 4], usize>,
    faces: Vec<([u32; 4], usize, u32)>,
    skipped: usize,
}

impl Surface {
    /// Adds points, checked finite and within f32's range; `at` says where they came from.
    pub(crate) fn add_points(&mut self, xyz: &[f64], at: &str) -> Result<(), String> {
        for (index, p) in xyz.chunks_exact(3).enumerate() {
            let p = DVec3::new(p[0], p[1], p[2]);
            if !in_range(p) {
                return Err(format!(
                    "{at}: point {index} has a non-finite coordinate {p}"
                ));
            }
            self.positions.push(p);
        }
        if u32::try_from(self.positions.len()).is_err() {
            return Err(format!("{at}: more points than 32-bit indices reach"));
        }
        Ok(())
    }

    /// How many points there are so far (the first of the next piece's).
    pub(crate) fn point_count(&self) -> usize {
        self.positions.len()
    }

    /// Adds cell `index` of type `kind` over `ids` (already offset to this surface's points).
    pub(crate) fn add_cell(&mut self, index: usize, kind: i64, ids: &[i64]) -> Result<(), String> {
        let count = self.positions.len();
        if let Some(&bad) = ids.iter().find(|&&v| v < 0 || v as usize >= count) {
            return Err(format!(
                "cell {index} uses point {bad}, but there are only {count} points"
            ));
        }
        let ids: Vec<u32> = ids.iter().map(|&v| v as u32).collect();
        let need = |n: usize, name: &str| {
            if ids.len() == n {
                Ok(())
            } else {
                Err(format!(
                    "cell {index} ({name}) has {} points, expected {n}",
                    ids.len()
                ))
            }
        };
        match kind {
            cell::VERTEX | cell::POLY_VERTEX | cell::LINE | cell::POLY_LINE => self.skipped += 1,
            cell::TRIANGLE => {
                need(3, "triangle")?;
                self.polygon(&ids);
            }
            cell::QUAD => {
                need(4, "quad")?;
                self.polygon(&ids);
            }
            cell::PIXEL => {
                need(4, "pixel")?;
                self.polygon(&[ids[0], ids[1], ids[3], ids[2]]);
            }
            cell::POLYGON => self.polygon(&ids),
            cell::TRIANGLE_STRIP => self.strip(&ids),
            _ => {
                let Some((points, faces)) = solid_faces(kind) else {
                    return Err(format!(
                        "cell {index} has type {kind}, which is not read (linear cells only: \
                         types 1-14)"
                    ));
                };
                need(points, "solid cell")?;
                for face in faces {
                    let face: Vec<u32> = face.iter().map(|&k| ids[k]).collect();
                    self.solid_face(&face);
                }
            }
        }
        Ok(())
    }

    /// A polygon as a fan; fewer than three points is a degenerate cell, skipped.
    pub(crate) fn polygon(&mut self, ids: &[u32]) {
        if ids.len() < 3 {
            self.skipped += 1;
        }
        for k in 1..ids.len().saturating_sub(1) {
            self.triangles.push([ids[0], ids[k], ids[k + 1]]);
        }
    }

    /// A triangle strip, every other triangle turned so that all face the same way.
    pub(crate) fn strip(&mut self, ids: &[u32]) {
        for k in 0..ids.len().saturating_sub(2) {
            let (a, b, c) = (ids[k], ids[k + 1], ids[k + 2]);
            self.triangles
                .push(if k % 2 == 0 { [a, b, c] } else { [b, a, c] });
        }
    }

    fn solid_face(&mut self, face: &[u32]) {
        let mut key = [u32::MAX; 4];
        key[..face.len()].copy_from_slice(face);
        let mut ordered = key;
        ordered[..face.len()].sort_unstable();
        match self.face_index.get(&ordered) {
            Some(&i) => self.faces[i].2 += 1,
            None => {
                self.face_index.insert(ordered, self.faces.len());
                self.faces.push((key, face.len(), 1));
            }
        }
    }

    /// The mesh: the polygons, then the solid faces used by one cell only.
    pub(crate) fn finish(mut self, what: &str) -> Mesh {
        let faces = std::mem::take(&mut self.faces);
        for (face, len, uses) in faces {
            if uses == 1 {
                self.polygon(&face[..len]);
            }
        }
        if self.skipped > 0 {
            tracing::info!(
                "{what}: skipped {} vertex, line or degenerate cells (only surfaces are drawn)",
                self.skipped
            );
        }
        Mesh {
            positions: self.positions,
            triangles: self.triangles,
            ..Default::default()
        }
    }
}

/// Whole numbers from values read as f64 (point ids, offsets, cell types); `what` names the
/// array in the error.
pub(crate) fn integers(values: &[f64], what: &str) -> Result<Vec<i64>, String> {
    values
        .iter()
        .enumerate()
        .map(|(index, &v)| {
            if v.fract() == 0.0 && v.abs() < 9.0e15 {
                Ok(v as i64)
            } else {
                Err(format!("{what} value {index} is {v}, not a whole number"))
            }
        })
        .collect()
}

/// Each cell's range of a connectivity list of `len` ids, from the offsets that end them
/// (the first cell starts at 0), which must rise and end within the list.
pub(crate) fn cell_ranges(ends: &[i64], len: usize) -> Result<Vec<std::ops::Range<usize>>, String> {
    let mut ranges = Vec::with_capacity(ends.len());
    let mut start = 0usize;
    for (index, &end) in ends.iter().enumerate() {
        if end < start as i64 || end as u64 > len as u64 {
            return Err(format!(
                "cell {index} ends at offset {end}: offsets must rise, from 0 to the {len} ids"
            ));
        }
        ranges.push(start..end as usize);
        start = end as usize;
    }
    Ok(ranges)
}

/// Counts a file gives, checked against what `available` bytes could hold before anything is
/// allocated for them: every value takes at least one byte.
pub(crate) fn check_count(
    what: &str,
    count: u64,
    per: u64,
    available: usize,
) -> Result<(), String> {
    match count.checked_mul(per) {
        Some(values) if values <= available as u64 => Ok(()),
        _ => Err(format!(
            "{what} claims {count} entries, more than the {available} bytes left could hold"
        )),
    }
}

#[cfg(test)]
pub(crate) mod tests;
