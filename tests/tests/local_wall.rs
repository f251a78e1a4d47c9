//! The local wall against the single-process reference, and what each display received.

use std::time::Duration;
use tessera_protocol::pixels::{STREAM_HEADER_LEN, TILE_HEADER_LEN};
use tessera_tests::*;

// Ambient occlusion is on so the comparison covers random samples too: they are keyed on
// (frame, pixel, sample), so any render node draws the same ones.
const WALL: [&str; 8] = [
    "--wall", "2x2", "--screen", "240x136", "--bezel", "12", "--ao", "2",
];

const FRAMES: u64 = 5;
/// Pixels of one 240x136 screen.
const OWNED: u64 = 240 * 136;
/// 240x136 screens in 64-pixel tiles: 4 columns, 3 rows.
const TILES_PER_DISPLAY: u64 = 4 * 3;

/// Runs the local wall for FRAMES frames, saving frame 3 to `out`.
fn run_local_wall(out: &std::path::Path, extra: &[&str]) {
    let mut args = vec!["local"];
    args.extend(WALL);
    args.extend([
        "--render-nodes",
        "2",
        "--frames",
        "5",
        "--save-frame",
        "3",
        // Each tile exactly once, which the byte counts below check: no copy of a late
        // node's tiles, whatever the machine's load.
        "--no-speculation",
        "--out",
        out.to_str().unwrap(),
    ]);
    args.extend(extra);
    run("tessera-master", &args, Duration::from_secs(120)).assert_success("local wall");
}

/// Checks what every display counted that does not depend on timing, and returns each
/// display's (stream bytes, wire bytes).
fn check_display_bytes(report: &serde_json::Value) -> Vec<(u64, u64)> {
    let displays = report["displays"].as_array().unwrap();
    assert_eq!(displays.len(), 4);
    displays
        .iter()
        .map(|d| {
            assert_eq!(d["pixels_owned"], OWNED);
            // Exactly its own pixels (as unpacked), once per frame: nothing of other screens,
            // nothing twice.
            assert_eq!(
                d["pixel_bytes_received"],
                OWNED * 3 * FRAMES,
                "display {}",
                d["id"]
            );
            assert_eq!(d["duplicate_tiles"], 0);
            assert_eq!(d["frames_presented"], FRAMES);
            let stream = d["stream_bytes_received"].as_u64().unwrap();
            let wire = d["wire_bytes_received"].as_u64().unwrap();
            // Every stream byte reaches the display inside some QUIC packet.
            assert!(
                wire > stream,
                "wire bytes {wire} below stream bytes {stream}"
            );
            let ratio = d["wire_bytes_per_pixel_byte"].as_f64().unwrap();
            let expected = wire as f64 / (OWNED * 3 * FRAMES) as f64;
            assert!((ratio - expected).abs() < 1e-9, "{ratio} vs {expected}");
            (stream, wire)
        })
        .collect()
}

#[test]
fn local_wall_equals_reference_and_each_display_gets_only_its_pixels() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("wall");
    let reference = dir.path().join("reference");
    let frames = FRAMES;
    run_local_wall(&out, &[]);

    let mut args = vec!["render"];
    args.extend(WALL);
    args.extend([
        "--frame",
        "3",
        "--aov",
        "depth",
        "--aov",
        "prim",
        "--out",
        reference.to_str().unwrap(),
    ]);
    run("tessera-master", &args, Duration::from_secs(120)).assert_success("reference render");

    let (w, h, wall) = load_rgb(&out.join("wall.png"));
    let (rw, rh, expected) = load_rgb(&reference.join("wall.png"));
    assert_eq!((w, h), (rw, rh));
    assert_eq!((w, h), (2 * 240 + 12, 2 * 136 + 12));
    let differing = wall.iter().zip(&expected).filter(|(a, b)| a != b).count();
    assert_eq!(
        differing, 0,
        "the wall differs from the reference in {differing} bytes"
    );
    // The picture is not trivially black: the comparison means something.
    assert!(expected.iter().filter(|&&b| b > 40).count() > expected.len() / 2);

    // AOVs cover the whole virtual image: a PFM header, then one float per pixel.
    for name in ["depth.pfm", "prim.pfm"] {
        let bytes = std::fs::read(reference.join(name)).unwrap();
        let header = format!("Pf\n{w} {h}\n-1.0\n");
        assert!(bytes.starts_with(header.as_bytes()), "{name}");
        assert_eq!(bytes.len(), header.len() + (w * h) as usize * 4, "{name}");
    }

    let report = read_json(&out.join("report.json"));
    assert_eq!(report["frames"], frames);
    assert_eq!(report["compression"], "none");
    assert!(report["fps"].as_f64().unwrap() > 0.0);
    for (stream, wire) in check_display_bytes(&report) {
        // Raw tiles: the pixels, a header per tile and one per stream (at least one stream
        // per frame, at most one per tile).
        let (tile_header, stream_header) = (TILE_HEADER_LEN as u64, STREAM_HEADER_LEN as u64);
        let headers = tile_header * TILES_PER_DISPLAY * FRAMES;
        let pixels = OWNED * 3 * FRAMES;
        assert!(
            stream >= pixels + headers + stream_header * FRAMES,
            "{stream}"
        );
        assert!(
            stream <= pixels + headers + stream_header * TILES_PER_DISPLAY * FRAMES,
            "{stream}"
        );
        assert!(wire > pixels, "wire bytes {wire} below pixel bytes");
    }
    let rendered: u64 = report["render_nodes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["tiles"].as_u64().unwrap())
        .sum();
    let tiles_per_frame = 4 * TILES_PER_DISPLAY;
    assert_eq!(rendered, tiles_per_frame * frames);
    for (i, display) in report["wall"]["displays"]
        .as_array()
        .unwrap()
        .iter()
        .enumerate()
    {
        let (dw, dh, pixels) = load_rgb(&out.join(format!("display-{i}.png")));
        assert_eq!((dw, dh), (240, 136));
        let (x, y) = (
            display["x"].as_u64().unwrap() as usize,
            display["y"].as_u64().unwrap() as usize,
        );
        for row in 0..136usize {
            let a = &pixels[row * 240 * 3..(row + 1) * 240 * 3];
            let at = ((y + row) * w as usize + x) * 3;
            assert_eq!(a, &expected[at..at + 240 * 3], "display {i} row {row}");
        }
    }
}

