//! Local walls whose render nodes share the scene in distributed shared memory (`--data dsm`):
//! the wall equals the single-process reference pixel for pixel (a mesh, and a volume drawn
//! through a transfer function and as an iso-surface, and a scene of a mesh, a volume and
//! particles), every render node stays within its memory budget (a mesh, a volume, the mixed
//! scene), and a render node's death loses no block (of a mesh,
//! or a volume's bricks).

use std::path::Path;
use std::time::Duration;
use tessera_tests::*;

/// A local wall of 2x1 screens of 160x90 with `render_nodes` one-thread render nodes sharing
/// `scene` (prepared into `dir/prepared`), the extra flags `rest`, its report in `dir/out`.
fn dsm_wall(dir: &Path, scene: &str, render_nodes: u32, rest: &[&str]) -> Proc {
    let (out, prepared) = (dir.join("out"), dir.join("prepared"));
    let nodes = render_nodes.to_string();
    let mut args = vec![
        "local",
        "--wall",
        "2x1",
        "--screen",
        "160x90",
        "--render-nodes",
        &nodes,
        "--threads",
        "1",
        "--scene",
        scene,
        "--data",
        "dsm",
        "--prepared",
        prepared.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend(rest);
    Proc::start("tessera-master", &args)
}

/// Three frames, the third saved, each render node caching a quarter of the scene.
const SAVED_AT_A_QUARTER_CACHE: [&str; 6] = [
    "--frames",
    "3",
    "--save-frame",
    "2",
    "--cache-fraction",
    "0.25",
];

/// The wall saved in `dir/out` equals `tessera-master render` of frame `frame` of `scene` seen
/// with `looks`, pixel for pixel.
fn assert_wall_is_the_reference(
    dir: &Path,
    (scene, frame): (&str, &str),
    looks: &[&str],
    what: &str,
) {
    let ref_dir = dir.join("reference");
    let mut reference = vec![
        "render", "--wall", "2x1", "--screen", "160x90", "--scene", scene, "--frame", frame,
    ];
    reference.extend(["--out", ref_dir.to_str().unwrap()]);
    reference.extend(looks);
    run("tessera-master", &reference, Duration::from_secs(120)).assert_success("render");
    assert_same_pixels(
        &dir.join("out/wall.png"),
        &ref_dir.join("wall.png"),
        &format!("{what} against the reference"),
    );
}

#[test]
fn a_shared_scene_renders_the_reference_pixels_with_every_ray_kind() {
    let dir = tempfile::tempdir().unwrap();
    // The gallery: mirrors and glass (reflected and transmitted rays), two lights (shadow
    // packets and rays), ambient occlusion; a cache of a sixteenth, so blocks are fetched,
    // evicted and fetched again.
    let quality = ["--ao", "4", "--eye", "0,1.5,5", "--target", "0,0.5,0"];
    let mut rest = vec![
        "--frames",
        "3",
        "--save-frame",
        "2",
        "--cache-fraction",
        "0.0625",
    ];
    rest.extend(quality);
    let o = dsm_wall(dir.path(), "gallery", 3, &rest).wait(Duration::from_secs(180));
    o.assert_success("the shared wall");
    assert_wall_is_the_reference(dir.path(), ("gallery", "2"), &quality, "the shared wall");
    let report = read_json(&dir.path().join("out/report.json"));
    assert_eq!(report["data"], "dsm", "{report}");
    for node in report["render_nodes"].as_array().unwrap() {
        let dsm = &node["dsm"];
        assert!(dsm["fetched"].as_u64().unwrap() > 0, "{node}");
        assert!(dsm["local_reads"].as_u64().unwrap() > 0, "{node}");
        assert!(node["max_rss_bytes"].as_u64().unwrap() > 0, "{node}");
    }
    let summary = &report["dsm"];
    // Every node fetched something: packets were set aside for it, and the threads waited at
    // least when a batch's last packets were all set aside.
    assert!(summary["parked"].as_u64().unwrap() > 0, "{summary}");
    assert!(
        summary["miss_wait_avg_us"].as_f64().unwrap() > 0.0,
        "{summary}"
    );
    eprintln!(
        "shared gallery: {} block reads a frame, {:.2} % fetched, {} packets set aside, threads idle {:.1} % of their time, a miss waited {:.0} µs, remote reads avg {:.0} µs (p99 {:.0}) against a {:.0} µs round trip",
        summary["blocks_read_per_frame"].as_f64().unwrap(),
        summary["miss_percent"].as_f64().unwrap(),
        summary["parked"],
        summary["wait_percent"].as_f64().unwrap(),
        summary["miss_wait_avg_us"].as_f64().unwrap(),
        summary["remote_read_avg_us"].as_f64().unwrap(),
        summary["remote_read_p99_us"].as_f64().unwrap(),
        summary["round_trip_us"].as_f64().unwrap(),
    );
}

/// Writes `DIR/blobs.vol.toml`: `nx` x `ny` x `nz` u8 voxels of two soft blobs.
fn write_blob_volume(dir: &Path, [nx, ny, nz]: [usize; 3]) -> String {
    let mut values = Vec::with_capacity(nx * ny * nz);
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                let d = |cx: f32, cy: f32, cz: f32, s: f32| {
                    let (dx, dy, dz) = (x as f32 - cx, y as f32 - cy, z as f32 - cz);
                    (-(dx * dx + dy * dy + dz * dz) / (s * s)).exp()
                };
                let (sx, sy) = (nx as f32 / 72.0, ny as f32 / 40.0);
                let v = d(24.0 * sx, 20.0 * sy, 18.0 * sy, 11.0 * sy)
                    + d(50.0 * sx, 18.0 * sy, 22.0 * sy, 9.0 * sy);
                values.push((v.min(1.0) * 250.0) as u8);
            }
        }
    }
    std::fs::write(dir.join("blobs.raw"), values).unwrap();
    let sidecar = dir.join("blobs.vol.toml");
    std::fs::write(
        &sidecar,
        format!(
            "data = \"blobs.raw\"\ndims = [{nx}, {ny}, {nz}]\ntype = \"u8\"\nspacing = [1.0, 1.0, 1.0]\n"
        ),
    )
    .unwrap();
    sidecar.to_str().unwrap().to_string()
}

