//! Walls on a machine whose every core is busy, beside a flood of datagrams at another wall's
//! port: both complete every frame on every display, and nobody is dropped. What a shared
//! host does to a wall, made repeatable; every load here is started and stopped by the test.

use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;
use tessera_tests::*;

const LIMIT: Duration = Duration::from_secs(240);
const FRAMES: u64 = 150;

/// A loop on every core until `stop`: other work on the machine.
fn spin_every_core(stop: &Arc<AtomicBool>) -> Vec<JoinHandle<()>> {
    let cores = std::thread::available_parallelism().map_or(2, |n| n.get());
    (0..cores)
        .map(|_| {
            let stop = stop.clone();
            std::thread::spawn(move || {
                let mut x = 0u64;
                while !stop.load(Ordering::Relaxed) {
                    x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
                }
            })
        })
        .collect()
}

/// Garbage datagrams at `target` until `stop` (at most 10 million): what a port scan or a
/// misdirected stream sends a master.
fn flood(target: SocketAddr, stop: &Arc<AtomicBool>) -> JoinHandle<u64> {
    let stop = stop.clone();
    std::thread::spawn(move || {
        let socket = UdpSocket::bind("127.0.0.1:0").expect("a socket");
        let junk = [0xA5u8; 1200];
        let mut sent = 0u64;
        while !stop.load(Ordering::Relaxed) && sent < 10_000_000 {
            if socket.send_to(&junk, target).is_ok() {
                sent += 1;
            }
        }
        sent
    })
}

fn local_wall(out: &std::path::Path) -> Proc {
    let frames = FRAMES.to_string();
    Proc::start(
        "tessera-master",
        &[
            "local",
            "--wall",
            "2x1",
            "--screen",
            "96x64",
            "--render-nodes",
            "2",
            "--threads",
            "1",
            "--frames",
            &frames,
            "--out",
            out.to_str().unwrap(),
        ],
    )
}

#[test]
fn walls_on_busy_cores_and_beside_a_datagram_flood_complete_every_frame() {
    let dir = tempfile::tempdir().unwrap();
    let (out_a, out_b) = (dir.path().join("a"), dir.path().join("b"));
    let stop = Arc::new(AtomicBool::new(false));
    let spinners = spin_every_core(&stop);
    let (a, b) = (local_wall(&out_a), local_wall(&out_b));
    let connect = control_args(&b, LIMIT);
    let target: SocketAddr = connect[1].parse().expect("the master's address");
    let flooder = flood(target, &stop);
    let (ra, rb) = (a.wait(LIMIT), b.wait(LIMIT));
    stop.store(true, Ordering::Relaxed);
    let sent = flooder.join().unwrap();
    for s in spinners {
        s.join().unwrap();
    }
    eprintln!("{sent} junk datagrams sent at the second wall's master");
    for (name, o, out) in [("first", ra, &out_a), ("second", rb, &out_b)] {
        o.assert_success(name);
        let report = read_json(&out.join("report.json"));
        assert_eq!(report["render_nodes_lost"], 0, "{name}: {report}");
        assert_eq!(report["displays_lost"], 0, "{name}: {report}");
        for d in report["displays"].as_array().unwrap() {
            assert_eq!(d["frames_presented"].as_u64(), Some(FRAMES), "{name}: {d}");
        }
        eprintln!(
            "{name} wall: {} suspicions, {} master pauses (longest {} ms), longest frame {} ms",
            report["nodes_suspected"],
            report["master_pauses"],
            report["longest_master_pause_ms"],
            report["frame_ms"]["max"]
        );
    }
}
