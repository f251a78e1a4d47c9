//! ssh and scp for `tessera-master launch`: the command lines, the run's directory on each
//! host, and the nodes as ssh children whose output is streamed with a prefix.
//!
//! A node runs under `ssh -tt`: the remote command gets a terminal, so when its ssh client
//! goes (stopped by the launcher, or killed with it: `PR_SET_PDEATHSIG`) sshd hangs the
//! terminal up and the kernel sends the node SIGHUP. Nothing is left running on a host
//! whatever happens to the launcher, short of a host that cannot be reached any more.

use super::hosts::Host;
use anyhow::{bail, Context, Result};
use std::os::unix::process::ExitStatusExt;
use std::path::Path;
use std::process::{ExitStatus, Stdio};
use std::time::Duration;
use tokio::io::{AsyncBufReadExt, AsyncRead, BufReader};
use tokio::process::{Child, Command};
use tokio::task::JoinHandle;

/// Longest a one-off ssh or scp command (make a directory, copy certificates, remove them)
/// may take.
const STEP_TIMEOUT: Duration = Duration::from_secs(60);
/// Options every ssh and scp gets after the host file's own (ssh keeps the first value of an
/// option, so the host file's win): never prompt (nobody can answer), give up on a dead link.
const DEFAULT_OPTIONS: [&str; 8] = [
    "-o",
    "BatchMode=yes",
    "-o",
    "ConnectTimeout=10",
    "-o",
    "ServerAliveInterval=5",
    "-o",
    "ServerAliveCountMax=3",
];

/// `text` quoted for a POSIX shell: the remote side of ssh parses its command line again.
pub fn shell_quote(text: &str) -> String {
    if !text.is_empty()
        && text
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_./:=@,+%".contains(c))
    {
        return text.to_string();
    }
    format!("'{}'", text.replace('\'', r"'\''"))
}

/// `words` as one shell command line.
pub fn shell_line(words: &[String]) -> String {
    words
        .iter()
        .map(|w| shell_quote(w))
        .collect::<Vec<_>>()
        .join(" ")
}

/// The options that pick the port and user, then the host file's, then the defaults.
fn connection_options(host: &Host) -> Vec<String> {
    let mut args = Vec::new();
    if let Some(port) = host.port {
        args.extend(["-o".to_string(), format!("Port={port}")]);
    }
    if let Some(user) = &host.user {
        args.extend(["-o".to_string(), format!("User={user}")]);
    }
    args.extend(host.options.iter().cloned());
    for pair in DEFAULT_OPTIONS.chunks(2) {
        let key = pair[1].split('=').next().unwrap_or_default();
        if !sets_option(&host.options, key) {
            args.extend(pair.iter().map(|s| s.to_string()));
        }
    }
    args
}

/// Whether ssh arguments `options` set `key` (`-o Key=...` or `-oKey=...`, any case).
fn sets_option(options: &[String], key: &str) -> bool {
    let key = key.to_ascii_lowercase();
    options.iter().any(|o| {
        let o = o
            .strip_prefix("-o")
            .unwrap_or(o)
            .trim_start()
            .to_ascii_lowercase();
        o.strip_prefix(&key)
            .is_some_and(|rest| rest.starts_with('=') || rest.starts_with(' '))
    })
}

/// The arguments of `ssh` running `remote` (a shell command line) on `host`; `tty` forces a
/// terminal (`-tt`), for nodes.
pub fn ssh_args(host: &Host, tty: bool, remote: &str) -> Vec<String> {
    let mut args = Vec::new();
    if tty {
        args.push("-tt".to_string());
        // Without it ssh says "Connection to HOST closed." on every exit of a node.
        args.extend(["-o".to_string(), "LogLevel=ERROR".to_string()]);
    }
    args.extend(connection_options(host));
    args.push(host.address.clone());
    args.push(remote.to_string());
    args
}

/// The arguments of `scp` copying the local directories `dirs` into `remote_dir` on `host`.
pub fn scp_args(host: &Host, dirs: &[&Path], remote_dir: &str) -> Vec<String> {
    let mut args = vec!["-q".to_string(), "-r".to_string()];
    args.extend(connection_options(host));
    args.extend(dirs.iter().map(|d| d.display().to_string()));
    // An IPv6 address needs brackets to keep its colons from the path's.
    let address = if host.address.contains(':') {
        format!("[{}]", host.address)
    } else {
        host.address.clone()
    };
    args.push(format!("{address}:{remote_dir}/"));
    args
}