#[test]
fn a_shared_volume_renders_the_reference_pixels_through_the_transfer_function_and_as_iso() {
    let dir = tempfile::tempdir().unwrap();
    // 12 bricks.
    let volume = write_blob_volume(dir.path(), [72, 40, 40]);
    let view = ["--eye", "36,-22,40", "--target", "36,20,20"];
    for (name, looks) in [
        ("dvr", vec!["--transfer", "ramp"]),
        ("iso", vec!["--iso", "120", "--ao", "4"]),
    ] {
        let run_dir = dir.path().join(name);
        let mut rest = SAVED_AT_A_QUARTER_CACHE.to_vec();
        rest.extend(&looks);
        rest.extend(view);
        let o = dsm_wall(&run_dir, &volume, 3, &rest).wait(Duration::from_secs(180));
        o.assert_success("the shared volume wall");
        let what = format!("the shared volume ({name})");
        let all: Vec<&str> = looks.iter().chain(&view).copied().collect();
        assert_wall_is_the_reference(&run_dir, (&volume, "2"), &all, &what);
        let report = read_json(&run_dir.join("out/report.json"));
        assert_eq!(report["data"], "dsm", "{report}");
        let fetched = dsm_total(report["render_nodes"].as_array().unwrap(), "fetched");
        assert!(fetched > 0, "{name}: no brick was fetched: {report}");
    }
}

/// The sum over `nodes` (a report's `render_nodes`) of their DSM figure `key`.
fn dsm_total(nodes: &[serde_json::Value], key: &str) -> u64 {
    nodes.iter().map(|n| n["dsm"][key].as_u64().unwrap()).sum()
}

