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
