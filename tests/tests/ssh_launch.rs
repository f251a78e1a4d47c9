//! `tessera-master launch --hosts FILE`: a 2x1 wall whose displays and render node are started
//! over ssh, through an sshd of the test's own on 127.0.0.1 (its host key, authorized key and
//! configuration in a temporary directory, run in the foreground as a child). The wall runs to
//! its end, then until a SIGINT, then with a render node that fails to start, then until a
//! SIGKILL of the launcher; after each, no node, ssh or sshd session is left. Needs root and openssh-server (`.ci/run`
//! installs it); the host-file checks run everywhere.

use std::path::{Path, PathBuf};
use std::time::Duration;
use tessera_tests::*;

const TEST: &str = "launch_runs_a_wall_over_ssh_and_leaves_nothing";

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The PIDs whose parent is `parent`.
fn child_pids(parent: u32) -> Vec<u32> {
    let children = tessera_cli::procs::children_of(parent);
    children.into_iter().map(|c| c.pid).collect()
}

/// An sshd on 127.0.0.1 that lets root in with the test's key; killed and reaped on drop.
struct Sshd {
    proc: Proc,
    port: u16,
    key: PathBuf,
}

impl Sshd {
    fn start(dir: &Path, tools: &[PathBuf]) -> Sshd {
        let (sshd, keygen) = (&tools[0], &tools[1]);
        let key = dir.join("id_ed25519");
        for k in [&dir.join("host_key"), &key] {
            let o = Proc::start_program(
                keygen,
                "ssh-keygen",
                &["-q", "-t", "ed25519", "-N", "", "-f", k.to_str().unwrap()],
                &[],
            )
            .wait(Duration::from_secs(30));
            o.assert_success("ssh-keygen");
        }
        std::fs::copy(dir.join("id_ed25519.pub"), dir.join("authorized_keys")).unwrap();
        // sshd refuses to start without its privilege-separation directory, which Debian makes
        // at boot (tmpfiles) rather than at install.
        std::fs::create_dir_all("/run/sshd").unwrap();
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let d = dir.display();
        let config = dir.join("sshd_config");
        std::fs::write(
            &config,
            format!(
                "Port {port}\nListenAddress 127.0.0.1\nHostKey {d}/host_key\nPidFile {d}/sshd.pid\n\
                 AuthorizedKeysFile {d}/authorized_keys\nPermitRootLogin prohibit-password\n\
                 PasswordAuthentication no\nKbdInteractiveAuthentication no\nUsePAM no\n\
                 StrictModes no\nSubsystem sftp internal-sftp\nLogLevel INFO\n"
            ),
        )
        .unwrap();
        // sshd re-executes itself, so it must be started by its absolute path.
        let proc = Proc::start_program(
            sshd,
            "sshd",
            &["-D", "-e", "-f", config.to_str().unwrap()],
            &[],
        );
        proc.wait_for_stderr("Server listening on", Duration::from_secs(30));
        Sshd { proc, port, key }
    }

    /// Waits, bounded, until no session of this sshd is left.
    fn assert_no_sessions(&self) {
        let pid = self.proc.pid();
        assert!(
            wait_for(Duration::from_secs(20), || child_pids(pid).is_empty()),
            "sshd sessions left: {:?}",
            child_pids(pid)
        );
    }
}

/// A host file for the wall: displays 0 and 1 on one host entry, the render node on another,
/// both 127.0.0.1 through `sshd`; remote certificates under `remote`.
fn host_file(dir: &Path, sshd: &Sshd, remote: &Path) -> PathBuf {
    let master = bin("tessera-master");
    let text = format!(
        r#"
[master]
address = "127.0.0.1"
listen = "127.0.0.1:0"

[ssh]
user = "root"
port = {port}
options = ["-F", "none", "-i", "{key}", "-o", "StrictHostKeyChecking=no", "-o", "UserKnownHostsFile=/dev/null"]
tessera = "{master}"
remote_dir = "{remote}"

[[host]]
address = "127.0.0.1"
displays = [0, 1]

[[host]]
address = "127.0.0.1"
render = 1
threads = 1
"#,
        port = sshd.port,
        key = sshd.key.display(),
        master = master.display(),
        remote = remote.display(),
    );
    let path = dir.join("hosts.toml");
    std::fs::write(&path, text).unwrap();
    path
}

