//! glTF 2.0 meshes: `.gltf` (buffers in external files or data URIs) and binary `.glb`.
//!
//! The `gltf` crate parses and validates the document; accessor data is read here instead of
//! through its reader, whose offset arithmetic is unchecked and panics on corrupt counts or
//! component types. A bad file must be an error naming the element, never a crashed node.

use super::colors::{encode_linear, SurfaceColors, TextureFiles};
use super::files::file_error;
use super::{Mesh, SceneError, MAX_TRIANGLES};
use glam::{Mat4, Vec2, Vec3, Vec4};
use gltf::accessor::{DataType, Dimensions};
use gltf::mesh::Mode;
use std::collections::hash_map::{Entry, HashMap};
use std::path::Path;

/// Reads the triangles of every mesh instanced by the default scene (every scene if there is
/// none, every root node if there are no scenes), in world space.
///
/// Triangle strips and fans are converted; points and lines are skipped with a warning.
/// Materials keep their base colour texture (on `TEXCOORD_0`, repeating) and vertices their
/// `COLOR_0`; skins and morph targets are ignored: a mesh is traced in its bind pose.
///
/// # Errors
/// A [`SceneError`] naming the file and the element (mesh, primitive, node, buffer) at fault.
pub fn load_gltf(path: &Path) -> Result<Mesh, SceneError> {
    let err = |message: String| file_error(path, message);
    let bytes = std::fs::read(path).map_err(|e| file_error(path, e))?;
    check_glb_header(&bytes).map_err(err)?;
    check_attribute_accessors(&bytes).map_err(err)?;
    let gltf::Gltf { document, blob } =
        gltf::Gltf::from_slice(&bytes).map_err(|e| err(format!("not a valid glTF file: {e}")))?;
    drop(bytes);
    let base = path.parent().unwrap_or(Path::new("."));
    let buffers = load_buffers(&document, base, blob).map_err(err)?;

    let mut mesh = materials_of(&document, &buffers, path)?;
    let mut decoded: HashMap<usize, Mesh> = HashMap::new();
    for (node, world) in instances(&document).map_err(err)? {
        let Some(source) = node.mesh() else { continue };
        let local = match decoded.entry(source.index()) {
            Entry::Occupied(known) => known.into_mut(),
            Entry::Vacant(new) => new.insert(
                decode_mesh(&source, &buffers, path, document.materials().len()).map_err(err)?,
            ),
        };
        let base = mesh.positions.len();
        if u32::try_from(base + local.positions.len()).is_err() {
            return Err(err("more vertices than 32-bit indices reach".into()));
        }
        let (uvs, vertex) = (&local.colors.uvs, &local.colors.vertex);
        mesh.colors
            .extend_vertices(base, local.positions.len(), uvs, vertex);
        for (i, &p) in local.positions.iter().enumerate() {
            // In f64: a node placed far from the origin keeps its mesh's detail.
            let p = world.as_dmat4().transform_point3(p);
            if !p.is_finite() {
                return Err(err(format!(
                    "node {}: its transform makes vertex {i} of mesh {} non-finite",
                    node.index(),
                    source.index()
                )));
            }
            mesh.positions.push(p);
        }
        // A mirroring transform turns the winding over; glTF asks for it to be restored so that
        // front faces stay front faces.
        let mirrored = world.determinant() < 0.0;
        let base = base as u32;
        mesh.triangles
            .extend(local.triangles.iter().map(|&[a, b, c]| {
                let [a, b, c] = [a + base, b + base, c + base];
                if mirrored {
                    [a, c, b]
                } else {
                    [a, b, c]
                }
            }));
        mesh.triangle_material
            .extend_from_slice(&local.triangle_material);
        if mesh.triangles.len() > MAX_TRIANGLES {
            return Err(SceneError::TooLarge {
                origin: path.display().to_string(),
                count: mesh.triangles.len(),
                limit: MAX_TRIANGLES,
            });
        }
    }
    Ok(mesh)
}

