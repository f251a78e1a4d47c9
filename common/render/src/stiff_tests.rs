//! Stiff and extreme cases, for every kind of data (issue 23): a scene moved far from the
//! origin, a volume whose values are scaled by 10^k, missing data, and geometry of extreme
//! sizes give the picture of the plain case, or one that is finite and what it must be.
//!
//! Pictures are compared by [`Agreement`]: the share of pixels within two levels of 255 on
//! every channel, and the largest depth difference relative to the scene's size. The same
//! comparison is `tessera-master bench stiff`'s, on a user's own data.

use crate::scene::particles::{frame_of, place, WorldParticle};
use crate::scene::{from_volume, knot_scene, Scene};
use crate::stiff::{agreement, picture, transformed, Agreement, Transform, View};
use crate::volume::{Volume, VoxelType};
use glam::{DVec3, Vec3};
use tessera_model::params::{RenderParams, RenderParamsSpec};
use tessera_model::volume_params::{
    IsoValues, TransferDomain, TransferFunction, TransferPoint, VolumeParams,
};

const SIZE: (u32, u32) = (64, 48);

/// The view from world point `eye` towards `target` of a scene of size `size`.
fn view(eye: DVec3, target: DVec3, size: f64) -> View {
    View { eye, target, size }
}

/// Asserts that at least `least` of the pixels agree, depths within 10⁻⁴ of the scene's size,
/// and at most two pixels hit in one picture and not the other.
fn assert_agrees(what: &str, agreed: Agreement, size: f64, least: f64) {
    assert!(
        agreed.pixels >= least && agreed.depth < 1e-4 * size && agreed.coverage <= 2,
        "{what}: {agreed:?}"
    );
}

/// A deterministic Gaussian cloud of `n` particles (σ 0.5, radius 0.03) around the origin.
fn cloud(n: usize) -> Vec<WorldParticle> {
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut uniform = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut normal = move || {
        let (u, v) = (uniform().max(1e-12), uniform());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    };
    (0..n)
        .map(|i| WorldParticle {
            center: DVec3::new(normal(), normal(), normal()) * 0.5,
            radius: 0.03,
            attribute: i as f32,
        })
        .collect()
}

/// Writes `particles` as CSV with every digit an f64 has, loads it as a scene.
fn particle_scene(particles: &[WorldParticle]) -> Scene {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cloud.csv");
    let mut text = String::from("x,y,z,radius,attribute\n");
    for p in particles {
        let c = p.center;
        let line = format!(
            "{:?},{:?},{:?},{},{}\n",
            c.x, c.y, c.z, p.radius, p.attribute
        );
        text.push_str(&line);
    }
    std::fs::write(&path, text).unwrap();
    Scene::load(&tessera_model::scene_spec::SceneSpec::File(path)).unwrap()
}

#[test]
fn particles_anywhere_up_to_1e7_render_the_picture_at_the_origin() {
    let at_origin = cloud(2000);
    let near = view(DVec3::new(0.0, 0.0, 4.0), DVec3::ZERO, 4.0);
    let params = RenderParams::interactive();
    let plain = picture(&particle_scene(&at_origin), &near, params, SIZE);
    for k in [3, 5, 6, 7] {
        let t = Transform::Offset(10f64.powi(k));
        let Transform::Offset(d) = t else {
            unreachable!()
        };
        let moved: Vec<_> = at_origin
            .iter()
            .map(|p| WorldParticle {
                center: p.center + DVec3::splat(d),
                ..*p
            })
            .collect();
        // Through the CSV loader, as a user's far data would come.
        let far = picture(&particle_scene(&moved), &near.transformed(t), params, SIZE);
        assert_agrees(&format!("{t}"), agreement(&plain, &far, t), 4.0, 0.995);
    }
}

#[test]
fn particles_placed_in_a_far_frame_keep_their_shape() {
    let cloud = cloud(50);
    let far: Vec<_> = cloud
        .iter()
        .map(|p| WorldParticle {
            center: p.center + DVec3::splat(1e7),
            ..*p
        })
        .collect();
    let (near, far) = (place(&cloud, frame_of(&cloud)), place(&far, frame_of(&far)));
    for (a, b) in near.iter().zip(&far) {
        assert!(
            (a.center - b.center).abs().max_element() < 1e-6,
            "{a:?} {b:?}"
        );
    }
}

