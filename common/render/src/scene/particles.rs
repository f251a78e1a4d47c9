//! Particle files: spheres, each with one scalar attribute (for colour mapping), as CSV or the
//! binary `.tpart` format. Both are specified in `docs/particles.md`; keep the two in step.
//!
//! Centres are read in f64 ([`WorldParticle`]) and only rounded to f32 once they are moved
//! near the render frame's origin ([`place`]): at 10⁶ from the origin f32 steps are 0.0625,
//! coarser than the spheres of many a simulation.

use super::files::file_error;
use super::SceneError;
use glam::{DVec3, Vec3};
use std::io::{BufRead, BufReader, BufWriter, Read, Write};
use std::path::Path;
use tessera_model::local_origin::RenderFromWorld;

/// One sphere and its scalar attribute; plain bytes, so that particles can be shared as blocks
/// (`crate::dsm::layout`).
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct Particle {
    /// The centre: world coordinates as the file gives it, render coordinates in a
    /// [`Scene`](super::Scene).
    pub center: Vec3,
    /// The radius, in the same units; positive.
    pub radius: f32,
    /// The scalar the sphere is coloured by, through a colour map over the scene's range of it.
    pub attribute: f32,
}

/// One sphere as a file gives it: its centre in world coordinates, in f64.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WorldParticle {
    /// The centre, in world coordinates.
    pub center: DVec3,
    /// The radius; positive.
    pub radius: f32,
    /// The scalar the sphere is coloured by; NaN (or ±infinity) is missing data, drawn in the
    /// missing-data colour.
    pub attribute: f32,
}

impl From<Particle> for WorldParticle {
    fn from(p: Particle) -> Self {
        WorldParticle {
            center: p.center.as_dvec3(),
            radius: p.radius,
            attribute: p.attribute,
        }
    }
}

/// The frame centred on `particles` (see [`RenderFromWorld::centred_on`]).
pub fn frame_of(particles: &[WorldParticle]) -> RenderFromWorld {
    let centers: Vec<DVec3> = particles.iter().map(|p| p.center).collect();
    RenderFromWorld::centred_on(&centers)
}

/// `particles` in the render frame `frame`: each centre moved in f64, then rounded.
pub fn place(particles: &[WorldParticle], frame: RenderFromWorld) -> Vec<Particle> {
    let placed = particles.iter().map(|p| Particle {
        center: frame.point(p.center),
        radius: p.radius,
        attribute: p.attribute,
    });
    placed.collect()
}

/// Record fields in `.tpart` order.
const FIELDS: [&str; 5] = ["x", "y", "z", "radius", "attribute"];
const MAGIC: &[u8; 4] = b"TPRT";
/// Version 1: records of five f32, centres as they are. Version 2: the same records, centres
/// relative to an f64 origin in the header (so that far data keeps its precision).
const VERSION: u32 = 2;
/// Magic, version and count; version 2 adds the origin, three f64.
const HEADER_BYTES: u64 = 16;
const ORIGIN_BYTES: u64 = 24;
const RECORD_BYTES: u64 = 20;

/// Why field `field` (an index into [`FIELDS`]) holding `value` is unusable, if it is. A
/// missing attribute (NaN, ±infinity) is not: it is drawn in the missing-data colour.
fn check_field(field: usize, value: f64) -> Result<(), String> {
    let single = value as f32;
    if field == 4 {
        Ok(())
    } else if !single.is_finite() {
        Err(format!("{} {single} is not finite", FIELDS[field]))
    } else if field == 3 && value <= 0.0 {
        Err(format!("radius {value} is not positive"))
    } else {
        Ok(())
    }
}

/// A particle from its fields in [`FIELDS`] order, the centre's `origin` added in f64.
fn from_fields(origin: DVec3, [x, y, z, radius, attribute]: [f64; 5]) -> WorldParticle {
    WorldParticle {
        center: origin + DVec3::new(x, y, z),
        radius: radius as f32,
        // Infinities (and what f32 cannot hold) are missing too: one NaN for all of them.
        attribute: Some(attribute as f32)
            .filter(|a| a.is_finite())
            .unwrap_or(f32::NAN),
    }
}

/// Whether `path` names a particle file (`.csv` or `.tpart`) rather than a mesh.
pub fn is_particle_file(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("csv") || e.eq_ignore_ascii_case("tpart"))
}

