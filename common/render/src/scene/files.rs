//! Mesh files: OBJ (via `tobj`), PLY ascii or binary (via `ply-rs-bw`), glTF/GLB (in
//! [`super::gltf`]), STL binary or ASCII (in `super::stl`), and VTK legacy `.vtk` and XML
//! `.vtp` / `.vtu` surfaces (in `super::vtk`). Every error names the file and, where the format has them, the line or the
//! element at fault: a render node that cannot load a scene must say exactly why.

use super::colors::{SurfaceColors, TextureFiles};
use super::obj_lines::obj_culprit;
use super::{Mesh, SceneError};
use glam::{DVec3, Vec2, Vec3};
use std::path::Path;

/// Reads the triangles of an OBJ, PLY, glTF, GLB, STL or VTK (`.vtk`, `.vtp`, `.vtu`) file;
/// polygons are fan-triangulated.
///
/// # Errors
/// A [`SceneError`] naming the file and what is wrong with it.
pub fn load_mesh_file(path: &Path) -> Result<Mesh, SceneError> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("obj") => load_obj(path),
        Some("ply") => load_ply(path),
        Some("gltf" | "glb") => super::gltf::load_gltf(path),
        Some("stl") => super::stl::load_stl(path),
        Some("vtk") => super::vtk::load_legacy(path),
        Some("vtp" | "vtu") => super::vtk::load_xml(path),
        _ => Err(SceneError::UnknownFormat {
            path: path.display().to_string(),
        }),
    }
}

/// Whether a vertex read in f64 is finite and within f32's range, as the renderer needs it.
pub(super) fn in_range(p: DVec3) -> bool {
    p.is_finite() && p.abs().max_element() <= f32::MAX as f64
}

pub(super) fn file_error(path: &Path, message: impl ToString) -> SceneError {
    SceneError::File {
        path: path.display().to_string(),
        message: message.to_string(),
    }
}

fn load_obj(path: &Path) -> Result<Mesh, SceneError> {
    let options = tobj::LoadOptions {
        triangulate: true,
        single_index: false,
        ignore_points: true,
        ignore_lines: true,
    };
    let file = std::fs::File::open(path).map_err(|e| file_error(path, e))?;
    let mut reader = std::io::BufReader::new(file);
    let dir = path.parent().unwrap_or(Path::new("")).to_path_buf();
    let loaded = tobj::load_obj_buf(&mut reader, &options, |mtl| tobj::load_mtl(dir.join(mtl)));
    let (models, file_materials) = match loaded {
        Ok(loaded) => loaded,
        Err(e) => {
            let why = obj_culprit(path).unwrap_or_else(|| format!("not a valid OBJ file: {e}"));
            return Err(file_error(path, why));
        }
    };
    // A mesh shared without its .mtl is still worth drawing: warn and use the neutral material.
    let file_materials = file_materials.unwrap_or_else(|e| {
        tracing::warn!(
            "{}: materials not loaded ({e}); drawing it in one neutral colour",
            path.display()
        );
        Vec::new()
    });
    let mut mesh = Mesh::default();
    let mut textures = TextureFiles::new(path);
    if models.iter().any(|m| m.mesh.material_id.is_some()) && !file_materials.is_empty() {
        obj_materials(&mut mesh, &file_materials, &mut textures, path)?;
    }
    let neutral = mesh.materials.len().saturating_sub(1) as u16;
    for model in models {
        let m = model.mesh;
        let base = mesh.positions.len() as u32;
        let (corners, colors) = obj_vertices(&m);
        let count = m.positions.len() / 3;
        let count = corners.as_ref().map_or(count, |c| c.vertices.len());
        let position = |i: u32| {
            let k = 3 * corners.as_ref().map_or(i, |c| c.vertices[i as usize].0) as usize;
            DVec3::new(m.positions[k], m.positions[k + 1], m.positions[k + 2])
        };
        mesh.colors
            .extend_vertices(base as usize, count, &colors.uvs, &colors.vertex);
        mesh.positions.extend((0..count as u32).map(position));
        let index = |k: usize| match &corners {
            Some(c) => base + c.of_corner[k],
            None => base + m.indices[k],
        };
        mesh.triangles.extend(
            (0..m.indices.len() / 3).map(|t| [index(3 * t), index(3 * t + 1), index(3 * t + 2)]),
        );
        if !mesh.materials.is_empty() {
            let id = m
                .material_id
                .filter(|&id| id < file_materials.len())
                .map_or(neutral, |id| id as u16);
            mesh.triangle_material
                .extend(std::iter::repeat_n(id, m.indices.len() / 3));
        }
    }
    mesh.colors.textures = textures.textures;
    if mesh.positions.iter().any(|p| !in_range(*p)) {
        let why = obj_culprit(path).unwrap_or_else(|| "has a non-finite vertex".into());
        return Err(file_error(path, why));
    }
    Ok(mesh)
}