/// `n`³ samples of the signed distance to a sphere of radius 0.6 (times `scale`), over -1..1
/// about `centre`.
fn sphere_field(n: usize, scale: f32, centre: DVec3) -> Volume {
    let at_origin = crate::volume::render_tests::field(n, |p| (p.length() - 0.6) * scale);
    at_origin.scaled(1.0, centre.to_array(), 1.0)
}

/// Volume parameters with everything in data units scaled by `scale`: the iso-value, or a
/// transfer function opaque inside the sphere and clear outside it.
fn volume_params(iso: bool, scale: f32) -> RenderParams {
    // Red deep inside, blue at the surface: a cut shows in the colour, not only the opacity.
    let point = |value: f32, color, opacity| TransferPoint {
        value: value * scale,
        color,
        opacity,
    };
    let points = [
        point(-0.3, [0.9, 0.2, 0.1], 0.5),
        point(0.0, [0.2, 0.4, 0.9], 0.2),
        point(0.05, [0.2, 0.9, 0.3], 0.0),
    ];
    let transfer = TransferFunction::new(TransferDomain::Data, &points).unwrap();
    let volume = VolumeParams {
        iso: if iso {
            IsoValues::new(&[0.1 * scale]).unwrap()
        } else {
            IsoValues::NONE
        },
        transfer,
        ..VolumeParams::DEFAULT
    };
    RenderParamsSpec {
        volume,
        ..RenderParamsSpec::INTERACTIVE
    }
    .build()
    .unwrap()
}

#[test]
fn a_volume_anywhere_up_to_1e7_renders_the_picture_at_the_origin() {
    let near = view(DVec3::new(0.4, 0.3, 3.5), DVec3::ZERO, 3.5);
    for iso in [true, false] {
        let params = volume_params(iso, 1.0);
        let plain = picture(
            &from_volume(sphere_field(24, 1.0, DVec3::ZERO)),
            &near,
            params,
            SIZE,
        );
        for k in [3, 6, 7] {
            let t = Transform::Offset(10f64.powi(k));
            let scene = from_volume(sphere_field(24, 1.0, DVec3::splat(10f64.powi(k))));
            let far = picture(&scene, &near.transformed(t), params, SIZE);
            assert_agrees(
                &format!("iso {iso}, {t}"),
                agreement(&plain, &far, t),
                3.5,
                0.995,
            );
        }
    }
}

#[test]
fn volume_values_scaled_by_1e_minus_30_to_1e30_render_the_same_picture() {
    let near = view(DVec3::new(0.4, 0.3, 3.5), DVec3::ZERO, 3.5);
    for iso in [true, false] {
        let scene = from_volume(sphere_field(24, 1.0, DVec3::ZERO));
        let plain = picture(&scene, &near, volume_params(iso, 1.0), SIZE);
        for k in [-30, -20, -10, -3, 3, 10, 20, 30] {
            let scale = 10f32.powi(k);
            let t = Transform::Values(scale);
            // The volume's values made at that scale, not scaled after the fact.
            let scene = from_volume(sphere_field(24, scale, DVec3::ZERO));
            let scaled = picture(&scene, &near, volume_params(iso, scale), SIZE);
            assert_agrees(
                &format!("iso {iso}, {t}"),
                agreement(&plain, &scaled, t),
                3.5,
                0.99,
            );
        }
    }
}

/// The sphere field with the voxels of one octant (x, y, z > 0.1) missing (NaN, or
/// ±infinity where `infinite`).
fn field_with_a_hole(infinite: bool) -> Volume {
    let n = 24;
    let full = sphere_field(n, 1.0, DVec3::ZERO);
    let step = 2.0 / (n - 1) as f32;
    let mut values = full.values().to_vec();
    for (i, v) in values.iter_mut().enumerate() {
        let p =
            Vec3::new((i % n) as f32, (i / n % n) as f32, (i / n / n) as f32) * step - Vec3::ONE;
        if p.min_element() > 0.1 {
            *v = if infinite { f32::INFINITY } else { f32::NAN };
        }
    }
    let origin = [-1.0; 3];
    Volume::new([n; 3], [step as f64; 3], origin, VoxelType::F32, values).unwrap()
}