/// A mesh with no triangles yet and the file's materials, its textures read, glTF's default
/// material (for primitives without one) last.
fn materials_of(
    document: &gltf::Document,
    buffers: &[Vec<u8>],
    path: &Path,
) -> Result<Mesh, SceneError> {
    let mut mesh = Mesh::default();
    if document.materials().len() >= u16::MAX as usize {
        return Err(file_error(
            path,
            format!(
                "has {} materials; at most 65534 are supported",
                document.materials().len()
            ),
        ));
    }
    let mut textures = TextureFiles::new(path);
    mesh.materials = document
        .materials()
        .map(|m| gltf_material(&m, buffers, &mut textures))
        .collect();
    mesh.colors.textures = textures.textures;
    mesh.material_names = document
        .materials()
        .map(|m| m.name().unwrap_or("unnamed").to_string())
        .collect();
    mesh.materials.push(super::NEUTRAL);
    mesh.material_names.push("glTF default".into());
    Ok(mesh)
}

/// The crate computes `length - 12` from the GLB header unchecked: a corrupt length would panic
/// (debug) or wrap (release) inside it.
fn check_glb_header(bytes: &[u8]) -> Result<(), String> {
    if !bytes.starts_with(b"glTF") {
        return Ok(());
    }
    let Some(length) = bytes.get(8..12) else {
        return Err(format!("GLB header truncated: {} bytes", bytes.len()));
    };
    let length = u32::from_le_bytes(length.try_into().unwrap_or_default());
    if length < 12 {
        return Err(format!(
            "GLB header gives a total length of {length} bytes, under 12"
        ));
    }
    Ok(())
}

/// gltf-json 1.4 looks up a primitive's POSITION accessor while validating, before it checks
/// that the index exists, and panics on one past the end (found by fuzzing): such a file is
/// refused here first. Anything else that does not parse is left for the crate to report.
fn check_attribute_accessors(bytes: &[u8]) -> Result<(), String> {
    let json = match gltf::Glb::from_slice(bytes) {
        Ok(glb) if bytes.starts_with(b"glTF") => glb.json,
        _ => bytes.into(),
    };
    let Ok(root) = gltf::json::Root::from_slice(&json) else {
        return Ok(());
    };
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, primitive) in mesh.primitives.iter().enumerate() {
            for index in primitive.attributes.values() {
                if index.value() >= root.accessors.len() {
                    return Err(format!(
                        "mesh {m}, primitive {p}: accessor {} does not exist ({} accessors)",
                        index.value(),
                        root.accessors.len()
                    ));
                }
            }
        }
    }
    Ok(())
}

/// Every buffer's bytes: from the GLB binary chunk, a data URI, or a file beside the glTF.
fn load_buffers(
    document: &gltf::Document,
    base: &Path,
    mut blob: Option<Vec<u8>>,
) -> Result<Vec<Vec<u8>>, String> {
    use gltf::buffer::Source;
    let mut buffers = Vec::new();
    for buffer in document.buffers() {
        let i = buffer.index();
        let (data, origin) = match buffer.source() {
            // Relative paths are resolved here: the crate unwraps their percent-decoding.
            Source::Uri(uri) if !uri.contains(':') => {
                let name = percent_decode(uri)
                    .ok_or_else(|| format!("buffer {i}: uri `{uri}` is badly percent-encoded"))?;
                let file = base.join(name);
                let data = std::fs::read(&file)
                    .map_err(|e| format!("buffer {i}: cannot read {}: {e}", file.display()))?;
                (data, file.display().to_string())
            }
            source => {
                let origin = match source {
                    Source::Uri(uri) if uri.starts_with("data:") => "data URI".to_string(),
                    Source::Uri(uri) => uri.to_string(),
                    Source::Bin => "GLB binary chunk".to_string(),
                };
                let data = gltf::buffer::Data::from_source_and_blob(source, Some(base), &mut blob)
                    .map_err(|e| format!("buffer {i} ({origin}): {e}"))?;
                (data.0, origin)
            }
        };
        if data.len() < buffer.length() {
            return Err(format!(
                "buffer {i} ({origin}) holds {} bytes, but the glTF says {}",
                data.len(),
                buffer.length()
            ));
        }
        buffers.push(data);
    }
    Ok(buffers)
}