fn launch_args<'a>(hosts: &'a str, out: &'a str, frames: &'a str) -> Vec<&'a str> {
    vec![
        "launch", "--hosts", hosts, "--wall", "2x1", "--screen", "160x90", "--frames", frames,
        "--out", out,
    ]
}

/// Nothing the run started is left: no node (their command lines name the remote directory),
/// no ssh (they name the test's key), no sshd session, no remote certificates.
fn assert_nothing_left(dir: &Path, remote: &Path, sshd: &Sshd) {
    let tmp = dir.display().to_string();
    let sshd_pid = sshd.proc.pid();
    let ours = || -> Vec<u32> {
        processes_mentioning(&tmp)
            .into_iter()
            .filter(|&p| p != sshd_pid)
            .collect()
    };
    assert!(
        wait_for(Duration::from_secs(20), || ours().is_empty()),
        "processes left behind: {:?}",
        ours()
    );
    sshd.assert_no_sessions();
    let runs: Vec<_> = std::fs::read_dir(remote)
        .unwrap()
        .flatten()
        .map(|e| e.file_name())
        .collect();
    assert!(runs.is_empty(), "remote run directories left: {runs:?}");
}

fn check_report(out: &Path, at_least: u64) -> u64 {
    let report = read_json(&out.join("report.json"));
    let frames = report["frames"].as_u64().unwrap();
    assert!(frames >= at_least, "{frames} frames");
    let displays = report["displays"].as_array().unwrap();
    assert_eq!(displays.len(), 2);
    for d in displays {
        assert_eq!(d["frames_presented"].as_u64(), Some(frames), "{d}");
    }
    assert_eq!(report["render_nodes"].as_array().unwrap().len(), 1);
    frames
}

#[test]
fn launch_runs_a_wall_over_ssh_and_leaves_nothing() {
    if !is_root() {
        skip(TEST, "not root (the test's sshd lets root in)");
        return;
    }
    let install = "apt-get install openssh-server openssh-client";
    let Some(tools) = require_tools(TEST, &["sshd", "ssh-keygen", "ssh", "scp"], install) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let remote = dir.path().join("remote");
    std::fs::create_dir(&remote).unwrap();
    let sshd = Sshd::start(dir.path(), &tools);
    let hosts = host_file(dir.path(), &sshd, &remote);
    let hosts = hosts.to_str().unwrap();

    // To the end of its frames.
    let out = dir.path().join("out");
    let out_s = out.to_str().unwrap();
    let o = Proc::start("tessera-master", &launch_args(hosts, out_s, "20"))
        .wait(Duration::from_secs(120));
    o.assert_success("launch");
    assert_eq!(check_report(&out, 20), 20);
    for label in [
        "[display-0@127.0.0.1]",
        "[display-1@127.0.0.1]",
        "[render-0@127.0.0.1]",
    ] {
        assert!(
            o.stderr.contains(label),
            "no output from {label}:\n{}",
            o.stderr
        );
    }
    assert_nothing_left(dir.path(), &remote, &sshd);

    // Until Ctrl-C, once frame 3 is saved (the wall is running): the master still finishes in
    // order, writes its report and wall.png, and stops every node.
    let out = dir.path().join("interrupted");
    let out_s = out.to_str().unwrap();
    let mut args = launch_args(hosts, out_s, "0");
    args.extend(["--save-frame", "3"]);
    let launcher = Proc::start("tessera-master", &args);
    let saved = wait_for(Duration::from_secs(60), || {
        out.join("display-1.png").exists() && out.join("display-0.png").exists()
    });
    if !saved {
        launcher.fail("the wall never saved frame 3");
    }
    launcher.signal(libc::SIGINT);
    let o = launcher.wait(Duration::from_secs(60));
    assert_eq!(o.status.code(), Some(130), "{}", o.stderr);
    check_report(&out, 4);
    assert!(out.join("wall.png").exists(), "{}", o.stderr);
    assert_nothing_left(dir.path(), &remote, &sshd);

    // A node that fails (here: no such program on its host) ends the run, naming it, and the
    // others are stopped.
    let bad = std::fs::read_to_string(hosts).unwrap().replace(
        "threads = 1",
        "threads = 1\ntessera = \"/nonexistent/tessera-master\"",
    );
    let bad_hosts = dir.path().join("bad-tessera.toml");
    std::fs::write(&bad_hosts, bad).unwrap();
    let out = dir.path().join("failed");
    let args = launch_args(bad_hosts.to_str().unwrap(), out.to_str().unwrap(), "20");
    let o = Proc::start("tessera-master", &args).wait(Duration::from_secs(60));
    o.assert_refused(
        "launch with a missing render node binary",
        &["render-0@127.0.0.1", "127"],
    );
    assert_nothing_left(dir.path(), &remote, &sshd);

    // Killed outright, the launcher cannot clean up: its ssh clients die with it
    // (PR_SET_PDEATHSIG) and sshd hangs their terminals up, which ends the nodes.
    let out = dir.path().join("killed");
    let out_s = out.to_str().unwrap();
    let launcher = Proc::start("tessera-master", &launch_args(hosts, out_s, "0"));
    launcher.wait_for_stderr("all nodes ready", Duration::from_secs(60));
    launcher.signal(libc::SIGKILL);
    let _ = launcher.wait(Duration::from_secs(30));
    let tmp = dir.path().display().to_string();
    let sshd_pid = sshd.proc.pid();
    let left = || -> Vec<u32> {
        processes_mentioning(&tmp)
            .into_iter()
            .filter(|&p| p != sshd_pid)
            .collect()
    };
    assert!(
        wait_for(Duration::from_secs(20), || left().is_empty()),
        "a killed launcher left processes: {:?}",
        left()
    );
    sshd.assert_no_sessions();
}

