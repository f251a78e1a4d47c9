//! Rendering from shared memory: the same pixels as replicated data, whatever the share and
//! however small the cache.

use super::*;
use crate::scene::particles::Particle;
use crate::scene::{gallery_scene, knot_scene, Scene};
use crate::volume::SharedVolume;
use crate::{orbit_of, render_tiles, FrameView};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use tessera_core::dsm::{BlockCache, BlockId, Residency};
use tessera_model::params::{RenderParams, RenderParamsSpec};
use tessera_model::wall::{TileGrid, WallSpec};

/// Every block at hand, as if every owner answered at once; counts what is asked.
struct AllBlocks {
    blocks: Vec<Arc<Block>>,
    asked: AtomicU64,
}

impl BlockFetch for AllBlocks {
    fn fetch(&self, k: BlockId) -> Arc<Block> {
        self.asked.fetch_add(1, Ordering::Relaxed);
        self.blocks[k as usize].clone()
    }
}

/// `scene` as node `rank` of `ranks` holds it, with a cache of `lines` lines.
fn shared(
    scene: &Scene,
    block_bytes: u32,
    (rank, ranks): (u32, u32),
    lines: usize,
) -> (PreparedScene, Arc<AllBlocks>) {
    let accel = crate::bvh::Accel::build(scene);
    let (manifest, volume, blocks) = prepare::blocks_of(scene, &accel, block_bytes).unwrap();
    let all = Arc::new(AllBlocks {
        blocks: blocks.map(|b| Arc::new(b.unwrap())).collect(),
        asked: AtomicU64::new(0),
    });
    let prepared = (&manifest, volume);
    let dsm = shared_from(prepared, &all.blocks, (rank, ranks), lines, all.clone());
    (dsm, all)
}

/// A node's share of the blocks of `manifest`, fetching the rest with `fetch`.
fn shared_from(
    (manifest, volume): (&Manifest, Vec<SharedVolume>),
    blocks: &[Arc<Block>],
    (rank, ranks): (u32, u32),
    lines: usize,
    fetch: Arc<dyn BlockFetch>,
) -> PreparedScene {
    let block_bytes = manifest.layout.block_bytes;
    let layout = manifest.layout;
    let residency = Residency::new(layout.total(), ranks, Some(rank), 1).unwrap();
    let per = (block_bytes / 64) as usize;
    let mut top = vec![Chunk([0; 64]); layout.top_blocks as usize * per];
    for k in 0..layout.top_blocks as usize {
        top[k * per..(k + 1) * per].copy_from_slice(blocks[k].chunks());
    }
    let mut share = vec![Chunk([0; 64]); residency.resident_len() * per];
    for (slot, k) in residency.resident_blocks() {
        share[slot * per..(slot + 1) * per].copy_from_slice(blocks[k as usize].chunks());
    }
    let tree = DsmTree::new(
        layout,
        residency,
        top.into_boxed_slice(),
        share.into_boxed_slice(),
        Arc::new(BlockCache::new(lines)),
        fetch,
    )
    .unwrap();
    PreparedScene::from_shared(manifest, tree, volume.into_iter().next())
}

fn view_of(scene: &Scene, params: RenderParams, (w, h): (u32, u32)) -> FrameView {
    // Half the default orbit's distance: close enough that particles, bricks and blocks fill
    // these tiny test walls, with much of the scene cut off at their edges.
    let framed = orbit_of(&scene.bounds(), 45.0).unwrap().camera_for_frame(7);
    let eye = framed.target() + (framed.eye() - framed.target()) * 0.5;
    let camera =
        tessera_model::camera::Camera::new(eye, framed.target(), framed.up(), 45.0).unwrap();
    FrameView::new(7, &camera, params, w, h)
}

/// Shadows, ambient occlusion and supersampling on, with the scene's lights.
fn every_ray_kind() -> RenderParams {
    RenderParamsSpec {
        shadows: true,
        ao_samples: 4,
        spp: 2,
        ..RenderParamsSpec::INTERACTIVE
    }
    .build()
    .unwrap()
}

