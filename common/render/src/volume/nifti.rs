//! NIfTI-1 volumes (`.nii`, `.nii.gz`, or a `.hdr` with its `.img`), read with the `nifti`
//! crate and placed in the world as NIfTI viewers place them: by the sform when its code is set,
//! else by the qform (a rotation quaternion, pixel sizes and qfac), else by the pixel sizes
//! alone. `scl_slope` and `scl_inter` are applied, so CT values arrive in Hounsfield units.

use super::{Volume, VolumeError, VoxelType};
use nifti::{Endianness, NiftiObject, NiftiType, NiftiVolume, ReaderOptions};
use std::path::Path;

pub(super) fn load(path: &Path) -> Result<Volume, VolumeError> {
    let object = ReaderOptions::new().read_file(path).map_err(|e| match e {
        nifti::NiftiError::Io(source) => VolumeError::io(path, source),
        other => VolumeError::field(path, "header", other.to_string()),
    })?;
    let header = object.header().clone();
    let volume = object.into_volume();
    let dims = dims_of(path, volume.dim())?;
    let little = header.endianness == Endianness::Little;
    if volume.data_type() == NiftiType::Float64 {
        return load_f64(path, &header, dims, volume.raw_data(), little);
    }
    let (voxel_type, mut values) = decode(path, volume.data_type(), volume.raw_data(), little)?;
    if let Some((slope, inter)) = rescale(&header) {
        for v in &mut values {
            // In f32, as the samples are: the header's f32 round-trips through f64 exactly.
            *v = *v * slope as f32 + inter as f32;
        }
    }
    let (axes, origin) = placement(path, &header)?;
    Ok(in_patient_axes(
        &header,
        Volume::checked(path, dims, axes, origin, voxel_type, values)?,
    ))
}

/// A volume placed by its sform or qform is in RAS+ patient axes, where +z is superior: the
/// head is up, not the scanner table's side.
fn in_patient_axes(header: &nifti::NiftiHeader, volume: Volume) -> Volume {
    if header.sform_code > 0 || header.qform_code > 0 {
        volume.with_up(glam::Vec3::Z)
    } else {
        volume
    }
}

/// A volume of f64 samples: scaled into f32's range where they lie beyond it (see
/// [`super::narrow_f64`]), `scl_slope` and `scl_inter` applied in f64 first.
fn load_f64(
    path: &Path,
    header: &nifti::NiftiHeader,
    dims: [usize; 3],
    raw: &[u8],
    little: bool,
) -> Result<Volume, VolumeError> {
    let rescale = rescale(header);
    let values: Vec<f64> = raw
        .chunks_exact(8)
        .map(|b| {
            let bytes: [u8; 8] = b.try_into().expect("8 bytes");
            let v = if little {
                f64::from_le_bytes(bytes)
            } else {
                f64::from_be_bytes(bytes)
            };
            rescale.map_or(v, |(slope, inter)| v * slope + inter)
        })
        .collect();
    let (narrowed, exponent) = super::narrow_f64(&values);
    let (axes, origin) = placement(path, header)?;
    let volume = Volume::checked(path, dims, axes, origin, VoxelType::F32, narrowed)?;
    Ok(in_patient_axes(
        header,
        Volume {
            value_exponent: exponent,
            ..volume
        },
    ))
}

/// `scl_slope` and `scl_inter`, where they change the values (a slope of 0 means none).
fn rescale(header: &nifti::NiftiHeader) -> Option<(f64, f64)> {
    let (slope, inter) = (header.scl_slope as f64, header.scl_inter as f64);
    let applies = slope != 0.0 && slope.is_finite() && inter.is_finite();
    (applies && (slope, inter) != (1.0, 0.0)).then_some((slope, inter))
}

/// Three spatial dimensions; a fourth (time) of length 1 is allowed, a longer one is a series.
fn dims_of(path: &Path, dim: &[u16]) -> Result<[usize; 3], VolumeError> {
    // `get`, not `dim[3..]`: a 1-D or 2-D file has fewer than three (found by fuzzing).
    let time = dim.get(3..).unwrap_or_default();
    if dim.is_empty() || dim.len() > 4 || time.iter().any(|&d| d != 1) {
        return Err(VolumeError::field(
            path,
            "dim",
            format!("{dim:?}: a 3-D volume is expected (a time series is not one file's job)"),
        ));
    }
    Ok(std::array::from_fn(|a| {
        dim.get(a).copied().unwrap_or(1) as usize
    }))
}

