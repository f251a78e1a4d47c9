use super::*;
use std::io::Write;

/// A 3×2×2 volume whose sample is its index times 10, for every format.
fn expected() -> Vec<f32> {
    (0..12).map(|i| i as f32 * 10.0).collect()
}

fn i16_bytes(values: &[f32], little: bool) -> Vec<u8> {
    values
        .iter()
        .flat_map(|&v| {
            let v = v as i16;
            if little {
                v.to_le_bytes()
            } else {
                v.to_be_bytes()
            }
        })
        .collect()
}

fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    e.write_all(bytes).unwrap();
    e.finish().unwrap()
}

fn nrrd(header: &str, data: &[u8]) -> Vec<u8> {
    let mut file = header.as_bytes().to_vec();
    file.extend_from_slice(data);
    file
}

#[test]
fn nrrd_raw_and_gzip_either_byte_order_give_the_same_volume() {
    let dir = tempfile::tempdir().unwrap();
    for (encoding, endian) in [("raw", "little"), ("gzip", "little"), ("raw", "big")] {
        let raw = i16_bytes(&expected(), endian == "little");
        let data = if encoding == "gzip" { gzip(&raw) } else { raw };
        let header = format!(
            "NRRD0004\n# a comment\ntype: short\ndimension: 3\nsizes: 3 2 2\n\
             space directions: (0.5,0,0) (0,0.5,0) (0,0,2.5)\nspace origin: (10,-4,0.25)\n\
             encoding: {encoding}\nendian: {endian}\n\n"
        );
        let path = dir.path().join(format!("v-{encoding}-{endian}.nrrd"));
        std::fs::write(&path, nrrd(&header, &data)).unwrap();
        let v = load(&path).unwrap();
        assert_eq!(v.dims(), [3, 2, 2]);
        assert_eq!(v.spacing(), [0.5, 0.5, 2.5]);
        assert_eq!(v.origin(), [10.0, -4.0, 0.25]);
        assert_eq!(v.voxel_type(), VoxelType::I16);
        assert_eq!(v.at([2, 1, 1]), 110.0, "{encoding} {endian}");
        assert_eq!(v.range(), (0.0, 110.0));
        assert_eq!(v.world_of_index([1.0, 1.0, 1.0]), [10.5, -3.5, 2.75]);
    }
}

/// A grid whose axes are not the world's (here flipped and sheared in x-y, as NIfTI and NRRD
/// files from scanners often are) is placed by its own axes.
#[test]
fn oblique_space_directions_place_the_grid() {
    let dir = tempfile::tempdir().unwrap();
    let header = "NRRD0005\ntype: uint8\ndimension: 3\nsizes: 3 2 2\n\
                  space directions: (-1,0.5,0) (0,2,0) (0,0,3)\nspace origin: (5,5,5)\n\
                  encoding: raw\n\n";
    let path = dir.path().join("oblique.nrrd");
    std::fs::write(&path, nrrd(header, &[7; 12])).unwrap();
    let v = load(&path).unwrap();
    assert_eq!(v.world_of_index([2.0, 1.0, 1.0]), [3.0, 8.0, 8.0]);
    assert_eq!(v.spacing()[1], 2.0);
    assert_eq!(v.range(), (7.0, 7.0));
}

#[test]
fn a_detached_nrrd_header_reads_its_data_file() {
    let dir = tempfile::tempdir().unwrap();
    let data: Vec<u8> = expected().iter().map(|&v| v as u8).collect();
    std::fs::write(dir.path().join("v.raw"), &data).unwrap();
    let header = "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 3 2 2\nspacings: 1 2 3\n\
                  encoding: raw\ndata file: v.raw\n";
    let path = dir.path().join("v.nhdr");
    std::fs::write(&path, header).unwrap();
    let v = load(&path).unwrap();
    assert_eq!(v.spacing(), [1.0, 2.0, 3.0]);
    assert_eq!(v.at([0, 0, 1]), 60.0);
}

#[test]
fn a_raw_volume_with_a_sidecar_loads_as_its_sidecar_says() {
    let dir = tempfile::tempdir().unwrap();
    let data: Vec<u8> = expected()
        .iter()
        .flat_map(|&v| (v + 0.5).to_be_bytes())
        .collect();
    std::fs::write(dir.path().join("v.f32"), &data).unwrap();
    let path = dir.path().join("v.vol.toml");
    std::fs::write(
        &path,
        "data = \"v.f32\"\ndims = [3, 2, 2]\ntype = \"f32\"\nspacing = [0.25, 0.25, 1.5]\n\
         endian = \"big\"\n",
    )
    .unwrap();
    let v = load(&path).unwrap();
    assert_eq!(v.at([1, 0, 0]), 10.5);
    assert_eq!(v.spacing(), [0.25, 0.25, 1.5]);
    assert_eq!(v.origin(), [0.0; 3]);
    assert!(is_volume_path(&path) && !is_volume_path(Path::new("wall.toml")));
}

/// Bad files fail with the field at fault named, and nothing is returned.
#[test]
fn bad_files_name_the_field_at_fault() {
    let dir = tempfile::tempdir().unwrap();
    let good = "NRRD0004\ntype: short\ndimension: 3\nsizes: 3 2 2\nencoding: raw\n\n";
    let cases: Vec<(&str, String, Vec<u8>, &str)> = vec![
        ("magic", "P6\n".into(), vec![], "magic"),
        (
            "type",
            good.replace("short", "double"),
            vec![0; 96],
            "`type`",
        ),
        (
            "dim",
            good.replace("dimension: 3", "dimension: 4"),
            vec![],
            "`dimension`",
        ),
        ("sizes", good.replace("3 2 2", "3 2"), vec![], "`sizes`"),
        ("zero", good.replace("3 2 2", "3 0 2"), vec![], "`sizes`"),
        (
            "enc",
            good.replace("raw", "bzip2"),
            vec![0; 24],
            "`encoding`",
        ),
        (
            "short",
            good.to_string(),
            vec![0; 23],
            "24 bytes of voxel data expected, 23 found",
        ),
        (
            "long",
            good.to_string(),
            vec![0; 25],
            "24 bytes of voxel data expected, 25 found",
        ),
        (
            "flat",
            good.replace(
                "encoding",
                "space directions: (1,1,0) (2,2,0) (0,0,1)\nencoding",
            ),
            vec![0; 24],
            "span 3-D space",
        ),
        (
            "dirs",
            good.replace("encoding", "space directions: (1,1,0) (0,1,0)\nencoding"),
            vec![0; 24],
            "`space directions`",
        ),
        (
            "nan",
            good.replace("short", "float"),
            nan_floats(),
            "voxel 0 is NaN",
        ),
    ];
    for (name, header, data, says) in cases {
        let path = dir.path().join(format!("{name}.nrrd"));
        std::fs::write(&path, nrrd(&header, &data)).unwrap();
        let message = load(&path).expect_err(name).to_string();
        assert!(message.contains(says), "{name}: {message}");
        assert!(
            message.contains(&*path.display().to_string()),
            "{name}: {message}"
        );
    }
    let sidecar = dir.path().join("bad.vol.toml");
    std::fs::write(&sidecar, "data = \"x\"\ntype = \"u8\"\n").unwrap();
    let message = load(&sidecar).unwrap_err().to_string();
    assert!(message.contains("dims"), "{message}");
    let message = load(Path::new("head.dcm")).unwrap_err().to_string();
    assert!(message.contains("unsupported extension"), "{message}");
}

fn nan_floats() -> Vec<u8> {
    (0..12).flat_map(|_| f32::NAN.to_le_bytes()).collect()
}
