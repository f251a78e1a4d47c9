//! Colours reach the pixels: OBJ `map_Kd` textures, PLY and glTF vertex colours, glTF base
//! colour textures; a texture that cannot be read is a warning naming it, and the mesh loads.

use super::texture::Texture;
use super::{Scene, SceneSpec};
use crate::{render_tiles, FrameView, PreparedScene};
use glam::{Vec2, Vec3};
use std::path::Path;
use std::sync::{Arc, Mutex};
use tessera_model::camera::Camera;
use tessera_model::params::RenderParams;
use tessera_model::wall::{TileGrid, WallLayout};

const RED: [u8; 3] = [255, 0, 0];
const GREEN: [u8; 3] = [0, 255, 0];
const BLUE: [u8; 3] = [0, 0, 255];
const WHITE: [u8; 3] = [255, 255, 255];

/// Writes a `w × h` PNG of `texels` (row-major from the top) to `path`.
fn write_png(path: &Path, w: u32, h: u32, texels: &[[u8; 3]]) {
    let image = image::RgbImage::from_fn(w, h, |x, y| image::Rgb(texels[(y * w + x) as usize]));
    image.save(path).unwrap();
}

/// The scene at `path`, rendered 16×16 looking down -z at the unit quad from z = 3.
fn render(path: &Path) -> Vec<[u8; 3]> {
    let scene = Scene::load(&SceneSpec::File(path.to_path_buf())).unwrap();
    render_scene(&scene)
}

fn render_scene(scene: &Scene) -> Vec<[u8; 3]> {
    let prepared = PreparedScene::new(scene);
    let wall = WallLayout::grid(1, 1, 16, 16).unwrap();
    let grid = TileGrid::new(wall);
    // The quad is centred on the render origin, whatever its world position.
    let camera = Camera::new(Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, Vec3::Y, 60.0).unwrap();
    let view = FrameView::new(0, &camera, RenderParams::interactive(), 16, 16);
    let (tiles, _) = render_tiles(&prepared, &view, grid.tiles());
    tiles[0].chunks(3).map(|c| [c[0], c[1], c[2]]).collect()
}

/// Whether `pixel` is mostly `channel` (0 red, 1 green, 2 blue).
fn is_mostly(pixel: [u8; 3], channel: usize) -> bool {
    let c = pixel[channel] as u32;
    (0..3).all(|k| k == channel || c > 2 * pixel[k] as u32 + 20)
}

/// The quadrants of the quad at pixels (5 or 10, 5 or 10): top left, top right, bottom left,
/// bottom right.
fn quadrants(image: &[[u8; 3]]) -> [[u8; 3]; 4] {
    [(5, 5), (10, 5), (5, 10), (10, 10)].map(|(x, y)| image[y * 16 + x])
}

/// Runs `f` with a subscriber that records every event; returns what `f` gave and the log.
fn with_log<T>(f: impl FnOnce() -> T) -> (T, String) {
    #[derive(Clone, Default)]
    struct Log(Arc<Mutex<Vec<u8>>>);
    impl std::io::Write for Log {
        fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
            self.0.lock().unwrap().extend_from_slice(b);
            Ok(b.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }
    let log = Log::default();
    let writer = log.clone();
    let subscriber = tracing_subscriber::fmt()
        .with_writer(move || writer.clone())
        .with_ansi(false)
        .finish();
    let out = tracing::subscriber::with_default(subscriber, f);
    let text = String::from_utf8(log.0.lock().unwrap().clone()).unwrap();
    (out, text)
}

/// A unit quad (-1..1 in x and y) with texture coordinates over the whole image; OBJ's v runs
/// up, so the image's top row is at y = 1.
const TEXTURED_QUAD: &str = "mtllib q.mtl\nv -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\n\
    vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nusemtl painted\nf 1/1 2/2 3/3 4/4\n";

#[test]
fn obj_map_kd_textures_are_drawn_not_dropped() {
    let dir = tempfile::tempdir().unwrap();
    write_png(
        &dir.path().join("quad.png"),
        2,
        2,
        &[RED, GREEN, BLUE, WHITE],
    );
    // A Windows path, as real MTL files have (assimp's spider.mtl).
    let mtl = "newmtl painted\nKd 1 1 1\nmap_Kd .\\quad.png\n";
    std::fs::write(dir.path().join("q.mtl"), mtl).unwrap();
    let obj = dir.path().join("q.obj");
    std::fs::write(&obj, TEXTURED_QUAD).unwrap();
    let [top_left, top_right, bottom_left, bottom_right] = quadrants(&render(&obj));
    assert!(is_mostly(top_left, 0), "{top_left:?}");
    assert!(is_mostly(top_right, 1), "{top_right:?}");
    assert!(is_mostly(bottom_left, 2), "{bottom_left:?}");
    let grey = bottom_right.iter().all(|&c| c > 100)
        && bottom_right.iter().max().unwrap() - bottom_right.iter().min().unwrap() < 8;
    assert!(grey, "{bottom_right:?}");
}

#[test]
fn a_texture_that_cannot_be_read_warns_naming_it_and_the_mesh_loads() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("broken.png"), b"not a png").unwrap();
    let mtl = "newmtl painted\nKd 0.2 0.4 0.6\nmap_Kd missing.png\n\
               newmtl other\nKd 1 1 1\nmap_Kd broken.png\n";
    std::fs::write(dir.path().join("q.mtl"), mtl).unwrap();
    let obj = dir.path().join("q.obj");
    let text = format!("{TEXTURED_QUAD}usemtl other\nf 1/1 2/2 3/3\n");
    std::fs::write(&obj, text).unwrap();
    let (scene, log) = with_log(|| Scene::load(&SceneSpec::File(obj.clone())));
    let scene = scene.unwrap();
    assert!(scene.materials.iter().all(|m| m.texture.is_none()));
    assert!(scene.colors.textures.is_empty());
    assert_eq!(scene.materials[0].albedo, Vec3::new(0.2, 0.4, 0.6));
    for (file, material) in [("missing.png", "painted"), ("broken.png", "other")] {
        let line = log.lines().find(|l| l.contains(file));
        let line = line.unwrap_or_else(|| panic!("no warning names {file}: {log}"));
        assert!(
            line.contains("WARN") && line.contains(material) && line.contains("q.obj"),
            "{line}"
        );
    }
    // Drawn in the material's colour: more blue than red.
    let [p, ..] = quadrants(&render_scene(&scene));
    assert!(p[2] > p[0] + 30, "{p:?}");
}