/// Reads a `.csv` or `.tpart` particle file, centres in f64. The result may be empty.
///
/// # Errors
/// A [`SceneError`] naming the file and the line and column (CSV) or record (`.tpart`) at fault.
pub fn load_particles(path: &Path) -> Result<Vec<WorldParticle>, SceneError> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    let file = || std::fs::File::open(path).map_err(|e| file_error(path, e));
    let loaded = match ext.as_deref() {
        Some("csv") => read_csv(BufReader::new(file()?)),
        Some("tpart") => {
            let file = file()?;
            let size = file.metadata().map(|m| m.len()).ok();
            read_tpart(BufReader::new(file), size)
        }
        _ => Err("unsupported particle file extension (expected .csv or .tpart)".into()),
    };
    loaded.map_err(|message| file_error(path, message))
}

/// Writes particles as `.tpart` (version 2, origin 0), as they are: no validation, so tests
/// can write bad files.
pub fn write_tpart(path: &Path, particles: &[Particle]) -> std::io::Result<()> {
    write_tpart_at(path, DVec3::ZERO, particles)
}

/// Writes particles whose centres are relative to the world point `origin` as `.tpart`
/// (version 2): data far from the world's origin keeps its precision.
pub fn write_tpart_at(path: &Path, origin: DVec3, particles: &[Particle]) -> std::io::Result<()> {
    let mut out = BufWriter::new(std::fs::File::create(path)?);
    out.write_all(MAGIC)?;
    out.write_all(&VERSION.to_le_bytes())?;
    out.write_all(&(particles.len() as u64).to_le_bytes())?;
    for o in origin.to_array() {
        out.write_all(&o.to_le_bytes())?;
    }
    for p in particles {
        let Vec3 { x, y, z } = p.center;
        for value in [x, y, z, p.radius, p.attribute] {
            out.write_all(&value.to_le_bytes())?;
        }
    }
    out.flush()
}

fn read_csv(reader: impl BufRead) -> Result<Vec<WorldParticle>, String> {
    // Column of each of FIELDS (radius and attribute may be absent), and the header's width,
    // once the header is read.
    let mut header: Option<([Option<usize>; 5], usize)> = None;
    let mut particles = Vec::new();
    // Lines are split as bytes so that a non-UTF-8 line still gets its number.
    for (n, line) in reader.split(b'\n').enumerate() {
        let number = n + 1;
        let line = line.map_err(|e| format!("line {number}: {e}"))?;
        let text = std::str::from_utf8(&line).map_err(|_| format!("line {number}: not UTF-8"))?;
        // Spreadsheets write a byte-order mark and CRLF line ends.
        let text = text.strip_prefix('\u{feff}').unwrap_or(text).trim();
        if text.is_empty() || text.starts_with('#') {
            continue;
        }
        let cells = text.split(',').map(str::trim);
        let Some((columns, width)) = header else {
            header = Some(read_header(cells.collect(), number)?);
            continue;
        };
        let mut fields = [0f64; 5];
        let mut found = 0;
        for (column, cell) in cells.enumerate() {
            found += 1;
            let Some(field) = columns.iter().position(|&c| c == Some(column)) else {
                continue;
            };
            let at = || format!("line {number}, column {} ({})", column + 1, FIELDS[field]);
            let value: f64 = cell
                .parse()
                .map_err(|_| format!("{}: `{cell}` is not a number", at()))?;
            check_field(field, value).map_err(|why| format!("{}: {why}", at()))?;
            fields[field] = value;
        }
        if found != width {
            return Err(format!(
                "line {number}: {found} columns, but the header has {width}"
            ));
        }
        // A point cloud: the height is the attribute, the spacing sizes the spheres (below).
        if columns[4].is_none() {
            fields[4] = fields[1];
        }
        if columns[3].is_none() {
            fields[3] = 1.0;
        }
        particles.push(from_fields(DVec3::ZERO, fields));
    }
    let Some((columns, _)) = header else {
        return Err(format!(
            "no header line: expected columns {} (radius and attribute optional)",
            FIELDS.join(",")
        ));
    };
    if columns[3].is_none() {
        let centres: Vec<DVec3> = particles.iter().map(|p| p.center).collect();
        let radius = super::points::spacing_radius(&centres);
        particles.iter_mut().for_each(|p| p.radius = radius);
    }
    Ok(particles)
}

/// Finds each of [`FIELDS`] among the header's column names, ignoring case; `radius` and
/// `attribute` may be absent (a point cloud: see [`super::points`]).
fn read_header(names: Vec<&str>, number: usize) -> Result<([Option<usize>; 5], usize), String> {
    let mut columns = [None; 5];
    for (index, (field, column)) in FIELDS.iter().zip(&mut columns).enumerate() {
        let mut matches = names
            .iter()
            .enumerate()
            .filter(|(_, name)| name.eq_ignore_ascii_case(field))
            .map(|(c, _)| c);
        *column = matches.next();
        if column.is_none() && index < 3 {
            return Err(format!(
                "line {number}: header has no `{field}` column (has: {}); \
                 the first line must name the columns",
                names.join(",")
            ));
        }
        if let (Some(first), Some(again)) = (*column, matches.next()) {
            return Err(format!(
                "line {number}: header names `{field}` twice (columns {} and {})",
                first + 1,
                again + 1
            ));
        }
    }
    Ok((columns, names.len()))
}

