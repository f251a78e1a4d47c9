//! `tessera-master launch --hosts FILE`: a wall across hosts started over ssh. This process is
//! the master; the host file says which host runs which render nodes and displays. Each run
//! gets a fresh cluster CA: the certificates are copied to their hosts with scp into a
//! directory of the run's own, the nodes run under `ssh -tt` (see [`remote`]), and on the end
//! of the run, on Ctrl-C or when a node fails, every node is stopped, every ssh reaped and
//! the copied certificates removed.

mod hosts;
mod remote;

use crate::args::{prepare_run, RunArgs};
use crate::outcome::Ended;
use crate::server::{bind, run_wall, RunSignals};
use crate::wall_run::{finish_run, stop_on_ctrl_c};
use anyhow::{Context, Result};
use hosts::{HostFile, NodeRole, PlannedNode};
use remote::{scp_args, shell_line, ssh_args, step, RemoteNode};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::Ordering;
use std::time::Duration;
use tessera_net::cluster::{CertRole, ClusterCa, NodeIdentity};

/// How long nodes get to leave by themselves after the master's shutdown before their ssh
/// sessions are cut.
const LEAVE_GRACE: Duration = Duration::from_secs(10);

#[derive(clap::Args)]
pub struct LaunchArgs {
    /// The host file (TOML): how to reach each host over ssh and which render nodes and
    /// displays it runs; the master runs here. See deploy/hosts/example.toml.
    #[arg(long, value_name = "FILE")]
    pub hosts: PathBuf,
    /// Check the host file against the wall and print the scp and ssh commands each host
    /// would get, then exit without connecting anywhere.
    #[arg(long)]
    pub dry_run: bool,
    #[command(flatten)]
    pub run: RunArgs,
}

/// Runs `launch`: see the module's documentation.
///
/// # Errors
/// A bad host file or flag, a host that cannot be reached or given its certificates, a node
/// that fails, or the wall's own errors.
pub async fn launch(args: LaunchArgs) -> Result<ExitCode> {
    let this = std::env::current_exe().context("cannot locate the running executable")?;
    let file = HostFile::load(&args.hosts, &this.display().to_string())?;
    let wall = args.run.wall.wall_file()?.layout;
    let plan = file
        .plan(wall.display_count())
        .with_context(|| format!("host file {}", args.hosts.display()))?;
    let run_dir = run_dir_name();
    if args.dry_run {
        print_dry_run(&file, &plan, &args.run, &run_dir);
        return Ok(ExitCode::SUCCESS);
    }
    let cfg = prepare_run(&args.run, file.render_nodes(), true)?;
    let certs = tempfile::Builder::new()
        .prefix("tessera-launch-")
        .tempdir()?;
    issue_certificates(&plan, certs.path())?;
    let control_dir = certs.path().join("control");
    let identity = NodeIdentity::load(&certs.path().join("master"))?;
    let endpoint = bind(file.master.listen, &identity)?;
    let port = endpoint.local_addr()?.port();
    let master_addr = host_port(&file.master.address, port);
    eprintln!(
        "tessera-master: listening on {}; the nodes dial {master_addr}",
        endpoint.local_addr()?
    );
    eprintln!(
        "tessera-master: control with `tessera-master control --connect {master_addr} --cert-dir {}` (while the wall runs)",
        control_dir.display()
    );

    let (stop, interrupted) = stop_on_ctrl_c();
    let copied = copy_certificates(&file, &plan, certs.path(), &run_dir).await;
    // Filled as the nodes start, so that those started before a failure are stopped too.
    let mut nodes = Vec::new();
    let end = match copied {
        Err(e) => Err(e),
        Ok(()) if interrupted.load(Ordering::SeqCst) => {
            Err(anyhow::anyhow!("interrupted before the nodes were started"))
        }
        Ok(()) => match start_nodes(&mut nodes, &file, &plan, &args.run, &run_dir, &master_addr) {
            Err(e) => Err(e),
            Ok(()) => {
                let signals = RunSignals::default();
                run_wall(endpoint, cfg, signals, stop, watch(&mut nodes), None).await
            }
        },
    };
    let mut failures = Vec::new();
    let stopping: Vec<_> = nodes.into_iter().map(|n| n.stop(LEAVE_GRACE)).collect();
    for problem in futures_all(stopping).await.into_iter().flatten() {
        failures.push(problem);
    }
    remove_certificates(&file, &run_dir).await;
    tracing::info!("every node has stopped and every ssh session is closed");
    let mut ended = Ended::of(end, interrupted.load(Ordering::SeqCst));
    ended.processes_failed = failures;
    finish_run(ended, &args.run, &wall)
}

