//! A time-varying volume played on a local wall: one step a frame, read ahead by the render
//! node's reader threads; the report counts the steps loaded and the prefetch hits, and a
//! frame of the wall equals the recorded session's frame rendered in one process.

use std::path::Path;
use std::time::Duration;
use tessera_tests::*;

/// Three 16³ steps, each a ball of a different size, and a scene file naming them by pattern.
fn write_series(dir: &Path) -> std::path::PathBuf {
    for step in 0..3usize {
        let radius = 3.0 + 2.0 * step as f32;
        let values: Vec<u8> = (0..16 * 16 * 16)
            .map(|i| {
                let (x, y, z) = (i % 16, i / 16 % 16, i / 256);
                let d = ((x as f32 - 7.5).powi(2)
                    + (y as f32 - 7.5).powi(2)
                    + (z as f32 - 7.5).powi(2))
                .sqrt();
                if d < radius {
                    200
                } else {
                    0
                }
            })
            .collect();
        std::fs::write(dir.join(format!("ball{step}.raw")), values).unwrap();
        std::fs::write(
            dir.join(format!("ball{step}.vol.toml")),
            format!("data = \"ball{step}.raw\"\ndims = [16, 16, 16]\ntype = \"u8\"\nspacing = [1.0, 1.0, 1.0]\n"),
        )
        .unwrap();
    }
    let scene = dir.join("balls.scene.toml");
    std::fs::write(&scene, "series = \"ball*.vol.toml\"\n").unwrap();
    scene
}

#[test]
fn a_played_series_changes_at_the_barrier_and_is_read_ahead() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write_series(dir.path());
    let out = dir.path().join("out");
    let record = dir.path().join("session.jsonl");
    let wall = [
        "--wall",
        "1x1",
        "--screen",
        "96x64",
        "--scene",
        scene.to_str().unwrap(),
        "--iso",
        "100",
    ];
    let mut args = vec!["local"];
    args.extend(wall);
    args.extend([
        "--render-nodes",
        "1",
        // A step is 16 KiB: 1 MiB holds the whole series ahead (the flag reaches the node).
        "--volume-cache-mb",
        "1",
        "--frames",
        "12",
        "--play",
        "--save-frame",
        "7",
        "--record",
        record.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let o = run("tessera-master", &args, Duration::from_secs(120));
    o.assert_success("local --play");
    let report = read_json(&out.join("report.json"));
    let node = &report["render_nodes"][0];
    let loads = node["volume_load_s"]
        .as_array()
        .expect("load times per step");
    let (hits, misses) = (
        node["prefetch_hits"].as_u64().unwrap(),
        node["prefetch_misses"].as_u64().unwrap(),
    );
    // Frames 1..12 each show the next step: 11 step changes, every one a hit or a miss; the
    // readers loaded steps 1 and 2 and, once the series looped, step 0.
    eprintln!(
        "series on the wall: {} loads, {hits} hits, {misses} misses",
        loads.len()
    );
    assert_eq!(hits + misses, 11, "{node}");
    assert!(loads.len() >= 2 && loads.len() <= 11, "{node}");
    assert!(node["volume_stall_s"].as_f64().unwrap() >= 0.0);
    // The saved frame equals the recorded session's frame 7, its time step included.
    assert_shows_replayed_frame(&wall, &record, 7, &out.join("wall.png"), dir.path());
    // And the steps really differ: frame 7 is not frame 7 of a wall stuck at step 0.
    let still = dir.path().join("still");
    let mut args = vec!["render"];
    args.extend(wall);
    args.extend(["--frame", "7", "--out", still.to_str().unwrap()]);
    run("tessera-master", &args, Duration::from_secs(120)).assert_success("render step 0");
    let (_, _, played) = load_rgb(&out.join("wall.png"));
    let (_, _, step0) = load_rgb(&still.join("wall.png"));
    assert_ne!(played, step0, "frame 7 shows a later step than 0");
}

#[test]
fn play_without_a_series_is_refused() {
    let o = run(
        "tessera-master",
        &[
            "local", "--wall", "1x1", "--screen", "32x32", "--frames", "2", "--play",
        ],
        Duration::from_secs(60),
    );
    o.assert_refused("--play on the knot", &["--play", "series"]);
}
