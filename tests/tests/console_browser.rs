//! The operator's console in a real browser (Debian's chromium, headless, driven by
//! chromedriver): a drag on the wall's picture turns the camera and the displays show it;
//! an edited transfer function changes the look on the wall; a series is paused and stepped;
//! a final snapshot of the still wall equals the replayed session's frame, pixel for pixel.
//! A screenshot of the page is kept as a CI artifact (`target/ci-artifacts/console.png`).

use serde_json::Value;
use std::path::PathBuf;
use std::time::Duration;
use tessera_tests::http::ConsoleWall;
use tessera_tests::webdriver::Browser;
use tessera_tests::*;

const LIMIT: Duration = Duration::from_secs(120);
const WALL: [&str; 4] = ["--wall", "2x1", "--screen", "160x90"];

/// Where CI keeps what a person would look at: `$TESSERA_ARTIFACTS`, or `target/ci-artifacts`.
fn artifacts() -> PathBuf {
    std::env::var_os("TESSERA_ARTIFACTS").map_or_else(
        || {
            bin("tessera-master")
                .parent()
                .unwrap()
                .parent()
                .unwrap()
                .join("ci-artifacts")
        },
        PathBuf::from,
    )
}

fn status(wall: &ConsoleWall) -> Value {
    wall.get("/api/status").json()
}

/// Waits (bounded) until the page's own status satisfies `check`.
fn page_shows(browser: &Browser, what: &str, check: impl Fn(&Value) -> bool) {
    let mut last = Value::Null;
    let seen = wait_for(LIMIT, || {
        last = browser.eval("return window.tessera ? window.tessera.status() : null");
        check(&last)
    });
    assert!(seen, "the page never showed {what}; its status: {last}");
}

#[test]
fn a_browser_steers_the_wall_edits_its_look_steps_its_series_and_snapshots_it() {
    let test = "a_browser_steers_the_wall_edits_its_look_steps_its_series_and_snapshots_it";
    let install = "apt-get install chromium chromium-driver";
    if require_tools(test, &["chromium", "chromedriver"], install).is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let scene = write_ball_series(dir.path(), 16);
    let (out, record) = (dir.path().join("out"), dir.path().join("session.jsonl"));
    let mut args = WALL.to_vec();
    args.extend([
        "--scene",
        scene.to_str().unwrap(),
        "--frames",
        "0",
        "--play",
    ]);
    args.extend([
        "--eye",
        "30,7.5,7.5",
        "--target",
        "7.5,7.5,7.5",
        "--refine",
        "on",
    ]);
    args.extend([
        "--out",
        out.to_str().unwrap(),
        "--record",
        record.to_str().unwrap(),
    ]);
    let wall = ConsoleWall::start(dir.path(), &args, LIMIT);
    let browser = Browser::start(&dir.path().join("profile"), LIMIT).expect("tools found");
    browser.open(&wall.url);
    page_shows(&browser, "the wall", |s| s["frame"].as_u64().is_some());

    // Pause, then step: the page and the wall agree on the step shown.
    browser.click("[data-test=pause]");
    page_shows(&browser, "the series paused", |s| {
        s["volume"]["playing"] == false
    });
    let step = status(&wall)["volume"]["time_step"].as_u64().unwrap();
    browser.click("[data-test=step-forward]");
    let next = (step + 1) % 3;
    page_shows(&browser, "the next step", |s| {
        s["volume"]["time_step"] == next
    });
    let shown =
        browser.eval("return document.querySelector('[data-test=current-step]').textContent");
    assert!(
        shown
            .as_str()
            .unwrap()
            .contains(&format!("{} of 3", next + 1)),
        "{shown}"
    );

    // A drag on the picture turns the camera: a new state, and the displays show new frames.
    let before = status(&wall);
    let picture_before = wall.get("/api/wall.png").body;
    browser.drag("[data-test=wall-picture]", 120, 0, 6);
    let id = before["state_id"].as_u64().unwrap();
    page_shows(&browser, "a new state after the drag", |s| {
        s["state_id"].as_u64().is_some_and(|s| s > id)
            && s["camera"]["eye"] != before["camera"]["eye"]
    });
    assert!(
        wait_for(LIMIT, || wall.get("/api/wall.png").body != picture_before),
        "the wall's picture never changed after the drag"
    );

    // An edited transfer function: the point selected made opaque, applied, seen on the wall.
    let picture_before = wall.get("/api/wall.png").body;
    browser.type_into("#tf-opacity", "0.9");
    browser.click("[data-test=tf-apply]");
    page_shows(&browser, "the edited transfer function", |s| {
        s["volume"]["transfer"]["points"]
            .as_array()
            .is_some_and(|p| {
                p.iter().any(|p| {
                    p["opacity"]
                        .as_f64()
                        .is_some_and(|o| (o - 0.9).abs() < 1e-6)
                })
            })
    });
    assert!(
        wait_for(LIMIT, || wall.get("/api/wall.png").body != picture_before),
        "the new look never reached the wall's picture"
    );

    // A final snapshot of the still wall: the replayed session's frame, pixel for pixel.
    browser.click("[data-test=snapshot-final]");
    let mut files = Value::Null;
    assert!(
        wait_for(LIMIT, || {
            files = browser
                .eval("return document.querySelector('[data-test=snapshot-files]').textContent");
            files.as_str().is_some_and(|f| f.contains("wall-frame-"))
        }),
        "the page never listed the snapshot's files: {files}"
    );
    browser.screenshot(&artifacts().join("console.png"));
    let text = files.as_str().unwrap();
    let name = text
        .split(['/', ' ', '\n'])
        .find(|w| w.starts_with("wall-frame-"))
        .unwrap();
    let frame: u64 = name
        .trim_start_matches("wall-frame-")
        .trim_end_matches(".png")
        .parse()
        .unwrap();
    drop(browser);
    wall.master.signal(libc::SIGINT);
    let o = wall.master.wait(LIMIT);
    assert_eq!(o.status.code(), Some(130), "{}", o.stderr);
    let mut render_wall = WALL.to_vec();
    render_wall.extend(["--scene", scene.to_str().unwrap()]);
    let shown = out.join(format!("wall-frame-{frame}.png"));
    assert_shows_replayed_frame(&render_wall, &record, frame, &shown, dir.path());
}
