//! The operator's console API on a running local wall: every route refuses a request without
//! the token, and a bad value with its reason, changing nothing; a converged wall snapshots
//! what it shows (the final quality, pixel for pixel), turns its overlay on and says it is
//! idle, with no camera move; `control` finds the local wall without being told where.

use std::path::Path;
use std::time::Duration;
use tessera_tests::http::{request, ConsoleWall};
use tessera_tests::*;

const LIMIT: Duration = Duration::from_secs(120);
const CAMERA: [&str; 4] = ["--eye", "3,2.5,6", "--target", "0,0.4,0"];

/// Every route of the API: method, path and a body that would be accepted.
const ROUTES: [(&str, &str, &str); 22] = [
    ("GET", "/api/status", ""),
    ("GET", "/api/figures", ""),
    ("GET", "/api/wall.png", ""),
    ("GET", "/api/histogram", ""),
    ("GET", "/api/openapi.json", ""),
    ("GET", "/api/views", ""),
    ("GET", "/api/probe?x=1&y=1", ""),
    ("POST", "/api/input", r#"{"Scroll":{"lines":1}}"#),
    ("POST", "/api/camera", r#"{"fit":true}"#),
    ("POST", "/api/quality", r#"{"spp":2}"#),
    ("POST", "/api/cuts", r#"{"planes":[[1,0,0,0]]}"#),
    ("POST", "/api/lights", r#"{"scene":true}"#),
    ("POST", "/api/volume", r#"{"iso":[30]}"#),
    ("POST", "/api/playback", r#"{"playing":true}"#),
    ("POST", "/api/views/front", ""),
    ("POST", "/api/views/front/go", ""),
    ("POST", "/api/overlay", r#"{"on":true}"#),
    ("POST", "/api/snapshot", r#"{"final":false}"#),
    ("POST", "/api/record", r#"{"on":true}"#),
    ("POST", "/api/replay", r#"{"path":"session.jsonl"}"#),
    ("POST", "/api/particles", r#"{"colormap":"magma"}"#),
    ("GET", "/api/heatmap.png", ""),
];

fn state_id(wall: &ConsoleWall) -> u64 {
    let s = wall.get("/api/status");
    assert_eq!(s.status, 200, "{}", s.text());
    s.json()["state_id"].as_u64().unwrap()
}

#[test]
fn every_route_refuses_without_the_token_and_bad_values_with_the_reason() {
    let dir = tempfile::tempdir().unwrap();
    let volume = write_ramp_volume(dir.path());
    let out = dir.path().join("out");
    let mut args = vec!["--wall", "2x1", "--screen", "160x90", "--frames", "0"];
    args.extend(["--out", out.to_str().unwrap()]);
    args.extend(["--scene", volume.to_str().unwrap(), "--eye", "20,3.5,3.5"]);
    args.extend(["--target", "3.5,3.5,3.5"]);
    let wall = ConsoleWall::start(dir.path(), &args, LIMIT);
    let before = state_id(&wall);

    for (method, path, body) in ROUTES {
        for token in [None, Some("0123456789abcdef0123456789abcdef")] {
            let a = request(&wall.addr, method, path, token, Some(body));
            assert_eq!(
                a.status,
                401,
                "{method} {path} with {token:?}: {}",
                a.text()
            );
            assert!(a.text().contains("token"), "{}", a.text());
        }
    }
    let paths = wall.get("/api/openapi.json").json()["paths"].clone();
    for (_, path, _) in ROUTES {
        let route = path.split('?').next().unwrap().replace("front", "{name}");
        assert!(
            paths.get(&route).is_some(),
            "{route} is not in the OpenAPI document"
        );
    }

    let refused = [
        (
            "/api/quality",
            r#"{"spp":100000}"#,
            422,
            "samples per pixel",
        ),
        ("/api/quality", r#"{"sp":1}"#, 400, "unknown field"),
        ("/api/quality", r#"{}"#, 400, "give --shadows"),
        ("/api/quality", r#"{"spp":"#, 400, "EOF"),
        ("/api/cuts", r#"{"planes":[[0,0,0,1]]}"#, 400, "normal"),
        (
            "/api/camera",
            r#"{"fit":true,"eye":[1,2,3]}"#,
            400,
            "one of",
        ),
        (
            "/api/camera",
            r#"{"eye":[0,0,0],"target":[0,0,0]}"#,
            400,
            "eye",
        ),
        ("/api/volume", r#"{"iso":[1,2,3,4,5]}"#, 400, "iso"),
        (
            "/api/volume",
            r#"{"transfer":{"domain":"Data","points":[{"value":1,"color":[1,1,1],"opacity":2}]}}"#,
            400,
            "opacity",
        ),
        ("/api/volume", r#"{"preset":"sunset"}"#, 400, "presets are"),
        (
            "/api/playback",
            r#"{"playing":true}"#,
            422,
            "not a time series",
        ),
        ("/api/views/a%20b", "", 400, "view name"),
        ("/api/views/never-saved/go", "", 422, "no view named"),
        (
            "/api/input",
            r#"{"Drag":{"button":"Left","dx":1000,"dy":0}}"#,
            400,
            "within",
        ),
        (
            "/api/input",
            r#"{"Click":{"button":"Left","fx":0.5,"fy":0.5}}"#,
            422,
            "probe",
        ),
        (
            "/api/lights",
            r#"{"scene":true,"lights":[]}"#,
            400,
            "either",
        ),
        ("/api/overlay", r#"{"on":"yes"}"#, 400, "on"),
        (
            "/api/record",
            r#"{"on":true,"path":"../escape.jsonl"}"#,
            400,
            "plain name",
        ),
        (
            "/api/replay",
            r#"{"path":"never-recorded.jsonl"}"#,
            400,
            "never-recorded",
        ),
        (
            "/api/particles",
            r#"{"colormap":"magma"}"#,
            422,
            "no particles",
        ),
    ];
    for (path, body, status, words) in refused {
        let a = wall.post(path, body);
        assert_eq!(a.status, status, "{path} {body}: {}", a.text());
        let reason = a.json()["error"].as_str().unwrap_or_default().to_string();
        assert!(
            reason.contains(words),
            "{path} {body}: {reason:?} lacks {words:?}"
        );
    }
    let outside = wall.get("/api/probe?x=5000&y=1");
    assert_eq!(outside.status, 422, "{}", outside.text());
    assert!(outside.text().contains("outside"), "{}", outside.text());
    let huge = format!(r#"{{"planes":[{}]}}"#, vec!["[1,0,0,0]"; 10_000].join(","));
    assert_eq!(
        wall.post("/api/cuts", &huge).status,
        413,
        "a body over the bound"
    );
    assert_eq!(state_id(&wall), before, "nothing refused changed the wall");
    let figures = wall.get("/api/figures").json();
    assert_eq!(figures["changes_applied"], 0, "{figures}");

    // The histogram is the volume's: 512 voxels of 8 values.
    let h = wall.get("/api/histogram").json();
    let counts: u64 = h["counts"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c.as_u64().unwrap())
        .sum();
    assert_eq!(
        (counts, h["range"].clone()),
        (512, serde_json::json!([0.0, 70.0]))
    );
    // A good change is answered with the state it makes and the frame that shows it first.
    let a = wall.post("/api/volume", r#"{"iso":[30]}"#);
    assert_eq!(a.status, 200, "{}", a.text());
    let queued = a.json();
    assert_eq!(queued["state_id"].as_u64(), Some(before + 1), "{queued}");
    assert!(
        wait_for(LIMIT, || state_id(&wall) == before + 1),
        "the change never reached the wall"
    );

    // Recorded from the console, then replayed: the recorded iso-value comes back.
    let rec = wall.post("/api/record", r#"{"on":true,"path":"s.jsonl"}"#);
    assert_eq!(rec.status, 200, "{}", rec.text());
    assert_eq!(wall.post("/api/volume", r#"{"iso":[50]}"#).status, 200);
    let iso = |v: f64| {
        move |w: &ConsoleWall| {
            w.get("/api/status").json()["volume"]["iso"] == serde_json::json!([v])
        }
    };
    assert!(wait_for(LIMIT, || iso(50.0)(&wall)), "iso 50 never queued");
    // A recording holds what frames rendered: stopped once a frame started with iso 50.
    assert!(
        wait_for(LIMIT, || state_id(&wall) == before + 2),
        "iso 50 never reached a frame"
    );
    assert_eq!(wall.post("/api/record", r#"{"on":false}"#).status, 200);
    let recorded = std::fs::read_to_string(out.join("s.jsonl")).unwrap();
    assert!(recorded.contains("50.0"), "{recorded}");
    assert_eq!(wall.post("/api/volume", r#"{"iso":[10]}"#).status, 200);
    assert!(wait_for(LIMIT, || iso(10.0)(&wall)), "iso 10 never applied");
    let replay = wall.post("/api/replay", r#"{"path":"s.jsonl"}"#);
    assert_eq!(replay.status, 200, "{}", replay.text());
    assert!(
        wait_for(LIMIT, || iso(50.0)(&wall)),
        "the replayed session never showed"
    );
    wall.master.signal(libc::SIGINT);
    let o = wall.master.wait(LIMIT);
    assert_eq!(o.status.code(), Some(130), "{}", o.stderr);
}

#[test]
fn a_converged_wall_snapshots_what_it_shows_and_says_it_is_idle() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let mut args = vec!["--wall", "2x1", "--screen", "160x90", "--frames", "0"];
    args.extend(["--refine", "on", "--still-frames", "2", "--final-spp", "4"]);
    args.extend(["--final-ao", "4", "--out", out.to_str().unwrap()]);
    args.extend(CAMERA);
    let wall = ConsoleWall::start(dir.path(), &args, LIMIT);
    wall.master
        .wait_for_stderr("is at the final quality", LIMIT);
    let idle = || wall.get("/api/figures").json()["idle"] == true;
    assert!(
        wait_for(LIMIT, idle),
        "the converged wall never said it was idle"
    );
    // Each render node's running figures come within a second or so.
    let traced = |f: &serde_json::Value| {
        f["render_nodes"].as_array().is_some_and(|nodes| {
            nodes.len() == 2
                && nodes.iter().all(|n| {
                    n["rays"].as_u64().is_some_and(|r| r > 0)
                        && n["peak_mib"].as_f64().is_some_and(|m| m > 1.0)
                })
        })
    };
    assert!(
        wait_for(LIMIT, || traced(&wall.get("/api/figures").json())),
        "render nodes never reported rays and memory: {}",
        wall.get("/api/figures").json()
    );
    let figures = wall.get("/api/figures").json();
    let presented = figures["frames_presented"].as_u64().unwrap();
    assert!(
        figures["fps"].as_f64().unwrap() >= 1.0,
        "the rest is not counted: {figures}"
    );

    // The snapshot is of the frame on the displays now: nothing else renders.
    let snap = wall.post("/api/snapshot", r#"{"final":false}"#);
    assert_eq!(snap.status, 200, "{}", snap.text());
    let snap = snap.json();
    assert_eq!(snap["shown"], true, "{snap}");
    let frame = snap["frame"].as_u64().unwrap();
    assert_eq!(frame, presented - 1, "{snap}");
    let wall_png = out.join(format!("wall-frame-{frame}.png"));
    let files: Vec<&str> = snap["files"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f.as_str().unwrap())
        .collect();
    assert!(files.contains(&wall_png.to_str().unwrap()), "{snap}");
    assert!(wall_png.exists(), "the wall's image is there at once");

    // The overlay and the CLI work on the still wall too; still nothing renders.
    assert_eq!(wall.post("/api/overlay", r#"{"on":true}"#).status, 200);
    assert_eq!(wall.get("/api/status").json()["overlay"], true);
    let cli = Proc::start_with_env(
        "tessera-master",
        &["control", "snapshot"],
        &[("TESSERA_STATE_DIR", wall.state_dir.to_str().unwrap())],
    )
    .wait(LIMIT);
    cli.assert_success("control snapshot, found through the state folder");
    assert_eq!(cli.stdout.trim(), frame.to_string(), "{}", cli.stderr);
    assert!(cli.stderr.contains("as shown"), "{}", cli.stderr);
    let later = wall.get("/api/figures").json();
    assert_eq!(
        later["frames_presented"].as_u64(),
        Some(presented),
        "{later}"
    );

    let picture = wall.get("/api/wall.png");
    assert_eq!(picture.status, 200);
    assert!(picture.body.starts_with(b"\x89PNG"), "a PNG");
    // The heatmap paints every tile in its render node's colour: none is left black.
    let heat = wall.get("/api/heatmap.png");
    assert_eq!(heat.status, 200, "{}", heat.text());
    let heat = image::load_from_memory(&heat.body)
        .expect("a PNG")
        .to_rgb8();
    let black = heat.pixels().filter(|p| p.0 == [0, 0, 0]).count();
    assert_eq!(black, 0, "tiles no render node rendered");
    wall.master.signal(libc::SIGINT);
    let o = wall.master.wait(LIMIT);
    assert_eq!(o.status.code(), Some(130), "{}", o.stderr);
    // Put together when taken (once for each of the two snapshots), not again at the end.
    let (during, after) = o.stderr.split_once("interrupted").expect("interrupted");
    assert_eq!(during.matches("wrote").count(), 2, "{}", o.stderr);
    assert!(!after.contains("wall-frame"), "{}", o.stderr);

    let reference = dir.path().join("reference");
    // Samples are seeded by the frame number: the reference renders the same frame.
    let frame_arg = frame.to_string();
    let mut args = vec![
        "render", "--wall", "2x1", "--screen", "160x90", "--spp", "4", "--ao", "4", "--frame",
    ];
    args.extend([frame_arg.as_str(), "--out"]);
    args.push(reference.to_str().unwrap());
    args.extend(CAMERA);
    run("tessera-master", &args, LIMIT).assert_success("reference at the final quality");
    assert_same_pixels(
        &wall_png,
        &reference.join("wall.png"),
        "the still wall's snapshot",
    );
}

#[test]
fn a_served_console_speaks_https_and_admits_a_control_certificate_without_the_token() {
    use tessera_tests::http::request_tls;
    let dir = tempfile::tempdir().unwrap();
    let cluster = dir.path().join("cluster");
    let control = issue_cert(&cluster, "control-1");
    let render = issue_cert(&cluster, "render-1");
    let mut args = vec![
        "serve",
        "--listen",
        "127.0.0.1:0",
        "--console",
        "127.0.0.1:0",
    ];
    args.extend(["--cluster-dir", cluster.to_str().unwrap(), "--frames", "0"]);
    args.extend(["--wall", "1x1", "--screen", "64x64"]);
    let master = Proc::start("tessera-master", &args);
    let line = master.wait_for_stderr("console at https://", LIMIT);
    let url = line
        .split_whitespace()
        .find(|w| w.starts_with("https://"))
        .unwrap();
    let addr = url
        .trim_start_matches("https://")
        .split('/')
        .next()
        .unwrap();
    let token = url.split("token=").nth(1).unwrap();
    let (control, render) = (Path::new(&control), Path::new(&render));
    let status = |cert: &Path, present: bool, token: Option<&str>| {
        request_tls(addr, cert, present, "/api/status", token).status
    };
    assert_eq!(
        status(render, false, None),
        401,
        "a browser without the token"
    );
    assert_eq!(status(render, false, Some(token)), 200, "a browser with it");
    assert_eq!(status(control, true, None), 200, "a control certificate");
    assert_eq!(
        status(render, true, None),
        401,
        "a render node's certificate"
    );
    master.signal(libc::SIGINT);
    let _ = master.wait(LIMIT);
}

#[test]
fn particles_take_the_colour_map_chosen_and_the_wall_shows_it() {
    let dir = tempfile::tempdir().unwrap();
    let mut csv = String::from("x,y,z,radius,attribute\n");
    for i in 0..40 {
        let t = i as f32 / 39.0;
        csv.push_str(&format!(
            "{},{},0,0.12,{t}\n",
            (t - 0.5) * 4.0,
            (t * 9.0).sin() * 0.5
        ));
    }
    let scene = dir.path().join("dots.csv");
    std::fs::write(&scene, csv).unwrap();
    let out = dir.path().join("out");
    let mut args = vec!["--wall", "2x1", "--screen", "160x90", "--frames", "0"];
    args.extend([
        "--scene",
        scene.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    args.extend(["--eye", "0,0,6", "--target", "0,0,0", "--refine", "off"]);
    let wall = ConsoleWall::start(dir.path(), &args, LIMIT);
    let status = wall.get("/api/status").json();
    assert_eq!(status["particles"]["colormap"], "viridis", "{status}");
    assert_eq!(
        status["volume"],
        serde_json::Value::Null,
        "no volume, no volume settings"
    );
    let shot = |wall: &ConsoleWall| {
        let snap = wall.post("/api/snapshot", r#"{"final":false}"#).json();
        load_rgb(&out.join(format!("wall-frame-{}.png", snap["frame"]))).2
    };
    let viridis = shot(&wall);
    let bad = wall.post("/api/particles", r#"{"colormap":"rainbow"}"#);
    assert_eq!(bad.status, 400, "{}", bad.text());
    assert!(bad.text().contains("viridis, magma"), "{}", bad.text());
    let a = wall.post("/api/particles", r#"{"colormap":"magma"}"#);
    assert_eq!(a.status, 200, "{}", a.text());
    let id = a.json()["state_id"].as_u64().unwrap();
    assert!(
        wait_for(LIMIT, || state_id(&wall) >= id),
        "the colour map never reached a frame"
    );
    assert_eq!(
        wall.get("/api/status").json()["particles"]["colormap"],
        "magma"
    );
    assert_ne!(shot(&wall), viridis, "the wall shows the new colours");
    wall.master.signal(libc::SIGINT);
    let o = wall.master.wait(LIMIT);
    assert_eq!(o.status.code(), Some(130), "{}", o.stderr);
}