/// Issues, under `dir`, the certificates of every node of `plan` (in `dir/NAME`), of the
/// master (`dir/master`) and of a control client (`dir/control`), from a new cluster CA.
fn issue_certificates(plan: &[PlannedNode], dir: &Path) -> Result<()> {
    let ca = ClusterCa::open_or_create(&dir.join("ca"))?;
    for node in plan {
        let out = dir.join(&node.name);
        match node.role {
            NodeRole::Render { .. } => ca.issue(&node.name, &out, Some(CertRole::Render))?,
            NodeRole::Display { id, .. } => ca.issue_display(&node.name, &out, id)?,
        }
    }
    ca.issue("master", &dir.join("master"), Some(CertRole::Master))?;
    ca.issue("control", &dir.join("control"), Some(CertRole::Control))?;
    Ok(())
}

/// Awaits every future, each on a task of its own so that they run at once.
async fn futures_all<T: Send + 'static>(
    futures: Vec<impl std::future::Future<Output = T> + Send + 'static>,
) -> Vec<T> {
    let tasks: Vec<_> = futures.into_iter().map(tokio::spawn).collect();
    let mut out = Vec::new();
    for task in tasks {
        if let Ok(value) = task.await {
            out.push(value);
        }
    }
    out
}

/// The run's directory under each host's `remote_dir`: this host, process and second, so two
/// launches never share one.
fn run_dir_name() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    format!(
        "tessera-launch-{}-{}-{secs}",
        tessera_net::hostname(),
        std::process::id()
    )
}

fn host_port(address: &str, port: u16) -> String {
    if address.contains(':') {
        format!("[{address}]:{port}")
    } else {
        format!("{address}:{port}")
    }
}

/// Makes the run's directory on every host (mode 700) and copies its nodes' certificates
/// there, all hosts at once.
async fn copy_certificates(
    file: &HostFile,
    plan: &[PlannedNode],
    local: &Path,
    run_dir: &str,
) -> Result<()> {
    let mut copies = Vec::new();
    for (index, host) in file.hosts.iter().enumerate() {
        let dirs: Vec<PathBuf> = plan
            .iter()
            .filter(|n| n.host == index)
            .map(|n| local.join(&n.name))
            .collect();
        let host = host.clone();
        let remote = format!("{}/{run_dir}", host.remote_dir);
        copies.push(async move {
            let mkdir = format!("umask 077 && mkdir -p {}", remote::shell_quote(&remote));
            step(
                &host,
                "make the run's directory",
                "ssh",
                &ssh_args(&host, false, &mkdir),
            )
            .await?;
            let dirs: Vec<&Path> = dirs.iter().map(PathBuf::as_path).collect();
            step(
                &host,
                "copy the certificates",
                "scp",
                &scp_args(&host, &dirs, &remote),
            )
            .await
        });
    }
    for result in futures_all(copies).await {
        result?;
    }
    Ok(())
}

/// Removes the run's directory (the certificates) from every host; a host that cannot be
/// reached is only warned about.
async fn remove_certificates(file: &HostFile, run_dir: &str) {
    let removals: Vec<_> = file
        .hosts
        .iter()
        .cloned()
        .map(|host| {
            let remote = format!("{}/{run_dir}", host.remote_dir);
            async move {
                let rm = format!("rm -rf {}", remote::shell_quote(&remote));
                if let Err(e) = step(
                    &host,
                    "remove the run's certificates",
                    "ssh",
                    &ssh_args(&host, false, &rm),
                )
                .await
                {
                    tracing::warn!("{e:#}; remove {remote} there by hand");
                }
            }
        })
        .collect();
    futures_all(removals).await;
}