/// Writes `DIR/mixed.scene.toml`: the blobs of [`write_blob_volume`] (72x40x40), 400 particles
/// among them and a backdrop quad behind them.
fn write_mixed_scene(dir: &Path) -> String {
    write_blob_volume(dir, [72, 40, 40]);
    std::fs::write(
        dir.join("backdrop.obj"),
        "v -10 -10 -3\nv 82 -10 -3\nv 82 50 -3\nv -10 50 -3\nf 1 2 3\nf 1 3 4\n",
    )
    .unwrap();
    let mut csv = String::from("x,y,z,radius,attribute\n");
    for i in 0..400u32 {
        // A low-discrepancy scatter through the volume's box.
        let u = |k: u32| ((i * k) % 997) as f32 / 997.0;
        let (x, y, z) = (u(409) * 72.0, u(613) * 40.0, u(787) * 40.0);
        let r = 0.8 + 1.2 * u(211);
        csv += &format!("{x},{y},{z},{r},{}\n", i % 10);
    }
    std::fs::write(dir.join("dots.csv"), csv).unwrap();
    let scene = dir.join("mixed.scene.toml");
    std::fs::write(
        &scene,
        "meshes = [\"backdrop.obj\"]\nvolume = \"blobs.vol.toml\"\nparticles = \"dots.csv\"\n",
    )
    .unwrap();
    scene.to_str().unwrap().to_string()
}

#[test]
fn a_shared_mixed_scene_renders_the_reference_pixels_within_the_budget() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write_mixed_scene(dir.path());
    let looks = [
        "--iso",
        "120",
        "--ao",
        "2",
        "--eye",
        "36,-22,40",
        "--target",
        "36,20,20",
    ];
    let budget_mib = 64;
    let budget = format!("{budget_mib}MiB");
    let mut rest = SAVED_AT_A_QUARTER_CACHE.to_vec();
    rest.extend(["--memory-budget", &budget]);
    rest.extend(looks);
    let o = dsm_wall(dir.path(), &scene, 3, &rest).wait(Duration::from_secs(180));
    o.assert_success("the shared mixed scene");
    assert_wall_is_the_reference(dir.path(), (&scene, "2"), &looks, "the shared mixed scene");
    let report = read_json(&dir.path().join("out/report.json"));
    assert_eq!(report["data"], "dsm", "{report}");
    for node in report["render_nodes"].as_array().unwrap() {
        assert_eq!(node["within_budget"], true, "{node}");
        assert!(node["dsm"]["fetched"].as_u64().unwrap() > 0, "{node}");
    }
}

#[test]
fn a_shared_volume_stays_within_each_render_nodes_memory_budget() {
    let dir = tempfile::tempdir().unwrap();
    // 80 bricks (11 MiB of blocks) over 3 nodes with room for about half of them in a cache.
    let volume = write_blob_volume(dir.path(), [160, 128, 128]);
    let budget_mib = 64;
    let budget = format!("{budget_mib}MiB");
    let rest = [
        "--frames",
        "6",
        "--memory-budget",
        &budget,
        "--transfer",
        "ramp",
    ];
    let o = dsm_wall(dir.path(), &volume, 3, &rest).wait(Duration::from_secs(300));
    o.assert_success("the volume wall within a budget");
    let report = read_json(&dir.path().join("out/report.json"));
    let nodes = report["render_nodes"].as_array().unwrap();
    assert_eq!(nodes.len(), 3);
    for node in nodes {
        let (dsm, rss) = (&node["dsm"], node["max_rss_bytes"].as_u64().unwrap());
        eprintln!(
            "volume, render node {}: peak resident {:.1} MiB of a {budget_mib} MiB budget (holds {:.1} MiB, caches {:.1} MiB)",
            node["id"],
            rss as f64 / 1048576.0,
            dsm["resident_bytes"].as_u64().unwrap() as f64 / 1048576.0,
            dsm["cache_bytes"].as_u64().unwrap() as f64 / 1048576.0,
        );
        assert!(rss <= budget_mib << 20, "{node}");
        assert_eq!(node["within_budget"], true, "{node}");
        let cache = dsm["cache_bytes"].as_u64().unwrap();
        assert!(
            cache > 0 && cache < 11 << 20,
            "the cache must hold part of the volume: {node}"
        );
        // Each node reads blocks it does not hold. Whether it must fetch any depends on the
        // tiles it is given: its cache is warmed from the prepared files at start (about half
        // the volume here), and a node whose tiles stayed within its share and the warmed
        // lines fetched nothing (3 runs of 4 in a row once, node 2: 183 cache hits, no miss).
        let reads = |key: &str| dsm[key].as_u64().unwrap();
        assert!(reads("block_reads") > reads("local_reads"), "{node}");
    }
    let fetched = dsm_total(nodes, "fetched");
    assert!(fetched > 0, "no node fetched a block: {nodes:?}");
}

