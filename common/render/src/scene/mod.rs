//! Scene description and loading: what the render nodes trace.
//!
//! A scene is a list of triangles with a material each, plus one directional light. It is
//! named by a [`SceneSpec`] (a built-in procedural scene, or a mesh file) that travels to every
//! render node, which loads it itself; the content hash in the session lets a node check that it
//! loaded the same bytes as the master, since identical input is what makes tiles bit-identical
//! on any node.

#[cfg(test)]
mod color_tests;
pub mod colors;
pub mod composite;
mod files;
pub mod footprint;
pub mod gltf;
mod obj_lines;
pub mod particles;
pub mod points;
mod procedural;
mod stl;
pub mod texture;
pub(crate) mod vtk;

use crate::geometry::Bounds;
use crate::volume::{self, Volume, VolumeError};
use glam::{DVec3, Vec3};
use serde::{Deserialize, Serialize};
use std::path::Path;
use tessera_model::camera::{CameraError, CameraMode};
use tessera_model::local_origin::RenderFromWorld;
use tessera_model::scene_spec::SceneSpec;

pub use files::load_mesh_file;
pub use procedural::{gallery_scene, knot_scene};

/// How a surface reflects and transmits light. One struct covers Lambert (the default), Phong,
/// mirror and transparency, because real files mix them (an OBJ material can be glossy, partly
/// mirroring and partly transparent at once); the renderer takes the cheap path for each part
/// that is zero.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Material {
    /// Diffuse (Lambert) colour.
    pub albedo: Vec3,
    /// Phong specular colour; zero for a purely diffuse surface.
    pub specular: Vec3,
    /// Phong exponent: larger is a smaller, sharper highlight.
    pub shininess: f32,
    /// Fraction of the light a perfect mirror reflects (0: none, 1: a perfect mirror).
    pub mirror: f32,
    /// 1 is opaque; below 1 the surface is blended with what lies behind it.
    pub opacity: f32,
    /// The texture ([`colors::SurfaceColors::textures`]) that multiplies `albedo`, if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub texture: Option<u16>,
}

impl Material {
    /// A purely diffuse surface of colour `albedo`: no highlight, no mirror, opaque.
    pub const fn lambert(albedo: Vec3) -> Self {
        Material {
            albedo,
            specular: Vec3::ZERO,
            shininess: 1.0,
            mirror: 0.0,
            opacity: 1.0,
            texture: None,
        }
    }

    /// A diffuse surface with a Phong highlight of colour `specular` and exponent `shininess`.
    pub const fn phong(albedo: Vec3, specular: Vec3, shininess: f32) -> Self {
        Material {
            specular,
            shininess,
            ..Self::lambert(albedo)
        }
    }

    /// A diffuse surface that also mirrors the fraction `reflectance` (0..=1) of the light.
    pub const fn mirror(albedo: Vec3, reflectance: f32) -> Self {
        Material {
            mirror: reflectance,
            ..Self::lambert(albedo)
        }
    }

    /// A diffuse surface blended with what lies behind it; `opacity` 1 is opaque, 0 invisible.
    pub const fn transparent(albedo: Vec3, opacity: f32) -> Self {
        Material {
            opacity,
            ..Self::lambert(albedo)
        }
    }

    /// Whether the shader must trace on through the surface and blend (opacity below 1).
    pub fn is_transparent(&self) -> bool {
        self.opacity < 1.0
    }

    /// Whether the shader traces a reflection ray (mirror above 0).
    pub fn is_mirror(&self) -> bool {
        self.mirror > 0.0
    }

    /// Whether the shader adds a Phong highlight (a specular colour other than black).
    pub fn has_specular(&self) -> bool {
        self.specular != Vec3::ZERO
    }

