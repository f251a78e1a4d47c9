//! VTK XML files (`<VTKFile type="…">`): PolyData and UnstructuredGrid surfaces here, and the
//! element tree and `DataArray` decoding that ImageData volumes (`volume::vti`) share.
//!
//! A `DataArray` is `ascii` (numbers as text), `binary` (base64 in the element, a byte-count
//! header before the data) or `appended` (at `offset` in `<AppendedData>`, raw or base64).
//! Binary data may be zlib-compressed (`vtkZLibDataCompressor`, VTK's block layout); the LZ4
//! and LZMA compressors are refused by name. The header is UInt32 or UInt64 (`header_type`),
//! numbers in `byte_order`. Errors name the element and its line.

use super::{cell, cell_ranges, integers, Surface};
use crate::scene::Mesh;
use quick_xml::events::{BytesStart, Event};
use std::io::Read;

/// One element: its name, attributes, text (for a `DataArray`, its data) and children.
struct Element {
    name: String,
    attrs: Vec<(String, String)>,
    text: String,
    children: Vec<usize>,
    /// Byte offset of the tag's end, for the line in errors.
    offset: usize,
}

/// A parsed VTK XML file: its elements (0 is `<VTKFile>`) and what decoding needs.
pub(crate) struct Document<'a> {
    bytes: &'a [u8],
    elements: Vec<Element>,
    /// The bytes after `<AppendedData …>`'s `_`, and whether they are base64.
    appended: Option<(&'a [u8], bool)>,
    little_endian: bool,
    header_bytes: usize,
    zlib: bool,
}

/// An element of a [`Document`], by index.
pub(crate) type Id = usize;

impl<'a> Document<'a> {
    /// Parses a file's XML (raw appended data cut out first: it is not XML).
    pub(crate) fn parse(bytes: &'a [u8]) -> Result<Self, String> {
        let (xml, appended) = split_appended(bytes)?;
        let elements = tree(&xml, bytes)?;
        let mut doc = Document {
            bytes,
            elements,
            appended,
            little_endian: true,
            header_bytes: 4,
            zlib: false,
        };
        if doc.elements.first().is_none_or(|e| e.name != "VTKFile") {
            return Err("not a VTK XML file (no <VTKFile> element)".into());
        }
        doc.little_endian = match doc.attr(0, "byte_order").unwrap_or("LittleEndian") {
            "LittleEndian" => true,
            "BigEndian" => false,
            other => return Err(format!("{}: byte_order `{other}`", doc.at(0))),
        };
        doc.header_bytes = match doc.attr(0, "header_type").unwrap_or("UInt32") {
            "UInt32" => 4,
            "UInt64" => 8,
            other => return Err(format!("{}: header_type `{other}`", doc.at(0))),
        };
        doc.zlib = match doc.attr(0, "compressor") {
            None | Some("") => false,
            Some("vtkZLibDataCompressor") => true,
            Some(other) => {
                return Err(format!(
                    "{}: compressor `{other}` is not read (only vtkZLibDataCompressor): save \
                     the file uncompressed or with zlib",
                    doc.at(0)
                ))
            }
        };
        Ok(doc)
    }

    /// The `type` of `<VTKFile>` (PolyData, UnstructuredGrid, ImageData, …).
    pub(crate) fn kind(&self) -> &str {
        self.attr(0, "type").unwrap_or("")
    }

    /// The value of attribute `name` of element `id`.
    pub(crate) fn attr(&self, id: Id, name: &str) -> Option<&str> {
        let attrs = &self.elements[id].attrs;
        attrs
            .iter()
            .find(|(k, _)| k == name)
            .map(|(_, v)| v.as_str())
    }

