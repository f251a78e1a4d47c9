use super::super::load_mesh_file;
use super::*;
use std::io::Write;

fn load(name: &str, bytes: &[u8]) -> Result<Mesh, String> {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(name);
    std::fs::write(&path, bytes).unwrap();
    load_mesh_file(&path).map_err(|e| {
        let e = e.to_string();
        assert!(e.contains(name) && !e.contains('\n'), "{e}");
        e
    })
}

fn assert_fails(name: &str, bytes: &[u8], want: &str) {
    let err = load(name, bytes).unwrap_err();
    assert!(err.contains(want), "{want}: {err}");
}

/// A unit square (two triangles) in z = 0.
const SQUARE: [f64; 12] = [0., 0., 0., 1., 0., 0., 1., 1., 0., 0., 1., 0.];

fn square_triangles() -> Vec<[u32; 3]> {
    vec![[0, 1, 2], [0, 2, 3]]
}

const LEGACY_HEAD: &str = "# vtk DataFile Version 3.0\nsquare\nASCII\nDATASET POLYDATA\n";

#[test]
fn legacy_ascii_binary_and_version_5_polydata_give_the_same_mesh() {
    let ascii = format!("{LEGACY_HEAD}POINTS 4 float\n0 0 0 1 0 0\n1 1 0 0 1 0\nPOLYGONS 1 5\n4 0 1 2 3\nPOINT_DATA 4\nSCALARS s float\n");
    let a = load("a.vtk", ascii.as_bytes()).unwrap();
    assert_eq!(a.triangles, square_triangles());
    assert_eq!(a.positions[2], DVec3::new(1.0, 1.0, 0.0));

    let mut binary = LEGACY_HEAD.replace("ASCII", "BINARY").into_bytes();
    binary.extend(b"POINTS 4 double\n");
    SQUARE.iter().for_each(|v| binary.extend(v.to_be_bytes()));
    binary.extend(b"\nPOLYGONS 1 5\n");
    [4i32, 0, 1, 2, 3]
        .iter()
        .for_each(|v| binary.extend(v.to_be_bytes()));
    binary.push(b'\n');
    let b = load("b.vtk", &binary).unwrap();
    assert_eq!((&a.positions, &a.triangles), (&b.positions, &b.triangles));

    let v5 = format!(
        "{}POINTS 4 float\n0 0 0 1 0 0 1 1 0 0 1 0\nMETADATA\nINFORMATION 0\n\n\
         POLYGONS 2 4\nOFFSETS vtktypeint64\n0 4\nCONNECTIVITY vtktypeint64\n0 1 2 3\n",
        LEGACY_HEAD.replace("3.0", "5.1")
    );
    let c = load("c.vtk", v5.as_bytes()).unwrap();
    assert_eq!((&a.positions, &a.triangles), (&c.positions, &c.triangles));
}

#[test]
fn tetrahedra_give_their_boundary_faces_and_shared_faces_are_dropped() {
    let grid = "# vtk DataFile Version 3.0\ntets\nASCII\nDATASET UNSTRUCTURED_GRID\n\
                POINTS 5 float\n0 0 0 1 0 0 0 1 0 0 0 1 1 1 1\n\
                CELLS 3 14\n4 0 1 2 3\n4 1 2 3 4\n3 0 1 4\nCELL_TYPES 3\n10 10 5\n";
    let mesh = load("t.vtk", grid.as_bytes()).unwrap();
    // Two tetrahedra share face 1-2-3: 8 faces, 6 on the boundary, then the triangle cell.
    assert_eq!(mesh.triangles.len(), 7);
    assert_eq!(
        mesh.triangles[0],
        [0, 1, 4],
        "cells first, then the boundary"
    );
    let shared = |t: &[u32; 3]| {
        let mut s = *t;
        s.sort();
        s == [1, 2, 3]
    };
    assert!(!mesh.triangles.iter().any(shared));
}