#[test]
fn the_example_host_file_plans_a_2x2_wall() {
    let example = repo().join("deploy/hosts/example.toml");
    let o = run(
        "tessera-master",
        &[
            "launch",
            "--hosts",
            example.to_str().unwrap(),
            "--wall",
            "2x2",
            "--dry-run",
        ],
        Duration::from_secs(30),
    );
    o.assert_success("launch --dry-run on deploy/hosts/example.toml");
    for node in [
        "display-0",
        "display-1",
        "display-2",
        "display-3",
        "render-0",
        "render-1",
        "render-2",
        "render-3",
    ] {
        assert!(
            o.stdout.contains(node),
            "no {node} in the plan:\n{}",
            o.stdout
        );
    }
    // gpu-box's own user and port, and the display ports counted up from display_port.
    assert!(
        o.stdout.contains("User=wall") && o.stdout.contains("Port=2222"),
        "{}",
        o.stdout
    );
    assert!(o.stdout.contains("0.0.0.0:7402"), "{}", o.stdout);
    assert!(
        o.stdout.contains("wall-head.example.org:7400"),
        "{}",
        o.stdout
    );
}

#[test]
fn a_bad_host_file_is_refused_naming_the_host_and_field() {
    let dir = tempfile::tempdir().unwrap();
    let example = std::fs::read_to_string(repo().join("deploy/hosts/example.toml")).unwrap();
    let cases = [
        (
            example.replace("port = 2222", "port = \"ssh\""),
            vec!["host 5 (gpu-box.example.org)", "port"],
        ),
        (
            example.replace("render = 2", "rendr = 2"),
            vec!["host 5 (gpu-box.example.org)", "rendr"],
        ),
        (
            example.replace("displays = [2, 3]", "displays = [2, 1]"),
            vec!["display 1", "host 1", "host 2"],
        ),
        (
            example.replace("displays = [2, 3]", "displays = [2, 4]"),
            vec!["host 2 (wall-disp-b.example.org)", "display 4"],
        ),
    ];
    for (i, (text, words)) in cases.iter().enumerate() {
        let path = dir.path().join(format!("bad-{i}.toml"));
        std::fs::write(&path, text).unwrap();
        let o = run(
            "tessera-master",
            &[
                "launch",
                "--hosts",
                path.to_str().unwrap(),
                "--wall",
                "2x2",
                "--dry-run",
            ],
            Duration::from_secs(30),
        );
        let mut all = words.clone();
        all.push(path.to_str().unwrap());
        o.assert_refused(&format!("bad host file {i}"), &all);
    }
}
