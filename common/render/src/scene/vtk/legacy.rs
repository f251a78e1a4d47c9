//! Legacy VTK (`# vtk DataFile Version x.y`), ASCII or BINARY (big-endian), datasets
//! `POLYDATA` and `UNSTRUCTURED_GRID`: `POINTS`, the cell lists in either layout (a count
//! before each cell's points, or version 5's `OFFSETS` and `CONNECTIVITY`), `CELL_TYPES`.
//! Reading stops at the first attribute section (`POINT_DATA`, `CELL_DATA`, `FIELD`): a
//! surface needs none of it. Errors name the line (ASCII) or byte offset (BINARY).

use super::{cell, check_count, Surface};
use crate::scene::Mesh;

/// Reads a legacy file's surface.
pub(crate) fn parse(bytes: &[u8]) -> Result<Mesh, String> {
    let mut r = Reader {
        bytes,
        pos: 0,
        line: 1,
        binary: false,
    };
    let first = r.line_text();
    if !first.starts_with("# vtk DataFile Version") {
        return Err("line 1: not a legacy VTK file (expected `# vtk DataFile Version`)".into());
    }
    r.line_text(); // The title, free text.
    r.binary = match r.line_text().trim().to_ascii_uppercase().as_str() {
        "ASCII" => false,
        "BINARY" => true,
        other => return Err(format!("line 3: `{other}`: expected ASCII or BINARY")),
    };
    let at = r.at();
    match (r.word(), r.word()) {
        (Some("DATASET"), Some(kind)) if kind.eq_ignore_ascii_case("POLYDATA") => {}
        (Some("DATASET"), Some(kind)) if kind.eq_ignore_ascii_case("UNSTRUCTURED_GRID") => {}
        (Some("DATASET"), Some(kind)) => {
            return Err(format!(
                "{at}: DATASET {kind} is not read (POLYDATA and UNSTRUCTURED_GRID are)"
            ))
        }
        _ => return Err(format!("{at}: expected `DATASET`")),
    }
    sections(&mut r)
}

/// The sections after `DATASET`, up to the first attribute section or the end.
fn sections(r: &mut Reader) -> Result<Mesh, String> {
    let mut surface = Surface::default();
    // An unstructured grid's cells, kept until `CELL_TYPES` says what they are.
    let mut cells: Option<(Vec<f64>, Vec<std::ops::Range<usize>>)> = None;
    while let Some(keyword) = r.word() {
        let at = r.at();
        match keyword.to_ascii_uppercase().as_str() {
            "POINTS" => {
                let count = r.count(&at, "POINTS")?;
                let kind = r.type_word(&at)?;
                let xyz = r.numbers(count.saturating_mul(3), kind, "POINTS")?;
                surface.add_points(&xyz, &format!("{at}: POINTS"))?;
            }
            "METADATA" => r.skip_metadata(),
            list @ ("POLYGONS" | "TRIANGLE_STRIPS" | "VERTICES" | "LINES" | "CELLS") => {
                let (ids, ranges) = r.cell_list(&at, list)?;
                match list {
                    "CELLS" => cells = Some((ids, ranges)),
                    "POLYGONS" | "TRIANGLE_STRIPS" => {
                        let kind = if list == "POLYGONS" {
                            cell::POLYGON
                        } else {
                            cell::TRIANGLE_STRIP
                        };
                        for (index, range) in ranges.into_iter().enumerate() {
                            let ids = super::integers(&ids[range], list)?;
                            surface
                                .add_cell(index, kind, &ids)
                                .map_err(|e| format!("{at}: {list}: {e}"))?;
                        }
                    }
                    _ => {}
                }
            }
            "CELL_TYPES" => {
                let count = r.count(&at, "CELL_TYPES")?;
                let types = r.numbers(count, INT, "CELL_TYPES")?;
                let (ids, ranges) = cells
                    .take()
                    .ok_or_else(|| format!("{at}: CELL_TYPES before CELLS"))?;
                if types.len() != ranges.len() {
                    return Err(format!(
                        "{at}: {} CELL_TYPES for {} CELLS",
                        types.len(),
                        ranges.len()
                    ));
                }
                let types = super::integers(&types, "CELL_TYPES")?;
                for (index, (range, kind)) in ranges.into_iter().zip(types).enumerate() {
                    let ids = super::integers(&ids[range], "CELLS")?;
                    surface
                        .add_cell(index, kind, &ids)
                        .map_err(|e| format!("{at}: CELLS: {e}"))?;
                }
            }
            "POINT_DATA" | "CELL_DATA" | "FIELD" => break,
            _ => return Err(format!("{at}: unexpected `{keyword}`")),
        }
    }
    if cells.is_some() {
        return Err("CELLS without CELL_TYPES".into());
    }
    Ok(surface.finish("legacy VTK file"))
}