#[test]
fn every_render_node_stays_within_its_memory_budget() {
    let dir = tempfile::tempdir().unwrap();
    // About 22 MB of blocks over 4 nodes: each holds a quarter, the rest of its 48 MiB is
    // overhead and cache.
    let budget_mib = 48;
    let budget = format!("{budget_mib}MiB");
    let o = dsm_wall(
        dir.path(),
        "knot:1200:160",
        4,
        &["--frames", "8", "--memory-budget", &budget],
    )
    .wait(Duration::from_secs(300));
    o.assert_success("the wall within a budget");
    let report = read_json(&dir.path().join("out/report.json"));
    let nodes = report["render_nodes"].as_array().unwrap();
    assert_eq!(nodes.len(), 4);
    let scene_bytes = dsm_total(nodes, "resident_bytes");
    for node in nodes {
        let rss = node["max_rss_bytes"].as_u64().unwrap();
        eprintln!(
            "render node {}: peak resident {:.1} MiB of a {budget_mib} MiB budget (holds {:.1} MiB, caches {:.1} MiB)",
            node["id"],
            rss as f64 / 1048576.0,
            node["dsm"]["resident_bytes"].as_u64().unwrap() as f64 / 1048576.0,
            node["dsm"]["cache_bytes"].as_u64().unwrap() as f64 / 1048576.0,
        );
        assert!(rss > 0 && rss <= budget_mib << 20, "{node}");
        assert_eq!(node["memory_budget"], budget_mib << 20, "{node}");
        assert_eq!(node["within_budget"], true, "{node}");
    }
    assert!(
        scene_bytes > 16 << 20,
        "the scene must not fit a node's share of the budget alone: {scene_bytes}"
    );
}

/// Runs a shared wall of 3 render nodes with `replicas`, SIGKILLs one once frame 3 is
/// presented, and returns the report of its 60 frames.
fn kill_a_holder(dir: &Path, replicas: &str) -> (serde_json::Value, String) {
    let view = ["--eye", "0,0.5,3.5", "--target", "0,0,0"];
    kill_a_holder_of(dir, "knot:600:40", &view, replicas)
}

/// [`kill_a_holder`] of `scene` seen with `looks`.
fn kill_a_holder_of(
    dir: &Path,
    scene: &str,
    looks: &[&str],
    replicas: &str,
) -> (serde_json::Value, String) {
    let mut rest = vec![
        "--frames",
        "60",
        "--save-frame",
        "3",
        "--replicas",
        replicas,
        "--cache-fraction",
        "0.125",
    ];
    rest.extend(looks);
    let master = dsm_wall(dir, scene, 3, &rest);
    let saved = dir.join("out/display-1.png");
    assert!(
        wait_for(Duration::from_secs(120), || saved.exists()
            || master.has_exited()),
        "the wall never presented frame 3"
    );
    let nodes = children(master.pid(), "render-node");
    assert_eq!(nodes.len(), 3, "{nodes:?}");
    // SIGKILL mid-frame: no goodbye; its rank's blocks are wanted by the others at once.
    // SAFETY: kill only sends a signal and touches no memory; the pid is a node
    // process of the wall this test started, still running.
    unsafe { libc::kill(nodes[1] as i32, libc::SIGKILL) };
    let o = master.wait(Duration::from_secs(240));
    // A local wall ends saying which of its children died.
    assert!(o.stderr.contains("exited with signal 9"), "{}", o.stderr);
    (read_json(&dir.join("out/report.json")), o.stderr)
}

