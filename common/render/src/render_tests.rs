//! Whole-image properties of the renderer: determinism, ray counts, particles, materials and
//! cutting planes.

use crate::frame::{render_tiles_with, ShadowRays};
use crate::scene::{knot_scene, Scene};
use crate::*;
use glam::Vec3;
use tessera_model::camera::Camera;
use tessera_model::cut::CutPlanes;
use tessera_model::params::{RenderParams, RenderParamsSpec, Shading};
use tessera_model::wall::{TileGrid, WallLayout, WallSpec};

#[test]
fn a_tile_is_identical_alone_or_in_a_batch_and_on_any_thread_count() {
    let scene = PreparedScene::new(&knot_scene(128, 16));
    let wall = WallSpec::grid(2, 1, 96, 64).tile_size(32).build().unwrap();
    let grid = TileGrid::new(wall.clone());
    let camera = orbit_of(&knot_scene(128, 16).bounds(), 45.0)
        .unwrap()
        .camera_for_frame(3);
    let view = FrameView::new(
        3,
        &camera,
        RenderParams::interactive(),
        wall.width(),
        wall.height(),
    );
    let (all, counts) = render_tiles(&scene, &view, grid.tiles());
    assert!(counts.primary == wall.visible_pixels() && counts.shadow > 0);
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    for (i, tile) in grid.tiles().iter().enumerate() {
        let (alone, _) = one.install(|| render_tiles(&scene, &view, std::slice::from_ref(tile)));
        assert_eq!(alone[0], all[i], "tile {i}");
    }
    // Something other than background was drawn.
    let distinct: std::collections::HashSet<&[u8]> = all.iter().flat_map(|t| t.chunks(3)).collect();
    assert!(distinct.len() > 20);
}

#[test]
fn shadows_off_traces_no_shadow_rays() {
    let scene = PreparedScene::new(&knot_scene(64, 8));
    let wall = WallLayout::grid(1, 1, 40, 30).unwrap();
    let grid = TileGrid::new(wall.clone());
    let camera = orbit_of(&knot_scene(64, 8).bounds(), 45.0)
        .unwrap()
        .camera_for_frame(0);
    let view = FrameView::new(
        0,
        &camera,
        RenderParamsSpec {
            shadows: false,
            ..RenderParamsSpec::INTERACTIVE
        }
        .build()
        .unwrap(),
        40,
        30,
    );
    let (_, counts) = render_tiles(&scene, &view, grid.tiles());
    assert_eq!(
        counts,
        RayCounts {
            primary: 1200,
            ..RayCounts::default()
        }
    );
}

#[test]
fn a_scene_without_lights_traces_no_shadow_rays_and_ao_only_when_asked() {
    let mut scene = knot_scene(64, 8);
    scene.lights.clear();
    let prepared = PreparedScene::new(&scene);
    let wall = WallLayout::grid(1, 1, 40, 30).unwrap();
    let grid = TileGrid::new(wall.clone());
    let camera = orbit_of(&scene.bounds(), 45.0).unwrap().camera_for_frame(0);
    for params in RenderParams::PRESETS {
        let view = FrameView::new(0, &camera, params, 40, 30);
        let (_, counts) = render_tiles(&prepared, &view, grid.tiles());
        assert_eq!(counts.shadow, 0, "{params:?}");
        assert_eq!(counts.ambient > 0, params.ao_samples() > 0, "{params:?}");
    }
}

#[test]
fn every_preset_is_deterministic_and_finite() {
    let scene = knot_scene(96, 12);
    let prepared = PreparedScene::new(&scene);
    let wall = WallSpec::grid(1, 1, 48, 32).tile_size(16).build().unwrap();
    let grid = TileGrid::new(wall.clone());
    let camera = orbit_of(&scene.bounds(), 45.0).unwrap().camera_for_frame(7);
    for params in RenderParams::PRESETS {
        let view = FrameView::new(7, &camera, params, 48, 32);
        let (a, _) = render_tiles(&prepared, &view, grid.tiles());
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        let (b, _) = one.install(|| render_tiles(&prepared, &view, grid.tiles()));
        assert_eq!(a, b, "{params:?}");
    }
}