/// The file's materials into `mesh`, their textures read, the neutral one last (for faces
/// before any `usemtl`).
fn obj_materials(
    mesh: &mut Mesh,
    file_materials: &[tobj::Material],
    textures: &mut TextureFiles,
    path: &Path,
) -> Result<(), SceneError> {
    mesh.materials = file_materials
        .iter()
        .map(|m| mtl_material(m, textures))
        .collect();
    mesh.material_names = file_materials.iter().map(|m| m.name.clone()).collect();
    mesh.materials.push(super::NEUTRAL);
    mesh.material_names.push("neutral (no usemtl)".into());
    if mesh.materials.len() > u16::MAX as usize {
        return Err(file_error(
            path,
            format!(
                "has {} materials; at most 65535 are supported",
                file_materials.len()
            ),
        ));
    }
    Ok(())
}

/// Vertices of an OBJ model with their own texture coordinates, by position and coordinate
/// index, and the vertex of each face corner.
struct Corners {
    vertices: Vec<(u32, u32)>,
    of_corner: Vec<u32>,
}

/// An OBJ model's per-vertex colours and texture coordinates. Without texture coordinates the
/// vertices are the model's own, with their colours (`v x y z r g b`). With them, a position
/// may carry a different coordinate in each face it is in (a seam), so each distinct pair of
/// position and coordinate becomes a vertex: `Some` [`Corners`].
fn obj_vertices(m: &tobj::Mesh) -> (Option<Corners>, SurfaceColors) {
    let color = |i: u32| {
        let k = 3 * i as usize;
        let c = m.vertex_color.get(k..k + 3).unwrap_or(&[1.0; 3]);
        SurfaceColors::encode_unit([c[0], c[1], c[2]].map(|c| c as f32))
    };
    let has_colors = !m.vertex_color.is_empty();
    let mut colors = SurfaceColors::default();
    if m.texcoords.is_empty() || m.texcoord_indices.len() != m.indices.len() {
        if has_colors {
            colors.vertex = (0..(m.positions.len() / 3) as u32).map(color).collect();
        }
        return (None, colors);
    }
    let mut known = std::collections::HashMap::new();
    let mut vertices = Vec::new();
    let of_corner = m
        .indices
        .iter()
        .zip(&m.texcoord_indices)
        .map(|(&p, &t)| {
            *known.entry((p, t)).or_insert_with(|| {
                vertices.push((p, t));
                vertices.len() as u32 - 1
            })
        })
        .collect();
    colors.uvs = vertices
        .iter()
        .map(|&(_, t)| {
            let k = 2 * t as usize;
            let uv = m.texcoords.get(k..k + 2).unwrap_or(&[0.0; 2]);
            // OBJ's v runs up the image; Tessera's, as glTF's, down from its top row.
            Vec2::new(uv[0] as f32, 1.0 - uv[1] as f32)
        })
        .collect();
    if has_colors {
        colors.vertex = vertices.iter().map(|&(p, _)| color(p)).collect();
    }
    let corners = Corners {
        vertices,
        of_corner,
    };
    (Some(corners), colors)
}

/// An MTL material as Tessera draws it: `Kd` is the diffuse colour, times the `map_Kd` texture
/// if it has one; `Ks` and `Ns` (illumination models 2 and up) make it Phong; models 3, 5 and
/// 7 ("reflection on, ray trace on") make `Ks` the mirror reflectance; `d` (or `Tr`) below 1
/// makes it transparent.
fn mtl_material(m: &tobj::Material, textures: &mut TextureFiles) -> super::Material {
    let illum = m.illumination_model.unwrap_or(2);
    // tobj reads in f64 (for positions far from the origin); colours need no such range.
    let colour = |c: [f64; 3]| DVec3::from_array(c).as_vec3();
    let albedo = m.diffuse.map_or(super::NEUTRAL.albedo, colour);
    let specular = m.specular.map_or(Vec3::ZERO, colour);
    super::Material {
        albedo,
        specular: if illum >= 2 { specular } else { Vec3::ZERO },
        shininess: m.shininess.unwrap_or(32.0) as f32,
        mirror: if matches!(illum, 3 | 5 | 7) {
            specular.max_element().clamp(0.0, 1.0)
        } else {
            0.0
        },
        opacity: m.dissolve.unwrap_or(1.0) as f32,
        texture: m
            .diffuse_texture
            .as_deref()
            .and_then(|file| textures.load(file, &m.name)),
    }
}

