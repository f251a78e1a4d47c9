//! `tessera-render-node bench`: rays per second of each kind on one image, and thread scaling.
//!
//! Prints machine-readable lines (`TESSERA_PRIMARY_MRAYPS 12.3`) that
//! `deploy/bench/embree-compare.sh` puts beside Embree's figure for the same mesh and camera.

use crate::memory::{map_large_allocations, release_freed, resident_bytes};
use anyhow::{Context, Result};
use std::time::Instant;
use tessera_cli::SceneArgs;
use tessera_model::camera::Camera;
use tessera_model::params::{RenderParams, RenderParamsSpec, Shading};
use tessera_model::wall::{parse_size, TileGrid, WallSpec};
use tessera_render::bench::{time_passes, AoRays, AoReach, Pass, PassTimes};
use tessera_render::bvh::cache::{load_or_build_timed, Source};
use tessera_render::bvh::Accel;
use tessera_render::isa::Isa;
use tessera_render::scene::Scene;
use tessera_render::{render_tiles, FrameView, PreparedScene};

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
    /// Frames to time (after one warm-up frame); the fastest and the median of each pass are
    /// reported.
    #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u32).range(1..=10_000))]
    frames: u32,
    /// Ambient-occlusion rays per hit.
    #[arg(long, default_value_t = 4)]
    ao: u32,
    /// Ambient-occlusion rays as Embree's `ao` shader traces them: from the hit point, from
    /// t = 0.001 (its `tnear`, in scene units), unbounded (`TESSERA_AO_MRAYPS`); the same
    /// directions from where the renderer starts them (a few ulps off the surface, from t = 0),
    /// unbounded, are timed too (`TESSERA_AO_SURFACE_MRAYPS`). Without it, AO rays are the
    /// renderer's: from there, reaching a share of the scene's diagonal.
    #[arg(long)]
    ao_unbounded: bool,
    /// Time the ambient-occlusion rays a second time, each hit's traced together as packets
    /// from their common origin (`TESSERA_AO_PACKET_MRAYPS`; they lose to single rays and take
    /// twice their time, so they are left out unless asked for).
    #[arg(long)]
    ao_packets: bool,
    /// Skip the 1-thread re-run that measures thread scaling.
    #[arg(long)]
    no_scaling: bool,
    /// Directory of cached BVHs (default: ~/.cache/tessera/bvh).
    #[arg(long)]
    bvh_cache: Option<std::path::PathBuf>,
    /// Always build the BVH; neither read nor write the cache.
    #[arg(long)]
    no_bvh_cache: bool,
}

/// Runs the benchmark `args` describe and prints its figures.
///
/// # Errors
/// Bad flags, a scene that cannot be loaded, a thread pool that cannot be built.
pub fn run(args: BenchArgs) -> Result<()> {
    let (width, height) = parse_size(&args.size).context("--size")?;
    if width == 0 || height == 0 || width > 1 << 16 || height > 1 << 16 {
        anyhow::bail!("--size {width}x{height}: each side must be from 1 to 65536 pixels");
    }
    let threads = args
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()?;
    let (prepared, camera) = prepare(&args, &pool, (width, height), threads)?;
    let params = RenderParamsSpec {
        ao_samples: args.ao,
        ..RenderParamsSpec::INTERACTIVE
    }
    .build()
    .context("--ao")?;
    let reach = if args.ao_unbounded {
        AoReach::Unbounded
    } else {
        AoReach::Renderer
    };
    let wall = WallSpec::grid(1, 1, width, height).build()?;
    let bench = Bench {
        prepared: &prepared,
        view: FrameView::new(0, &camera, params, width, height),
        frame_views: frame_params()?.map(|(name, params, what)| {
            (
                name,
                FrameView::new(0, &camera, params, width, height),
                what,
            )
        }),
        grid: TileGrid::new(wall),
        size: (width, height),
        ao: AoRays {
            samples: args.ao,
            reach,
            packets: args.ao_packets,
        },
        frames: args.frames,
    };
    let frames = bench.measure(&pool);
    frames.print_all(&bench.frame_views, width as u64 * height as u64, args.ao);
    if threads > 1 && !args.no_scaling {
        let one = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
        let single = bench.measure(&one);
        let (many, one) = (frames.best(|p| p.primary), single.best(|p| p.primary));
        println!("TESSERA_PRIMARY_MRAYPS_1T {:.3}", one.mrays_per_s());
        println!(
            "TESSERA_SCALING_PRIMARY {:.3} ({threads} threads / 1 thread)",
            many.mrays_per_s() / one.mrays_per_s()
        );
    }
    Ok(())
}