#[test]
fn every_ray_kind_gives_the_replicated_pixels_on_every_node_with_a_tiny_cache() {
    // The gallery has mirrors and tinted glass (reflected and transmitted rays), a sun and a
    // point light (shadow packets and single shadow rays), and ambient occlusion is on.
    let scene = gallery_scene();
    let wall = WallSpec::grid(2, 1, 64, 48).tile_size(16).build().unwrap();
    let grid = TileGrid::new(wall.clone());
    let view = view_of(&scene, every_ray_kind(), (wall.width(), wall.height()));
    let replicated = crate::PreparedScene::new(&scene);
    let (want, want_rays) = render_tiles(&replicated, &view, grid.tiles());
    assert!(want_rays.reflected > 0 && want_rays.transmitted > 0 && want_rays.ambient > 0);
    for (rank, lines) in [(0, 4), (1, 0), (2, 64)] {
        let (dsm, fetch) = shared(&scene, 2048, (rank, 3), lines);
        let (got, rays) = render_tiles(&dsm, &view, grid.tiles());
        assert_eq!(rays, want_rays, "rank {rank}");
        for (t, (a, b)) in got.iter().zip(&want).enumerate() {
            assert!(a == b, "rank {rank}, {lines} lines: tile {t} differs");
        }
        let stats = dsm.shared.as_ref().unwrap().stats();
        assert!(stats.fetched > 0, "nothing was remote: {stats:?}");
        assert_eq!(stats.fetched, fetch.asked.load(Ordering::Relaxed));
        assert!(stats.local_reads > 0 && stats.block_reads > stats.fetched);
    }
}

/// An owner that answers late and out of order: a block asked for lands only when the render
/// threads have nothing left but to wait, and then only every other one of those asked for,
/// the last asked first.
#[derive(Default)]
struct LateBlocks {
    blocks: Vec<Arc<Block>>,
    pending: std::sync::Mutex<Vec<(Landing, Arc<Block>)>>,
    landed: AtomicU64,
    waited_for: AtomicU64,
    /// Blocks from this one on are counted in `asked_from_first`.
    first_counted: BlockId,
    asked_from_first: AtomicU64,
}

impl BlockFetch for LateBlocks {
    fn fetch(&self, k: BlockId) -> Arc<Block> {
        self.waited_for.fetch_add(1, Ordering::Relaxed);
        self.blocks[k as usize].clone()
    }

    fn request(&self, k: BlockId) -> Landing {
        let landing = Landing::default();
        if k >= self.first_counted {
            self.asked_from_first.fetch_add(1, Ordering::Relaxed);
        }
        let block = self.blocks[k as usize].clone();
        self.pending.lock().unwrap().push((landing.clone(), block));
        landing
    }

    fn landings(&self) -> u64 {
        self.landed.load(Ordering::SeqCst)
    }

    fn wait_for_landing(&self, _seen: u64, _timeout: std::time::Duration) -> bool {
        let mut pending = self.pending.lock().unwrap();
        let asked = std::mem::take(&mut *pending);
        for (i, (landing, block)) in asked.into_iter().rev().enumerate() {
            if i % 2 == 0 {
                landing.land(block);
                self.landed.fetch_add(1, Ordering::SeqCst);
            } else {
                pending.push((landing, block));
            }
        }
        true
    }
}

/// Rank 1 of 3 with a cache of `lines` lines, whose blocks come late and out of order (those
/// from `first` on counted as they are asked for).
fn shared_late(
    prepared: (&Manifest, Vec<SharedVolume>),
    blocks: &[Arc<Block>],
    (first, lines): (BlockId, usize),
) -> (PreparedScene, Arc<LateBlocks>) {
    let late = Arc::new(LateBlocks {
        blocks: blocks.to_vec(),
        first_counted: first,
        ..LateBlocks::default()
    });
    let dsm = shared_from(prepared, &late.blocks, (1, 3), lines, late.clone());
    (dsm, late)
}

#[test]
fn parked_packets_finish_with_the_replicated_pixels_when_blocks_come_late_out_of_order() {
    let scene = gallery_scene();
    let wall = WallSpec::grid(2, 1, 64, 48).tile_size(16).build().unwrap();
    let grid = TileGrid::new(wall.clone());
    let view = view_of(&scene, every_ray_kind(), (wall.width(), wall.height()));
    let (want, want_rays) = render_tiles(&crate::PreparedScene::new(&scene), &view, grid.tiles());
    for lines in [0, 4, 64] {
        let accel = crate::bvh::Accel::build(&scene);
        let (manifest, volume, blocks) = prepare::blocks_of(&scene, &accel, 2048).unwrap();
        let late = Arc::new(LateBlocks {
            blocks: blocks.map(|b| Arc::new(b.unwrap())).collect(),
            ..LateBlocks::default()
        });
        let dsm = shared_from(
            (&manifest, volume),
            &late.blocks,
            (1, 3),
            lines,
            late.clone(),
        );
        let (got, rays) = render_tiles(&dsm, &view, grid.tiles());
        assert_eq!(rays, want_rays, "{lines} lines");
        assert!(got == want, "{lines} lines: not the replicated pixels");
        let stats = dsm.shared.as_ref().unwrap().stats();
        assert!(stats.parked > 0, "{lines} lines: nothing was set aside");
        assert!(late.landed.load(Ordering::SeqCst) > 0);
        // Every packet finished by being traced again, none by waiting for a block.
        assert_eq!(late.waited_for.load(Ordering::Relaxed), 0, "{lines} lines");
    }
}