/// One PLY element row, keeping only what a mesh needs: the crate's default element is a map
/// per row, hundreds of bytes for each vertex of what may be a multi-million-vertex scan.
#[derive(Default)]
struct PlyRow {
    xyz: [Option<f64>; 3],
    indices: Option<Vec<i64>>,
    /// A vertex colour's red, green and blue from 0 to 1; bit k of `has_rgb` says channel k
    /// was given.
    rgb: [f32; 3],
    has_rgb: u8,
}

/// A PLY colour channel from 0 to 1: integers count up to their type's largest value, floats
/// are that fraction already.
fn ply_channel(property: &ply_rs_bw::ply::Property) -> Option<f32> {
    use ply_rs_bw::ply::Property as P;
    Some(match *property {
        P::UChar(v) => v as f32 / 255.0,
        P::UShort(v) => v as f32 / 65535.0,
        P::Float(v) => v,
        P::Double(v) => v as f32,
        _ => return None,
    })
}

impl ply_rs_bw::ply::PropertyAccess for PlyRow {
    fn new() -> Self {
        Self::default()
    }

    fn set_property(
        &mut self,
        name: &str,
        property: ply_rs_bw::ply::Property,
    ) -> ply_rs_bw::ply::PropertyAccessResult {
        use ply_rs_bw::ply::{Property as P, PropertyAccessResult as R};
        let channel = match name {
            "red" | "diffuse_red" | "r" => Some(0),
            "green" | "diffuse_green" | "g" => Some(1),
            "blue" | "diffuse_blue" | "b" => Some(2),
            _ => None,
        };
        if let Some(k) = channel {
            let Some(value) = ply_channel(&property) else {
                return R::UnsupportedType;
            };
            self.rgb[k] = value;
            self.has_rgb |= 1 << k;
            return R::Set;
        }
        let axis = match name {
            "x" => 0,
            "y" => 1,
            "z" => 2,
            "vertex_indices" | "vertex_index" => {
                fn wide<T: Into<i64>>(list: Vec<T>) -> Vec<i64> {
                    list.into_iter().map(Into::into).collect()
                }
                self.indices = Some(match property {
                    P::ListChar(l) => wide(l),
                    P::ListUChar(l) => wide(l),
                    P::ListShort(l) => wide(l),
                    P::ListUShort(l) => wide(l),
                    P::ListInt(l) => wide(l),
                    P::ListUInt(l) => wide(l),
                    _ => return R::UnsupportedType,
                });
                return R::Set;
            }
            _ => return R::Ignored,
        };
        let value = match property {
            P::Char(v) => Some(f64::from(v)),
            P::UChar(v) => Some(f64::from(v)),
            P::Short(v) => Some(f64::from(v)),
            P::UShort(v) => Some(f64::from(v)),
            P::Int(v) => Some(f64::from(v)),
            P::UInt(v) => Some(f64::from(v)),
            P::Float(v) => Some(f64::from(v)),
            // Read in full: a scan far from the origin keeps its detail until the local origin.
            P::Double(v) => Some(v),
            _ => None,
        };
        match value {
            Some(value) => {
                self.xyz[axis] = Some(value);
                R::Set
            }
            None => R::UnsupportedType,
        }
    }
}