/// `%XX` escapes decoded, or `None` if one is malformed or the result is not UTF-8.
fn percent_decode(uri: &str) -> Option<String> {
    let mut out = Vec::with_capacity(uri.len());
    let mut rest = uri.as_bytes();
    while let Some((&byte, tail)) = rest.split_first() {
        if byte == b'%' {
            let hex = tail
                .get(..2)
                .filter(|h| h.iter().all(u8::is_ascii_hexdigit))?;
            out.push(u8::from_str_radix(std::str::from_utf8(hex).ok()?, 16).ok()?);
            rest = &tail[2..];
        } else {
            out.push(byte);
            rest = tail;
        }
    }
    String::from_utf8(out).ok()
}

/// The nodes to draw with their world transforms, in document order so that every node loads
/// the scene into identical bytes.
fn instances(document: &gltf::Document) -> Result<Vec<(gltf::Node<'_>, Mat4)>, String> {
    let roots: Vec<gltf::Node> = match document.default_scene() {
        Some(scene) => scene.nodes().collect(),
        None if document.scenes().len() > 0 => document.scenes().flat_map(|s| s.nodes()).collect(),
        None => {
            let mut is_child = vec![false; document.nodes().len()];
            for child in document.nodes().flat_map(|n| n.children()) {
                is_child[child.index()] = true;
            }
            document.nodes().filter(|n| !is_child[n.index()]).collect()
        }
    };
    // Scenes may share root nodes; each is drawn once.
    let mut is_root = vec![false; document.nodes().len()];
    let mut stack: Vec<(gltf::Node, Mat4)> = roots
        .into_iter()
        .filter(|n| !std::mem::replace(&mut is_root[n.index()], true))
        .map(|n| (n, Mat4::IDENTITY))
        .collect();
    stack.reverse();
    // glTF node hierarchies are disjoint trees; a node met twice means a cycle, which would
    // never end, or a shared child, which can multiply geometry exponentially.
    let mut seen = vec![false; document.nodes().len()];
    let mut out = Vec::new();
    while let Some((node, parent)) = stack.pop() {
        if std::mem::replace(&mut seen[node.index()], true) {
            return Err(format!(
                "node {} is reached twice: the node hierarchy is not a tree",
                node.index()
            ));
        }
        let world = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
        let children: Vec<_> = node.children().collect();
        stack.extend(children.into_iter().rev().map(|c| (c, world)));
        out.push((node, world));
    }
    Ok(out)
}

/// One mesh's triangle primitives merged, in the mesh's own space.
/// `default_material` is the index that primitives without a material get.
fn decode_mesh(
    mesh: &gltf::Mesh,
    buffers: &[Vec<u8>],
    path: &Path,
    default_material: usize,
) -> Result<Mesh, String> {
    let mut out = Mesh::default();
    for primitive in mesh.primitives() {
        let at = format!("mesh {} primitive {}", mesh.index(), primitive.index());
        let mode = primitive.mode();
        if !matches!(
            mode,
            Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan
        ) {
            tracing::warn!(
                file = %path.display(),
                "skipping {mode:?} primitive {} of mesh {} `{}`: only triangles are traced",
                primitive.index(),
                mesh.index(),
                mesh.name().unwrap_or_default()
            );
            continue;
        }
        let accessor = primitive
            .get(&gltf::Semantic::Positions)
            .ok_or_else(|| format!("{at}: has no POSITION attribute"))?;
        let positions = read_positions(&accessor, buffers)
            .map_err(|e| format!("{at}: POSITION accessor {}: {e}", accessor.index()))?;
        if let Some((i, p)) = positions.iter().enumerate().find(|(_, p)| !p.is_finite()) {
            return Err(format!("{at}: vertex {i} has a non-finite position {p}"));
        }
        let indices = match primitive.indices() {
            Some(accessor) => read_indices(&accessor, buffers)
                .map_err(|e| format!("{at}: index accessor {}: {e}", accessor.index()))?,
            None => (0..positions.len() as u32).collect(),
        };
        let count = positions.len();
        if let Some(bad) = indices.iter().find(|&&i| i as usize >= count) {
            return Err(format!("{at}: index {bad} out of range ({count} vertices)"));
        }
        let base = out.positions.len();
        if u32::try_from(base + count).is_err() {
            return Err(format!("{at}: more vertices than 32-bit indices reach"));
        }
        let base = base as u32;
        let at_base = |t: [u32; 3]| t.map(|i| i + base);
        match mode {
            Mode::Triangles if indices.len() % 3 != 0 => {
                let n = indices.len();
                return Err(format!(
                    "{at}: {n} indices is not a whole number of triangles"
                ));
            }
            Mode::Triangles => out
                .triangles
                .extend(indices.chunks_exact(3).map(|t| at_base([t[0], t[1], t[2]]))),
            // Every other strip triangle is reversed so that all keep the first one's winding.
            Mode::TriangleStrip => {
                out.triangles
                    .extend(indices.windows(3).enumerate().map(|(k, t)| match k % 2 {
                        0 => at_base([t[0], t[1], t[2]]),
                        _ => at_base([t[0], t[2], t[1]]),
                    }))
            }
            _ => out.triangles.extend(
                indices
                    .windows(2)
                    .skip(1)
                    .map(|t| at_base([indices[0], t[0], t[1]])),
            ),
        }
        let colors = primitive_colors(&primitive, buffers).map_err(|e| format!("{at}: {e}"))?;
        out.colors
            .extend_vertices(base as usize, count, &colors.uvs, &colors.vertex);
        out.positions.extend(positions.iter().map(|p| p.as_dvec3()));
        let material = primitive.material().index().unwrap_or(default_material) as u16;
        out.triangle_material.resize(out.triangles.len(), material);
    }
    Ok(out)
}

