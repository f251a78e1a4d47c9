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
            "every one of the 12 voxels is missing data",
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

/// A NIfTI-1 single file (`n+1`) of the 3×2×2 i16 samples, with `edit` applied to its header.
fn nifti_file(edit: impl Fn(&mut [u8])) -> Vec<u8> {
    let mut h = vec![0u8; 352];
    let put_i16 = |h: &mut [u8], at: usize, v: i16| h[at..at + 2].copy_from_slice(&v.to_le_bytes());
    let put_f32 = |h: &mut [u8], at: usize, v: f32| h[at..at + 4].copy_from_slice(&v.to_le_bytes());
    h[0..4].copy_from_slice(&348i32.to_le_bytes());
    for (i, d) in [3i16, 3, 2, 2, 1, 1, 1, 1].iter().enumerate() {
        put_i16(&mut h, 40 + 2 * i, *d);
    }
    put_i16(&mut h, 70, 4); // datatype: int16
    put_i16(&mut h, 72, 16); // bitpix
    for (i, p) in [1.0f32, 0.5, 0.25, 2.0].iter().enumerate() {
        put_f32(&mut h, 76 + 4 * i, *p);
    }
    put_f32(&mut h, 108, 352.0); // vox_offset
    h[344..348].copy_from_slice(b"n+1\0");
    edit(&mut h);
    h.extend(i16_bytes(&expected(), true));
    h
}

#[test]
fn nifti_is_placed_by_its_sform_else_its_qform_and_rescaled() {
    let dir = tempfile::tempdir().unwrap();
    let put_f32 = |h: &mut [u8], at: usize, v: f32| h[at..at + 4].copy_from_slice(&v.to_le_bytes());
    // Pixel sizes only: spacing 0.5, 0.25, 2 from the origin; scl_slope 2 and inter -1024.
    let plain = dir.path().join("plain.nii");
    std::fs::write(
        &plain,
        nifti_file(|h| {
            put_f32(h, 112, 2.0);
            put_f32(h, 116, -1024.0);
        }),
    )
    .unwrap();
    let v = load(&plain).unwrap();
    assert_eq!(v.dims(), [3, 2, 2]);
    assert_eq!(v.spacing(), [0.5, 0.25, 2.0]);
    assert_eq!(v.up(), None, "no sform or qform: no anatomy known");
    assert_eq!(v.at([1, 0, 0]), 10.0 * 2.0 - 1024.0);
    // A qform turning x into y (90° about z: b = c = 0, d = sin 45°) with an offset; gzip.
    let q = std::f32::consts::FRAC_1_SQRT_2;
    let qform = nifti_file(|h| {
        h[252..254].copy_from_slice(&1i16.to_le_bytes());
        put_f32(h, 264, q);
        for (i, o) in [10.0f32, 20.0, 30.0].iter().enumerate() {
            put_f32(h, 268 + 4 * i, *o);
        }
    });
    let gz = dir.path().join("q.nii.gz");
    std::fs::write(&gz, gzip(&qform)).unwrap();
    let v = load(&gz).unwrap();
    assert_eq!(
        v.up(),
        Some(glam::Vec3::Z),
        "RAS+: superior is up, not the table"
    );
    let p = v.world_of_index([1.0, 0.0, 0.0]);
    assert!(
        (p[0] - 10.0).abs() < 1e-6 && (p[1] - 20.5).abs() < 1e-6,
        "{p:?}"
    );
    // An sform wins over the qform.
    let sform = nifti_file(|h| {
        h[252..254].copy_from_slice(&1i16.to_le_bytes());
        h[254..256].copy_from_slice(&2i16.to_le_bytes());
        for (row, values) in [
            [0.0f32, 0.0, 3.0, 1.0],
            [0.0, 1.0, 0.0, 2.0],
            [1.0, 0.0, 0.0, 3.0],
        ]
        .iter()
        .enumerate()
        {
            for (i, v) in values.iter().enumerate() {
                put_f32(h, 280 + 16 * row + 4 * i, *v);
            }
        }
    });
    let s = dir.path().join("s.nii");
    std::fs::write(&s, sform).unwrap();
    let v = load(&s).unwrap();
    assert_eq!(v.world_of_index([1.0, 0.0, 1.0]), [4.0, 2.0, 4.0]);
    // A series (dim[4] = 3) and a cut-short file are refused by name.
    let series = dir.path().join("t.nii");
    let mut three = nifti_file(|h| {
        h[40..42].copy_from_slice(&4i16.to_le_bytes());
        h[48..50].copy_from_slice(&3i16.to_le_bytes());
    });
    three.extend(i16_bytes(&[expected(), expected()].concat(), true));
    std::fs::write(&series, three).unwrap();
    let err = load(&series).unwrap_err().to_string();
    assert!(err.contains("t.nii") && err.contains("`dim`"), "{err}");
    let short = dir.path().join("short.nii");
    let mut bytes = nifti_file(|_| {});
    bytes.truncate(bytes.len() - 4);
    std::fs::write(&short, bytes).unwrap();
    assert!(load(&short).is_err());
}

