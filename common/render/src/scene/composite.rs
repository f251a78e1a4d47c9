//! A scene of several files, named by a small TOML file (`NAME.scene.toml`): meshes, particles
//! and a volume together, in one world. Paths are relative to the scene file.
//!
//! ```toml
//! meshes = ["skull.obj", "implant.ply"]
//! volume = "head.nii.gz"
//! particles = "tracers.csv"
//! ```
//!
//! `particles` may be a point cloud too (a PLY of vertices alone, a CSV of positions alone). A
//! time series takes the place of `volume`: `series = ["t0.nrrd", "t1.nrrd"]`, or a pattern
//! with one `*` in the file name, `series = "flow/t*.nrrd"`, its matches in name order.
//!
//! Every part keeps its world coordinates; the render frame is centred on all of them together
//! (in f64, as for one mesh), so a mesh drawn inside a CT volume sits where it should.

use super::{default_light, from_mesh_in, particles, Mesh, Scene, SceneError, NEUTRAL};
use crate::volume::{self, Volume};
use glam::DVec3;
use serde::Deserialize;
use std::path::{Path, PathBuf};
use tessera_model::local_origin::RenderFromWorld;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneFile {
    #[serde(default)]
    meshes: Vec<PathBuf>,
    particles: Option<PathBuf>,
    volume: Option<PathBuf>,
    series: Option<Series>,
}

#[derive(Deserialize)]
#[serde(untagged)]
enum Series {
    List(Vec<PathBuf>),
    Pattern(String),
}

/// The files of a series: the list as given, or the pattern's matches in name order.
fn series_paths(dir: &Path, series: &Series, scene: &Path) -> Result<Vec<PathBuf>, SceneError> {
    let bad = |message: String| SceneError::File {
        path: scene.display().to_string(),
        message,
    };
    let paths: Vec<PathBuf> = match series {
        Series::List(list) => list.iter().map(|p| dir.join(p)).collect(),
        Series::Pattern(pattern) => {
            let full = dir.join(pattern);
            let folder = full.parent().unwrap_or(dir).to_path_buf();
            let name = full.file_name().and_then(|n| n.to_str()).unwrap_or("");
            let Some((head, tail)) = name.split_once('*') else {
                return Err(bad(format!(
                    "series pattern {pattern:?} has no * in its file name"
                )));
            };
            let entries = std::fs::read_dir(&folder)
                .map_err(|e| bad(format!("series folder {}: {e}", folder.display())))?;
            let mut names: Vec<String> = entries
                .filter_map(|e| e.ok()?.file_name().into_string().ok())
                .filter(|n| {
                    n.len() >= head.len() + tail.len() && n.starts_with(head) && n.ends_with(tail)
                })
                .collect();
            names.sort();
            names.into_iter().map(|n| folder.join(n)).collect()
        }
    };
    if paths.is_empty() {
        return Err(bad("the series names no files".into()));
    }
    Ok(paths)
}

/// Whether `path` names a scene file (`.scene.toml`).
pub fn is_scene_file(path: &Path) -> bool {
    path.to_string_lossy()
        .to_ascii_lowercase()
        .ends_with(".scene.toml")
}

/// Loads every part the scene file at `path` names.
///
/// # Errors
/// An unreadable or malformed scene file (naming the field), a file that names no part, or any
/// part's own load error (which names that part's file).
pub fn load_scene_file(path: &Path) -> Result<Scene, SceneError> {
    let bad = |message: String| SceneError::File {
        path: path.display().to_string(),
        message,
    };
    let text = std::fs::read_to_string(path).map_err(|e| bad(e.to_string()))?;
    let file: SceneFile = toml::from_str(&text).map_err(|e| bad(e.to_string()))?;
    let dir = path.parent().unwrap_or(Path::new("."));
    if file.volume.is_some() && file.series.is_some() {
        return Err(bad("give a volume or a series, not both".into()));
    }
    let series = match &file.series {
        Some(series) => series_paths(dir, series, path)?,
        None => Vec::new(),
    };
    if file.meshes.is_empty()
        && file.particles.is_none()
        && file.volume.is_none()
        && series.is_empty()
    {
        return Err(bad("names no meshes, particles or volume".into()));
    }
    let mut mesh = Mesh::default();
    for part in &file.meshes {
        if super::points::is_point_cloud(&dir.join(part)) {
            return Err(bad(format!(
                "mesh {} has vertices and no faces: a point cloud, name it as `particles`",
                part.display()
            )));
        }
        append(
            &mut mesh,
            super::load_mesh_file(&dir.join(part))?,
            &dir.join(part),
        )?;
    }
    // A series is placed, bounded and hashed by its first step.
    let first = file
        .volume
        .as_ref()
        .map(|v| dir.join(v))
        .or(series.first().cloned());
    let volume: Option<Volume> = first.as_deref().map(volume::load).transpose()?;
    let world_particles = match &file.particles {
        // Particles, or a point cloud (a PLY of vertices alone, a CSV of positions).
        Some(p) => super::points::load(&dir.join(p))?,
        None => Vec::new(),
    };
    let mut extent: Vec<DVec3> = mesh.positions.clone();
    if let Some(v) = &volume {
        extent.extend(v.world_corners().map(DVec3::from_array));
    }
    extent.extend(world_particles.iter().map(|p| p.center));
    let frame = RenderFromWorld::centred_on(&extent);
    let particles = particles::place(&world_particles, frame);
    let mut scene = if mesh.triangles.is_empty() {
        Scene {
            lights: vec![default_light()],
            render_from_world: frame,
            ..Scene::default()
        }
    } else {
        from_mesh_in(mesh, path, frame)
    };
    scene.up = volume.as_ref().and_then(Volume::up);
    scene.volume = volume;
    scene.series = series;
    scene.particles = particles;
    Ok(scene)
}

