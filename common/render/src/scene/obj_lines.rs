//! The OBJ loader's second look at a file `tobj` refused: `tobj` reports no line numbers, so
//! this pass finds the line at fault, and runs only once a load has failed (good files pay
//! nothing for it).

use std::io::BufRead;
use std::path::Path;

/// Finds the first line of an OBJ file that `tobj` would reject, or that yields a non-finite
/// vertex. `tobj` reports no line numbers, so this second pass runs only once a load has failed:
/// good files pay nothing for it.
pub(super) fn obj_culprit(path: &Path) -> Option<String> {
    let reader = std::io::BufReader::new(std::fs::File::open(path).ok()?);
    let mut vertices = 0usize;
    // OBJ allows forward references, so indices past the end are only known to be bad at the
    // end; the line of the largest one is blamed.
    let mut largest: Option<(usize, usize)> = None;
    for (n, line) in reader.split(b'\n').enumerate() {
        let number = n + 1;
        let line = line.ok()?;
        let Ok(text) = std::str::from_utf8(&line) else {
            return Some(format!("line {number}: not valid UTF-8"));
        };
        let mut words = text.split_whitespace();
        let bad = match words.next() {
            Some("v") => {
                vertices += 1;
                obj_vertex(words).map_err(|e| format!("vertex {vertices} {e}"))
            }
            Some(key @ ("vt" | "vn")) => {
                let want = if key == "vt" { 2 } else { 3 };
                let ok = words
                    .take(want)
                    .filter(|w| w.parse::<f32>().is_ok())
                    .count()
                    == want;
                ok.then_some(())
                    .ok_or_else(|| format!("`{key}` needs {want} numbers"))
            }
            Some("f" | "l") if words.clone().next().is_none() => Err("face has no vertices".into()),
            Some("f" | "l") => words.try_for_each(|word| {
                let index = obj_face_index(word, vertices)?;
                if index > largest.map_or(0, |(_, i)| i) {
                    largest = Some((number, index));
                }
                Ok(())
            }),
            Some("usemtl") if words.next().is_none() => Err("`usemtl` names no material".into()),
            _ => Ok(()),
        };
        if let Err(why) = bad {
            return Some(format!("line {number}: {why}"));
        }
    }
    match largest {
        Some((number, index)) if index > vertices => Some(format!(
            "line {number}: face uses vertex {index}, but the file has only {vertices} vertices"
        )),
        _ => None,
    }
}

/// Checks the words after `v` as `tobj` reads them: x y z, then an optional weight w that
/// divides them, or an r g b colour.
fn obj_vertex<'a>(words: impl Iterator<Item = &'a str>) -> Result<(), String> {
    let words: Vec<&str> = words.collect();
    if !matches!(words.len(), 3 | 4 | 6) {
        return Err(format!(
            "has {} values (expected x y z [w] or x y z r g b)",
            words.len()
        ));
    }
    let mut xyz = [0f32; 3];
    for (c, word) in xyz.iter_mut().zip(&words) {
        *c = word
            .parse()
            .map_err(|_| format!("coordinate `{word}` is not a number"))?;
        if !c.is_finite() {
            return Err(format!("coordinate `{word}` is not finite"));
        }
    }
    if let [_, _, _, w] = words[..] {
        let weight: f32 = w
            .parse()
            .map_err(|_| format!("weight `{w}` is not a number"))?;
        if weight == 0.0 || !xyz.iter().all(|c| (c / weight).is_finite()) {
            return Err(format!("weight `{w}` gives a non-finite position"));
        }
    }
    Ok(())
}

/// The 1-based vertex a face word (`v`, `v/vt`, `v//vn`, `v/vt/vn`) refers to, resolving
/// negative (relative) indices against the vertices read so far.
fn obj_face_index(word: &str, vertices: usize) -> Result<usize, String> {
    let first = word.split('/').next().unwrap_or_default();
    let index: i64 = first
        .parse()
        .map_err(|_| format!("face vertex `{word}` is not an index"))?;
    match index {
        0 => Err("face uses vertex index 0 (OBJ indices start at 1)".into()),
        i if i > 0 => Ok(i as usize),
        i => {
            let back = i.unsigned_abs() as usize;
            if back > vertices {
                Err(format!(
                    "face uses relative vertex {i}, but only {vertices} vertices precede it"
                ))
            } else {
                Ok(vertices - back + 1)
            }
        }
    }
}
