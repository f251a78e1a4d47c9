//! STL meshes, binary or ASCII. STL stores each triangle with three corners of its own, so
//! corners with the same f32 bits are welded into one vertex: the mesh comes out indexed, as
//! the other loaders give it (and the BVH build and the scene hash see each vertex once).
//!
//! A file is binary when its length is exactly `84 + 50 × count` for the count in its header,
//! whatever its first bytes say: many CAD programs write `solid` at the start of a binary
//! header. Otherwise it must be ASCII (`solid` … `facet` … `outer loop` … `vertex` ×3 …
//! `endloop` … `endfacet` … `endsolid`), read line by line with errors naming the line.

use super::files::file_error;
use super::{Mesh, SceneError};
use glam::DVec3;
use std::collections::HashMap;
use std::path::Path;

/// The binary header: 80 bytes of anything, then the triangle count (u32, little-endian).
const HEADER: usize = 84;
/// One binary triangle: normal, three corners (12 f32), and a 2-byte attribute.
const RECORD: usize = 50;

/// Reads an STL file, binary or ASCII, welding corners with the same coordinates.
///
/// # Errors
/// A [`SceneError`] naming the file and the line (ASCII) or triangle (binary) at fault, or a
/// binary length that does not match its triangle count.
pub(super) fn load_stl(path: &Path) -> Result<Mesh, SceneError> {
    let bytes = std::fs::read(path).map_err(|e| file_error(path, e))?;
    let corners = parse(&bytes).map_err(|why| file_error(path, why))?;
    Ok(weld(&corners))
}

/// The corners of every triangle, three per triangle, in file order.
fn parse(bytes: &[u8]) -> Result<Vec<[f32; 3]>, String> {
    let count = (bytes.len() >= HEADER)
        .then(|| u32::from_le_bytes([bytes[80], bytes[81], bytes[82], bytes[83]]) as u64);
    let binary_length = count.map(|n| HEADER as u64 + RECORD as u64 * n);
    if binary_length == Some(bytes.len() as u64) {
        return binary(&bytes[HEADER..]);
    }
    let text_start = bytes.iter().position(|b| !b.is_ascii_whitespace());
    if text_start.is_some_and(|at| bytes[at..].starts_with(b"solid")) {
        return ascii(bytes);
    }
    match (count, binary_length) {
        (Some(count), Some(want)) => Err(format!(
            "binary STL header announces {count} triangles ({want} bytes), but the file has {} \
             bytes (and it does not start with `solid`, so it is not ASCII STL)",
            bytes.len()
        )),
        _ => Err(format!(
            "{} bytes: too short for a binary STL header ({HEADER} bytes), and it does not start \
             with `solid` (ASCII STL)",
            bytes.len()
        )),
    }
}

/// The triangle records of a binary file (its length already checked against the count).
fn binary(records: &[u8]) -> Result<Vec<[f32; 3]>, String> {
    let mut corners = Vec::with_capacity(records.len() / RECORD * 3);
    for (index, record) in records.chunks_exact(RECORD).enumerate() {
        // Bytes 0..12 are the facet normal, which the renderer recomputes from the corners.
        for corner in record[12..48].chunks_exact(12) {
            let c: [f32; 3] = std::array::from_fn(|a| {
                f32::from_le_bytes(corner[a * 4..a * 4 + 4].try_into().unwrap())
            });
            if !c.iter().all(|v| v.is_finite()) {
                return Err(format!("triangle {index} has a non-finite corner {c:?}"));
            }
            corners.push(c);
        }
    }
    Ok(corners)
}

/// Where an ASCII reader is in the `solid` / `facet` / `outer loop` nesting.
#[derive(Clone, Copy, PartialEq)]
enum State {
    Outside,
    Solid,
    Facet,
    /// Inside `outer loop`, with this many vertices read.
    Loop(usize),
    /// After `endloop`, before `endfacet`.
    Looped,
}