/// Reads a `.tpart` header: the record count, the origin the centres are relative to, and
/// the header's length.
fn read_tpart_header(reader: &mut impl Read) -> Result<(u64, DVec3, u64), String> {
    let mut header = [0u8; HEADER_BYTES as usize];
    read_full(reader, &mut header).map_err(|got| {
        format!("truncated header: {got} bytes, a .tpart header is {HEADER_BYTES}")
    })?;
    if &header[..4] != MAGIC {
        return Err(format!(
            "bad magic \"{}\" (expected \"TPRT\"): not a .tpart file",
            header[..4].escape_ascii()
        ));
    }
    let version = u32::from_le_bytes([header[4], header[5], header[6], header[7]]);
    let mut count = [0u8; 8];
    count.copy_from_slice(&header[8..]);
    let count = u64::from_le_bytes(count);
    match version {
        1 => Ok((count, DVec3::ZERO, HEADER_BYTES)),
        2 => {
            let mut origin = [0u8; ORIGIN_BYTES as usize];
            read_full(reader, &mut origin).map_err(|got| {
                format!("truncated header: a version 2 header has a 24-byte origin, found {got}")
            })?;
            let axis = |a: usize| f64::from_le_bytes(origin[a * 8..a * 8 + 8].try_into().unwrap());
            let origin = DVec3::new(axis(0), axis(1), axis(2));
            if !origin.is_finite() {
                return Err(format!("origin {origin} is not finite"));
            }
            Ok((count, origin, HEADER_BYTES + ORIGIN_BYTES))
        }
        _ => Err(format!(
            ".tpart version {version} is not supported (only 1 and {VERSION})"
        )),
    }
}

/// Checks a record count against the file's `size` (`header` bytes of it the header's)
/// before it is trusted with an allocation.
fn check_count(count: u64, size: u64, header: u64) -> Result<(), String> {
    let body = size.saturating_sub(header);
    let (present, stray) = (body / RECORD_BYTES, body % RECORD_BYTES);
    // Twice the data there is cannot be a short copy: the header itself is corrupt.
    if count
        .checked_mul(RECORD_BYTES)
        .is_none_or(|bytes| bytes / 2 > body)
    {
        return Err(format!(
            "record count {count} is absurd for a file of {size} bytes \
             (room for {present} records): corrupt header?"
        ));
    }
    if count > present {
        return Err(format!(
            "truncated: expected {count} records, found {present} (and {stray} bytes more)"
        ));
    }
    if count < present || stray != 0 {
        return Err(format!(
            "{} bytes after the {count} records the header announces",
            body - count * RECORD_BYTES
        ));
    }
    Ok(())
}

/// Reads `.tpart` data; `size` is the file's length when known, to check the record count
/// before trusting it with an allocation.
fn read_tpart(mut reader: impl Read, size: Option<u64>) -> Result<Vec<WorldParticle>, String> {
    let (count, origin, header) = read_tpart_header(&mut reader)?;
    if let Some(size) = size {
        check_count(count, size, header)?;
    }
    let count = usize::try_from(count).map_err(|_| format!("{count} records is too many"))?;
    // Without a known size (a pipe), capacity grows with what actually arrives.
    let mut particles = Vec::new();
    // The count is the file's word: a failed reservation is an error, not an abort.
    if size.is_some() {
        particles.try_reserve_exact(count).map_err(|_| {
            format!(
                "cannot allocate {count} particles ({} bytes): not enough memory",
                count.saturating_mul(std::mem::size_of::<WorldParticle>())
            )
        })?;
    }
    let mut record = [0u8; RECORD_BYTES as usize];
    for index in 0..count {
        read_full(&mut reader, &mut record)
            .map_err(|_| format!("truncated: expected {count} records, found {index}"))?;
        let mut fields = [0f64; 5];
        for (field, (value, bytes)) in fields.iter_mut().zip(record.chunks_exact(4)).enumerate() {
            *value = f32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]) as f64;
            check_field(field, *value).map_err(|why| format!("record {index}: {why}"))?;
        }
        particles.push(from_fields(origin, fields));
    }
    Ok(particles)
}

