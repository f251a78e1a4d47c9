//! `tessera-master render --frames A..B`: every frame of a range as a PNG, each the image that
//! `render --frame K` writes; camera paths as sessions; `--mp4` through the system's ffmpeg.

use glam::Vec3;
use std::path::{Path, PathBuf};
use std::time::Duration;
use tessera_model::camera::{Camera, CameraMode};
use tessera_model::params::RenderParams;
use tessera_model::state::WallState;
use tessera_tests::{
    assert_same_pixels, assert_shows_replayed_frame, load_rgb, require_tools, run, Output, Proc,
};

const LIMIT: Duration = Duration::from_secs(120);
/// A tiny wall and scene: each frame renders in milliseconds.
const WALL: [&str; 4] = ["--wall", "1x1", "--scene", "knot:64:8"];

/// `render` on the tiny wall with `extra`, its screen 64x48 unless `extra` says otherwise.
fn render_args<'a>(extra: &[&'a str]) -> Vec<&'a str> {
    let mut args = vec!["render"];
    args.extend(WALL);
    if !extra.contains(&"--screen") {
        args.extend(["--screen", "64x48"]);
    }
    args.extend(extra);
    args
}

fn render(extra: &[&str]) -> Output {
    run("tessera-master", &render_args(extra), LIMIT)
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn frame(dir: &Path, k: u64) -> PathBuf {
    dir.join(format!("frame-{k:06}.png"))
}

/// The frames of `dir`, sorted.
fn frames_in(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .map(|d| {
            d.map(|e| e.unwrap().file_name().into_string().unwrap())
                .filter(|n| n.starts_with("frame-"))
                .collect()
        })
        .unwrap_or_default();
    names.sort();
    names
}

/// How many bytes of two images' pixels differ.
fn differing(a: &Path, b: &Path) -> usize {
    let (a, b) = (load_rgb(a).2, load_rgb(b).2);
    a.iter().zip(&b).filter(|(x, y)| x != y).count()
}

/// A session as `--record` writes it: the orbit from frame 0, then a fixed camera with
/// ambient occlusion from frame 2.
fn write_session(path: &Path) {
    let orbit = CameraMode::orbit(Vec3::ZERO, 3.0, 45.0).unwrap();
    let fixed = CameraMode::fixed(
        Camera::new(Vec3::new(1.0, 2.0, 6.0), Vec3::ZERO, Vec3::Y, 40.0).unwrap(),
    );
    let ao = tessera_model::params::RenderParamsSpec {
        ao_samples: 2,
        ..RenderParams::interactive().spec()
    }
    .build()
    .unwrap();
    let lines: Vec<String> = [(0, orbit, RenderParams::interactive()), (2, fixed, ao)]
        .iter()
        .enumerate()
        .map(|(i, (frame, camera, params))| {
            let wall = WallState {
                camera: *camera,
                params: *params,
                lights: None,
            };
            serde_json::json!({
                "frame": frame,
                "state": i,
                "wall": wall,
                "camera_at_frame": camera.camera_for_frame(*frame),
            })
            .to_string()
        })
        .collect();
    std::fs::write(path, lines.join("\n") + "\n").unwrap();
}

#[test]
fn movie_frames_of_a_session_are_the_single_frame_renders() {
    let dir = tempfile::tempdir().unwrap();
    let session = dir.path().join("s.jsonl");
    write_session(&session);
    let movie = dir.path().join("movie");
    render(&[
        "--replay",
        s(&session),
        "--frames",
        "0..4",
        "--out",
        s(&movie),
    ])
    .assert_success("render --frames 0..4");
    let names: Vec<String> = (0..4).map(|k| format!("frame-{k:06}.png")).collect();
    assert_eq!(frames_in(&movie), names, "A..B leaves B out");
    for k in 0..4 {
        let single = dir.path().join(format!("single-{k}"));
        let frame_arg = k.to_string();
        render(&[
            "--replay",
            s(&session),
            "--frame",
            &frame_arg,
            "--out",
            s(&single),
        ])
        .assert_success("render --frame");
        assert_same_pixels(
            &frame(&movie, k),
            &single.join("wall.png"),
            &format!("frame {k}"),
        );
    }
    // The frames show the session moving: the orbit turns, then the camera and quality change.
    let moved = |a: u64, b: u64| differing(&frame(&movie, a), &frame(&movie, b)) > 0;
    assert!(moved(0, 1), "the orbit turns a degree a frame");
    assert!(moved(1, 2), "frame 2 has the fixed camera");
    // Inclusive ranges include their end.
    let tail = dir.path().join("tail");
    render(&[
        "--replay",
        s(&session),
        "--frames",
        "2..=3",
        "--out",
        s(&tail),
    ])
    .assert_success("render --frames 2..=3");
    assert_eq!(frames_in(&tail), names[2..].to_vec());
}

const PATH: &str = r#"
interpolation = "linear"
[[key]]
frame = 0
eye = [0.0, 1.0, 6.0]
target = [0.0, 0.0, 0.0]
fov = 40.0
[[key]]
frame = 4
eye = [6.0, 1.0, 0.0]
target = [0.0, 0.0, 0.0]
fov = 50.0
"#;

#[test]
fn a_camera_path_renders_as_a_session_from_key_to_key() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("fly.path.toml");
    std::fs::write(&path, PATH).unwrap();
    let movie = dir.path().join("movie");
    render(&[
        "--replay",
        s(&path),
        "--frames",
        "0..=4",
        "--out",
        s(&movie),
    ])
    .assert_success("render a camera path");
    assert_eq!(frames_in(&movie).len(), 5);
    // At its keys the path's camera is the key's, exactly as the camera flags give it.
    for (k, eye, fov) in [(0, "0,1,6", "40"), (4, "6,1,0", "50")] {
        let flags = dir.path().join(format!("flags-{k}"));
        let frame_arg = k.to_string();
        render(&[
            "--eye",
            eye,
            "--target",
            "0,0,0",
            "--fov",
            fov,
            "--frame",
            &frame_arg,
            "--out",
            s(&flags),
        ])
        .assert_success("render --eye");
        assert_same_pixels(
            &frame(&movie, k),
            &flags.join("wall.png"),
            &format!("key at frame {k}"),
        );
    }
    for key in [0, 4] {
        let moved = differing(&frame(&movie, 2), &frame(&movie, key));
        assert!(
            moved > 0,
            "between the keys the camera moves away from key {key}'s"
        );
    }
    // One frame of the path, as of a session.
    let single = dir.path().join("single");
    render(&["--replay", s(&path), "--frame", "2", "--out", s(&single)])
        .assert_success("--frame 2");
    assert_same_pixels(
        &frame(&movie, 2),
        &single.join("wall.png"),
        "frame 2 of the path",
    );
    // Before its first key a path has no camera, as a session has no state.
    std::fs::write(
        &path,
        PATH.replace("frame = 0", "frame = 3")
            .replace("frame = 4", "frame = 9"),
    )
    .unwrap();
    render(&["--replay", s(&path), "--frames", "0..5", "--out", s(&movie)]).assert_refused(
        "a range before the path",
        &["starts at frame 3", "fly.path.toml"],
    );
    std::fs::write(&path, PATH.replace("fov = 50.0", "fov = 500.0")).unwrap();
    render(&["--replay", s(&path), "--frames", "0..5", "--out", s(&movie)])
        .assert_refused("a bad key", &["fly.path.toml", "key 2", "`fov` 500"]);
}

