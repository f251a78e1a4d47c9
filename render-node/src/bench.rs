//! `tessera-render-node bench`: rays per second of each kind on one image, and thread scaling.
//!
//! Prints machine-readable lines (`TESSERA_PRIMARY_MRAYPS 12.3`) that
//! `deploy/bench/embree-compare.sh` puts beside Embree's figure for the same mesh and camera.

use anyhow::{Context, Result};
use std::time::Instant;
use tessera_cli::SceneArgs;
use tessera_render::accel_cache::load_or_build;
use tessera_render::bench::{time_passes, PassTimes};
use tessera_render::scene::Scene;
use tessera_render::{orbit_of, FrameView, PreparedScene};
use tessera_wire::params::RenderParamsSpec;
use tessera_wire::wall::parse_size;

#[derive(clap::Args, Debug)]
pub struct BenchArgs {
    #[command(flatten)]
    scene: SceneArgs,
    /// Image size WIDTHxHEIGHT.
    #[arg(long, default_value = "1920x1080")]
    size: String,
    /// Threads to render with (default: all cores). With more than one, the 1-thread figure
    /// is measured too and the scaling printed.
    #[arg(long, value_parser = crate::parse_threads)]
    threads: Option<usize>,
    /// Frames to time; the best frame of each pass is reported (after one warm-up frame).
    #[arg(long, default_value_t = 10)]
    frames: u32,
    /// Ambient-occlusion rays per hit.
    #[arg(long, default_value_t = 4)]
    ao: u32,
    /// Directory of cached BVHs (default: ~/.cache/tessera/bvh).
    #[arg(long)]
    bvh_cache: Option<std::path::PathBuf>,
    /// Always build the BVH; neither read nor write the cache.
    #[arg(long)]
    no_bvh_cache: bool,
}

pub fn run(args: BenchArgs) -> Result<()> {
    let (width, height) = parse_size(&args.size).context("--size")?;
    if width == 0 || height == 0 || width > 1 << 16 || height > 1 << 16 {
        anyhow::bail!("--size {width}x{height}: each side must be from 1 to 65536 pixels");
    }
    let threads = args
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let spec = args.scene.spec()?;
    let t0 = Instant::now();
    let scene = Scene::load(&spec)?;
    let loaded = t0.elapsed();
    let camera = args
        .scene
        .camera_mode(|fov| orbit_of(&scene.bounds(), fov))?
        .camera_for_frame(0);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()?;
    let t1 = Instant::now();
    let cache = crate::cache_dir(args.bvh_cache, args.no_bvh_cache);
    let (accel, source) = pool.install(|| load_or_build(&scene, cache.as_deref()));
    let prepared = PreparedScene::from_accel(&scene, accel);
    eprintln!(
        "{} triangles: loaded in {:.2} s, BVH {source:?} in {:.2} s ({} nodes); {width}x{height}, {threads} threads",
        scene.triangles.len(),
        loaded.as_secs_f64(),
        t1.elapsed().as_secs_f64(),
        prepared.accel.nodes.len()
    );
    let params = RenderParamsSpec {
        ao_samples: args.ao,
        ..RenderParamsSpec::INTERACTIVE
    }
    .build()
    .context("--ao")?;
    let view = FrameView::new(0, &camera, params, width, height);
    let measure = |pool: &rayon::ThreadPool| -> PassTimes {
        let mut best = pool.install(|| time_passes(&prepared, &view, width, height, args.ao));
        for _ in 0..args.frames {
            let t = pool.install(|| time_passes(&prepared, &view, width, height, args.ao));
            for (b, n) in [
                (&mut best.primary, t.primary),
                (&mut best.shadow, t.shadow),
                (&mut best.shadow_single, t.shadow_single),
                (&mut best.ambient, t.ambient),
            ] {
                if n.seconds < b.seconds {
                    *b = n;
                }
            }
        }
        best
    };
    let times = measure(&pool);
    println!("TESSERA_PRIMARY_MRAYPS {:.3}", times.primary.mrays_per_s());
    println!("TESSERA_SHADOW_MRAYPS {:.3}", times.shadow.mrays_per_s());
    println!(
        "TESSERA_SHADOW_SINGLE_MRAYPS {:.3} (the same shadow rays one by one; packets are {:.2}x)",
        times.shadow_single.mrays_per_s(),
        times.shadow.mrays_per_s() / times.shadow_single.mrays_per_s()
    );
    println!("TESSERA_AO_MRAYPS {:.3}", times.ambient.mrays_per_s());
    if threads > 1 {
        let one = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
        let single = measure(&one);
        println!(
            "TESSERA_PRIMARY_MRAYPS_1T {:.3}",
            single.primary.mrays_per_s()
        );
        println!(
            "TESSERA_SCALING_PRIMARY {:.3} ({threads} threads / 1 thread)",
            times.primary.mrays_per_s() / single.primary.mrays_per_s()
        );
    }
    Ok(())
}
