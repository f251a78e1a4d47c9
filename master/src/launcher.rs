//! `tessera-master local`: the wall's nodes as child processes on 127.0.0.1.
//!
//! Children get certificates from a fresh cluster CA in a temporary directory, are killed when
//! the master exits (also on a crash: `PR_SET_PDEATHSIG`), and are always reaped. Log lines
//! name a child as the master's own lines and the report name its node (`render node 2`, by
//! the id the master gave it when it joined, not by the order it was started in), with its pid.

use crate::server::{ExitedNode, RunSignals};
use anyhow::{Context, Result};
use std::path::Path;
use std::process::ExitStatus;
use std::sync::atomic::Ordering;
use std::time::Duration;
use tessera_model::wall::DisplayId;
use tessera_protocol::RenderNodeId;
use tokio::process::{Child, Command};

/// Which node a child process runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NodeKind {
    /// Display node `id`.
    Display(u32),
    /// The `slot`-th render node started; the master numbers it when it joins.
    Render {
        /// Its place in the order of starting.
        slot: u32,
    },
}

/// A node started as a child process, until it is reaped.
pub struct NodeProcess {
    /// Which node it runs.
    pub kind: NodeKind,
    /// A display's death ends the run; a render node's is survivable.
    pub essential: bool,
    /// Its process id, kept: a child that was reaped no longer says it.
    pid: u32,
    /// The id the master gave this render node when it last joined (it gets a new one each
    /// time it rejoins).
    node: Option<RenderNodeId>,
    child: Child,
}

impl NodeProcess {
    /// The process as log lines name it: its node as the master's log and the report name
    /// it, and its pid (`render node 2 (pid 1234)`).
    pub fn name(&self) -> String {
        let pid = self.pid;
        match (self.kind, self.node) {
            (NodeKind::Display(d), _) => format!("display {d} (pid {pid})"),
            (NodeKind::Render { .. }, Some(node)) => format!("render node {} (pid {pid})", node.0),
            (NodeKind::Render { slot }, None) => {
                format!("render node process {slot} (pid {pid}, not joined)")
            }
        }
    }
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

/// How much a local wall's render nodes yield the CPU to its master and displays: they share
/// this machine's cores, and a render node building a BVH or tracing takes every core it can,
/// while the master and displays need a little CPU at once (a control answer, a present).
const RENDER_NICENESS: libc::c_int = 10;

/// Starts the command at [`RENDER_NICENESS`]: its threads, all created after, inherit it.
fn yield_to_the_wall(cmd: &mut Command) {
    #[cfg(target_os = "linux")]
    // SAFETY: the closure runs in the child between fork and exec and calls only setpriority,
    // which is async-signal-safe. A failure only leaves the node at normal priority.
    unsafe {
        cmd.pre_exec(|| {
            libc::setpriority(libc::PRIO_PROCESS, 0, RENDER_NICENESS);
            Ok(())
        });
    }
    #[cfg(not(target_os = "linux"))]
    let _ = cmd;
}

/// Starts a node process of kind `kind`: killed with its parent, a render node at a lower
/// priority than the master and displays.
pub fn spawn(
    kind: NodeKind,
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
    if matches!(kind, NodeKind::Render { .. }) {
        yield_to_the_wall(&mut cmd);
    }
    let child = cmd
        .spawn()
        .with_context(|| format!("cannot start {kind:?} ({})", program.display()))?;
    let pid = child.id().context("a child just started has a pid")?;
    let process = NodeProcess {
        kind,
        essential,
        pid,
        node: None,
        child,
    };
    tracing::debug!("started {}", process.name());
    Ok(process)
}

/// Puts the render nodes that joined since the `seen` first onto the children running them:
/// the process whose QUIC endpoint has the port the master saw the node join from.
fn name_joined(children: &mut [NodeProcess], signals: &RunSignals, seen: &mut usize) {
    let joins: Vec<_> = {
        let joins = signals.render_joins.lock();
        let joins = joins.unwrap_or_else(|e| e.into_inner());
        joins.iter().skip(*seen).copied().collect()
    };
    *seen += joins.len();
    for (node, from) in joins {
        let renders = children
            .iter_mut()
            .filter(|c| matches!(c.kind, NodeKind::Render { .. }));
        for c in renders {
            if tessera_cli::procs::udp_ports(c.pid).contains(&from.port()) {
                c.node = Some(node);
                break;
            }
        }
    }
}

/// Watches children while the run goes on. Returns when an essential child dies, or when any
/// child dies before the first frame (a node that cannot start is a configuration error).
pub async fn watch(
    children: &mut Vec<NodeProcess>,
    signals: RunSignals,
    lost: &mut Vec<String>,
) -> anyhow::Error {
    let mut seen = 0;
    loop {
        name_joined(children, &signals, &mut seen);
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
            let what = format!("{} exited with {}", c.name(), describe(status));
            if c.essential || !signals.started.load(Ordering::SeqCst) {
                return anyhow::anyhow!("{what}; stopping the wall (see its log lines above)");
            }
            let rest = match c.kind {
                NodeKind::Display(_) => "the other displays go on without it",
                NodeKind::Render { .. } => "the other render nodes take over its tiles",
            };
            tracing::error!("{what}; {rest}");
            let node = match (c.kind, c.node) {
                (NodeKind::Display(d), _) => Some(ExitedNode::Display(DisplayId(d))),
                (NodeKind::Render { .. }, node) => node.map(ExitedNode::Render),
            };
            if let Some(node) = node {
                let how = format!("exited with {}", describe(status));
                let exited = signals.exited.lock();
                exited.unwrap_or_else(|e| e.into_inner()).push((node, how));
                signals.exit_notify.notify_one();
            }
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
            Some(s) => failures.push(format!("{} exited with {}", c.name(), describe(s))),
            None => failures.push(format!("{} did not exit and was killed", c.name())),
        }
    }
    children.clear();
    failures
}
