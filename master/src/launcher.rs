//! `tessera-master local`: the wall's nodes as child processes on 127.0.0.1.
//!
//! Children get certificates from a fresh cluster CA in a temporary directory, are killed when
//! the master exits (also on a crash: `PR_SET_PDEATHSIG`), and are always reaped.

use anyhow::{Context, Result};
use std::path::Path;
use std::process::ExitStatus;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;
use tokio::process::{Child, Command};

pub struct NodeProcess {
    pub name: String,
    /// A display's death ends the run; a render node's is survivable.
    pub essential: bool,
    child: Child,
}

/// Has the kernel send `signal` to the process `cmd` starts when this process dies (Linux;
/// elsewhere nothing), so that a launcher killed without cleaning up leaves no child behind.
pub fn die_with_parent(cmd: &mut Command, signal: libc::c_int) {
    #[cfg(target_os = "linux")]
    // SAFETY: the closure runs in the child between fork and exec and calls only prctl, which
    // is async-signal-safe, and reads errno.
    unsafe {
        cmd.pre_exec(move || {
            if libc::prctl(libc::PR_SET_PDEATHSIG, signal) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    #[cfg(not(target_os = "linux"))]
    let _ = (cmd, signal);
}

pub fn spawn(
    name: String,
    essential: bool,
    program: &Path,
    args: &[String],
) -> Result<NodeProcess> {
    let mut cmd = Command::new(program);
    cmd.args(args)
        .kill_on_drop(true)
        .stdin(std::process::Stdio::null());
    // If the master dies without cleaning up, the kernel kills the children: no orphans.
    die_with_parent(&mut cmd, libc::SIGKILL);
    let child = cmd
        .spawn()
        .with_context(|| format!("cannot start {name} ({})", program.display()))?;
    tracing::debug!("started {name} (pid {:?})", child.id());
    Ok(NodeProcess {
        name,
        essential,
        child,
    })
}

/// Watches children while the run goes on. Returns when an essential child dies, or when any
/// child dies before the first frame (a node that cannot start is a configuration error).
pub async fn watch(
    children: &mut Vec<NodeProcess>,
    started: Arc<AtomicBool>,
    lost: &mut Vec<String>,
) -> anyhow::Error {
    loop {
        let mut dead = None;
        for (i, c) in children.iter_mut().enumerate() {
            if let Ok(Some(status)) = c.child.try_wait() {
                dead = Some((i, status));
                break;
            }
        }
        if let Some((i, status)) = dead {
            let c = children.remove(i);
            if status.success() {
                // Nodes exit 0 only after the master's shutdown; the run is ending.
                continue;
            }
            let what = format!("{} exited with {}", c.name, describe(status));
            if c.essential || !started.load(Ordering::SeqCst) {
                return anyhow::anyhow!("{what}; stopping the wall (see its log lines above)");
            }
            let rest = if c.name.starts_with("display") {
                "the other displays go on without it"
            } else {
                "the other render nodes take over its tiles"
            };
            tracing::error!("{what}; {rest}");
            lost.push(what);
            continue;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

fn describe(status: ExitStatus) -> String {
    use std::os::unix::process::ExitStatusExt;
    match (status.code(), status.signal()) {
        (Some(code), _) => format!("status {code}"),
        (None, Some(sig)) => format!("signal {sig}"),
        _ => status.to_string(),
    }
}

/// Stops every child: waits up to `grace` for them to exit on their own (they were told to
/// shut down), then kills and reaps the rest.
pub async fn reap(children: &mut Vec<NodeProcess>, grace: Duration) -> Vec<String> {
    let mut failures = Vec::new();
    let deadline = tokio::time::Instant::now() + grace;
    for c in children.iter_mut() {
        let status = match tokio::time::timeout_at(deadline, c.child.wait()).await {
            Ok(Ok(status)) => Some(status),
            _ => {
                let _ = c.child.start_kill();
                c.child.wait().await.ok();
                None
            }
        };
        match status {
            Some(s) if s.success() => {}
            Some(s) => failures.push(format!("{} exited with {}", c.name, describe(s))),
            None => failures.push(format!("{} did not exit and was killed", c.name)),
        }
    }
    children.clear();
    failures
}
