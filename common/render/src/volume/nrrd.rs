//! NRRD (Teem's "nearly raw raster data"): a text header of `field: value` lines up to a blank
//! line, then the voxels, or a `data file:` the header names (a detached `.nhdr`). Read here:
//! 3-D scalar data of type u8, i16, u16 or f32, `raw` or `gzip` encoding, either byte order,
//! placed by `space directions` and `space origin` (any three independent axes), or by
//! `spacings`.

use super::{axis_aligned, decode_exact, little_endian, Volume, VolumeError, VoxelType};
use std::collections::HashMap;
use std::io::Read;
use std::path::Path;

/// Loads a `.nrrd` or `.nhdr` file.
pub(super) fn load(path: &Path) -> Result<Volume, VolumeError> {
    let file = std::fs::read(path).map_err(|e| VolumeError::io(path, e))?;
    let (fields, body) = split_header(path, &file)?;
    let get = |name: &str| fields.get(name).map(String::as_str);
    let need = |name: &str| get(name).ok_or_else(|| VolumeError::field(path, name, "missing"));

    let voxel_type = parse_type(path, need("type")?)?;
    if need("dimension")?.trim() != "3" {
        return Err(VolumeError::field(
            path,
            "dimension",
            format!("{} (only 3-D scalar volumes are read)", need("dimension")?),
        ));
    }
    let sizes = parse_numbers::<usize>(path, "sizes", need("sizes")?)?;
    let dims: [usize; 3] = sizes
        .try_into()
        .map_err(|_| VolumeError::field(path, "sizes", "must list 3 sizes"))?;
    let little_endian = little_endian(path, get("endian"))?;
    let (axes, origin) = placement(path, &fields)?;

    let encoded = match get("data file").or(get("datafile")) {
        Some(name) => {
            let data_path = path.parent().unwrap_or(Path::new(".")).join(name.trim());
            std::fs::read(&data_path).map_err(|e| VolumeError::io(&data_path, e))?
        }
        None => body.to_vec(),
    };
    let bytes = match need("encoding")?.trim() {
        "raw" => encoded,
        "gzip" | "gz" => {
            let mut out = Vec::new();
            flate2::read::MultiGzDecoder::new(&encoded[..])
                .read_to_end(&mut out)
                .map_err(|e| VolumeError::field(path, "encoding", format!("gzip data: {e}")))?;
            out
        }
        other => {
            return Err(VolumeError::field(
                path,
                "encoding",
                format!("{other:?} (raw and gzip are read)"),
            ))
        }
    };
    let values = decode_exact(path, &bytes, dims, voxel_type, little_endian)?;
    let volume = Volume::checked(path, dims, axes, origin, voxel_type, values)?;
    // Every anatomical space NRRD names (RAS, LPS, LAS, or spelt out, ending in "superior")
    // puts superior at +z.
    let anatomical = fields.get("space").is_some_and(|s| {
        let s = s.trim().to_ascii_lowercase();
        s.ends_with("superior") || matches!(s.as_str(), "ras" | "lps" | "las")
    });
    Ok(if anatomical {
        volume.with_up(glam::Vec3::Z)
    } else {
        volume
    })
}

/// The voxel count an NRRD header declares, read from the start of the file only (the
/// header ends within its first 64 KiB or it is not read): what a load will hold, known
/// before it allocates.
pub(super) fn declared_voxels(path: &Path) -> Option<u64> {
    use std::io::Read as _;
    let mut head = Vec::new();
    std::fs::File::open(path)
        .ok()?
        .take(64 << 10)
        .read_to_end(&mut head)
        .ok()?;
    let (fields, _) = split_header(path, &head).ok()?;
    let sizes = parse_numbers::<u64>(path, "sizes", fields.get("sizes")?).ok()?;
    sizes.iter().try_fold(1u64, |n, &s| n.checked_mul(s))
}

