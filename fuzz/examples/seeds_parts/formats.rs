//! Seeds of the formats issue 26 added: STL, VTK (legacy, XML surfaces, image data) and PLY
//! point clouds. A part of `seeds.rs`, which was past the project's 800 lines a file.

use super::{base64, put};
use std::io::Write;
use std::path::Path;

/// STL, VTK (legacy, XML surfaces, image data) and PLY point clouds: issue 26's formats.
pub(super) fn formats(root: &Path) {
    let square = [
        0f32, 0., 0., 1., 0., 0., 1., 1., 0., 0., 0., 0., 1., 1., 0., 0., 1., 0.,
    ];
    let mut stl = String::from("solid s\n");
    for t in square.chunks(9) {
        stl += "facet normal 0 0 1\nouter loop\n";
        for c in t.chunks(3) {
            stl += &format!("vertex {} {} {}\n", c[0], c[1], c[2]);
        }
        stl += "endloop\nendfacet\n";
    }
    put(root, "mesh_stl", "ascii", stl + "endsolid s\n");
    let mut binary = b"solid binary".to_vec();
    binary.resize(80, 0);
    binary.extend(2u32.to_le_bytes());
    for t in square.chunks(9) {
        binary.extend([0; 12]);
        t.iter().for_each(|c| binary.extend(c.to_le_bytes()));
        binary.extend([0; 2]);
    }
    put(root, "mesh_stl", "binary", binary);

    let head = "# vtk DataFile Version 3.0\nseed\nASCII\nDATASET POLYDATA\n";
    let points = "POINTS 4 float\n0 0 0 1 0 0 1 1 0 0 1 0\n";
    put(
        root,
        "mesh_vtk",
        "polydata",
        format!(
            "{head}{points}POLYGONS 1 5\n4 0 1 2 3\nTRIANGLE_STRIPS 1 5\n4 0 1 3 2\nPOINT_DATA 4\n"
        ),
    );
    put(root, "mesh_vtk", "version5", format!("{}{points}POLYGONS 2 4\nOFFSETS vtktypeint64\n0 4\nCONNECTIVITY vtktypeint64\n0 1 2 3\n", head.replace("3.0", "5.1")));
    let grid = head.replace("POLYDATA", "UNSTRUCTURED_GRID");
    put(root, "mesh_vtk", "tetrahedra", format!("{grid}POINTS 5 float\n0 0 0 1 0 0 0 1 0 0 0 1 1 1 1\nCELLS 3 14\n4 0 1 2 3\n4 1 2 3 4\n3 0 1 4\nCELL_TYPES 3\n10 10 5\n"));
    let mut binary = head.replace("ASCII", "BINARY").into_bytes();
    binary.extend(b"POINTS 3 double\n");
    [0f64, 0., 0., 1., 0., 0., 0., 1., 0.]
        .iter()
        .for_each(|v| binary.extend(v.to_be_bytes()));
    binary.extend(b"\nPOLYGONS 1 4\n");
    [3i32, 0, 1, 2]
        .iter()
        .for_each(|v| binary.extend(v.to_be_bytes()));
    put(root, "mesh_vtk", "binary", binary);
    vtk_xml(root);
    vti_and_point_clouds(root);
}