    /// Attribute `name` of `id` as numbers, `default` when it is absent.
    pub(crate) fn numbers(&self, id: Id, name: &str, default: &str) -> Result<Vec<f64>, String> {
        let text = self.attr(id, name).unwrap_or(default);
        text.split_whitespace()
            .map(|w| w.parse::<f64>().ok().filter(|v| v.is_finite()))
            .collect::<Option<Vec<_>>>()
            .ok_or_else(|| {
                format!(
                    "{}: {name}=\"{text}\" is not a list of numbers",
                    self.at(id)
                )
            })
    }

    /// Attribute `name` of `id` as a count, `default` when it is absent.
    pub(crate) fn count(
        &self,
        id: Id,
        name: &str,
        default: Option<usize>,
    ) -> Result<usize, String> {
        match (self.attr(id, name), default) {
            (None, Some(d)) => Ok(d),
            (None, None) => Err(format!("{}: no {name} attribute", self.at(id))),
            (Some(text), _) => text
                .trim()
                .parse()
                .map_err(|_| format!("{}: {name}=\"{text}\" is not a count", self.at(id))),
        }
    }

    /// The children of `id` named `name`.
    pub(crate) fn children<'s>(&'s self, id: Id, name: &'s str) -> impl Iterator<Item = Id> + 's {
        let kids = self.elements[id].children.iter().copied();
        kids.filter(move |&c| self.elements[c].name == name)
    }

    /// The first child of `id` named `name`, or an error saying it is missing.
    pub(crate) fn child(&self, id: Id, name: &str) -> Result<Id, String> {
        self.children(id, name)
            .next()
            .ok_or_else(|| format!("{} has no <{name}>", self.at(id)))
    }

    /// The `DataArray` child of `id` whose `Name` is `name`.
    pub(crate) fn array_named(&self, id: Id, name: &str) -> Result<Id, String> {
        self.children(id, "DataArray")
            .find(|&c| self.attr(c, "Name") == Some(name))
            .ok_or_else(|| format!("{} has no DataArray named `{name}`", self.at(id)))
    }

    /// An element as errors name it: `<DataArray Name="offsets"> (line 12)`.
    pub(crate) fn at(&self, id: Id) -> String {
        let e = &self.elements[id];
        let line = 1 + self.bytes[..e.offset.min(self.bytes.len())]
            .iter()
            .filter(|&&b| b == b'\n')
            .count();
        match self.attr(id, "Name") {
            Some(name) => format!("<{} Name=\"{name}\"> (line {line})", e.name),
            None => format!("<{}> (line {line})", e.name),
        }
    }

    /// The values of `DataArray` `id`, which must number exactly `count`, each converted by
    /// `convert` (so that a volume's samples never pass through a Vec of f64).
    pub(crate) fn values<T>(
        &self,
        id: Id,
        count: usize,
        convert: impl Fn(f64) -> T,
    ) -> Result<Vec<T>, String> {
        let at = || self.at(id);
        let ty = self.attr(id, "type").unwrap_or("");
        let (size, decode) =
            number_type(ty).ok_or_else(|| format!("{}: type `{ty}` is not a number type", at()))?;
        let format = self.attr(id, "format").unwrap_or("ascii");
        let values: Vec<T> = if format == "ascii" {
            let text = &self.elements[id].text;
            let mut out = Vec::with_capacity(count.min(text.len() / 2 + 1));
            for (index, word) in text.split_whitespace().enumerate() {
                let v: f64 = word
                    .parse()
                    .map_err(|_| format!("{}: value {index} `{word}` is not a number", at()))?;
                out.push(convert(v));
            }
            out
        } else {
            let bytes = count
                .checked_mul(size)
                .ok_or_else(|| format!("{}: {count} values overflow", at()))?;
            let data = self
                .binary(id, format, bytes)
                .map_err(|e| format!("{}: {e}", at()))?;
            let little = self.little_endian;
            data.chunks_exact(size)
                .map(|b| convert(decode(b, little)))
                .collect()
        };
        if values.len() != count {
            return Err(format!(
                "{}: {} values, expected {count}",
                at(),
                values.len()
            ));
        }
        Ok(values)
    }