/// The command line `node` runs on its host.
fn node_command(
    file: &HostFile,
    node: &PlannedNode,
    run: &RunArgs,
    run_dir: &str,
    master_addr: &str,
) -> Vec<String> {
    let host = &file.hosts[node.host];
    let cert_dir = format!("{}/{run_dir}/{}", host.remote_dir, node.name);
    let mut words: Vec<String> = vec!["exec".into(), host.tessera.clone()];
    match node.role {
        NodeRole::Render { threads } => {
            words.extend(["render-node".into(), "--master".into(), master_addr.into()]);
            words.extend(["--cert-dir".into(), cert_dir]);
            if let Some(t) = threads {
                words.extend(["--threads".into(), t.to_string()]);
            }
            words.extend(host.render_args.iter().cloned());
        }
        NodeRole::Display { id, port } => {
            words.extend(["display-node".into(), "--master".into(), master_addr.into()]);
            words.extend(["--display".into(), id.to_string()]);
            words.extend(["--cert-dir".into(), cert_dir]);
            let listen = format!("0.0.0.0:{}", port.unwrap_or(0));
            words.extend(["--listen".into(), listen]);
            // Saved frames go where the master's --out is: wall.png is assembled from them
            // where that directory is shared (or the display runs on this host).
            if let (Some(out), Some(_)) = (&run.out, run.save_frame) {
                words.extend(["--out".into(), out.display().to_string()]);
            }
            words.extend(host.display_args.iter().cloned());
        }
    }
    words
}

/// Starts every node of `plan` over ssh, into `nodes`.
fn start_nodes(
    nodes: &mut Vec<RemoteNode>,
    file: &HostFile,
    plan: &[PlannedNode],
    run: &RunArgs,
    run_dir: &str,
    master_addr: &str,
) -> Result<()> {
    for node in plan {
        let host = &file.hosts[node.host];
        let command = shell_line(&node_command(file, node, run, run_dir, master_addr));
        let label = format!("{}@{}", node.name, host.address);
        tracing::debug!("{label}: {command}");
        nodes.push(RemoteNode::start(label, host, &command)?);
    }
    Ok(())
}

/// Returns when a node fails (its ssh exits with an error): the launcher then stops them all.
/// A node that exits cleanly left after the master's shutdown and is let go.
async fn watch(nodes: &mut Vec<RemoteNode>) -> anyhow::Error {
    let mut tick = tokio::time::interval(Duration::from_millis(100));
    loop {
        tick.tick().await;
        let failed = nodes.iter_mut().enumerate().find_map(|(i, n)| {
            n.exited()
                .filter(|s| !s.success())
                .map(|s| (i, remote::describe(s)))
        });
        if let Some((i, why)) = failed {
            let node = nodes.remove(i);
            let label = node.label.clone();
            let _ = node.stop(Duration::ZERO).await;
            return anyhow::anyhow!(
                "{label} exited with {why}; stopping the wall (see its lines above, prefixed [{label}])"
            );
        }
    }
}

fn print_dry_run(file: &HostFile, plan: &[PlannedNode], run: &RunArgs, run_dir: &str) {
    let master_addr = host_port(&file.master.address, file.master.listen.port());
    println!(
        "master: here, listening on {}; the nodes dial {master_addr}",
        file.master.listen
    );
    for (index, host) in file.hosts.iter().enumerate() {
        let names: Vec<&str> = plan
            .iter()
            .filter(|n| n.host == index)
            .map(|n| n.name.as_str())
            .collect();
        let remote = format!("{}/{run_dir}", host.remote_dir);
        let dirs: Vec<PathBuf> = names
            .iter()
            .map(|n| PathBuf::from("CERTS").join(n))
            .collect();
        let dirs: Vec<&Path> = dirs.iter().map(PathBuf::as_path).collect();
        println!("{}: {}", host.label(), names.join(", "));
        println!("  scp {}", shell_line(&scp_args(host, &dirs, &remote)));
        for node in plan.iter().filter(|n| n.host == index) {
            let command = shell_line(&node_command(file, node, run, run_dir, &master_addr));
            println!("  ssh {}", shell_line(&ssh_args(host, true, &command)));
        }
    }
}