/// A legacy file's bytes, read as words where it is text and as blocks where it is binary.
struct Reader<'a> {
    bytes: &'a [u8],
    pos: usize,
    /// The line `pos` is on, counted through text only.
    line: usize,
    binary: bool,
}

/// The number types of legacy files: their size in BINARY files, and whether a float.
#[derive(Clone, Copy)]
struct Kind {
    size: usize,
    float: bool,
    signed: bool,
}

/// Cell lists and types, which name no type: 32-bit ints.
const INT: Kind = Kind {
    size: 4,
    float: false,
    signed: true,
};

impl<'a> Reader<'a> {
    /// Where the reader is, for an error: the line in ASCII files, the byte in BINARY ones
    /// (whose line numbers lose their meaning after the first block of data).
    fn at(&self) -> String {
        if self.binary {
            format!("byte {}", self.pos)
        } else {
            format!("line {}", self.line)
        }
    }

    /// The rest of the current line, and the reader moved past its end.
    fn line_text(&mut self) -> String {
        let rest = &self.bytes[self.pos..];
        let end = rest.iter().position(|&b| b == b'\n').unwrap_or(rest.len());
        self.pos += (end + 1).min(rest.len());
        self.line += 1;
        String::from_utf8_lossy(&rest[..end]).into_owned()
    }