#[test]
fn a_cache_as_large_as_the_rest_fetches_each_block_once() {
    let scene = knot_scene(400, 24);
    let wall = WallSpec::grid(1, 1, 96, 64).tile_size(32).build().unwrap();
    let grid = TileGrid::new(wall.clone());
    let view = view_of(&scene, RenderParams::interactive(), (96, 64));
    let replicated = crate::PreparedScene::new(&scene);
    let (want, _) = render_tiles(&replicated, &view, grid.tiles());
    let (probe, _) = shared(&scene, 4096, (1, 4), 0);
    let total = probe.shared.as_ref().unwrap().layout().total() as usize;
    let (dsm, fetch) = shared(&scene, 4096, (1, 4), total);
    for pass in 0..3 {
        let (got, _) = render_tiles(&dsm, &view, grid.tiles());
        assert_eq!(got, want, "pass {pass}");
    }
    let tree = dsm.shared.as_ref().unwrap();
    let fetched = fetch.asked.load(Ordering::Relaxed) as usize;
    let cache = tree.cache().stats();
    // Each remote block fetched once (threads that missed it together may each have asked).
    assert!(cache.evictions == 0, "{cache:?}");
    assert!(
        fetched <= cache.filled as usize + 2,
        "{fetched} fetches, {cache:?}"
    );
}

/// A measurement, not a check of speed: one thread's reads of shared memory against the
/// replicated arrays on a real mesh with ambient occlusion, with no network in the way (every
/// block its own, or half of them in a cache that holds them all). Frames alternate between
/// the four so that a busy machine slows each alike; it prints min and median ratios, and
/// checks that every frame is the replicated one. Run with
/// `RAYON_NUM_THREADS=1 cargo test --release -p tessera-render reader_overhead -- --ignored --nocapture`
/// (it needs Debian's assimp-testmodels; `AO_RAYS=0` for primary rays alone, 4 by default).
#[test]
#[ignore = "a measurement: run it by hand in release"]
fn reader_overhead_against_replicated() {
    let path = std::path::Path::new(
        "/usr/share/assimp/models/glTF2/2CylinderEngine-glTF-Binary/2CylinderEngine.glb",
    );
    if !path.exists() {
        eprintln!("skipped: {} is not installed", path.display());
        return;
    }
    let scene = Scene::load(&tessera_model::scene_spec::SceneSpec::File(path.into())).unwrap();
    let (w, h) = (640, 360);
    let wall = WallSpec::grid(1, 1, w, h).tile_size(32).build().unwrap();
    let grid = TileGrid::new(wall.clone());
    let params = RenderParamsSpec {
        ao_samples: std::env::var("AO_RAYS").map_or(4, |v| v.parse().unwrap()),
        ..RenderParamsSpec::INTERACTIVE
    };
    let view = view_of(&scene, params.build().unwrap(), (w, h));
    let replicated = crate::PreparedScene::new(&scene);
    let mut accel = crate::bvh::Accel::build(&scene);
    let per_block = 8192 / std::mem::size_of::<crate::bvh::node::WideNode>();
    accel.wide = super::reorder::reorder_for_blocks(&accel.wide, per_block);
    let reordered = crate::PreparedScene::from_accel(&scene, accel);
    let (all_local, _) = shared(&scene, 8192, (0, 1), 0);
    let (probe, _) = shared(&scene, 8192, (0, 2), 0);
    let total = probe.shared.as_ref().unwrap().layout().total() as usize;
    let (cached, _) = shared(&scene, 8192, (0, 2), total);
    let variants = [
        ("replicated", &replicated),
        ("reordered tree, replicated", &reordered),
        ("shared, every block its own", &all_local),
        ("shared, half in the cache", &cached),
    ];
    let (want, _) = render_tiles(&replicated, &view, grid.tiles());
    let mut times = vec![Vec::new(); variants.len()];
    for _ in 0..12 {
        for (v, (name, p)) in variants.iter().enumerate() {
            let t = std::time::Instant::now();
            let (got, _) = render_tiles(p, &view, grid.tiles());
            times[v].push(t.elapsed().as_secs_f64());
            assert!(got == want, "{name}: not the replicated pixels");
        }
    }
    for t in &mut times {
        t.sort_by(f64::total_cmp);
    }
    let (min, median) = (times[0][0], times[0][times[0].len() / 2]);
    for (v, (name, _)) in variants.iter().enumerate() {
        let (m, med) = (times[v][0], times[v][times[v].len() / 2]);
        println!(
            "{name:28} min {m:.4} s ({:.3}x)  median {med:.4} s ({:.3}x)",
            min / m,
            median / med
        );
    }
    for (name, p) in &variants[2..] {
        println!("{name}: {:?}", p.shared.as_ref().unwrap().stats());
    }
}

