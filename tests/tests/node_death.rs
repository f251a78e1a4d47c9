//! Deaths in the middle of a local wall's run. A render node killed: the wall goes on, and its
//! stall is bounded by the master's node deadline, not by the network's idle timeout. The
//! master killed: every node notices within the idle timeout and exits, with a message.

use std::time::Duration;
use tessera_tests::*;

/// A local wall of `wall` screens (`--wall`) with `render_nodes` one-thread render nodes and
/// the extra flags `rest`, writing into `out`; returned once its last display has saved frame
/// `saved` (an event to wait for, not a time to guess).
fn local_wall(
    out: &std::path::Path,
    wall: &str,
    render_nodes: u32,
    rest: &[&str],
    saved: u32,
) -> Proc {
    let (nodes, save) = (render_nodes.to_string(), saved.to_string());
    let mut args = vec![
        "local",
        "--wall",
        wall,
        "--screen",
        "96x64",
        "--render-nodes",
        &nodes,
        "--threads",
        "1",
        "--save-frame",
        &save,
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend(rest);
    let master = Proc::start("tessera-master", &args);
    let displays: u32 = wall.split('x').map(|n| n.parse::<u32>().unwrap()).product();
    let last = out.join(format!("display-{}.png", displays - 1));
    assert!(
        wait_for(Duration::from_secs(90), || last.exists()
            || master.has_exited()),
        "the wall never presented frame {saved}"
    );
    master
}

#[test]
fn a_killed_render_node_of_a_local_wall_is_dropped_at_once_and_stalls_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    // The master's default suspicion deadline (--node-deadline-ms).
    let deadline_ms = 300;
    let master = local_wall(&out, "2x1", 3, &["--frames", "100000"], 3);
    let nodes = children(master.pid(), "render-node");
    assert_eq!(
        nodes.len(),
        3,
        "render nodes of {}: {nodes:?}",
        master.pid()
    );
    // SIGKILL: no goodbye on the connection; the launcher, its parent, sees it die.
    // SAFETY: kill only sends a signal and touches no memory; the pid is a node
    // process of the wall this test started, still running.
    unsafe { libc::kill(nodes[1] as i32, libc::SIGKILL) };
    master.wait_for_stderr(
        "its tiles go to the other render nodes",
        Duration::from_secs(60),
    );
    master.signal(libc::SIGINT);
    let o = master.wait(Duration::from_secs(60));
    assert!(
        o.stderr
            .contains("disconnected (its process exited with signal 9)"),
        "the launcher saw its child die and told the master at once:\n{}",
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

/// Whether process `pid` is still running (a zombie is not).
fn running(pid: u32) -> bool {
    std::fs::read_to_string(format!("/proc/{pid}/stat")).is_ok_and(|s| !s.contains(") Z "))
}

#[test]
fn a_killed_local_master_leaves_no_node_behind() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let master = local_wall(&out, "2x1", 2, &["--frames", "100000"], 2);
    let mut nodes = children(master.pid(), "render-node");
    nodes.extend(children(master.pid(), "display-node"));
    assert_eq!(nodes.len(), 4, "{nodes:?}");
    master.signal(libc::SIGKILL);
    // The launcher's children die with it (PR_SET_PDEATHSIG), before any timeout.
    assert!(
        wait_for(Duration::from_secs(5), || nodes
            .iter()
            .all(|&p| !running(p))),
        "orphans: {:?}",
        nodes.iter().filter(|&&p| running(p)).collect::<Vec<_>>()
    );
    let _ = master.wait(Duration::from_secs(10));
}

/// A served 2x1 wall of 160x90 that runs until interrupted and saves frame 2 into `out`, its
/// nodes started by hand as on hosts of their own.
struct Served {
    master: Proc,
    addr: String,
    cluster: std::path::PathBuf,
    out: std::path::PathBuf,
}

impl Served {
    fn start(dir: &std::path::Path) -> Served {
        Served::start_with(dir, &[])
    }

    /// Its two displays and a render node, each started with `--reconnect` and waiting
    /// `timeout` seconds for a lost master, returned once frames are flowing.
    fn reconnecting(dir: &std::path::Path, timeout: &str) -> (Served, [Proc; 3]) {
        let wall = Served::start(dir);
        let reconnect = ["--reconnect", "--reconnect-timeout", timeout];
        let nodes = [
            wall.display_with(0, &reconnect),
            wall.display_with(1, &reconnect),
            wall.render_with(&reconnect),
        ];
        wall.wait_for_frame_2();
        (wall, nodes)
    }

    /// With the master's flags `extra` as well.
    fn start_with(dir: &std::path::Path, extra: &[&str]) -> Served {
        let (cluster, out) = (dir.join("cluster"), dir.join("out"));
        let master = Served::master(&cluster, "127.0.0.1:0", &out, &["--frames", "0"], extra);
        let listening = master.wait_for_stderr("listening on", Duration::from_secs(60));
        let addr = listening
            .rsplit(' ')
            .next()
            .expect("an address")
            .to_string();
        Served {
            master,
            addr,
            cluster,
            out,
        }
    }

    /// A master of this wall listening on `listen`, saving frame 2 into `out`.
    fn master(
        cluster: &std::path::Path,
        listen: &str,
        out: &std::path::Path,
        frames: &[&str],
        extra: &[&str],
    ) -> Proc {
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
            "--save-frame",
            "2",
            "--out",
            out.to_str().unwrap(),
        ];
        args.extend(frames);
        args.extend(extra);
        Proc::start("tessera-master", &args)
    }

    /// The certificate directory of node `name`, issued on first use.
    fn certs(&self, name: &str) -> String {
        let dir = self.cluster.join(name);
        if dir.exists() {
            return dir.display().to_string();
        }
        issue_cert(&self.cluster, name)
    }

    fn display(&self, id: u32) -> Proc {
        self.display_with(id, &[])
    }

    fn display_with(&self, id: u32, extra: &[&str]) -> Proc {
        let certs = self.certs(&format!("display-{id}"));
        let id = id.to_string();
        let mut args = vec![
            "--master",
            &self.addr,
            "--display",
            &id,
            "--cert-dir",
            &certs,
            "--listen",
            "127.0.0.1:0",
            "--out",
            self.out.to_str().unwrap(),
        ];
        args.extend(extra);
        Proc::start("tessera-display-node", &args)
    }

    fn render(&self) -> Proc {
        self.render_with(&[])
    }

    fn render_with(&self, extra: &[&str]) -> Proc {
        let certs = self.certs("render-0");
        let mut args = vec![
            "--master",
            &self.addr,
            "--cert-dir",
            &certs,
            "--threads",
            "1",
        ];
        args.extend(extra);
        Proc::start("tessera-render-node", &args)
    }

    fn wait_for_frame_2(&self) {
        assert!(
            wait_for(Duration::from_secs(60), || self
                .out
                .join("display-1.png")
                .exists()),
            "the wall never presented frame 2"
        );
    }
}