/// Runs `program args` to completion within [`STEP_TIMEOUT`]; fails with `what`, the host and
/// what the program said.
pub async fn step(host: &Host, what: &str, program: &str, args: &[String]) -> Result<()> {
    let run = Command::new(program)
        .args(args)
        .stdin(Stdio::null())
        .kill_on_drop(true)
        .output();
    let output = tokio::time::timeout(STEP_TIMEOUT, run)
        .await
        .map_err(|_| {
            anyhow::anyhow!(
                "{}: cannot {what}: `{program}` took longer than {} s",
                host.label(),
                STEP_TIMEOUT.as_secs()
            )
        })?
        .with_context(|| format!("cannot run {program} (is openssh-client installed?)"))?;
    if !output.status.success() {
        let said = String::from_utf8_lossy(&output.stderr);
        let hint = if output.status.code() == Some(255) {
            " (ssh could not connect or log in: check the host's `address`, `port`, `user` and `options`, and that `ssh HOST true` works without a password)"
        } else {
            ""
        };
        bail!(
            "{}: cannot {what}: {program} exited with {}{hint}: {}",
            host.label(),
            describe(output.status),
            said.trim()
        );
    }
    Ok(())
}

/// A node's ssh client and the tasks streaming its output.
pub struct RemoteNode {
    /// `render-0@HOST`: the prefix of its output lines and its name in messages.
    pub label: String,
    child: Child,
    streams: Vec<JoinHandle<()>>,
}

impl RemoteNode {
    /// Starts `remote` on `host` under `ssh -tt`, its output printed line by line after
    /// `[label] `.
    ///
    /// # Errors
    /// ssh cannot be started.
    pub fn start(label: String, host: &Host, remote: &str) -> Result<RemoteNode> {
        let mut cmd = Command::new("ssh");
        cmd.args(ssh_args(host, true, remote))
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .kill_on_drop(true)
            // Its own process group: a Ctrl-C at the terminal reaches the launcher alone, which
            // stops the wall in order rather than have every ssh cut its node off at once.
            .process_group(0);
        // Should the launcher die, ssh goes too, and with it (hang-up) the remote node.
        crate::launcher::die_with_parent(&mut cmd, libc::SIGTERM);
        let mut child = cmd.spawn().with_context(|| {
            format!("cannot start ssh for {label} (is openssh-client installed?)")
        })?;
        let mut streams = Vec::new();
        if let Some(out) = child.stdout.take() {
            streams.push(tokio::spawn(prefix_lines(label.clone(), out)));
        }
        if let Some(err) = child.stderr.take() {
            streams.push(tokio::spawn(prefix_lines(label.clone(), err)));
        }
        Ok(RemoteNode {
            label,
            child,
            streams,
        })
    }

    /// Its exit status, if its ssh has exited.
    pub fn exited(&mut self) -> Option<ExitStatus> {
        self.child.try_wait().ok().flatten()
    }

    /// Waits up to `grace` for ssh to exit by itself (the node left after the master's
    /// shutdown); then SIGTERM (ssh closes the session: the node gets SIGHUP), and 5 s later
    /// SIGKILL. Always reaps it. Returns a problem to report, if any.
    pub async fn stop(mut self, grace: Duration) -> Option<String> {
        let status = match tokio::time::timeout(grace, self.child.wait()).await {
            Ok(Ok(status)) => Some(status),
            _ => None,
        };
        let problem = match status {
            Some(s) if s.success() => None,
            Some(s) => Some(format!("{} exited with {}", self.label, describe(s))),
            None => {
                if let Some(pid) = self.child.id() {
                    // SAFETY: kill only sends a signal and touches no memory of ours. `id` is
                    // `Some` only while the child is not reaped, so the pid is still ssh's.
                    unsafe {
                        libc::kill(pid as i32, libc::SIGTERM);
                    }
                }
                if tokio::time::timeout(Duration::from_secs(5), self.child.wait())
                    .await
                    .is_err()
                {
                    let _ = self.child.start_kill();
                }
                let _ = self.child.wait().await;
                Some(format!("{} did not exit and was stopped", self.label))
            }
        };
        for stream in self.streams {
            // The pipes close with ssh; a remote that still held them is cut off.
            if tokio::time::timeout(Duration::from_secs(2), stream)
                .await
                .is_err()
            {
                tracing::debug!("{}: output still open after ssh exited", self.label);
            }
        }
        problem
    }
}

