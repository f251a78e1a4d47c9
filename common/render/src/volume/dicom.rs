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
use dicom_object::{open_file, DefaultDicomObject, Tag};
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
        // dicom-rs allocates whatever length a damaged header claims: those are refused first.
        let bytes = std::fs::read(&path).map_err(|e| VolumeError::io(&path, e))?;
        super::dicom_lengths::check(&bytes)
            .map_err(|m| VolumeError::field(&path, "element length", m))?;
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
    // DICOM places slices in LPS patient axes, where +z is superior.
    Volume::checked(
        dir,
        [cols, rows, values.len() / (cols * rows)],
        axes,
        origin,
        voxel_type,
        values,
    )
    .map(|v| v.with_up(glam::Vec3::Z))
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
    let fields = Fields { path, object };
    let position = fields.floats(tags::IMAGE_POSITION_PATIENT, "ImagePositionPatient", 3)?;
    let orientation = fields.floats(
        tags::IMAGE_ORIENTATION_PATIENT,
        "ImageOrientationPatient",
        6,
    )?;
    let spacing = fields.floats(tags::PIXEL_SPACING, "PixelSpacing", 2)?;
    let (size, voxel_type) = fields.pixel_format()?;
    let values = fields.values(size, voxel_type)?;
    Ok(Slice {
        path: path.to_path_buf(),
        position: [position[0], position[1], position[2]],
        orientation: std::array::from_fn(|i| orientation[i]),
        spacing: [spacing[0], spacing[1]],
        size,
        voxel_type,
        values,
    })
}

/// A slice file's elements, read with errors that name the field at fault.
struct Fields<'a> {
    path: &'a Path,
    object: &'a DefaultDicomObject,
}

