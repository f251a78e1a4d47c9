//! Volumes of scalar samples on a regular grid, placed in the world by an affine map: the data
//! model that volume rendering and direct iso-surfaces (issue 11) start from, and its file
//! loaders, bricks and min/max grid ([`PreparedVolume`]), ray marching through a transfer
//! function with opacity correction, and direct iso-surfaces.
//!
//! Samples are kept as f32 whatever the file's voxel type (u8, i16, u16, f32), in x-fastest
//! order, with the file's own values (no rescaling). A NaN or infinite sample is missing data
//! (land in an ocean model, outside a simulation's domain): it is kept as NaN, which every
//! interpolation through it carries, so a sample of a cell that touches one is transparent and
//! no iso-surface crosses such a cell (the surface ends open at the cell's boundary). A file is read whole and checked before a
//! [`Volume`] exists: a bad header names the field, data cut short says how many bytes were
//! expected, and nothing half-loaded is ever returned.
//!
//! ```
//! use tessera_render::volume::{Volume, VoxelType};
//! let v = Volume::new([2, 1, 1], [0.5, 1.0, 1.0], [0.0; 3], VoxelType::U8, vec![0.0, 255.0])?;
//! assert_eq!(v.world_of_index([1.0, 0.0, 0.0]), [0.5, 0.0, 0.0]);
//! assert_eq!(v.range(), (0.0, 255.0));
//! # Ok::<(), tessera_render::volume::VolumeError>(())
//! ```

mod bricks;
mod cell_mask;
mod dicom;
mod dicom_lengths;
mod empty_space;
mod grid_walk;
mod nifti;
mod nrrd;
mod prepared;
mod raw;
mod series;
mod transfer;
mod vti;

pub use bricks::{
    BrickSource, Bricks, MinMaxGrid, Replicated, BRICK_CELLS, BRICK_SAMPLES, MACRO_CELLS,
};
pub use prepared::{
    FrameTables, Placement, PreparedVolume, SharedVolume, MIN_STEP_FRACTION, OPAQUE_ENOUGH,
};
pub use series::{SeriesCache, SeriesStats};
pub use transfer::{corrected_opacity, TransferTable};

use std::path::Path;

/// The voxel type a file stores.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VoxelType {
    /// Unsigned 8-bit integers.
    U8,
    /// Signed 16-bit integers.
    I16,
    /// Unsigned 16-bit integers.
    U16,
    /// 32-bit floats.
    F32,
}

impl VoxelType {
    /// Size of one voxel in the file, in bytes.
    pub fn bytes(self) -> usize {
        match self {
            VoxelType::U8 => 1,
            VoxelType::I16 | VoxelType::U16 => 2,
            VoxelType::F32 => 4,
        }
    }

    /// Decodes `bytes` (a whole number of voxels) in the given byte order.
    /// The samples of `bytes` (of the volume at `path`).
    ///
    /// # Errors
    /// Not the memory for them: the size is the file's word, so a failed reservation is
    /// refused, never an abort.
    fn decode(
        self,
        path: &Path,
        bytes: &[u8],
        little_endian: bool,
    ) -> Result<Vec<f32>, VolumeError> {
        let n = self.bytes();
        let count = bytes.len() / n;
        let mut values = Vec::new();
        values.try_reserve_exact(count).map_err(|_| {
            let message = format!("cannot allocate {count} samples as f32: not enough memory");
            VolumeError::field(path, "sizes", message)
        })?;
        let decoded = bytes.chunks_exact(n).map(|b| match (self, little_endian) {
            (VoxelType::U8, _) => b[0] as f32,
            (VoxelType::I16, true) => i16::from_le_bytes([b[0], b[1]]) as f32,
            (VoxelType::I16, false) => i16::from_be_bytes([b[0], b[1]]) as f32,
            (VoxelType::U16, true) => u16::from_le_bytes([b[0], b[1]]) as f32,
            (VoxelType::U16, false) => u16::from_be_bytes([b[0], b[1]]) as f32,
            (VoxelType::F32, true) => f32::from_le_bytes([b[0], b[1], b[2], b[3]]),
            (VoxelType::F32, false) => f32::from_be_bytes([b[0], b[1], b[2], b[3]]),
        });
        values.extend(decoded);
        Ok(values)
    }
}