/// The samples as f32, and the voxel type they are reported as (types outside u8, i16, u16
/// and f32 are widened or narrowed to f32 and reported as such).
fn decode(
    path: &Path,
    datatype: NiftiType,
    raw: &[u8],
    little: bool,
) -> Result<(VoxelType, Vec<f32>), VolumeError> {
    let native = match datatype {
        NiftiType::Uint8 => Some(VoxelType::U8),
        NiftiType::Int16 => Some(VoxelType::I16),
        NiftiType::Uint16 => Some(VoxelType::U16),
        NiftiType::Float32 => Some(VoxelType::F32),
        _ => None,
    };
    if let Some(t) = native {
        return Ok((t, t.decode(path, raw, little)?));
    }
    let word = |b: &[u8]| -> [u8; 8] {
        let mut w = [0u8; 8];
        w[..b.len()].copy_from_slice(b);
        if !little {
            w[..b.len()].reverse();
        }
        w
    };
    let (size, convert): (usize, fn([u8; 8]) -> f32) = match datatype {
        NiftiType::Int8 => (1, |w| w[0] as i8 as f32),
        NiftiType::Int32 => (4, |w| i32::from_le_bytes([w[0], w[1], w[2], w[3]]) as f32),
        NiftiType::Uint32 => (4, |w| u32::from_le_bytes([w[0], w[1], w[2], w[3]]) as f32),
        other => {
            return Err(VolumeError::field(
                path,
                "datatype",
                format!("{other:?} is not a scalar type this loader reads"),
            ))
        }
    };
    let values = raw.chunks_exact(size).map(|b| convert(word(b))).collect();
    Ok((VoxelType::F32, values))
}

/// The voxel axes (columns of the index-to-world map) and the origin.
fn placement(
    path: &Path,
    h: &nifti::NiftiHeader,
) -> Result<([[f64; 3]; 3], [f64; 3]), VolumeError> {
    if h.sform_code > 0 {
        let rows = [h.srow_x, h.srow_y, h.srow_z].map(|r| r.map(|v| v as f64));
        let axes = std::array::from_fn(|a| std::array::from_fn(|w| rows[w][a]));
        return Ok((axes, std::array::from_fn(|w| rows[w][3])));
    }
    let pixdim: [f64; 3] = std::array::from_fn(|a| h.pixdim[a + 1].abs() as f64);
    if !pixdim.iter().all(|p| p.is_finite() && *p > 0.0) {
        return Err(VolumeError::field(
            path,
            "pixdim",
            format!(
                "{:?}: voxel sizes must be finite and positive",
                &h.pixdim[1..4]
            ),
        ));
    }
    if h.qform_code > 0 {
        let (b, c, d) = (h.quatern_b as f64, h.quatern_c as f64, h.quatern_d as f64);
        let a = (1.0 - (b * b + c * c + d * d)).max(0.0).sqrt();
        let r = [
            [
                a * a + b * b - c * c - d * d,
                2.0 * (b * c - a * d),
                2.0 * (b * d + a * c),
            ],
            [
                2.0 * (b * c + a * d),
                a * a + c * c - b * b - d * d,
                2.0 * (c * d - a * b),
            ],
            [
                2.0 * (b * d - a * c),
                2.0 * (c * d + a * b),
                a * a + d * d - c * c - b * b,
            ],
        ];
        let qfac = if h.pixdim[0] < 0.0 { -1.0 } else { 1.0 };
        let scale = [pixdim[0], pixdim[1], pixdim[2] * qfac];
        let axes = std::array::from_fn(|a| std::array::from_fn(|w| r[w][a] * scale[a]));
        let origin = [h.quatern_x, h.quatern_y, h.quatern_z].map(|v| v as f64);
        return Ok((axes, origin));
    }
    let axes =
        std::array::from_fn(|a| std::array::from_fn(|w| if w == a { pixdim[a] } else { 0.0 }));
    Ok((axes, [0.0; 3]))
}
