//! How a local wall's run ends, as its exit status and `report.json` say it: a run that lost a
//! render node and completed exits 0 and names the node (as the log does); a run that did not
//! complete exits 1 and still writes its report, the failure in it; a render node paused long
//! enough to be dropped rejoins the wall instead of exiting.

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

#[test]
fn a_render_node_of_a_local_wall_paused_past_its_deadline_rejoins_the_wall() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let master = local_wall(&out, 3, &["--frames", "100000"]);
    let nodes = children(master.pid(), "render-node");
    assert_eq!(nodes.len(), 3, "{nodes:?}");
    let paused = nodes[0];
    // A hung machine, as SIGSTOP makes one: ten times the 300 ms deadline. The pause is what
    // is tested, not a wait for readiness.
    signal(paused, libc::SIGSTOP);
    master.wait_for_stderr("past the 300 ms deadline", Duration::from_secs(30));
    std::thread::sleep(Duration::from_secs(3));
    signal(paused, libc::SIGCONT);
    master.wait_for_stderr("the master is back; rejoined", Duration::from_secs(30));
    master.wait_for_stderr("joins the running wall", Duration::from_secs(30));
    assert!(
        children(master.pid(), "render-node").contains(&paused),
        "the paused node still runs"
    );
    master.signal(libc::SIGINT);
    let o = master.wait(Duration::from_secs(60));
    assert_eq!(o.status.code(), Some(130), "stderr:\n{}", o.stderr);
    assert!(!o.stderr.contains("exited with"), "{}", o.stderr);
    let report = read_json(&out.join("report.json"));
    assert_eq!(report["render_nodes_lost"], 1, "{report}");
    // Every process sent its figures at the end, the rejoined one under its new id (ids go
    // 0, 1, 2 to the first three joins, 3 to the rejoin); the lost id is gone.
    let lost = report["nodes_lost"][0]["node"].as_str().unwrap();
    let ids: Vec<String> = report["render_nodes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|n| n["id"].to_string())
        .collect();
    assert_eq!(ids.len(), 3, "{report}");
    assert!(ids.contains(&"3".to_string()), "{report}");
    assert!(
        !ids.iter()
            .any(|id| lost.starts_with(&format!("render node {id} ("))),
        "{report}"
    );
    let frames = report["frames"].as_u64().unwrap();
    for d in report["displays"].as_array().unwrap() {
        assert_eq!(d["frames_presented"].as_u64().unwrap(), frames, "{d}");
    }
}
