//! The render node: joins a master, ray-traces the tiles it is given on every core, and sends
//! each finished tile straight to the display that owns it.
//!
//! A library with a thin binary, so that `tessera-master` can run the same node from its own
//! executable (`tessera-master render-node ...`, what `local` starts) and the installed
//! `tessera-render-node` stays for render hosts. What the node does with each message of a
//! session is the sans-IO [`tessera_core::node::render::RenderSession`] (its queue and batch
//! sizes are [`tessera_core::worker`]'s); the driver loop (`node`) only moves bytes and
//! reads clocks for it, a batch renders on the render threads in `batch`, and the link to the
//! master and the loop that rejoins a lost one are `tessera_net::link` and
//! `tessera_net::reconnect`.

#![warn(missing_docs)]

mod batch;
mod bench;
mod block_server;
mod dsm;
mod fetch_driver;
mod loading;
pub mod memory;
mod node;
mod pixels_out;

use anyhow::{bail, Context, Result};
use std::path::PathBuf;
use std::process::ExitCode;
use tessera_model::scene_spec::SceneSpec;
use tessera_render::scene::Scene;

/// Most rendering threads a node may be asked for.
pub const MAX_THREADS: usize = 1024;

/// Tessera render node: renders the tiles a master assigns and sends them to the displays.
///
/// Without a subcommand it joins a master (`--master HOST:PORT --cert-dir DIR`).
#[derive(clap::Parser, Debug)]
#[command(version, about, long_about = None, args_conflicts_with_subcommands = true)]
pub struct Cli {
    #[command(subcommand)]
    command: Option<Tool>,
    /// The master's address, HOST:PORT; or a comma-separated list, A,B: a primary and its
    /// standby (`tessera-master serve --standby-of`). The node joins the first that answers;
    /// a master lost or silent for --failover-after is left for the next of the list, round
    /// it, for up to --reconnect-timeout (a list waits so without --reconnect too), and one of
    /// an older term than the node has followed is refused.
    #[arg(long, value_name = "ADDR[,ADDR...]")]
    master: Option<String>,
    /// This node's certificate directory (node.pem, node.key, ca.pem) from `tessera-master issue-cert`.
    #[arg(long)]
    cert_dir: Option<PathBuf>,
    /// Rendering threads (default: all cores; at most 1024).
    #[arg(long, value_parser = parse_threads)]
    threads: Option<usize>,
    /// Directory of cached BVHs, keyed by scene content (default: ~/.cache/tessera/bvh).
    #[arg(long)]
    bvh_cache: Option<PathBuf>,
    /// Always build the BVH; neither read nor write the cache.
    #[arg(long)]
    no_bvh_cache: bool,
    /// Memory for the steps of a time-varying volume read ahead of the one shown, in MiB.
    #[arg(long, default_value_t = 2048)]
    volume_cache_mb: usize,
    #[command(flatten)]
    reconnect: tessera_cli::reconnect::ReconnectArgs,
    /// Memory this node may use in all (such as 512MiB or 2GiB), for a scene in distributed
    /// shared memory: its cache of other nodes' blocks is what is left after its share and a
    /// fixed overhead. Default: the master's --memory-budget.
    #[arg(long, value_parser = tessera_cli::bytes::parse_bytes, value_name = "SIZE")]
    memory_budget: Option<u64>,
    /// This host's copy of a scene prepared for distributed shared memory (`tessera-master
    /// prepare`). Default: the folder the master names.
    #[arg(long, value_name = "DIR")]
    prepared: Option<PathBuf>,
}

fn parse_threads(text: &str) -> Result<usize, String> {
    match text.parse::<usize>() {
        Ok(n) if (1..=MAX_THREADS).contains(&n) => Ok(n),
        _ => Err(format!(
            "`{text}` is not a thread count from 1 to {MAX_THREADS}"
        )),
    }
}

#[derive(clap::Subcommand, Debug)]
enum Tool {
    /// Measure Mrays/s of primary, shadow and ambient-occlusion rays on one image.
    Bench(bench::BenchArgs),
    /// Write a scene's triangles as OBJ (to feed the same mesh to another renderer).
    ExportObj {
        /// `builtin`, `knot:SEGMENTS:SIDES` or a mesh path.
        #[arg(long)]
        scene: String,
        /// The OBJ file to write.
        #[arg(long)]
        out: PathBuf,
    },
}

/// Runs what `cli` asks and turns the outcome into the process's exit code, printing the
/// error (with its causes) if there is one.
pub fn main(cli: Cli) -> ExitCode {
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("tessera-render-node: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// Runs what `cli` asks: join a master, or one of the tools.
///
/// # Errors
/// Bad flags or input, a master that cannot be reached or refuses the node, a lost master.
pub fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Some(Tool::Bench(args)) => bench::run(args),
        Some(Tool::ExportObj { scene, out }) => export_obj(&scene, &out),
        None => {
            let (Some(master), Some(cert_dir)) = (cli.master, cli.cert_dir) else {
                bail!("to join a wall give --master HOST:PORT and --cert-dir DIR (see --help)");
            };
            // Before the scene is loaded, so its arrays never pin each other in the heap.
            memory::map_large_allocations();
            memory::few_heaps();
            let options = node::Options {
                master,
                cert_dir,
                threads: cli.threads,
                bvh_cache: cache_dir(cli.bvh_cache, cli.no_bvh_cache),
                volume_cache_bytes: cli.volume_cache_mb.saturating_mul(1 << 20),
                reconnect: cli.reconnect.wait(),
                failover_after: cli.reconnect.failover_after(),
                dsm: dsm::DsmOptions {
                    prepared: cli.prepared,
                    memory_budget: cli.memory_budget,
                    // Set once the node knows its thread count.
                    threads: 0,
                },
            };
            let runtime = tessera_net::link::node_runtime()?;
            let outcome = runtime.block_on(node::run(options));
            // Dropping a runtime waits for its blocking tasks: a scene still loading, or a
            // BVH building, for a master that is gone would hold the exit for as long as it
            // takes. Rendering is cancelled already; nothing else there is worth waiting for.
            runtime.shutdown_background();
            outcome
        }
    }
}

/// The BVH cache directory the flags ask for.
fn cache_dir(dir: Option<PathBuf>, disabled: bool) -> Option<PathBuf> {
    if disabled {
        None
    } else {
        dir.or_else(tessera_render::bvh::cache::default_cache_dir)
    }
}

fn export_obj(scene: &str, out: &std::path::Path) -> Result<()> {
    let scene = Scene::load(&SceneSpec::from_arg(scene)?)?;
    scene
        .export_obj(out)
        .with_context(|| format!("cannot write {}", out.display()))?;
    eprintln!(
        "wrote {} ({} triangles)",
        out.display(),
        scene.triangles.len()
    );
    Ok(())
}