#[test]
fn particles_are_drawn_colour_mapped_and_cropped_and_only_they_get_a_sphere_bvh() {
    use crate::scene::particles::{write_tpart, Particle};
    assert!(PreparedScene::new(&knot_scene(32, 4)).spheres.is_none());
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("p.tpart");
    let particles: Vec<Particle> = (0..50)
        .map(|i| Particle {
            center: Vec3::new((i % 10) as f32, (i / 10) as f32, 0.0),
            radius: 0.4,
            attribute: i as f32,
        })
        .collect();
    write_tpart(&path, &particles).unwrap();
    let scene = Scene::load(&tessera_model::scene_spec::SceneSpec::File(path)).unwrap();
    assert_eq!(scene.particles.len(), 50);
    let prepared = PreparedScene::new(&scene);
    assert!(prepared.spheres.is_some() && prepared.accel.wide.is_empty());
    let wall = WallSpec::grid(1, 1, 64, 48).tile_size(32).build().unwrap();
    let grid = TileGrid::new(wall.clone());
    // The file's world point (4.5, 2, 0) is the middle of the particles, the render origin.
    let frame = scene.render_from_world;
    assert_eq!(frame.world_origin, glam::DVec3::new(4.5, 2.0, 0.0));
    let camera = Camera::new(
        frame.point(glam::DVec3::new(4.5, 2.0, 14.0)),
        frame.point(glam::DVec3::new(4.5, 2.0, 0.0)),
        Vec3::Y,
        50.0,
    )
    .unwrap();
    let background_pixels = |params: RenderParams| {
        let view = FrameView::new(0, &camera, params, 64, 48);
        let (tiles, _) = render_tiles(&prepared, &view, grid.tiles());
        let rays = PixelRays::new(&camera, 64, 48);
        grid.tiles()
            .iter()
            .zip(&tiles)
            .map(|(t, rgb)| {
                (0..t.pixel_count())
                    .filter(|&k| {
                        let (x, y) = (t.x + k as u32 % t.width, t.y + k as u32 / t.width);
                        rgb[k * 3..k * 3 + 3] == encode_srgb_ish(background(rays.direction(x, y)))
                    })
                    .count()
            })
            .sum::<usize>()
    };
    let all = background_pixels(RenderParams::interactive());
    let none = background_pixels(
        RenderParamsSpec {
            crop: Some((1000.0, 2000.0)),
            ..RenderParamsSpec::INTERACTIVE
        }
        .build()
        .unwrap(),
    );
    let half = background_pixels(
        RenderParamsSpec {
            crop: Some((0.0, 24.5)),
            ..RenderParamsSpec::INTERACTIVE
        }
        .build()
        .unwrap(),
    );
    assert_eq!(
        none,
        64 * 48,
        "everything cropped away leaves only background"
    );
    assert!(all < half && half < none, "{all} < {half} < {none}");
}

/// Renders the whole of a `w × h` one-screen wall.
fn render_all(scene: &PreparedScene, view: &FrameView, w: u32, h: u32) -> (Vec<u8>, RayCounts) {
    let grid = TileGrid::new(WallSpec::grid(1, 1, w, h).tile_size(16).build().unwrap());
    let image = crate::render_wall(scene, view, &grid);
    let (_, counts) = render_tiles(scene, view, grid.tiles());
    (image.rgb, counts)
}

fn gallery_camera() -> Camera {
    Camera::new(
        Vec3::new(0.5, 1.0, 9.0),
        Vec3::new(0.0, 0.0, -2.0),
        Vec3::Y,
        55.0,
    )
    .unwrap()
}

