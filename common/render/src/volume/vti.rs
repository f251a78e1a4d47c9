//! VTK XML ImageData (`.vti`): a grid of `WholeExtent` samples at `Origin`, `Spacing` apart
//! along the `Direction` axes, its samples the piece's point-data scalars (the array that
//! `PointData`'s `Scalars` names, else the first one-component array). One piece only;
//! ascii, base64 or appended data, raw or zlib-compressed, as [`crate::scene::vtk::xml`] reads
//! them. Cell data is not read: VTK writes volumes as point data.

use super::{voxel_count, Volume, VolumeError, VoxelType};
use crate::scene::vtk::xml::{Document, Id};
use std::path::Path;

/// Loads a `.vti` file.
pub(super) fn load(path: &Path) -> Result<Volume, VolumeError> {
    let bytes = std::fs::read(path).map_err(|e| VolumeError::io(path, e))?;
    let field = |name: &'static str| move |message: String| VolumeError::field(path, name, message);
    let doc = Document::parse(&bytes).map_err(field("VTKFile"))?;
    if doc.kind() != "ImageData" {
        let message = format!("type \"{}\" is not ImageData", doc.kind());
        return Err(VolumeError::field(path, "VTKFile", message));
    }
    let image = doc.child(0, "ImageData").map_err(field("ImageData"))?;
    let extent = extent(&doc, image, "WholeExtent").map_err(field("WholeExtent"))?;
    let pieces: Vec<Id> = doc.children(image, "Piece").collect();
    let [piece] = pieces[..] else {
        let message = format!("{} pieces (one-piece image data is read)", pieces.len());
        return Err(VolumeError::field(path, "Piece", message));
    };
    if doc.attr(piece, "Extent").is_some() {
        let own = extent_of(&doc, piece).map_err(field("Extent"))?;
        if own != extent {
            let message = format!("{own:?} is not the whole extent {extent:?}");
            return Err(VolumeError::field(path, "Extent", message));
        }
    }
    let dims: [usize; 3] =
        std::array::from_fn(|a| (extent[2 * a + 1] - extent[2 * a] + 1) as usize);
    let (axes, origin) = placement(&doc, image, extent).map_err(field("Spacing"))?;
    let array = scalars(&doc, piece).map_err(field("PointData"))?;
    let count = voxel_count(path, dims)?;
    let values = doc
        .values(array, count, |v| v as f32)
        .map_err(field("DataArray"))?;
    let voxel_type = match doc.attr(array, "type") {
        Some("UInt8") => VoxelType::U8,
        Some("Int16") => VoxelType::I16,
        Some("UInt16") => VoxelType::U16,
        _ => VoxelType::F32,
    };
    Volume::checked(path, dims, axes, origin, voxel_type, values)
}

/// `WholeExtent`: the first and last index along each axis, whole numbers, first ≤ last.
fn extent(doc: &Document, id: Id, name: &str) -> Result<[i64; 6], String> {
    let values = doc.numbers(id, name, "")?;
    let whole = values.iter().all(|v| v.fract() == 0.0 && v.abs() < 1e15);
    match <[f64; 6]>::try_from(values) {
        Ok(e) if whole && (0..3).all(|a| e[2 * a] <= e[2 * a + 1]) => Ok(e.map(|v| v as i64)),
        _ => Err(format!(
            "{}: {name} must be six whole numbers, x0 x1 y0 y1 z0 z1, each first ≤ last",
            doc.at(id)
        )),
    }
}

fn extent_of(doc: &Document, piece: Id) -> Result<[i64; 6], String> {
    extent(doc, piece, "Extent")
}

/// The axes (`Spacing` along `Direction`'s columns) and the world position of the extent's
/// first sample.
fn placement(
    doc: &Document,
    image: Id,
    extent: [i64; 6],
) -> Result<([[f64; 3]; 3], [f64; 3]), String> {
    let triple = |name: &str, default: &str| -> Result<[f64; 3], String> {
        let v = doc.numbers(image, name, default)?;
        v.try_into()
            .map_err(|_| format!("{}: {name} must be three numbers", doc.at(image)))
    };
    let origin = triple("Origin", "0 0 0")?;
    let spacing = triple("Spacing", "1 1 1")?;
    let direction: [f64; 9] = doc
        .numbers(image, "Direction", "1 0 0 0 1 0 0 0 1")?
        .try_into()
        .map_err(|_| format!("{}: Direction must be nine numbers", doc.at(image)))?;
    // Direction is row-major; index axis a runs along its column a.
    let axes: [[f64; 3]; 3] =
        std::array::from_fn(|a| std::array::from_fn(|w| direction[3 * w + a] * spacing[a]));
    let first: [f64; 3] = std::array::from_fn(|w| {
        origin[w]
            + (0..3)
                .map(|a| extent[2 * a] as f64 * axes[a][w])
                .sum::<f64>()
    });
    Ok((axes, first))
}

