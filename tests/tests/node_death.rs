//! A render node killed in the middle of a local wall's run: the wall goes on, and its stall
//! is bounded by the master's node deadline, not by the network's ten-second idle timeout.

use std::time::Duration;
use tessera_tests::*;

/// The render nodes `parent` started: its children whose command line runs `render-node`.
fn render_children(parent: u32) -> Vec<u32> {
    let mut found = Vec::new();
    for entry in std::fs::read_dir("/proc").into_iter().flatten().flatten() {
        let Ok(pid) = entry.file_name().to_string_lossy().parse::<u32>() else {
            continue;
        };
        let Ok(stat) = std::fs::read_to_string(entry.path().join("stat")) else {
            continue;
        };
        // The fields after the command name, which may hold spaces and parentheses.
        let after = stat.rsplit_once(") ").map_or("", |(_, rest)| rest);
        let ppid: Option<u32> = after.split_whitespace().nth(1).and_then(|p| p.parse().ok());
        let cmdline = std::fs::read(entry.path().join("cmdline")).unwrap_or_default();
        let runs_render_node = String::from_utf8_lossy(&cmdline)
            .split('\0')
            .any(|arg| arg == "render-node");
        if ppid == Some(parent) && runs_render_node {
            found.push(pid);
        }
    }
    found
}

#[test]
fn a_killed_render_node_stalls_the_wall_for_no_longer_than_its_deadline() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let deadline_ms = 300;
    let master = Proc::start(
        "tessera-master",
        &[
            "local",
            "--wall",
            "2x1",
            "--screen",
            "160x90",
            "--render-nodes",
            "3",
            "--threads",
            "1",
            "--node-deadline-ms",
            &deadline_ms.to_string(),
            "--frames",
            "100000",
            "--save-frame",
            "3",
            "--out",
            out.to_str().unwrap(),
        ],
    );
    assert!(
        wait_for(Duration::from_secs(90), || out
            .join("display-1.png")
            .exists()
            || master.has_exited()),
        "the wall never presented frame 3"
    );
    let nodes = render_children(master.pid());
    assert_eq!(
        nodes.len(),
        3,
        "render nodes of {}: {nodes:?}",
        master.pid()
    );
    // SIGKILL: no goodbye on the connection, so only the master's own clock can notice.
    unsafe { libc::kill(nodes[1] as i32, libc::SIGKILL) };
    master.wait_for_stderr(
        "its tiles go to the other render nodes",
        Duration::from_secs(60),
    );
    master.signal(libc::SIGINT);
    let o = master.wait(Duration::from_secs(60));
    assert!(
        o.stderr
            .contains(&format!("past the {deadline_ms} ms deadline")),
        "the master's clock, not the transport, noticed the death:\n{}",
        o.stderr
    );
    let report = read_json(&out.join("report.json"));
    assert_eq!(report["render_nodes_lost"], 1, "{report}");
    let frames = report["frames"].as_u64().unwrap();
    for d in report["displays"].as_array().unwrap() {
        assert_eq!(d["frames_presented"].as_u64().unwrap(), frames, "{d}");
    }
    // The longest frame: at most the deadline plus a generous allowance for a debug build on
    // a shared machine. The transport alone would have stalled it ten seconds.
    let longest = report["frame_ms"]["max"].as_f64().unwrap();
    eprintln!(
        "killed render node: longest frame {longest:.0} ms (median {:.0} ms), {} tiles speculated",
        report["frame_ms"]["p50"].as_f64().unwrap(),
        report["tiles_speculated"]
    );
    assert!(
        longest < (deadline_ms + 2_000) as f64,
        "the wall froze for {longest} ms"
    );
}