    /// Material values out of their meaningful ranges would give NaN or negative light.
    pub(crate) fn check(&self) -> Result<(), String> {
        let finite = self.albedo.is_finite()
            && self.specular.is_finite()
            && self.shininess.is_finite()
            && self.mirror.is_finite()
            && self.opacity.is_finite();
        if !finite {
            return Err("has a non-finite value".into());
        }
        if self.albedo.min_element() < 0.0 || self.specular.min_element() < 0.0 {
            return Err("has a negative colour".into());
        }
        if self.shininess < 0.0 {
            return Err(format!("has a negative shininess {}", self.shininess));
        }
        if !(0.0..=1.0).contains(&self.mirror) || !(0.0..=1.0).contains(&self.opacity) {
            return Err(format!(
                "has mirror {} or opacity {} outside 0..1",
                self.mirror, self.opacity
            ));
        }
        Ok(())
    }
}

/// The scene as the renderer consumes it.
#[derive(Clone, Debug, Default)]
pub struct Scene {
    /// Vertices in render coordinates: the world's moved by [`Scene::render_from_world`].
    pub positions: Vec<Vec3>,
    /// Three indices into `positions` for each triangle.
    pub triangles: Vec<[u32; 3]>,
    /// Material index of each triangle.
    pub triangle_material: Vec<u16>,
    /// The materials `triangle_material` indexes.
    pub materials: Vec<Material>,
    /// Names of the materials as the file gave them, for error messages (may be empty).
    pub material_names: Vec<String>,
    /// Lights; a scene without lights traces no shadow rays.
    pub lights: Vec<Light>,
    /// Texture coordinates and colours of the vertices, and the textures; empty for a scene
    /// drawn in its materials' colours alone.
    pub colors: colors::SurfaceColors,
    /// Spheres with a scalar attribute; a scene without them builds no sphere BVH.
    pub particles: Vec<particles::Particle>,
    /// A volume of samples, placed in the world; a scene without one builds no bricks. For a
    /// time series, its first step.
    pub volume: Option<Volume>,
    /// The files of a time series (empty: none); its steps are loaded as frames show them.
    pub series: Vec<std::path::PathBuf>,
    /// Where the render coordinates sit in the world (identity for built-in scenes): a file's
    /// mesh is moved to its middle, in f64, before it becomes f32.
    pub render_from_world: RenderFromWorld,
    /// The scene's own up, where its file says one (a volume in patient axes: superior);
    /// `None` is +y, the convention of meshes.
    pub up: Option<Vec3>,
}

pub use tessera_model::light::Light;