/// The triangles of an ASCII file; several `solid`s one after another are read as one mesh.
fn ascii(bytes: &[u8]) -> Result<Vec<[f32; 3]>, String> {
    let mut corners = Vec::new();
    let mut state = State::Outside;
    let mut number = 0;
    for line in bytes.split(|&b| b == b'\n') {
        number += 1;
        let text = String::from_utf8_lossy(line);
        let mut words = text.split_whitespace();
        let Some(keyword) = words.next() else {
            continue;
        };
        let at = |why: String| format!("line {number}: {why}");
        state = match (keyword, state) {
            ("solid", State::Outside) => State::Solid,
            ("endsolid", State::Solid) => State::Outside,
            ("facet", State::Solid) => State::Facet,
            ("outer", State::Facet) if words.next() == Some("loop") => State::Loop(0),
            ("vertex", State::Loop(n)) if n < 3 => {
                corners.push(vertex(words).map_err(at)?);
                State::Loop(n + 1)
            }
            ("vertex", State::Loop(_)) => {
                return Err(at("a fourth `vertex` (STL facets are triangles)".into()))
            }
            ("endloop", State::Loop(3)) => State::Looped,
            ("endloop", State::Loop(n)) => {
                return Err(at(format!("loop ends after {n} vertices, not 3")))
            }
            ("endfacet", State::Looped) => State::Solid,
            (word, state) => return Err(at(format!("unexpected `{word}` ({})", expected(state)))),
        };
    }
    if matches!(state, State::Facet | State::Loop(_) | State::Looped) {
        return Err(format!(
            "line {number}: the file ends inside a facet (cut short?)"
        ));
    }
    // A facet cut short is refused above; only whole ones are in `corners`.
    Ok(corners)
}

/// What may come next in `state`, for an error message.
fn expected(state: State) -> &'static str {
    match state {
        State::Outside => "expected `solid`",
        State::Solid => "expected `facet` or `endsolid`",
        State::Facet => "expected `outer loop`",
        State::Loop(_) => "expected `vertex` or `endloop`",
        State::Looped => "expected `endfacet`",
    }
}

/// The three coordinates after `vertex`.
fn vertex<'a>(mut words: impl Iterator<Item = &'a str>) -> Result<[f32; 3], String> {
    let mut c = [0f32; 3];
    for value in &mut c {
        let word = words.next().ok_or("`vertex` needs three coordinates")?;
        *value = word
            .parse()
            .map_err(|_| format!("vertex coordinate `{word}` is not a number"))?;
        if !value.is_finite() {
            return Err(format!("vertex coordinate `{word}` is not finite"));
        }
    }
    match words.next() {
        Some(extra) => Err(format!("`vertex` has a fourth value `{extra}`")),
        None => Ok(c),
    }
}

/// An indexed mesh of `corners` (three per triangle): corners with the same f32 bits become
/// one vertex, numbered in order of first use. -0 is taken as +0 (their bits differ).
fn weld(corners: &[[f32; 3]]) -> Mesh {
    let mut index: HashMap<[u32; 3], u32> = HashMap::new();
    let mut positions = Vec::new();
    let mut ids = corners.iter().map(|c| {
        let key = c.map(|v| (v + 0.0).to_bits());
        *index.entry(key).or_insert_with(|| {
            positions.push(DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64));
            (positions.len() - 1) as u32
        })
    });
    let mut triangles = Vec::with_capacity(corners.len() / 3);
    while let (Some(a), Some(b), Some(c)) = (ids.next(), ids.next(), ids.next()) {
        triangles.push([a, b, c]);
    }
    drop(ids);
    Mesh {
        positions,
        triangles,
        ..Default::default()
    }
}

#[cfg(test)]
mod tests {
    use super::super::load_mesh_file;
    use super::*;

    /// Two triangles sharing an edge: a unit square in z = 0.
    const SQUARE: [[f32; 3]; 6] = [
        [0., 0., 0.],
        [1., 0., 0.],
        [1., 1., 0.],
        [0., 0., -0.],
        [1., 1., 0.],
        [0., 1., 0.],
    ];