#[test]
fn nodes_of_a_killed_served_master_exit_within_the_idle_timeout_saying_why() {
    let dir = tempfile::tempdir().unwrap();
    let wall = Served::start(dir.path());
    let nodes = [wall.display(0), wall.display(1), wall.render()];
    wall.wait_for_frame_2();
    // SIGKILL, and another host's nodes: no goodbye, no parent to take them along.
    let killed = std::time::Instant::now();
    wall.master.signal(libc::SIGKILL);
    let bound = tessera_net::quic::IDLE_TIMEOUT + Duration::from_secs(3);
    for node in nodes {
        let o = node.wait(bound);
        assert_eq!(o.status.code(), Some(1), "{}", o.stderr);
        assert!(o.stderr.contains("lost the master"), "{}", o.stderr);
    }
    eprintln!(
        "every node exited {:?} after the master was killed",
        killed.elapsed()
    );
    let _ = wall.master.wait(Duration::from_secs(10));
}

#[test]
fn a_killed_render_node_of_a_served_wall_is_suspected_then_dead_by_its_rhythm() {
    let dir = tempfile::tempdir().unwrap();
    let wall = Served::start(dir.path());
    let (_d0, _d1, _r0) = (wall.display(0), wall.display(1), wall.render());
    let victim = wall.render();
    wall.wait_for_frame_2();
    // Another host's node: no parent to see it die, no goodbye; only the master's clock.
    let killed = std::time::Instant::now();
    victim.signal(libc::SIGKILL);
    wall.master
        .wait_for_stderr("suspected; its tiles are copied", Duration::from_secs(10));
    let suspected = killed.elapsed();
    wall.master
        .wait_for_stderr("past what its heartbeats allow", Duration::from_secs(20));
    let dead = killed.elapsed();
    eprintln!("killed render node: suspected after {suspected:?}, dead after {dead:?}");
    // Dead after the served default's 3 s acceptable pause past its rhythm, before the
    // transport's idle timeout would have said so.
    assert!(dead >= Duration::from_secs(3), "{dead:?}");
    assert!(dead < tessera_net::quic::IDLE_TIMEOUT, "{dead:?}");
    wall.master.signal(libc::SIGKILL);
    let _ = wall.master.wait(Duration::from_secs(10));
}

