//! Progressive refinement on a running local wall: a still camera refines to the final
//! quality, which equals the single-process reference at that quality pixel for pixel; then
//! the wall renders nothing until something changes, and a change renders again.

use std::time::Duration;
use tessera_tests::*;

const LIMIT: Duration = Duration::from_secs(120);
const CAMERA: [&str; 4] = ["--eye", "3,2.5,6", "--target", "0,0.4,0"];

fn figures(connect: &[String]) -> serde_json::Value {
    let o = control(connect, &["figures"], LIMIT);
    o.assert_success("control figures");
    let v: serde_json::Value = serde_json::from_str(&o.stdout).expect("JSON figures");
    v["Figures"].clone()
}

#[test]
fn a_still_view_converges_to_the_reference_then_stops_rendering() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    // Two still frames, then passes of 2 and 4 samples: frame 3 is the final quality.
    let mut args = vec![
        "local",
        "--wall",
        "2x1",
        "--screen",
        "160x90",
        "--frames",
        "0",
        "--refine",
        "on",
        "--still-frames",
        "2",
        "--final-spp",
        "4",
        "--final-ao",
        "4",
        "--save-frame",
        "3",
        "--out",
    ];
    args.push(out.to_str().unwrap());
    args.extend(CAMERA);
    let master = Proc::start("tessera-master", &args);
    let connect = control_args(&master, LIMIT);
    master.wait_for_stderr("is at the final quality", LIMIT);
    // Frame 3 started at the final quality; wait until it is on every display.
    let presented = |f: &serde_json::Value| f["frames_presented"].as_u64().unwrap();
    assert!(
        wait_for(LIMIT, || presented(&figures(&connect)) >= 4),
        "the final pass never reached the displays"
    );
    // Every tile of those 4 frames reported (a report can trail its frame's present):
    // 2 screens of 3x2 tiles, 12 a frame.
    let tiles = |f: &serde_json::Value| -> u64 {
        f["render_nodes"]
            .as_array()
            .unwrap()
            .iter()
            .map(|n| n["tiles"].as_u64().unwrap())
            .sum()
    };
    assert!(
        wait_for(LIMIT, || tiles(&figures(&connect)) >= 4 * 12),
        "the tiles of the 4 frames were never all reported"
    );
    // Nothing renders while nothing changes: the counters stand still over a second. A
    // node late with its tiles has them copied to another (speculative re-issue), so a tile
    // may be reported twice, and the late copy's report may land in the first second; over
    // the next, nothing may move.
    std::thread::sleep(Duration::from_secs(1));
    let settled = figures(&connect);
    std::thread::sleep(Duration::from_secs(1));
    let later = figures(&connect);
    assert_eq!(presented(&later), 4, "{later}");
    assert_eq!(
        tiles(&later),
        tiles(&settled),
        "render nodes kept working: {later}"
    );
    // A change renders again.
    control(&connect, &["quality", "--shadows", "off"], LIMIT).assert_success("control quality");
    assert!(
        wait_for(LIMIT, || figures(&connect)["frames_presented"]
            .as_u64()
            .unwrap()
            > 4),
        "a change did not wake the wall"
    );
    master.signal(libc::SIGINT);
    let o = master.wait(LIMIT);
    assert_eq!(o.status.code(), Some(130), "{}", o.stderr);

    let reference = dir.path().join("reference");
    let mut args = vec![
        "render", "--wall", "2x1", "--screen", "160x90", "--frame", "3", "--spp", "4", "--ao", "4",
        "--out",
    ];
    args.push(reference.to_str().unwrap());
    args.extend(CAMERA);
    run("tessera-master", &args, LIMIT).assert_success("reference at the final quality");
    let (_, _, wall) = load_rgb(&out.join("wall.png"));
    let (_, _, expected) = load_rgb(&reference.join("wall.png"));
    let differing = wall.iter().zip(&expected).filter(|(a, b)| a != b).count();
    assert_eq!(
        differing, 0,
        "the converged frame differs from the reference"
    );
}