/// Reads a PLY file row by row into the mesh: no element's rows are held, so the load's peak
/// is the mesh itself (the crate's own payload reader kept every row, each face with its own
/// index list: 150 MB, 172 bytes a triangle, for the 871k-triangle dragon).
fn load_ply(path: &Path) -> Result<Mesh, SceneError> {
    use ply_rs_bw::parser::{Parser, Reader};
    use ply_rs_bw::ply::Encoding;

    let err = |message: String| file_error(path, message);
    let file = std::fs::File::open(path).map_err(|e| file_error(path, e))?;
    let mut reader = Reader::new(std::io::BufReader::new(file));
    let parser = Parser::<PlyRow>::new();
    let header = parser.read_header(&mut reader).map_err(|e| {
        err(format!(
            "not a valid PLY file: {}",
            one_line(&e.to_string())
        ))
    })?;
    check_ply_header(path, &header)?;
    let mut rows = PlyRows {
        path,
        ascii: header.encoding == Encoding::Ascii,
        first_line: reader.line().max(1),
    };
    let mut mesh = Mesh::default();
    let mut colors = Some(Vec::new());
    let mut seen_vertices = false;
    for (name, def) in &header.elements {
        let each = |index: usize, row: PlyRow, rows: &PlyRows| match name.as_str() {
            "vertex" => rows.vertex(index, row, &mut mesh, &mut colors),
            "face" if !seen_vertices => Err(err("has its `face` element before `vertex`".into())),
            "face" => rows.face(index, row, &mut mesh),
            _ => Ok(()),
        };
        rows.read_element(
            &parser,
            reader.get_mut(),
            (name, def),
            header.encoding,
            each,
        )?;
        seen_vertices |= name == "vertex";
        rows.first_line += def.count;
    }
    if u32::try_from(mesh.positions.len()).is_err() {
        return Err(err(format!(
            "{} vertices is more than 32-bit indices reach",
            mesh.positions.len()
        )));
    }
    mesh.colors.vertex = colors.unwrap_or_default();
    Ok(mesh)
}

/// Refuses a PLY header whose element counts the file cannot hold, or that lacks the vertex
/// and face properties a mesh needs: a header fault, said once rather than for every row.
fn check_ply_header(path: &Path, header: &ply_rs_bw::ply::Header) -> Result<(), SceneError> {
    let err = |message: String| file_error(path, message);
    // Every row takes at least a byte (a property, or an ascii line's end), so a count beyond
    // the file's length is a lie, and the crate would allocate for it before reading a row
    // (found by fuzzing: an element of no properties and 10^16 rows).
    let file_bytes = std::fs::metadata(path).map_or(u64::MAX, |m| m.len());
    for (name, def) in &header.elements {
        if def.count as u64 > file_bytes {
            return Err(err(format!(
                "element `{name}` claims {} rows, more than the file's {file_bytes} bytes hold",
                def.count
            )));
        }
    }
    for element in ["vertex", "face"] {
        let Some(def) = header.elements.get(element) else {
            return Err(err(format!("has no `{element}` element")));
        };
        let missing = |p: &str| !def.properties.contains_key(p);
        let absent = match element {
            "vertex" => ["x", "y", "z"].into_iter().find(|p| missing(p)),
            _ => (missing("vertex_indices") && missing("vertex_index")).then_some("vertex_indices"),
        };
        if let Some(p) = absent {
            return Err(err(format!(
                "the `{element}` element has no `{p}` property"
            )));
        }
    }
    Ok(())
}

/// A PLY file's element rows, read into a mesh with errors that say where a row is: its
/// index, and for ascii files its line too.
struct PlyRows<'a> {
    path: &'a Path,
    ascii: bool,
    /// The line of the element being read's first row (ascii files).
    first_line: usize,
}