/// Why a volume could not be loaded: each variant names the file, and the field where one is
/// at fault.
#[derive(Debug, thiserror::Error)]
pub enum VolumeError {
    /// The file (or a detached data file or slice it names) could not be read, or a time-series
    /// step failed to load.
    // `reason`, not `source`: a source is printed again by every error chain (anyhow's `{:#}`),
    // and the reason would be said twice.
    #[error("volume {path}: {reason}")]
    Io {
        /// The file as the user named it, or the one it refers to.
        path: String,
        /// The underlying error (for a time-series step that failed in the background, its
        /// message).
        reason: std::io::Error,
    },
    /// A header field is missing, malformed or out of range, or the data has a non-finite voxel
    /// (field `data`).
    #[error("volume {path}: field `{field}`: {message}")]
    Field {
        /// The file at fault.
        path: String,
        /// The header field at fault, by its name in the format (or `sizes`, `spacing`, `data`).
        field: String,
        /// What is wrong with it.
        message: String,
    },
    /// The voxel data is not as long as the header's sizes and type make it: cut short, or longer.
    #[error("volume {path}: {expected} bytes of voxel data expected, {found} found")]
    Truncated {
        /// The file at fault.
        path: String,
        /// Bytes of voxel data the header calls for.
        expected: usize,
        /// Bytes there are.
        found: usize,
    },
    /// The name is none of the volume formats and not a folder (a DICOM series).
    #[error(
        "volume {path}: unsupported extension (expected .nrrd, .nhdr, .nii, .nii.gz, .vti or .vol.toml)"
    )]
    UnknownFormat {
        /// The file as the user named it.
        path: String,
    },
}

impl VolumeError {
    fn field(path: &Path, field: &str, message: impl Into<String>) -> Self {
        VolumeError::Field {
            path: path.display().to_string(),
            field: field.to_string(),
            message: message.into(),
        }
    }

    fn io(path: &Path, reason: std::io::Error) -> Self {
        VolumeError::Io {
            path: path.display().to_string(),
            reason,
        }
    }
}

/// A grid of `dims` samples placed in the world by an affine map (f64): voxel `(i, j, k)` sits
/// at `origin + i·axes[0] + j·axes[1] + k·axes[2]`; values in x-fastest order.
#[derive(Clone, Debug, PartialEq)]
pub struct Volume {
    dims: [usize; 3],
    /// World step of one voxel along each index axis (the columns of the affine map).
    axes: [[f64; 3]; 3],
    origin: [f64; 3],
    voxel_type: VoxelType,
    values: Vec<f32>,
    range: (f32, f32),
    /// How many samples are missing data (NaN, as the file's NaN and infinities become).
    missing: usize,
    /// The samples are the file's times 2^this: 0 unless the file's f64 values lie beyond
    /// f32's range (see [`narrow_f64`]).
    value_exponent: i32,
    /// The world's up as the file gives it: +z (superior) for data in patient axes.
    up: Option<glam::Vec3>,
}

impl Volume {
    /// A grid aligned with the world's axes, `spacing` apart (world units), its voxel (0, 0, 0)
    /// at `origin`; `values` x fastest, `voxel_type` the type they were stored as.
    ///
    /// # Errors
    /// A dimension of 0, a spacing that is not finite and positive, an origin that is not
    /// finite, a value count other than the product of `dims`, or no value that is not
    /// missing data (NaN or infinite).
    pub fn new(
        dims: [usize; 3],
        spacing: [f64; 3],
        origin: [f64; 3],
        voxel_type: VoxelType,
        values: Vec<f32>,
    ) -> Result<Self, VolumeError> {
        let memory = Path::new("(memory)");
        let axes = axis_aligned(memory, "spacing", spacing)?;
        Self::checked(memory, dims, axes, origin, voxel_type, values)
    }