/// The point-data array the samples come from.
fn scalars(doc: &Document, piece: Id) -> Result<Id, String> {
    let data = doc.child(piece, "PointData")?;
    if let Some(name) = doc.attr(data, "Scalars") {
        return doc.array_named(data, name);
    }
    doc.children(data, "DataArray")
        .find(|&a| {
            doc.attr(a, "NumberOfComponents")
                .is_none_or(|n| n.trim() == "1")
        })
        .ok_or_else(|| format!("{} has no one-component DataArray", doc.at(data)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::vtk::tests::{Arrays, Layout};

    /// A 3×2×2 grid whose sample is its index times 10, as `ty`, over `extent`.
    fn vti(layout: Layout, ty: &str, extent: &str, extra: &str) -> Vec<u8> {
        let mut a = Arrays::new(layout);
        let values: Vec<f64> = (0..12).map(|i| i as f64 * 10.0).collect();
        let array = a.array("density", ty, 1, &values);
        let mut text = format!(
            "<VTKFile type=\"ImageData\" {}>\n<ImageData WholeExtent=\"{extent}\" \
             Origin=\"1 2 3\" Spacing=\"0.5 1 2\" {extra}>\n<Piece Extent=\"{extent}\">\n\
             <PointData Scalars=\"density\">\n{array}</PointData>\n</Piece>\n</ImageData>\n",
            a.file_attrs()
        )
        .into_bytes();
        text.extend(a.finish());
        text
    }

    fn load_bytes(name: &str, bytes: &[u8]) -> Result<Volume, String> {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(name);
        std::fs::write(&path, bytes).unwrap();
        crate::volume::load(&path).map_err(|e| {
            let e = e.to_string();
            assert!(e.contains(name), "{e}");
            e
        })
    }

    #[test]
    fn vti_image_data_loads_as_a_volume_in_every_layout() {
        let want: Vec<f32> = (0..12).map(|i| i as f32 * 10.0).collect();
        for layout in [
            Layout::Ascii,
            Layout::Base64,
            Layout::AppendedRaw,
            Layout::Zlib,
        ] {
            let v = load_bytes("v.vti", &vti(layout, "Float32", "0 2 0 1 0 1", "")).unwrap();
            assert_eq!(v.dims(), [3, 2, 2], "{layout:?}");
            assert_eq!(v.spacing(), [0.5, 1.0, 2.0]);
            assert_eq!(v.origin(), [1.0, 2.0, 3.0]);
            assert_eq!(v.values(), want, "{layout:?}");
            assert_eq!(v.at([2, 1, 1]), 110.0);
        }
        let v = load_bytes("u8.vti", &vti(Layout::Base64, "UInt8", "0 2 0 1 0 1", "")).unwrap();
        assert_eq!((v.voxel_type(), v.values()), (VoxelType::U8, &want[..]));
        // An extent from x = 2 starts two steps along x; Direction turns x into -y.
        let turned = r#"Direction="0 0 1 -1 0 0 0 1 0""#;
        let v = load_bytes(
            "t.vti",
            &vti(Layout::Ascii, "Float32", "2 4 0 1 0 1", turned),
        );
        let v = v.unwrap();
        assert_eq!(
            v.axes(),
            [[0.0, -0.5, 0.0], [0.0, 0.0, 1.0], [2.0, 0.0, 0.0]]
        );
        assert_eq!(v.origin(), [1.0, 1.0, 3.0]);
    }

    #[test]
    fn bad_vti_files_name_the_field_and_element() {
        let good = String::from_utf8(vti(Layout::Ascii, "Float32", "0 2 0 1 0 1", "")).unwrap();
        #[rustfmt::skip]
        let cases = [
            (good.replace("0 2 0 1 0 1\" Origin", "0 2 0 1 0\" Origin"), "field `WholeExtent`: <ImageData> (line 2): WholeExtent must be six whole numbers"),
            (good.replace("Extent=\"0 2 0 1 0 1\">", "Extent=\"0 1 0 1 0 1\">"), "field `Extent`: [0, 1, 0, 1, 0, 1] is not the whole extent"),
            (good.replace(" 110\n", "\n"), "field `DataArray`: <DataArray Name=\"density\"> (line 5): 11 values, expected 12"),
            (good.replace("Scalars=\"density\"", "Scalars=\"temperature\""), "<PointData> (line 4) has no DataArray named `temperature`"),
            (good.replace("</Piece>\n", "</Piece>\n<Piece/>\n"), "field `Piece`: 2 pieces"),
            (good.replace("ImageData\" ", "PolyData\" "), "field `VTKFile`: type \"PolyData\" is not ImageData"),
            (good.replace("Spacing=\"0.5 1 2\"", "Spacing=\"0.5 0 2\""), "field `spacing`: the voxel axes must be finite and span 3-D space"),
        ];
        for (text, want) in cases {
            let err = load_bytes("bad.vti", text.as_bytes()).unwrap_err();
            assert!(err.contains(want), "{want}: {err}");
        }
    }
}