/// The gallery with a volume of 27 bricks through it (a mixed scene), or the volume alone.
fn with_volume(mesh: bool) -> Scene {
    let blobs = |p: glam::Vec3| {
        let g = |c: glam::Vec3, s: f32| (-(p - c).length_squared() / (s * s)).exp();
        g(glam::Vec3::new(-0.3, -0.2, 0.0), 0.35) + g(glam::Vec3::new(0.35, 0.1, 0.1), 0.3)
    };
    let volume = crate::volume::render_tests::field(70, blobs).scaled(1.5, [0.0; 3], 1.0);
    let scene = if mesh {
        gallery_scene()
    } else {
        Scene::default()
    };
    Scene {
        volume: Some(volume),
        ..scene
    }
}

/// Iso-surfaces shaded, shadowed and ambient-occluded, or the transfer function, with the
/// other ray kinds of [`every_ray_kind`]; `cut`: a cut plane through the volume, and the
/// second pass of progressive refinement.
fn volume_params(iso: bool, cut: bool) -> RenderParams {
    volume_spec(iso, cut).build().unwrap()
}

/// The parameters of [`volume_params`], to be changed.
fn volume_spec(iso: bool, cut: bool) -> RenderParamsSpec {
    use tessera_model::cut::CutPlanes;
    use tessera_model::volume_params::{IsoValues, VolumeParams};
    let iso = if iso { &[0.3, 0.6][..] } else { &[] };
    let cuts = if cut {
        CutPlanes::new(&[(glam::Vec3::new(1.0, 0.2, 0.0), 0.1)]).unwrap()
    } else {
        CutPlanes::default()
    };
    RenderParamsSpec {
        shadows: true,
        ao_samples: 4,
        spp: 2,
        cuts,
        first_sample: if cut { 2 } else { 0 },
        volume: VolumeParams {
            iso: IsoValues::new(iso).unwrap(),
            ..VolumeParams::DEFAULT
        },
        ..RenderParamsSpec::INTERACTIVE
    }
}

#[test]
fn a_shared_volume_gives_the_replicated_pixels_with_blocks_late_and_out_of_order() {
    let brick = crate::volume::BRICK_SAMPLES * 4;
    let block_bytes = super::layout::brick_block_bytes(brick as u32);
    let wall = WallSpec::grid(2, 1, 48, 32).tile_size(16).build().unwrap();
    let grid = TileGrid::new(wall.clone());
    let cases = [
        (false, false, false),
        (false, true, false),
        (true, false, false),
        (true, true, false),
        (false, false, true),
        (true, true, true),
    ];
    for (mesh, iso, cut) in cases {
        let scene = with_volume(mesh);
        let view = view_of(
            &scene,
            volume_params(iso, cut),
            (wall.width(), wall.height()),
        );
        let replicated = crate::PreparedScene::new(&scene);
        let (want, want_rays) = render_tiles(&replicated, &view, grid.tiles());
        let without = Scene {
            volume: None,
            ..scene.clone()
        };
        let (unseen, _) = render_tiles(&crate::PreparedScene::new(&without), &view, grid.tiles());
        assert!(unseen != want, "the volume is not in view");
        let accel = crate::bvh::Accel::build(&scene);
        let (manifest, volume, blocks) = prepare::blocks_of(&scene, &accel, block_bytes).unwrap();
        assert_eq!(manifest.layout.brick_blocks, 27);
        let blocks: Vec<_> = blocks.map(|b| Arc::new(b.unwrap())).collect();
        for lines in [0, 4, 64] {
            let case = format!("mesh {mesh}, iso {iso}, cut {cut}, {lines} lines");
            let first = manifest.layout.first_brick_block();
            let prepared = (&manifest, volume.clone());
            let (dsm, late) = shared_late(prepared, &blocks, (first, lines));
            let (got, rays) = render_tiles(&dsm, &view, grid.tiles());
            assert_eq!(rays, want_rays, "{case}");
            assert!(got == want, "{case}: not the replicated pixels");
            let stats = dsm.shared.as_ref().unwrap().stats();
            assert!(stats.parked > 0, "{case}: nothing was set aside");
            assert_eq!(late.waited_for.load(Ordering::Relaxed), 0, "{case}");
            let bricks_asked = late.asked_from_first.load(Ordering::Relaxed);
            assert!(bricks_asked > 0, "{case}: no brick was asked for");
        }
    }
}

