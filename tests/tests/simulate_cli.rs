//! `tessera-master simulate`: the simulated wall finishes every frame under loss and a node
//! death, writes its figures, and refuses impossible flags with a reason.

use std::time::Duration;
use tessera_tests::{read_json, run};

const LIMIT: Duration = Duration::from_secs(120);

#[test]
fn simulated_wall_completes_every_frame_under_loss_and_a_death_and_writes_its_report() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("sim");
    let out_arg = out.display().to_string();
    let args = [
        "simulate",
        "--render-nodes",
        "64",
        "--displays",
        "8",
        "--frames",
        "20",
        "--loss",
        "0.02",
        "--kill",
        "3@5",
        "--out",
        &out_arg,
    ];
    let o = run("tessera-master", &args, LIMIT);
    o.assert_success("tessera-master simulate");
    assert!(o.stdout.contains("balance efficiency"), "{}", o.stdout);
    let report = read_json(&out.join("report.json"));
    assert_eq!(report["frames_completed"], 20, "{report}");
    assert_eq!(report["frames_requested"], 20);
    assert_eq!(report["render_nodes"], 64);
    assert_eq!(report["render_nodes_killed"], 1);
    assert_eq!(report["displays"], 8);
    assert_eq!(report["corrupt_frames"], 0);
    let efficiency = report["efficiency"]
        .as_f64()
        .expect("efficiency is a number");
    assert!(efficiency > 0.0 && efficiency <= 1.0, "{efficiency}");
    assert!(
        report["retransmissions"].as_u64().unwrap() > 0,
        "2 % loss cost no retransmission: {report}"
    );

    // The same seed replays the same run.
    let again = dir.path().join("again");
    let again_arg = again.display().to_string();
    let mut args2 = args;
    args2[args2.len() - 1] = &again_arg;
    run("tessera-master", &args2, LIMIT).assert_success("second run");
    let replay = read_json(&again.join("report.json"));
    for field in ["efficiency", "elapsed_s", "messages", "retransmissions"] {
        assert_eq!(report[field], replay[field], "{field}");
    }
}

#[test]
fn impossible_kills_and_losses_are_refused_with_the_reason() {
    let cases: [(&[&str], &str); 6] = [
        (&["--kill", "64@1"], "no render node 64"),
        (&["--kill", "3"], "N@F"),
        (&["--kill", "3@99"], "frame 99"),
        (&["--kill", "1@1", "--kill", "1@2"], "killed twice"),
        (&["--loss", "1.5"], "[0, 1)"),
        (&["--loss", "lots"], "not a number"),
    ];
    for (extra, why) in cases {
        let mut args = vec!["simulate", "--render-nodes", "64", "--frames", "20"];
        args.extend_from_slice(extra);
        let o = run("tessera-master", &args, LIMIT);
        assert!(!o.status.success(), "{extra:?} was accepted");
        assert!(
            o.stderr.contains(why),
            "{extra:?}: expected `{why}` in\n{}",
            o.stderr
        );
    }
}

#[test]
fn the_reality_deck_runs_with_two_thousand_render_nodes() {
    // 416 screens of 2560x1440 in a ring, 1.5 gigapixels: refused before walls of screens,
    // whose one virtual image would be a million pixels wide.
    let wall =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/walls/reality-deck.toml");
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("sim");
    let args = [
        "simulate",
        "--wall-file",
        wall.to_str().unwrap(),
        "--render-nodes",
        "2048",
        "--frames",
        "2",
        "--out",
        out.to_str().unwrap(),
    ];
    let o = run("tessera-master", &args, Duration::from_secs(300));
    o.assert_success("the Reality Deck");
    assert!(o.stdout.contains("1.53 gigapixels"), "{}", o.stdout);
    let report = read_json(&out.join("report.json"));
    assert_eq!(report["displays"], 416, "{report}");
    assert_eq!(report["frames_completed"], 2, "{report}");
    assert_eq!(report["corrupt_frames"], 0);
    eprintln!(
        "Reality Deck, 2,048 render nodes: efficiency {:.4}, {} tiles a frame",
        report["efficiency"], report["tiles_per_frame"]
    );
    // The same screens as the grid shorthand: too wide for one image, laid out as screens.
    let o = run(
        "tessera-master",
        &[
            "simulate",
            "--displays",
            "416",
            "--screen",
            "2560x1440",
            "--render-nodes",
            "64",
            "--frames",
            "1",
        ],
        Duration::from_secs(300),
    );
    o.assert_success("416 displays from the shorthand");
}

#[test]
fn simulate_shows_progress_on_stderr_when_it_is_not_a_terminal() {
    let args = [
        "simulate",
        "--render-nodes",
        "64",
        "--displays",
        "8",
        "--frames",
        "20",
    ];
    let o = run("tessera-master", &args, LIMIT);
    o.assert_success("tessera-master simulate");
    let percents: Vec<u64> = o
        .stderr
        .lines()
        .filter_map(|l| {
            l.strip_prefix("simulate: ")?
                .split_once("frames presented (")?
                .1
                .split(' ')
                .next()?
                .parse()
                .ok()
        })
        .collect();
    assert!(percents.len() >= 3, "too few progress lines:\n{}", o.stderr);
    assert!(
        percents.windows(2).all(|w| w[0] <= w[1]),
        "progress went back:\n{}",
        o.stderr
    );
}