#[test]
fn lz4_wall_equals_reference_and_sends_fewer_bytes_than_pixels() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("wall");
    let reference = dir.path().join("reference");
    run_local_wall(&out, &["--compress", "lz4"]);
    let mut args = vec!["render"];
    args.extend(WALL);
    args.extend(["--frame", "3", "--out", reference.to_str().unwrap()]);
    run("tessera-master", &args, Duration::from_secs(120)).assert_success("reference render");

    let (w, h, wall) = load_rgb(&out.join("wall.png"));
    let (rw, rh, expected) = load_rgb(&reference.join("wall.png"));
    assert_eq!((w, h), (rw, rh));
    assert!(wall == expected, "the lz4 wall differs from the reference");
    for i in 0..4 {
        let (dw, dh, _) = load_rgb(&out.join(format!("display-{i}.png")));
        assert_eq!((dw, dh), (240, 136));
    }

    let report = read_json(&out.join("report.json"));
    assert_eq!(report["frames"], FRAMES);
    assert_eq!(report["compression"], "lz4");
    for (stream, _) in check_display_bytes(&report) {
        // The scene's flat background packs well, whatever the noise of the AO samples, and a
        // tile never grows: the stream is well under the raw pixels.
        assert!(stream < OWNED * 3 * FRAMES / 2, "{stream}");
    }
}

#[test]
fn eyelight_wall_equals_reference_and_differs_from_full_shading() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("wall");
    run_local_wall(&out, &["--shading", "eyelight"]);
    let reference = |name: &str, shading: &str| {
        let path = dir.path().join(name);
        let mut args = vec!["render"];
        args.extend(WALL);
        args.extend(["--frame", "3", "--shading", shading]);
        args.extend(["--out", path.to_str().unwrap()]);
        run("tessera-master", &args, Duration::from_secs(120)).assert_success("reference render");
        load_rgb(&path.join("wall.png"))
    };
    let (w, h, wall) = load_rgb(&out.join("wall.png"));
    let (rw, rh, expected) = reference("eyelight", "eyelight");
    assert_eq!((w, h), (rw, rh));
    assert!(
        wall == expected,
        "the eye-light wall differs from the reference"
    );
    let (_, _, full) = reference("full", "full");
    assert!(full != expected, "--shading eyelight drew the full shading");
}