    /// The `bytes` bytes of a binary or appended array, its header checked.
    fn binary(&self, id: Id, format: &str, bytes: usize) -> Result<Vec<u8>, String> {
        let text = self.elements[id].text.as_bytes();
        let mut source = match format {
            "binary" => Source::Base64(Base64::new(text)),
            "appended" => {
                let (data, base64) = self
                    .appended
                    .ok_or("format=\"appended\", but the file has no <AppendedData>")?;
                let offset = self.count(id, "offset", None)?;
                let data = data.get(offset..).ok_or_else(|| {
                    format!(
                        "offset {offset} is past the {} bytes of appended data",
                        data.len()
                    )
                })?;
                match base64 {
                    true => Source::Base64(Base64::new(data)),
                    false => Source::Raw(data),
                }
            }
            other => return Err(format!("format `{other}` (ascii, binary or appended)")),
        };
        let header = |source: &mut Source, n: usize| -> Result<Vec<u64>, String> {
            let raw = source.take(n * self.header_bytes)?;
            Ok(raw
                .chunks_exact(self.header_bytes)
                .map(|b| decode_uint(b, self.little_endian))
                .collect())
        };
        if !self.zlib {
            let size = header(&mut source, 1)?[0];
            if size != bytes as u64 {
                return Err(format!("its header says {size} bytes, expected {bytes}"));
            }
            return source.take(bytes);
        }
        inflate_blocks(&mut source, bytes, header)
    }
}

/// VTK's zlib layout: block count, block size, last block's size, each block's compressed
/// size, then the blocks, which must inflate to `bytes` in all.
fn inflate_blocks(
    source: &mut Source,
    bytes: usize,
    header: impl Fn(&mut Source, usize) -> Result<Vec<u64>, String>,
) -> Result<Vec<u8>, String> {
    let head = header(source, 3)?;
    let (blocks, block, last) = (head[0], head[1], head[2]);
    // Each compressed size takes at least one header byte, so this bounds the count.
    let sizes = header(
        source,
        usize::try_from(blocks).unwrap_or(usize::MAX).min(1 << 40),
    )?;
    let last = if last == 0 { block } else { last };
    let total = blocks
        .checked_sub(1)
        .and_then(|full| full.checked_mul(block))
        .and_then(|t| t.checked_add(last))
        .unwrap_or(0);
    if total != bytes as u64 {
        return Err(format!(
            "its compression header says {total} bytes ({blocks} blocks of {block}), expected \
             {bytes}"
        ));
    }
    // zlib expands at most about 1032 to 1: a claim beyond that is a corrupt header.
    let compressed: u64 = sizes.iter().fold(0u64, |s, &c| s.saturating_add(c));
    if bytes as u64 > compressed.saturating_mul(1100).saturating_add(1024) {
        return Err(format!(
            "{bytes} bytes cannot inflate from {compressed} compressed bytes"
        ));
    }
    let mut out = Vec::with_capacity(bytes);
    for (index, &size) in sizes.iter().enumerate() {
        let want = if index as u64 + 1 == blocks {
            last
        } else {
            block
        };
        let packed = source.take(usize::try_from(size).unwrap_or(usize::MAX))?;
        let before = out.len();
        flate2::read::ZlibDecoder::new(&packed[..])
            .take(want)
            .read_to_end(&mut out)
            .map_err(|e| format!("zlib block {index}: {e}"))?;
        if (out.len() - before) as u64 != want {
            return Err(format!(
                "zlib block {index} inflates to {} bytes, expected {want}",
                out.len() - before
            ));
        }
    }
    Ok(out)
}

