//! A local wall's windows under Xvfb: the grid's windows open side by side from
//! `--window-origin`, not on top of each other; F1 shows the key help in the window it was
//! pressed in only, and again hides it; Z in a window fits the scene to the view as the
//! control's `fit` does; O over particles shows their colour map's legend, in the colours
//! the render nodes give them.
//!
//! Needs Xvfb, xwininfo, xdotool and ImageMagick's `import` (`deploy/xvfb-screenshot.sh
//! install`, which `.ci/run` calls); skipped, saying why, where they are missing outside CI.

use std::path::Path;
use std::process::Command;
use std::time::Duration;
use tessera_model::colormap::ColorMap;
use tessera_render::encode_srgb_ish;
use tessera_tests::xvfb::{screenshot_script, xwininfo_field, Xvfb};
use tessera_tests::*;

const LIMIT: Duration = Duration::from_secs(120);

/// Before: `--wall 3x1 --window` opened all three windows at +0+0.
#[test]
fn grid_windows_open_side_by_side_not_on_top_of_each_other() {
    let test = "grid_windows_open_side_by_side_not_on_top_of_each_other";
    for origin in [None, Some((50, 40))] {
        let Some(xvfb) = Xvfb::start(test, "800x300", &["xwininfo"]) else {
            return;
        };
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out");
        let origin_arg = origin.map(|(x, y)| format!("{x},{y}"));
        let mut args = vec![
            "local", "--wall", "3x1", "--screen", "160x90", "--window", "--frames", "0",
            "--refine", "off", "--out",
        ];
        args.push(out.to_str().unwrap());
        if let Some(o) = &origin_arg {
            args.extend(["--window-origin", o]);
        }
        let master = Proc::start_with_env(
            "tessera-master",
            &args,
            &[("DISPLAY", xvfb.display.as_str())],
        );
        let (x0, y0) = origin.unwrap_or((0, 0));
        for d in 0..3 {
            let title = format!("Tessera display {d}");
            let Some(info) = xvfb.window(&title, LIMIT, || !master.has_exited()) else {
                master.fail(&format!("no window {title:?} on {}", xvfb.display));
            };
            let at = (
                xwininfo_field(&info, "Absolute upper-left X:"),
                xwininfo_field(&info, "Absolute upper-left Y:"),
            );
            assert_eq!(
                at,
                (x0 + 160 * d, y0),
                "origin {origin:?}, {title}:\n{info}"
            );
        }
        master.signal(libc::SIGINT);
        let o = master.wait(LIMIT);
        assert_eq!(o.status.code(), Some(130), "{}", o.stderr);
    }
}