#[test]
fn ply_vertex_colours_reach_the_pixel_as_bytes_or_floats() {
    let dir = tempfile::tempdir().unwrap();
    for (kind, [r, g, b], channel) in [
        ("uchar", ["255", "0", "0"], 0),
        ("float", ["0", "1", "0"], 1),
    ] {
        let ply = format!(
            "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n\
             property float z\nproperty {kind} red\nproperty {kind} green\nproperty {kind} blue\n\
             element face 1\nproperty list uchar int vertex_indices\nend_header\n\
             -1 -1 0 {r} {g} {b}\n1 -1 0 {r} {g} {b}\n1 1 0 {r} {g} {b}\n-1 1 0 {r} {g} {b}\n\
             4 0 1 2 3\n"
        );
        let path = dir.path().join(format!("{kind}.ply"));
        std::fs::write(&path, ply).unwrap();
        let mesh = super::load_mesh_file(&path).unwrap();
        let want = [RED, GREEN][channel];
        assert_eq!(mesh.colors.vertex, vec![want; 4], "{kind}");
        for p in quadrants(&render(&path)) {
            assert!(is_mostly(p, channel), "{kind}: {p:?}");
        }
    }
}

/// A glTF quad in `m.bin`: positions, texture coordinates, COLOR_0 (white but for vertex 0's
/// `first`) and indices; its material's base colour texture is `t.png`.
fn gltf_quad(dir: &Path, first: [f32; 3]) -> std::path::PathBuf {
    let mut bin = Vec::new();
    let floats = |bin: &mut Vec<u8>, v: &[f32]| v.iter().for_each(|f| bin.extend(f.to_le_bytes()));
    floats(
        &mut bin,
        &[-1., -1., 0., 1., -1., 0., 1., 1., 0., -1., 1., 0.],
    );
    floats(&mut bin, &[0., 1., 1., 1., 1., 0., 0., 0.]);
    floats(&mut bin, &first);
    floats(&mut bin, &[1.; 9]);
    [0u16, 1, 2, 0, 2, 3]
        .iter()
        .for_each(|i| bin.extend(i.to_le_bytes()));
    std::fs::write(dir.join("m.bin"), &bin).unwrap();
    let json = r#"{"asset":{"version":"2.0"},"scene":0,"scenes":[{"nodes":[0]}],
      "nodes":[{"mesh":0}],
      "meshes":[{"primitives":[{"attributes":{"POSITION":0,"TEXCOORD_0":1,"COLOR_0":2},
        "indices":3,"material":0}]}],
      "materials":[{"name":"painted","pbrMetallicRoughness":{"baseColorTexture":{"index":0},
        "metallicFactor":0,"roughnessFactor":1}}],
      "textures":[{"source":0}],"images":[{"uri":"t.png"}],
      "buffers":[{"byteLength":140,"uri":"m.bin"}],
      "bufferViews":[{"buffer":0,"byteLength":48},{"buffer":0,"byteOffset":48,"byteLength":32},
        {"buffer":0,"byteOffset":80,"byteLength":48},{"buffer":0,"byteOffset":128,"byteLength":12}],
      "accessors":[
        {"bufferView":0,"componentType":5126,"count":4,"type":"VEC3","min":[-1,-1,0],"max":[1,1,0]},
        {"bufferView":1,"componentType":5126,"count":4,"type":"VEC2"},
        {"bufferView":2,"componentType":5126,"count":4,"type":"VEC3"},
        {"bufferView":3,"componentType":5123,"count":6,"type":"SCALAR"}]}"#;
    let path = dir.join("m.gltf");
    std::fs::write(&path, json).unwrap();
    path
}