#[test]
fn only_scenes_with_transparency_blend_and_only_mirrors_reflect() {
    let knot = PreparedScene::new(&knot_scene(64, 8));
    assert!(!knot.blends);
    let camera = orbit_of(&knot_scene(64, 8).bounds(), 45.0)
        .unwrap()
        .camera_for_frame(2);
    for params in RenderParams::PRESETS {
        let view = FrameView::new(2, &camera, params, 48, 32);
        let (_, counts) = render_all(&knot, &view, 48, 32);
        assert_eq!((counts.transmitted, counts.reflected), (0, 0), "{params:?}");
    }

    let gallery = crate::scene::gallery_scene();
    let prepared = PreparedScene::new(&gallery);
    assert!(prepared.blends);
    let view = FrameView::new(0, &gallery_camera(), RenderParams::interactive(), 64, 48);
    let (image, counts) = render_all(&prepared, &view, 64, 48);
    assert!(counts.transmitted > 0 && counts.reflected > 0, "{counts:?}");

    // The glass and the mirror change the picture: made opaque and matte, it differs.
    let mut matte = gallery.clone();
    for m in &mut matte.materials {
        *m = crate::scene::Material::lambert(m.albedo);
    }
    let matte = PreparedScene::new(&matte);
    assert!(!matte.blends);
    let (plain, counts) = render_all(&matte, &view, 64, 48);
    assert_eq!((counts.transmitted, counts.reflected), (0, 0));
    let differing = image.chunks(3).zip(plain.chunks(3)).filter(|(a, b)| a != b);
    assert!(differing.count() > 64 * 48 / 10);
}

#[test]
fn materials_render_the_same_on_any_thread_count() {
    let prepared = PreparedScene::new(&crate::scene::gallery_scene());
    for params in RenderParams::PRESETS {
        let view = FrameView::new(5, &gallery_camera(), params, 40, 30);
        let (a, _) = render_all(&prepared, &view, 40, 30);
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        let (b, _) = one.install(|| render_all(&prepared, &view, 40, 30));
        assert_eq!(a, b, "{params:?}");
    }
}

#[test]
fn cutting_planes_remove_what_they_cut_and_nothing_else() {
    let scene = knot_scene(96, 12);
    let prepared = PreparedScene::new(&scene);
    let camera = orbit_of(&scene.bounds(), 45.0).unwrap().camera_for_frame(4);
    let grid = TileGrid::new(WallSpec::grid(1, 1, 64, 48).tile_size(16).build().unwrap());
    let with_cuts = |planes: &[(Vec3, f32)]| {
        RenderParamsSpec {
            cuts: CutPlanes::new(planes).unwrap(),
            ..RenderParams::final_frame().spec()
        }
        .build()
        .unwrap()
    };
    let whole = FrameView::new(4, &camera, RenderParams::final_frame(), 64, 48);
    let (uncut_image, _) = render_all(&prepared, &whole, 64, 48);
    let uncut = crate::aov::primary_aovs(&prepared, &whole, &grid);

    // A plane beyond the scene cuts nothing: the image is unchanged, bit for bit.
    let far = FrameView::new(4, &camera, with_cuts(&[(Vec3::X, 1000.0)]), 64, 48);
    assert_eq!(render_all(&prepared, &far, 64, 48).0, uncut_image);

    // Cutting away the top half and the front: every visible point is kept, and the picture
    // changes.
    let planes = [(Vec3::Y, 0.0), (Vec3::new(0.3, 0.0, 1.0), 0.5)];
    let params = with_cuts(&planes);
    let view = FrameView::new(4, &camera, params, 64, 48);
    let cut = crate::aov::primary_aovs(&prepared, &view, &grid);
    let rays = PixelRays::new(&camera, 64, 48);
    let tolerance = 1e-4 * scene.bounds().diagonal().length();
    let mut changed = 0;
    for (k, (&depth, &before)) in cut.depth.iter().zip(&uncut.depth).enumerate() {
        if depth.is_finite() {
            let p = rays.eye + rays.direction(k as u32 % 64, k as u32 / 64) * depth;
            let outside = params
                .cuts()
                .planes()
                .iter()
                .map(|pl| pl.truncate().dot(p) - pl.w)
                .fold(f32::NEG_INFINITY, f32::max);
            assert!(outside <= tolerance, "pixel {k} shows a cut point {p}");
        }
        changed += usize::from(depth != before);
    }
    assert!(changed > 100, "only {changed} pixels changed");

    // Cutting away everything leaves only the background.
    let all = FrameView::new(4, &camera, with_cuts(&[(Vec3::Y, -100.0)]), 64, 48);
    let (image, counts) = render_all(&prepared, &all, 64, 48);
    assert_eq!(counts.shadow + counts.ambient, 0);
    for (k, px) in image.chunks(3).enumerate() {
        let dir = rays.direction(k as u32 % 64, k as u32 / 64);
        assert_eq!(px, encode_srgb_ish(background(dir)));
    }
}