#[test]
fn f1_shows_the_key_help_in_its_window_only_and_z_fits_the_wall() {
    let test = "f1_shows_the_key_help_in_its_window_only_and_z_fits_the_wall";
    let Some(xvfb) = Xvfb::start(test, "800x300", &["xwininfo", "xdotool", "import"]) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    // A fixed camera and no refinement: every frame of the still wall is the same picture.
    let master = Proc::start_with_env(
        "tessera-master",
        &[
            "local",
            "--wall",
            "2x1",
            "--screen",
            "160x90",
            "--window",
            "--frames",
            "0",
            "--refine",
            "off",
            "--eye",
            "0,0,5",
            "--target",
            "0,0,0",
            "--out",
            out.to_str().unwrap(),
        ],
        &[("DISPLAY", xvfb.display.as_str())],
    );
    let connect = control_args(&master, LIMIT);
    let state = || {
        let o = control(&connect, &["state"], LIMIT);
        o.assert_success("state");
        serde_json::from_str::<serde_json::Value>(&o.stdout).expect("state is JSON")
    };
    if !wait_for(LIMIT, || state()["frame"].as_u64().is_some_and(|f| f >= 3)) {
        master.fail("the wall never reached frame 3");
    }

    // What each window shows without help: a snapshot of the wall.
    let snap = control(&connect, &["snapshot"], LIMIT);
    snap.assert_success("snapshot");
    let frame: u64 = snap.stdout.trim().parse().unwrap();
    let saved: Vec<(u32, u32, Vec<u8>)> = (0..2)
        .map(|d| {
            let png = out.join(format!("display-{d}-frame-{frame}.png"));
            assert!(wait_for(LIMIT, || png.exists()), "no {}", png.display());
            load_rgb(&png)
        })
        .collect();
    let shows_frame = |d: usize| {
        let (w, h, rgb) = &saved[d];
        let shot = dir.path().join(format!("frame-{d}.png"));
        let title = format!("Tessera display {d}");
        xvfb.wait_for_window_image(&title, (*w, *h, rgb), &shot, Duration::from_secs(10))
    };
    for d in 0..2 {
        if let Err(last) = shows_frame(d) {
            master.fail(&format!("window {d} is not its saved frame: {last}"));
        }
    }

    let left = xdotool_window(&xvfb, "Tessera display 0");
    xvfb.client("xdotool", &["windowfocus", "--sync", &left]);
    xvfb.client("xdotool", &["key", "F1"]);
    let shot = dir.path().join("help.png");
    let mut last = String::new();
    let helped = wait_for(Duration::from_secs(10), || {
        let Some((w, _, rgb)) = grab(&xvfb, "Tessera display 0", &shot) else {
            return false;
        };
        let (changed, white) = top_left_changes(&rgb, &saved[0].2, w);
        last = format!("{changed} pixels changed, {white} of them white");
        changed > 100 && white > 20
    });
    if !helped {
        master.fail(&format!("F1 showed no help in window 0: {last}"));
    }
    if let Err(last) = shows_frame(1) {
        master.fail(&format!("the help showed in window 1 too: {last}"));
    }
    xvfb.client("xdotool", &["key", "F1"]);
    if let Err(last) = shows_frame(0) {
        master.fail(&format!("F1 again did not hide the help: {last}"));
    }

    // Z in the window fits the scene, as `control fit` does from the same camera.
    let start = state()["camera"].clone();
    xvfb.client("xdotool", &["key", "z"]);
    let mut fitted = serde_json::Value::Null;
    if !wait_for(LIMIT, || {
        fitted = state()["camera"].clone();
        fitted != start
    }) {
        master.fail(&format!("Z never changed the camera: {start}"));
    }
    control(
        &connect,
        &["camera", "--eye", "0,0,5", "--target", "0,0,0"],
        LIMIT,
    )
    .assert_success("camera back");
    assert!(
        wait_for(LIMIT, || state()["camera"] == start),
        "the camera never went back to {start}"
    );
    control(&connect, &["fit"], LIMIT).assert_success("fit");
    let mut by_control = serde_json::Value::Null;
    let same = wait_for(LIMIT, || {
        by_control = state()["camera"].clone();
        by_control == fitted
    });
    assert!(same, "Z gave {fitted}, control fit {by_control}");
    master.signal(libc::SIGINT);
    let o = master.wait(LIMIT);
    assert_eq!(o.status.code(), Some(130), "{}", o.stderr);
}