/// Fills `buf`, or says how many bytes there were before the end (or a read error).
fn read_full(reader: &mut impl Read, buf: &mut [u8]) -> Result<(), usize> {
    let mut got = 0;
    while got < buf.len() {
        match reader.read(&mut buf[got..]) {
            Ok(0) => return Err(got),
            Ok(n) => got += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(_) => return Err(got),
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn particle(x: f32, radius: f32, attribute: f32) -> Particle {
        Particle {
            center: Vec3::new(x, -x, 2.0 * x),
            radius,
            attribute,
        }
    }

    /// Writes `bytes` as `name`, loads it, and returns the error, which must name the file.
    fn error_of(name: &str, bytes: &[u8]) -> String {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(name);
        std::fs::write(&path, bytes).unwrap();
        let err = load_particles(&path).unwrap_err().to_string();
        assert!(err.contains(name), "{err}");
        err
    }

    fn world(particles: &[Particle]) -> Vec<WorldParticle> {
        particles.iter().copied().map(WorldParticle::from).collect()
    }

    fn tpart_bytes(particles: &[Particle]) -> Vec<u8> {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("p.tpart");
        write_tpart(&path, particles).unwrap();
        std::fs::read(path).unwrap()
    }

    #[test]
    fn csv_columns_in_any_order_and_case() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("p.csv");
        let text = "\u{feff}# exported\r\nid, Radius,X,y,Z,temp,ATTRIBUTE\r\n\
                    7,0.5,1,-1,2,hot,3\r\n\r\n8, 1e-3 ,0,0,0,,-4.5\r\n";
        std::fs::write(&path, text).unwrap();
        let loaded = load_particles(&path).unwrap();
        let want = world(&[particle(1.0, 0.5, 3.0), particle(0.0, 1e-3, -4.5)]);
        assert_eq!(loaded, want);
        std::fs::write(&path, "x,y,z,radius,attribute\n").unwrap();
        assert_eq!(load_particles(&path).unwrap(), []);
    }

    #[test]
    fn tpart_round_trips() {
        let particles: Vec<_> = (0..1000)
            .map(|i| particle(i as f32 * 0.25, 1.0 + i as f32, -(i as f32)))
            .collect();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("p.TPART");
        write_tpart(&path, &particles).unwrap();
        assert_eq!(std::fs::metadata(&path).unwrap().len(), 40 + 20 * 1000);
        assert_eq!(load_particles(&path).unwrap(), world(&particles));
        write_tpart(&path, &[]).unwrap();
        assert_eq!(load_particles(&path).unwrap(), []);
    }

    #[test]
    fn csv_errors_name_line_and_column() {
        let head = "x,y,z,radius,attribute\n1,2,3,1,0\n";
        for (tail, want) in [
            (
                "1,2,oops,1,0\n",
                "line 3, column 3 (z): `oops` is not a number",
            ),
            ("NaN,2,3,1,0\n", "line 3, column 1 (x): x NaN is not finite"),
            ("1,inf,3,1,0\n", "line 3, column 2 (y): y inf is not finite"),
            (
                "1,2,3,1e39,0\n",
                "line 3, column 4 (radius): radius inf is not finite",
            ),
            (
                "1,2,3,0,0\n",
                "line 3, column 4 (radius): radius 0 is not positive",
            ),
            (
                "\n1,2,3,-1,0\n",
                "line 4, column 4 (radius): radius -1 is not positive",
            ),
            ("1,2,3,1\n", "line 3: 4 columns, but the header has 5"),
            ("1,2,3,1,0,\n", "line 3: 6 columns, but the header has 5"),
        ] {
            let err = error_of("bad.csv", format!("{head}{tail}").as_bytes());
            assert!(err.contains(want), "{tail:?}: {err}");
        }
        for (text, want) in [
            (
                "x,attribute,z\n",
                "line 1: header has no `y` column (has: x,attribute,z)",
            ),
            ("1,2,3,4,5\n", "line 1: header has no `x` column"),
            (
                "x,y,z,radius,X,attribute\n",
                "line 1: header names `x` twice (columns 1 and 5)",
            ),
            ("# nothing\n\n", "no header line"),
        ] {
            let err = error_of("head.csv", text.as_bytes());
            assert!(err.contains(want), "{text:?}: {err}");
        }
        let err = error_of("latin1.csv", b"x,y,z,radius,attribute\n# caf\xe9\n");
        assert!(err.contains("line 2: not UTF-8"), "{err}");
    }

    #[test]
    fn tpart_errors_name_the_record() {
        let good = tpart_bytes(&[particle(1.0, 1.0, 0.0); 3]);
        let mut bad_magic = good.clone();
        bad_magic[..4].copy_from_slice(b"PLY\n");
        let mut version = good.clone();
        version[4] = 3;
        let mut absurd = good.clone();
        absurd[8..16].copy_from_slice(&u64::MAX.to_le_bytes());
        let mut trailing = good.clone();
        trailing.extend([0; 5]);
        for (bytes, want) in [
            (&good[..10], "truncated header: 10 bytes"),
            (&bad_magic[..], "bad magic \"PLY\\n\""),
            (&version[..], "version 3 is not supported"),
            (
                &absurd[..],
                "record count 18446744073709551615 is absurd for a file of 100 bytes",
            ),
            (
                &good[..30],
                "a version 2 header has a 24-byte origin, found 14",
            ),
            (
                &good[..good.len() - 3],
                "truncated: expected 3 records, found 2 (and 17 bytes more)",
            ),
            (&trailing[..], "5 bytes after the 3 records"),
        ] {
            let err = error_of("bad.tpart", bytes);
            assert!(err.contains(want), "{want}: {err}");
        }
        for (p, want) in [
            (
                particle(f32::NAN, 1.0, 0.0),
                "record 2: x NaN is not finite",
            ),
            (
                particle(1.0, f32::INFINITY, 0.0),
                "record 2: radius inf is not finite",
            ),
            (
                particle(1.0, -0.5, 0.0),
                "record 2: radius -0.5 is not positive",
            ),
            (
                particle(1.0, 0.0, 0.0),
                "record 2: radius 0 is not positive",
            ),
        ] {
            let bytes = tpart_bytes(&[particle(0.0, 1.0, 0.0), particle(1.0, 2.0, 0.0), p]);
            let err = error_of("bad.tpart", &bytes);
            assert!(err.contains(want), "{want}: {err}");
        }
    }

    #[test]
    fn tpart_from_a_stream_of_unknown_size_is_checked_as_it_is_read() {
        let good = tpart_bytes(&[particle(1.0, 1.0, 0.0); 3]);
        assert_eq!(read_tpart(&good[..], None).unwrap().len(), 3);
        let err = read_tpart(&good[..good.len() - 1], None).unwrap_err();
        assert!(
            err.contains("truncated: expected 3 records, found 2"),
            "{err}"
        );
    }

    #[test]
    fn far_centres_keep_their_precision_and_missing_attributes_load() {
        let dir = tempfile::tempdir().unwrap();
        let origin = DVec3::splat(1e7);
        let near = [particle(0.001, 0.01, f32::NAN), particle(-0.003, 0.01, 2.0)];
        let path = dir.path().join("far.tpart");
        write_tpart_at(&path, origin, &near).unwrap();
        let far = load_particles(&path).unwrap();
        assert!(far[0].attribute.is_nan() && far[1].attribute == 2.0);
        let frame = frame_of(&far);
        let off = frame.world_origin - (origin + DVec3::new(-0.001, 0.001, -0.002));
        assert!(off.abs().max_element() < 1e-9, "{off}");
        let placed = place(&far, frame);
        // 0.004 apart at 10⁷ from the origin: f32 there would have merged them (steps of 1).
        let apart = (placed[0].center - placed[1].center).x;
        assert!((apart - 0.004).abs() < 1e-7, "{apart}");

        let csv = dir.path().join("far.csv");
        let text = "x,y,z,radius,attribute\n10000000.001,0,0,0.01,nan\n9999999.997,0,0,0.01,1\n";
        std::fs::write(&csv, text).unwrap();
        let far = load_particles(&csv).unwrap();
        let placed = place(&far, frame_of(&far));
        let apart = (placed[0].center - placed[1].center).x;
        assert!((apart - 0.004).abs() < 1e-6, "{apart}");
    }

    #[test]
    fn version_1_files_still_load() {
        let mut bytes = b"TPRT".to_vec();
        bytes.extend(1u32.to_le_bytes());
        bytes.extend(1u64.to_le_bytes());
        for v in [1f32, 2.0, 3.0, 0.5, 7.0] {
            bytes.extend(v.to_le_bytes());
        }
        let loaded = read_tpart(&bytes[..], Some(bytes.len() as u64)).unwrap();
        assert_eq!(
            loaded,
            world(&[Particle {
                center: Vec3::new(1.0, 2.0, 3.0),
                radius: 0.5,
                attribute: 7.0
            }])
        );
    }

    #[test]
    fn unknown_extension_is_an_error() {
        let err = error_of("p.xyz", b"");
        assert!(err.contains(".csv or .tpart"), "{err}");
    }
}
