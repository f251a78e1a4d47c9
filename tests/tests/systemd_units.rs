//! `deploy/systemd/`: the node units pass `systemd-analyze verify` (where it is installed), and
//! the very command line their `ExecStart` gives runs a node of a served wall that tells the
//! service manager `READY=1` once it joined and `STOPPING=1` when the wall ends.

use std::collections::HashMap;
use std::os::unix::net::UnixDatagram;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};
use tessera_tests::*;

/// Where deploy/README.md says to install the binary, as the units name it.
const INSTALLED: &str = "/usr/local/bin/tessera-master";

fn unit(name: &str) -> (PathBuf, String) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../deploy/systemd")
        .join(name);
    let text = std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
    (path, text)
}

/// The unit's `ExecStart`, continuation lines joined, split into words.
fn exec_start(text: &str) -> Vec<String> {
    let joined = text.replace("\\\n", " ");
    let line = joined
        .lines()
        .find_map(|l| l.strip_prefix("ExecStart="))
        .expect("an ExecStart line");
    line.split_whitespace().map(str::to_string).collect()
}

/// The unit's `Environment=` defaults, then `env` over them, as systemd would set them.
fn environment(text: &str, env: &[(&str, &str)]) -> HashMap<String, String> {
    let mut vars = HashMap::new();
    for line in text.lines().filter_map(|l| l.strip_prefix("Environment=")) {
        for pair in line.split_whitespace() {
            let (k, v) = pair.split_once('=').expect("KEY=VALUE");
            vars.insert(k.to_string(), v.to_string());
        }
    }
    for (k, v) in env {
        vars.insert(k.to_string(), v.to_string());
    }
    vars
}

/// What systemd makes of `ExecStart` words: specifiers (`%i`, `%d`, `%C`, `%S` from
/// `specifiers`), `${VAR}` as one word, a lone `$VAR` split into words (none when empty).
fn expand(
    words: &[String],
    vars: &HashMap<String, String>,
    specifiers: &[(&str, &str)],
) -> Vec<String> {
    let mut out = Vec::new();
    for word in words {
        if let Some(name) = word.strip_prefix('$').filter(|n| !n.starts_with('{')) {
            let value = vars
                .get(name)
                .unwrap_or_else(|| panic!("${name} is not set"));
            out.extend(value.split_whitespace().map(str::to_string));
            continue;
        }
        let mut w = word.clone();
        for (k, v) in vars {
            w = w.replace(&format!("${{{k}}}"), v);
        }
        for (spec, value) in specifiers {
            w = w.replace(spec, value);
        }
        assert!(
            !w.contains("${") && !w.contains('%'),
            "{word} left unexpanded: {w}"
        );
        out.push(w);
    }
    out
}

#[test]
fn units_pass_systemd_analyze_verify() {
    let test = "units_pass_systemd_analyze_verify";
    let install = "apt-get install systemd";
    let Some(tools) = require_tools(test, &["systemd-analyze"], install) else {
        return;
    };
    let analyze = &tools[0];
    let dir = tempfile::tempdir().unwrap();
    let master = bin("tessera-master");
    for (template, instance) in [
        ("tessera-render-node@.service", "render-a"),
        ("tessera-display-node@.service", "0"),
    ] {
        let (_, text) = unit(template);
        for needed in [
            "Type=notify",
            "Restart=on-failure",
            "RestartSec=",
            "EnvironmentFile=/etc/tessera/node.env",
            "--reconnect",
        ] {
            assert!(text.contains(needed), "{template} lacks {needed}");
        }
        assert_eq!(
            exec_start(&text)[0],
            INSTALLED,
            "{template}: ExecStart runs the installed path"
        );
        // systemd-analyze checks that ExecStart's binary exists: point the copy at the one
        // this build made.
        let copy = text.replace(INSTALLED, master.to_str().unwrap());
        std::fs::write(dir.path().join(template), &copy).unwrap();
        let instance_unit = dir
            .path()
            .join(template.replace("@.", &format!("@{instance}.")));
        let o = std::process::Command::new(analyze)
            .arg("verify")
            .arg(&instance_unit)
            .output()
            .expect("run systemd-analyze");
        let said =
            String::from_utf8_lossy(&o.stderr).to_string() + &String::from_utf8_lossy(&o.stdout);
        assert!(
            o.status.success() && said.trim().is_empty(),
            "systemd-analyze verify {template} ({}):\n{said}",
            o.status
        );

        // The check is real: the same unit with a binary that is not there fails it.
        let broken = dir.path().join(template.replace("tessera-", "broken-"));
        std::fs::write(
            &broken,
            text.replace(INSTALLED, "/nonexistent/tessera-master"),
        )
        .unwrap();
        let broken_instance = broken
            .to_str()
            .unwrap()
            .replace("@.", &format!("@{instance}."));
        let o = std::process::Command::new(analyze)
            .args(["verify", &broken_instance])
            .output()
            .expect("run systemd-analyze");
        assert!(
            !o.status.success(),
            "verify passed a unit whose binary is missing"
        );
    }
}