#[test]
fn missing_voxels_are_transparent_and_no_surface_crosses_their_cells() {
    let near = view(DVec3::new(2.0, 1.5, 2.5), DVec3::ZERO, 3.5);
    let same = Transform::Offset(0.0);
    for iso in [true, false] {
        let params = volume_params(iso, 1.0);
        let sphere = from_volume(sphere_field(24, 1.0, DVec3::ZERO));
        let whole = picture(&sphere, &near, params, SIZE);
        for infinite in [false, true] {
            let volume = field_with_a_hole(infinite);
            assert!(volume.missing() > 0 && volume.values().iter().all(|v| !v.is_infinite()));
            let holed = picture(&from_volume(volume), &near, params, SIZE);
            assert!(holed.rgb.len() == whole.rgb.len());
            let agreed = agreement(&whole, &holed, same);
            // The corner of the sphere towards the eye is cut away, and only it.
            assert!(
                agreed.pixels < 0.99 && agreed.pixels > 0.8,
                "iso {iso}, infinite {infinite}: {agreed:?}"
            );
            if iso {
                // What the hole uncovers is behind it, never in front: no hit comes nearer.
                let nearer = whole.depth.iter().zip(&holed.depth);
                let nearer = nearer.filter(|(w, h)| h.is_finite() && **h < **w - 1e-4);
                assert_eq!(
                    nearer.count(),
                    0,
                    "a surface crossed a cell with missing data"
                );
            }
        }
    }
}

#[test]
fn a_mesh_of_extent_1e_minus_6_or_1e6_renders_the_picture_of_extent_1() {
    let knot = knot_scene(96, 12);
    let near = view(DVec3::new(0.5, 1.0, 9.0), DVec3::new(0.0, 0.0, -2.0), 12.0);
    let params = RenderParams::interactive();
    let plain = picture(&knot, &near, params, SIZE);
    for k in [-6, -3, 3, 6] {
        let t = Transform::Extent(10f64.powi(k));
        let scaled = picture(
            &transformed(&knot, t).unwrap(),
            &near.transformed(t),
            params,
            SIZE,
        );
        assert_agrees(&format!("{t}"), agreement(&plain, &scaled, t), 12.0, 0.995);
    }
}

#[test]
fn every_stiff_case_of_a_particle_and_volume_scene_agrees() {
    let mut scene = from_volume(sphere_field(16, 1.0, DVec3::splat(5.0)));
    let cloud = cloud(300);
    scene.particles = place(&cloud, scene.render_from_world);
    let near = View::of(&scene);
    let params = volume_params(true, 1.0);
    let plain = picture(&scene, &near, params, SIZE);
    for t in crate::stiff::cases(&scene) {
        let seen = picture(
            &transformed(&scene, t).unwrap(),
            &near.transformed(t),
            crate::stiff::transformed_params(params, t),
            SIZE,
        );
        assert_agrees(
            &format!("{t}"),
            agreement(&plain, &seen, t),
            near.size,
            0.99,
        );
    }
}

/// A closed cube of half-size 1 about the origin, as a mesh scene.
fn cube() -> Scene {
    let positions: Vec<Vec3> = (0..8)
        .map(|i| Vec3::new((i & 1) as f32, (i >> 1 & 1) as f32, (i >> 2 & 1) as f32) * 2.0 - 1.0)
        .collect();
    let faces = [
        [0, 2, 6, 4],
        [1, 5, 7, 3],
        [0, 4, 5, 1],
        [2, 3, 7, 6],
        [0, 1, 3, 2],
        [4, 6, 7, 5],
    ];
    let triangles: Vec<[u32; 3]> = faces
        .iter()
        .flat_map(|[a, b, c, d]| [[*a, *b, *c], [*a, *c, *d]])
        .collect();
    Scene {
        triangle_material: vec![0; triangles.len()],
        positions,
        triangles,
        materials: vec![crate::scene::NEUTRAL],
        lights: vec![crate::scene::default_light()],
        ..Scene::default()
    }
}

/// The distance from a point inside the cube of half-size 1 to its wall along `dir`.
fn to_the_wall(from: DVec3, dir: DVec3) -> f64 {
    (0..3)
        .filter(|&a| dir[a] != 0.0)
        .map(|a| (dir[a].signum() - from[a]) / dir[a])
        .fold(f64::INFINITY, f64::min)
}

