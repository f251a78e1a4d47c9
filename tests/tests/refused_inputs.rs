//! Inputs that used to panic a node, hang it or be silently ignored, each refused now with a
//! clear error that names the value, a non-zero exit and no panic: from the command line, and
//! from a master that sends what no real master sends.

use serde::Serialize;
use std::path::Path;
use std::time::Duration;
use tessera_model::camera::Camera;
use tessera_model::params::RenderParamsSpec;
use tessera_model::scene_spec::SceneSpec;
use tessera_model::state::StateId;
use tessera_model::wall::WallSpec;
use tessera_net::cluster::{CertRole, ClusterCa, NodeIdentity};
use tessera_net::framed::read_msg;
use tessera_net::quic;
use tessera_protocol::{codec, FrameId, FromNode, RenderNodeId, ToNode};
use tessera_tests::*;

/// A refusal comes at once: well before anything could have been rendered.
const QUICK: Duration = Duration::from_secs(60);

fn render_with(flags: &[&str]) -> Output {
    let dir = tempfile::tempdir().unwrap();
    let mut args = vec!["render", "--out", dir.path().to_str().unwrap()];
    args.extend(flags);
    run("tessera-master", &args, QUICK)
}

#[test]
fn ao_of_four_billion_rays_per_hit_is_refused_rather_than_run_for_ever() {
    render_with(&["--ao", "4000000000"]).assert_refused("render --ao 4e9", &["4000000000"]);
    let o = run(
        "tessera-master",
        &[
            "local",
            "--wall",
            "1x1",
            "--ao",
            "4000000000",
            "--frames",
            "1",
        ],
        QUICK,
    );
    o.assert_refused("local --ao 4e9", &["4000000000", "ambient-occlusion"]);
}

#[test]
fn samples_times_ao_rays_beyond_the_budget_are_refused() {
    render_with(&["--spp", "4096", "--ao", "1024"])
        .assert_refused("render --spp 4096 --ao 1024", &["rays per pixel"]);
}

#[test]
fn fov_of_0_or_180_degrees_is_refused_with_either_camera() {
    for fov in ["0", "180"] {
        render_with(&["--fov", fov]).assert_refused("orbit with --fov", &[fov, "degrees"]);
        render_with(&["--eye", "0,0,5", "--target", "0,0,0", "--fov", fov])
            .assert_refused("fixed camera with --fov", &[fov, "degrees"]);
    }
}

#[test]
fn fov_is_honoured_by_the_orbit_camera() {
    // It used to be ignored: the orbit always looked through 45 degrees.
    let image = |flags: &[&str]| {
        let dir = tempfile::tempdir().unwrap();
        let mut args = vec![
            "render",
            "--wall",
            "1x1",
            "--screen",
            "96x64",
            "--scene",
            "knot:64:8",
        ];
        args.extend(flags);
        args.extend(["--out", dir.path().to_str().unwrap()]);
        run("tessera-master", &args, QUICK).assert_success("render");
        load_rgb(&dir.path().join("wall.png")).2
    };
    let default = image(&[]);
    assert_eq!(default, image(&["--fov", "45"]), "45 is the default");
    assert_ne!(
        default,
        image(&["--fov", "20"]),
        "--fov 20 must narrow the orbit's view"
    );
}

#[test]
fn a_missing_file_says_its_reason_once() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["x.vol.toml", "x.nrrd", "x.obj", "x.csv", "x.scene.toml"] {
        let path = dir.path().join(name);
        let o = render_with(&["--scene", path.to_str().unwrap()]);
        o.assert_refused(name, &[name, "No such file"]);
        let said = o.stderr.matches("No such file").count();
        assert_eq!(said, 1, "{name}: the reason {said} times:\n{}", o.stderr);
    }
    let o = render_with(&["--transfer", dir.path().join("tf.toml").to_str().unwrap()]);
    o.assert_refused("--transfer tf.toml", &["tf.toml", "No such file"]);
    assert_eq!(o.stderr.matches("No such file").count(), 1, "{}", o.stderr);
}

