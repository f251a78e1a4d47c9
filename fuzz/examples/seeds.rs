//! Writes the seed corpus, `fuzz/corpus/<target>/`: a few small valid inputs per target, made
//! with the crates' own encoders where they have one, so the seeds follow the formats when
//! they change. Run by `fuzz/run.sh --seeds`.

use dicom_core::{DataElement, PrimitiveValue, VR};
use dicom_dictionary_std::{tags, uids};
use dicom_object::{FileMetaTableBuilder, InMemDicomObject};
use glam::Vec3;
use std::io::Write;
use std::path::{Path, PathBuf};
use tessera_render::scene::particles::{write_tpart, Particle};
use tessera_model::camera::Camera;
use tessera_protocol::control::{ControlReply, ControlRequest, LiveFigures, ViewName};
use tessera_model::params::RenderParams;
use tessera_protocol::pixels::{encode_batch, BatchSource, Compression};
use tessera_protocol::*;
use tessera_model::state::StateId;
use tessera_protocol::dsm::{BlockHolder, BlockRequest, DataSpec, DsmStats, DsmSpec};
use tessera_model::wall::{DisplayId, TileGrid, TileId, WallSpec};

#[path = "seeds_parts/formats.rs"]
mod formats;
use formats::formats;

fn main() {
    let root = PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| "corpus".into()));
    codec(&root);
    pixels(&root);
    bvh(&root);
    meshes(&root);
    particles(&root);
    volumes(&root);
    formats(&root);
    files(&root);
    shared(&root);
    check(&root);
}