    fn binary_stl(header: &[u8; 5], corners: &[[f32; 3]]) -> Vec<u8> {
        let mut bytes = header.to_vec();
        bytes.resize(80, b' ');
        bytes.extend((corners.len() as u32 / 3).to_le_bytes());
        for triangle in corners.chunks(3) {
            bytes.extend([0u8; 12]);
            triangle
                .iter()
                .flatten()
                .for_each(|c| bytes.extend(c.to_le_bytes()));
            bytes.extend([0u8; 2]);
        }
        bytes
    }

    fn ascii_stl(corners: &[[f32; 3]]) -> String {
        let mut text = String::from("solid square\n");
        for triangle in corners.chunks(3) {
            text += "  facet normal 0 0 1\n    outer loop\n";
            for c in triangle {
                text += &format!("      vertex {} {} {}\n", c[0], c[1], c[2]);
            }
            text += "    endloop\n  endfacet\n";
        }
        text + "endsolid square\n"
    }

    fn load(name: &str, bytes: &[u8]) -> Result<Mesh, String> {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(name);
        std::fs::write(&path, bytes).unwrap();
        load_mesh_file(&path).map_err(|e| {
            let e = e.to_string();
            assert!(e.contains(name) && !e.contains('\n'), "{e}");
            e
        })
    }

    #[test]
    fn binary_and_ascii_stl_give_the_same_welded_mesh() {
        let ascii = load("a.stl", ascii_stl(&SQUARE).as_bytes()).unwrap();
        // A binary header that starts with `solid`, as CAD programs write them.
        let binary = load("b.STL", &binary_stl(b"solid", &SQUARE)).unwrap();
        assert_eq!(ascii.positions, binary.positions);
        assert_eq!(ascii.triangles, binary.triangles);
        assert_eq!(ascii.positions.len(), 4, "shared corners (and -0) welded");
        assert_eq!(ascii.triangles, vec![[0, 1, 2], [0, 2, 3]]);
        let empty = load("e.stl", &binary_stl(b"empty", &[])).unwrap();
        assert!(empty.triangles.is_empty());
    }

    #[test]
    fn stl_errors_name_the_line_or_the_count() {
        let good = ascii_stl(&SQUARE);
        #[rustfmt::skip]
        let cases = [
            (good.replacen("vertex 1 0 0", "vertex 1 zz 0", 1), "line 5: vertex coordinate `zz` is not a number"),
            (good.replacen("vertex 1 0 0", "vertex 1 nan 0", 1), "line 5: vertex coordinate `nan` is not finite"),
            (good.replacen("vertex 1 0 0", "vertex 1 0", 1), "line 5: `vertex` needs three coordinates"),
            (good.replacen("      vertex 1 0 0\n", "", 1), "line 6: loop ends after 2 vertices, not 3"),
            (good.replacen("endfacet", "endloop", 1), "line 8: unexpected `endloop` (expected `endfacet`)"),
            (good.replacen("outer loop", "inner loop", 1), "line 3: unexpected `inner`"),
            (good[..good.len() - 40].to_string(), "ends inside a facet"),
        ];
        for (text, want) in cases {
            let err = load("bad.stl", text.as_bytes()).unwrap_err();
            assert!(err.contains(want), "{want}: {err}");
        }
        let binary = binary_stl(b"mesh!", &SQUARE);
        let err = load("cut.stl", &binary[..binary.len() - 1]).unwrap_err();
        assert!(
            err.contains("announces 2 triangles (184 bytes), but the file has 183"),
            "{err}"
        );
        let err = load("tiny.stl", b"abc").unwrap_err();
        assert!(err.contains("too short for a binary STL header"), "{err}");
        let mut nan = SQUARE;
        nan[4][1] = f32::INFINITY;
        let err = load("nan.stl", &binary_stl(b"mesh!", &nan)).unwrap_err();
        assert!(err.contains("triangle 1 has a non-finite corner"), "{err}");
    }
}