#[test]
fn supersampling_averages_jittered_samples_and_stays_deterministic() {
    let scene = knot_scene(64, 8);
    let prepared = PreparedScene::new(&scene);
    let camera = orbit_of(&scene.bounds(), 45.0).unwrap().camera_for_frame(1);
    let with = |spp, first_sample| {
        RenderParamsSpec {
            spp,
            first_sample,
            ..RenderParamsSpec::INTERACTIVE
        }
        .build()
        .unwrap()
    };
    let view = |p| FrameView::new(1, &camera, p, 48, 32);
    let (one, c1) = render_all(&prepared, &view(with(1, 0)), 48, 32);
    let (four, c4) = render_all(&prepared, &view(with(4, 0)), 48, 32);
    assert_eq!(c4.primary, 4 * c1.primary);
    // Edges get antialiased: some pixels change, most stay close.
    let changed = one.iter().zip(&four).filter(|(a, b)| a != b).count();
    assert!(changed > 0);
    let one_thread = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let again = one_thread.install(|| render_all(&prepared, &view(with(4, 0)), 48, 32).0);
    assert_eq!(four, again);
    // A later progressive pass draws other samples.
    let (later, _) = render_all(&prepared, &view(with(4, 4)), 48, 32);
    assert_ne!(later, four);
}

#[test]
fn an_empty_scene_traces_nothing() {
    let prepared = PreparedScene::new(&Scene::default());
    assert!(prepared.is_empty());
    let camera = Camera::new(Vec3::Z, Vec3::ZERO, Vec3::Y, 40.0).unwrap();
    let (image, counts) = render_all(
        &prepared,
        &FrameView::new(0, &camera, RenderParams::final_frame(), 20, 10),
        20,
        10,
    );
    assert_eq!(counts.total(), 0);
    assert!(image.chunks(3).all(|p| p == &image[..3]));
}

#[test]
fn shadow_packets_give_the_pixels_of_single_shadow_rays() {
    use crate::scene::particles::Particle;
    use crate::scene::Light;
    use tessera_model::scene_spec::SceneSpec;
    // Mirrors and glass (their bounces trace single shadow rays), a point light, two
    // directional lights, particles that cast shadows, and a cutting plane.
    let mut scene = Scene::load(&SceneSpec::Gallery).unwrap();
    scene.lights.push(Light::Directional {
        towards: Vec3::new(0.3, 1.0, 0.4).normalize(),
        intensity: 0.6,
    });
    scene.lights.push(Light::Directional {
        towards: Vec3::new(-0.8, 0.5, 0.1).normalize(),
        intensity: 0.3,
    });
    scene.particles = (0..12)
        .map(|i| Particle {
            center: Vec3::new(i as f32 * 0.5 - 3.0, 1.5, 0.5),
            radius: 0.2,
            attribute: i as f32,
        })
        .collect();
    let prepared = PreparedScene::new(&scene);
    assert!(prepared.spheres.is_some() && prepared.lights().len() >= 3);
    let grid = TileGrid::new(WallSpec::grid(1, 1, 96, 64).tile_size(32).build().unwrap());
    for cuts in [
        CutPlanes::EMPTY,
        CutPlanes::new(&[(Vec3::new(0.1, 1.0, 0.0), 1.2)]).unwrap(),
    ] {
        let params = RenderParamsSpec {
            cuts,
            ..RenderParamsSpec::INTERACTIVE
        }
        .build()
        .unwrap();
        let view = FrameView::new(0, &gallery_camera(), params, 96, 64);
        let never = Cancel::new();
        let (packets, packet_counts, _) =
            render_tiles_with(&prepared, &view, grid.tiles(), ShadowRays::Packets, &never).unwrap();
        let (single, single_counts, _) =
            render_tiles_with(&prepared, &view, grid.tiles(), ShadowRays::Single, &never).unwrap();
        assert!(packet_counts.shadow > 1000, "{packet_counts:?}");
        assert_eq!(packet_counts, single_counts);
        assert_eq!(packets, single);
    }
}

