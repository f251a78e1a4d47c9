//! Walls of physical screens and stereo: a wall of mixed resolutions, a portrait screen and an
//! angled one renders on a local wall as the reference does, pixel for pixel; a straight edge
//! of the scene stays straight across the gap between two screens; the two eyes see an object
//! behind the screen apart by the parallax geometry predicts; `validate` refuses each kind of
//! broken wall file with the screen and field at fault.

use std::path::{Path, PathBuf};
use std::time::Duration;
use tessera_tests::*;

fn walls() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/walls")
}

const CAMERA: [&str; 4] = ["--eye", "0,1.2,3.5", "--target", "0,0.4,0"];

/// `local` with `wall` flags, 2 frames, frame 1 saved into `out`; and `render` of frame 1 into
/// `reference`: the two wall images must be the same.
fn wall_equals_reference(dir: &Path, wall: &[&str]) {
    let (out, reference) = (dir.join("out"), dir.join("reference"));
    let mut local = vec![
        "local",
        "--render-nodes",
        "2",
        "--threads",
        "1",
        "--frames",
        "2",
    ];
    local.extend(["--save-frame", "1", "--out", out.to_str().unwrap()]);
    local.extend(wall);
    local.extend(CAMERA);
    run("tessera-master", &local, Duration::from_secs(180)).assert_success("the local wall");
    let mut render = vec![
        "render",
        "--frame",
        "1",
        "--out",
        reference.to_str().unwrap(),
    ];
    render.extend(wall);
    render.extend(CAMERA);
    run("tessera-master", &render, Duration::from_secs(120)).assert_success("render");
    assert_same_pixels(
        &out.join("wall.png"),
        &reference.join("wall.png"),
        "the wall against the reference",
    );
}

#[test]
fn mixed_resolutions_a_portrait_and_an_angled_screen_render_as_the_reference() {
    let dir = tempfile::tempdir().unwrap();
    let file = walls().join("mixed.toml");
    wall_equals_reference(dir.path(), &["--wall-file", file.to_str().unwrap()]);
}

#[test]
fn a_side_by_side_stereo_wall_renders_both_eyes_as_the_reference() {
    let dir = tempfile::tempdir().unwrap();
    let flags = [
        "--wall",
        "2x1",
        "--screen",
        "160x90",
        "--stereo",
        "side-by-side",
    ];
    wall_equals_reference(dir.path(), &flags);
}

/// A wall file of `screens` (TOML tables) seen from 600 mm in front of the origin.
fn write_wall(dir: &Path, extra: &str, screens: &str) -> PathBuf {
    let path = dir.join("wall.toml");
    let text =
        format!("tile_size = 32\n{extra}\n[viewer]\nposition_mm = [0.0, 0.0, 600.0]\n{screens}");
    std::fs::write(&path, text).unwrap();
    path
}

fn flat_screen(x: f64, y: f64, w: f64, h: f64, res: (u32, u32)) -> String {
    format!(
        "[[screen]]\nresolution = [{}, {}]\nx_mm = {x}\ny_mm = {y}\nwidth_mm = {w}\nheight_mm = {h}\n",
        res.0, res.1
    )
}

/// One triangle of the scene (an OBJ), in metres in front of a camera at the origin.
fn write_triangle(dir: &Path, corners: [[f64; 3]; 3]) -> PathBuf {
    let path = dir.join("triangle.obj");
    let mut text = String::new();
    for c in corners {
        text.push_str(&format!("v {} {} {}\n", c[0], c[1], c[2]));
    }
    text.push_str("f 1 2 3\n");
    std::fs::write(&path, text).unwrap();
    path
}