/// Where binary data comes from: appended raw bytes, or base64 text.
enum Source<'a> {
    Raw(&'a [u8]),
    Base64(Base64<'a>),
}

impl Source<'_> {
    /// The next `n` bytes, refused (before allocating) if fewer remain.
    fn take(&mut self, n: usize) -> Result<Vec<u8>, String> {
        match self {
            Source::Raw(data) => {
                if n > data.len() {
                    return Err(format!("{n} bytes of data expected, {} remain", data.len()));
                }
                let (head, tail) = data.split_at(n);
                *data = tail;
                Ok(head.to_vec())
            }
            Source::Base64(b) => b.take(n),
        }
    }
}

/// A base64 stream, decoded four characters at a time so that blocks encoded one after
/// another (VTK encodes a header and its data separately, each padded) read as one.
struct Base64<'a> {
    text: &'a [u8],
    pending: Vec<u8>,
}

impl<'a> Base64<'a> {
    fn new(text: &'a [u8]) -> Self {
        Base64 {
            text,
            pending: Vec::new(),
        }
    }

    fn take(&mut self, n: usize) -> Result<Vec<u8>, String> {
        if n > self.text.len() / 4 * 3 + 3 + self.pending.len() {
            return Err(format!("{n} bytes expected, the base64 text holds fewer"));
        }
        let mut out = std::mem::take(&mut self.pending);
        out.reserve(n.saturating_sub(out.len()));
        while out.len() < n {
            let mut quad = [0u8; 4];
            let mut k = 0;
            while k < 4 {
                let Some((&c, rest)) = self.text.split_first() else {
                    break;
                };
                self.text = rest;
                if !c.is_ascii_whitespace() {
                    quad[k] = c;
                    k += 1;
                }
            }
            if k < 2 {
                return Err(format!("base64 data ends after {} of {n} bytes", out.len()));
            }
            decode_quad(&quad[..k], &mut out)?;
        }
        self.pending = out.split_off(n);
        Ok(out)
    }
}

/// Appends the bytes of 2 to 4 base64 characters (`=` padding ends them early).
fn decode_quad(quad: &[u8], out: &mut Vec<u8>) -> Result<(), String> {
    let mut bits = 0u32;
    let mut used = 0;
    for &c in quad {
        let v = match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' => 62,
            b'/' => 63,
            b'=' => break,
            _ => return Err(format!("`{}` is not a base64 character", c.escape_ascii())),
        };
        bits |= u32::from(v) << (18 - 6 * used);
        used += 1;
    }
    let bytes = bits.to_be_bytes();
    out.extend_from_slice(&bytes[1..1 + (used * 6 / 8)]);
    Ok(())
}

/// Decodes one number from its bytes (little-endian or not).
type Decode = fn(&[u8], bool) -> f64;

/// A VTK number type's size and its decoder (bytes, little-endian?) to f64.
fn number_type(name: &str) -> Option<(usize, Decode)> {
    fn int<const SIGNED: bool>(b: &[u8], little: bool) -> f64 {
        let mut wide = [0u8; 8];
        if little {
            wide[..b.len()].copy_from_slice(b);
            wide.reverse();
        } else {
            wide[8 - b.len()..].copy_from_slice(b);
        }
        let bits = u64::from_be_bytes(wide);
        let shift = 64 - 8 * b.len() as u32;
        if SIGNED {
            ((bits << shift) as i64 >> shift) as f64
        } else {
            bits as f64
        }
    }
    fn float(b: &[u8], little: bool) -> f64 {
        let u = decode_uint(b, little);
        match b.len() {
            4 => f32::from_bits(u as u32) as f64,
            _ => f64::from_bits(u),
        }
    }
    Some(match name {
        "Int8" | "Char" => (1, int::<true>),
        "UInt8" => (1, int::<false>),
        "Int16" => (2, int::<true>),
        "UInt16" => (2, int::<false>),
        "Int32" => (4, int::<true>),
        "UInt32" => (4, int::<false>),
        "Int64" => (8, int::<true>),
        "UInt64" => (8, int::<false>),
        "Float32" => (4, float),
        "Float64" => (8, float),
        _ => return None,
    })
}

