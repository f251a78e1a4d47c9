//! The master: balances the wall's work over the render nodes, runs the frame barrier, and
//! launches a whole local wall, serves one over several hosts, renders the single-process
//! reference image, runs measurement experiments and simulates walls.
//!
//! A library with a thin binary (`tessera-master`). The binary also runs the node roles
//! (`tessera-master render-node ...`, `tessera-master display-node ...`, the very code of
//! `tessera-render-node` and `tessera-display-node`), so a local wall needs nothing but the
//! master's executable. The driver loop (`server`) moves bytes and reads clocks for the
//! sans-IO [`tessera_core::master::Master`], which makes every decision of the run. The
//! operator's console (`console`: a web page and a REST/JSON API, axum) hands its requests to
//! that loop as control requests and reads what it publishes, never the other way round.

#![warn(missing_docs)]

mod args;
mod bench;
mod camera_path;
mod console;
mod control;
mod dsm_data;
mod launch;
mod launcher;
mod movie;
mod outcome;
mod peers;
mod probe;
mod record;
mod reference;
mod relay;
mod server;
mod simulate;
mod standby_link;
mod validate;
mod wall_run;

// The report's and the timing's types live with the sans-IO master that fills them.
use tessera_core::master::{report, timing};

use anyhow::Result;
use clap::Subcommand;
use std::process::ExitCode;
use tessera_net::cluster::ClusterCa;

/// Tessera's master: hands image tiles to render nodes over QUIC and makes every display
/// present each frame at the same moment.
#[derive(clap::Parser)]
#[command(version, about, long_about = None)]
pub struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run a whole wall on this machine: display and render nodes as processes on 127.0.0.1.
    ///
    /// The nodes are started with --reconnect: one paused or starved long enough to be
    /// dropped rejoins the wall. Exit status: 0 when the run completed (every frame presented,
    /// even if nodes were lost on the way: report.json's `nodes_lost` names them), 130 on
    /// Ctrl-C or SIGTERM, 1 when it did not complete or its report could not be written.
    /// With --out, report.json is written for every run, a failed one too, its `outcome`
    /// saying how the run ended.
    Local(args::LocalArgs),
    /// Run a wall across hosts, its nodes started over ssh from a host file (which host runs
    /// which render nodes and displays); this process is the master. Every node is stopped on
    /// exit, on Ctrl-C and when one fails.
    ///
    /// Exit status and report.json as for `local`.
    Launch(launch::LaunchArgs),
    /// Wait for the wall's nodes on an address and run it (a real wall over several hosts).
    ///
    /// Exit status and report.json as for `local`: 0 when the run completed (nodes lost on
    /// the way are named in the report), 130 on Ctrl-C or SIGTERM (how a run of --frames 0
    /// ends), 1 when it did not complete.
    Serve(args::ServeArgs),
    /// Render one frame of the wall in this process, no network: the reference image.
    Render(args::RenderArgs),
    /// Run a measurement experiment on a local wall: max-fps, latency, scaling,
    /// error-vs-time, soak, dsm or stiff; writes report.json, a CSV and an SVG plot into --out
    /// DIR.
    Bench(bench::BenchArgs),
    /// Prepare a scene for distributed shared memory (`--data dsm`): its BVH and triangles in
    /// checksummed blocks, reused while the scene is the same.
    Prepare(dsm_data::PrepareArgs),
    /// Check a wall file (fields, sizes, overlapping screens, screens facing away from the
    /// viewer) and draw it as an SVG: screens, bezels, tiles, which display owns what.
    Validate(validate::ValidateArgs),
    /// Write a node certificate signed by the cluster CA (creating the CA on first use).
    IssueCert(args::IssueCertArgs),
    /// Simulate a wall in this process on a virtual clock (the real load balancer and frame
    /// barrier, virtual nodes and network): prints balance efficiency and frames completed.
    Simulate(simulate::SimulateArgs),
    /// Steer a running wall: camera, quality, cuts, crop, lights, saved views, overlay; query
    /// its state and live figures (needs a certificate from `issue-cert --role control`).
    Control(control::ControlArgs),
    /// Relay UDP between nodes, impaired (loss, delay, jitter, reordering, duplication, a
    /// partition that heals): a bad network on loopback, for tests and trials.
    Relay(relay::RelayArgs),
    /// Run as a render node, exactly as `tessera-render-node` does (see its --help): one
    /// executable can serve every host of a wall.
    RenderNode(tessera_render_node::Cli),
    /// Run as a display node, exactly as `tessera-display-node` does (see its --help).
    DisplayNode(tessera_display_node::Cli),
}

/// Runs what `cli` asks and turns the outcome into the process's exit code, printing the
/// error (with its causes) if there is one.
pub fn main(cli: Cli) -> ExitCode {
    match cli.command {
        // The node roles print their own errors, named as their own binaries do.
        Command::RenderNode(node) => return tessera_render_node::main(node),
        Command::DisplayNode(node) => return tessera_display_node::main(node),
        _ => {}
    }
    match run(cli.command) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("tessera-master: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn run(command: Command) -> Result<ExitCode> {
    match command {
        Command::Render(args) => reference::render_reference(args).map(|()| ExitCode::SUCCESS),
        Command::IssueCert(args) => {
            let ca = ClusterCa::open_or_create(&args.cluster_dir)?.valid_for(args.valid_days);
            match (args.role, args.display) {
                (args::RoleArg::Display, Some(display)) => {
                    ca.issue_display(&args.name, &args.out, display)?
                }
                (args::RoleArg::Display, None) => {
                    anyhow::bail!("--role display needs --display ID")
                }
                (role, None) => ca.issue(&args.name, &args.out, Some(role.cert_role()))?,
                (_, Some(_)) => anyhow::bail!("--display is for --role display only"),
            }
            println!(
                "wrote the certificate of `{}` to {} (give it to the node with --cert-dir)",
                args.name,
                args.out.display()
            );
            Ok(ExitCode::SUCCESS)
        }
        Command::Local(args) => runtime()?.block_on(wall_run::local(args)),
        Command::Serve(args) => runtime()?.block_on(wall_run::serve(args)),
        Command::Launch(args) => runtime()?.block_on(launch::launch(args)),
        Command::Simulate(args) => simulate::simulate(args),
        Command::Validate(args) => validate::validate(args).map(|()| ExitCode::SUCCESS),
        Command::Prepare(args) => dsm_data::prepare_command(args).map(|()| ExitCode::SUCCESS),
        Command::Bench(args) => runtime()?.block_on(bench::bench(args)),
        Command::Control(args) => runtime()?.block_on(control::control(args)),
        Command::Relay(args) => runtime()?.block_on(relay::relay(args)),
        Command::RenderNode(node) => tessera_render_node::run(node).map(|()| ExitCode::SUCCESS),
        Command::DisplayNode(node) => tessera_display_node::run(node).map(|()| ExitCode::SUCCESS),
    }
}

fn runtime() -> Result<tokio::runtime::Runtime> {
    Ok(tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?)
}