impl Fields<'_> {
    /// Exactly `count` finite numbers.
    fn floats(&self, tag: Tag, name: &str, count: usize) -> Result<Vec<f64>, VolumeError> {
        let values = self
            .object
            .element(tag)
            .map_err(|_| VolumeError::field(self.path, name, "missing"))?
            .to_multi_float64()
            .map_err(|e| VolumeError::field(self.path, name, e.to_string()))?;
        if values.len() != count || !values.iter().all(|v| v.is_finite()) {
            return Err(VolumeError::field(
                self.path,
                name,
                format!("{values:?}: {count} finite numbers expected"),
            ));
        }
        Ok(values)
    }

    fn int(&self, tag: Tag, name: &str) -> Result<u32, VolumeError> {
        self.object
            .element(tag)
            .map_err(|_| VolumeError::field(self.path, name, "missing"))?
            .to_int::<u32>()
            .map_err(|e| VolumeError::field(self.path, name, e.to_string()))
    }

    fn optional(&self, tag: Tag, default: f64) -> f64 {
        self.object
            .element(tag)
            .ok()
            .and_then(|e| e.to_float64().ok())
            .unwrap_or(default)
    }

    /// The slice's rows and columns and how a pixel is stored: one grey sample of 8 or 16
    /// bits.
    fn pixel_format(&self) -> Result<((usize, usize), VoxelType), VolumeError> {
        let path = self.path;
        let (rows, cols) = (
            self.int(tags::ROWS, "Rows")? as usize,
            self.int(tags::COLUMNS, "Columns")? as usize,
        );
        // An empty slice made the series' depth a division by zero (found by fuzzing).
        if rows == 0 || cols == 0 {
            return Err(VolumeError::field(
                path,
                "Rows/Columns",
                format!("{rows}×{cols}: a slice needs at least one pixel"),
            ));
        }
        if self
            .int(tags::SAMPLES_PER_PIXEL, "SamplesPerPixel")
            .unwrap_or(1)
            != 1
        {
            return Err(VolumeError::field(
                path,
                "SamplesPerPixel",
                "only one sample per pixel (grey) is read",
            ));
        }
        let signed = self.int(tags::PIXEL_REPRESENTATION, "PixelRepresentation")? == 1;
        let voxel_type = match (self.int(tags::BITS_ALLOCATED, "BitsAllocated")?, signed) {
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
        Ok(((rows, cols), voxel_type))
    }

    /// The pixels of a `rows × cols` slice of `voxel_type`, rescaled to the modality's values.
    fn values(
        &self,
        (rows, cols): (usize, usize),
        voxel_type: VoxelType,
    ) -> Result<Vec<f32>, VolumeError> {
        let path = self.path;
        let pixels = self
            .object
            .element(tags::PIXEL_DATA)
            .map_err(|_| VolumeError::field(path, "PixelData", "missing"))?
            .to_bytes()
            .map_err(|e| VolumeError::field(path, "PixelData", e.to_string()))?;
        // Checked: Rows and Columns may arrive as 32-bit values, whose product overflows.
        let expected = rows
            .checked_mul(cols)
            .and_then(|n| n.checked_mul(voxel_type.bytes()))
            .ok_or_else(|| {
                VolumeError::field(path, "Rows/Columns", "the slice's size overflows")
            })?;
        if pixels.len() < expected {
            return Err(VolumeError::Truncated {
                path: path.display().to_string(),
                expected,
                found: pixels.len(),
            });
        }
        let (slope, intercept) = (
            self.optional(tags::RESCALE_SLOPE, 1.0),
            self.optional(tags::RESCALE_INTERCEPT, 0.0),
        );
        Ok(voxel_type
            .decode(path, &pixels[..expected], true)?
            .into_iter()
            .map(|v| (v as f64 * slope + intercept) as f32)
            .collect())
    }
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

    #[test]
    fn a_slice_claiming_more_bytes_than_it_holds_is_refused_before_allocating() {
        // The fuzzer's case: a 426-byte slice whose meta group claimed a 4 GB element, which
        // dicom-object allocated and zeroed before finding the file short.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.dcm");
        write_slice(&path, 0.0, 0);
        let good = std::fs::read(&path).unwrap();
        assert!(super::super::dicom_lengths::check(&good).is_ok());
        let find =
            |bytes: &[u8], what: &[u8]| bytes.windows(what.len()).position(|w| w == what).unwrap();
        // Media Storage SOP Instance UID (0002,0003), VR UI: its u16 length, then the data set's
        // pixel data (7FE0,0010), VR OW: its u32 length.
        let mut meta = good.clone();
        let at = find(&meta, &[2, 0, 3, 0, b'U', b'I']) + 6;
        meta[at..at + 2].copy_from_slice(&0xfff0u16.to_le_bytes());
        let mut pixels = good.clone();
        let at = find(&pixels, &[0xe0, 0x7f, 0x10, 0, b'O', b'W']) + 8;
        pixels[at..at + 4].copy_from_slice(&0xffff_fff0u32.to_le_bytes());
        for (name, bytes, tag) in [
            ("meta", meta, "(0002,0003)"),
            ("pixels", pixels, "(7FE0,0010)"),
        ] {
            std::fs::write(&path, bytes).unwrap();
            let err = load(dir.path()).unwrap_err().to_string();
            assert!(
                err.contains("a.dcm") && err.contains(tag) && err.contains("claims"),
                "{name}: {err}"
            );
        }
    }

    #[test]
    fn a_slice_of_no_rows_is_refused_not_divided_by() {
        // The fuzzer's case: Rows = 0 passed every check and the depth was values / (0 × cols).
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.dcm");
        write_slice(&path, 0.0, 0);
        let mut bytes = std::fs::read(&path).unwrap();
        let rows = [0x28, 0, 0x10, 0, b'U', b'S', 2, 0];
        let at = bytes.windows(8).position(|w| w == rows).unwrap() + 8;
        bytes[at..at + 2].copy_from_slice(&0u16.to_le_bytes());
        std::fs::write(&path, bytes).unwrap();
        let err = load(dir.path()).unwrap_err().to_string();
        assert!(err.contains("Rows/Columns") && err.contains("0×4"), "{err}");
    }

    #[test]
    fn a_data_set_behind_an_odd_meta_group_is_still_walked() {
        // The fuzzer's second case: the transfer syntax UID ends in a no-break space, which
        // dicom-rs trims and this pass did not (so it left the data set unwalked), and the meta
        // group's last element runs past its group length (so the data set starts after it).
        // There an element claims 4 GB, which dicom-parser allocated.
        let dir = tempfile::tempdir().unwrap();
        let bytes = include_bytes!("fuzz-cases/dicom-element-past-meta-group.dcm");
        std::fs::write(dir.path().join("a.dcm"), bytes).unwrap();
        let err = load(dir.path()).unwrap_err().to_string();
        assert!(err.contains("(FFFF,001A) claims 4294901760 bytes"), "{err}");
    }
}