#[test]
fn missing_data_is_drawn_by_default_and_refused_under_nan_refuse() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("p.csv");
    std::fs::write(&csv, "x,y,z,radius,attribute\n0,0,0,0.5,1\n1,0,0,0.5,nan\n").unwrap();
    let raw = dir.path().join("v.raw");
    let mut voxels: Vec<u8> = (0..27).flat_map(|i| (i as f32).to_le_bytes()).collect();
    voxels[13 * 4..14 * 4].copy_from_slice(&f32::NAN.to_le_bytes());
    std::fs::write(&raw, voxels).unwrap();
    let vol = dir.path().join("v.vol.toml");
    let sidecar = "data = \"v.raw\"\ndims = [3, 3, 3]\ntype = \"f32\"\n";
    std::fs::write(&vol, sidecar).unwrap();
    for (scene, what) in [(&csv, "particle 1"), (&vol, "voxel 13")] {
        let scene = scene.to_str().unwrap();
        let drawn = render_with(&["--scene", scene]);
        assert!(drawn.status.success(), "{scene}: {}", drawn.stderr);
        render_with(&["--scene", scene, "--nan", "refuse"])
            .assert_refused(scene, &[what, "missing", "--nan refuse"]);
    }
    let drawn = render_with(&["--scene", vol.to_str().unwrap()]);
    assert!(
        drawn.stderr.contains("1 of 27 voxels are missing data"),
        "{}",
        drawn.stderr
    );
}

#[test]
fn flags_the_scene_has_nothing_for_are_refused_naming_the_flag() {
    let dir = tempfile::tempdir().unwrap();
    let volume = write_ramp_volume(dir.path());
    let series = write_ball_series(dir.path(), 8);
    let (volume, series) = (volume.to_str().unwrap(), series.to_str().unwrap());
    for (flags, says) in [
        (vec!["--iso", "300"], vec!["--iso", "no", "volume"]),
        (vec!["--transfer", "ct-bone"], vec!["--transfer", "volume"]),
        (vec!["--time-step", "2"], vec!["--time-step", "volume"]),
        (vec!["--colormap", "magma"], vec!["--colormap", "particles"]),
        (
            vec!["--scene", volume, "--time-step", "1000"],
            vec!["--time-step 1000", "not a series"],
        ),
        (
            vec!["--scene", series, "--time-step", "1000"],
            vec!["--time-step 1000", "3 steps"],
        ),
    ] {
        render_with(&flags).assert_refused(&format!("render {flags:?}"), &says);
    }
    let mut local = vec!["local", "--wall", "1x1", "--frames", "1", "--no-console"];
    local.extend(["--iso", "300"]);
    run("tessera-master", &local, QUICK).assert_refused("local --iso on builtin", &["--iso"]);
}

#[test]
fn walls_whose_display_count_overflows_are_refused() {
    // 65536 × 65536 screens is 2^32 displays: the count wrapped to 0 in a u32.
    render_with(&["--wall", "65536x65536", "--screen", "1x1"])
        .assert_refused("a 2^32-display wall", &["4294967296", "screens"]);
}

#[test]
fn walls_whose_tile_count_overflows_are_refused() {
    render_with(&[
        "--wall",
        "1x1",
        "--screen",
        "65536x65536",
        "--tile-size",
        "1",
    ])
    .assert_refused("2^32 one-pixel tiles", &["4294967296", "tiles"]);
}

#[test]
fn a_wall_whose_session_would_exceed_the_codec_limit_is_refused_at_the_flags() {
    // 65536 screens of one pixel: their session (an address per display) was 1.7 MB, over the
    // 1 MiB control-message limit, and the master's encoder asserted when a node joined.
    let o = run(
        "tessera-master",
        &[
            "local", "--wall", "65536x1", "--screen", "1x1", "--frames", "1",
        ],
        QUICK,
    );
    o.assert_refused("a 65536-display local wall", &["65536 screens", "4096"]);
}

#[test]
fn more_than_four_cut_planes_are_refused() {
    let cut = ["--cut", "1,0,0,0"];
    let flags: Vec<&str> = cut.iter().cycle().take(10).copied().collect();
    render_with(&flags).assert_refused("five --cut", &["at most 4", "5"]);
}

#[test]
fn a_join_timeout_or_linger_too_long_to_represent_is_refused() {
    // Both ended in a Duration or an Instant overflow: a panic.
    let o = run(
        "tessera-master",
        &[
            "local",
            "--join-timeout",
            "18446744073709551615",
            "--frames",
            "1",
        ],
        QUICK,
    );
    o.assert_refused("--join-timeout u64::MAX", &["--join-timeout"]);
    let o = run(
        "tessera-master",
        &["local", "--window", "--linger", "1e300", "--frames", "1"],
        QUICK,
    );
    o.assert_refused("--linger 1e300", &["1e300"]);
}

