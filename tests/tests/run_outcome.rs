//! How a local wall's run ends, as its exit status and `report.json` say it: a run that lost a
//! render node and completed exits 0 and names the node (as the log does); a run that did not
//! complete exits 1 and still writes its report, the failure in it; pauses of the master, a
//! display and render nodes (SIGSTOP, up to 3 s) drop nobody and lose no frame.

use std::time::Duration;
use tessera_tests::*;

/// A local 2x1 wall of 96x64 screens with `render_nodes` one-thread render nodes, the flags
/// `rest`, writing into `out`; returned once display 1 has saved frame 2 (an event to wait
/// for, not a time to guess), still running.
fn local_wall(out: &std::path::Path, render_nodes: u32, rest: &[&str]) -> Proc {
    let nodes = render_nodes.to_string();
    let mut args = vec![
        "local",
        "--wall",
        "2x1",
        "--screen",
        "96x64",
        "--render-nodes",
        &nodes,
        "--threads",
        "1",
        "--save-frame",
        "2",
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend(rest);
    let master = Proc::start("tessera-master", &args);
    let saved = out.join("display-1.png");
    let flowing = wait_for(Duration::from_secs(90), || {
        saved.exists() || master.has_exited()
    });
    if !flowing || master.has_exited() {
        master.fail("the wall never presented frame 2, or ended before the test could act");
    }
    master
}

/// The pid of the child of `master` that runs display `id`.
fn display_child(master: &Proc, id: u32) -> u32 {
    let id = id.to_string();
    tessera_cli::procs::children_of(master.pid())
        .into_iter()
        .find(|c| c.runs("display-node") && c.args.windows(2).any(|w| w == ["--display", &id]))
        .map(|c| c.pid)
        .expect("the display runs")
}

/// Sends `sig` to `pid`, a node process of a wall this test started, still running.
fn signal(pid: u32, sig: i32) {
    // SAFETY: kill only sends a signal and touches no memory; the pid is a node process of
    // the wall this test started, not yet reaped by its master.
    unsafe { libc::kill(pid as i32, sig) };
}

#[test]
fn a_run_that_loses_a_render_node_and_completes_exits_0_naming_it_as_the_log_does() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let master = local_wall(&out, 3, &["--frames", "300"]);
    let nodes = children(master.pid(), "render-node");
    assert_eq!(nodes.len(), 3, "{nodes:?}");
    signal(nodes[1], libc::SIGKILL);
    let o = master.wait(Duration::from_secs(120));
    assert_eq!(o.status.code(), Some(0), "stderr:\n{}", o.stderr);
    let report = read_json(&out.join("report.json"));
    assert_eq!(report["outcome"]["completed"], true, "{report}");
    assert_eq!(report["outcome"]["exit_status"], 0, "{report}");
    assert_eq!(report["frames"], 300, "{report}");
    assert_eq!(report["render_nodes_lost"], 1, "{report}");
    // The report names the node as the master's log does, and the launcher's line about the
    // killed process names the same node.
    let lost = report["nodes_lost"][0]["node"]
        .as_str()
        .expect("a node named");
    let id = lost
        .strip_prefix("render node ")
        .and_then(|rest| rest.split(' ').next())
        .unwrap_or_else(|| panic!("{lost}"));
    let killed = format!("render node {id} (pid {}) exited with signal 9", nodes[1]);
    assert!(
        o.stderr.contains(&killed),
        "no {killed:?} in:\n{}",
        o.stderr
    );
    assert_eq!(report["outcome"]["processes_failed"][0], killed, "{report}");
    assert!(
        o.stderr.contains(&format!("{lost} disconnected")),
        "{}",
        o.stderr
    );
}