/// The header's fields (names lower-cased) and the bytes after the blank line that ends it.
fn split_header<'a>(
    path: &Path,
    file: &'a [u8],
) -> Result<(HashMap<String, String>, &'a [u8]), VolumeError> {
    if !file.starts_with(b"NRRD000") {
        return Err(VolumeError::field(
            path,
            "magic",
            "the file does not start with NRRD000x",
        ));
    }
    let mut fields = HashMap::new();
    let mut at = 0;
    let mut first = true;
    loop {
        let Some(end) = file[at..].iter().position(|&b| b == b'\n') else {
            // A header with no blank line: the data must be in a detached file.
            return Ok((fields, &file[file.len()..]));
        };
        let line = std::str::from_utf8(&file[at..at + end])
            .map_err(|_| VolumeError::field(path, "header", "a header line is not UTF-8"))?
            .trim_end_matches('\r');
        at += end + 1;
        if first {
            first = false;
            continue;
        }
        if line.is_empty() {
            return Ok((fields, &file[at..]));
        }
        if line.starts_with('#') || line.contains(":=") {
            continue;
        }
        let (name, value) = line.split_once(": ").ok_or_else(|| {
            VolumeError::field(path, "header", format!("{line:?} is not `field: value`"))
        })?;
        fields.insert(name.trim().to_ascii_lowercase(), value.to_string());
    }
}

fn parse_type(path: &Path, name: &str) -> Result<VoxelType, VolumeError> {
    Ok(match name.trim() {
        "uchar" | "unsigned char" | "uint8" | "uint8_t" => VoxelType::U8,
        "short" | "short int" | "signed short" | "signed short int" | "int16" | "int16_t" => {
            VoxelType::I16
        }
        "ushort" | "unsigned short" | "unsigned short int" | "uint16" | "uint16_t" => {
            VoxelType::U16
        }
        "float" => VoxelType::F32,
        other => {
            return Err(VolumeError::field(
                path,
                "type",
                format!("{other:?} (u8, i16, u16 and float are read)"),
            ))
        }
    })
}

fn parse_numbers<T: std::str::FromStr>(
    path: &Path,
    field: &str,
    value: &str,
) -> Result<Vec<T>, VolumeError> {
    value
        .split_whitespace()
        .map(|v| {
            v.parse()
                .map_err(|_| VolumeError::field(path, field, format!("{v:?} is not a number")))
        })
        .collect()
}

/// The voxel axes and origin from `space directions` and `space origin`, or from `spacings`.
fn placement(
    path: &Path,
    fields: &HashMap<String, String>,
) -> Result<([[f64; 3]; 3], [f64; 3]), VolumeError> {
    let origin = match fields.get("space origin") {
        Some(v) => vector(path, "space origin", v)?,
        None => [0.0; 3],
    };
    if let Some(directions) = fields.get("space directions") {
        let vectors: Vec<[f64; 3]> = directions
            .split_whitespace()
            .map(|v| vector(path, "space directions", v))
            .collect::<Result<_, _>>()?;
        let axes = vectors
            .try_into()
            .map_err(|_| VolumeError::field(path, "space directions", "must give 3 vectors"))?;
        return Ok((axes, origin));
    }
    let spacing: [f64; 3] = match fields.get("spacings") {
        Some(v) => parse_numbers::<f64>(path, "spacings", v)?
            .try_into()
            .map_err(|_| VolumeError::field(path, "spacings", "must list 3 spacings"))?,
        None => [1.0; 3],
    };
    Ok((axis_aligned(path, "spacings", spacing)?, origin))
}

/// A vector written `(x,y,z)`.
fn vector(path: &Path, field: &str, text: &str) -> Result<[f64; 3], VolumeError> {
    let inner = text
        .trim()
        .strip_prefix('(')
        .and_then(|t| t.strip_suffix(')'))
        .ok_or_else(|| VolumeError::field(path, field, format!("{text:?} is not (x,y,z)")))?;
    let numbers = parse_numbers::<f64>(path, field, &inner.replace(',', " "))?;
    numbers
        .try_into()
        .map_err(|_| VolumeError::field(path, field, format!("{text:?} is not (x,y,z)")))
}