#[test]
fn legacy_errors_name_the_line() {
    let head = "# vtk DataFile Version 3.0\nt\nASCII\nDATASET POLYDATA\nPOINTS 3 float\n";
    #[rustfmt::skip]
    let cases = [
        ("0 0 0 1 0 0 0 zz 0\n", "line 6: POINTS value 7: `zz` is not a number"),
        ("0 0 0 1 0 0 0 1e39 0\n", "POINTS: point 2 has a non-finite coordinate"),
        ("0 0 0 1 0 0 0 1 0\nPOLYGONS 1 4\n3 0 1 7\n", "line 7: POLYGONS: cell 0 uses point 7, but there are only 3"),
        ("0 0 0 1 0 0 0 1 0\nPOLYGONS 1 4\n5 0 1 2\n", "line 7: POLYGONS: cell 0 claims 5 points, past the list's end"),
        ("0 0 0 1 0 0 0 1 0\nPOLYGONS 1 5\n3 0 1 2 2\n", "1 cells use 4 of the 5 numbers"),
        ("0 0 0 1 0 0 0 1 0\nBOGUS 1\n", "line 7: unexpected `BOGUS`"),
        ("0 0 0 1 0 0\n", "POINTS: the file ends after 6 of 9 values"),
    ];
    for (tail, want) in cases {
        assert_fails("bad.vtk", format!("{head}{tail}").as_bytes(), want);
    }
    let grid = head.replace("POLYDATA", "UNSTRUCTURED_GRID");
    let cells = format!("{grid}0 0 0 1 0 0 0 1 0\nCELLS 1 4\n3 0 1 2\nCELL_TYPES 1\n42\n");
    assert_fails(
        "g.vtk",
        cells.as_bytes(),
        "CELLS: cell 0 has type 42, which is not read",
    );
    let tet = format!("{grid}0 0 0 1 0 0 0 1 0\nCELLS 1 4\n3 0 1 2\nCELL_TYPES 1\n10\n");
    assert_fails(
        "g.vtk",
        tet.as_bytes(),
        "cell 0 (solid cell) has 3 points, expected 4",
    );
    let image = head.replace("POLYDATA", "STRUCTURED_POINTS");
    assert_fails(
        "i.vtk",
        image.as_bytes(),
        "line 4: DATASET STRUCTURED_POINTS is not read",
    );
    assert_fails("x.vtk", b"solid x\n", "line 1: not a legacy VTK file");
    // A binary count the file cannot hold is refused before anything is allocated.
    let huge = LEGACY_HEAD.replace("ASCII", "BINARY") + "POINTS 4000000000000 float\n\0\0";
    assert_fails("h.vtk", huge.as_bytes(), "claims 12000000000000 entries");
}

fn base64(bytes: &[u8]) -> String {
    const ABC: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::new();
    for chunk in bytes.chunks(3) {
        let b = [
            chunk[0],
            *chunk.get(1).unwrap_or(&0),
            *chunk.get(2).unwrap_or(&0),
        ];
        let n = u32::from_be_bytes([0, b[0], b[1], b[2]]);
        for k in 0..4 {
            out.push(match k <= chunk.len() {
                true => ABC[(n >> (18 - 6 * k) & 63) as usize] as char,
                false => '=',
            });
        }
    }
    out
}

/// How a test file stores its arrays.
#[derive(Clone, Copy, PartialEq, Debug)]
pub(crate) enum Layout {
    Ascii,
    Base64,
    AppendedRaw,
    AppendedBase64,
    Zlib,
}

/// Writes VTK XML `DataArray`s in one [`Layout`], gathering appended data.
pub(crate) struct Arrays {
    layout: Layout,
    appended: Vec<u8>,
}

impl Arrays {
    pub(crate) fn new(layout: Layout) -> Self {
        Arrays {
            layout,
            appended: Vec::new(),
        }
    }