/// A primitive's `TEXCOORD_0` and `COLOR_0`, each empty when it has none.
fn primitive_colors(
    primitive: &gltf::Primitive,
    buffers: &[Vec<u8>],
) -> Result<SurfaceColors, String> {
    let mut out = SurfaceColors::default();
    if let Some(a) = primitive.get(&gltf::Semantic::TexCoords(0)) {
        out.uvs = read_vectors(&a, buffers, Dimensions::Vec2)
            .map_err(|e| format!("TEXCOORD_0 accessor {}: {e}", a.index()))?
            .into_iter()
            .map(|v| Vec2::new(v.x, v.y))
            .collect();
    }
    if let Some(a) = primitive.get(&gltf::Semantic::Colors(0)) {
        let dims = a.dimensions();
        let dims = if dims == Dimensions::Vec4 {
            dims
        } else {
            Dimensions::Vec3
        };
        out.vertex = read_vectors(&a, buffers, dims)
            .map_err(|e| format!("COLOR_0 accessor {}: {e}", a.index()))?
            .into_iter()
            .map(|v| encode_linear(v.truncate()))
            .collect();
    }
    Ok(out)
}

/// An accessor of `dims` floats or normalized unsigned integers (what glTF allows for texture
/// coordinates and colours), as floats, unused components zero.
fn read_vectors(
    accessor: &gltf::Accessor,
    buffers: &[Vec<u8>],
    dims: Dimensions,
) -> Result<Vec<Vec4>, String> {
    let kind = (
        accessor.dimensions(),
        accessor.data_type(),
        accessor.normalized(),
    );
    let n = dims.multiplicity();
    let component: fn(&[u8], usize) -> f32 = match kind {
        (d, DataType::F32, _) if d == dims => {
            |b, k| f32::from_le_bytes([b[4 * k], b[4 * k + 1], b[4 * k + 2], b[4 * k + 3]])
        }
        (d, DataType::U8, true) if d == dims => |b, k| b[k] as f32 / 255.0,
        (d, DataType::U16, true) if d == dims => {
            |b, k| u16::from_le_bytes([b[2 * k], b[2 * k + 1]]) as f32 / 65535.0
        }
        _ => {
            return Err(format!(
                "is {kind:?}; expected {dims:?} of FLOAT or normalized UNSIGNED_BYTE/SHORT"
            ))
        }
    };
    Ok(elements(accessor, buffers)?
        .map(|b| {
            let mut v = [0f32; 4];
            v.iter_mut()
                .take(n)
                .enumerate()
                .for_each(|(k, c)| *c = component(b, k));
            Vec4::from_array(v)
        })
        .collect())
}

