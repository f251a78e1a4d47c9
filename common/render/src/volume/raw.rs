//! Raw voxels described by a sidecar: `NAME.vol.toml` names the data file and says how to
//! read it.
//!
//! ```toml
//! data = "head.raw"        # relative to the sidecar
//! dims = [256, 256, 113]   # x, y, z
//! type = "i16"             # u8, i16, u16 or f32
//! spacing = [0.9, 0.9, 2.0]  # world units per voxel step (default 1, 1, 1)
//! origin = [0.0, 0.0, 0.0]   # world position of voxel (0, 0, 0) (default 0)
//! endian = "little"        # or "big" (default little)
//! up = [0.0, 0.0, 1.0]     # the world's up, e.g. a CT's superior (default: none, +y)
//! ```

use super::{axis_aligned, decode_exact, little_endian, Volume, VolumeError, VoxelType};
use serde::Deserialize;
use std::path::Path;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Sidecar {
    data: String,
    dims: [usize; 3],
    #[serde(rename = "type")]
    voxel_type: String,
    spacing: Option<[f64; 3]>,
    origin: Option<[f64; 3]>,
    endian: Option<String>,
    up: Option<[f32; 3]>,
}

/// The voxel count a sidecar declares, before its data is read.
pub(super) fn declared_voxels(path: &Path) -> Option<u64> {
    let text = std::fs::read_to_string(path).ok()?;
    let sidecar: Sidecar = toml::from_str(&text).ok()?;
    sidecar
        .dims
        .iter()
        .try_fold(1u64, |n, &d| n.checked_mul(d as u64))
}

/// Loads the volume a `.vol.toml` sidecar describes.
pub(super) fn load(path: &Path) -> Result<Volume, VolumeError> {
    let text = std::fs::read_to_string(path).map_err(|e| VolumeError::io(path, e))?;
    let sidecar: Sidecar = toml::from_str(&text).map_err(|e| {
        let field = e
            .message()
            .split('`')
            .nth(1)
            .unwrap_or("sidecar")
            .to_string();
        VolumeError::field(path, &field, e.message().to_string())
    })?;
    let voxel_type = match sidecar.voxel_type.as_str() {
        "u8" => VoxelType::U8,
        "i16" => VoxelType::I16,
        "u16" => VoxelType::U16,
        "f32" => VoxelType::F32,
        other => {
            return Err(VolumeError::field(
                path,
                "type",
                format!("{other:?} (u8, i16, u16 or f32)"),
            ))
        }
    };
    let little_endian = little_endian(path, sidecar.endian.as_deref())?;
    let data_path = path.parent().unwrap_or(Path::new(".")).join(&sidecar.data);
    let bytes = std::fs::read(&data_path).map_err(|e| VolumeError::io(&data_path, e))?;
    let values = decode_exact(&data_path, &bytes, sidecar.dims, voxel_type, little_endian)?;
    let axes = axis_aligned(path, "spacing", sidecar.spacing.unwrap_or([1.0; 3]))?;
    let volume = Volume::checked(
        path,
        sidecar.dims,
        axes,
        sidecar.origin.unwrap_or([0.0; 3]),
        voxel_type,
        values,
    )?;
    match sidecar.up.map(glam::Vec3::from_array) {
        None => Ok(volume),
        Some(up) if up.is_finite() && up != glam::Vec3::ZERO => Ok(volume.with_up(up)),
        Some(up) => Err(VolumeError::field(
            path,
            "up",
            format!("{:?} is not a direction", up.to_array()),
        )),
    }
}