#[test]
fn gltf_base_colour_textures_and_color_0_are_drawn() {
    let dir = tempfile::tempdir().unwrap();
    write_png(&dir.path().join("t.png"), 2, 2, &[RED, GREEN, BLUE, WHITE]);
    let path = gltf_quad(dir.path(), [0.25, 0.5, 1.0]);
    let mesh = super::load_mesh_file(&path).unwrap();
    assert_eq!(mesh.materials[0].texture, Some(0));
    assert_eq!(mesh.colors.textures[0].size(), (2, 2));
    assert_eq!(mesh.colors.uvs[2], Vec2::new(1.0, 0.0));
    // COLOR_0 is linear; kept display-encoded (square root) like texels.
    assert_eq!(mesh.colors.vertex[0], [128, 180, 255]);
    assert_eq!(mesh.colors.vertex[1], WHITE);

    let path = gltf_quad(dir.path(), [1.0; 3]);
    let [top_left, top_right, bottom_left, _] = quadrants(&render(&path));
    assert!(is_mostly(top_left, 0), "{top_left:?}");
    assert!(is_mostly(top_right, 1), "{top_right:?}");
    assert!(is_mostly(bottom_left, 2), "{bottom_left:?}");

    // Vertex colours multiply the texture: green vertices over the white quadrant.
    write_png(&dir.path().join("t.png"), 1, 1, &[WHITE]);
    let mut bin = std::fs::read(dir.path().join("m.bin")).unwrap();
    for k in 0..12 {
        let v: f32 = if k % 3 == 1 { 1.0 } else { 0.0 };
        bin[80 + 4 * k..84 + 4 * k].copy_from_slice(&v.to_le_bytes());
    }
    std::fs::write(dir.path().join("m.bin"), bin).unwrap();
    for p in quadrants(&render(&path)) {
        assert!(is_mostly(p, 1), "{p:?}");
    }
}

#[test]
fn a_scene_file_keeps_each_meshes_colours_with_its_vertices() {
    let dir = tempfile::tempdir().unwrap();
    write_png(&dir.path().join("quad.png"), 1, 1, &[BLUE]);
    std::fs::write(
        dir.path().join("q.mtl"),
        "newmtl painted\nmap_Kd quad.png\n",
    )
    .unwrap();
    std::fs::write(dir.path().join("q.obj"), TEXTURED_QUAD).unwrap();
    let plain = "v 5 5 5\nv 6 5 5\nv 5 6 5\nf 1 2 3\n";
    std::fs::write(dir.path().join("plain.obj"), plain).unwrap();
    let path = dir.path().join("both.scene.toml");
    std::fs::write(&path, "meshes = [\"plain.obj\", \"q.obj\", \"q.obj\"]\n").unwrap();
    let scene = Scene::load(&SceneSpec::File(path)).unwrap();
    assert_eq!(scene.colors.uvs.len(), scene.positions.len());
    assert_eq!(scene.colors.uvs[..3], [Vec2::ZERO; 3], "the plain mesh's");
    assert_eq!(scene.colors.uvs[3], Vec2::new(0.0, 1.0));
    assert_eq!(scene.colors.textures.len(), 2, "one per part that read it");
    let textured: Vec<_> = scene.materials.iter().filter_map(|m| m.texture).collect();
    assert_eq!(textured, [0, 1]);
}

#[test]
fn textures_are_part_of_the_content_hash() {
    let dir = tempfile::tempdir().unwrap();
    write_png(&dir.path().join("quad.png"), 1, 1, &[BLUE]);
    std::fs::write(
        dir.path().join("q.mtl"),
        "newmtl painted\nmap_Kd quad.png\n",
    )
    .unwrap();
    let obj = dir.path().join("q.obj");
    std::fs::write(&obj, TEXTURED_QUAD).unwrap();
    let load = || Scene::load(&SceneSpec::File(obj.clone())).unwrap();
    let before = load().content_hash();
    assert_eq!(before, load().content_hash());
    write_png(&dir.path().join("quad.png"), 1, 1, &[RED]);
    assert_ne!(before, load().content_hash());
}

#[test]
fn a_scene_without_colours_prepares_none() {
    let scene = crate::scene::knot_scene(16, 4);
    assert!(scene.colors.is_empty());
    assert!(PreparedScene::new(&scene).colors.is_none());
    let mut textured = scene.clone();
    textured.colors.textures = vec![Texture::new("t", 1, 1, vec![RED])];
    assert!(PreparedScene::new(&textured).colors.is_none(), "no uvs");
}