/// Why a scene could not be loaded; every variant names the file and what is wrong.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// A mesh or scene file could not be read or parsed, or its data is inconsistent (for example
    /// a triangle count that differs from its material count).
    #[error("scene file {path}: {message}")]
    File {
        /// The file (or, from [`Scene::validate`], the scene's origin) as the user named it.
        path: String,
        /// What is wrong, as the parser or the check put it.
        message: String,
    },
    /// The file's extension is none of the formats a scene is loaded from.
    #[error("scene file {path}: unsupported extension (expected .obj, .ply, .gltf, .glb, .stl, .vtk, .vtp, .vtu, .csv, .tpart, .nrrd, .nhdr, .nii, .nii.gz, .vti, .vol.toml or .scene.toml)")]
    UnknownFormat {
        /// The file as the user named it.
        path: String,
    },
    /// A vertex has a NaN or infinite coordinate (in render coordinates).
    #[error("scene {origin}: vertex {index} has a non-finite coordinate {value:?}")]
    NonFinite {
        /// Where the scene came from: its file, or the built-in scene's name.
        origin: String,
        /// The vertex's index in [`Scene::positions`].
        index: usize,
        /// The vertex as it was, in render coordinates.
        value: [f32; 3],
    },
    /// A triangle names a vertex past the end of the vertex list.
    #[error("scene {origin}: triangle {index} uses vertex {vertex}, but there are only {count}")]
    IndexOutOfRange {
        /// Where the scene came from: its file, or the built-in scene's name.
        origin: String,
        /// The triangle's index in [`Scene::triangles`].
        index: usize,
        /// The vertex index it uses.
        vertex: u32,
        /// How many vertices there are.
        count: usize,
    },
    /// A triangle names a material past the end of the material list.
    #[error(
        "scene {origin}: triangle {index} uses material {material}, but there are only {count}"
    )]
    MaterialOutOfRange {
        /// Where the scene came from: its file, or the built-in scene's name.
        origin: String,
        /// The triangle's index in [`Scene::triangles`].
        index: usize,
        /// The material index it uses.
        material: u16,
        /// How many materials there are.
        count: usize,
    },
    /// A material has a non-finite, negative or out-of-range value (see [`Material`]).
    #[error("scene {origin}: material {index} ({name}) {why}")]
    BadMaterial {
        /// Where the scene came from: its file, or the built-in scene's name.
        origin: String,
        /// The material's index in [`Scene::materials`].
        index: usize,
        /// Its name in the file, or `#index` when the file gave none.
        name: String,
        /// Which value is wrong, as a phrase ("has a negative colour").
        why: String,
    },
    /// The scene has nothing to draw: no triangles, no particles and no volume.
    #[error("scene {origin}: contains no triangles")]
    Empty {
        /// Where the scene came from: its file, or the built-in scene's name.
        origin: String,
    },
    /// The scene's volume could not be loaded.
    #[error(transparent)]
    Volume(#[from] VolumeError),
    /// The scene has more triangles than [`MAX_TRIANGLES`].
    #[error("scene {origin}: {count} triangles is over the limit of {limit}")]
    TooLarge {
        /// Where the scene came from: its file, or the built-in scene's name.
        origin: String,
        /// How many triangles the scene has.
        count: usize,
        /// The limit: [`MAX_TRIANGLES`].
        limit: usize,
    },
}

/// Largest triangle count accepted: indices are u32 and the BVH node count is about 2× this.
pub const MAX_TRIANGLES: usize = 1 << 30;

impl Scene {
    /// Loads what `spec` names. Files are resolved relative to the working directory.
    pub fn load(spec: &SceneSpec) -> Result<Scene, SceneError> {
        let scene = match spec {
            SceneSpec::Knot { segments, sides } => knot_scene(*segments, *sides),
            SceneSpec::Gallery => procedural::gallery_scene(),
            // Empty by design, so the check for something to draw does not apply.
            SceneSpec::Empty => return Ok(Scene::default()),
            SceneSpec::File(path)
                if particles::is_particle_file(path) || points::is_point_cloud(path) =>
            {
                let world = points::load(path)?;
                let render_from_world = particles::frame_of(&world);
                Scene {
                    particles: particles::place(&world, render_from_world),
                    lights: vec![default_light()],
                    render_from_world,
                    ..Scene::default()
                }
            }
            SceneSpec::File(path) if composite::is_scene_file(path) => {
                composite::load_scene_file(path)?
            }
            SceneSpec::File(path) if volume::is_volume_path(path) => {
                from_volume(volume::load(path)?)
            }
            SceneSpec::File(path) => from_mesh(load_mesh_file(path)?, path),
        };
        scene.validate(&spec_origin(spec))?;
        Ok(scene)
    }