/// Adds `part` to `mesh`: its vertices after the ones there, its materials after theirs (a part
/// without materials gets the neutral one).
fn append(mesh: &mut Mesh, mut part: Mesh, path: &Path) -> Result<(), SceneError> {
    if part.materials.is_empty() {
        part.triangle_material = vec![0; part.triangles.len()];
        part.materials = vec![NEUTRAL];
        part.material_names = vec!["neutral".into()];
    }
    let too_many = |what: &str| SceneError::File {
        path: path.display().to_string(),
        message: format!("the scene's meshes have more {what} than one scene holds"),
    };
    let first_vertex = u32::try_from(mesh.positions.len()).map_err(|_| too_many("vertices"))?;
    let first_material = u16::try_from(mesh.materials.len()).map_err(|_| too_many("materials"))?;
    if mesh.materials.len() + part.materials.len() > u16::MAX as usize {
        return Err(too_many("materials"));
    }
    let shift = mesh
        .colors
        .append(mesh.positions.len(), part.positions.len(), part.colors);
    if mesh.colors.textures.len() > u16::MAX as usize {
        return Err(too_many("textures"));
    }
    for m in &mut part.materials {
        m.texture = m.texture.map(|t| t + shift);
    }
    mesh.positions.extend(part.positions);
    mesh.triangles.extend(
        part.triangles
            .iter()
            .map(|t| t.map(|v| v.saturating_add(first_vertex))),
    );
    mesh.triangle_material
        .extend(part.triangle_material.iter().map(|m| m + first_material));
    mesh.materials.extend(part.materials);
    mesh.material_names.extend(part.material_names);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_scene_file_puts_a_mesh_inside_a_volume_in_one_frame() {
        let dir = tempfile::tempdir().unwrap();
        let obj = "v 10 10 10\nv 12 10 10\nv 10 12 10\nf 1 2 3\n";
        std::fs::write(dir.path().join("tri.obj"), obj).unwrap();
        std::fs::write(dir.path().join("tri2.obj"), obj).unwrap();
        std::fs::write(dir.path().join("v.raw"), vec![7u8; 27]).unwrap();
        std::fs::write(
            dir.path().join("v.vol.toml"),
            "data = \"v.raw\"\ndims = [3, 3, 3]\ntype = \"u8\"\nspacing = [10.0, 10.0, 10.0]\n",
        )
        .unwrap();
        let path = dir.path().join("both.scene.toml");
        std::fs::write(
            &path,
            "meshes = [\"tri.obj\", \"tri2.obj\"]\nvolume = \"v.vol.toml\"\n",
        )
        .unwrap();
        let scene = load_scene_file(&path).unwrap();
        assert_eq!(scene.triangles, vec![[0, 1, 2], [3, 4, 5]]);
        assert!(scene.volume.is_some());
        // The frame is centred on the volume's box (0..20), which holds the triangles.
        assert_eq!(scene.render_from_world.world_origin, DVec3::splat(10.0));
        assert_eq!(scene.positions[1], glam::Vec3::new(2.0, 0.0, 0.0));
        let bounds = scene.bounds();
        assert_eq!(
            (bounds.min, bounds.max),
            (glam::Vec3::splat(-10.0), glam::Vec3::splat(10.0))
        );
        scene.validate("both").unwrap();

        // A series by pattern: its matches in name order, the first step loaded.
        std::fs::copy(
            dir.path().join("v.vol.toml"),
            dir.path().join("s1.vol.toml"),
        )
        .unwrap();
        std::fs::copy(
            dir.path().join("v.vol.toml"),
            dir.path().join("s0.vol.toml"),
        )
        .unwrap();
        std::fs::write(&path, "series = \"s*.vol.toml\"\n").unwrap();
        let scene = load_scene_file(&path).unwrap();
        let names: Vec<_> = scene
            .series
            .iter()
            .map(|p| p.file_name().unwrap().to_owned())
            .collect();
        assert_eq!(names, ["s0.vol.toml", "s1.vol.toml"]);
        assert!(scene.volume.is_some());
        std::fs::write(&path, "series = \"q*.vol.toml\"\n").unwrap();
        assert!(load_scene_file(&path)
            .unwrap_err()
            .to_string()
            .contains("no files"));

        std::fs::write(&path, "meshes = [\"missing.obj\"]\n").unwrap();
        let err = load_scene_file(&path).unwrap_err().to_string();
        assert!(err.contains("missing.obj"), "{err}");
        std::fs::write(&path, "mesh = \"tri.obj\"\n").unwrap();
        let err = load_scene_file(&path).unwrap_err().to_string();
        assert!(
            err.contains("unknown field") && err.contains("mesh"),
            "{err}"
        );
        std::fs::write(&path, "").unwrap();
        assert!(load_scene_file(&path).is_err());
    }

    #[test]
    fn a_point_cloud_in_a_scene_file_is_particles_and_refused_as_a_mesh() {
        let dir = tempfile::tempdir().unwrap();
        let cloud = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n\
                     property float y\nproperty float z\nend_header\n0 0 0\n1 0 0\n0 1 0\n";
        std::fs::write(dir.path().join("cloud.ply"), cloud).unwrap();
        let path = dir.path().join("s.scene.toml");
        std::fs::write(&path, "particles = \"cloud.ply\"\n").unwrap();
        let scene = load_scene_file(&path).unwrap();
        assert_eq!(scene.particles.len(), 3);
        std::fs::write(&path, "meshes = [\"cloud.ply\"]\n").unwrap();
        let err = load_scene_file(&path).unwrap_err().to_string();
        assert!(
            err.contains("point cloud") && err.contains("particles"),
            "{err}"
        );
    }
}