fn decode_uint(b: &[u8], little: bool) -> u64 {
    let mut wide = [0u8; 8];
    if little {
        wide[..b.len()].copy_from_slice(b);
        u64::from_le_bytes(wide)
    } else {
        wide[8 - b.len()..].copy_from_slice(b);
        u64::from_be_bytes(wide)
    }
}

/// The file without its `<AppendedData>` payload (kept aside: raw bytes are not XML), and
/// the payload after its `_` marker with whether it is base64.
#[allow(clippy::type_complexity)]
fn split_appended(bytes: &[u8]) -> Result<(Vec<u8>, Option<(&[u8], bool)>), String> {
    let Some(start) = find(bytes, b"<AppendedData") else {
        return Ok((bytes.to_vec(), None));
    };
    let open_end =
        start + find(&bytes[start..], b">").ok_or("<AppendedData> is never closed with `>`")?;
    let tag = String::from_utf8_lossy(&bytes[start..open_end]);
    let base64 = !tag.contains("raw");
    let marker = open_end
        + find(&bytes[open_end..], b"_").ok_or("<AppendedData> has no `_` before its data")?;
    let end = bytes
        .windows(15)
        .rposition(|w| w == b"</AppendedData>")
        .filter(|&e| e > marker)
        .unwrap_or(bytes.len());
    let mut xml = bytes[..marker].to_vec();
    xml.extend_from_slice(&bytes[end..]);
    let mut data = &bytes[marker + 1..end];
    if base64 {
        data = data.trim_ascii();
    }
    Ok((xml, Some((data, base64))))
}

fn find(haystack: &[u8], needle: &[u8]) -> Option<usize> {
    haystack.windows(needle.len()).position(|w| w == needle)
}

/// The element tree of `xml` (`file` only for the line of a syntax error).
fn tree(xml: &[u8], file: &[u8]) -> Result<Vec<Element>, String> {
    let mut reader = quick_xml::Reader::from_reader(xml);
    let mut elements: Vec<Element> = Vec::new();
    let mut stack: Vec<usize> = Vec::new();
    let line_of = |offset: u64| {
        let end = (offset as usize).min(file.len());
        1 + file[..end].iter().filter(|&&b| b == b'\n').count()
    };
    loop {
        let event = reader.read_event().map_err(|e| {
            let line = line_of(reader.error_position());
            format!("line {line}: not well-formed XML: {e}")
        })?;
        let offset = reader.buffer_position() as usize;
        match event {
            Event::Start(e) | Event::Empty(e) if stack.is_empty() && !elements.is_empty() => {
                let name = String::from_utf8_lossy(e.name().as_ref()).into_owned();
                return Err(format!(
                    "line {}: <{name}> after the root element",
                    line_of(offset as u64)
                ));
            }
            Event::Start(e) => {
                stack.push(push(&mut elements, &stack, &e, offset)?);
            }
            Event::Empty(e) => {
                push(&mut elements, &stack, &e, offset)?;
            }
            Event::End(_) => {
                stack.pop();
            }
            Event::Text(t) => {
                if let Some(&top) = stack.last() {
                    elements[top].text.push_str(&String::from_utf8_lossy(&t));
                }
            }
            Event::CData(t) => {
                if let Some(&top) = stack.last() {
                    elements[top].text.push_str(&String::from_utf8_lossy(&t));
                }
            }
            Event::Eof => break,
            _ => {}
        }
    }
    Ok(elements)
}

/// Adds element `e` under the top of `stack`; its index.
fn push(
    elements: &mut Vec<Element>,
    stack: &[usize],
    e: &BytesStart,
    offset: usize,
) -> Result<usize, String> {
    let mut attrs = Vec::new();
    for a in e.attributes() {
        let a = a.map_err(|err| format!("an attribute: {err}"))?;
        attrs.push((
            String::from_utf8_lossy(a.key.as_ref()).into_owned(),
            String::from_utf8_lossy(&a.value).into_owned(),
        ));
    }
    let id = elements.len();
    elements.push(Element {
        name: String::from_utf8_lossy(e.name().as_ref()).into_owned(),
        attrs,
        text: String::new(),
        children: Vec::new(),
        offset,
    });
    if let Some(&parent) = stack.last() {
        elements[parent].children.push(id);
    }
    Ok(id)
}

