//! A time-varying volume played on a local wall: one step a frame, read ahead by the render
//! node's reader threads; the report counts the steps loaded and the prefetch hits, and a
//! frame of the wall equals the recorded session's frame rendered in one process.

use std::path::Path;
use std::time::Duration;
use tessera_tests::*;

/// Three 16³ steps, each a ball of a different size, and a scene file naming them by pattern.
fn write_series(dir: &Path) -> std::path::PathBuf {
    write_ball_series(dir, 16)
}

/// 12 frames of `--play`, frame 7 saved, the session recorded to `record`, the report in `out`.
fn played<'a>(record: &'a Path, out: &'a Path) -> [&'a str; 9] {
    [
        "--frames",
        "12",
        "--play",
        "--save-frame",
        "7",
        "--record",
        record.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]
}

/// One screen of `screen` pixels showing `scene`'s iso-surface at 100.
fn wall_of<'a>(scene: &'a str, screen: &'a str) -> [&'a str; 8] {
    [
        "--wall", "1x1", "--screen", screen, "--scene", scene, "--iso", "100",
    ]
}

#[test]
fn a_played_series_changes_at_the_barrier_and_is_read_ahead() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write_series(dir.path());
    let out = dir.path().join("out");
    let record = dir.path().join("session.jsonl");
    let wall = wall_of(scene.to_str().unwrap(), "96x64");
    let mut args = vec!["local"];
    args.extend(wall);
    args.extend([
        "--render-nodes",
        "1",
        // A step is 16 KiB: 1 MiB holds the whole series ahead (the flag reaches the node).
        "--volume-cache-mb",
        "1",
    ]);
    args.extend(played(&record, &out));
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
fn a_shared_series_plays_with_the_next_step_fetched_ahead() {
    let dir = tempfile::tempdir().unwrap();
    // 40³ steps: 8 bricks each, 24 in all over 2 render nodes.
    let scene = write_ball_series(dir.path(), 40);
    let (out, record) = (dir.path().join("out"), dir.path().join("session.jsonl"));
    let prepared = dir.path().join("prepared");
    let wall = wall_of(scene.to_str().unwrap(), "256x128");
    let mut args = vec!["local"];
    args.extend(wall);
    args.extend([
        "--render-nodes",
        "2",
        "--threads",
        "1",
        "--data",
        "dsm",
        "--prepared",
        prepared.to_str().unwrap(),
        // 6 lines: a step's bricks of the other node (4) fit, the whole series (12) does not.
        "--cache-fraction",
        "0.25",
    ]);
    args.extend(played(&record, &out));
    let o = run("tessera-master", &args, Duration::from_secs(180));
    o.assert_success("local --play --data dsm");
    let manifest = read_json(&prepared.join("manifest.json"));
    assert_eq!(manifest["series_steps"], 3, "{manifest}");
    assert_eq!(manifest["layout"]["brick_blocks"], 24, "{manifest}");
    let report = read_json(&out.join("report.json"));
    assert_eq!(report["data"], "dsm", "{report}");
    let (mut prefetched, mut shown) = (0, 0);
    for node in report["render_nodes"].as_array().unwrap() {
        let (on_time, late) = (
            node["prefetch_hits"].as_u64().unwrap(),
            node["prefetch_misses"].as_u64().unwrap(),
        );
        let late_s = node["volume_stall_s"].as_f64().unwrap();
        eprintln!("shared series, render node {}: {on_time} steps on time, {late} late by {late_s:.4} s in all", node["id"]);
        // A node counts each step it rendered tiles of, on time or late.
        assert!(on_time + late <= 12, "{node}");
        shown += on_time + late;
        assert!(late_s >= 0.0 && (late > 0 || late_s == 0.0), "{node}");
        assert!(
            node["volume_load_s"].as_array().unwrap().is_empty(),
            "{node}"
        );
        prefetched += node["dsm"]["prefetched"].as_u64().unwrap();
    }
    // Every frame's step was rendered by one node at least (a step shown again at once, as
    // step 0 after step 2 of a node that skipped frames, counts once).
    assert!(shown >= 10, "{shown} steps shown: {report}");
    assert!(prefetched > 0, "no brick was fetched ahead: {report}");
    assert_shows_replayed_frame(&wall, &record, 7, &out.join("wall.png"), dir.path());
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
