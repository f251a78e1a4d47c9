//! A real scanned-style mesh moved by 10⁶ in x, y and z, the camera with it, gives the same depth
//! image as the original: the loader reads f64 and moves the mesh to a local origin before f32,
//! and the camera given in world coordinates is moved the same way. In plain f32 the moved
//! vertices would sit on a 0.0625 grid, far coarser than the mesh's detail.

mod real_mesh;

use glam::{DVec3, Vec3};
use tessera_model::camera::Camera;
use tessera_model::params::RenderParams;
use tessera_model::scene_spec::SceneSpec;
use tessera_model::wall::{TileGrid, WallSpec};
use tessera_render::aov::primary_aovs;
use tessera_render::scene::Scene;
use tessera_render::{FrameView, PreparedScene};

const SHIFT: f64 = 1e6;
const SIZE: (u32, u32) = (320, 240);

/// The OBJ text with every vertex moved by `shift` on each axis, computed and printed in f64.
fn shifted_obj(text: &str, shift: f64) -> String {
    let mut out = String::with_capacity(text.len() * 2);
    for line in text.lines() {
        let mut words = line.split_whitespace();
        if words.next() == Some("v") {
            let xyz: Vec<f64> = words.take(3).map(|w| w.parse().unwrap()).collect();
            out.push_str(&format!(
                "v {} {} {}\n",
                xyz[0] + shift,
                xyz[1] + shift,
                xyz[2] + shift
            ));
        } else {
            out.push_str(line);
            out.push('\n');
        }
    }
    out
}

/// The depth image of `scene` seen from world points `eye` towards `target`.
fn depth(scene: &Scene, eye: DVec3, target: DVec3) -> Vec<f32> {
    let frame = scene.render_from_world;
    let camera = Camera::new(frame.point(eye), frame.point(target), Vec3::Y, 40.0).unwrap();
    let prepared = PreparedScene::new(scene);
    let wall = WallSpec::grid(1, 1, SIZE.0, SIZE.1).build().unwrap();
    let view = FrameView::new(0, &camera, RenderParams::interactive(), SIZE.0, SIZE.1);
    primary_aovs(&prepared, &view, &TileGrid::new(wall.clone())).depth
}

#[test]
fn a_mesh_moved_a_million_away_gives_the_same_depth_image() {
    let Some(path) = real_mesh::real_mesh() else {
        return;
    };
    let near = Scene::load(&SceneSpec::File(path.into())).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let moved_path = dir.path().join("moved.obj");
    let text = std::fs::read_to_string(path).unwrap();
    std::fs::write(&moved_path, shifted_obj(&text, SHIFT)).unwrap();
    let far = Scene::load(&SceneSpec::File(moved_path)).unwrap();
    assert_eq!(far.triangles.len(), near.triangles.len());

    let bounds = near.bounds();
    let middle = near.render_from_world.world_point(bounds.center());
    let eye = middle + DVec3::new(0.55, 0.45, 0.8) * bounds.diagonal().length() as f64 * 0.75;
    let shift = DVec3::splat(SHIFT);
    let (a, b) = (
        depth(&near, eye, middle),
        depth(&far, eye + shift, middle + shift),
    );

    let hits = a.iter().filter(|d| d.is_finite()).count();
    assert!(hits > a.len() / 10, "the mesh covers only {hits} pixels");
    let agree = a
        .iter()
        .zip(&b)
        .filter(|(x, y)| match (x.is_finite(), y.is_finite()) {
            (true, true) => ((*x - *y) / *x).abs() <= 1e-4,
            (false, false) => true,
            _ => false,
        })
        .count();
    let share = agree as f64 / a.len() as f64;
    eprintln!(
        "{agree} of {} pixels agree ({:.4} %), {hits} hit",
        a.len(),
        share * 100.0
    );
    assert!(
        share >= 0.999,
        "only {:.3} % of pixels agree",
        share * 100.0
    );
}