    /// The next whitespace-separated word (None at the end, or for one that is not UTF-8,
    /// which no keyword or number is).
    fn word(&mut self) -> Option<&'a str> {
        while let Some(&b) = self.bytes.get(self.pos) {
            if !b.is_ascii_whitespace() {
                break;
            }
            self.line += usize::from(b == b'\n');
            self.pos += 1;
        }
        let rest = &self.bytes[self.pos..];
        let len = rest
            .iter()
            .position(u8::is_ascii_whitespace)
            .unwrap_or(rest.len());
        self.pos += len;
        (len > 0).then(|| std::str::from_utf8(&rest[..len]).unwrap_or("\u{fffd}"))
    }

    fn count(&mut self, at: &str, what: &str) -> Result<usize, String> {
        let word = self.word().unwrap_or("");
        word.parse()
            .map_err(|_| format!("{at}: {what}: count `{word}` is not a whole number"))
    }

    fn type_word(&mut self, at: &str) -> Result<Kind, String> {
        let word = self.word().unwrap_or("");
        let kind = |size, float, signed| Kind {
            size,
            float,
            signed,
        };
        Ok(match word.to_ascii_lowercase().as_str() {
            "unsigned_char" => kind(1, false, false),
            "char" => kind(1, false, true),
            "unsigned_short" => kind(2, false, false),
            "short" => kind(2, false, true),
            "unsigned_int" => kind(4, false, false),
            "int" => kind(4, false, true),
            "unsigned_long" | "vtktypeuint64" => kind(8, false, false),
            "long" | "vtktypeint64" | "vtkidtype" => kind(8, false, true),
            "float" => kind(4, true, true),
            "double" => kind(8, true, true),
            _ => return Err(format!("{at}: data type `{word}` is not read")),
        })
    }

    /// `count` numbers of type `kind` as f64: words in ASCII files; in BINARY ones the
    /// big-endian block that starts on the next line.
    fn numbers(&mut self, count: usize, kind: Kind, what: &str) -> Result<Vec<f64>, String> {
        let at = self.at();
        if !self.binary {
            check_count(&format!("{at}: {what}"), count as u64, 1, self.left())?;
            let mut out = Vec::with_capacity(count);
            for index in 0..count {
                let Some(word) = self.word() else {
                    return Err(format!(
                        "{what}: the file ends after {index} of {count} values"
                    ));
                };
                let value = word.parse::<f64>().map_err(|_| {
                    format!(
                        "line {}: {what} value {index}: `{word}` is not a number",
                        self.line
                    )
                })?;
                out.push(value);
            }
            return Ok(out);
        }
        // The block starts after the end of the keyword's line.
        let rest = &self.bytes[self.pos..];
        self.pos += rest
            .iter()
            .position(|&b| b == b'\n')
            .map_or(rest.len(), |n| n + 1);
        check_count(
            &format!("{at}: {what}"),
            count as u64,
            kind.size as u64,
            self.left(),
        )?;
        let block = &self.bytes[self.pos..self.pos + count * kind.size];
        self.pos += block.len();
        Ok(block
            .chunks_exact(kind.size)
            .map(|b| big_endian(b, kind))
            .collect())
    }

    fn left(&self) -> usize {
        self.bytes.len() - self.pos
    }

    /// Skips a `METADATA` block: everything up to the next empty line.
    fn skip_metadata(&mut self) {
        self.line_text();
        while self.pos < self.bytes.len() && !self.line_text().trim().is_empty() {}
    }

    /// A cell list (`POLYGONS n size` and its numbers, or version 5's `OFFSETS` and
    /// `CONNECTIVITY` after the counts): the point ids, and each cell's range of them.
    fn cell_list(
        &mut self,
        at: &str,
        what: &str,
    ) -> Result<(Vec<f64>, Vec<std::ops::Range<usize>>), String> {
        let cells = self.count(at, what)?;
        let size = self.count(at, what)?;
        let save = (self.pos, self.line);
        if self.word() == Some("OFFSETS") {
            let kind = self.type_word(at)?;
            let offsets = self.numbers(cells, kind, &format!("{what} OFFSETS"))?;
            let at = self.at();
            if self.word() != Some("CONNECTIVITY") {
                return Err(format!("{at}: {what}: expected CONNECTIVITY after OFFSETS"));
            }
            let kind = self.type_word(&at)?;
            let ids = self.numbers(size, kind, &format!("{what} CONNECTIVITY"))?;
            let offsets = super::integers(&offsets, "OFFSETS")?;
            if offsets.first().is_some_and(|&o| o != 0) {
                return Err(format!("{at}: {what}: OFFSETS must start at 0"));
            }
            let ranges = super::cell_ranges(offsets.get(1..).unwrap_or(&[]), ids.len())
                .map_err(|e| format!("{at}: {what}: {e}"))?;
            return Ok((ids, ranges));
        }
        (self.pos, self.line) = save;
        let numbers = self.numbers(size, INT, what)?;
        let mut ranges = Vec::with_capacity(cells.min(numbers.len()));
        let mut next = 0;
        for index in 0..cells {
            let Some(&n) = numbers.get(next) else {
                return Err(format!(
                    "{at}: {what}: the list ends before cell {index} of {cells}"
                ));
            };
            let n = n as usize;
            if n as f64 != numbers[next] || n >= numbers.len() - next {
                return Err(format!(
                    "{at}: {what}: cell {index} claims {} points, past the list's end",
                    numbers[next]
                ));
            }
            ranges.push(next + 1..next + 1 + n);
            next += 1 + n;
        }
        if next != numbers.len() {
            return Err(format!(
                "{at}: {what}: {cells} cells use {next} of the {size} numbers announced"
            ));
        }
        Ok((numbers, ranges))
    }
}

/// One big-endian number of `kind` from its bytes.
fn big_endian(b: &[u8], kind: Kind) -> f64 {
    let mut wide = [0u8; 8];
    wide[8 - b.len()..].copy_from_slice(b);
    let bits = u64::from_be_bytes(wide);
    match (kind.float, kind.size, kind.signed) {
        (true, 4, _) => f32::from_bits(bits as u32) as f64,
        (true, _, _) => f64::from_bits(bits),
        (false, 8, true) => bits as i64 as f64,
        (false, _, true) => {
            // Sign-extend from the number's own width.
            let shift = 64 - 8 * b.len() as u32;
            ((bits << shift) as i64 >> shift) as f64
        }
        (false, _, false) => bits as f64,
    }
}