/// Prints each line of `stream` after `[label] ` until it ends.
async fn prefix_lines(label: String, stream: impl AsyncRead + Unpin) {
    use std::io::IsTerminal;
    // Nodes colour their logs for the terminal ssh gives them; a log file wants none.
    let plain = !std::io::stderr().is_terminal();
    let mut lines = BufReader::new(stream).lines();
    while let Ok(Some(line)) = lines.next_line().await {
        // The remote terminal ends lines with CR LF.
        let line = line.trim_end_matches('\r');
        if plain {
            eprintln!("[{label}] {}", strip_colours(line));
        } else {
            eprintln!("[{label}] {line}");
        }
    }
}

/// `line` without its terminal escape sequences (`ESC [ ... letter`).
fn strip_colours(line: &str) -> String {
    let mut out = String::with_capacity(line.len());
    let mut chars = line.chars();
    while let Some(c) = chars.next() {
        if c != '\u{1b}' {
            out.push(c);
            continue;
        }
        if chars.next() == Some('[') {
            // Parameters and intermediates, up to the final letter (bounded by the line).
            for c in chars.by_ref() {
                if c.is_ascii_alphabetic() || c == '~' {
                    break;
                }
            }
        }
    }
    out
}

/// An exit status in words.
pub fn describe(status: ExitStatus) -> String {
    match (status.code(), status.signal()) {
        (Some(255), _) => "status 255 (ssh failed: host unreachable, or login refused)".into(),
        (Some(127), _) => {
            "status 127 (no such program on the host: check the host file's `tessera`)".into()
        }
        (Some(code), _) => format!("status {code}"),
        (None, Some(sig)) => format!("signal {sig}"),
        _ => status.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn host() -> Host {
        Host {
            number: 1,
            address: "::1".into(),
            user: Some("wall".into()),
            port: Some(2222),
            options: vec!["-i".into(), "/k".into()],
            tessera: "/t".into(),
            remote_dir: "/r".into(),
            render: 1,
            threads: None,
            render_args: vec![],
            displays: vec![],
            display_port: None,
            display_args: vec![],
        }
    }

    #[test]
    fn quoting_survives_the_remote_shell() {
        assert_eq!(shell_quote("render-node"), "render-node");
        assert_eq!(shell_quote("a b"), "'a b'");
        assert_eq!(shell_quote("it's"), r"'it'\''s'");
        assert_eq!(shell_quote(""), "''");
        assert_eq!(shell_quote("$(reboot)"), "'$(reboot)'");
        let words = ["exec".to_string(), "/t".into(), "x y".into()];
        assert_eq!(shell_line(&words), "exec /t 'x y'");
    }

    #[test]
    fn host_settings_come_before_the_defaults() {
        let args = ssh_args(&host(), true, "exec true");
        assert_eq!(&args[..3], ["-tt", "-o", "LogLevel=ERROR"]);
        let port = args.iter().position(|a| a == "Port=2222").unwrap();
        let batch = args.iter().position(|a| a == "BatchMode=yes").unwrap();
        assert!(port < batch);
        assert!(args.contains(&"User=wall".to_string()));
        assert_eq!(&args[args.len() - 2..], ["::1", "exec true"]);
    }

    #[test]
    fn a_default_the_host_file_sets_is_left_out() {
        let mut h = host();
        h.options = vec![
            "-o".into(),
            "ConnectTimeout=3".into(),
            "-oBatchMode=no".into(),
        ];
        let args = ssh_args(&h, false, "true");
        let timeouts = args
            .iter()
            .filter(|a| a.starts_with("ConnectTimeout"))
            .count();
        assert_eq!(timeouts, 1, "{args:?}");
        assert!(!args.contains(&"BatchMode=yes".to_string()), "{args:?}");
        assert!(args.contains(&"ServerAliveInterval=5".to_string()));
    }

    #[test]
    fn colours_are_stripped() {
        let line = "\u{1b}[2mtime\u{1b}[0m \u{1b}[32m INFO\u{1b}[0m ready";
        assert_eq!(strip_colours(line), "time  INFO ready");
        assert_eq!(strip_colours("plain"), "plain");
    }

    #[test]
    fn scp_brackets_an_ipv6_address() {
        let args = scp_args(&host(), &[Path::new("/local/render-0")], "/r/run");
        assert_eq!(args.last().unwrap(), "[::1]:/r/run/");
        assert!(args.contains(&"/local/render-0".to_string()));
    }
}