/// Renders frame 0 of `wall` with `scene` seen from the origin down -z, with no shadows;
/// returns the wall image.
fn render(dir: &Path, wall: &Path, scene: &Path) -> (u32, u32, Vec<u8>) {
    let out = dir.join("out");
    let args = [
        "render",
        "--wall-file",
        wall.to_str().unwrap(),
        "--scene",
        scene.to_str().unwrap(),
        "--eye",
        "0,0,0",
        "--target",
        "0,0,-1",
        "--no-shadows",
        "--out",
        out.to_str().unwrap(),
    ];
    run("tessera-master", &args, Duration::from_secs(60)).assert_success("render");
    load_rgb(&out.join("wall.png"))
}

/// Whether a pixel is the backdrop (a blue gradient) rather than the grey triangle.
fn backdrop(rgb: &[u8]) -> bool {
    rgb[2] as i32 - rgb[0] as i32 > 20
}

#[test]
fn a_straight_edge_stays_straight_across_the_gap_between_screens() {
    let dir = tempfile::tempdir().unwrap();
    // Two screens 400 x 300 mm, a millimetre a pixel, 40 mm apart; the viewer 600 mm away.
    let screens = flat_screen(-420.0, -150.0, 400.0, 300.0, (400, 300))
        + &flat_screen(20.0, -150.0, 400.0, 300.0, (400, 300));
    let wall = write_wall(dir.path(), "", &screens);
    // A plane 2 m away whose lower edge runs slantwise across both screens.
    let scene = write_triangle(
        dir.path(),
        [[-3.0, -0.6, -2.0], [3.0, 0.3, -2.0], [-3.0, 3.0, -2.0]],
    );
    let (width, _, rgb) = render(dir.path(), &wall, &scene);
    // Each column's lowest triangle pixel, as the point of the wall (mm) at its lower edge.
    let mut points = Vec::new();
    for (screen, left_mm) in [(0u32, -420.0), (1, 20.0)] {
        for px in 0..400u32 {
            let x = screen * 400 + px;
            let lowest = (0..300u32)
                .rev()
                .find(|&y| !backdrop(&rgb[((y * width + x) * 3) as usize..][..3]));
            if let Some(py) = lowest.filter(|&py| py > 0 && py < 299) {
                points.push((left_mm + px as f64 + 0.5, 150.0 - (py as f64 + 1.0)));
            }
        }
    }
    assert!(
        points.len() > 700,
        "the edge crosses both screens: {} points",
        points.len()
    );
    let fit = |pts: &[(f64, f64)]| {
        let n = pts.len() as f64;
        let (sx, sy) = pts.iter().fold((0.0, 0.0), |a, p| (a.0 + p.0, a.1 + p.1));
        let (mx, my) = (sx / n, sy / n);
        let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
        let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
        let slope = sxy / sxx;
        (slope, my - slope * mx)
    };
    let (slope, intercept) = fit(&points);
    let worst = points
        .iter()
        .map(|p| (p.1 - (slope * p.0 + intercept)).abs())
        .fold(0.0, f64::max);
    let left: Vec<_> = points.iter().copied().filter(|p| p.0 < 0.0).collect();
    let right: Vec<_> = points.iter().copied().filter(|p| p.0 > 0.0).collect();
    let (sl, il) = fit(&left);
    let (sr, ir) = fit(&right);
    eprintln!(
        "edge across the gap: one line within {worst:.2} mm of every edge pixel; slopes {sl:.4} and {sr:.4}, offsets {il:.1} and {ir:.1} mm"
    );
    // A pixel is 1 mm: the edge is where the pixels say, within one of them, on one line.
    assert!(worst < 1.5, "{worst} mm off the line");
    assert!((sl - sr).abs() < 0.01 && (il - ir).abs() < 2.0);
}