    /// Checks what the renderer relies on: finite coordinates, indices in range, something to
    /// draw. Loaders call it so that bad input fails at load, never as a NaN pixel later.
    pub fn validate(&self, origin: &str) -> Result<(), SceneError> {
        if self.triangles.is_empty() && self.particles.is_empty() && self.volume.is_none() {
            return Err(SceneError::Empty {
                origin: origin.into(),
            });
        }
        if self.triangles.len() > MAX_TRIANGLES {
            return Err(SceneError::TooLarge {
                origin: origin.into(),
                count: self.triangles.len(),
                limit: MAX_TRIANGLES,
            });
        }
        if let Some((index, p)) = self
            .positions
            .iter()
            .enumerate()
            .find(|(_, p)| !p.is_finite())
        {
            return Err(SceneError::NonFinite {
                origin: origin.into(),
                index,
                value: p.to_array(),
            });
        }
        let count = self.positions.len();
        for (index, tri) in self.triangles.iter().enumerate() {
            if let Some(&vertex) = tri.iter().find(|&&v| v as usize >= count) {
                return Err(SceneError::IndexOutOfRange {
                    origin: origin.into(),
                    index,
                    vertex,
                    count,
                });
            }
        }
        let materials = self.materials.len();
        if self.triangle_material.len() != self.triangles.len() {
            return Err(SceneError::File {
                path: origin.into(),
                message: format!(
                    "{} triangles but {} material indices",
                    self.triangles.len(),
                    self.triangle_material.len()
                ),
            });
        }
        if let Some((index, &material)) = self
            .triangle_material
            .iter()
            .enumerate()
            .find(|(_, &m)| m as usize >= materials)
        {
            return Err(SceneError::MaterialOutOfRange {
                origin: origin.into(),
                index,
                material,
                count: materials,
            });
        }
        self.colors
            .check(count, &self.materials)
            .map_err(|message| SceneError::File {
                path: origin.into(),
                message,
            })?;
        for (index, m) in self.materials.iter().enumerate() {
            m.check().map_err(|why| SceneError::BadMaterial {
                origin: origin.into(),
                index,
                name: self
                    .material_names
                    .get(index)
                    .cloned()
                    .unwrap_or_else(|| format!("#{index}")),
                why,
            })?;
        }
        Ok(())
    }

    /// Whether any surface blends with what lies behind it: without, no transmission rays and
    /// no blending are ever computed.
    pub fn has_transparency(&self) -> bool {
        self.materials.iter().any(Material::is_transparent)
    }

    /// Writes the scene's triangles as OBJ in world coordinates, so other renderers can load
    /// exactly the same mesh (f64 text, so reading it back gives the same f32 vertices).
    pub fn export_obj(&self, out: &Path) -> std::io::Result<()> {
        use std::io::Write;
        let mut w = std::io::BufWriter::new(std::fs::File::create(out)?);
        for &p in &self.positions {
            let p = self.render_from_world.world_point(p);
            writeln!(w, "v {} {} {}", p.x, p.y, p.z)?;
        }
        for t in &self.triangles {
            writeln!(w, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1)?;
        }
        w.flush()
    }

    /// The first missing data of the scene, said as a phrase ("voxel 13 is missing data (NaN
    /// or infinite)"), for `--nan refuse`; None when it has none.
    pub fn first_missing(&self) -> Option<String> {
        if let Some(i) = self.volume.as_ref().and_then(|v| v.first_missing()) {
            return Some(format!("voxel {i} is missing data (NaN or infinite)"));
        }
        let particle = self.particles.iter().position(|p| p.attribute.is_nan());
        particle.map(|i| format!("particle {i} has a missing attribute (NaN or infinite)"))
    }

