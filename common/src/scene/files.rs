//! Mesh files: OBJ (via `tobj`) and PLY, ascii or binary (via `ply-rs-bw`).

use super::{Mesh, SceneError};
use glam::Vec3;
use std::path::Path;

/// Reads the triangles of an OBJ or PLY file; polygons are fan-triangulated.
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
        _ => Err(SceneError::UnknownFormat {
            path: path.display().to_string(),
        }),
    }
}

fn file_error(path: &Path, message: impl ToString) -> SceneError {
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
    // Materials only affect colour, which the first renderer takes from the scene, so a missing
    // .mtl must not make a mesh unloadable.
    let (models, _) = tobj::load_obj_buf(&mut reader, &options, |_| {
        Ok((Vec::new(), Default::default()))
    })
    .map_err(|e| file_error(path, format!("not a valid OBJ file: {e}")))?;
    let mut mesh = Mesh::default();
    for model in models {
        let m = model.mesh;
        let base = mesh.positions.len() as u32;
        if m.positions.len() % 3 != 0 {
            return Err(file_error(
                path,
                "vertex list is not a multiple of 3 floats",
            ));
        }
        mesh.positions.extend(
            m.positions
                .chunks_exact(3)
                .map(|p| Vec3::new(p[0], p[1], p[2])),
        );
        let count = m.positions.len() as u32 / 3;
        for (face, tri) in m.indices.chunks_exact(3).enumerate() {
            if let Some(&bad) = tri.iter().find(|&&i| i >= count) {
                return Err(file_error(
                    path,
                    format!(
                        "object `{}` face {face} uses vertex {} of {count}",
                        model.name,
                        bad + 1
                    ),
                ));
            }
            mesh.triangles
                .push([base + tri[0], base + tri[1], base + tri[2]]);
        }
    }
    Ok(mesh)
}

fn load_ply(path: &Path) -> Result<Mesh, SceneError> {
    use ply_rs_bw::parser::Parser;
    use ply_rs_bw::ply::{DefaultElement, Property};

    let file = std::fs::File::open(path).map_err(|e| file_error(path, e))?;
    let mut reader = std::io::BufReader::new(file);
    let ply = Parser::<DefaultElement>::new()
        .read_ply(&mut reader)
        .map_err(|e| file_error(path, format!("not a valid PLY file: {e}")))?;
    let vertices = ply
        .payload
        .get("vertex")
        .ok_or_else(|| file_error(path, "has no `vertex` element"))?;
    let mut mesh = Mesh::default();
    for (index, vertex) in vertices.iter().enumerate() {
        let coord = |name: &str| {
            vertex
                .get(name)
                .and_then(Property::to_f32_lossy)
                .ok_or_else(|| file_error(path, format!("vertex {index} has no scalar `{name}`")))
        };
        mesh.positions
            .push(Vec3::new(coord("x")?, coord("y")?, coord("z")?));
    }
    let faces = ply
        .payload
        .get("face")
        .ok_or_else(|| file_error(path, "has no `face` element"))?;
    for (index, face) in faces.iter().enumerate() {
        let list = face
            .get("vertex_indices")
            .or_else(|| face.get("vertex_index"))
            .and_then(Property::to_u32_list)
            .ok_or_else(|| {
                file_error(path, format!("face {index} has no `vertex_indices` list"))
            })?;
        if list.len() < 3 {
            return Err(file_error(
                path,
                format!("face {index} has {} vertices, fewer than 3", list.len()),
            ));
        }
        for k in 1..list.len() - 1 {
            mesh.triangles.push([list[0], list[k], list[k + 1]]);
        }
    }
    Ok(mesh)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    fn write(dir: &Path, name: &str, text: &[u8]) -> std::path::PathBuf {
        let path = dir.join(name);
        std::fs::File::create(&path)
            .unwrap()
            .write_all(text)
            .unwrap();
        path
    }

    #[test]
    fn obj_quad_is_triangulated() {
        let dir = tempfile::tempdir().unwrap();
        let path = write(
            dir.path(),
            "q.obj",
            b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n",
        );
        let mesh = load_mesh_file(&path).unwrap();
        assert_eq!(mesh.positions.len(), 4);
        assert_eq!(mesh.triangles.len(), 2);
    }

    #[test]
    fn ascii_and_binary_ply_give_the_same_mesh() {
        let dir = tempfile::tempdir().unwrap();
        let ascii = write(
            dir.path(),
            "a.ply",
            b"ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n\
property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n\
0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n",
        );
        let mut binary = b"ply\nformat binary_little_endian 1.0\nelement vertex 4\n\
property float x\nproperty float y\nproperty float z\nelement face 1\n\
property list uchar int vertex_indices\nend_header\n"
            .to_vec();
        for p in [[0f32, 0., 0.], [1., 0., 0.], [1., 1., 0.], [0., 1., 0.]] {
            for c in p {
                binary.extend(c.to_le_bytes());
            }
        }
        binary.push(4);
        for i in [0i32, 1, 2, 3] {
            binary.extend(i.to_le_bytes());
        }
        let binary = write(dir.path(), "b.ply", &binary);
        let a = load_mesh_file(&ascii).unwrap();
        let b = load_mesh_file(&binary).unwrap();
        assert_eq!(a.positions, b.positions);
        assert_eq!(a.triangles, b.triangles);
        assert_eq!(a.triangles, vec![[0, 1, 2], [0, 2, 3]]);
    }

    #[test]
    fn bad_files_name_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let garbage = write(dir.path(), "g.ply", b"this is not a ply\n");
        let err = load_mesh_file(&garbage).unwrap_err().to_string();
        assert!(err.contains("g.ply"), "{err}");
        let missing = dir.path().join("missing.obj");
        let err = load_mesh_file(&missing).unwrap_err().to_string();
        assert!(err.contains("missing.obj"), "{err}");
        let err = load_mesh_file(Path::new("x.stl")).unwrap_err().to_string();
        assert!(err.contains("x.stl") && err.contains("extension"), "{err}");
    }
}