    /// The `<VTKFile>` attributes this layout needs.
    pub(crate) fn file_attrs(&self) -> &'static str {
        match self.layout {
            Layout::Zlib => r#"byte_order="LittleEndian" compressor="vtkZLibDataCompressor""#,
            _ => r#"byte_order="LittleEndian""#,
        }
    }

    /// A `DataArray` of `values` as `ty` (Float32, Int64 or UInt8).
    pub(crate) fn array(&mut self, name: &str, ty: &str, comps: usize, values: &[f64]) -> String {
        let head = format!(r#"<DataArray type="{ty}" Name="{name}" NumberOfComponents="{comps}""#);
        let mut data = Vec::new();
        for &v in values {
            match ty {
                "Float32" => data.extend((v as f32).to_le_bytes()),
                "Int64" => data.extend((v as i64).to_le_bytes()),
                _ => data.push(v as u8),
            }
        }
        let size = (data.len() as u32).to_le_bytes();
        match self.layout {
            Layout::Ascii => {
                let text: Vec<String> = values.iter().map(f64::to_string).collect();
                format!(
                    "{head} format=\"ascii\">\n{}\n</DataArray>\n",
                    text.join(" ")
                )
            }
            Layout::Base64 => {
                // VTK encodes the header and the data separately, each padded.
                format!(
                    "{head} format=\"binary\">\n  {}{}\n</DataArray>\n",
                    base64(&size),
                    base64(&data)
                )
            }
            Layout::Zlib => {
                let mut z =
                    flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::fast());
                z.write_all(&data).unwrap();
                let packed = z.finish().unwrap();
                let mut header = Vec::new();
                for v in [1, data.len(), data.len(), packed.len()] {
                    header.extend((v as u32).to_le_bytes());
                }
                format!(
                    "{head} format=\"binary\">{}{}</DataArray>\n",
                    base64(&header),
                    base64(&packed)
                )
            }
            Layout::AppendedRaw | Layout::AppendedBase64 => {
                let offset = self.appended.len();
                if self.layout == Layout::AppendedRaw {
                    self.appended.extend(size);
                    self.appended.extend(data);
                } else {
                    self.appended.extend(base64(&size).bytes());
                    self.appended.extend(base64(&data).bytes());
                }
                format!("{head} format=\"appended\" offset=\"{offset}\"/>\n")
            }
        }
    }

    /// The `<AppendedData>` element, if any, and the end of the file.
    pub(crate) fn finish(self) -> Vec<u8> {
        let mut out = Vec::new();
        if !self.appended.is_empty() {
            let encoding = match self.layout {
                Layout::AppendedRaw => "raw",
                _ => "base64",
            };
            out.extend(format!("<AppendedData encoding=\"{encoding}\">\n   _").bytes());
            out.extend(self.appended);
            out.extend(b"\n</AppendedData>\n");
        }
        out.extend(b"</VTKFile>\n");
        out
    }
}

const LAYOUTS: [Layout; 5] = [
    Layout::Ascii,
    Layout::Base64,
    Layout::AppendedRaw,
    Layout::AppendedBase64,
    Layout::Zlib,
];

fn vtp(layout: Layout) -> Vec<u8> {
    let mut a = Arrays::new(layout);
    let points = a.array("Points", "Float32", 3, &SQUARE);
    let conn = a.array("connectivity", "Int64", 1, &[0., 1., 2., 3.]);
    let offsets = a.array("offsets", "Int64", 1, &[4.]);
    let mut text = format!(
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"PolyData\" version=\"1.0\" {}>\n<PolyData>\n\
         <Piece NumberOfPoints=\"4\" NumberOfPolys=\"1\">\n<Points>\n{points}</Points>\n\
         <Polys>\n{conn}{offsets}</Polys>\n</Piece>\n</PolyData>\n",
        a.file_attrs()
    )
    .into_bytes();
    text.extend(a.finish());
    text
}