    /// Checks everything and makes the volume; `path` is only for the errors.
    fn checked(
        path: &Path,
        dims: [usize; 3],
        axes: [[f64; 3]; 3],
        origin: [f64; 3],
        voxel_type: VoxelType,
        mut values: Vec<f32>,
    ) -> Result<Self, VolumeError> {
        if dims.contains(&0) {
            return Err(VolumeError::field(
                path,
                "sizes",
                "every dimension must be at least 1",
            ));
        }
        let [a, b, c] = axes;
        let cross = [
            b[1] * c[2] - b[2] * c[1],
            b[2] * c[0] - b[0] * c[2],
            b[0] * c[1] - b[1] * c[0],
        ];
        let volume = a[0] * cross[0] + a[1] * cross[1] + a[2] * cross[2];
        if !(axes.iter().flatten().all(|v| v.is_finite()) && volume.abs() > 0.0) {
            return Err(VolumeError::field(
                path,
                "spacing",
                "the voxel axes must be finite and span 3-D space",
            ));
        }
        if !origin.iter().all(|o| o.is_finite()) {
            return Err(VolumeError::field(path, "origin", "must be finite"));
        }
        let count = voxel_count(path, dims)?;
        if values.len() != count {
            return Err(VolumeError::Truncated {
                path: path.display().to_string(),
                expected: count * voxel_type.bytes(),
                found: values.len() * voxel_type.bytes(),
            });
        }
        let missing = mark_missing(&mut values);
        if missing == count {
            return Err(VolumeError::field(
                path,
                "data",
                format!("every one of the {count} voxels is missing data (NaN or infinite)"),
            ));
        }
        let range = values
            .iter()
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &v| {
                (lo.min(v), hi.max(v))
            });
        Ok(Volume {
            dims,
            axes,
            origin,
            voxel_type,
            values,
            range,
            missing,
            value_exponent: 0,
            up: None,
        })
    }

    /// The samples are the file's values times 2 to this power: 0 unless the file held f64
    /// values beyond f32's range, which were scaled into it (iso-values and data-domain
    /// transfer points are then in those scaled units).
    pub fn value_exponent(&self) -> i32 {
        self.value_exponent
    }

    /// The world's up as the file said (`None`: the file gives no anatomy or up).
    pub fn up(&self) -> Option<glam::Vec3> {
        self.up
    }

    /// The same volume, whose file says which way is up in its world (a patient's superior, +z
    /// in both RAS and LPS).
    pub fn with_up(self, up: glam::Vec3) -> Volume {
        Volume {
            up: Some(up),
            ..self
        }
    }

    /// This volume with every length multiplied by `extent`, then moved by `offset`, and every
    /// value multiplied by `values` (missing ones stay missing): the stiff cases of
    /// [`crate::stiff`].
    pub fn scaled(&self, extent: f64, offset: [f64; 3], values: f32) -> Volume {
        let scaled: Vec<f32> = self.values.iter().map(|v| v * values).collect();
        let range = scaled
            .iter()
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &v| {
                (lo.min(v), hi.max(v))
            });
        // Field by field: `..self.clone()` would copy every sample only to drop them.
        Volume {
            dims: self.dims,
            axes: self.axes.map(|a| a.map(|c| c * extent)),
            origin: std::array::from_fn(|w| self.origin[w] * extent + offset[w]),
            voxel_type: self.voxel_type,
            values: scaled,
            range,
            missing: self.missing,
            value_exponent: self.value_exponent,
            up: self.up,
        }
    }

    /// How many samples are missing data (NaN or infinite in the file).
    pub fn missing(&self) -> usize {
        self.missing
    }

    /// The first missing sample (index, as [`Volume::values`] orders them), for a refusal.
    pub fn first_missing(&self) -> Option<usize> {
        if self.missing == 0 {
            return None;
        }
        self.values.iter().position(|v| v.is_nan())
    }

    /// Samples along each index axis, x first.
    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }

    /// Distance between neighbouring voxels along each index axis.
    pub fn spacing(&self) -> [f64; 3] {
        self.axes
            .map(|v| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt())
    }

    /// World step of one voxel along each index axis.
    pub fn axes(&self) -> [[f64; 3]; 3] {
        self.axes
    }

    /// World position of voxel (0, 0, 0).
    pub fn origin(&self) -> [f64; 3] {
        self.origin
    }

    /// The type the file stored the samples as (they are held as f32 whatever it is).
    pub fn voxel_type(&self) -> VoxelType {
        self.voxel_type
    }

    /// The samples, x fastest.
    pub fn values(&self) -> &[f32] {
        &self.values
    }

    /// Smallest and largest sample that is not missing.
    pub fn range(&self) -> (f32, f32) {
        self.range
    }

    /// The sample at grid index `(x, y, z)`.
    ///
    /// # Panics
    /// Outside the grid.
    pub fn at(&self, [x, y, z]: [usize; 3]) -> f32 {
        assert!(x < self.dims[0] && y < self.dims[1] && z < self.dims[2]);
        self.values[(z * self.dims[1] + y) * self.dims[0] + x]
    }

    /// The corners of the box the volume fills, in world coordinates: the grid's, or for an
    /// axis of one sample a slab one voxel thick around it (as it is drawn).
    pub fn world_corners(&self) -> [[f64; 3]; 8] {
        std::array::from_fn(|i| {
            let index: [f64; 3] = std::array::from_fn(|a| {
                let far = (i >> a) & 1 == 1;
                match (self.dims[a], far) {
                    (1, false) => -0.5,
                    (1, true) => 0.5,
                    (_, false) => 0.0,
                    (d, true) => (d - 1) as f64,
                }
            });
            self.world_of_index(index)
        })
    }

    /// World position of a (fractional) grid index.
    pub fn world_of_index(&self, index: [f64; 3]) -> [f64; 3] {
        std::array::from_fn(|w| {
            self.origin[w]
                + index[0] * self.axes[0][w]
                + index[1] * self.axes[1][w]
                + index[2] * self.axes[2][w]
        })
    }
}