/// `count` particles scattered through `around` (deterministically), of radii a hundredth to
/// three hundredths of its diagonal, every 37th with its attribute missing.
fn particles_in(around: &crate::geometry::Bounds, count: u32) -> Vec<Particle> {
    let (center, size) = (around.center(), around.diagonal());
    let mut seed = 0x2545_f491_u32;
    let mut unit = || {
        seed ^= seed << 13;
        seed ^= seed >> 17;
        seed ^= seed << 5;
        seed as f32 / u32::MAX as f32
    };
    (0..count)
        .map(|i| Particle {
            center: center + (glam::Vec3::new(unit(), unit(), unit()) - 0.5) * size * 0.8,
            radius: size.length() * (0.01 + 0.02 * unit()),
            attribute: if i % 37 == 0 {
                f32::NAN
            } else {
                (i % 17) as f32
            },
        })
        .collect()
}

#[test]
fn shared_particles_give_the_replicated_pixels_alone_and_mixed_with_blocks_late() {
    let wall = WallSpec::grid(2, 1, 48, 32).tile_size(16).build().unwrap();
    let grid = TileGrid::new(wall.clone());
    let brick_block = super::layout::brick_block_bytes(crate::volume::BRICK_SAMPLES as u32 * 4);
    // Particles alone in small blocks (many blocks of tree nodes and of particles), cropped
    // or not; then the gallery with a volume and particles, iso-surfaces and a cut plane.
    let cases = [(false, None), (false, Some((2.0, 9.0))), (true, None)];
    for (mixed, crop) in cases {
        let mut scene = if mixed {
            with_volume(true)
        } else {
            Scene::default()
        };
        let around = if mixed {
            scene.bounds()
        } else {
            crate::geometry::Bounds {
                min: glam::Vec3::splat(-1.0),
                max: glam::Vec3::splat(1.0),
            }
        };
        scene.particles = particles_in(&around, if mixed { 300 } else { 3000 });
        let params = RenderParamsSpec {
            crop,
            ..volume_spec(mixed, mixed)
        }
        .build()
        .unwrap();
        let view = view_of(&scene, params, (wall.width(), wall.height()));
        let (want, want_rays) =
            render_tiles(&crate::PreparedScene::new(&scene), &view, grid.tiles());
        let without = Scene {
            particles: Vec::new(),
            ..scene.clone()
        };
        let (unseen, _) = render_tiles(&crate::PreparedScene::new(&without), &view, grid.tiles());
        let differ = unseen.iter().flatten().zip(want.iter().flatten());
        let changed = differ.filter(|(a, b)| a != b).count();
        assert!(changed > 500, "{changed} bytes show particles");
        let accel = crate::bvh::Accel::build(&scene);
        let block_bytes = if mixed { brick_block } else { 2048 };
        let (manifest, volume, blocks) = prepare::blocks_of(&scene, &accel, block_bytes).unwrap();
        let layout = manifest.layout;
        assert!(layout.sphere_blocks > 0 && layout.sphere_node_blocks > 0);
        assert!(mixed || layout.sphere_blocks >= 20, "{layout:?}");
        let blocks: Vec<_> = blocks.map(|b| Arc::new(b.unwrap())).collect();
        for lines in [0, 4, 64] {
            let case = format!("mixed {mixed}, crop {crop:?}, {lines} lines");
            let first = layout.first_sphere_node_block();
            let prepared = (&manifest, volume.clone());
            let (dsm, late) = shared_late(prepared, &blocks, (first, lines));
            let (got, rays) = render_tiles(&dsm, &view, grid.tiles());
            assert_eq!(rays, want_rays, "{case}");
            assert!(got == want, "{case}: not the replicated pixels");
            assert_eq!(late.waited_for.load(Ordering::Relaxed), 0, "{case}");
            let particle_blocks_asked = late.asked_from_first.load(Ordering::Relaxed);
            assert!(
                particle_blocks_asked > 0,
                "{case}: no particle block was asked for"
            );
        }
    }
}