/// The 160 x 128 x 128 blob volume through the ramp, seen whole.
const BIG_VOLUME_LOOKS: [&str; 6] = [
    "--transfer",
    "ramp",
    "--eye",
    "80,-60,100",
    "--target",
    "80,64,64",
];

/// Every frame came, and a killed holder's blocks were read from the prepared files.
fn assert_blocks_came_from_the_prepared_files(report: &serde_json::Value, log: &str) {
    assert_every_frame_complete(report);
    assert!(
        log.contains("the other render nodes read them from the prepared files"),
        "{log}"
    );
    assert!(
        report["dsm"]["read_locally"].as_u64().unwrap() > 0,
        "{report}"
    );
}

fn assert_every_frame_complete(report: &serde_json::Value) {
    assert_eq!(report["frames"], 60, "{report}");
    assert_eq!(report["render_nodes_lost"], 1, "{report}");
    for d in report["displays"].as_array().unwrap() {
        assert_eq!(d["frames_presented"], 60, "{d}");
    }
}

#[test]
fn with_two_replicas_a_killed_render_node_loses_no_block() {
    let dir = tempfile::tempdir().unwrap();
    let (report, log) = kill_a_holder(dir.path(), "2");
    assert_every_frame_complete(&report);
    assert!(
        log.contains("its blocks' other owners answer for them"),
        "{log}"
    );
    // Every block it held came from its second owner; none had to be read from the disk.
    assert_eq!(report["dsm"]["read_locally"], 0, "{report}");
}

#[test]
fn without_replicas_a_killed_holders_blocks_are_read_from_the_prepared_files() {
    let dir = tempfile::tempdir().unwrap();
    let (report, log) = kill_a_holder(dir.path(), "1");
    assert_blocks_came_from_the_prepared_files(&report, &log);
}

#[test]
fn a_killed_holder_of_a_volumes_bricks_loses_none_of_them() {
    let dir = tempfile::tempdir().unwrap();
    let volume = write_blob_volume(dir.path(), [160, 128, 128]);
    let looks = BIG_VOLUME_LOOKS;
    let (report, log) = kill_a_holder_of(dir.path(), &volume, &looks, "1");
    assert_blocks_came_from_the_prepared_files(&report, &log);
}

#[test]
fn out_of_core_every_block_is_read_from_the_prepared_files_within_the_budget() {
    let dir = tempfile::tempdir().unwrap();
    // 80 bricks; no node holds any, each caches about 70 of them.
    let volume = write_blob_volume(dir.path(), [160, 128, 128]);
    let looks = BIG_VOLUME_LOOKS;
    let mut rest = vec![
        "--out-of-core",
        "--memory-budget",
        "64MiB",
        "--frames",
        "4",
        "--save-frame",
        "3",
    ];
    rest.extend(looks);
    let o = dsm_wall(dir.path(), &volume, 3, &rest).wait(Duration::from_secs(300));
    o.assert_success("the out-of-core wall");
    assert_wall_is_the_reference(dir.path(), (&volume, "3"), &looks, "the out-of-core wall");
    let report = read_json(&dir.path().join("out/report.json"));
    assert_eq!(report["dsm"]["ranks"], 0, "{report}");
    assert!(
        report["dsm"]["read_locally"].as_u64().unwrap() > 0,
        "{report}"
    );
    for node in report["render_nodes"].as_array().unwrap() {
        assert_eq!(node["dsm"]["resident_bytes"], 0, "{node}");
        assert_eq!(node["within_budget"], true, "{node}");
    }
}