/// The surface of a PolyData (`.vtp`) or UnstructuredGrid (`.vtu`) file, all its pieces.
pub(crate) fn surface(bytes: &[u8]) -> Result<Mesh, String> {
    let doc = Document::parse(bytes)?;
    let kind = doc.kind().to_string();
    if kind != "PolyData" && kind != "UnstructuredGrid" {
        return Err(format!(
            "{}: type \"{kind}\" is not a surface (PolyData or UnstructuredGrid; ImageData \
             loads from a .vti file as a volume)",
            doc.at(0)
        ));
    }
    let dataset = doc.child(0, &kind)?;
    let mut surface = Surface::default();
    for piece in doc.children(dataset, "Piece") {
        let base = surface.point_count() as i64;
        let points = doc.count(piece, "NumberOfPoints", None)?;
        if points > 0 {
            let array = doc.child(doc.child(piece, "Points")?, "DataArray")?;
            let xyz = doc.values(array, points.saturating_mul(3), |v| v)?;
            surface.add_points(&xyz, &doc.at(array))?;
        }
        let sections: &[(&str, &str, i64)] = if kind == "PolyData" {
            &[
                ("Polys", "NumberOfPolys", cell::POLYGON),
                ("Strips", "NumberOfStrips", cell::TRIANGLE_STRIP),
            ]
        } else {
            &[("Cells", "NumberOfCells", 0)]
        };
        for &(section, count_name, kind) in sections {
            let count = doc.count(piece, count_name, Some(0))?;
            if count > 0 {
                let section = doc.child(piece, section)?;
                cells(&doc, section, count, kind, base, &mut surface)?;
            }
        }
    }
    Ok(surface.finish("VTK XML file"))
}

/// Adds the `count` cells of `section` (`<Polys>`, `<Strips>` or `<Cells>`, the last with
/// its own `types`; `kind` the others' cell type), their ids offset by `base`.
fn cells(
    doc: &Document,
    section: Id,
    count: usize,
    kind: i64,
    base: i64,
    surface: &mut Surface,
) -> Result<(), String> {
    let offsets_id = doc.array_named(section, "offsets")?;
    let offsets = integers(&doc.values(offsets_id, count, |v| v)?, "offsets")
        .map_err(|e| format!("{}: {e}", doc.at(offsets_id)))?;
    let ids_id = doc.array_named(section, "connectivity")?;
    let total = offsets.last().copied().unwrap_or(0).max(0) as usize;
    let ids = integers(&doc.values(ids_id, total, |v| v)?, "connectivity")
        .map_err(|e| format!("{}: {e}", doc.at(ids_id)))?;
    let ranges =
        cell_ranges(&offsets, ids.len()).map_err(|e| format!("{}: {e}", doc.at(offsets_id)))?;
    let types = if kind == 0 {
        let types_id = doc.array_named(section, "types")?;
        integers(&doc.values(types_id, count, |v| v)?, "types")
            .map_err(|e| format!("{}: {e}", doc.at(types_id)))?
    } else {
        vec![kind; count]
    };
    let mut cell_ids = Vec::new();
    for (index, (range, kind)) in ranges.into_iter().zip(types).enumerate() {
        cell_ids.clear();
        cell_ids.extend(ids[range].iter().map(|&v| v.saturating_add(base)));
        surface
            .add_cell(index, kind, &cell_ids)
            .map_err(|e| format!("{}: {e}", doc.at(ids_id)))?;
    }
    Ok(())
}