#[test]
fn the_overlay_shows_the_particles_colour_map_legend_and_follows_the_map() {
    let test = "the_overlay_shows_the_particles_colour_map_legend_and_follows_the_map";
    let Some(xvfb) = Xvfb::start(test, "400x200", &["xwininfo", "xdotool", "import"]) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let mut csv = String::from("x,y,z,radius,attribute\n");
    for i in 0..20 {
        let t = i as f32 / 19.0;
        csv.push_str(&format!(
            "{},0,0,0.15,{}\n",
            (t - 0.5) * 4.0,
            t * 10.0 - 2.0
        ));
    }
    let scene = dir.path().join("dots.csv");
    std::fs::write(&scene, csv).unwrap();
    let master = Proc::start_with_env(
        "tessera-master",
        &[
            "local",
            "--wall",
            "1x1",
            "--screen",
            "240x136",
            "--window",
            "--frames",
            "0",
            "--refine",
            "off",
            "--scene",
            scene.to_str().unwrap(),
            "--eye",
            "0,0,6",
            "--target",
            "0,0,0",
        ],
        &[("DISPLAY", xvfb.display.as_str())],
    );
    let connect = control_args(&master, LIMIT);
    let running = wait_for(LIMIT, || {
        let o = control(&connect, &["state"], LIMIT);
        o.status.success() && o.stdout.contains("\"frame\"")
    });
    assert!(running, "the wall never answered its state");
    let id = xdotool_window(&xvfb, "Tessera display 0");
    xvfb.client("xdotool", &["windowfocus", "--sync", &id]);
    xvfb.client("xdotool", &["key", "o"]);
    // On a 240-pixel screen the legend's bar is 128x8 pixels, 4 from the right edge, under
    // its title's line (display-node/src/legend.rs); the ends are labelled under it.
    let (bar_x, bar_y, bar_w) = (108u32, 14u32, 128u32);
    let shot = dir.path().join("legend.png");
    let shows = |map: ColorMap, last: &mut String| {
        let ends = [map.eval(0.0), map.eval(1.0)]
            .map(|c| encode_srgb_ish(glam::Vec3::from_array(c)).to_vec());
        wait_for(Duration::from_secs(20), || {
            let Some((w, _, rgb)) = grab(&xvfb, "Tessera display 0", &shot) else {
                return false;
            };
            let at = |x: u32, y: u32| {
                let i = ((y * w + x) * 3) as usize;
                rgb[i..i + 3].to_vec()
            };
            let y = bar_y + 4;
            let labels = (bar_y + 9..bar_y + 18)
                .flat_map(|y| (bar_x..bar_x + 24).map(move |x| (x, y)))
                .filter(|&(x, y)| at(x, y) == [255, 255, 255])
                .count();
            *last = format!(
                "bar ends {:?} {:?}, want {ends:?}; {labels} white label pixels",
                at(bar_x, y),
                at(bar_x + bar_w - 1, y)
            );
            [at(bar_x, y), at(bar_x + bar_w - 1, y)] == ends && labels > 5
        })
    };
    let mut last = String::new();
    if !shows(ColorMap::Viridis, &mut last) {
        master.fail(&format!("O showed no viridis legend: {last}"));
    }
    control(&connect, &["colormap", "magma"], LIMIT).assert_success("colormap magma");
    if !shows(ColorMap::Magma, &mut last) {
        master.fail(&format!(
            "the legend did not follow the map to magma: {last}"
        ));
    }
    master.signal(libc::SIGINT);
    let o = master.wait(LIMIT);
    assert_eq!(o.status.code(), Some(130), "{}", o.stderr);
}

/// Grabs the window titled `title` into `shot`: its width, height and RGB bytes, or `None`
/// if the grab failed.
fn grab(xvfb: &Xvfb, title: &str, shot: &Path) -> Option<(u32, u32, Vec<u8>)> {
    let grabbed = Command::new("bash")
        .arg(screenshot_script())
        .args(["grab", title, shot.to_str().unwrap()])
        .env("DISPLAY", &xvfb.display)
        .status()
        .is_ok_and(|s| s.success());
    grabbed.then(|| load_rgb(shot))
}

/// In the top-left 80x40 pixels (where the help's first lines go) of two `width`-wide RGB
/// images: how many pixels differ, and how many of those are white in `shown`.
fn top_left_changes(shown: &[u8], frame: &[u8], width: u32) -> (usize, usize) {
    let (mut changed, mut white) = (0, 0);
    for y in 0..40 {
        for x in 0..80.min(width) {
            let i = ((y * width + x) * 3) as usize;
            let (a, b) = (shown.get(i..i + 3), frame.get(i..i + 3));
            if a != b {
                changed += 1;
                white += usize::from(a == Some(&[255, 255, 255][..]));
            }
        }
    }
    (changed, white)
}

/// xdotool's id of the window titled exactly `title`.
fn xdotool_window(xvfb: &Xvfb, title: &str) -> String {
    xvfb.client("xdotool", &["search", "--name", &format!("^{title}$")])
        .lines()
        .next()
        .expect("xdotool finds the window")
        .to_string()
}