#[test]
fn a_thread_count_beyond_reason_is_refused() {
    let o = run(
        "tessera-render-node",
        &[
            "--master",
            "127.0.0.1:9",
            "--cert-dir",
            "/nonexistent",
            "--threads",
            "0",
        ],
        QUICK,
    );
    o.assert_refused("--threads 0", &["--threads", "0"]);
    let o = run(
        "tessera-render-node",
        &["bench", "--scene", "knot:32:4", "--threads", "1000000"],
        QUICK,
    );
    o.assert_refused("bench --threads 1e6", &["1000000"]);
}

// ---- from the network: a fake master that welcomes a real render node, then lies ----

/// RenderParamsSpec's fields in its wire order, with room for values no constructor makes.
#[derive(Serialize)]
struct RawParams {
    shadows: bool,
    ao_samples: u32,
    ao_range: f32,
    crop: Option<(f32, f32)>,
    cuts: Vec<[f32; 4]>,
    spp: u32,
    first_sample: u32,
    volume: tessera_model::volume_params::VolumeParams,
    colormap: tessera_model::colormap::ColorMap,
    shading: tessera_model::params::Shading,
}

impl RawParams {
    fn interactive() -> Self {
        let i = RenderParamsSpec::INTERACTIVE;
        RawParams {
            shadows: i.shadows,
            ao_samples: i.ao_samples,
            ao_range: i.ao_range,
            crop: i.crop,
            cuts: Vec::new(),
            spp: i.spp,
            first_sample: i.first_sample,
            volume: i.volume,
            colormap: i.colormap,
            shading: i.shading,
        }
    }
}

/// ToNode's variants up to FrameStart, in wire order, with a FrameStart of raw parameters.
#[allow(clippy::large_enum_variant)]
#[derive(Serialize)]
enum RawToNode {
    _Welcome,
    _Refused,
    FrameStart(FrameId, StateId, Camera, RawParams, Option<()>),
}

fn certificates(dir: &Path) -> (NodeIdentity, String) {
    let ca = ClusterCa::open_or_create(&dir.join("ca")).unwrap();
    ca.issue("master", &dir.join("master"), Some(CertRole::Master))
        .unwrap();
    ca.issue("render", &dir.join("render"), Some(CertRole::Render))
        .unwrap();
    let master = NodeIdentity::load(&dir.join("master")).unwrap();
    (master, dir.join("render").to_str().unwrap().to_string())
}

/// Starts a render node against a fake master, welcomes it into a one-screen wall of a small
/// knot, waits until it is ready, sends `lie` as raw bytes, and returns how the node ended.
fn render_node_told(lie: &[u8]) -> Output {
    let dir = tempfile::tempdir().unwrap();
    let (identity, render_certs) = certificates(dir.path());
    let rt = tokio::runtime::Runtime::new().unwrap();
    rt.block_on(async {
        let endpoint = quic::endpoint("127.0.0.1:0".parse().unwrap(), &identity, true).unwrap();
        let addr = endpoint.local_addr().unwrap().to_string();
        let node = Proc::start(
            "tessera-render-node",
            &[
                "--master",
                &addr,
                "--cert-dir",
                &render_certs,
                "--threads",
                "1",
                "--no-bvh-cache",
            ],
        );
        let talk = async {
            let conn = endpoint.accept().await.expect("the node connects").await?;
            let (mut send, mut recv) = conn.accept_bi().await?;
            let hello = read_msg::<FromNode>(&mut recv).await?;
            assert!(matches!(hello, Some(FromNode::Hello(_))), "{hello:?}");
            let spec = SceneSpec::Knot {
                segments: 32,
                sides: 4,
            };
            let scene = tessera_render::scene::Scene::load(&spec).unwrap();
            let session = tessera_protocol::Session::new(tessera_protocol::SessionSpec {
                wall: WallSpec::grid(1, 1, 64, 64).build().unwrap(),
                scene: spec,
                scene_hash: scene.content_hash(),
                displays: Vec::new(),
                save_frame: None,
                compression: Default::default(),
                windows: Default::default(),
                data: tessera_protocol::dsm::DataSpec::Replicated,
                particle_range: None,
            })
            .unwrap();
            let welcome = ToNode::Welcome {
                node: Some(RenderNodeId(0)),
                session,
                term: 0,
            };
            send.write_all(&codec::encode(&welcome).unwrap()).await?;
            let ready = read_msg::<FromNode>(&mut recv).await?;
            assert_eq!(ready, Some(FromNode::Ready));
            send.write_all(lie).await?;
            // Keep the connection until the node gives up on it.
            let _ = tokio::time::timeout(QUICK, conn.closed()).await;
            anyhow::Ok(())
        };
        tokio::time::timeout(QUICK, talk)
            .await
            .expect("the node joined and left in time")
            .unwrap();
        node.wait(QUICK)
    })
}