/// The texture of a material's base colour, read from a buffer view, a data URI or a file
/// beside the glTF; `None`, with a warning naming the image, when it cannot be read or uses
/// texture coordinates other than `TEXCOORD_0`.
fn base_color_texture(
    m: &gltf::Material,
    buffers: &[Vec<u8>],
    textures: &mut TextureFiles,
) -> Option<u16> {
    use gltf::image::Source;
    let info = m.pbr_metallic_roughness().base_color_texture()?;
    let image = info.texture().source();
    let material = m.name().unwrap_or("unnamed");
    let name = format!("image {}", image.index());
    if info.tex_coord() != 0 {
        let why = format!(
            "it uses TEXCOORD_{}; only TEXCOORD_0 is read",
            info.tex_coord()
        );
        textures.warn(std::path::Path::new(&name), material, &why);
        return None;
    }
    let bytes = match image.source() {
        Source::View { view, .. } => buffers[view.buffer().index()]
            .get(view.offset()..view.offset().saturating_add(view.length()))
            .map(<[u8]>::to_vec)
            .ok_or("its buffer view runs past the end of its buffer".to_string()),
        Source::Uri { uri, .. } if uri.starts_with("data:") => {
            let source = gltf::buffer::Source::Uri(uri);
            gltf::buffer::Data::from_source_and_blob(source, None, &mut None)
                .map(|d| d.0)
                .map_err(|e| e.to_string())
        }
        Source::Uri { uri, .. } => {
            let Some(file) = percent_decode(uri) else {
                let why = "its uri is badly percent-encoded";
                textures.warn(std::path::Path::new(uri), material, why);
                return None;
            };
            let dir = textures.mesh.parent().unwrap_or(Path::new("."));
            return textures.load_path(dir.join(file), material);
        }
    };
    match bytes {
        Ok(bytes) => textures.decode(&name, &bytes, material),
        Err(why) => {
            textures.warn(std::path::Path::new(&name), material, &why);
            None
        }
    }
}

/// A metallic-roughness material as Tessera draws it: the base colour is the diffuse colour
/// (times its texture, if it has one); smooth surfaces get a Phong highlight whose width follows the roughness (the exponent that
/// matches a Beckmann lobe, 2/r⁴ − 2); smooth metals (roughness ≤ 0.1) become mirrors; alpha
/// mode BLEND makes the base colour's alpha the opacity.
fn gltf_material(
    m: &gltf::Material,
    buffers: &[Vec<u8>],
    textures: &mut TextureFiles,
) -> super::Material {
    let pbr = m.pbr_metallic_roughness();
    let [r, g, b, a] = pbr.base_color_factor();
    let base = glam::Vec3::new(r, g, b);
    let metallic = pbr.metallic_factor().clamp(0.0, 1.0);
    let roughness = pbr.roughness_factor().clamp(0.0, 1.0);
    let smooth = 1.0 - roughness;
    let alpha = roughness.max(0.05);
    super::Material {
        albedo: base * (1.0 - metallic),
        specular: glam::Vec3::splat(0.04).lerp(base, metallic) * smooth,
        shininess: (2.0 / alpha.powi(4) - 2.0).clamp(1.0, 10_000.0),
        mirror: if roughness <= 0.1 { metallic } else { 0.0 },
        opacity: if m.alpha_mode() == gltf::material::AlphaMode::Blend {
            a.clamp(0.0, 1.0)
        } else {
            1.0
        },
        texture: base_color_texture(m, buffers, textures),
    }
}

fn read_positions(accessor: &gltf::Accessor, buffers: &[Vec<u8>]) -> Result<Vec<Vec3>, String> {
    let kind = (
        accessor.dimensions(),
        accessor.data_type(),
        accessor.normalized(),
    );
    if kind != (Dimensions::Vec3, DataType::F32, false) {
        return Err(format!("is {kind:?}; positions must be VEC3 of FLOAT"));
    }
    let f = |b: &[u8], k: usize| f32::from_le_bytes([b[k], b[k + 1], b[k + 2], b[k + 3]]);
    Ok(elements(accessor, buffers)?
        .map(|b| Vec3::new(f(b, 0), f(b, 4), f(b, 8)))
        .collect())
}