fn vtu(layout: Layout) -> Vec<u8> {
    let mut a = Arrays::new(layout);
    let xyz = [
        0., 0., 0., 1., 0., 0., 0., 1., 0., 0., 0., 1., 5., 5., 5., 6., 5., 5.,
    ];
    let points = a.array("Points", "Float32", 3, &xyz);
    // A tetrahedron, a line (skipped) and a quad.
    let conn = a.array(
        "connectivity",
        "Int64",
        1,
        &[0., 1., 2., 3., 4., 5., 0., 1., 5., 4.],
    );
    let offsets = a.array("offsets", "Int64", 1, &[4., 6., 10.]);
    let types = a.array("types", "UInt8", 1, &[10., 3., 9.]);
    let mut text = format!(
        "<VTKFile type=\"UnstructuredGrid\" {}>\n<UnstructuredGrid>\n\
         <Piece NumberOfPoints=\"6\" NumberOfCells=\"3\">\n<Points>\n{points}</Points>\n\
         <Cells>\n{conn}{offsets}{types}</Cells>\n</Piece>\n</UnstructuredGrid>\n",
        a.file_attrs()
    )
    .into_bytes();
    text.extend(a.finish());
    text
}

#[test]
fn xml_polydata_and_unstructured_grids_load_in_every_data_layout() {
    for layout in LAYOUTS {
        let mesh = load("s.vtp", &vtp(layout)).unwrap_or_else(|e| panic!("{layout:?}: {e}"));
        assert_eq!(mesh.triangles, square_triangles(), "{layout:?}");
        assert_eq!(mesh.positions[2], DVec3::new(1.0, 1.0, 0.0), "{layout:?}");
        let mesh = load("g.vtu", &vtu(layout)).unwrap_or_else(|e| panic!("{layout:?}: {e}"));
        assert_eq!(mesh.positions.len(), 6);
        // The quad's two triangles, then the tetrahedron's four faces.
        assert_eq!(mesh.triangles.len(), 6, "{layout:?}");
        assert_eq!(mesh.triangles[..2], [[0, 1, 5], [0, 5, 4]]);
    }
}

#[test]
fn xml_errors_name_the_element_and_its_line() {
    let ascii = String::from_utf8(vtp(Layout::Ascii)).unwrap();
    #[rustfmt::skip]
    let cases = [
        (ascii.replace("0 1 2 3\n", "0 1 2 9\n"), "<DataArray Name=\"connectivity\"> (line 11): cell 0 uses point 9, but there are only 4"),
        (ascii.replace("0 1 2 3\n", "0 1 2\n"), "<DataArray Name=\"connectivity\"> (line 11): 3 values, expected 4"),
        (ascii.replace("\n4\n", "\n5\n"), "<DataArray Name=\"connectivity\"> (line 11): 4 values, expected 5"),
        (ascii.replace("1 1 0 0", "1 x 0 0"), "<DataArray Name=\"Points\"> (line 6): value 7 `x` is not a number"),
        (ascii.replace("NumberOfPolys=\"1\"", "NumberOfPolys=\"one\""), "<Piece> (line 4): NumberOfPolys=\"one\" is not a count"),
        (ascii.replace("Name=\"offsets\"", "Name=\"ends\""), "<Polys> (line 10) has no DataArray named `offsets`"),
        (ascii.replace("</Polys>", "</Poly>"), "line 17: not well-formed XML: ill-formed document: expected `</Polys>`"),
        (ascii.replace("PolyData\" ", "ImageData\" "), "type \"ImageData\" is not a surface"),
        (ascii.replace("LittleEndian\"", "LittleEndian\" compressor=\"vtkLZ4DataCompressor\""), "compressor `vtkLZ4DataCompressor` is not read"),
    ];
    for (text, want) in cases {
        assert_fails("bad.vtp", text.as_bytes(), want);
    }
    let raw = vtp(Layout::AppendedRaw);
    assert_fails(
        "cut.vtp",
        &raw[..raw.len() - 40],
        "4 bytes of data expected",
    );
    let mut lied = raw.clone();
    let at = lied.windows(2).position(|w| w == b"_\x30").unwrap();
    lied[at + 1] = 0x31; // The points' byte count, 48, made 49.
    assert_fails("lied.vtp", &lied, "its header says 49 bytes, expected 48");
    let zlib = String::from_utf8(vtp(Layout::Zlib)).unwrap();
    let bomb = zlib.replace("NumberOfPoints=\"4\"", "NumberOfPoints=\"4000000000\"");
    assert_fails("bomb.vtp", bomb.as_bytes(), "compression header says");
}
