//! A served wall with a standby master (`serve --standby-of`), its primary SIGKILLed mid-run:
//! the standby takes the wall over, every node (started with `--master PRIMARY,STANDBY`)
//! rejoins it, every display presents again, and the dark time is measured and reported.

use std::path::Path;
use std::time::{Duration, Instant};
use tessera_tests::*;

/// A master of a 2x1 wall of 160x90 that runs until interrupted, on loopback, with `extra`.
fn master(cluster: &Path, out: &Path, extra: &[&str]) -> (Proc, String) {
    let mut args = vec![
        "serve",
        "--listen",
        "127.0.0.1:0",
        "--cluster-dir",
        cluster.to_str().unwrap(),
        "--render-nodes",
        "1",
        "--wall",
        "2x1",
        "--screen",
        "160x90",
        "--frames",
        "0",
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend(extra);
    let master = Proc::start("tessera-master", &args);
    let listening = master.wait_for_stderr("listening on", Duration::from_secs(60));
    let addr = listening
        .rsplit(' ')
        .next()
        .expect("an address")
        .to_string();
    (master, addr)
}

/// The frames each display presented, from the summary a master prints at its run's end.
fn presented_per_display(stderr: &str) -> Vec<u64> {
    stderr
        .lines()
        .filter(|l| l.starts_with("display ") && l.ends_with(" frames presented"))
        .map(|l| {
            let words: Vec<&str> = l.split_whitespace().collect();
            words[words.len() - 3].parse().expect("a count")
        })
        .collect()
}

#[test]
fn a_standby_takes_over_a_wall_whose_primary_was_killed_and_every_display_presents_again() {
    let dir = tempfile::tempdir().unwrap();
    let cluster = dir.path().join("cluster");
    let (out, out_standby) = (dir.path().join("out"), dir.path().join("out-standby"));
    let (primary, primary_addr) = master(&cluster, &out, &["--save-frame", "2"]);
    let (standby, standby_addr) = master(&cluster, &out_standby, &["--standby-of", &primary_addr]);
    primary.wait_for_stderr("standby master at", Duration::from_secs(30));
    let masters = format!("{primary_addr},{standby_addr}");
    let reconnect = ["--reconnect", "--reconnect-timeout", "60"];
    let mut nodes = Vec::new();
    for id in ["0", "1"] {
        let certs = issue_cert(&cluster, &format!("display-{id}"));
        let mut args = vec!["--master", &masters, "--display", id, "--cert-dir", &certs];
        args.extend(["--listen", "127.0.0.1:0", "--out", out.to_str().unwrap()]);
        args.extend(reconnect);
        nodes.push(Proc::start("tessera-display-node", &args));
    }
    let certs = issue_cert(&cluster, "render-0");
    // Without --reconnect: a list of masters is waited for all the same.
    let args = ["--master", &masters, "--cert-dir", &certs, "--threads", "1"];
    nodes.push(Proc::start("tessera-render-node", &args));
    assert!(
        wait_for(Duration::from_secs(60), || out
            .join("display-1.png")
            .exists()),
        "the primary's wall never presented frame 2"
    );
    // SIGKILL: no goodbye to the standby or the nodes; only their clocks tell.
    let killed = Instant::now();
    primary.signal(libc::SIGKILL);
    let primary_end = primary.wait(Duration::from_secs(10));
    assert_eq!(primary_end.status.code(), None, "killed by a signal");
    // The standby's failure bound (the same silence after which nodes leave a master), plus
    // a margin for the nodes to rejoin and the first frame to go round on a busy machine.
    let bound = tessera_net::link::FAILOVER_SILENCE + Duration::from_secs(30);
    let took = standby.wait_for_stderr("took the wall over; dark for", bound);
    let since_kill = killed.elapsed();
    eprintln!("standby: {took} (first frame of the new master {since_kill:?} after the kill)");
    let dark_ms: u64 = took
        .split_whitespace()
        .nth_back(1)
        .and_then(|ms| ms.parse().ok())
        .expect("the dark time in ms");
    assert!(
        u128::from(dark_ms) >= tessera_net::link::FAILOVER_SILENCE.as_millis(),
        "dark for {dark_ms} ms, shorter than the failure bound: the standby did not wait"
    );
    // Ctrl-C: frames in flight finish, the nodes are shut down and send their figures.
    standby.signal(libc::SIGINT);
    let end = standby.wait(Duration::from_secs(60));
    let presented = presented_per_display(&end.stderr);
    assert_eq!(presented.len(), 2, "{}", end.stderr);
    assert!(
        presented.iter().all(|&n| n > 0),
        "a display presented nothing from the new master: {presented:?}\n{}",
        end.stderr
    );
    let report = read_json(&out_standby.join("report.json"));
    let takeovers = report["takeovers"].as_array().expect("takeovers listed");
    assert_eq!(takeovers.len(), 1, "{report}");
    assert_eq!(takeovers[0]["term"], 1, "{report}");
    assert!(takeovers[0]["dark_ms"].as_f64().is_some(), "{report}");
    for node in nodes {
        let o = node.wait(Duration::from_secs(30));
        o.assert_success("a node of the taken-over wall");
    }
}