impl PlyRows<'_> {
    fn err(&self, message: String) -> SceneError {
        file_error(self.path, message)
    }

    /// Where row `index` of element `name` is.
    fn row(&self, name: &str, index: usize) -> String {
        if self.ascii {
            format!("{name} {index} (line {})", self.first_line + index)
        } else {
            format!("{name} {index}")
        }
    }

    /// Reads element `name`'s rows one at a time, handing each to `each` with its index.
    fn read_element<R: std::io::BufRead>(
        &self,
        parser: &ply_rs_bw::parser::Parser<PlyRow>,
        reader: &mut R,
        (name, def): (&str, &ply_rs_bw::ply::ElementDef),
        encoding: ply_rs_bw::ply::Encoding,
        mut each: impl FnMut(usize, PlyRow, &Self) -> Result<(), SceneError>,
    ) -> Result<(), SceneError> {
        use ply_rs_bw::ply::Encoding;
        let mut line = String::with_capacity(128);
        for index in 0..def.count {
            let row = match encoding {
                Encoding::Ascii => self.ascii_row(parser, reader, &mut line, (name, def), index)?,
                Encoding::BinaryLittleEndian => parser
                    .read_little_endian_element(reader, def)
                    .map_err(|e| self.binary_error(name, def.count, index, e))?,
                Encoding::BinaryBigEndian => parser
                    .read_big_endian_element(reader, def)
                    .map_err(|e| self.binary_error(name, def.count, index, e))?,
            };
            each(index, row, self)?;
        }
        Ok(())
    }

    /// Ascii row `index` of element `name`, read through `line`.
    fn ascii_row<R: std::io::BufRead>(
        &self,
        parser: &ply_rs_bw::parser::Parser<PlyRow>,
        reader: &mut R,
        line: &mut String,
        (name, def): (&str, &ply_rs_bw::ply::ElementDef),
        index: usize,
    ) -> Result<PlyRow, SceneError> {
        let at = || self.row(name, index);
        line.clear();
        let read = reader
            .read_line(line)
            .map_err(|e| self.err(e.to_string()))?;
        if read == 0 {
            return Err(self.err(format!(
                "{}: Unexpected end of file while reading element '{name}' (expected {}, got {index}).",
                at(),
                def.count
            )));
        }
        parser.read_ascii_element(line, def).map_err(|e| {
            let text = line.trim_end();
            let why = format!("Couldn't read element line.\n\tString: '{text}'\n\tError: {e}");
            self.err(format!("{}: {}", at(), one_line(&why)))
        })
    }

    /// The crate's error reading binary row `index` of `count`, naming the row at fault.
    fn binary_error(
        &self,
        name: &str,
        count: usize,
        index: usize,
        e: ply_rs_bw::parser::ParseError,
    ) -> SceneError {
        let at = self.row(name, index);
        if e.kind() == std::io::ErrorKind::UnexpectedEof {
            return self.err(format!(
                "{at}: Unexpected end of file while reading binary element '{name}' (expected {count}, got {index})"
            ));
        }
        self.err(format!("{at}: {}", one_line(&e.to_string())))
    }

    /// Vertex row `index` as the mesh's next position, and its colour while every vertex so
    /// far has all three channels (a partial set is no colour).
    fn vertex(
        &self,
        index: usize,
        vertex: PlyRow,
        mesh: &mut Mesh,
        colors: &mut Option<Vec<[u8; 3]>>,
    ) -> Result<(), SceneError> {
        let at = || self.row("vertex", index);
        let [Some(x), Some(y), Some(z)] = vertex.xyz else {
            return Err(self.err(format!("{} lacks one of x, y, z", at())));
        };
        let p = DVec3::new(x, y, z);
        if !in_range(p) {
            return Err(self.err(format!("{} has a non-finite coordinate {p}", at())));
        }
        mesh.positions.push(p);
        match colors {
            Some(list) if vertex.has_rgb == 0b111 => {
                list.push(SurfaceColors::encode_unit(vertex.rgb))
            }
            _ => *colors = None,
        }
        Ok(())
    }

    /// Face row `index` as the mesh's triangles, a polygon as a fan.
    fn face(&self, index: usize, face: PlyRow, mesh: &mut Mesh) -> Result<(), SceneError> {
        let count = mesh.positions.len();
        let at = || self.row("face", index);
        let list = face
            .indices
            .as_deref()
            .ok_or_else(|| self.err(format!("{} has no `vertex_indices` list", at())))?;
        if list.len() < 3 {
            return Err(self.err(format!(
                "{} has {} vertices, fewer than 3",
                at(),
                list.len()
            )));
        }
        if let Some(&bad) = list.iter().find(|&&v| v < 0 || v as usize >= count) {
            return Err(self.err(format!(
                "{} uses vertex {bad}, but there are only {count} vertices",
                at()
            )));
        }
        // In range of a u32-indexed vertex list, checked just above.
        let v = |k: usize| list[k] as u32;
        for k in 1..list.len() - 1 {
            mesh.triangles.push([v(0), v(k), v(k + 1)]);
        }
        Ok(())
    }
}