/// Receives the datagrams a node sent to its notify socket until `want` is among them or
/// `limit` passes; returns them all.
fn received_until(socket: &UnixDatagram, want: &str, limit: Duration) -> Vec<String> {
    let deadline = Instant::now() + limit;
    let mut seen = Vec::new();
    let mut buf = [0u8; 1024];
    socket
        .set_read_timeout(Some(Duration::from_millis(200)))
        .unwrap();
    while Instant::now() < deadline && !seen.iter().any(|m: &String| m.starts_with(want)) {
        if let Ok(n) = socket.recv(&mut buf) {
            seen.push(String::from_utf8_lossy(&buf[..n]).to_string());
        }
    }
    seen
}

#[test]
fn unit_command_lines_run_nodes_that_notify_systemd() {
    let dir = tempfile::tempdir().unwrap();
    let cluster = dir.path().join("cluster");
    let out = dir.path().join("out");
    let master = Proc::start(
        "tessera-master",
        &[
            "serve",
            "--listen",
            "127.0.0.1:0",
            "--cluster-dir",
            cluster.to_str().unwrap(),
            "--render-nodes",
            "1",
            "--wall",
            "1x1",
            "--screen",
            "96x54",
            "--frames",
            "8",
            "--out",
            out.to_str().unwrap(),
        ],
    );
    let line = master.wait_for_stderr("listening on", Duration::from_secs(60));
    let addr = line.rsplit(' ').next().unwrap().to_string();
    let state = dir.path().join("state");
    let cache = dir.path().join("cache");
    let env = [("TESSERA_MASTER", addr.as_str())];

    let mut nodes = Vec::new();
    let mut sockets = Vec::new();
    for (template, instance, cert) in [
        ("tessera-display-node@.service", "0", "display-0"),
        ("tessera-render-node@.service", "render-a", "render-a"),
    ] {
        let (_, text) = unit(template);
        let cert_dir = issue_cert(&cluster, cert);
        let specifiers = [
            ("%i", instance),
            ("%d", cert_dir.as_str()),
            ("%C", cache.to_str().unwrap()),
            ("%S", state.to_str().unwrap()),
        ];
        let words = expand(&exec_start(&text), &environment(&text, &env), &specifiers);
        assert_eq!(words[0], INSTALLED);
        let socket_path = dir.path().join(format!("notify-{instance}"));
        sockets.push((instance, UnixDatagram::bind(&socket_path).unwrap()));
        let args: Vec<&str> = words[1..].iter().map(String::as_str).collect();
        nodes.push(Proc::start_with_env(
            "tessera-master",
            &args,
            &[("NOTIFY_SOCKET", socket_path.to_str().unwrap())],
        ));
    }
    for (instance, socket) in &sockets {
        let seen = received_until(socket, "READY=1", Duration::from_secs(60));
        assert!(
            seen.iter().any(|m| m.starts_with("READY=1\nSTATUS=")),
            "node {instance} never said READY=1: {seen:?}"
        );
    }
    let o = master.wait(Duration::from_secs(60));
    o.assert_success("tessera-master serve");
    for (instance, socket) in &sockets {
        let seen = received_until(socket, "STOPPING=1", Duration::from_secs(30));
        assert!(
            seen.iter().any(|m| m.starts_with("STOPPING=1")),
            "node {instance} left without STOPPING=1: {seen:?}"
        );
    }
    // The wall ended: the nodes exit 0, so Restart=on-failure leaves them stopped.
    for node in nodes {
        node.wait(Duration::from_secs(30))
            .assert_success("a node run from its unit's ExecStart");
    }
    let report = read_json(&out.join("report.json"));
    assert_eq!(report["frames"].as_u64(), Some(8));
}