#[test]
fn a_killed_display_leaves_the_others_presenting_every_frame() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let frames = 300;
    let master = local_wall(&out, "3x1", 2, &["--frames", &frames.to_string()], 3);
    let displays = children(master.pid(), "display-node");
    assert_eq!(displays.len(), 3, "{displays:?}");
    let victim = displays
        .iter()
        .copied()
        .find(|p| {
            std::fs::read(format!("/proc/{p}/cmdline")).is_ok_and(|c| {
                let line = String::from_utf8_lossy(&c).into_owned();
                let args: Vec<&str> = line.split('\0').collect();
                args.windows(2).any(|w| w == ["--display", "1"])
            })
        })
        .expect("display 1 runs");
    // SAFETY: kill only sends a signal and touches no memory; the pid is a node
    // process of the wall this test started, still running.
    unsafe { libc::kill(victim as i32, libc::SIGKILL) };
    let o = master.wait(Duration::from_secs(120));
    assert!(
        o.stderr.contains("the other displays go on without it"),
        "{}",
        o.stderr
    );
    let report = read_json(&out.join("report.json"));
    assert_eq!(report["frames"].as_u64(), Some(frames), "{report}");
    assert_eq!(report["displays_lost"], 1, "{report}");
    let presented: Vec<u64> = report["displays"]
        .as_array()
        .unwrap()
        .iter()
        .map(|d| d["frames_presented"].as_u64().unwrap())
        .collect();
    assert_eq!(
        presented,
        vec![frames, frames],
        "the two living displays showed every frame"
    );
    let longest = report["frame_ms"]["max"].as_f64().unwrap();
    eprintln!(
        "killed display: longest frame {longest:.0} ms (median {:.0} ms)",
        report["frame_ms"]["p50"].as_f64().unwrap()
    );
    assert!(longest < 2_300.0, "the wall froze for {longest} ms");
}

#[test]
fn a_restarted_display_rejoins_the_running_wall_and_shows_its_frames() {
    let dir = tempfile::tempdir().unwrap();
    let wall = Served::start(dir.path());
    let control_certs = wall.certs("control-0");
    let (_d0, first, _render) = (wall.display(0), wall.display(1), wall.render());
    wall.wait_for_frame_2();
    first.signal(libc::SIGKILL);
    let master = &wall.master;
    master.wait_for_stderr(
        "the other displays go on without it",
        Duration::from_secs(30),
    );
    // The same display, restarted: same certificate, a new address.
    let _again = wall.display(1);
    master.wait_for_stderr(
        "display 1 rejoined the running wall",
        Duration::from_secs(30),
    );
    let rejoined = std::time::Instant::now();
    let connect = ["--connect", &wall.addr, "--cert-dir", &control_certs].map(String::from);
    let snap = control(&connect, &["snapshot"], Duration::from_secs(30));
    snap.assert_success("snapshot");
    let frame: u64 = snap.stdout.trim().parse().expect("a frame number");
    let shown = wall.out.join(format!("display-1-frame-{frame}.png"));
    assert!(
        wait_for(Duration::from_secs(30), || shown.exists()),
        "the rejoined display never showed frame {frame}"
    );
    eprintln!(
        "rejoined display: showed frame {frame} {:?} after the master logged its rejoining",
        rejoined.elapsed()
    );
    wall.master.signal(libc::SIGINT);
    let o = wall.master.wait(Duration::from_secs(60));
    assert_eq!(o.status.code(), Some(130), "{}", o.stderr);
    let report = read_json(&wall.out.join("report.json"));
    assert_eq!(report["displays_lost"], 1, "{report}");
}

