//! What colours a surface besides its material: texture coordinates and colours per vertex,
//! and the textures materials name. All of it is empty for a mesh whose file has none, so such
//! a scene spends no memory and no shading time on it.

use super::texture::Texture;
use super::Material;
use glam::{Vec2, Vec3};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// Per-vertex texture coordinates and colours, and the textures, of a mesh or a scene.
/// `uvs` and `vertex` are each either empty or as long as the vertex list.
#[derive(Clone, Debug, Default)]
pub struct SurfaceColors {
    /// Texture coordinates of each vertex: u across, v down from the image's top row (glTF's
    /// convention; OBJ's v, which runs up, is flipped at load).
    pub uvs: Vec<Vec2>,
    /// Colour of each vertex, display-encoded as texels are ([`super::texture::decode`]).
    pub vertex: Vec<[u8; 3]>,
    /// The textures [`Material::texture`] indexes.
    pub textures: Vec<Texture>,
}

/// White, the colour a vertex without one gets when others in the mesh have one.
pub const WHITE: [u8; 3] = [255; 3];

impl SurfaceColors {
    /// Whether there is nothing here: the scene is drawn in its materials' colours alone.
    pub fn is_empty(&self) -> bool {
        self.uvs.is_empty() && self.vertex.is_empty() && self.textures.is_empty()
    }

    /// Appends the per-vertex values of `count` vertices that follow the `before` vertices
    /// already here: `uvs` and `vertex` (each empty when those vertices have none). A list
    /// stays empty while no vertex has a value; once one has, the others get a zero
    /// coordinate or white.
    pub fn extend_vertices(
        &mut self,
        before: usize,
        count: usize,
        uvs: &[Vec2],
        vertex: &[[u8; 3]],
    ) {
        extend(&mut self.uvs, before, count, uvs, Vec2::ZERO);
        extend(&mut self.vertex, before, count, vertex, WHITE);
    }

    /// Appends `other`'s vertices (after the `before` here) and textures; returns how far
    /// `other`'s texture indices move.
    pub(crate) fn append(&mut self, before: usize, count: usize, other: SurfaceColors) -> u16 {
        self.extend_vertices(before, count, &other.uvs, &other.vertex);
        let shift = self.textures.len() as u16;
        self.textures.extend(other.textures);
        shift
    }

    /// The linear colour of a vertex colour read as a number from 0 to 1 (PLY floats, OBJ's
    /// `v x y z r g b`), stored as display-encoded bytes.
    pub fn encode_unit(rgb: [f32; 3]) -> [u8; 3] {
        rgb.map(|c| (c.clamp(0.0, 1.0) * 255.0 + 0.5) as u8)
    }

    /// Feeds what is here to `hasher`; nothing when empty, so scenes without colours hash as
    /// they did before colours existed.
    pub(crate) fn hash_into(&self, hasher: &mut blake3::Hasher) {
        if self.is_empty() {
            return;
        }
        hasher.update(b"colors");
        hasher.update(&(self.uvs.len() as u64).to_le_bytes());
        hasher.update(bytemuck::cast_slice(&self.uvs));
        hasher.update(&(self.vertex.len() as u64).to_le_bytes());
        hasher.update(bytemuck::cast_slice(&self.vertex));
        for texture in &self.textures {
            texture.hash_into(hasher);
        }
    }

    /// Checks the lengths against `vertices` and the materials' texture indices.
    pub(crate) fn check(&self, vertices: usize, materials: &[Material]) -> Result<(), String> {
        for (what, len) in [
            ("texture coordinates", self.uvs.len()),
            ("vertex colours", self.vertex.len()),
        ] {
            if len != 0 && len != vertices {
                return Err(format!("{len} {what} for {vertices} vertices"));
            }
        }
        if let Some(bad) = self.uvs.iter().position(|uv| !uv.is_finite()) {
            return Err(format!("vertex {bad} has a non-finite texture coordinate"));
        }
        let count = self.textures.len();
        match materials
            .iter()
            .enumerate()
            .find_map(|(i, m)| m.texture.filter(|&t| t as usize >= count).map(|t| (i, t)))
        {
            Some((i, t)) => Err(format!(
                "material {i} uses texture {t}, but there are only {count}"
            )),
            None => Ok(()),
        }
    }
}

