//! A display node with --window under Xvfb presents into a real window, and a screenshot of that
//! window equals the display's saved image of the same frame.
//!
//! Needs Xvfb, xwininfo and ImageMagick's `import` (`deploy/xvfb-screenshot.sh install`, which
//! `.ci/run` calls). Where they are missing the test says so and passes only outside CI; in CI
//! (CI=true) a missing tool is a failure.

use std::path::{Path, PathBuf};
use std::time::Duration;
use tessera_tests::xvfb::Xvfb;
use tessera_tests::*;

#[test]
fn window_shows_exactly_the_saved_frame() {
    let Some(xvfb) = Xvfb::start(
        "window_shows_exactly_the_saved_frame",
        "800x600",
        &["xwininfo", "import"],
    ) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("windowed");
    let (master, saved) =
        start_windowed_wall(&xvfb, &["--wall", "1x1", "--screen", "320x180"], &out);
    let (w, h, expected) = load_rgb(&saved);
    assert_eq!((w, h), (320, 180));
    let shot = dir.path().join("shot.png");
    if let Err(last) = xvfb.wait_for_window_image(
        "Tessera display 0",
        (w, h, &expected),
        &shot,
        Duration::from_secs(6),
    ) {
        panic!("screenshot is not display-0.png: {last}");
    }
    let o = master.wait(Duration::from_secs(60));
    o.assert_success("windowed local wall");
}

#[test]
fn a_full_screen_window_covers_its_monitor_with_the_frame_scaled() {
    let test = "a_full_screen_window_covers_its_monitor_with_the_frame_scaled";
    let Some(xvfb) = Xvfb::start(test, "320x200", &["xwininfo", "import"]) else {
        return;
    };
    // A bare X server, no window manager: as on many walls. The window must cover the
    // monitor all the same, the 80x50 frame scaled four times, nearest pixel.
    let dir = tempfile::tempdir().unwrap();
    let wall = dir.path().join("one.toml");
    std::fs::write(
        &wall,
        "columns = 1\nrows = 1\nscreen_width = 80\nscreen_height = 50\n\
         [[window]]\ndisplay = 0\nfullscreen = 0\n",
    )
    .unwrap();
    let out = dir.path().join("out");
    let (master, saved) =
        start_windowed_wall(&xvfb, &["--wall-file", wall.to_str().unwrap()], &out);
    let (_, _, frame) = load_rgb(&saved);
    let scaled: Vec<u8> = (0..200)
        .flat_map(|y| (0..320).map(move |x| ((y / 4) * 80 + x / 4) * 3))
        .flat_map(|i| frame[i..i + 3].to_vec())
        .collect();
    let shot = dir.path().join("shot.png");
    if let Err(last) = xvfb.wait_for_window_image(
        "Tessera display 0",
        (320, 200, &scaled),
        &shot,
        Duration::from_secs(6),
    ) {
        panic!("the full-screen window is not the scaled frame: {last}");
    }
    master
        .wait(Duration::from_secs(60))
        .assert_success("full-screen wall");
}

/// Starts a local wall whose display presents in a window on `xvfb` and saves frame 2 under
/// `out`; returns the master and that saved image, once it exists.
fn start_windowed_wall(xvfb: &Xvfb, wall: &[&str], out: &Path) -> (Proc, PathBuf) {
    let mut args = vec!["local"];
    args.extend(wall);
    args.extend([
        "--frames",
        "3",
        "--save-frame",
        "2",
        "--window",
        "--linger",
        "8",
        "--out",
        out.to_str().unwrap(),
    ]);
    let master = Proc::start_with_env(
        "tessera-master",
        &args,
        &[("DISPLAY", xvfb.display.as_str())],
    );
    let saved = out.join("display-0.png");
    if !wait_for(Duration::from_secs(60), || saved.exists()) {
        master.fail("display never saved frame 2");
    }
    (master, saved)
}