#[test]
fn an_eye_inside_a_mesh_sees_its_walls_at_their_distance_everywhere() {
    let eye = DVec3::new(0.1, -0.2, 0.3);
    let inside = view(eye, DVec3::new(0.5, 0.0, -1.0), 2.0);
    let seen = picture(&cube(), &inside, RenderParams::interactive(), SIZE);
    let camera =
        tessera_model::camera::Camera::new(eye.as_vec3(), inside.target.as_vec3(), Vec3::Y, 40.0)
            .unwrap();
    let rays = crate::PixelRays::new(&camera, SIZE.0, SIZE.1);
    for y in 0..SIZE.1 {
        for x in 0..SIZE.0 {
            let depth = seen.depth[(y * SIZE.0 + x) as usize] as f64;
            let want = to_the_wall(eye, rays.direction(x, y).as_dvec3());
            assert!(
                (depth - want).abs() < 1e-5,
                "pixel {x},{y}: {depth} for {want}"
            );
        }
    }
    assert!(seen.rgb.chunks(3).all(|p| p.iter().any(|&c| c > 0)));
}

#[test]
fn an_iso_surface_exactly_at_voxel_values_has_no_hole() {
    // f = x on a 9³ grid over -1..1: the iso-value 0 is the value of a whole plane of voxels,
    // so every crossing is through vertices and cell faces.
    let n = 9;
    let step = 2.0 / (n - 1) as f64;
    let values: Vec<f32> = (0..n * n * n)
        .map(|i| (i % n) as f32 * step as f32 - 1.0)
        .collect();
    let volume = Volume::new([n; 3], [step; 3], [-1.0; 3], VoxelType::F32, values).unwrap();
    let params = RenderParamsSpec {
        volume: VolumeParams {
            iso: IsoValues::new(&[0.0]).unwrap(),
            ..VolumeParams::DEFAULT
        },
        ..RenderParamsSpec::INTERACTIVE
    }
    .build()
    .unwrap();
    // Straight at the plane x = 0, from x = -2, close enough that the plane fills the view.
    let eye = DVec3::new(-2.0, 0.05, 0.03);
    let seen = picture(
        &from_volume(volume),
        &view(eye, DVec3::new(0.0, 0.05, 0.03), 3.0),
        params,
        SIZE,
    );
    let camera = tessera_model::camera::Camera::new(
        eye.as_vec3(),
        Vec3::new(0.0, 0.05, 0.03),
        Vec3::Y,
        40.0,
    )
    .unwrap();
    let rays = crate::PixelRays::new(&camera, SIZE.0, SIZE.1);
    for y in 0..SIZE.1 {
        for x in 0..SIZE.0 {
            let dir = rays.direction(x, y).as_dvec3();
            let want = 2.0 / dir.x;
            let depth = seen.depth[(y * SIZE.0 + x) as usize] as f64;
            assert!(
                (depth - want).abs() < 1e-4,
                "pixel {x},{y}: {depth} for {want}"
            );
        }
    }
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(24))]

    /// Any offset up to 10⁷ times the scene's own units on each axis, any units from 10⁻⁶ to
    /// 10⁶ and any value scale from 10⁻³⁰ to 10³⁰, together, leave the picture of a volume with
    /// particles beside it. Offsets are in the scene's units: f64 world coordinates themselves
    /// hold a scene of 10⁻⁵ at 10⁷ to 2·10⁻⁹ only, 5·10⁻⁵ of its size (proptest found it).
    #[test]
    fn any_offset_units_and_value_scale_leave_the_picture(
        offset in proptest::array::uniform3(0.0f64..1e7),
        extent_exponent in -6i32..=6,
        value_exponent in -30i32..=30,
        iso in proptest::bool::ANY,
    ) {
        let mut scene = from_volume(sphere_field(16, 1.0, DVec3::new(2.0, 0.0, 0.0)));
        scene.particles = place(&cloud(200), scene.render_from_world);
        let near = View::of(&scene);
        let params = volume_params(iso, 1.0);
        let plain = picture(&scene, &near, params, SIZE);
        let values = Transform::Values(10f32.powi(value_exponent));
        let scale = Transform::Extent(10f64.powi(extent_exponent));
        let Transform::Extent(s) = scale else { unreachable!() };
        let offset = DVec3::from_array(offset) * s;
        let seen_scene = crate::stiff::moved_and_scaled(&transformed(&scene, values).unwrap(), s, offset);
        let seen_view = View {
            eye: near.eye * s + offset,
            target: near.target * s + offset,
            size: near.size * s,
        };
        let seen_params = crate::stiff::transformed_params(
            crate::stiff::transformed_params(params, values),
            scale,
        );
        let seen = picture(&seen_scene, &seen_view, seen_params, SIZE);
        let agreed = agreement(&plain, &seen, scale);
        proptest::prop_assert!(
            agreed.pixels >= 0.99 && agreed.depth < 1e-4 * near.size && agreed.coverage <= 2,
            "{agreed:?}"
        );
    }
}