/// VTK XML surfaces in three array layouts: ascii, appended raw, base64.
fn vtk_xml(root: &Path) {
    let f32s = |v: &[f32]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
    let i64s = |v: &[i64]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
    let sized = |data: Vec<u8>| [(data.len() as u32).to_le_bytes().to_vec(), data].concat();
    let vtp = |arrays: [&str; 3], tail: &[u8]| {
        let mut out = format!(
            "<?xml version=\"1.0\"?>\n<VTKFile type=\"PolyData\" byte_order=\"LittleEndian\">\n\
             <PolyData><Piece NumberOfPoints=\"4\" NumberOfPolys=\"1\">\n<Points>{}</Points>\n\
             <Polys>{}{}</Polys></Piece></PolyData>\n",
            arrays[0], arrays[1], arrays[2]
        )
        .into_bytes();
        out.extend(tail);
        out.extend(b"</VTKFile>\n");
        out
    };
    let ascii = [
        r#"<DataArray type="Float32" NumberOfComponents="3" format="ascii">0 0 0 1 0 0 1 1 0 0 1 0</DataArray>"#,
        r#"<DataArray type="Int64" Name="connectivity" format="ascii">0 1 2 3</DataArray>"#,
        r#"<DataArray type="Int64" Name="offsets" format="ascii">4</DataArray>"#,
    ];
    put(root, "mesh_vtk_xml", "ascii.vtp", vtp(ascii, b""));
    let xyz = sized(f32s(&[0., 0., 0., 1., 0., 0., 1., 1., 0., 0., 1., 0.]));
    let conn = sized(i64s(&[0, 1, 2, 3]));
    let appended = [
        r#"<DataArray type="Float32" NumberOfComponents="3" format="appended" offset="0"/>"#
            .to_string(),
        format!(
            r#"<DataArray type="Int64" Name="connectivity" format="appended" offset="{}"/>"#,
            xyz.len()
        ),
        format!(
            r#"<DataArray type="Int64" Name="offsets" format="appended" offset="{}"/>"#,
            xyz.len() + conn.len()
        ),
    ];
    let mut raw = b"<AppendedData encoding=\"raw\">_".to_vec();
    raw.extend([xyz, conn, sized(i64s(&[4]))].concat());
    raw.extend(b"</AppendedData>\n");
    put(
        root,
        "mesh_vtk_xml",
        "appended.vtp",
        vtp(appended.each_ref().map(String::as_str), &raw),
    );
    let b64 = |data: Vec<u8>| base64(&sized(data));
    put(root, "mesh_vtk_xml", "grid.vtu", format!(
        "<VTKFile type=\"UnstructuredGrid\" header_type=\"UInt32\">\n<UnstructuredGrid>\n\
         <Piece NumberOfPoints=\"4\" NumberOfCells=\"1\"><Points>\n\
         <DataArray type=\"Float32\" NumberOfComponents=\"3\" format=\"binary\">{}</DataArray>\n\
         </Points><Cells>\n<DataArray type=\"Int64\" Name=\"connectivity\" format=\"binary\">{}</DataArray>\n\
         <DataArray type=\"Int64\" Name=\"offsets\" format=\"binary\">{}</DataArray>\n\
         <DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">10</DataArray>\n\
         </Cells></Piece></UnstructuredGrid></VTKFile>\n",
        b64(f32s(&[0., 0., 0., 1., 0., 0., 0., 1., 0., 0., 0., 1.])),
        b64(i64s(&[0, 1, 2, 3])),
        b64(i64s(&[4])),
    ));
}

/// `.vti` volumes (ascii, zlib) and PLY point clouds (ascii, binary).
fn vti_and_point_clouds(root: &Path) {
    let f32s = |v: &[f32]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
    let vti = |array: &str| {
        format!(
            "<VTKFile type=\"ImageData\" byte_order=\"LittleEndian\">\n\
         <ImageData WholeExtent=\"0 1 0 1 0 1\" Origin=\"0 0 0\" Spacing=\"1 1 2\">\n\
         <Piece Extent=\"0 1 0 1 0 1\"><PointData Scalars=\"v\">{array}</PointData></Piece>\n\
         </ImageData></VTKFile>\n"
        )
    };
    put(
        root,
        "volume_vti",
        "ascii",
        vti(
            r#"<DataArray type="UInt8" Name="v" format="ascii">0 10 20 30 40 50 60 70</DataArray>"#,
        ),
    );
    let data = f32s(&[0., 1., 2., 3., 4., 5., 6., 7.]);
    let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::fast());
    z.write_all(&data).unwrap();
    let packed = z.finish().unwrap();
    let header: Vec<u8> = [1, data.len(), data.len(), packed.len()]
        .iter()
        .flat_map(|&v| (v as u32).to_le_bytes())
        .collect();
    let zlib = vti(&format!(
        r#"<DataArray type="Float32" Name="v" format="binary">{}{}</DataArray>"#,
        base64(&header),
        base64(&packed)
    ))
    .replace(
        "LittleEndian\"",
        "LittleEndian\" compressor=\"vtkZLibDataCompressor\"",
    );
    put(root, "volume_vti", "zlib", zlib);

    let cloud = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n\
                 property float z\nproperty uchar intensity\nend_header\n\
                 0 0 0 1\n1 0 0 2\n0 1 0 3\n0 0 1 4\n";
    put(root, "points_ply", "ascii", cloud);
    let mut binary = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty double x\n\
        property double y\nproperty double z\nelement face 0\n\
        property list uchar int vertex_indices\nend_header\n"
        .to_vec();
    [0f64, 0., 0., 1., 0., 0., 0., 2., 0.]
        .iter()
        .for_each(|v| binary.extend(v.to_le_bytes()));
    put(root, "points_ply", "binary", binary);
}
