//! Distributed shared memory, the master's side: how a run holds its scene (`--data`), the
//! scene prepared into blocks (the `prepare` command, and before a shared run), and the choice
//! `auto` makes.

use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};
use tessera_cli::bytes::{parse_bytes, show_bytes};
use tessera_protocol::dsm::{DataSpec, DsmSpec};
use tessera_render::dsm::prepare::{self, Manifest, PrepareError};
use tessera_render::scene::Scene;

/// How render nodes hold the scene.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum DataMode {
    Replicated,
    Dsm,
    Auto,
}

#[derive(clap::Args, Clone, Debug)]
pub struct DataArgs {
    /// How render nodes hold the scene: `replicated` (each loads all of it), `dsm`
    /// (distributed shared memory: the scene is prepared in blocks, each render node holds
    /// 1/N of them plus a cache and fetches the rest from their owners; meshes, a volume or a
    /// volume series, particles), or `auto` (dsm when the prepared scene
    /// does not fit --memory-budget).
    #[arg(long, value_enum, default_value_t = DataMode::Replicated)]
    pub data: DataMode,
    /// Memory each render node may use, such as 512MiB or 2GiB. With --data dsm it sizes the
    /// block cache (what is left after the node's share and a fixed overhead); `auto` decides
    /// by it. A render node's own --memory-budget overrides it.
    #[arg(long, value_parser = parse_bytes, value_name = "SIZE")]
    pub memory_budget: Option<u64>,
    /// With --data dsm: render nodes holding each block (1 to the number of render nodes); 2
    /// keeps every block reachable when a render node dies.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=4096))]
    pub replicas: u32,
    /// With --data dsm: the size of a block (a multiple of 256 bytes, 2KiB to 1MiB); a scene
    /// with a volume uses at least a brick's (140.5KiB).
    #[arg(long, default_value = "8KiB", value_parser = parse_bytes, value_name = "SIZE")]
    pub block_size: u64,
    /// Where the scene prepared in blocks is, or goes (default:
    /// ~/.cache/tessera/dsm/<scene hash>-<block size>); render nodes read their share there,
    /// or in their own --prepared.
    #[arg(long, value_name = "DIR")]
    pub prepared: Option<PathBuf>,
    /// With --data dsm: each render node's cache as a share of the scene's blocks (0 < F <=
    /// 1), in place of what --memory-budget leaves; the knob of `bench dsm`.
    #[arg(long, value_name = "F")]
    pub cache_fraction: Option<f32>,
    /// With --data dsm: out of core. No render node holds a share of the blocks: each reads
    /// what it misses from the prepared files into its cache (every render node must see the
    /// files: one machine, or a shared filesystem). For a scene whose shares would not fit
    /// the nodes' --memory-budget; --data auto chooses it when they would not.
    #[arg(long)]
    pub out_of_core: bool,
}

/// `tessera-master prepare`: the scene in blocks, for `--data dsm`.
#[derive(clap::Args)]
pub struct PrepareArgs {
    /// The scene: `builtin`, `gallery`, `knot:SEGMENTS:SIDES`, a mesh (OBJ, PLY, glTF/GLB), a
    /// volume (.nrrd, .nhdr, .nii, .nii.gz, .vol.toml) or a .scene.toml of meshes and a volume.
    #[arg(long)]
    pub scene: String,
    /// The folder to write (default: ~/.cache/tessera/dsm/<scene hash>-<block size>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Block size (a multiple of 256 bytes, 2KiB to 1MiB); a scene with a volume uses at
    /// least a brick's (140.5KiB).
    #[arg(long, default_value = "8KiB", value_parser = parse_bytes, value_name = "SIZE")]
    pub block_size: u64,
}

/// Where a scene prepared in blocks of `block_bytes` goes unless told otherwise.
pub fn default_dir(scene_hash: &[u8; 32], block_bytes: u32) -> Result<PathBuf> {
    let base = tessera_render::bvh::cache::default_cache_dir()
        .and_then(|bvh| bvh.parent().map(Path::to_path_buf))
        .context("no home or cache directory to prepare the scene in: give --prepared DIR")?;
    let hash = prepare::hash_hex(scene_hash);
    Ok(base
        .join("dsm")
        .join(format!("{}-{block_bytes}", &hash[..24])))
}

fn block_bytes(size: u64) -> Result<u32> {
    u32::try_from(size).map_err(|_| anyhow::anyhow!("block size {size} is too large"))
}

/// The block size a scene is shared in when `asked` was asked for: at least a volume brick
/// (a brick is one block, about 140 KiB; the tree and triangles of a scene with a volume are
/// cut to the same size).
pub fn scene_block_bytes(scene: &Scene, asked: u32) -> u32 {
    if scene.volume.is_none() {
        return asked;
    }
    let brick = tessera_render::volume::BRICK_SAMPLES * std::mem::size_of::<f32>();
    let needed = tessera_render::dsm::layout::brick_block_bytes(brick as u32);
    if asked < needed {
        tracing::info!(
            "the scene has a volume: blocks of {} (a brick) in place of {}",
            show_bytes(needed as u64),
            show_bytes(asked as u64)
        );
    }
    asked.max(needed)
}