fn read_indices(accessor: &gltf::Accessor, buffers: &[Vec<u8>]) -> Result<Vec<u32>, String> {
    let kind = accessor.data_type();
    let decode: fn(&[u8]) -> u32 = match (accessor.dimensions(), kind) {
        (Dimensions::Scalar, DataType::U8) => |b| b[0].into(),
        (Dimensions::Scalar, DataType::U16) => |b| u16::from_le_bytes([b[0], b[1]]).into(),
        (Dimensions::Scalar, DataType::U32) => |b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]),
        (dims, _) => return Err(format!("is {dims:?} of {kind:?}; indices must be unsigned")),
    };
    Ok(elements(accessor, buffers)?.map(decode).collect())
}

/// The bytes of each element of an accessor, after checking that all of them lie inside its
/// buffer view and the view inside its buffer.
fn elements<'b>(
    accessor: &gltf::Accessor,
    buffers: &'b [Vec<u8>],
) -> Result<impl Iterator<Item = &'b [u8]>, String> {
    if accessor.sparse().is_some() {
        return Err("sparse accessors are not supported".into());
    }
    let view = accessor.view().ok_or("has no buffer view")?;
    let (size, count, offset) = (accessor.size(), accessor.count(), accessor.offset());
    let stride = view.stride().unwrap_or(size);
    if stride < size {
        return Err(format!(
            "byte stride {stride} is less than its element size {size}"
        ));
    }
    let buffer = &buffers[view.buffer().index()];
    let bytes = view
        .offset()
        .checked_add(view.length())
        .and_then(|end| buffer.get(view.offset()..end))
        .ok_or_else(|| {
            format!(
                "buffer view {} ({} bytes at {}) runs past the end of buffer {} ({} bytes)",
                view.index(),
                view.length(),
                view.offset(),
                view.buffer().index(),
                buffer.len()
            )
        })?;
    let needed = match count {
        0 => Some(offset),
        n => (n - 1)
            .checked_mul(stride)
            .and_then(|s| s.checked_add(offset)?.checked_add(size)),
    };
    if needed.is_none_or(|n| n > bytes.len()) {
        return Err(format!(
            "{count} elements of {size} bytes, stride {stride}, from byte {offset} do not fit \
             in buffer view {} ({} bytes)",
            view.index(),
            bytes.len()
        ));
    }
    Ok(bytes[offset..]
        .chunks(stride)
        .take(count)
        .map(move |e| &e[..size]))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Mesh 0 has two primitives, indexed and not; scene 1 (the default) draws it through node
    /// 0 (translation) and its child node 1 (scale); scene 0 draws it untransformed via node 2.
    const DOC: &str = r#"{"asset":{"version":"2.0"},"scene":1,
      "scenes":[{"nodes":[2]},{"nodes":[0]}],
      "nodes":[{"translation":[10,0,0],"children":[1]},{"scale":[2,2,2],"mesh":0},{"mesh":0}],
      "meshes":[{"name":"pair","primitives":[
        {"attributes":{"POSITION":0},"indices":1,"mode":MODE},{"attributes":{"POSITION":2}}]}],
      "buffers":[BUFFER],
      "bufferViews":[{"buffer":0,"byteLength":36},{"buffer":0,"byteOffset":36,"byteLength":6},
        {"buffer":0,"byteOffset":44,"byteLength":36}],
      "accessors":[
        {"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]},
        {"bufferView":1,"componentType":5123,"count":3,"type":"SCALAR"},
        {"bufferView":2,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,1],"max":[1,1,1]}]}"#;

    /// The 80-byte buffer of [`DOC`]: a triangle at z = 0, its indices, a triangle at z = 1.
    fn bin(indices: [u16; 3]) -> Vec<u8> {
        let mut out = Vec::new();
        let tri = |z: f32| [0f32, 0., z, 1., 0., z, 0., 1., z];
        tri(0.).iter().for_each(|c| out.extend(c.to_le_bytes()));
        indices.iter().for_each(|i| out.extend(i.to_le_bytes()));
        out.extend([0, 0]);
        tri(1.).iter().for_each(|c| out.extend(c.to_le_bytes()));
        out
    }

    fn doc(buffer: &str, mode: u32) -> String {
        DOC.replace("BUFFER", buffer)
            .replace("MODE", &mode.to_string())
    }

    fn base64(bytes: &[u8]) -> String {
        const ABC: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
        let mut out = String::new();
        for chunk in bytes.chunks(3) {
            let n =
                chunk.iter().fold(0u32, |n, &b| n << 8 | u32::from(b)) << (8 * (3 - chunk.len()));
            for k in 0..4 {
                let sextet = (n >> (18 - 6 * k)) & 63;
                out.push(if k <= chunk.len() {
                    ABC[sextet as usize] as char
                } else {
                    '='
                });
            }
        }
        out
    }

    fn data_uri_doc(indices: [u16; 3], mode: u32) -> String {
        let uri = format!(
            "data:application/octet-stream;base64,{}",
            base64(&bin(indices))
        );
        doc(&format!(r#"{{"byteLength":80,"uri":"{uri}"}}"#), mode)
    }

    fn glb(json: &str, bin: &[u8]) -> Vec<u8> {
        let mut json = json.as_bytes().to_vec();
        json.resize(json.len().next_multiple_of(4), b' ');
        let mut out = b"glTF".to_vec();
        out.extend(2u32.to_le_bytes());
        out.extend(((12 + 8 + json.len() + 8 + bin.len()) as u32).to_le_bytes());
        out.extend((json.len() as u32).to_le_bytes());
        out.extend(b"JSON");
        out.extend(json);
        out.extend((bin.len() as u32).to_le_bytes());
        out.extend(b"BIN\0");
        out.extend(bin);
        out
    }

    fn load(name: &str, bytes: &[u8]) -> Result<Mesh, String> {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("m.bin"), bin([0, 1, 2])).unwrap();
        let path = dir.path().join(name);
        std::fs::write(&path, bytes).unwrap();
        super::super::load_mesh_file(&path).map_err(|e| {
            let e = e.to_string();
            assert!(e.contains(name), "{e}");
            e
        })
    }

    /// [`DOC`] with its data in a data URI and one edit.
    fn edited(from: &str, to: &str) -> Vec<u8> {
        data_uri_doc([0, 1, 2], 4).replace(from, to).into_bytes()
    }

    const WORLD: [[f32; 3]; 6] = [
        [10., 0., 0.],
        [12., 0., 0.],
        [10., 2., 0.],
        [10., 0., 2.],
        [12., 0., 2.],
        [10., 2., 2.],
    ];

    #[test]
    fn default_scene_is_loaded_in_world_space() {
        let mesh = load("m.gltf", &edited("", "")).unwrap();
        assert_eq!(
            mesh.positions,
            WORLD.map(|p| Vec3::from_array(p).as_dvec3())
        );
        assert_eq!(mesh.triangles, [[0, 1, 2], [3, 4, 5]]);
    }

    #[test]
    fn materials_map_to_mirror_glass_and_default() {
        let json = edited(
            r#""mode":4},{"attributes":{"POSITION":2}}"#,
            r#""mode":4,"material":1},{"attributes":{"POSITION":2}}"#,
        );
        let json = String::from_utf8(json).unwrap().replace(
            r#""buffers""#,
            r#""materials":[
              {"name":"chrome","pbrMetallicRoughness":{"metallicFactor":1,"roughnessFactor":0}},
              {"name":"glass","alphaMode":"BLEND",
               "pbrMetallicRoughness":{"baseColorFactor":[0.2,0.4,0.8,0.3],"metallicFactor":0}}],
            "buffers""#,
        );
        let mesh = load("m.gltf", json.as_bytes()).unwrap();
        assert_eq!(mesh.materials.len(), 3);
        assert!(mesh.materials[0].is_mirror() && !mesh.materials[0].is_transparent());
        let glass = mesh.materials[mesh.triangle_material[0] as usize];
        assert_eq!(glass.opacity, 0.3);
        assert_eq!(glass.albedo, Vec3::new(0.2, 0.4, 0.8));
        assert_eq!(mesh.triangle_material[1], 2, "no material: glTF's default");
    }

    #[test]
    fn external_bin_and_glb_give_the_same_mesh() {
        let external = doc(r#"{"byteLength":80,"uri":"m%2Ebin"}"#, 4);
        let binary = glb(&doc(r#"{"byteLength":80}"#, 4), &bin([0, 1, 2]));
        for mesh in [load("e.gltf", external.as_bytes()), load("b.glb", &binary)] {
            let mesh = mesh.unwrap();
            assert_eq!(
                mesh.positions,
                WORLD.map(|p| Vec3::from_array(p).as_dvec3())
            );
            assert_eq!(mesh.triangles, [[0, 1, 2], [3, 4, 5]]);
        }
    }

    #[test]
    fn without_a_default_scene_every_scene_is_loaded() {
        let mesh = load("all.gltf", &edited(r#""scene":1,"#, "")).unwrap();
        assert_eq!(mesh.triangles.len(), 4);
        assert_eq!(
            mesh.positions[0],
            glam::DVec3::ZERO,
            "scene 0 (node 2) first"
        );
    }

    #[test]
    fn lines_are_skipped_and_strips_converted() {
        let mesh = load("l.gltf", data_uri_doc([0, 1, 2], 1).as_bytes()).unwrap();
        assert_eq!(mesh.triangles, [[0, 1, 2]], "only primitive 1 is left");
        let mesh = load("s.gltf", data_uri_doc([2, 1, 0], 5).as_bytes()).unwrap();
        assert_eq!(mesh.triangles, [[2, 1, 0], [3, 4, 5]]);
    }

    #[test]
    fn mirroring_node_keeps_the_winding() {
        let mesh = load("mirror.gltf", &edited("[2,2,2]", "[-2,2,2]")).unwrap();
        assert_eq!(mesh.positions[1], glam::DVec3::new(8., 0., 0.));
        assert_eq!(mesh.triangles, [[0, 2, 1], [3, 5, 4]]);
    }

    #[test]
    fn bad_files_name_the_element() {
        let buffer = |json: &str| doc(json, 4).into_bytes();
        let mut nan = bin([0, 1, 2]);
        nan[4..8].copy_from_slice(&f32::NAN.to_le_bytes());
        let mut corrupt = glb(&doc(r#"{"byteLength":80}"#, 4), &bin([0, 1, 2]));
        corrupt[8..12].copy_from_slice(&3u32.to_le_bytes());
        #[rustfmt::skip]
        let cases = [
            ("i.gltf", data_uri_doc([0, 1, 99], 4).into_bytes(),
                "mesh 0 primitive 0: index 99 out of range (3 vertices)"),
            ("b.gltf", buffer(r#"{"byteLength":80,"uri":"gone.bin"}"#), "buffer 0: cannot read"),
            ("u.gltf", buffer(r#"{"byteLength":80,"uri":"%zz"}"#), "buffer 0: uri `%zz`"),
            ("l.gltf", buffer(r#"{"byteLength":90,"uri":"m.bin"}"#), "80 bytes, but the glTF says 90"),
            ("c.gltf", edited(r#"3,"type":"SCALAR""#, r#"4,"type":"SCALAR""#),
                "mesh 0 primitive 0: index accessor 1: 4 elements of 2 bytes"),
            ("t.gltf", edited("5123", "5122"), "primitive 0: index accessor 1: is Scalar of I16"),
            ("n.gltf", edited(r#""scale":[2,2,2],"#, r#""children":[0],"#), "node 0 is reached twice"),
            ("v.gltf", edited("\"2.0\"", "2"), "not a valid glTF file"),
            ("nan.glb", glb(&doc(r#"{"byteLength":80}"#, 4), &nan),
                "mesh 0 primitive 0: vertex 0 has a non-finite"),
            ("corrupt.glb", corrupt, "total length of 3 bytes"),
            // Found by fuzzing: gltf-json indexed these accessors before checking them, and
            // panicked.
            ("a.gltf", edited(r#""POSITION":2"#, r#""POSITION":3"#),
                "mesh 0, primitive 1: accessor 3 does not exist (3 accessors)"),
            ("a.glb", glb(&doc(r#"{"byteLength":80}"#, 4).replace(r#""POSITION":0"#, r#""POSITION":4"#), &bin([0, 1, 2])),
                "mesh 0, primitive 0: accessor 4 does not exist (3 accessors)"),
        ];
        for (name, bytes, want) in cases {
            let err = load(name, &bytes).unwrap_err();
            assert!(err.contains(want), "{want}: {err}");
        }
    }
}
