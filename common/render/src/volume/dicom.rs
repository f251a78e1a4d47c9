//! DICOM series: a folder of CT or MR slices (dicom-rs), ordered by their position along the
//! slice normal, each rescaled by its own slope and intercept, placed in patient coordinates
//! by ImagePositionPatient, ImageOrientationPatient and PixelSpacing.
//!
//! Uncompressed transfer syntaxes only (implicit and explicit VR little endian): a compressed
//! series (JPEG and the like) is refused by name, since decoding it needs pixel-data codecs
//! this build does not carry. Files in the folder that are not DICOM (a DICOMDIR, notes) are
//! skipped.

use super::{Volume, VolumeError, VoxelType};
use dicom_dictionary_std::tags;
use dicom_object::{open_file, DefaultDicomObject};
use std::path::{Path, PathBuf};

/// Transfer syntaxes whose pixel data are stored as plain little-endian samples.
const UNCOMPRESSED: [&str; 2] = ["1.2.840.10008.1.2", "1.2.840.10008.1.2.1"];

/// One slice, as the series needs it.
struct Slice {
    path: PathBuf,
    position: [f64; 3],
    orientation: [f64; 6],
    /// Row spacing (between rows) and column spacing (between columns), as DICOM gives them.
    spacing: [f64; 2],
    size: (usize, usize),
    voxel_type: VoxelType,
    values: Vec<f32>,
}

pub(super) fn load(dir: &Path) -> Result<Volume, VolumeError> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| VolumeError::io(dir, e))?
        .filter_map(|e| Some(e.ok()?.path()))
        .filter(|p| p.is_file())
        .collect();
    files.sort();
    let mut slices = Vec::new();
    for path in files {
        // Not every file in a series folder is DICOM; those that are must be readable slices.
        if let Ok(object) = open_file(&path) {
            slices.push(read_slice(&path, &object)?);
        }
    }
    let Some(first) = slices.first() else {
        return Err(VolumeError::field(
            dir,
            "series",
            "the folder holds no DICOM slices",
        ));
    };
    let (cols, rows) = (first.size.1, first.size.0);
    for s in &slices {
        let same = s.size == first.size
            && s.spacing == first.spacing
            && s.voxel_type == first.voxel_type
            && s.orientation
                .iter()
                .zip(&first.orientation)
                .all(|(a, b)| (a - b).abs() < 1e-4);
        if !same {
            return Err(VolumeError::field(
                &s.path,
                "Rows/Columns/PixelSpacing/ImageOrientationPatient",
                format!("differs from {}", first.path.display()),
            ));
        }
    }
    let (o, pixel_spacing, voxel_type) = (first.orientation, first.spacing, first.voxel_type);
    let row_dir = [o[0], o[1], o[2]];
    let col_dir = [o[3], o[4], o[5]];
    let normal = cross(row_dir, col_dir);
    let depth = |s: &Slice| dot(s.position, normal);
    slices.sort_by(|a, b| depth(a).total_cmp(&depth(b)));
    let step = slice_step(&slices, depth)?;
    let origin = slices[0].position;
    // x runs along a row (across columns), y down the rows, z through the slices.
    let axes = [
        row_dir.map(|v| v * pixel_spacing[1]),
        col_dir.map(|v| v * pixel_spacing[0]),
        normal.map(|v| v * step),
    ];
    let mut values = Vec::with_capacity(cols * rows * slices.len());
    for s in slices {
        values.extend(s.values);
    }
    Volume::checked(
        dir,
        [cols, rows, values.len() / (cols * rows)],
        axes,
        origin,
        voxel_type,
        values,
    )
}

/// The distance between consecutive slices, which must be even (within 1 %) and non-zero; one
/// slice is one millimetre thick unless it says otherwise.
fn slice_step(slices: &[Slice], depth: impl Fn(&Slice) -> f64) -> Result<f64, VolumeError> {
    if slices.len() == 1 {
        return Ok(1.0);
    }
    let gaps: Vec<f64> = slices
        .windows(2)
        .map(|w| depth(&w[1]) - depth(&w[0]))
        .collect();
    // Against the median, so the slice out of step is the one named.
    let mut sorted = gaps.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    for (i, gap) in gaps.iter().enumerate() {
        if *gap <= 0.0 || (gap - median).abs() > 0.01 * median {
            return Err(VolumeError::field(
                &slices[i + 1].path,
                "ImagePositionPatient",
                format!(
                    "{gap} mm from the slice before, where the series steps {median} mm: \
                     slices must be evenly spaced and at distinct positions"
                ),
            ));
        }
    }
    Ok(gaps.iter().sum::<f64>() / gaps.len() as f64)
}