#[test]
fn bad_inputs_fail_with_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let bad_obj = dir.path().join("broken.obj");
    std::fs::write(&bad_obj, "v 0 0 0\nv 1 0 0\nv 0 1 nan\nf 1 2 3\n").unwrap();
    let o = run(
        "tessera-master",
        &[
            "render",
            "--scene",
            bad_obj.to_str().unwrap(),
            "--out",
            dir.path().to_str().unwrap(),
        ],
        Duration::from_secs(60),
    );
    assert!(!o.status.success());
    assert!(
        o.stderr.contains("broken.obj") && o.stderr.contains("line 3"),
        "{}",
        o.stderr
    );

    let o = run(
        "tessera-master",
        &["local", "--scene", "/nonexistent/mesh.ply", "--frames", "1"],
        Duration::from_secs(60),
    );
    assert!(!o.status.success());
    assert!(o.stderr.contains("/nonexistent/mesh.ply"), "{}", o.stderr);

    let wall_file = dir.path().join("wall.toml");
    std::fs::write(
        &wall_file,
        "columns = 2\nrows = 0\nscreen_width = 10\nscreen_height = 10\n",
    )
    .unwrap();
    let o = run(
        "tessera-master",
        &[
            "render",
            "--wall-file",
            wall_file.to_str().unwrap(),
            "--out",
            dir.path().to_str().unwrap(),
        ],
        Duration::from_secs(60),
    );
    assert!(!o.status.success());
    assert!(
        o.stderr.contains("rows") && o.stderr.contains("wall.toml"),
        "{}",
        o.stderr
    );

    let o = run(
        "tessera-master",
        &[
            "render",
            "--wall",
            "2by2",
            "--out",
            dir.path().to_str().unwrap(),
        ],
        Duration::from_secs(60),
    );
    assert!(!o.status.success());
    assert!(o.stderr.contains("2by2"), "{}", o.stderr);

    let o = run(
        "tessera-master",
        &[
            "render",
            "--eye",
            "1,1,1",
            "--target",
            "1,1,1",
            "--out",
            dir.path().to_str().unwrap(),
        ],
        Duration::from_secs(60),
    );
    assert!(!o.status.success());
    assert!(o.stderr.contains("eye and target"), "{}", o.stderr);
}

/// A 2x1 local wall of many frames writing into `out`, returned once frames are flowing: a
/// display has saved frame 2 (an event to wait for, not a time to guess).
fn flowing_wall(out: &std::path::Path, extra: &[&str]) -> Proc {
    let out_s = out.to_str().unwrap();
    let mut args = vec![
        "local",
        "--wall",
        "2x1",
        "--screen",
        "160x90",
        "--frames",
        "100000",
        "--save-frame",
        "2",
        "--out",
        out_s,
    ];
    args.extend(extra);
    let master = Proc::start("tessera-master", &args);
    let saved = out.join("display-1.png");
    assert!(
        wait_for(Duration::from_secs(60), || saved.exists()
            || master.has_exited()),
        "the wall never presented frame 2"
    );
    assert!(!master.has_exited(), "the master exited on its own");
    master
}

/// The pid of the process whose command line holds every one of `words`.
fn process_with(words: &[&str]) -> Option<u32> {
    let me = std::process::id();
    tessera_cli::procs::processes()
        .into_iter()
        .find(|p| {
            let line = p.args.join(" ");
            p.pid != me && !p.zombie && words.iter().all(|w| line.contains(w))
        })
        .map(|p| p.pid)
}

#[test]
fn ctrl_c_stops_the_wall_and_leaves_no_process_behind() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("interrupted-run");
    let out_s = out.to_str().unwrap().to_string();
    let master = flowing_wall(&out, &[]);
    assert!(
        processes_mentioning(&out_s).len() >= 2,
        "the displays run with --out {out_s}"
    );
    master.signal(libc::SIGINT);
    let o = master.wait(Duration::from_secs(60));
    assert_eq!(o.status.code(), Some(130), "stderr:\n{}", o.stderr);
    assert!(o.stderr.contains("interrupted"), "{}", o.stderr);
    assert!(
        wait_for(Duration::from_secs(5), || processes_mentioning(&out_s)
            .is_empty()),
        "orphans: {:?}",
        processes_mentioning(&out_s)
    );
    let report = read_json(&out.join("report.json"));
    // Frame 2 was on screen before the interrupt, so at least frames 0..=2 were presented.
    assert!(report["frames"].as_u64().unwrap() >= 3, "{report}");
}

#[test]
fn with_display_loss_stop_a_dead_display_stops_the_wall_with_an_error_and_no_orphans() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("display-dies");
    let out_s = out.to_str().unwrap().to_string();
    let master = flowing_wall(&out, &["--display-loss", "stop"]);
    let victim = process_with(&[&out_s, "--display 1 "]).expect("display 1 is running");
    // SAFETY: kill only sends a signal and touches no memory; the pid is a node
    // process of the wall this test started, still running.
    unsafe { libc::kill(victim as i32, libc::SIGKILL) };
    let o = master.wait(Duration::from_secs(60));
    o.assert_refused("a wall that lost a display", &["display"]);
    // Named whichever notices first: the launcher (the child died) or the link (it closed).
    assert!(o.stderr.contains("display 1 ("), "{}", o.stderr);
    assert!(
        wait_for(Duration::from_secs(5), || processes_mentioning(&out_s)
            .is_empty()),
        "orphans left"
    );
}