#[test]
fn the_linear_image_is_what_the_8_bit_image_encodes() {
    let scene = knot_scene(64, 8);
    let prepared = PreparedScene::new(&scene);
    let wall = WallSpec::grid(2, 1, 40, 28).tile_size(16).build().unwrap();
    let grid = TileGrid::new(wall.clone());
    let camera = orbit_of(&scene.bounds(), 45.0).unwrap().camera_for_frame(1);
    let params = RenderParamsSpec {
        spp: 3,
        ao_samples: 2,
        ..RenderParamsSpec::INTERACTIVE
    }
    .build()
    .unwrap();
    let view = FrameView::new(1, &camera, params, wall.width(), wall.height());
    let rgb8 = render_wall(&prepared, &view, &grid);
    let linear = render_wall_linear(&prepared, &view, &grid);
    assert_eq!(linear.len() * 3, rgb8.rgb.len());
    for (c, px) in linear.iter().zip(rgb8.rgb.chunks(3)) {
        assert_eq!(&encode_srgb_ish(*c)[..], px);
    }
}

#[test]
fn a_cancelled_render_of_a_runaway_quality_stops_within_a_sample_and_returns_nothing() {
    let scene = knot_scene(64, 8);
    let prepared = PreparedScene::new(&scene);
    let wall = WallSpec::grid(1, 1, 64, 32).tile_size(32).build().unwrap();
    let grid = TileGrid::new(wall.clone());
    let camera = orbit_of(&scene.bounds(), 45.0).unwrap().camera_for_frame(0);
    // 2^18 rays per pixel, the most a control client may ask: minutes for these two tiles.
    let params = RenderParamsSpec {
        spp: 4096,
        ao_samples: 63,
        ..RenderParamsSpec::INTERACTIVE
    }
    .build()
    .unwrap();
    let view = FrameView::new(0, &camera, params, wall.width(), wall.height());
    let session = Cancel::new();
    let batch = session.child();
    let traced = std::thread::scope(|s| {
        let render = s.spawn(|| render_tiles_footprints(&prepared, &view, grid.tiles(), &batch));
        // Not a wait for readiness: cancelled before it starts, the render returns nothing
        // all the same; the pause only makes a cancel in mid-packet the likely case.
        std::thread::sleep(std::time::Duration::from_millis(50));
        let cancelled = std::time::Instant::now();
        session.cancel();
        let traced = render.join().unwrap();
        (traced, cancelled.elapsed())
    });
    assert!(traced.0.is_none(), "a cancelled batch returns no pixels");
    // A sample of a packet is some 4,000 rays: milliseconds even in a debug build.
    assert!(
        traced.1 < std::time::Duration::from_millis(500),
        "{:?}",
        traced.1
    );
}

#[test]
fn a_render_nobody_cancels_is_the_plain_render() {
    let scene = knot_scene(64, 8);
    let prepared = PreparedScene::new(&scene);
    let wall = WallSpec::grid(1, 1, 40, 28).tile_size(16).build().unwrap();
    let grid = TileGrid::new(wall.clone());
    let camera = orbit_of(&scene.bounds(), 45.0).unwrap().camera_for_frame(2);
    let view = FrameView::new(2, &camera, RenderParams::interactive(), 40, 28);
    let (plain, plain_counts) = render_tiles(&prepared, &view, grid.tiles());
    let sibling = Cancel::new();
    let (tiles, counts, _) =
        render_tiles_footprints(&prepared, &view, grid.tiles(), &sibling.child()).unwrap();
    assert_eq!((tiles, counts), (plain, plain_counts));
    sibling.child().cancel();
    assert!(
        !sibling.is_cancelled(),
        "a child does not cancel its parent"
    );
}