/// `tessera-master-standby.service`: passes `systemd-analyze verify` (where it is installed),
/// and the very command line its `ExecStart` gives follows a live primary as its standby and
/// leaves, with status 0, when the primary's run ends.
#[test]
fn the_standby_unit_verifies_and_its_command_line_follows_a_primary() {
    let name = "tessera-master-standby.service";
    let (_, text) = unit(name);
    let dir = tempfile::tempdir().unwrap();
    let master = bin("tessera-master");
    let install = "apt-get install systemd";
    let test = "the_standby_unit_verifies_and_its_command_line_follows_a_primary";
    if let Some(tools) = require_tools(test, &["systemd-analyze"], install) {
        let copy = dir.path().join(name);
        std::fs::write(&copy, text.replace(INSTALLED, master.to_str().unwrap())).unwrap();
        let o = std::process::Command::new(&tools[0])
            .arg("verify")
            .arg(&copy)
            .output()
            .expect("run systemd-analyze");
        let said =
            String::from_utf8_lossy(&o.stderr).to_string() + &String::from_utf8_lossy(&o.stdout);
        assert!(
            o.status.success() && said.trim().is_empty(),
            "{name}:\n{said}"
        );
    }
    let cluster = dir.path().join("cluster");
    let run = [
        "--render-nodes",
        "1",
        "--wall",
        "1x1",
        "--screen",
        "64x36",
        "--frames",
        "0",
    ];
    let mut args = vec!["serve", "--listen", "127.0.0.1:0", "--cluster-dir"];
    args.push(cluster.to_str().unwrap());
    args.extend(run);
    let primary = Proc::start("tessera-master", &args);
    let line = primary.wait_for_stderr("listening on", Duration::from_secs(60));
    let addr = line.rsplit(' ').next().expect("an address").to_string();
    let serve_args = run.join(" ");
    let env = [
        ("TESSERA_PRIMARY", addr.as_str()),
        ("TESSERA_STANDBY_LISTEN", "127.0.0.1:0"),
        ("TESSERA_SERVE_ARGS", serve_args.as_str()),
    ];
    let vars = environment(&text, &env);
    let state = dir.path().join("state");
    let words = expand(
        &exec_start(&text),
        &vars,
        &[("%S", state.to_str().unwrap())],
    );
    assert_eq!(
        words[0], INSTALLED,
        "{name}: ExecStart runs the installed path"
    );
    // The test's cluster directory stands for /etc/tessera/cluster.
    let words: Vec<String> = words[1..]
        .iter()
        .map(|w| w.replace("/etc/tessera/cluster", cluster.to_str().unwrap()))
        .collect();
    let words: Vec<&str> = words.iter().map(String::as_str).collect();
    let standby = Proc::start_program(&master, "standby", &words, &[]);
    primary.wait_for_stderr("standby master at", Duration::from_secs(30));
    standby.wait_for_stderr("following its run", Duration::from_secs(30));
    primary.signal(libc::SIGINT);
    primary.wait(Duration::from_secs(60));
    let o = standby.wait(Duration::from_secs(30));
    o.assert_success("the standby of a primary whose run ended");
    assert!(
        o.stderr.contains("the primary's run is over"),
        "{}",
        o.stderr
    );
}