#[test]
fn a_nifti_file_of_fewer_than_three_dimensions_is_read_not_a_panic() {
    // The fuzzer's case: dim[0] = 1 made the time-axis check slice past the end of `dim`.
    let dir = tempfile::tempdir().unwrap();
    for (rank, dims) in [(1i16, [3, 1, 1]), (2, [3, 2, 1])] {
        let path = dir.path().join(format!("rank{rank}.nii"));
        let bytes = nifti_file(|h| h[40..42].copy_from_slice(&rank.to_le_bytes()));
        std::fs::write(&path, bytes).unwrap();
        match load(&path) {
            Ok(v) => assert_eq!(v.dims(), dims),
            Err(e) => panic!("rank {rank}: {e}"),
        }
    }
}

#[test]
fn f64_values_beyond_f32_are_scaled_by_a_power_of_two_and_others_kept() {
    let (kept, e) = super::narrow_f64(&[1.0, -2.5, 1e30, f64::NAN]);
    assert_eq!(e, 0);
    assert_eq!(&kept[..3], &[1.0, -2.5, 1e30f32]);
    assert!(kept[3].is_nan());
    for values in [[1e200, -3e199, 7.0, 0.0], [1e-200, 5e-201, -1e-201, 0.0]] {
        let (narrowed, e) = super::narrow_f64(&values);
        assert!(
            e != 0 && narrowed.iter().all(|v| v.is_finite()),
            "{narrowed:?}"
        );
        assert!((0.5..1.0).contains(&narrowed[0]), "{narrowed:?}");
        for (n, v) in narrowed.iter().zip(values) {
            let back = *n as f64 * 2f64.powi(-e);
            assert!(
                (back - v).abs() <= v.abs() * 6e-8 + 1e-30 * values[0].abs(),
                "{back} {v}"
            );
        }
    }
}

#[test]
fn volumes_in_patient_axes_and_sidecars_that_say_so_stand_upright() {
    let dir = tempfile::tempdir().unwrap();
    let data = i16_bytes(&expected(), true);
    for (space, up) in [
        ("space: left-posterior-superior\n", Some(glam::Vec3::Z)),
        ("space: RAS\n", Some(glam::Vec3::Z)),
        ("", None),
    ] {
        let header = format!(
            "NRRD0004\ntype: short\ndimension: 3\n{space}sizes: 3 2 2\nspacings: 1 1 1\n\
             encoding: raw\nendian: little\n\n"
        );
        let path = dir.path().join("v.nrrd");
        std::fs::write(&path, nrrd(&header, &data)).unwrap();
        assert_eq!(load(&path).unwrap().up(), up, "{space:?}");
    }
    std::fs::write(dir.path().join("v.raw"), &data).unwrap();
    let sidecar = dir.path().join("v.vol.toml");
    let text = "data = \"v.raw\"\ndims = [3, 2, 2]\ntype = \"i16\"\n";
    std::fs::write(&sidecar, format!("{text}up = [0.0, 0.0, 1.0]\n")).unwrap();
    assert_eq!(load(&sidecar).unwrap().up(), Some(glam::Vec3::Z));
    std::fs::write(&sidecar, format!("{text}up = [0.0, 0.0, 0.0]\n")).unwrap();
    let err = load(&sidecar).unwrap_err().to_string();
    assert!(
        err.contains("up") && err.contains("not a direction"),
        "{err}"
    );
    // The orbit of such a scene turns about +z.
    std::fs::write(&sidecar, format!("{text}up = [0.0, 0.0, 1.0]\n")).unwrap();
    let scene =
        crate::scene::Scene::load(&tessera_model::scene_spec::SceneSpec::File(sidecar)).unwrap();
    let camera = scene.orbit(45.0).unwrap().camera_for_frame(0);
    assert_eq!(camera.up(), glam::Vec3::Z);
}