    /// The least and greatest particle attribute, NaN (missing) ignored: what the ends of the
    /// colour map stand for. Infinite ends, the wrong way round, when no attribute is finite.
    pub fn attribute_range(&self) -> (f32, f32) {
        self.particles
            .iter()
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), p| {
                (lo.min(p.attribute), hi.max(p.attribute))
            })
    }

    /// The default orbit around the scene (its bounds, about its own up), with vertical field
    /// of view `fov_y_deg`: the home view of a wall that was given no camera.
    ///
    /// # Errors
    /// As [`crate::orbit_of`].
    pub fn orbit(&self, fov_y_deg: f32) -> Result<CameraMode, CameraError> {
        crate::pixel_rays::orbit_about_of(&self.bounds(), self.up.unwrap_or(Vec3::Y), fov_y_deg)
    }

    /// The box, in render coordinates, around the triangles, the particles and the volume; empty
    /// for an empty scene.
    pub fn bounds(&self) -> Bounds {
        let mut bounds = Bounds::EMPTY;
        for tri in &self.triangles {
            for &v in tri {
                bounds.grow(self.positions[v as usize]);
            }
        }
        for p in &self.particles {
            bounds.grow(p.center - Vec3::splat(p.radius));
            bounds.grow(p.center + Vec3::splat(p.radius));
        }
        if let Some(volume) = &self.volume {
            for corner in volume.world_corners() {
                bounds.grow(self.render_from_world.point(DVec3::from_array(corner)));
            }
        }
        bounds
    }

    /// A hash of everything that affects the picture, so nodes can check they agree.
    pub fn content_hash(&self) -> [u8; 32] {
        let mut hasher = blake3::Hasher::new();
        hasher.update(bytemuck::cast_slice(&self.positions));
        hasher.update(bytemuck::bytes_of(&self.render_from_world.world_origin));
        hasher.update(bytemuck::cast_slice(&self.triangles));
        hasher.update(bytemuck::cast_slice(&self.triangle_material));
        for m in &self.materials {
            hasher.update(bytemuck::bytes_of(&m.albedo));
            hasher.update(bytemuck::bytes_of(&m.specular));
            hasher.update(bytemuck::bytes_of(&[m.shininess, m.mirror, m.opacity]));
            if let Some(texture) = m.texture {
                hasher.update(&texture.to_le_bytes());
            }
        }
        self.colors.hash_into(&mut hasher);
        for p in &self.particles {
            hasher.update(bytemuck::bytes_of(&[
                p.center.x,
                p.center.y,
                p.center.z,
                p.radius,
                p.attribute,
            ]));
        }
        if let Some(volume) = &self.volume {
            for d in volume.dims() {
                hasher.update(&(d as u64).to_le_bytes());
            }
            hasher.update(bytemuck::cast_slice(&volume.axes()));
            hasher.update(bytemuck::cast_slice(&volume.origin()));
            hasher.update(bytemuck::cast_slice(volume.values()));
        }
        // The steps after the first by name and size: nodes load them as frames show them.
        for path in &self.series {
            let name = path.file_name().map(|n| n.to_string_lossy().into_owned());
            hasher.update(name.unwrap_or_default().as_bytes());
            let size = std::fs::metadata(path).map_or(u64::MAX, |m| m.len());
            hasher.update(&size.to_le_bytes());
        }
        for light in &self.lights {
            let (tag, v, i) = match *light {
                Light::Directional { towards, intensity } => (0u8, towards, intensity),
                Light::Point {
                    position,
                    intensity,
                } => (1u8, position, intensity),
            };
            hasher.update(&[tag]);
            hasher.update(bytemuck::bytes_of(&v));
            hasher.update(&i.to_le_bytes());
        }
        *hasher.finalize().as_bytes()
    }
}

fn spec_origin(spec: &SceneSpec) -> String {
    match spec {
        SceneSpec::Knot { .. } => "built-in knot".into(),
        SceneSpec::Gallery => "built-in gallery".into(),
        SceneSpec::Empty => "empty scene".into(),
        SceneSpec::File(path) => path.display().to_string(),
    }
}

/// Loader output: positions, triangles and the file's own materials, before the light is added.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    /// World coordinates, as read (f64, so that a mesh far from the origin keeps its shape).
    pub positions: Vec<DVec3>,
    /// Three indices into `positions` for each triangle, as the file gave them.
    pub triangles: Vec<[u32; 3]>,
    /// Material of each triangle; empty when the file has none (all get the neutral one).
    pub triangle_material: Vec<u16>,
    /// The file's materials, which `triangle_material` indexes; empty when it has none.
    pub materials: Vec<Material>,
    /// Names of `materials` as the file gave them, for error messages.
    pub material_names: Vec<String>,
    /// Texture coordinates and colours of `positions`, and the textures materials name.
    pub colors: colors::SurfaceColors,
}