#[test]
fn a_display_restarted_after_0_2_0_5_and_1_s_rejoins_each_time() {
    let dir = tempfile::tempdir().unwrap();
    let wall = Served::start(dir.path());
    let control_certs = wall.certs("control-0");
    let (_d0, mut current, _render) = (wall.display(0), wall.display(1), wall.render());
    wall.wait_for_frame_2();
    let connect = ["--connect", &wall.addr, "--cert-dir", &control_certs].map(String::from);
    for ms in [200, 500, 1000] {
        current.signal(libc::SIGKILL);
        let _ = current.wait(Duration::from_secs(10));
        // The restart's delay is what is tested, not a wait for anything.
        std::thread::sleep(Duration::from_millis(ms));
        let restarted = std::time::Instant::now();
        current = wall.display(1);
        // Shown again: a snapshot the restarted display saves (asked again while it rejoins).
        let showing = wait_for(Duration::from_secs(30), || {
            let snap = control(&connect, &["snapshot"], Duration::from_secs(30));
            snap.assert_success("snapshot");
            let frame: u64 = snap.stdout.trim().parse().expect("a frame number");
            let shown = wall.out.join(format!("display-1-frame-{frame}.png"));
            wait_for(Duration::from_secs(2), || shown.exists())
        });
        assert!(
            showing,
            "display 1 restarted after {ms} ms never showed a frame"
        );
        eprintln!(
            "display 1 restarted after {ms} ms: showing frames {:?} after its restart",
            restarted.elapsed()
        );
    }
    wall.master.signal(libc::SIGINT);
    let o = wall.master.wait(Duration::from_secs(60));
    assert_eq!(o.status.code(), Some(130), "{}", o.stderr);
    assert!(
        o.stderr.contains("replaced: display 1 joined again"),
        "{}",
        o.stderr
    );
}

#[test]
fn nodes_started_with_reconnect_rejoin_a_restarted_master() {
    let dir = tempfile::tempdir().unwrap();
    let (wall, nodes) = Served::reconnecting(dir.path(), "60");
    wall.master.signal(libc::SIGKILL);
    for node in &nodes {
        node.wait_for_stderr(
            "waiting up to 60 s for it to come back",
            Duration::from_secs(30),
        );
    }
    // The same master, restarted at the same address, for a run of 10 frames (its report in
    // the same folder: the killed master wrote none).
    let out = wall.out.clone();
    let restarted = std::time::Instant::now();
    let again = Served::master(&wall.cluster, &wall.addr, &out, &["--frames", "10"], &[]);
    let o = again.wait(Duration::from_secs(120));
    o.assert_success("the restarted master's run");
    eprintln!(
        "restarted master: its 10 frames done {:?} after its start",
        restarted.elapsed()
    );
    let report = read_json(&out.join("report.json"));
    assert_eq!(report["frames"], 10, "{report}");
    let presented: Vec<u64> = report["displays"]
        .as_array()
        .unwrap()
        .iter()
        .map(|d| d["frames_presented"].as_u64().unwrap())
        .collect();
    assert_eq!(presented, vec![10, 10], "{report}");
    assert_eq!(
        report["render_nodes"].as_array().unwrap().len(),
        1,
        "{report}"
    );
    // The restarted master shut the wall down: every node exits cleanly.
    for node in nodes {
        let o = node.wait(Duration::from_secs(30));
        o.assert_success("a node that rejoined");
        assert!(
            o.stderr.contains("the master is back; rejoined"),
            "{}",
            o.stderr
        );
    }
    let _ = wall.master.wait(Duration::from_secs(10));
}