/// Every seed must load: a seed that fails at its first field only teaches the fuzzer errors.
fn check(root: &Path) {
    use tessera_render::scene::Scene;
    use tessera_model::scene_spec::SceneSpec;
    let dir = std::env::temp_dir().join(format!("tessera-seed-check-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let scene_parts = [
        ("m.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n".as_bytes()),
        ("p.csv", b"x,y,z,radius,attribute\n0,0,0,0.5,1\n"),
        ("v.raw", &[0, 10, 20, 30, 40, 50, 60, 70]),
        (
            "v.vol.toml",
            b"data = \"v.raw\"\ndims = [2, 2, 2]\ntype = \"u8\"\n",
        ),
        (
            "t0.vol.toml",
            b"data = \"v.raw\"\ndims = [2, 2, 2]\ntype = \"u8\"\n",
        ),
        (
            "t1.vol.toml",
            b"data = \"v.raw\"\ndims = [2, 2, 2]\ntype = \"u8\"\n",
        ),
    ];
    for (name, bytes) in scene_parts {
        std::fs::write(dir.join(name), bytes).unwrap();
    }
    let scene = |target: &str, name: &str| {
        for seed in seeds(root, target) {
            let path = dir.join(name);
            std::fs::write(&path, std::fs::read(&seed).unwrap()).unwrap();
            let spec = SceneSpec::from_arg(path.to_str().unwrap()).unwrap();
            if let Err(e) = Scene::load(&spec) {
                panic!("seed {} does not load: {e}", seed.display());
            }
        }
    };
    scene("mesh_obj", "mesh.obj");
    scene("mesh_ply", "mesh.ply");
    scene("mesh_gltf", "mesh.gltf");
    scene("mesh_glb", "mesh.glb");
    scene("particles_csv", "particles.csv");
    scene("particles_tpart", "particles.tpart");
    scene("scene_toml", "fuzzed.scene.toml");
    scene("volume_nrrd", "volume.nrrd");
    scene("mesh_stl", "mesh.stl");
    scene("mesh_vtk", "mesh.vtk");
    scene("points_ply", "points.ply");
    for seed in seeds(root, "mesh_vtk_xml") {
        let bytes = std::fs::read(&seed).unwrap();
        let grid = bytes.windows(16).any(|w| w == b"UnstructuredGrid");
        let path = dir.join(if grid { "mesh.vtu" } else { "mesh.vtp" });
        std::fs::write(&path, bytes).unwrap();
        let spec = SceneSpec::from_arg(path.to_str().unwrap()).unwrap();
        Scene::load(&spec).unwrap_or_else(|e| panic!("seed {} does not load: {e}", seed.display()));
    }
    for seed in seeds(root, "volume_vti") {
        let path = dir.join("volume.vti");
        std::fs::write(&path, std::fs::read(&seed).unwrap()).unwrap();
        tessera_render::volume::load(&path).unwrap();
    }
    scene("volume_nifti", "volume.nii");
    for seed in seeds(root, "volume_raw") {
        let bytes = std::fs::read(&seed).unwrap();
        let at = bytes.iter().position(|&b| b == 0).unwrap();
        std::fs::write(dir.join("data.raw"), &bytes[at + 1..]).unwrap();
        std::fs::write(dir.join("volume.vol.toml"), &bytes[..at]).unwrap();
        tessera_render::volume::load(&dir.join("volume.vol.toml")).unwrap();
    }
    for seed in seeds(root, "volume_dicom") {
        let series = dir.join("series");
        let _ = std::fs::remove_dir_all(&series);
        std::fs::create_dir_all(&series).unwrap();
        let bytes = std::fs::read(&seed).unwrap();
        let marker = b"--TESSERA-FUZZ-SLICE--";
        let mut rest = &bytes[..];
        let mut i = 0;
        loop {
            let at = rest.windows(marker.len()).position(|w| w == marker);
            let slice = &rest[..at.unwrap_or(rest.len())];
            std::fs::write(series.join(format!("slice{i}.dcm")), slice).unwrap();
            i += 1;
            match at {
                Some(at) => rest = &rest[at + marker.len()..],
                None => break,
            }
        }
        tessera_render::volume::load(&series).unwrap();
    }
    for seed in seeds(root, "wall_file") {
        let text = std::fs::read_to_string(&seed).unwrap();
        tessera_model::window::WallFile::from_toml(&text, "seed").unwrap();
    }
    for seed in seeds(root, "transfer_file") {
        let path = dir.join("transfer.toml");
        std::fs::write(&path, std::fs::read(&seed).unwrap()).unwrap();
        tessera_cli::transfer_file::transfer_function(path.to_str().unwrap()).unwrap();
    }
    for seed in seeds(root, "codec_to_node") {
        codec::decode_frame::<ToNode>(&std::fs::read(&seed).unwrap()).unwrap();
    }
    for seed in seeds(root, "codec_from_node") {
        codec::decode_frame::<FromNode>(&std::fs::read(&seed).unwrap()).unwrap();
    }
    for seed in seeds(root, "bvh_cache") {
        let bytes = std::fs::read(&seed).unwrap();
        let triangles = u64::from_le_bytes(bytes[16..24].try_into().unwrap()) as usize;
        tessera_render::bvh::cache::decode_bytes(&bytes, triangles).unwrap();
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

fn seeds(root: &Path, target: &str) -> Vec<PathBuf> {
    let mut out: Vec<PathBuf> = std::fs::read_dir(root.join(target))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    out.sort();
    out
}

fn put(root: &Path, target: &str, name: &str, bytes: impl AsRef<[u8]>) {
    let dir = root.join(target);
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join(name), bytes).unwrap();
}

fn codec(root: &Path) {
    let camera = Camera::new(Vec3::ONE, Vec3::ZERO, Vec3::Y, 40.0).unwrap();
    let to_node = [
        ToNode::Welcome {
            node: Some(RenderNodeId(2)),
            session: Session::new(SessionSpec {
                wall: WallSpec::grid(2, 2, 480, 270).bezel(16).build().unwrap(),
                scene: Default::default(),
                scene_hash: [7; 32],
                displays: vec![DisplayEndpoint {
                    display: DisplayId(0),
                    addr: "[::1]:9".parse().unwrap(),
                }],
                save_frame: Some(FrameId(3)),
                compression: Compression::Lz4,
                windows: Default::default(),
                data: DataSpec::Dsm(DsmSpec {
                    dir: "/var/tessera/prepared".into(),
                    block_bytes: 8192,
                    ranks: 4,
                    replicas: 2,
                    memory_budget: Some(512 << 20),
                    cache_fraction: Some(0.125),
                }),
                particle_range: Some([-1.5, 2.0]),
            })
            .unwrap(),
            term: 0,
        },
        ToNode::BlockHolders {
            rank: Some(1),
            holders: vec![BlockHolder {
                rank: 0,
                addr: "127.0.0.1:7401".parse().unwrap(),
            }],
        },
        ToNode::FrameStart(FrameStart::new(
            FrameId(1),
            StateId(7),
            camera,
            RenderParams::interactive(),
        )),
        ToNode::Assign {
            frame: FrameId(4),
            tiles: vec![
                TileRange::new(0, 9).unwrap(),
                TileRange::new(12, 13).unwrap(),
            ],
        },
        ToNode::PresentAt {
            frame: FrameId(5),
            clock_ns: 1 << 60,
        },
        ToNode::ControlReply {
            id: 3,
            reply: ControlReply::Figures(LiveFigures::default()),
        },
        ToNode::ControlReply {
            id: 4,
            reply: ControlReply::Views(vec![ViewName::new("home").unwrap()]),
        },
        ToNode::Refused {
            reason: "full".into(),
        },
        ToNode::Shutdown,
    ];
    for (i, msg) in to_node.iter().enumerate() {
        put(
            root,
            "codec_to_node",
            &format!("seed{i}"),
            codec::encode(msg).unwrap(),
        );
    }
    let from_node = [
        FromNode::Hello(Hello {
            version: PROTOCOL_VERSION,
            role: Role::Display {
                display: DisplayId(3),
                pixel_addr: "127.0.0.1:4000".parse().unwrap(),
            },
            host: "wall-3".into(),
        }),
        FromNode::TilesDone {
            frame: FrameId(9),
            tiles: vec![TileRange::new(4, 90).unwrap()],
            want_more: true,
        },
        FromNode::Stats(NodeStats::Render(RenderStats {
            tiles: 5,
            rays: 1 << 40,
            busy_s: 1.5,
            elapsed_s: 2.0,
            volume_load_s: vec![0.25, 0.5],
            prefetch_hits: 7,
            prefetch_misses: 1,
            volume_stall_s: 0.25,
            max_rss_bytes: 40 << 20,
            dsm: Some(Box::new(DsmStats {
                rank: Some(2),
                block_reads: 1000,
                fetched: 12,
                latency_avg_us: 250.0,
                ..Default::default()
            })),
        })),
        FromNode::BlocksAt {
            addr: "0.0.0.0:7401".parse().unwrap(),
        },
        FromNode::Control {
            id: 1,
            request: ControlRequest::Probe { x: 10, y: 20 },
            stamp_ns: 99,
        },
        FromNode::Control {
            id: 2,
            request: ControlRequest::SaveView(ViewName::new("left").unwrap()),
            stamp_ns: 0,
        },
        FromNode::Failed {
            message: "no scene".into(),
        },
    ];
    for (i, msg) in from_node.iter().enumerate() {
        put(
            root,
            "codec_from_node",
            &format!("seed{i}"),
            codec::encode(msg).unwrap(),
        );
    }
}

/// A block request as a render node sends it, and a prepared scene's manifest.
fn shared(root: &Path) {
    for (i, blocks) in [vec![], vec![3, 4, 900_000]].into_iter().enumerate() {
        let request = BlockRequest {
            blocks,
            ahead: i == 1,
        };
        put(root, "dsm_wire", &format!("request{i}"), codec::encode(&request).unwrap());
    }
    let scene = tessera_render::scene::knot_scene(24, 4);
    let accel = tessera_render::bvh::Accel::build(&scene);
    let (manifest, _, _) = tessera_render::dsm::prepare::blocks_of(&scene, &accel, 2048).unwrap();
    let text = serde_json::to_string_pretty(&manifest).unwrap();
    put(root, "dsm_manifest", "knot", text);
}

/// The wall of `fuzz_targets/pixel_stream.rs`.
fn pixels(root: &Path) {
    let grid = TileGrid::new(WallSpec::grid(2, 1, 100, 70).tile_size(32).build().unwrap());
    for (name, compression) in [("raw", Compression::None), ("lz4", Compression::Lz4)] {
        let tiles: Vec<(TileId, Vec<u8>)> = grid
            .display_tiles(DisplayId(0))
            .iter()
            .take(3)
            .map(|t| {
                let rgb = (0..t.pixel_count() * 3).map(|i| (i / 7) as u8).collect();
                (t.id, compression.encode_tile(rgb))
            })
            .collect();
        let mut stream = vec![0u8];
        stream.extend(encode_batch(
            (FrameId(1), StateId(2)),
            BatchSource::default(),
            compression,
            tiles.iter().map(|(id, p)| (*id, p.as_slice())),
        ));
        put(root, "pixel_stream", name, stream);
    }
}

fn bvh(root: &Path) {
    let dir = std::env::temp_dir().join(format!("tessera-seeds-{}", std::process::id()));
    let scene = tessera_render::scene::knot_scene(6, 3);
    tessera_render::bvh::cache::load_or_build(&scene, Some(&dir));
    for entry in std::fs::read_dir(&dir).unwrap() {
        put(
            root,
            "bvh_cache",
            "knot",
            std::fs::read(entry.unwrap().path()).unwrap(),
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

fn meshes(root: &Path) {
    put(root, "mesh_obj", "quad", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvn 0 0 1\nvt 0 0\nf 1/1/1 2/1/1 3/1/1 4/1/1\nf -4 -3 -2\n");
    put(
        root,
        "mesh_obj",
        "groups",
        "mtllib m.mtl\no a\ng g1\nusemtl red\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\ns off\nl 1 2\n",
    );
    let ply_header = |format: &str| {
        format!(
            "ply\nformat {format} 1.0\ncomment fuzz seed\nelement vertex 4\nproperty float x\n\
             property float y\nproperty float z\nelement face 1\n\
             property list uchar int vertex_indices\nend_header\n"
        )
    };
    let mut ascii = ply_header("ascii");
    ascii.push_str("0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n");
    put(root, "mesh_ply", "ascii", ascii);
    let mut binary = ply_header("binary_little_endian").into_bytes();
    for c in [0f32, 0., 0., 1., 0., 0., 1., 1., 0., 0., 1., 0.] {
        binary.extend(c.to_le_bytes());
    }
    binary.push(3);
    for i in [0i32, 1, 2] {
        binary.extend(i.to_le_bytes());
    }
    put(root, "mesh_ply", "binary", binary);

    // A triangle, its u16 indices, and a second triangle, as in the gltf module's tests.
    let mut bin = Vec::new();
    let tri = |z: f32| [0f32, 0., z, 1., 0., z, 0., 1., z];
    tri(0.).iter().for_each(|c| bin.extend(c.to_le_bytes()));
    [0u16, 1, 2]
        .iter()
        .for_each(|i| bin.extend(i.to_le_bytes()));
    bin.extend([0, 0]);
    tri(1.).iter().for_each(|c| bin.extend(c.to_le_bytes()));
    let doc = |buffer: &str| GLTF.replace("BUFFER", buffer);
    put(
        root,
        "mesh_gltf",
        "data_uri",
        doc(&format!(
            r#"{{"byteLength":80,"uri":"data:application/octet-stream;base64,{}"}}"#,
            base64(&bin)
        )),
    );
    put(
        root,
        "mesh_glb",
        "bin_chunk",
        glb(&doc(r#"{"byteLength":80}"#), &bin),
    );
}

const GLTF: &str = r#"{"asset":{"version":"2.0"},"scene":1,
  "scenes":[{"nodes":[2]},{"nodes":[0]}],
  "nodes":[{"translation":[10,0,0],"children":[1]},{"scale":[2,2,-2],"mesh":0},{"mesh":0}],
  "materials":[{"pbrMetallicRoughness":{"baseColorFactor":[1,0,0,0.5],"metallicFactor":1,
    "roughnessFactor":0.1},"alphaMode":"BLEND"}],
  "meshes":[{"name":"pair","primitives":[
    {"attributes":{"POSITION":0},"indices":1,"mode":4,"material":0},
    {"attributes":{"POSITION":2},"mode":5}]}],
  "buffers":[BUFFER],
  "bufferViews":[{"buffer":0,"byteLength":36},{"buffer":0,"byteOffset":36,"byteLength":6},
    {"buffer":0,"byteOffset":44,"byteLength":36}],
  "accessors":[
    {"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]},
    {"bufferView":1,"componentType":5123,"count":3,"type":"SCALAR"},
    {"bufferView":2,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,1],"max":[1,1,1]}]}"#;

fn base64(bytes: &[u8]) -> String {
    const ABC: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::new();
    for chunk in bytes.chunks(3) {
        let n = chunk.iter().fold(0u32, |n, &b| n << 8 | u32::from(b)) << (8 * (3 - chunk.len()));
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

fn particles(root: &Path) {
    put(
        root,
        "particles_csv",
        "columns",
        "x,y,z,radius,attribute\n0,0,0,0.5,1\n2,1,0,0.25,3.5\n",
    );
    put(
        root,
        "particles_csv",
        "reordered",
        "# tracers\nAttribute , Z,y,x,Radius\n1e3,1,2,3,0.1\n",
    );
    let particles = [
        Particle {
            center: Vec3::ZERO,
            radius: 0.5,
            attribute: 1.0,
        },
        Particle {
            center: Vec3::new(2.0, -1.0, 0.5),
            radius: 0.25,
            attribute: -4.0,
        },
    ];
    let path = std::env::temp_dir().join(format!("tessera-seed-{}.tpart", std::process::id()));
    write_tpart(&path, &particles).unwrap();
    put(
        root,
        "particles_tpart",
        "two",
        std::fs::read(&path).unwrap(),
    );
    std::fs::remove_file(&path).unwrap();
}

fn volumes(root: &Path) {
    let header = "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 2 2 2\nspacings: 1 1 2\n";
    let voxels = [0u8, 10, 20, 30, 40, 50, 60, 70];
    let mut raw = format!("{header}encoding: raw\n\n").into_bytes();
    raw.extend(voxels);
    put(root, "volume_nrrd", "raw", raw);
    let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    for v in [0i16, -1000, 500, 20, 3, 4, 5, 6] {
        gz.write_all(&v.to_be_bytes()).unwrap();
    }
    let mut gzip = "NRRD0004\ntype: short\ndimension: 3\nsizes: 2 2 2\nendian: big\n\
         space directions: (1,0,0) (0,1,0) (0,0.5,1)\nspace origin: (10,20,30)\nencoding: gzip\n\n"
        .to_string()
        .into_bytes();
    gzip.extend(gz.finish().unwrap());
    put(root, "volume_nrrd", "gzip", gzip);

    put(root, "volume_nifti", "sform", nifti(1));
    put(root, "volume_nifti", "qform", nifti(0));

    let mut sidecar =
        b"data = \"data.raw\"\ndims = [2, 2, 2]\ntype = \"u16\"\nspacing = [1, 1, 3]\n\
        origin = [5, 0, 0]\nendian = \"big\"\n\0"
            .to_vec();
    for v in 0u16..8 {
        sidecar.extend((v * 100).to_be_bytes());
    }
    put(root, "volume_raw", "u16", sidecar);

    let mut series = Vec::new();
    for (z, base) in [(0.0, 10), (2.5, 20)] {
        if !series.is_empty() {
            series.extend(b"--TESSERA-FUZZ-SLICE--");
        }
        series.extend(dicom_slice(z, base));
    }
    put(root, "volume_dicom", "two_slices", series);
    put(root, "volume_dicom", "one_slice", dicom_slice(1.0, 0));
}

/// A 2×2×2 i16 NIfTI-1 file placed by its sform (`sform` 1) or its qform.
fn nifti(sform: i16) -> Vec<u8> {
    let mut h = vec![0u8; 352];
    let at = |h: &mut Vec<u8>, off: usize, bytes: &[u8]| {
        h[off..off + bytes.len()].copy_from_slice(bytes)
    };
    at(&mut h, 0, &348i32.to_le_bytes());
    for (i, d) in [3i16, 2, 2, 2, 1, 1, 1, 1].iter().enumerate() {
        at(&mut h, 40 + 2 * i, &d.to_le_bytes());
    }
    at(&mut h, 70, &4i16.to_le_bytes()); // DT_SIGNED_SHORT
    at(&mut h, 72, &16i16.to_le_bytes());
    for (i, p) in [1f32, 0.5, 0.5, 2.0, 1.0, 1.0, 1.0, 1.0].iter().enumerate() {
        at(&mut h, 76 + 4 * i, &p.to_le_bytes());
    }
    at(&mut h, 108, &352f32.to_le_bytes());
    at(&mut h, 112, &2f32.to_le_bytes());
    at(&mut h, 116, &(-1024f32).to_le_bytes());
    at(&mut h, 252, &1i16.to_le_bytes());
    at(&mut h, 254, &sform.to_le_bytes());
    for (i, q) in [0f32, 0.0, std::f32::consts::FRAC_1_SQRT_2, 1.0, 2.0, 3.0]
        .iter()
        .enumerate()
    {
        at(&mut h, 256 + 4 * i, &q.to_le_bytes());
    }
    for (i, s) in [0.5f32, 0., 0., -10., 0., 0.5, 0., 20., 0., 0., 2., 5.]
        .iter()
        .enumerate()
    {
        at(&mut h, 280 + 4 * i, &s.to_le_bytes());
    }
    at(&mut h, 344, b"n+1\0");
    for v in 0i16..8 {
        h.extend((v * 3).to_le_bytes());
    }
    h
}

/// A 2-row, 2-column CT slice at height `z`, as the dicom module's tests write them.
fn dicom_slice(z: f64, base: u16) -> Vec<u8> {
    let pixels: Vec<u16> = (0..4).map(|i| base + i).collect();
    let uid = format!("2.25.{}", 1000 + base);
    let ds = |tag, text: &str| DataElement::new(tag, VR::DS, PrimitiveValue::from(text));
    let us = |tag, v: u16| DataElement::new(tag, VR::US, PrimitiveValue::from(v));
    let obj = InMemDicomObject::from_element_iter([
        DataElement::new(
            tags::SOP_CLASS_UID,
            VR::UI,
            PrimitiveValue::from(uids::CT_IMAGE_STORAGE),
        ),
        DataElement::new(
            tags::SOP_INSTANCE_UID,
            VR::UI,
            PrimitiveValue::from(uid.as_str()),
        ),
        us(tags::ROWS, 2),
        us(tags::COLUMNS, 2),
        us(tags::BITS_ALLOCATED, 16),
        us(tags::PIXEL_REPRESENTATION, 0),
        us(tags::SAMPLES_PER_PIXEL, 1),
        ds(tags::PIXEL_SPACING, "0.5\\0.75"),
        ds(tags::IMAGE_ORIENTATION_PATIENT, "1\\0\\0\\0\\1\\0"),
        ds(tags::IMAGE_POSITION_PATIENT, &format!("-10\\20\\{z}")),
        ds(tags::RESCALE_SLOPE, "1"),
        ds(tags::RESCALE_INTERCEPT, "-1024"),
        DataElement::new(tags::PIXEL_DATA, VR::OW, PrimitiveValue::U16(pixels.into())),
    ]);
    let file = obj
        .with_meta(FileMetaTableBuilder::new().transfer_syntax(uids::EXPLICIT_VR_LITTLE_ENDIAN))
        .unwrap();
    let mut out = Vec::new();
    file.write_all(&mut out).unwrap();
    out
}

fn files(root: &Path) {
    let walls = Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/walls");
    for entry in std::fs::read_dir(walls).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_stem().unwrap().to_str().unwrap().to_string();
        put(root, "wall_file", &name, std::fs::read(&path).unwrap());
    }
    put(root, "wall_file", "windows", "columns = 2\nrows = 1\nscreen_width = 640\nscreen_height = 360\n\
        tile_size = 48\n[[window]]\ndisplay = 0\nwidth = 320\nheight = 180\n[[window]]\ndisplay = 1\nfullscreen = 1\n");
    put(root, "wall_file", "stereo", "columns = 2\nrows = 1\nscreen_width = 64\nscreen_height = 48\n\
        [stereo]\nmode = \"displays\"\neye_separation = 0.1\n");
    put(
        root,
        "transfer_file",
        "data",
        "domain = \"data\"\n[[point]]\nvalue = 150.0\ncolor = [0.6, 0.3, 0.2]\n\
        opacity = 0.0\n[[point]]\nvalue = 600.0\ncolor = [1.0, 0.95, 0.85]\nopacity = 0.8\n",
    );
    put(root, "transfer_file", "normalized", "[[point]]\nvalue = 0.0\ncolor = [0, 0, 0]\nopacity = 0\n\
        [[point]]\nvalue = 0.5\ncolor = [1, 0, 0]\nopacity = 0.1\n[[point]]\nvalue = 1\ncolor = [1, 1, 1]\nopacity = 1\n");
    let scenes = [
        (
            "all",
            "meshes = [\"m.obj\", \"m.obj\"]\nparticles = \"p.csv\"\nvolume = \"v.vol.toml\"\n",
        ),
        (
            "series_list",
            "meshes = [\"m.obj\"]\nseries = [\"t0.vol.toml\", \"t1.vol.toml\"]\n",
        ),
        ("series_pattern", "series = \"t*.vol.toml\"\n"),
        ("particles", "particles = \"p.csv\"\n"),
    ];
    for (name, text) in scenes {
        put(root, "scene_toml", name, text);
    }
}