/// The scene prepared in `dir`: reused if it holds this very scene in blocks of
/// `block_bytes`, else written there (the BVH from its cache, with a progress bar).
pub fn ensure_prepared(
    scene: &Scene,
    dir: &Path,
    block_bytes: u32,
    show_progress: bool,
) -> Result<Manifest> {
    let hash = prepare::hash_hex(&scene.content_hash());
    match prepare::load_manifest(dir, Some((&hash, block_bytes))) {
        Ok(manifest) => {
            tracing::info!("the scene is prepared in {} already", dir.display());
            return Ok(manifest);
        }
        Err(PrepareError::Io { .. }) => {}
        Err(why) => tracing::info!("preparing the scene again: {why}"),
    }
    let t0 = std::time::Instant::now();
    let (accel, _) = tessera_render::bvh::cache::load_or_build(
        scene,
        tessera_render::bvh::cache::default_cache_dir().as_deref(),
    );
    let bar = show_progress.then(|| {
        let bar = indicatif::ProgressBar::new(0);
        bar.set_style(
            indicatif::ProgressStyle::with_template(
                "preparing blocks {bar:30} {pos}/{len} {elapsed_precise}",
            )
            .expect("valid template"),
        );
        bar
    });
    let manifest = prepare::prepare(scene, &accel, dir, block_bytes, &mut |done, total| {
        if let Some(bar) = &bar {
            bar.set_length(total);
            bar.set_position(done);
        }
    })
    .with_context(|| format!("cannot prepare the scene in {}", dir.display()))?;
    if let Some(bar) = bar {
        bar.finish_and_clear();
    }
    let layout = manifest.layout;
    tracing::info!(
        "prepared {} triangles, {} volume bricks ({} steps) and {} particles in {} blocks of {} ({}) in {:.1} s: {}",
        layout.triangle_count,
        layout.brick_blocks,
        manifest.series_steps.max(manifest.volume.is_some() as u32),
        layout.sphere_count,
        layout.total(),
        show_bytes(layout.block_bytes as u64),
        show_bytes(layout.total_bytes()),
        t0.elapsed().as_secs_f64(),
        dir.display()
    );
    Ok(manifest)
}

/// `tessera-master prepare`.
pub fn prepare_command(args: PrepareArgs) -> Result<()> {
    let spec = tessera_model::scene_spec::SceneSpec::from_arg(&args.scene)?;
    let scene = Scene::load(&spec)?;
    let bytes = scene_block_bytes(&scene, block_bytes(args.block_size)?);
    let dir = match args.out {
        Some(dir) => dir,
        None => default_dir(&scene.content_hash(), bytes)?,
    };
    let manifest = ensure_prepared(&scene, &dir, bytes, true)?;
    println!(
        "{}: {} blocks of {} ({} in all; the top of the tree, {}, on every node)",
        dir.display(),
        manifest.layout.total(),
        show_bytes(bytes as u64),
        show_bytes(manifest.layout.total_bytes()),
        show_bytes(manifest.layout.top_blocks as u64 * bytes as u64)
    );
    Ok(())
}

/// What `--data auto` makes of a scene prepared as `manifest` under `budget` with
/// `render_nodes` nodes holding `replicas` of each block: None where it fits whole
/// (replicated), else whether it goes out of core (a node's share, with the fixed overhead,
/// would take more than half the budget, leaving too little for a cache); says why, in sizes.
fn auto_choice(
    manifest: &Manifest,
    budget: u64,
    (render_nodes, replicas): (u32, u32),
) -> Option<bool> {
    let total = manifest.layout.total_bytes();
    let overhead = tessera_render::dsm::NODE_OVERHEAD_BYTES;
    if total + overhead <= budget {
        tracing::info!(
            "--data auto: the scene ({}) fits the budget of {}: replicated",
            show_bytes(total),
            show_bytes(budget)
        );
        return None;
    }
    let share = total.div_ceil(render_nodes as u64) * replicas as u64;
    let out_of_core = share + overhead > budget / 2;
    let how = if out_of_core {
        "out of core: each node's share with its overhead would take more than half of it, so every node reads blocks from the prepared files into its cache"
    } else {
        "distributed shared memory, each node holding its share"
    };
    tracing::info!(
        "--data auto: the scene ({}) does not fit the budget of {}; a node's share is {} beside {} of overhead: {how}",
        show_bytes(total),
        show_bytes(budget),
        show_bytes(share),
        show_bytes(overhead)
    );
    Some(out_of_core)
}

/// How the run's render nodes hold `scene`: as `args` ask, preparing it first when it is
/// shared, and for `auto` by whether it fits the budget.
pub fn data_spec(
    args: &DataArgs,
    scene: &Scene,
    render_nodes: u32,
    show_progress: bool,
) -> Result<DataSpec> {
    if args.data == DataMode::Replicated {
        return Ok(DataSpec::Replicated);
    }
    let budget = args.memory_budget;
    if args.data == DataMode::Auto && budget.is_none() {
        bail!("--data auto decides by --memory-budget: give one (such as 2GiB)");
    }
    if args.replicas > render_nodes {
        bail!(
            "--replicas {} needs at least as many render nodes (--render-nodes {render_nodes})",
            args.replicas
        );
    }
    let bytes = scene_block_bytes(scene, block_bytes(args.block_size)?);
    let dir = match &args.prepared {
        Some(dir) => dir.clone(),
        None => default_dir(&scene.content_hash(), bytes)?,
    };
    let manifest = ensure_prepared(scene, &dir, bytes, show_progress)?;
    let mut out_of_core = args.out_of_core;
    if let (DataMode::Auto, Some(budget)) = (args.data, budget) {
        let Some(out) = auto_choice(&manifest, budget, (render_nodes, args.replicas)) else {
            return Ok(DataSpec::Replicated);
        };
        out_of_core |= out;
    }
    let spec = DsmSpec {
        dir,
        block_bytes: bytes,
        ranks: if out_of_core { 0 } else { render_nodes },
        replicas: args.replicas,
        memory_budget: budget,
        cache_fraction: args.cache_fraction,
    };
    spec.check()
        .map_err(|e| anyhow::anyhow!("--data dsm: {e}"))?;
    Ok(DataSpec::Dsm(spec))
}