#[test]
fn nodes_waiting_for_a_master_that_never_comes_back_give_up_at_their_timeout() {
    let dir = tempfile::tempdir().unwrap();
    let (wall, nodes) = Served::reconnecting(dir.path(), "1");
    let killed = std::time::Instant::now();
    wall.master.signal(libc::SIGKILL);
    // The idle timeout to notice, the 1 s wait, and a generous allowance for a loaded machine.
    let bound = tessera_net::quic::IDLE_TIMEOUT + Duration::from_secs(1 + 5);
    for node in nodes {
        let o = node.wait(bound);
        assert_eq!(o.status.code(), Some(1), "{}", o.stderr);
        assert!(
            o.stderr.contains("did not come back within 1 s"),
            "{}",
            o.stderr
        );
    }
    eprintln!(
        "every waiting node gave up {:?} after the master was killed",
        killed.elapsed()
    );
    let _ = wall.master.wait(Duration::from_secs(10));
}

#[test]
fn waiting_for_a_lost_display_holds_the_wall_until_it_rejoins() {
    let dir = tempfile::tempdir().unwrap();
    let wall = Served::start_with(dir.path(), &["--display-loss", "wait"]);
    let control_certs = wall.certs("control-0");
    let (_d0, first, _render) = (wall.display(0), wall.display(1), wall.render());
    wall.wait_for_frame_2();
    first.signal(libc::SIGKILL);
    let master = &wall.master;
    master.wait_for_stderr("the wall waits for it to rejoin", Duration::from_secs(30));
    let connect = ["--connect", &wall.addr, "--cert-dir", &control_certs].map(String::from);
    // While it is away the wall stands still: control clients asking for half a second (a
    // wall going on would present a dozen frames meanwhile) all see the same count.
    let presented = || {
        let o = control(&connect, &["figures"], Duration::from_secs(30));
        o.assert_success("figures");
        let figures: serde_json::Value = serde_json::from_str(&o.stdout).expect("JSON figures");
        figures["Figures"]["frames_presented"]
            .as_u64()
            .expect("a count")
    };
    let asked = std::time::Instant::now();
    let mut counts = Vec::new();
    while counts.len() < 100 && asked.elapsed() < Duration::from_millis(500) {
        counts.push(presented());
    }
    let span = asked.elapsed();
    assert!(
        counts.iter().all(|&c| c == counts[0]),
        "{counts:?} over {span:?}"
    );
    let _again = wall.display(1);
    master.wait_for_stderr(
        "display 1 rejoined the running wall",
        Duration::from_secs(30),
    );
    let snap = control(&connect, &["snapshot"], Duration::from_secs(30));
    snap.assert_success("snapshot");
    let frame: u64 = snap.stdout.trim().parse().expect("a frame number");
    for d in 0..2 {
        let shown = wall.out.join(format!("display-{d}-frame-{frame}.png"));
        assert!(
            wait_for(Duration::from_secs(30), || shown.exists()),
            "display {d} never showed frame {frame}"
        );
    }
    wall.master.signal(libc::SIGINT);
    let o = wall.master.wait(Duration::from_secs(60));
    assert_eq!(o.status.code(), Some(130), "{}", o.stderr);
    let report = read_json(&wall.out.join("report.json"));
    assert_eq!(report["displays_lost"], 1, "{report}");
    // Only the frames in flight when the loss was noticed went on without display 1; the
    // wall showed nothing new while it was away (go-on would have gone on presenting).
    let short = report["frames_short_of_displays"].as_u64().unwrap();
    eprintln!(
        "waited for a display: {short} frames presented without it, none over {span:?} of asking, longest frame {:.0} ms",
        report["frame_ms"]["max"].as_f64().unwrap()
    );
    assert!(short <= 2, "{report}");
}