/// f64 samples as f32: as they are where f32 holds the largest finite one within a factor of
/// 2¹⁰⁰ of its limits, else every one multiplied by the power of two 2^e that brings the
/// largest magnitude to between 1/2 and 1 — exact but for f32's rounding (a relative error of
/// at most 2⁻²⁴ of each value, and values under 2⁻¹⁴⁹ of the largest flushed towards 0).
/// Returns the samples and `e`.
fn narrow_f64(values: &[f64]) -> (Vec<f32>, i32) {
    let largest = values
        .iter()
        .filter(|v| v.is_finite())
        .fold(0f64, |m, v| m.max(v.abs()));
    let exponent = if largest == 0.0 || (2f64.powi(-100)..2f64.powi(100)).contains(&largest) {
        0
    } else {
        -(largest.log2().floor() as i32 + 1)
    };
    let unit = 2f64.powi(exponent);
    let narrowed = values.iter().map(|v| (v * unit) as f32).collect();
    (narrowed, exponent)
}

/// Makes every non-finite sample the one NaN (so that nodes hash the same bits whatever NaN
/// or infinity the file held) and counts them.
fn mark_missing(values: &mut [f32]) -> usize {
    let mut missing = 0;
    for v in values.iter_mut().filter(|v| !v.is_finite()) {
        *v = f32::NAN;
        missing += 1;
    }
    missing
}

/// The axes of a grid aligned with the world's, `spacing` apart; `field` names the spacing in
/// the error if it is not finite and positive.
fn axis_aligned(path: &Path, field: &str, spacing: [f64; 3]) -> Result<[[f64; 3]; 3], VolumeError> {
    if !spacing.iter().all(|s| s.is_finite() && *s > 0.0) {
        return Err(VolumeError::field(
            path,
            field,
            "must be finite and positive",
        ));
    }
    Ok(std::array::from_fn(|a| {
        std::array::from_fn(|w| if w == a { spacing[a] } else { 0.0 })
    }))
}

/// Whether an `endian` field (absent: little) says little-endian.
fn little_endian(path: &Path, value: Option<&str>) -> Result<bool, VolumeError> {
    match value.map(str::trim) {
        None | Some("little") => Ok(true),
        Some("big") => Ok(false),
        Some(other) => Err(VolumeError::field(
            path,
            "endian",
            format!("{other:?} (little or big)"),
        )),
    }
}

/// The product of `dims`, or an error naming `sizes` if it overflows.
fn voxel_count(path: &Path, dims: [usize; 3]) -> Result<usize, VolumeError> {
    dims.iter()
        .try_fold(1usize, |n, &d| n.checked_mul(d))
        .ok_or_else(|| VolumeError::field(path, "sizes", "the voxel count overflows"))
}