#[test]
fn the_eyes_see_an_object_behind_the_screen_apart_by_its_parallax() {
    let dir = tempfile::tempdir().unwrap();
    // One screen 400 x 300 mm at 1 mm a pixel, 600 mm from the viewer; each eye a display.
    let screen = flat_screen(-200.0, -150.0, 400.0, 300.0, (400, 300));
    let stereo = "[stereo]\nmode = \"displays\"\neye_separation = 64.0\n";
    let wall = write_wall(dir.path(), stereo, &screen);
    // A small triangle 1.2 m from the eyes, straight ahead.
    let scene = write_triangle(
        dir.path(),
        [[-0.05, -0.05, -1.2], [0.05, -0.05, -1.2], [0.0, 0.05, -1.2]],
    );
    let (width, _, rgb) = render(dir.path(), &wall, &scene);
    let centre_x = |display: u32| {
        let (mut sum, mut n) = (0.0, 0.0);
        for y in 0..300u32 {
            for px in 0..400u32 {
                let x = display * 400 + px;
                if !backdrop(&rgb[((y * width + x) * 3) as usize..][..3]) {
                    sum += px as f64 + 0.5;
                    n += 1.0;
                }
            }
        }
        assert!(n > 10.0, "display {display} shows the object");
        sum / n
    };
    let (left, right) = (centre_x(0), centre_x(1));
    // Seen through a screen at 600 mm, a point at 1200 mm lies 64 × (1200 − 600) / 1200 =
    // 32 mm further right for the right eye than for the left (uncrossed: behind the screen).
    let expected = 64.0 * (1200.0 - 600.0) / 1200.0;
    eprintln!(
        "parallax: left eye x {left:.2}, right eye x {right:.2}: {:.2} mm apart, {expected} expected",
        right - left
    );
    assert!((right - left - expected).abs() < 1.0, "{} mm", right - left);
}

#[test]
fn validate_refuses_each_kind_of_broken_wall_file_and_draws_a_good_one() {
    let dir = tempfile::tempdir().unwrap();
    let ok = flat_screen(0.0, 0.0, 500.0, 300.0, (640, 360));
    let cases = [
        (ok.clone() + &flat_screen(400.0, 0.0, 500.0, 300.0, (640, 360)), "screen 1", "overlaps screen 0"),
        (ok.clone() + &flat_screen(600.0, 0.0, 0.0, 300.0, (640, 360)), "screen 1", "width_mm"),
        (ok.clone() + &flat_screen(600.0, 0.0, 500.0, 300.0, (0, 360)), "screen 1", "resolution"),
        (ok.clone() + "[[screen]]\nresolution = [64, 64]\nx_mm = 600.0\ny_mm = 0.0\n", "screen 1", "x_mm"),
        (ok.replace("[[screen]]\n", "[[screen]]\nrotation = 45\n"), "screen 0", "rotation"),
        (
            "[[screen]]\nresolution = [64, 64]\nbottom_left_mm = [100.0, 0.0, 0.0]\nbottom_right_mm = [0.0, 0.0, 0.0]\ntop_left_mm = [100.0, 100.0, 0.0]\n".to_string(),
            "screen 0",
            "faces away",
        ),
        (ok.replace("x_mm", "left_mm"), "left_mm", ""),
    ];
    for (screens, who, what) in cases {
        let wall = write_wall(dir.path(), "", &screens);
        let o = run(
            "tessera-master",
            &["validate", wall.to_str().unwrap()],
            Duration::from_secs(30),
        );
        assert_eq!(o.status.code(), Some(1), "{screens}\n{}", o.stderr);
        assert!(
            o.stderr.contains(who) && o.stderr.contains(what),
            "{}",
            o.stderr
        );
    }
    let svg = dir.path().join("mixed.svg");
    let file = walls().join("mixed.toml");
    let o = run(
        "tessera-master",
        &[
            "validate",
            file.to_str().unwrap(),
            "--out",
            svg.to_str().unwrap(),
        ],
        Duration::from_secs(30),
    );
    o.assert_success("validate mixed.toml");
    let text = std::fs::read_to_string(&svg).unwrap();
    assert!(
        text.contains("display 2") && text.contains("<polygon"),
        "{text}"
    );
    assert!(o.stdout.contains("3 displays"), "{}", o.stdout);
}