#[test]
fn a_wall_replays_a_camera_path_as_render_renders_it() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("fly.path.toml");
    std::fs::write(&path, PATH).unwrap();
    let out = dir.path().join("wall");
    let wall = ["--wall", "2x1", "--screen", "64x48", "--scene", "knot:64:8"];
    let mut args = vec!["local"];
    args.extend(wall);
    args.extend(["--render-nodes", "1", "--no-console", "--frames", "6"]);
    args.extend(["--replay", s(&path), "--save-frame", "2", "--out", s(&out)]);
    run("tessera-master", &args, LIMIT).assert_success("local --replay fly.path.toml");
    assert_shows_replayed_frame(&wall, &path, 2, &out.join("wall.png"), dir.path());
}

#[test]
fn a_movie_of_a_played_series_prepares_each_step_it_shows() {
    let dir = tempfile::tempdir().unwrap();
    let scene = tessera_tests::write_ball_series(dir.path(), 16);
    let record = dir.path().join("played.jsonl");
    let wall = [
        "--wall",
        "1x1",
        "--screen",
        "48x32",
        "--scene",
        s(&scene),
        "--iso",
        "100",
        "--eye",
        "40,7.5,7.5",
        "--target",
        "7.5,7.5,7.5",
    ];
    let mut args = vec!["local"];
    args.extend(wall);
    args.extend([
        "--render-nodes",
        "1",
        "--no-console",
        "--frames",
        "8",
        "--play",
    ]);
    args.extend(["--record", s(&record)]);
    run("tessera-master", &args, LIMIT).assert_success("local --play --record");
    let movie = dir.path().join("movie");
    let mut args = vec!["render"];
    args.extend(wall);
    args.extend([
        "--replay",
        s(&record),
        "--frames",
        "0..8",
        "--out",
        s(&movie),
    ]);
    run("tessera-master", &args, LIMIT).assert_success("a movie of the played session");
    for k in 0..8 {
        assert_shows_replayed_frame(&wall, &record, k, &frame(&movie, k), dir.path());
    }
    // The wall steps through the series as its readers keep up: the recording says which
    // step each frame showed. Frames of one step are the same image, of two steps not.
    let steps = recorded_steps(&record, 8);
    assert!(
        steps.iter().any(|&step| step != steps[0]),
        "the series played: {steps:?}"
    );
    for a in 0..8 {
        for b in a + 1..8 {
            let same = differing(&frame(&movie, a as u64), &frame(&movie, b as u64)) == 0;
            assert_eq!(
                same,
                steps[a] == steps[b],
                "frames {a} and {b} of steps {steps:?}"
            );
        }
    }
}