/// The colour of a mesh whose file gives none.
pub const NEUTRAL: Material = Material::lambert(Vec3::new(0.8, 0.78, 0.74));

/// A file mesh keeps its materials (or gets the neutral one) and gets a light from the upper
/// front left. Its vertices are moved to a local origin at their middle before they become
/// f32, and triangles with no area there are dropped (counted in the log): they can never be
/// hit, and a million of them would only slow the BVH build.
fn from_mesh(mesh: Mesh, path: &Path) -> Scene {
    let frame = RenderFromWorld::centred_on(&mesh.positions);
    from_mesh_in(mesh, path, frame)
}

/// [`from_mesh`] in a given render frame (a scene of several parts centres it on all of them).
fn from_mesh_in(mut mesh: Mesh, path: &Path, render_from_world: RenderFromWorld) -> Scene {
    let count = mesh.triangles.len();
    if mesh.materials.is_empty() {
        mesh.triangle_material = vec![0; count];
        mesh.materials = vec![NEUTRAL];
        mesh.material_names = vec!["neutral".into()];
    }
    drop_unmapped_textures(&mut mesh, path);
    let positions: Vec<Vec3> = mesh
        .positions
        .iter()
        .map(|&p| render_from_world.point(p))
        .collect();
    let (triangles, triangle_material) =
        drop_degenerate(&positions, mesh.triangles, mesh.triangle_material);
    if triangles.len() < count {
        tracing::info!(
            "{}: dropped {} degenerate triangles (no area, or a repeated or missing vertex) of {count}",
            path.display(),
            count - triangles.len()
        );
    }
    Scene {
        positions,
        triangles,
        triangle_material,
        materials: mesh.materials,
        material_names: mesh.material_names,
        colors: mesh.colors,
        lights: vec![default_light()],
        particles: Vec::new(),
        volume: None,
        series: Vec::new(),
        render_from_world,
        up: None,
    }
}

/// A material's texture needs texture coordinates: without them it is dropped, said once.
fn drop_unmapped_textures(mesh: &mut Mesh, path: &Path) {
    if !mesh.colors.uvs.is_empty() || mesh.colors.textures.is_empty() {
        return;
    }
    tracing::warn!(
        "{}: has {} textures but no texture coordinates; drawing the materials' colours",
        path.display(),
        mesh.colors.textures.len()
    );
    mesh.colors.textures.clear();
    for m in &mut mesh.materials {
        m.texture = None;
    }
}

/// A volume alone, lit by the default light, its render coordinates centred on its box.
pub(crate) fn from_volume(volume: Volume) -> Scene {
    let corners: Vec<DVec3> = volume
        .world_corners()
        .iter()
        .map(|&c| DVec3::from_array(c))
        .collect();
    Scene {
        lights: vec![default_light()],
        render_from_world: RenderFromWorld::centred_on(&corners),
        up: volume.up(),
        volume: Some(volume),
        ..Scene::default()
    }
}

/// The triangles (and their materials) that have an area in f32. Indices out of range are
/// kept, for [`Scene::validate`] to name.
fn drop_degenerate(
    positions: &[Vec3],
    triangles: Vec<[u32; 3]>,
    materials: Vec<u16>,
) -> (Vec<[u32; 3]>, Vec<u16>) {
    let corner = |i: u32| positions.get(i as usize).copied();
    let has_area = |t: &[u32; 3]| match (corner(t[0]), corner(t[1]), corner(t[2])) {
        (Some(a), Some(b), Some(c)) => {
            let n = (b - a).cross(c - a);
            n != Vec3::ZERO && n.is_finite()
        }
        _ => true,
    };
    if triangles.iter().all(has_area) {
        return (triangles, materials);
    }
    triangles
        .into_iter()
        .zip(materials)
        .filter(|(t, _)| has_area(t))
        .unzip()
}