fn frame_start(params: RawParams) -> Vec<u8> {
    let camera = Camera::new(
        glam::Vec3::new(0.0, 1.0, 4.0),
        glam::Vec3::ZERO,
        glam::Vec3::Y,
        45.0,
    )
    .unwrap();
    codec::encode(&RawToNode::FrameStart(
        FrameId(0),
        StateId(0),
        camera,
        params,
        None,
    ))
    .unwrap()
}

#[test]
fn a_frame_start_with_five_cut_planes_is_refused_by_the_render_node() {
    // It used to be accepted, and CutPlanes::planes() panicked slicing 5 of 4 planes.
    let lie = frame_start(RawParams {
        cuts: vec![[1.0, 0.0, 0.0, 0.0]; 5],
        ..RawParams::interactive()
    });
    render_node_told(&lie).assert_refused(
        "five cut planes from the master",
        &["lost the master", "at most 4 cutting planes", "got 5"],
    );
}

#[test]
fn a_frame_start_with_four_billion_ao_rays_is_refused_by_the_render_node() {
    let lie = frame_start(RawParams {
        ao_samples: 4_000_000_000,
        ..RawParams::interactive()
    });
    render_node_told(&lie).assert_refused("4e9 AO rays from the master", &["4000000000"]);
}

#[test]
fn an_assignment_of_tiles_the_wall_lacks_is_refused_by_the_render_node() {
    let frame = frame_start(RawParams::interactive());
    let assign = codec::encode(&ToNode::Assign {
        frame: FrameId(0),
        tiles: vec![tessera_protocol::TileRange::new(0, 4_000_000).unwrap()],
    })
    .unwrap();
    let lie = [frame, assign].concat();
    render_node_told(&lie).assert_refused("tiles 0..4000000 of a 1-tile wall", &["0..4000000"]);
}

#[test]
fn simulated_times_and_counts_that_overflow_the_virtual_clock_are_refused() {
    // Each of these overflowed a u64 inside the simulator: a panic, not an error.
    for (flag, value) in [
        ("--latency-us", "18446744073709551615"),
        ("--tile-us", "18446744073709551615"),
        ("--frames", "18446744073709551615"),
    ] {
        let o = run(
            "tessera-master",
            &[
                "simulate",
                "--render-nodes",
                "2",
                "--displays",
                "1",
                flag,
                value,
            ],
            QUICK,
        );
        o.assert_refused(&format!("simulate {flag} {value}"), &[flag, value]);
    }
}

#[test]
fn a_bulk_transfer_of_infinite_or_nan_seconds_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    for seconds in ["inf", "nan"] {
        let o = run(
            "tessera-master",
            &[
                "bench",
                "max-fps",
                "--transport-seconds",
                seconds,
                "--out",
                dir.path().to_str().unwrap(),
            ],
            QUICK,
        );
        o.assert_refused("--transport-seconds", &[seconds, "seconds"]);
    }
}

#[test]
fn a_refused_transfer_function_says_its_reason_once() {
    // Points that make no transfer function were refused with their reason twice, once as
    // the message and again as its source.
    let dir = tempfile::tempdir().unwrap();
    let volume = write_ramp_volume(dir.path());
    let point = |value: f32, opacity: f32| {
        format!("[[point]]\nvalue = {value:?}\ncolor = [1.0, 1.0, 1.0]\nopacity = {opacity:?}\n")
    };
    let files = [
        (
            "points.toml",
            point(0.0, 0.0) + &point(1.0, 2.0),
            "opacity 2 is outside 0..1",
        ),
        (
            "shape.toml",
            "point = 3\n".to_string(),
            "expected a sequence",
        ),
    ];
    let mut cases = vec![("nosuch".to_string(), "is neither a preset")];
    for (name, text, reason) in files {
        let path = dir.path().join(name);
        std::fs::write(&path, text).unwrap();
        cases.push((path.to_str().unwrap().to_string(), reason));
    }
    for (arg, reason) in &cases {
        let o = render_with(&["--scene", volume.to_str().unwrap(), "--transfer", arg]);
        o.assert_refused(&format!("--transfer {arg}"), &["--transfer", reason]);
        let said = o.stderr.matches(reason).count();
        assert_eq!(said, 1, "{arg}: the reason {said} times:\n{}", o.stderr);
    }
}