/// Pixels of a bright magenta hue (the dark purple viridis starts with is not one).
fn magenta(p: &crate::stiff::Picture) -> usize {
    let is = |c: &[u8]| c[0] > 100 && c[2] > 100 && 4 * (c[1] as u32) < c[0].min(c[2]) as u32;
    p.rgb.chunks(3).filter(|c| is(c)).count()
}

#[test]
fn missing_data_is_drawn_in_the_missing_colour_when_asked() {
    let near = view(DVec3::new(2.0, 1.5, 2.5), DVec3::ZERO, 3.5);
    let plain = volume_params(false, 1.0);
    let mut spec = plain.spec();
    spec.volume.missing_color = Some([1.0, 0.0, 1.0]);
    let asked = spec.build().unwrap();
    let holed = from_volume(field_with_a_hole(false));
    assert_eq!(magenta(&picture(&holed, &near, plain, SIZE)), 0);
    let coloured = magenta(&picture(&holed, &near, asked, SIZE));
    assert!(coloured > 200, "{coloured} pixels show the missing octant");

    let mut cloud = cloud(400);
    for p in cloud.iter_mut().step_by(2) {
        p.attribute = f32::NAN;
    }
    let particles = particle_scene(&cloud);
    let eye = view(DVec3::new(0.0, 0.0, 4.0), DVec3::ZERO, 4.0);
    let grey = magenta(&picture(&particles, &eye, plain, SIZE));
    let coloured = magenta(&picture(&particles, &eye, asked, SIZE));
    assert!(
        coloured > grey + 20,
        "{coloured} pixels, against {grey} without the colour"
    );
}

#[test]
fn a_viewer_almost_in_a_screens_plane_gets_a_finite_picture() {
    use tessera_model::screens::{PhysicalSpec, ScreenSpec, Viewer};
    use tessera_model::wall::{TileGrid, WallDescription, WallLayout};
    let prepared = crate::PreparedScene::new(&knot_scene(64, 8));
    let camera =
        tessera_model::camera::Camera::new(Vec3::new(0.5, 1.0, 9.0), Vec3::ZERO, Vec3::Y, 40.0)
            .unwrap();
    // A screen to the right of the viewer, who is 1 µm to 1 pm in front of its plane: every
    // ray grazes it.
    for z_mm in [1e-3, 1e-6, 1e-9] {
        let screen = ScreenSpec {
            resolution: [64, 48],
            x_mm: Some(500.0),
            y_mm: Some(0.0),
            width_mm: Some(1000.0),
            height_mm: Some(750.0),
            ..ScreenSpec::default()
        };
        let spec = PhysicalSpec {
            tile_size: 16,
            viewer: Viewer {
                position_mm: [0.0, 0.0, z_mm],
                scene_units_per_m: 1.0,
            },
            stereo: Default::default(),
            screens: vec![screen],
            ring: None,
        };
        let wall = WallLayout::new(WallDescription::Screens(spec)).unwrap();
        let view = crate::FrameView::for_wall(0, &camera, RenderParams::interactive(), &wall);
        let grid = TileGrid::new(wall);
        let linear = crate::render_wall_linear(&prepared, &view, &grid);
        assert!(
            linear
                .iter()
                .all(|c| c.is_finite() && c.min_element() >= 0.0),
            "viewer {z_mm} mm before the plane"
        );
        let depth = crate::aov::primary_aovs(&prepared, &view, &grid).depth;
        assert!(
            depth.iter().all(|d| !d.is_nan()),
            "viewer {z_mm} mm before the plane"
        );
    }
}