/// The crate's messages nest, `what\n\tString: '<text>'\n\tError: <cause>`, sometimes twice
/// over; a scene error is one line: what, the text at fault, and the innermost cause.
fn one_line(text: &str) -> String {
    let mut parts = text.split("\n\t");
    let mut out = parts.next().unwrap_or_default().trim().to_string();
    let (mut quoted, mut cause) = (None, None);
    for part in parts {
        if let Some(text) = part.strip_prefix("String: ") {
            quoted.get_or_insert(text.trim().trim_matches('\'').trim());
        } else if let Some(text) = part.strip_prefix("Error: ") {
            cause = Some(text.trim());
        }
    }
    if let Some(quoted) = quoted {
        out = format!("{} `{quoted}`", out.trim_end_matches('.'));
    }
    // Header faults carry the grammar's debug dump as the cause; the line says more.
    if let Some(cause) = cause.filter(|c| !c.starts_with("ParseError {")) {
        out = format!("{}: {cause}", out.trim_end_matches('.'));
    }
    out.replace(['\n', '\r', '\t'], " ")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Loads `bytes` as file `name`; the result, or the error text, which must name the file.
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

    const PLY_HEAD: &str = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\n\
property float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\n\
end_header\n";

    fn binary_ply(coords: [f32; 12], face: &[u8]) -> Vec<u8> {
        let mut bytes = PLY_HEAD
            .replace("ascii", "binary_little_endian")
            .into_bytes();
        coords.iter().for_each(|c| bytes.extend(c.to_le_bytes()));
        bytes.extend(face);
        bytes
    }

    #[test]
    fn obj_quad_is_triangulated_and_relative_and_forward_indices_work() {
        let mesh = load("q.obj", b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n").unwrap();
        assert_eq!(mesh.positions.len(), 4);
        assert_eq!(mesh.triangles.len(), 2);
        let mesh = load("r.obj", b"f 1 2 3\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\n").unwrap();
        assert_eq!(mesh.triangles.len(), 2);
    }

    #[test]
    fn obj_materials_come_from_the_mtl_file_and_a_missing_mtl_is_not_fatal() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(
            dir.path().join("m.mtl"),
            "newmtl matte\nKd 0.5 0.25 0.125\nillum 1\n\
             newmtl shiny\nKd 1 1 1\nKs 0.4 0.4 0.4\nNs 80\nillum 2\n\
             newmtl chrome\nKd 0 0 0\nKs 0.9 0.9 0.9\nillum 3\n\
             newmtl glass\nKd 0.2 0.5 0.8\nd 0.25\n",
        )
        .unwrap();
        let obj = "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nusemtl glass\nf 1 2 3\n\
                   usemtl matte\nf 1 2 3\nusemtl chrome\nf 1 2 3\nusemtl shiny\nf 1 2 3\n";
        let path = dir.path().join("m.obj");
        std::fs::write(&path, obj).unwrap();
        let mesh = load_mesh_file(&path).unwrap();
        let of = |i: usize| mesh.materials[mesh.triangle_material[i] as usize];
        assert_eq!(mesh.triangles.len(), 5);
        assert_eq!(of(0), crate::scene::NEUTRAL, "faces before any usemtl");
        assert!(of(1).is_transparent() && of(1).opacity == 0.25);
        assert_eq!(of(2).albedo, Vec3::new(0.5, 0.25, 0.125));
        assert!(!of(2).has_specular() && !of(2).is_mirror());
        assert!(of(3).is_mirror() && of(3).mirror == 0.9);
        assert!(of(4).has_specular() && of(4).shininess == 80.0 && !of(4).is_mirror());

        std::fs::remove_file(dir.path().join("m.mtl")).unwrap();
        let mesh = load_mesh_file(&path).unwrap();
        assert!(mesh.materials.is_empty() && mesh.triangles.len() == 5);
    }

    #[test]
    fn obj_errors_name_the_line() {
        #[rustfmt::skip]
        let cases = [
            ("v 1 zz 0\nf 1 2 3\n", "line 4: vertex 3 coordinate `zz` is not a number"),
            ("v 1 nan 0\nf 1 2 3\n", "line 4: vertex 3 coordinate `nan` is not finite"),
            ("v 1 1 inf\nf 1 2 3\n", "line 4: vertex 3 coordinate `inf` is not finite"),
            ("v 1 1e39 0\nf 1 2 3\n", "line 4: vertex 3 coordinate `1e39` is not finite"),
            ("v 1 1\nf 1 2 3\n", "line 4: vertex 3 has 2 values"),
            ("v 1 1 1 0\nf 1 2 3\n", "line 4: vertex 3 weight `0` gives a non-finite"),
            ("v 0 1 0\nf 1 2 9\n", "line 5: face uses vertex 9, but the file has only 3"),
            ("v 0 1 0\nf 1 2 0\n", "line 5: face uses vertex index 0"),
            ("v 0 1 0\nf 1 2 -4\n", "line 5: face uses relative vertex -4"),
            ("v 0 1 0\nf 1 2 x\n", "line 5: face vertex `x` is not an index"),
            ("vn 0 q 1\nv 0 1 0\nf 1 2 3\n", "line 4: `vn` needs 3 numbers"),
            ("v 0 1 0\nf\nf 1 2 3\n", "line 5: face has no vertices"),
            ("v 0 1 0\nusemtl \nf 1 2 3\n", "line 5: `usemtl` names no material"),
        ];
        for (tail, want) in cases {
            assert_fails(
                "bad.obj",
                format!("# c\nv 0 0 0\nv 1 0 0\n{tail}").as_bytes(),
                want,
            );
        }
    }

    #[test]
    fn ascii_and_binary_ply_give_the_same_mesh() {
        let ascii = format!("{PLY_HEAD}0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n");
        let a = load("a.ply", ascii.as_bytes()).unwrap();
        let square = [0., 0., 0., 1., 0., 0., 1., 1., 0., 0., 1., 0.];
        let b = load(
            "b.ply",
            &binary_ply(square, &[4, 0, 0, 0, 0, 1, 0, 0, 0, 2, 0, 0, 0, 3, 0, 0, 0]),
        );
        let b = b.unwrap();
        assert_eq!(a.positions, b.positions);
        assert_eq!(a.triangles, b.triangles);
        assert_eq!(a.triangles, vec![[0, 1, 2], [0, 2, 3]]);
    }

    #[test]
    fn ply_errors_name_the_element() {
        // Header lines 1-9, so vertex 0 is line 10 and face 0 line 14.
        #[rustfmt::skip]
        let cases = [
            ("1 zz 0\n0 1 0\n4 0 1 2 3\n", "vertex 2 (line 12): Couldn't read element line `1 zz 0`"),
            ("1 nan 0\n0 1 0\n4 0 1 2 3\n", "vertex 2 (line 12): Couldn't read element line"),
            ("1 1 0\n0 1e39 0\n4 0 1 2 3\n", "vertex 3 (line 13) has a non-finite coordinate"),
            ("1 1 0\n0 1 0\n4 0 1 2 7\n", "face 0 (line 14) uses vertex 7, but there are only 4"),
            ("1 1 0\n0 1 0\n4 0 1 -1 2\n", "face 0 (line 14) uses vertex -1"),
            ("1 1 0\n0 1 0\n2 0 1\n", "face 0 (line 14) has 2 vertices, fewer than 3"),
            ("", "vertex 2 (line 12): Unexpected end of file"),
        ];
        for (tail, want) in cases {
            assert_fails(
                "bad.ply",
                format!("{PLY_HEAD}0 0 0\n1 0 0\n{tail}").as_bytes(),
                want,
            );
        }
        // A binary file has no lines: its rows are named by index alone.
        let nan = binary_ply(
            [0., 0., 0., 1., 0., 0., 1., f32::NAN, 0., 0., 1., 0.],
            &[3, 0, 0, 0, 0, 1, 0, 0, 0, 2, 0, 0, 0],
        );
        assert_fails("nan.ply", &nan, "vertex 2 has a non-finite");
        assert_fails(
            "short.ply",
            &nan[..nan.len() - 30],
            "vertex 2: Unexpected end of file",
        );
    }

    #[test]
    fn bad_files_name_the_file() {
        assert_fails(
            "g.ply",
            b"this is not a ply\n",
            "not a valid PLY file: Line 1: Expected magic",
        );
        let no_z = PLY_HEAD.replace("property float z\n", "");
        assert_fails(
            "noz.ply",
            no_z.as_bytes(),
            "the `vertex` element has no `z` property",
        );
        // A count no file of this size could hold is refused before anything is allocated.
        let huge = PLY_HEAD.replace(
            "element face 1",
            "element junk 11326434445538011\nelement face 1",
        );
        assert_fails(
            "huge.ply",
            huge.as_bytes(),
            "element `junk` claims 11326434445538011 rows",
        );
        let no_face = PLY_HEAD.replace("element face 1", "element edge 1");
        assert_fails("noface.ply", no_face.as_bytes(), "has no `face` element");
        let err = load_mesh_file(Path::new("/nonexistent/missing.obj"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("missing.obj"), "{err}");
        let err = load_mesh_file(Path::new("x.3ds")).unwrap_err().to_string();
        assert!(err.contains("x.3ds") && err.contains("extension"), "{err}");
    }
}