/// CPU seconds process `pid` has used so far (user and system), from `/proc/PID/stat`.
fn cpu_seconds(pid: u32) -> f64 {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    // The fields after the command name, which may hold spaces, closed by the last ')'.
    let fields: Vec<&str> = stat
        .rsplit_once(')')
        .map_or("", |(_, rest)| rest)
        .split_whitespace()
        .collect();
    let ticks: u64 = [11, 12]
        .iter()
        .filter_map(|&i| fields.get(i)?.parse::<u64>().ok())
        .sum();
    // SAFETY: sysconf reads a constant of the system and touches no memory of ours.
    let per_second = unsafe { libc::sysconf(libc::_SC_CLK_TCK) }.max(1);
    ticks as f64 / per_second as f64
}

#[test]
fn a_render_node_tracing_a_runaway_frame_stops_when_its_master_is_killed() {
    let dir = tempfile::tempdir().unwrap();
    // 2^18 rays per pixel, the most a control client may ask for: hours of one thread for a
    // frame of this wall, seconds for each 8x8 packet.
    let wall = Served::start_with(dir.path(), &["--spp", "4096", "--ao", "63"]);
    let (_d0, _d1) = (wall.display(0), wall.display(1));
    let render = wall.render();
    render.wait_for_stderr("ready", Duration::from_secs(60));
    // Tracing: its CPU time grows past what it had when ready (loading counted too).
    let at_ready = cpu_seconds(render.pid());
    assert!(
        wait_for(Duration::from_secs(30), || cpu_seconds(render.pid())
            > at_ready + 0.3),
        "the render node never started tracing"
    );
    let killed = std::time::Instant::now();
    wall.master.signal(libc::SIGKILL);
    // Its watch of the master's packets holds the render threads after 1 s of silence:
    // from then on the node spends (next to) no CPU, although its connection lasts until
    // the transport's idle timeout.
    let silence = tessera_net::link::MASTER_SILENCE;
    render.wait_for_stderr(
        "the master has been silent",
        silence + Duration::from_secs(5),
    );
    let noticed = killed.elapsed();
    let held = cpu_seconds(render.pid());
    let window = std::time::Instant::now();
    // A window to measure over, not a wait for anything.
    std::thread::sleep(Duration::from_secs(1));
    let spent = cpu_seconds(render.pid()) - held;
    let per_second = spent / window.elapsed().as_secs_f64();
    eprintln!(
        "render node held its tracing {noticed:?} after its master was killed; then {per_second:.3} CPU s/s"
    );
    // Tracing used both threads (2 CPU s/s); a held node only polls its flags and sockets.
    assert!(per_second < 0.2, "still tracing: {per_second:.3} CPU s/s");
    let bound = tessera_net::quic::IDLE_TIMEOUT + Duration::from_secs(3);
    wait_for(bound, || render.has_exited());
    let exited = killed.elapsed();
    let o = render.wait(Duration::from_secs(5));
    eprintln!("render node exited {exited:?} after its master was killed mid-frame");
    assert_eq!(o.status.code(), Some(1), "{}", o.stderr);
    assert!(o.stderr.contains("lost the master"), "{}", o.stderr);
    assert!(
        exited < bound,
        "exited {exited:?} after the kill\n{}",
        o.stderr
    );
    let _ = wall.master.wait(Duration::from_secs(10));
}

#[test]
fn a_render_node_refuses_a_replicated_scene_over_its_memory_budget_naming_the_sizes() {
    let dir = tempfile::tempdir().unwrap();
    // 131,072 triangles: some 22 MiB at the load's peak, cheap for the master to hash.
    let wall = Served::start_with(dir.path(), &["--scene", "knot:512:128"]);
    let (_d0, _d1) = (wall.display(0), wall.display(1));
    let render = wall.render_with(&["--memory-budget", "16MiB"]);
    let o = render.wait(Duration::from_secs(60));
    assert_eq!(o.status.code(), Some(1), "{}", o.stderr);
    for words in [
        "22.0 MiB",
        "16.0 MiB",
        "--memory-budget",
        "131072 triangles",
    ] {
        assert!(o.stderr.contains(words), "{words:?} in:\n{}", o.stderr);
    }
    let line = wall
        .master
        .wait_for_stderr("refusing the replicated scene", Duration::from_secs(30));
    eprintln!("the master logged: {line}");
    wall.master.signal(libc::SIGKILL);
    let _ = wall.master.wait(Duration::from_secs(10));
}