/// Eye-light parameters: the wall's defaults (shadows on, lights) but the eye light alone.
fn eye_light_params(spec: RenderParamsSpec) -> RenderParams {
    RenderParamsSpec {
        shading: Shading::EyeLight,
        ..spec
    }
    .build()
    .unwrap()
}

#[test]
fn an_eye_light_pixel_is_the_cosine_to_the_eye_times_the_albedo() {
    // A quad through the origin turned 60° about y, in front of a camera at z = 5.
    let normal = Vec3::new(60f32.to_radians().sin(), 0.0, 60f32.to_radians().cos());
    let (u, v) = (normal.cross(Vec3::Y), Vec3::Y);
    let albedo = Vec3::new(0.9, 0.5, 0.2);
    let scene = Scene {
        positions: vec![-u - v, u - v, u + v, -u + v],
        triangles: vec![[0, 1, 2], [0, 2, 3]],
        triangle_material: vec![0, 0],
        materials: vec![crate::scene::Material::lambert(albedo)],
        ..Scene::default()
    };
    let prepared = PreparedScene::new(&scene);
    let camera = Camera::new(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, Vec3::Y, 30.0).unwrap();
    let view = FrameView::new(
        0,
        &camera,
        eye_light_params(RenderParamsSpec::INTERACTIVE),
        33,
        33,
    );
    let (image, counts) = render_all(&prepared, &view, 33, 33);
    assert_eq!(
        counts.total(),
        counts.primary,
        "no ray but the primary ones"
    );
    for (x, y) in [(16, 16), (14, 10), (18, 21)] {
        let dir = view.rays.direction_at(x, y, 0.5, 0.5);
        let expected = encode_srgb_ish(albedo * normal.dot(dir).abs());
        let at = ((y * 33 + x) * 3) as usize;
        assert_eq!(&image[at..at + 3], &expected[..], "pixel {x},{y}");
    }
}

#[test]
fn the_eye_light_fast_path_gives_the_pixels_of_the_general_shading() {
    // Three materials, a cutting plane and two samples a pixel.
    let scene = knot_scene(64, 8);
    let prepared = PreparedScene::new(&scene);
    assert!(prepared.spheres.is_none() && prepared.volume.is_none() && prepared.colors.is_none());
    let grid = TileGrid::new(WallSpec::grid(2, 1, 60, 44).tile_size(20).build().unwrap());
    let camera = orbit_of(&scene.bounds(), 45.0).unwrap().camera_for_frame(2);
    let cut = CutPlanes::new(&[(Vec3::new(0.2, 1.0, 0.1), 0.3)]).unwrap();
    let never = Cancel::new();
    for (cuts, spp) in [(CutPlanes::EMPTY, 1), (cut, 2)] {
        let params = eye_light_params(RenderParamsSpec {
            cuts,
            spp,
            ..RenderParamsSpec::INTERACTIVE
        });
        let view = FrameView::new(2, &camera, params, 120, 44);
        let render = |rays| render_tiles_with(&prepared, &view, grid.tiles(), rays, &never);
        let (fast, fast_counts, _) = render(ShadowRays::Packets).unwrap();
        let (general, general_counts, _) = render(ShadowRays::Single).unwrap();
        assert_eq!(fast_counts, general_counts);
        assert_eq!(fast_counts.total(), fast_counts.primary);
        assert_eq!(fast, general);
        let full = FrameView::new(2, &camera, RenderParams::interactive(), 120, 44);
        assert_ne!(fast, render_tiles(&prepared, &full, grid.tiles()).0);
    }
}