fn extend<T: Copy>(list: &mut Vec<T>, before: usize, count: usize, new: &[T], fill: T) {
    if list.is_empty() && new.is_empty() {
        return;
    }
    list.resize(before, fill);
    if new.len() == count {
        list.extend_from_slice(new);
    } else {
        list.resize(before + count, fill);
    }
}

/// Image files read for one mesh file, each once however many materials name it.
pub(crate) struct TextureFiles<'a> {
    /// The mesh file: textures are found relative to its folder, and messages name it.
    pub mesh: &'a Path,
    loaded: HashMap<PathBuf, Option<u16>>,
    /// The textures read so far, in the order materials first named them.
    pub textures: Vec<Texture>,
}

impl<'a> TextureFiles<'a> {
    pub(crate) fn new(mesh: &'a Path) -> Self {
        TextureFiles {
            mesh,
            loaded: HashMap::new(),
            textures: Vec::new(),
        }
    }

    /// The index of the texture that `material` names as `reference` (an MTL `map_Kd` value:
    /// options first, the file last, `\` or `/` between folders). A file that cannot be read
    /// is a warning naming it and the material, and `None`: the material's own colour is
    /// drawn.
    pub(crate) fn load(&mut self, reference: &str, material: &str) -> Option<u16> {
        let path = self.resolve(reference)?;
        self.load_path(path, material)
    }

    /// The index of the texture in the image file `path`, or a warning naming it and `None`.
    pub(crate) fn load_path(&mut self, path: PathBuf, material: &str) -> Option<u16> {
        if let Some(&known) = self.loaded.get(&path) {
            return known;
        }
        let index = match Texture::open(&path) {
            Ok(texture) if self.textures.len() < u16::MAX as usize => {
                self.textures.push(texture);
                Some(self.textures.len() as u16 - 1)
            }
            Ok(_) => {
                self.warn(&path, material, "too many textures (65535 at most)");
                None
            }
            Err(e) => {
                self.warn(&path, material, &e);
                None
            }
        };
        self.loaded.insert(path, index);
        index
    }

    /// A texture decoded from bytes the mesh file holds (a glTF buffer view or data URI),
    /// or a warning naming it and `None`.
    pub(crate) fn decode(&mut self, name: &str, bytes: &[u8], material: &str) -> Option<u16> {
        match Texture::decode_image(name, bytes) {
            Ok(texture) if self.textures.len() < u16::MAX as usize => {
                self.textures.push(texture);
                Some(self.textures.len() as u16 - 1)
            }
            Ok(_) => None,
            Err(e) => {
                self.warn(Path::new(name), material, &e);
                None
            }
        }
    }

    pub(crate) fn warn(&self, texture: &Path, material: &str, why: &str) {
        tracing::warn!(
            "{}: texture {} of material `{material}` not loaded ({why}); drawing the material's colour",
            self.mesh.display(),
            texture.display()
        );
    }

    fn resolve(&self, reference: &str) -> Option<PathBuf> {
        let words: Vec<&str> = reference.split_whitespace().collect();
        // Options (`-s 1 1 1`, `-bm 0.5`) come before the file; a name with spaces has none.
        let name = match words.first() {
            Some(w) if w.starts_with('-') => words.last()?.to_string(),
            _ => reference.trim().to_string(),
        };
        if name.is_empty() {
            return None;
        }
        // Files written on Windows separate folders with `\`.
        let name = name.replace('\\', "/");
        let dir = self.mesh.parent().unwrap_or(Path::new(""));
        Some(dir.join(name.trim_start_matches("./")))
    }
}

/// The vertex colour of a unit-range linear colour (glTF's `COLOR_0` is linear), encoded as
/// the renderer's textures are.
pub fn encode_linear(rgb: Vec3) -> [u8; 3] {
    rgb.to_array().map(super::texture::encode)
}
