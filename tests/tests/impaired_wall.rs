//! A served wall whose every link runs through `tessera-master relay`: the master's traffic
//! through one relay, each display's pixels through another. Clean, then with 2 % loss and
//! 20 ms (± 5 ms) delay each way: every frame completes on every display, and the figures
//! of both runs are printed side by side. A partition of every link for 2 s loses no frame
//! and nobody.

use std::time::Duration;
use tessera_tests::*;

fn free_udp_port() -> u16 {
    std::net::UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// A relay to `to` with `faults` (relay flags); returns it and the address it listens on.
fn relay(to: &str, faults: &[&str], stats: &std::path::Path) -> (Proc, String) {
    let mut args = vec!["relay", "--to", to, "--stats", stats.to_str().unwrap()];
    args.extend(faults);
    let p = Proc::start("tessera-master", &args);
    let line = p.wait_for_stderr("relay: listening on", Duration::from_secs(30));
    let addr = line
        .split_whitespace()
        .nth(3)
        .expect("relay: listening on ADDR for TO")
        .to_string();
    (p, addr)
}

struct RunFigures {
    fps: f64,
    present_p95_ms: f64,
    dropped: u64,
    forwarded: u64,
}

fn wall_through_relays(dir: &std::path::Path, faults: &[&str], frames: u64) -> RunFigures {
    let cluster = dir.join("cluster");
    let out = dir.join("out");
    let (d0, d1, r0) = (
        issue_cert(&cluster, "display-0"),
        issue_cert(&cluster, "display-1"),
        issue_cert(&cluster, "render-0"),
    );
    let master_port = free_udp_port();
    let master_addr = format!("127.0.0.1:{master_port}");
    let master = Proc::start(
        "tessera-master",
        &[
            "serve",
            "--listen",
            &master_addr,
            "--cluster-dir",
            cluster.to_str().unwrap(),
            "--render-nodes",
            "1",
            "--wall",
            "2x1",
            "--screen",
            "160x90",
            "--frames",
            &frames.to_string(),
            "--out",
            out.to_str().unwrap(),
            // The default deadlines: a display whose heartbeats a lost packet held up is
            // suspected at 300 ms, never dropped for it.
        ],
    );
    master.wait_for_stderr("listening on", Duration::from_secs(60));
    let stats: Vec<_> = (0..3)
        .map(|i| dir.join(format!("relay-{i}.json")))
        .collect();
    let (master_relay, via_master) = relay(&master_addr, faults, &stats[0]);
    let mut relays = vec![master_relay];
    let mut displays = Vec::new();
    for (id, certs) in [(0, &d0), (1, &d1)] {
        let listen = format!("127.0.0.1:{}", free_udp_port());
        let (r, via) = relay(&listen, faults, &stats[id + 1]);
        relays.push(r);
        displays.push(Proc::start(
            "tessera-display-node",
            &[
                "--master",
                &via_master,
                "--display",
                &id.to_string(),
                "--cert-dir",
                certs,
                "--listen",
                &listen,
                "--advertise",
                &via,
            ],
        ));
    }
    let render = Proc::start(
        "tessera-render-node",
        &["--master", &via_master, "--cert-dir", &r0, "--threads", "1"],
    );
    let o = master.wait(Duration::from_secs(240));
    assert!(o.status.success(), "{}", o.stderr);
    for node in displays.into_iter().chain([render]) {
        node.wait(Duration::from_secs(30))
            .assert_success("a node after the run");
    }
    let report = read_json(&out.join("report.json"));
    assert_eq!(report["frames"].as_u64(), Some(frames), "{report}");
    // Loss and delay are no death: no node may be taken for dead on their account.
    assert_eq!(report["render_nodes_lost"], 0, "{report}");
    assert_eq!(report["displays_lost"], 0, "{report}");
    for d in report["displays"].as_array().unwrap() {
        assert_eq!(d["frames_presented"].as_u64(), Some(frames), "{d}");
    }
    let (mut dropped, mut forwarded) = (0, 0);
    for (r, path) in relays.into_iter().zip(&stats) {
        r.signal(libc::SIGINT);
        r.wait(Duration::from_secs(30)).assert_success("relay");
        let s = read_json(path);
        dropped += s["dropped"].as_u64().unwrap();
        forwarded += s["forwarded"].as_u64().unwrap();
    }
    RunFigures {
        fps: report["fps"].as_f64().unwrap(),
        present_p95_ms: report["start_to_present_ms"]["p95"].as_f64().unwrap(),
        dropped,
        forwarded,
    }
}

#[test]
fn every_frame_completes_through_loss_and_delay() {
    let frames = 40;
    let clean_dir = tempfile::tempdir().unwrap();
    let clean = wall_through_relays(clean_dir.path(), &[], frames);
    assert_eq!(clean.dropped, 0);
    let bad_dir = tempfile::tempdir().unwrap();
    let impaired = [
        "--loss",
        "0.02",
        "--delay-ms",
        "20",
        "--jitter-ms",
        "5",
        "--seed",
        "11",
    ];
    let bad = wall_through_relays(bad_dir.path(), &impaired, frames);
    assert!(bad.dropped > 0, "the relay dropped nothing");
    eprintln!(
        "through relays, clean: {:.1} fps, start-to-present p95 {:.0} ms, {} datagrams; \
         2 % loss + 20 ms: {:.1} fps, p95 {:.0} ms, {} datagrams, {} dropped",
        clean.fps,
        clean.present_p95_ms,
        clean.forwarded,
        bad.fps,
        bad.present_p95_ms,
        bad.forwarded,
        bad.dropped
    );
}

#[test]
fn a_two_second_partition_of_every_link_loses_no_frame_and_nobody() {
    let dir = tempfile::tempdir().unwrap();
    // Every relay cuts its link from 3 s after it started, for 2 s, while frames flow.
    let cut = wall_through_relays(dir.path(), &["--partition", "3:2"], 300);
    assert!(cut.dropped > 0, "the partition fell outside the run");
    eprintln!(
        "2 s partition of every link: {:.1} fps, {} datagrams dropped by it, every frame shown",
        cut.fps, cut.dropped
    );
}