/// The volume formats, as chosen by a file's name.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Format {
    Nrrd,
    Nifti,
    RawWithSidecar,
    DicomSeries,
    /// VTK XML ImageData.
    Vti,
}

/// The format `path`'s name says, if it names a volume this module loads.
fn format_of(path: &Path) -> Option<Format> {
    if path.is_dir() {
        return Some(Format::DicomSeries);
    }
    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
    let lower = name.to_ascii_lowercase();
    if lower.ends_with(".nrrd") || lower.ends_with(".nhdr") {
        Some(Format::Nrrd)
    } else if lower.ends_with(".nii") || lower.ends_with(".nii.gz") || lower.ends_with(".hdr") {
        Some(Format::Nifti)
    } else if lower.ends_with(".vol.toml") {
        Some(Format::RawWithSidecar)
    } else if lower.ends_with(".vti") {
        Some(Format::Vti)
    } else {
        None
    }
}

/// Whether `path` names a volume this module loads (by extension, as meshes are chosen).
pub fn is_volume_path(path: &Path) -> bool {
    format_of(path).is_some()
}

/// The voxels the volume at `path` declares, from its header alone (NRRD, a raw sidecar);
/// `None` for the formats whose count is not read ahead (NIfTI, DICOM) or an unreadable
/// header, which [`load`] will report.
pub fn declared_voxels(path: &Path) -> Option<u64> {
    match format_of(path)? {
        Format::Nrrd => nrrd::declared_voxels(path),
        Format::RawWithSidecar => raw::declared_voxels(path),
        Format::Nifti | Format::DicomSeries | Format::Vti => None,
    }
}

/// Loads the volume at `path`, choosing the reader by extension: `.nrrd` / `.nhdr` (NRRD,
/// raw or gzip encoding, data attached or in a detached file), `.nii` / `.nii.gz` / `.hdr`
/// (NIfTI-1, placed by its sform or qform), `.vol.toml` (raw voxels described by a small TOML
/// sidecar, see `raw`), `.vti` (VTK XML image data, see `vti`) and a folder (a DICOM series of
/// uncompressed slices).
///
/// # Errors
/// An unknown extension, an unreadable file, a bad header field (named), or data cut short.
pub fn load(path: &Path) -> Result<Volume, VolumeError> {
    let volume = match format_of(path) {
        Some(Format::Nrrd) => nrrd::load(path),
        Some(Format::Nifti) => nifti::load(path),
        Some(Format::DicomSeries) => dicom::load(path),
        Some(Format::RawWithSidecar) => raw::load(path),
        Some(Format::Vti) => vti::load(path),
        None => Err(VolumeError::UnknownFormat {
            path: path.display().to_string(),
        }),
    }?;
    if volume.value_exponent != 0 {
        tracing::warn!(
            "volume {}: its f64 values lie beyond f32's range; they are stored times 2^{} \
             (relative error under 6e-8), and --iso and data-domain transfer points are in those \
             units",
            path.display(),
            volume.value_exponent
        );
    }
    if volume.missing > 0 {
        tracing::info!(
            "volume {}: {} of {} voxels are missing data (NaN or infinite): drawn transparent, \
             no iso-surface through their cells",
            path.display(),
            volume.missing,
            volume.values.len()
        );
    }
    Ok(volume)
}

/// Reads exactly the voxels of `dims` × `voxel_type` from the start of `bytes`; more bytes
/// than that is an error too (a wrong size or type in the header, most likely).
fn decode_exact(
    path: &Path,
    bytes: &[u8],
    dims: [usize; 3],
    voxel_type: VoxelType,
    little_endian: bool,
) -> Result<Vec<f32>, VolumeError> {
    let expected = voxel_count(path, dims)?
        .checked_mul(voxel_type.bytes())
        .ok_or_else(|| VolumeError::field(path, "sizes", "the byte count overflows"))?;
    if bytes.len() != expected {
        return Err(VolumeError::Truncated {
            path: path.display().to_string(),
            expected,
            found: bytes.len(),
        });
    }
    voxel_type.decode(path, bytes, little_endian)
}

#[cfg(test)]
pub(crate) mod render_tests;
#[cfg(test)]
mod tests;