fn read_slice(path: &Path, object: &DefaultDicomObject) -> Result<Slice, VolumeError> {
    let syntax = object.meta().transfer_syntax().trim_end_matches('\0');
    if !UNCOMPRESSED.contains(&syntax) {
        return Err(VolumeError::field(
            path,
            "TransferSyntaxUID",
            format!("{syntax} is compressed or big-endian; only uncompressed little-endian slices are read"),
        ));
    }
    let floats = |tag, name: &str, count: usize| -> Result<Vec<f64>, VolumeError> {
        let values = object
            .element(tag)
            .map_err(|_| VolumeError::field(path, name, "missing"))?
            .to_multi_float64()
            .map_err(|e| VolumeError::field(path, name, e.to_string()))?;
        if values.len() != count || !values.iter().all(|v| v.is_finite()) {
            return Err(VolumeError::field(
                path,
                name,
                format!("{values:?}: {count} finite numbers expected"),
            ));
        }
        Ok(values)
    };
    let int = |tag, name: &str| -> Result<u32, VolumeError> {
        object
            .element(tag)
            .map_err(|_| VolumeError::field(path, name, "missing"))?
            .to_int::<u32>()
            .map_err(|e| VolumeError::field(path, name, e.to_string()))
    };
    let optional = |tag, default: f64| {
        object
            .element(tag)
            .ok()
            .and_then(|e| e.to_float64().ok())
            .unwrap_or(default)
    };
    let position = floats(tags::IMAGE_POSITION_PATIENT, "ImagePositionPatient", 3)?;
    let orientation = floats(
        tags::IMAGE_ORIENTATION_PATIENT,
        "ImageOrientationPatient",
        6,
    )?;
    let spacing = floats(tags::PIXEL_SPACING, "PixelSpacing", 2)?;
    let (rows, cols) = (
        int(tags::ROWS, "Rows")? as usize,
        int(tags::COLUMNS, "Columns")? as usize,
    );
    if int(tags::SAMPLES_PER_PIXEL, "SamplesPerPixel").unwrap_or(1) != 1 {
        return Err(VolumeError::field(
            path,
            "SamplesPerPixel",
            "only one sample per pixel (grey) is read",
        ));
    }
    let signed = int(tags::PIXEL_REPRESENTATION, "PixelRepresentation")? == 1;
    let voxel_type = match (int(tags::BITS_ALLOCATED, "BitsAllocated")?, signed) {
        (8, false) => VoxelType::U8,
        (16, false) => VoxelType::U16,
        (16, true) => VoxelType::I16,
        (bits, _) => {
            return Err(VolumeError::field(
                path,
                "BitsAllocated",
                format!("{bits} (8 or 16 expected)"),
            ))
        }
    };
    let pixels = object
        .element(tags::PIXEL_DATA)
        .map_err(|_| VolumeError::field(path, "PixelData", "missing"))?
        .to_bytes()
        .map_err(|e| VolumeError::field(path, "PixelData", e.to_string()))?;
    let expected = rows * cols * voxel_type.bytes();
    if pixels.len() < expected {
        return Err(VolumeError::Truncated {
            path: path.display().to_string(),
            expected,
            found: pixels.len(),
        });
    }
    let (slope, intercept) = (
        optional(tags::RESCALE_SLOPE, 1.0),
        optional(tags::RESCALE_INTERCEPT, 0.0),
    );
    let values = voxel_type
        .decode(&pixels[..expected], true)
        .into_iter()
        .map(|v| (v as f64 * slope + intercept) as f32)
        .collect();
    Ok(Slice {
        path: path.to_path_buf(),
        position: [position[0], position[1], position[2]],
        orientation: std::array::from_fn(|i| orientation[i]),
        spacing: [spacing[0], spacing[1]],
        size: (rows, cols),
        voxel_type,
        values,
    })
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[cfg(test)]
mod tests {
    use super::*;
    use dicom_core::{DataElement, PrimitiveValue, VR};
    use dicom_dictionary_std::uids;
    use dicom_object::{FileMetaTableBuilder, InMemDicomObject};

    /// A 3-row, 4-column CT slice at height `z` whose stored pixel i is `base + i`.
    fn write_slice(path: &Path, z: f64, base: u16) {
        let pixels: Vec<u16> = (0..12).map(|i| base + i).collect();
        let uid = format!("2.25.{}", 1000 + base);
        let obj = InMemDicomObject::from_element_iter([
            DataElement::new(
                tags::SOP_CLASS_UID,
                VR::UI,
                PrimitiveValue::from(uids::CT_IMAGE_STORAGE),
            ),
            DataElement::new(
                tags::SOP_INSTANCE_UID,
                VR::UI,
                PrimitiveValue::from(uid.as_str()),
            ),
            DataElement::new(tags::ROWS, VR::US, PrimitiveValue::from(3u16)),
            DataElement::new(tags::COLUMNS, VR::US, PrimitiveValue::from(4u16)),
            DataElement::new(tags::BITS_ALLOCATED, VR::US, PrimitiveValue::from(16u16)),
            DataElement::new(
                tags::PIXEL_REPRESENTATION,
                VR::US,
                PrimitiveValue::from(0u16),
            ),
            DataElement::new(tags::SAMPLES_PER_PIXEL, VR::US, PrimitiveValue::from(1u16)),
            DataElement::new(
                tags::PIXEL_SPACING,
                VR::DS,
                PrimitiveValue::from("0.5\\0.75"),
            ),
            DataElement::new(
                tags::IMAGE_ORIENTATION_PATIENT,
                VR::DS,
                PrimitiveValue::from("1\\0\\0\\0\\1\\0"),
            ),
            DataElement::new(
                tags::IMAGE_POSITION_PATIENT,
                VR::DS,
                PrimitiveValue::from(format!("-10\\20\\{z}")),
            ),
            DataElement::new(tags::RESCALE_SLOPE, VR::DS, PrimitiveValue::from("1")),
            DataElement::new(
                tags::RESCALE_INTERCEPT,
                VR::DS,
                PrimitiveValue::from("-1024"),
            ),
            DataElement::new(tags::PIXEL_DATA, VR::OW, PrimitiveValue::U16(pixels.into())),
        ]);
        let file = obj
            .with_meta(FileMetaTableBuilder::new().transfer_syntax(uids::EXPLICIT_VR_LITTLE_ENDIAN))
            .unwrap();
        file.write_to_file(path).unwrap();
    }

    #[test]
    fn a_series_is_ordered_by_position_rescaled_and_placed() {
        let dir = tempfile::tempdir().unwrap();
        // File names out of slice order, and a file that is not DICOM.
        write_slice(&dir.path().join("b.dcm"), 5.0, 200);
        write_slice(&dir.path().join("a.dcm"), 7.5, 300);
        write_slice(&dir.path().join("c.dcm"), 2.5, 100);
        std::fs::write(dir.path().join("README.txt"), "not a slice").unwrap();
        let v = load(dir.path()).unwrap();
        assert_eq!(v.dims(), [4, 3, 3]);
        assert_eq!(v.spacing(), [0.75, 0.5, 2.5]);
        assert_eq!(v.origin(), [-10.0, 20.0, 2.5]);
        assert_eq!(v.voxel_type(), VoxelType::U16);
        // Slice 0 is the one at z = 2.5 (base 100); pixel (1, 2) is stored value 100 + 2·4 + 1.
        assert_eq!(v.at([1, 2, 0]), 109.0 - 1024.0);
        assert_eq!(v.at([0, 0, 2]), 300.0 - 1024.0);

        // A slice out of step is refused by name.
        write_slice(&dir.path().join("d.dcm"), 11.0, 400);
        let err = load(dir.path()).unwrap_err().to_string();
        assert!(
            err.contains("d.dcm") && err.contains("ImagePositionPatient"),
            "{err}"
        );
        let empty = tempfile::tempdir().unwrap();
        assert!(load(empty.path())
            .unwrap_err()
            .to_string()
            .contains("no DICOM"));
    }
}