/// Loads the scene and builds (or reads) its BVH as a render node would, printing what that
/// took and cost; returns the prepared scene and the camera the flags ask for.
fn prepare(
    args: &BenchArgs,
    pool: &rayon::ThreadPool,
    (width, height): (u32, u32),
    threads: usize,
) -> Result<(PreparedScene, Camera)> {
    let spec = args.scene.spec()?;
    map_large_allocations();
    let resident_before = resident_bytes();
    let t0 = Instant::now();
    let scene = Scene::load(&spec)?;
    if args.scene.nan == tessera_cli::NanPolicy::Refuse {
        if let Some(what) = scene.first_missing() {
            anyhow::bail!(
                "scene {}: {what}, and --nan refuse was given",
                args.scene.scene
            );
        }
    }
    let loaded = t0.elapsed();
    let camera = args
        .scene
        .camera_mode(&scene.render_from_world, |fov| scene.orbit(fov))?
        .camera_for_frame(0);
    let t1 = Instant::now();
    let cache = crate::cache_dir(args.bvh_cache.clone(), args.no_bvh_cache);
    let (accel, source, build) = pool.install(|| load_or_build_timed(&scene, cache.as_deref()));
    let bvh_seconds = t1.elapsed().as_secs_f64();
    let sah = accel.sah();
    println!(
        "TESSERA_TREE_SAH {:.3} (inner nodes {:.3}, leaves {:.3} in blocks of 4; {} leaves of {:.2} triangles; Embree's verbose statistic)",
        sah.nodes + sah.leaves,
        sah.nodes,
        sah.leaves,
        sah.leaf_count,
        sah.leaf_size
    );
    let mut prepared = PreparedScene::from_accel(&scene, accel);
    // As a render node keeps it (`loading::prepare`).
    prepared.slim_for_rendering();
    let triangles = scene.triangles.len();
    // What a render node keeps is the prepared scene; the loaded one goes, as in `loading`.
    drop(scene);
    release_freed();
    eprintln!(
        "{triangles} triangles: loaded in {:.2} s, BVH {source:?} in {bvh_seconds:.2} s ({} 8-wide nodes); {width}x{height}, {threads} threads",
        loaded.as_secs_f64(),
        prepared.accel.wide.len()
    );
    report_memory(&prepared, triangles, resident_before);
    report_build(source, triangles, threads, build.as_secs_f64(), bvh_seconds);
    Ok((prepared, camera))
}

/// Which traversal build runs, and how fast the BVH was built (or read from the cache).
fn report_build(source: Source, triangles: usize, threads: usize, build_s: f64, bvh_s: f64) {
    let isas: Vec<&str> = Isa::available().iter().map(|i| i.name()).collect();
    println!(
        "TESSERA_ISA {} (packet traversal build; this CPU runs {}; TESSERA_ISA=NAME picks one)",
        Isa::best().name(),
        isas.join(", ")
    );
    match source {
        Source::Built => println!(
            "TESSERA_BUILD_MTRIS_PER_S {:.3} (obvhs preset {}, {threads} threads, {build_s:.3} s, flattening and the 8-wide collapse included, storing the cache not)",
            triangles as f64 / build_s / 1e6,
            Accel::preset_name(triangles)
        ),
        Source::Cached => println!(
            "TESSERA_BVH_CACHE_LOAD_S {bvh_s:.3} (no build: read from the cache; --no-bvh-cache to time the build)"
        ),
    }
}

/// What each timed frame renders.
struct Bench<'a> {
    prepared: &'a PreparedScene,
    /// The passes' view, with the ambient-occlusion rays asked for.
    view: FrameView,
    /// The whole frames timed (rays generated, traced, shaded and stored as RGB8 tiles): their
    /// figure's name, view and what it is.
    frame_views: [(&'static str, FrameView, &'static str); 3],
    grid: TileGrid,
    size: (u32, u32),
    ao: AoRays,
    frames: u32,
}

impl Bench<'_> {
    /// Times every pass on `pool`, after one untimed warm-up frame of each.
    fn measure(&self, pool: &rayon::ThreadPool) -> Frames {
        let (width, height) = self.size;
        let passes = || time_passes(self.prepared, &self.view, width, height, self.ao);
        let shaded = |view: &FrameView| render_tiles(self.prepared, view, self.grid.tiles());
        let mut frames = Frames {
            shaded: vec![Vec::new(); self.frame_views.len()],
            ..Frames::default()
        };
        pool.install(passes);
        for (_, view, _) in &self.frame_views {
            pool.install(|| shaded(view));
        }
        for _ in 0..self.frames {
            frames.passes.push(pool.install(passes));
            for (k, (_, view, _)) in self.frame_views.iter().enumerate() {
                let t = Instant::now();
                std::hint::black_box(pool.install(|| shaded(view)));
                frames.shaded[k].push(Pass {
                    rays: width as u64 * height as u64,
                    seconds: t.elapsed().as_secs_f64(),
                });
            }
        }
        frames
    }
}

