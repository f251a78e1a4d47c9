//! A served wall with a standby master (`serve --standby-of`). Its primary SIGKILLed mid-run:
//! the standby takes the wall over, every node (started with `--master PRIMARY,STANDBY`)
//! rejoins it, every display presents again, and the dark time is measured and reported; the
//! run's report and session record go on in the standby's. A standby cut off from a live
//! primary takes over without a wall and does no harm; a stopped primary that comes back
//! after a takeover ends its run; a chain of standbys outlives two masters.
//! `failover_dark_time_p95_over_repeated_kills` (ignored) measures the dark time over kills.

use std::path::Path;
use std::time::{Duration, Instant};
use tessera_tests::*;

/// A master of a 2x1 wall of 160x90 that runs until interrupted, on loopback, with `extra`.
fn master(cluster: &Path, out: &Path, extra: &[&str]) -> (Proc, String) {
    master_on(cluster, out, "127.0.0.1:0", extra)
}

/// As [`master`], listening on `listen`.
fn master_on(cluster: &Path, out: &Path, listen: &str, extra: &[&str]) -> (Proc, String) {
    let mut args = vec![
        "serve",
        "--listen",
        listen,
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

/// The wall's nodes, two displays and a render node, each given the list `masters`; the
/// displays write their files to `out`.
fn nodes(cluster: &Path, out: &Path, masters: &str) -> Vec<Proc> {
    let reconnect = ["--reconnect", "--reconnect-timeout", "60"];
    let mut nodes = Vec::new();
    for id in ["0", "1"] {
        let certs = issue_cert(cluster, &format!("display-{id}"));
        let mut args = vec!["--master", masters, "--display", id, "--cert-dir", &certs];
        args.extend(["--listen", "127.0.0.1:0", "--out", out.to_str().unwrap()]);
        args.extend(reconnect);
        nodes.push(Proc::start("tessera-display-node", &args));
    }
    let certs = issue_cert(cluster, "render-0");
    // Without --reconnect: a list of masters is waited for all the same.
    let args = ["--master", masters, "--cert-dir", &certs, "--threads", "1"];
    nodes.push(Proc::start("tessera-render-node", &args));
    nodes
}

/// SIGKILLs `master` (no goodbye to its standby or its nodes: only their clocks tell) and
/// reaps it.
fn kill(master: Proc) -> Instant {
    let killed = Instant::now();
    master.signal(libc::SIGKILL);
    let end = master.wait(Duration::from_secs(10));
    assert_eq!(end.status.code(), None, "killed by a signal");
    killed
}

/// Waits for `standby`'s first presented frame after its takeover; its dark time in ms, as
/// the standby measured it (from the primary's last word to the first frame presented).
fn dark_ms(standby: &Proc) -> u64 {
    // The failure bound, plus a margin for the nodes to rejoin and the first frame to go
    // round on a busy machine.
    let bound = tessera_net::link::FAILOVER_SILENCE + Duration::from_secs(30);
    let took = standby.wait_for_stderr("took the wall over; dark for", bound);
    let dark: u64 = took
        .split_whitespace()
        .nth_back(1)
        .and_then(|ms| ms.parse().ok())
        .expect("the dark time in ms");
    assert!(
        u128::from(dark) >= tessera_net::link::FAILOVER_SILENCE.as_millis(),
        "dark for {dark} ms, shorter than the failure bound: the standby did not wait"
    );
    dark
}

/// A UDP port free now, for a master whose address the nodes must know before it starts.
fn free_udp_port() -> u16 {
    std::net::UdpSocket::bind("127.0.0.1:0")
        .and_then(|s| s.local_addr())
        .map(|a| a.port())
        .expect("a free port")
}

/// Stops `master` with Ctrl-C (frames in flight finish, the nodes are shut down and send their
/// figures); its stderr.
fn interrupt(master: Proc) -> String {
    master.signal(libc::SIGINT);
    master.wait(Duration::from_secs(60)).stderr
}

/// Reaps the nodes of a wall whose master ended its run, each of which must exit well.
fn reap_nodes(nodes: Vec<Proc>) -> Vec<String> {
    nodes
        .into_iter()
        .map(|node| {
            let o = node.wait(Duration::from_secs(30));
            o.assert_success("a node of the wall");
            o.stderr
        })
        .collect()
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

/// The lines of a session record, each a JSON object.
fn record_lines(path: &Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{l}: {e}")))
        .collect()
}

#[test]
fn a_standby_takes_over_a_wall_whose_primary_was_killed_and_every_display_presents_again() {
    let dir = tempfile::tempdir().unwrap();
    let cluster = dir.path().join("cluster");
    let (out, out_standby) = (dir.path().join("out"), dir.path().join("out-standby"));
    let (record, record_standby) = (dir.path().join("p.jsonl"), dir.path().join("s.jsonl"));
    let rec = |p: &Path| p.to_str().unwrap().to_string();
    let (primary, primary_addr) = master(
        &cluster,
        &out,
        &["--save-frame", "2", "--record", &rec(&record)],
    );
    let extra = [
        "--standby-of",
        &primary_addr,
        "--record",
        &rec(&record_standby),
    ];
    let (standby, standby_addr) = master(&cluster, &out_standby, &extra);
    primary.wait_for_stderr("standby master at", Duration::from_secs(30));
    let nodes = nodes(&cluster, &out, &format!("{primary_addr},{standby_addr}"));
    assert!(
        wait_for(Duration::from_secs(60), || out
            .join("display-1.png")
            .exists()),
        "the primary's wall never presented frame 2"
    );
    let killed = kill(primary);
    let dark = dark_ms(&standby);
    eprintln!(
        "standby: dark for {dark} ms ({:?} after the kill)",
        killed.elapsed()
    );
    let end = interrupt(standby);
    let presented = presented_per_display(&end);
    assert_eq!(presented.len(), 2, "{end}");
    assert!(
        presented.iter().all(|&n| n > 0),
        "a display presented nothing from the new master: {presented:?}\n{end}"
    );
    // One report for the whole run: the primary's frames and the takeover in it.
    let report = read_json(&out_standby.join("report.json"));
    let takeovers = report["takeovers"].as_array().expect("takeovers listed");
    assert_eq!(takeovers.len(), 1, "{report}");
    assert_eq!(takeovers[0]["term"], 1, "{report}");
    let reported = takeovers[0]["dark_ms"]
        .as_f64()
        .expect("the dark time reported");
    assert_eq!(reported.floor() as u64, dark, "{report}");
    // The primary presented frames 0 to 2 at least; the report counts them with the standby's.
    let own = presented.iter().max().unwrap();
    assert!(report["frames"].as_u64() >= Some(own + 2), "{report}");
    // One session record: the primary's lines first (frame 0 on), then the standby's own.
    let (theirs, whole) = (record_lines(&record), record_lines(&record_standby));
    assert!(!theirs.is_empty(), "the primary recorded nothing");
    assert_eq!(
        whole.first(),
        theirs.first(),
        "the record does not start at the run's start"
    );
    assert!(whole.len() >= theirs.len(), "{whole:?}\n{theirs:?}");
    // ...with the takeover marked in it: its term and the dark time the report gives.
    let marked: Vec<&serde_json::Value> =
        whole.iter().filter(|l| !l["takeover"].is_null()).collect();
    assert_eq!(marked.len(), 1, "{whole:?}");
    assert_eq!(marked[0]["takeover"]["term"], 1, "{whole:?}");
    assert_eq!(marked[0]["takeover"]["dark_ms"], dark, "{whole:?}");
    reap_nodes(nodes);
}

/// Item 3 of the issue (no split brain): the standby's link to its primary runs through a
/// relay that the test kills, the nodes' links do not. The standby takes over with no wall;
/// the nodes, which never lost the primary, stay with it and every display keeps presenting
/// its frames; no display presents a frame of the standby's term.
#[test]
fn a_standby_cut_off_from_a_live_primary_takes_over_no_wall_and_the_primary_keeps_it() {
    let dir = tempfile::tempdir().unwrap();
    let cluster = dir.path().join("cluster");
    let (out, out_standby) = (dir.path().join("out"), dir.path().join("out-standby"));
    let (primary, primary_addr) = master(&cluster, &out, &["--save-frame", "2"]);
    let relay = Proc::start("tessera-master", &["relay", "--to", &primary_addr]);
    let line = relay.wait_for_stderr("relay: listening on", Duration::from_secs(30));
    let via = line
        .split("listening on ")
        .nth(1)
        .and_then(|rest| rest.split_whitespace().next())
        .expect("relay: listening on ADDR for TO");
    let (standby, standby_addr) = master(&cluster, &out_standby, &["--standby-of", via]);
    primary.wait_for_stderr("standby master at", Duration::from_secs(30));
    let nodes = nodes(&cluster, &out, &format!("{primary_addr},{standby_addr}"));
    assert!(
        wait_for(Duration::from_secs(60), || out
            .join("display-1.png")
            .exists()),
        "the primary's wall never presented frame 2"
    );
    // The partition: the primary and its nodes still see each other, the standby sees nobody.
    kill(relay);
    standby.wait_for_stderr("taking the wall over", Duration::from_secs(30));
    // The primary, which runs no further than its standby acknowledged, drops the silent
    // standby and goes on (under CI load it had stalled at the standby's horizon until the
    // connection's idle timeout); the connection itself closes later (12 s): all that while
    // the standby holds the higher term.
    primary.wait_for_stderr("acknowledged nothing", Duration::from_secs(60));
    primary.wait_for_stderr(
        "standby master's connection closed",
        Duration::from_secs(60),
    );
    // ...and presents on: two readings of its count apart, the second higher.
    let connect = [
        "--connect".to_string(),
        primary_addr.clone(),
        "--cert-dir".into(),
        issue_cert(&cluster, "control-0"),
    ];
    let presented_now = || {
        let o = control(&connect, &["figures"], Duration::from_secs(30));
        o.assert_success("figures");
        let figures: serde_json::Value = serde_json::from_str(&o.stdout).expect("JSON figures");
        figures["Figures"]["frames_presented"]
            .as_u64()
            .expect("a count")
    };
    let dropped_at = presented_now();
    assert!(
        wait_for(Duration::from_secs(30), || presented_now() > dropped_at + 1),
        "the primary stood still after dropping its standby (at {dropped_at} frames)"
    );
    let end = interrupt(primary);
    let presented = presented_per_display(&end);
    let nodes_said = reap_nodes(nodes);
    let standby_end = interrupt(standby);
    assert!(
        !standby_end.contains("took the wall over; dark for"),
        "a display presented a frame of the standby's term:\n{standby_end}"
    );
    let report = read_json(&out_standby.join("report.json"));
    let takeover = &report["takeovers"][0];
    assert_eq!(takeover["term"], 1, "{report}");
    assert!(
        takeover["dark_ms"].is_null(),
        "the standby's wall presented: {report}"
    );
    let at = takeover["frame"].as_u64().expect("the frame taken over at");
    assert_eq!(presented.len(), 2, "{end}");
    assert!(
        presented.iter().all(|&n| n > at),
        "the primary's displays stopped at the standby's takeover (frame {at}): {presented:?}"
    );
    let primary_report = read_json(&out.join("report.json"));
    assert_eq!(primary_report["displays_lost"], 0, "{primary_report}");
    assert_eq!(primary_report["render_nodes_lost"], 0, "{primary_report}");
    for said in nodes_said {
        assert!(
            !said.contains("giving it up"),
            "a node left the primary:\n{said}"
        );
    }
}

/// Item 4 of the issue (chains): a standby joins the master that took the wall over, and takes
/// it over in turn when that one is killed; the nodes know all three masters.
#[test]
fn a_second_standby_follows_the_new_master_and_takes_the_wall_over_from_it() {
    let dir = tempfile::tempdir().unwrap();
    let cluster = dir.path().join("cluster");
    let outs: Vec<_> = (0..3)
        .map(|i| dir.path().join(format!("out-{i}")))
        .collect();
    let (first, first_addr) = master(&cluster, &outs[0], &["--save-frame", "2"]);
    let (second, second_addr) = master(&cluster, &outs[1], &["--standby-of", &first_addr]);
    first.wait_for_stderr("standby master at", Duration::from_secs(30));
    // The third's address is in the nodes' list before it starts.
    let third_addr = format!("127.0.0.1:{}", free_udp_port());
    let masters = format!("{first_addr},{second_addr},{third_addr}");
    let nodes = nodes(&cluster, &outs[0], &masters);
    assert!(
        wait_for(Duration::from_secs(60), || outs[0]
            .join("display-1.png")
            .exists()),
        "the first master's wall never presented frame 2"
    );
    kill(first);
    let dark_second = dark_ms(&second);
    let extra = ["--standby-of", second_addr.as_str()];
    let (third, _) = master_on(&cluster, &outs[2], &third_addr, &extra);
    second.wait_for_stderr("standby master at", Duration::from_secs(30));
    kill(second);
    let dark_third = dark_ms(&third);
    eprintln!("chain: dark for {dark_second} ms, then {dark_third} ms");
    let end = interrupt(third);
    let presented = presented_per_display(&end);
    assert_eq!(presented.len(), 2, "{end}");
    assert!(presented.iter().all(|&n| n > 0), "{presented:?}\n{end}");
    let report = read_json(&outs[2].join("report.json"));
    let terms: Vec<_> = report["takeovers"]
        .as_array()
        .expect("takeovers listed")
        .iter()
        .map(|t| t["term"].as_u64())
        .collect();
    assert_eq!(terms, [Some(1), Some(2)], "{report}");
    reap_nodes(nodes);
}

/// Item 2 of the issue, measured: kills the primary of a fresh wall at a random frame,
/// `TESSERA_FAILOVER_KILLS` times (8 unless set), and prints each dark time and the p95. No
/// bound is asserted: the figures are a machine's. Run with
/// `cargo test -p tessera-tests --test standby -- --ignored --nocapture`.
#[test]
#[ignore = "a measurement: run by hand, see its doc"]
fn failover_dark_time_p95_over_repeated_kills() {
    let kills: usize = std::env::var("TESSERA_FAILOVER_KILLS")
        .ok()
        .and_then(|n| n.parse().ok())
        .unwrap_or(8)
        .clamp(1, 100);
    let mut seed = u64::from(std::process::id()) ^ 0x9e37_79b9_7f4a_7c15;
    let (mut dark, mut seen) = (Vec::new(), Vec::new());
    for kill_no in 1..=kills {
        seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
        let frame = (2 + (seed >> 33) % 60).to_string();
        let dir = tempfile::tempdir().unwrap();
        let cluster = dir.path().join("cluster");
        let (out, out_standby) = (dir.path().join("out"), dir.path().join("out-standby"));
        let (primary, primary_addr) = master(&cluster, &out, &["--save-frame", &frame]);
        let extra = ["--standby-of", &primary_addr];
        let (standby, standby_addr) = master(&cluster, &out_standby, &extra);
        primary.wait_for_stderr("standby master at", Duration::from_secs(30));
        let nodes = nodes(&cluster, &out, &format!("{primary_addr},{standby_addr}"));
        let saved = out.join("display-1.png");
        assert!(
            wait_for(Duration::from_secs(60), || saved.exists()),
            "no frame {frame}"
        );
        let killed = kill(primary);
        let ms = dark_ms(&standby);
        // The test's own view: from the kill to the line read (its polling adds up to 20 ms).
        let since_kill = killed.elapsed().as_millis();
        eprintln!("kill {kill_no}/{kills} at frame {frame}: dark {ms} ms (line read {since_kill} ms after the kill)");
        dark.push(ms);
        seen.push(since_kill as u64);
        interrupt(standby);
        reap_nodes(nodes);
    }
    let p95 = |v: &mut Vec<u64>| {
        v.sort_unstable();
        v[(v.len() * 95).div_ceil(100) - 1]
    };
    eprintln!(
        "failover after {} ms: dark p95 {} ms, max {} ms over {kills} kills; kill to line p95 {} ms",
        tessera_net::link::FAILOVER_SILENCE.as_millis(),
        p95(&mut dark),
        dark.last().unwrap(),
        p95(&mut seen)
    );
}

/// Item 3 of the issue, the other way round: a primary stopped (SIGSTOP) past the failure
/// bound loses its wall to the standby. Resumed, it finds its nodes gone (they closed its
/// connections as silent) and ends its run, so the wall never has two masters; the standby
/// keeps the wall. (The nodes would refuse its older term should they meet it again:
/// `FromNode::StaleMaster`, after which it steps down; unit-tested in the core.)
#[test]
fn a_stopped_primary_resumed_after_a_takeover_ends_its_run_and_the_standby_keeps_the_wall() {
    let dir = tempfile::tempdir().unwrap();
    let cluster = dir.path().join("cluster");
    let (out, out_standby) = (dir.path().join("out"), dir.path().join("out-standby"));
    let (primary, primary_addr) = master(&cluster, &out, &["--save-frame", "2"]);
    let (standby, standby_addr) = master(&cluster, &out_standby, &["--standby-of", &primary_addr]);
    primary.wait_for_stderr("standby master at", Duration::from_secs(30));
    let nodes = nodes(&cluster, &out, &format!("{primary_addr},{standby_addr}"));
    assert!(
        wait_for(Duration::from_secs(60), || out
            .join("display-1.png")
            .exists()),
        "the primary's wall never presented frame 2"
    );
    primary.signal(libc::SIGSTOP);
    let dark = dark_ms(&standby);
    eprintln!("the standby took over a stopped primary; dark for {dark} ms");
    primary.signal(libc::SIGCONT);
    let old = primary.wait(Duration::from_secs(60));
    assert!(!old.status.success(), "{}", old.stderr);
    assert!(
        old.stderr
            .contains("every render node or every display is gone"),
        "the resumed primary did not end its run for want of nodes:\n{}",
        old.stderr
    );
    let end = interrupt(standby);
    let presented = presented_per_display(&end);
    assert_eq!(presented.len(), 2, "{end}");
    assert!(presented.iter().all(|&n| n > 0), "{presented:?}\n{end}");
    reap_nodes(nodes);
}