#[test]
fn a_run_that_does_not_complete_exits_1_and_still_writes_its_report_with_the_failure() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    // A lost display is waited for at most the join timeout; this one never comes back.
    let wait = [
        "--frames",
        "100000",
        "--display-loss",
        "wait",
        "--join-timeout",
        "5",
    ];
    let master = local_wall(&out, 2, &wait);
    let display = display_child(&master, 1);
    signal(display, libc::SIGKILL);
    let o = master.wait(Duration::from_secs(60));
    assert_eq!(o.status.code(), Some(1), "stderr:\n{}", o.stderr);
    assert!(o.stderr.contains("display 1 was not back"), "{}", o.stderr);
    let report = read_json(&out.join("report.json"));
    let outcome = &report["outcome"];
    assert_eq!(outcome["completed"], false, "{report}");
    assert_eq!(outcome["exit_status"], 1, "{report}");
    let error = outcome["error"].as_str().expect("the failure");
    assert!(error.contains("display 1 was not back"), "{error}");
    // Whatever figures it had: display 1 saved frame 2, so three frames were presented.
    assert!(report["frames"].as_u64().unwrap() >= 3, "{report}");
    assert_eq!(report["displays_lost"], 1, "{report}");
    let lost = report["nodes_lost"][0]["node"].as_str().unwrap();
    assert!(lost.starts_with("display 1 ("), "{report}");
    assert_eq!(
        outcome["processes_failed"],
        serde_json::json!([format!("display 1 (pid {display}) exited with signal 9")]),
        "the other nodes left when the run was over: {report}"
    );
}

/// Stops `pid` for `pause`, then lets it go on: what a busy machine does to a process, made
/// repeatable. The pause is what is tested, not a wait for anything.
fn pause(pid: u32, pause: Duration) {
    signal(pid, libc::SIGSTOP);
    std::thread::sleep(pause);
    signal(pid, libc::SIGCONT);
}

#[test]
fn pauses_of_the_master_a_display_and_a_render_node_drop_nobody_and_lose_no_frame() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let master = local_wall(&out, 3, &["--frames", "100000"]);
    let renders = children(master.pid(), "render-node");
    assert_eq!(renders.len(), 3, "{renders:?}");
    let display = display_child(&master, 1);
    let short = Duration::from_millis(600);
    // Between pauses, frames flow again for a moment: a window, not a readiness wait.
    let flow = Duration::from_millis(700);
    for (who, pid, length) in [
        ("the master", master.pid(), short),
        ("display 1", display, short),
        ("a render node", renders[0], short),
        ("the master", master.pid(), Duration::from_secs(1)),
        ("the master", master.pid(), Duration::from_secs(3)),
        ("a render node", renders[1], Duration::from_secs(3)),
    ] {
        eprintln!("pausing {who} for {length:?}");
        pause(pid, length);
        std::thread::sleep(flow);
    }
    master.wait_for_stderr("is back after", Duration::from_secs(30));
    master.signal(libc::SIGINT);
    let o = master.wait(Duration::from_secs(60));
    assert_eq!(o.status.code(), Some(130), "stderr:\n{}", o.stderr);
    assert!(!o.stderr.contains("exited with"), "{}", o.stderr);
    assert!(!o.stderr.contains("disconnected"), "{}", o.stderr);
    let report = read_json(&out.join("report.json"));
    assert_eq!(report["render_nodes_lost"], 0, "{report}");
    assert_eq!(report["displays_lost"], 0, "{report}");
    let ids: Vec<u64> = report["render_nodes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|n| n["id"].as_u64().unwrap())
        .collect();
    assert_eq!(
        ids,
        [0, 1, 2],
        "nobody rejoined: nobody was dropped; {report}"
    );
    let frames = report["frames"].as_u64().unwrap();
    for d in report["displays"].as_array().unwrap() {
        assert_eq!(d["frames_presented"].as_u64().unwrap(), frames, "{d}");
    }
    // The master's own pauses were seen as such: at least the 3 s one.
    let longest = report["longest_master_pause_ms"].as_f64().unwrap();
    assert!(longest >= 2_500.0, "{report}");
    eprintln!(
        "{frames} frames; {} suspicions, {} master pauses (longest {longest:.0} ms)",
        report["nodes_suspected"], report["master_pauses"]
    );
}