/// The whole frames timed, one primary ray a pixel each: Embree's viewer's eye light (the
/// like-for-like figure), the lights without shadows, and the wall's default (lights and
/// shadows).
fn frame_params() -> Result<[(&'static str, RenderParams, &'static str); 3]> {
    let eye_light = RenderParamsSpec {
        shading: Shading::EyeLight,
        ..RenderParamsSpec::INTERACTIVE
    };
    let unshadowed = RenderParamsSpec {
        shadows: false,
        ..RenderParamsSpec::INTERACTIVE
    };
    Ok([
        (
            "TESSERA_EYELIGHT_MRAYPS",
            eye_light.build()?,
            "the eye light, |N.D| times the base colour, as Embree's viewer and viewer_stream shade; written as RGB8 tiles",
        ),
        (
            "TESSERA_SHADED_MRAYPS",
            unshadowed.build()?,
            "full frame, lights without shadows; written as RGB8 tiles",
        ),
        (
            "TESSERA_FULL_MRAYPS",
            RenderParamsSpec::INTERACTIVE.build()?,
            "full frame, lights and shadows (the wall's default; shadow rays not counted); written as RGB8 tiles",
        ),
    ])
}

/// Resident memory of the prepared scene, and what its arrays take by count.
fn report_memory(prepared: &PreparedScene, triangles: usize, before: Option<u64>) {
    let per = |bytes: usize| bytes as f64 / triangles.max(1) as f64;
    let a = &prepared.accel;
    let wide = std::mem::size_of_val(&a.wide[..]);
    let leaf = std::mem::size_of_val(&a.triangles[..]);
    let index = std::mem::size_of_val(&a.scene_index[..]);
    let materials = prepared.slot_material_bytes();
    let counted = wide + leaf + index + materials;
    match (before, resident_bytes()) {
        (Some(before), Some(after)) => println!(
            "TESSERA_BYTES_PER_TRIANGLE {:.1} (resident {:.1} MB more after the scene was prepared and the loaded copy freed)",
            per(after.saturating_sub(before) as usize),
            after.saturating_sub(before) as f64 / 1e6
        ),
        _ => println!("TESSERA_BYTES_PER_TRIANGLE n/a (no /proc/self/statm here)"),
    }
    println!(
        "TESSERA_ARRAY_BYTES_PER_TRIANGLE {:.1} (8-wide nodes {:.1}, leaf triangles {:.1}, triangle index {:.1}, materials {:.1})",
        per(counted),
        per(wide),
        per(leaf),
        per(index),
        per(materials)
    );
}

/// Each timed frame's passes, for the fastest and the median.
#[derive(Default)]
struct Frames {
    passes: Vec<PassTimes>,
    /// Per frame view of [`Bench::frame_views`], each timed frame.
    shaded: Vec<Vec<Pass>>,
}

impl Frames {
    fn sorted(passes: impl Iterator<Item = Pass>) -> Vec<Pass> {
        let mut all: Vec<Pass> = passes.collect();
        all.sort_by(|a, b| a.seconds.total_cmp(&b.seconds));
        all
    }

    fn best(&self, pass: impl Fn(&PassTimes) -> Pass) -> Pass {
        Self::sorted(self.passes.iter().map(pass))[0]
    }

    fn line(name: &str, all: &[Pass], what: &str) {
        let median = all[all.len() / 2];
        println!(
            "{name} {:.3} (fastest of {}; median {:.3}; {what})",
            all[0].mrays_per_s(),
            all.len(),
            median.mrays_per_s()
        );
    }

    fn print(&self, name: &str, pass: impl Fn(&PassTimes) -> Pass, what: &str) {
        Self::line(name, &Self::sorted(self.passes.iter().map(pass)), what);
    }

    /// Prints every pass's figures; `pixels` primary rays a frame, `ao` rays per hit.
    fn print_all(&self, views: &[(&str, FrameView, &str)], pixels: u64, ao: u32) {
        self.print(
            "TESSERA_PRIMARY_MRAYPS",
            |p| p.primary,
            "8x8 packets: ray generation, traversal and intersection, closest hit only, no shading",
        );
        for ((name, _, what), passes) in views.iter().zip(&self.shaded) {
            Self::line(name, &Self::sorted(passes.iter().copied()), what);
        }
        self.print(
            "TESSERA_SHADOW_MRAYPS",
            |p| p.shadow,
            "one per primary hit, towards the light, as packets",
        );
        self.print(
            "TESSERA_SHADOW_SINGLE_MRAYPS",
            |p| p.shadow_single,
            "the same shadow rays one by one",
        );
        let unbounded = self.passes[0].ambient_from_surface.is_some();
        self.print(
            "TESSERA_AO_MRAYPS",
            |p| p.ambient,
            if unbounded {
                "single rays, cosine-distributed, any hit, as Embree's ao shader: from the hit \
                 point, t from 0.001, unbounded"
            } else {
                "single rays, cosine-distributed, any hit, the renderer's reach"
            },
        );
        if unbounded {
            self.print(
                "TESSERA_AO_SURFACE_MRAYPS",
                |p| p.ambient_from_surface.unwrap_or_default(),
                "the same directions from the renderer's offset origin, t from 0, unbounded",
            );
        }
        if self.passes[0].ambient_packets.is_some() {
            self.print(
                "TESSERA_AO_PACKET_MRAYPS",
                |p| p.ambient_packets.unwrap_or_default(),
                "the same rays, each hit's traced together as packets from their common origin",
            );
        }
        println!(
            "TESSERA_PRIMARY_HITS {} (of {pixels} primary rays; {ao} AO rays per hit)",
            self.passes[0].hits,
        );
    }
}