/// The series step each of the first `frames` frames of a recorded session shows.
fn recorded_steps(record: &Path, frames: u64) -> Vec<u64> {
    let lines: Vec<serde_json::Value> = std::fs::read_to_string(record)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    (0..frames)
        .map(|k| {
            let line = lines
                .iter()
                .rev()
                .find(|l| l["frame"].as_u64().unwrap() <= k);
            line.expect("a state for every frame")["wall"]["params"]["volume"]["time_step"]
                .as_u64()
                .expect("a time step")
        })
        .collect()
}

#[test]
fn mp4_holds_the_frames_of_the_range_and_no_stale_ones() {
    let test = "mp4_holds_the_frames_of_the_range_and_no_stale_ones";
    let Some(tools) = require_tools(test, &["ffmpeg", "ffprobe"], "apt-get install ffmpeg") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let movie = dir.path().join("movie");
    // A longer earlier run leaves frames 8 and 9 in the folder; an odd-sized wall, which
    // yuv420p cannot take as it is.
    let odd = ["--screen", "63x47"];
    render(&[&odd[..], &["--frames", "3..10", "--out", s(&movie)]].concat())
        .assert_success("the earlier run");
    let mp4 = dir.path().join("movie.mp4");
    render(
        &[
            &odd[..],
            &[
                "--frames",
                "3..=7",
                "--out",
                s(&movie),
                "--mp4",
                s(&mp4),
                "--fps",
                "10",
            ],
        ]
        .concat(),
    )
    .assert_success("render --mp4");
    assert!(std::fs::metadata(&mp4).unwrap().len() > 0, "an empty MP4");
    let probe = |entries: &str| {
        let out = std::process::Command::new(&tools[1])
            .args(["-v", "error", "-count_frames", "-select_streams", "v:0"])
            .args(["-show_entries", entries, "-of", "csv=p=0"])
            .arg(&mp4)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "ffprobe: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8(out.stdout).unwrap().trim().to_string()
    };
    assert_eq!(probe("stream=nb_read_frames"), "5", "frames 3..=7");
    assert_eq!(probe("stream=r_frame_rate"), "10/1");
    assert_eq!(
        probe("stream=width,height"),
        "64,48",
        "padded to even sides"
    );
}

#[test]
fn mp4_without_ffmpeg_says_how_to_get_it_before_rendering() {
    let dir = tempfile::tempdir().unwrap();
    let empty = dir.path().join("empty-path");
    std::fs::create_dir(&empty).unwrap();
    let movie = dir.path().join("movie");
    let mp4 = dir.path().join("movie.mp4");
    let args = render_args(&["--frames", "0..3", "--out", s(&movie), "--mp4", s(&mp4)]);
    Proc::start_with_env("tessera-master", &args, &[("PATH", s(&empty))])
        .wait(LIMIT)
        .assert_refused(
            "--mp4 without ffmpeg",
            &[
                "--mp4 needs ffmpeg on the PATH",
                "apt-get install ffmpeg",
                s(&movie),
            ],
        );
    assert!(frames_in(&movie).is_empty(), "nothing is rendered first");
    assert!(!mp4.exists());
}

#[test]
fn bad_frame_ranges_are_refused_naming_frames() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    for (extra, words) in [
        (
            &["--frames", "5..3"][..],
            &["--frames", "before its start"][..],
        ),
        (&["--frames", "4..4"], &["--frames", "empty"]),
        (&["--frames", "4"], &["--frames", "not a range"]),
        (&["--frames", "-1..3"], &["--frames", "not a frame number"]),
        (
            &["--frame", "2", "--frames", "0..3"],
            &["--frames", "--frame"],
        ),
        (
            &["--frames", "0..3", "--aov", "depth"],
            &["--frames", "--aov"],
        ),
        (&["--mp4", "m.mp4"], &["--mp4", "--frames"]),
        (
            &["--frames", "0..3", "--mp4", "m.mp4", "--fps", "0"],
            &["--fps"],
        ),
    ] {
        let mut args = extra.to_vec();
        args.extend(["--out", s(&out)]);
        render(&args).assert_refused(&format!("render {extra:?}"), words);
    }
    assert!(!out.exists(), "nothing was rendered");
}