/// A sun from the upper front left.
pub(crate) fn default_light() -> Light {
    Light::Directional {
        towards: Vec3::new(-0.45, 0.8, 0.4).normalize(),
        intensity: 0.65,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn one_triangle() -> Scene {
        from_mesh(
            Mesh {
                positions: vec![DVec3::ZERO, DVec3::X, DVec3::Y],
                triangles: vec![[0, 1, 2]],
                ..Mesh::default()
            },
            Path::new("t"),
        )
    }

    #[test]
    fn nan_and_inf_vertices_are_rejected_with_their_index() {
        for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            let mut scene = one_triangle();
            scene.positions[2].y = bad;
            let err = scene.validate("m.obj").unwrap_err().to_string();
            assert!(err.contains("m.obj") && err.contains("vertex 2"), "{err}");
        }
    }

    #[test]
    fn out_of_range_index_is_rejected() {
        let mut scene = one_triangle();
        scene.triangles[0][1] = 7;
        let err = scene.validate("m.ply").unwrap_err().to_string();
        assert!(
            err.contains("triangle 0") && err.contains("vertex 7"),
            "{err}"
        );
    }

    #[test]
    fn bad_materials_are_rejected_with_their_name() {
        let mut scene = one_triangle();
        scene.materials[0].opacity = 1.5;
        let err = scene.validate("m.obj").unwrap_err().to_string();
        assert!(
            err.contains("material 0 (neutral)") && err.contains("opacity"),
            "{err}"
        );
        let mut scene = one_triangle();
        scene.materials[0].specular.x = f32::NAN;
        assert!(scene.validate("m.obj").is_err());
        let mut scene = one_triangle();
        scene.triangle_material[0] = 3;
        let err = scene.validate("m.obj").unwrap_err().to_string();
        assert!(err.contains("material 3"), "{err}");
    }

    #[test]
    fn degenerate_triangles_are_dropped_with_their_materials() {
        let scene = from_mesh(
            Mesh {
                positions: vec![DVec3::ZERO, DVec3::X, DVec3::Y, DVec3::X * 2.0],
                // Good, repeated vertex, collinear, good.
                triangles: vec![[0, 1, 2], [0, 0, 2], [0, 1, 3], [1, 3, 2]],
                triangle_material: vec![0, 1, 1, 2],
                materials: vec![NEUTRAL; 3],
                material_names: vec!["a".into(), "b".into(), "c".into()],
                ..Mesh::default()
            },
            Path::new("t"),
        );
        assert_eq!(scene.triangles, vec![[0, 1, 2], [1, 3, 2]]);
        assert_eq!(scene.triangle_material, vec![0, 2]);
    }

    #[test]
    fn a_far_mesh_is_centred_in_f64() {
        let far = DVec3::splat(1e6);
        let scene = from_mesh(
            Mesh {
                positions: vec![far, far + DVec3::X * 0.01, far + DVec3::Y * 0.01],
                triangles: vec![[0, 1, 2]],
                ..Mesh::default()
            },
            Path::new("t"),
        );
        assert_eq!(
            scene.render_from_world.world_origin,
            far + DVec3::new(0.005, 0.005, 0.0)
        );
        // In f32 around 1e6 the three corners would be one point; centred they keep their shape.
        assert_eq!(scene.triangles.len(), 1);
        assert!((scene.positions[1] - scene.positions[0] - Vec3::X * 0.01).length() < 1e-7);
    }

    #[test]
    fn content_hash_sees_a_moved_vertex() {
        let a = one_triangle();
        let mut b = one_triangle();
        b.positions[1].x += 1e-6;
        assert_ne!(a.content_hash(), b.content_hash());
        assert_eq!(a.content_hash(), one_triangle().content_hash());
    }
}
