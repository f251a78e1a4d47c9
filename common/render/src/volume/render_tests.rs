//! Volume rendering against what it must equal: a finer step, a march that skips nothing, a
//! sphere's known radius, a triangulated iso-surface, and the extreme cases of issue 11.

use super::prepared::PreparedVolume;
use super::{Replicated, Volume, VoxelType};
use crate::aov::primary_aovs;
use crate::scene::{Scene, NEUTRAL};
use crate::shade::background;
use crate::{orbit_of, render_tiles, FrameView, PreparedScene};
use glam::Vec3;
use tessera_model::camera::Camera;
use tessera_model::local_origin::RenderFromWorld;
use tessera_model::params::{RenderParams, RenderParamsSpec};
use tessera_model::volume_params::{
    IsoValues, TransferDomain, TransferFunction, TransferPoint, VolumeParams,
};
use tessera_model::wall::{TileGrid, WallLayout};

/// `n`³ samples of `f` over -1..1 on each axis (spacing 2 / (n - 1)).
pub(crate) fn field(n: usize, f: impl Fn(Vec3) -> f32) -> Volume {
    let step = 2.0 / (n - 1) as f64;
    let mut values = Vec::with_capacity(n * n * n);
    for z in 0..n {
        for y in 0..n {
            for x in 0..n {
                let p = Vec3::new(x as f32, y as f32, z as f32) * step as f32 - Vec3::ONE;
                values.push(f(p));
            }
        }
    }
    Volume::new([n; 3], [step; 3], [-1.0; 3], VoxelType::F32, values).unwrap()
}

fn blobs(p: Vec3) -> f32 {
    let g = |c: Vec3, s: f32| (-(p - c).length_squared() / (s * s)).exp();
    (g(Vec3::new(-0.3, -0.2, 0.0), 0.35) + g(Vec3::new(0.35, 0.1, 0.1), 0.3)).min(1.0)
}

/// The linear colour of each of `w × h` rays from `eye` towards the volume's middle: the
/// volume composited over the backdrop, as a pixel of a volume scene is.
fn image(
    volume: &PreparedVolume,
    params: &VolumeParams,
    eye: Vec3,
    (w, h): (u32, u32),
) -> Vec<Vec3> {
    let tables = volume.tables(params);
    let forward = (-eye).normalize();
    let right = forward.cross(Vec3::Y).normalize();
    let up = right.cross(forward);
    let mut out = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let sx = (x as f32 + 0.5) / w as f32 * 2.0 - 1.0;
            let sy = (y as f32 + 0.5) / h as f32 * 2.0 - 1.0;
            let dir = (forward + right * sx * 0.5 + up * sy * 0.5).normalize();
            let behind = background(dir);
            let [r, g, b, a] =
                volume.composite(&tables, (eye, dir), (0.0, f32::INFINITY), &mut Replicated);
            out.push(Vec3::new(r, g, b) + behind * (1.0 - a));
        }
    }
    out
}

fn rmse(a: &[Vec3], b: &[Vec3]) -> f32 {
    let sum: f32 = a
        .iter()
        .zip(b)
        .map(|(x, y)| (*x - *y).length_squared())
        .sum();
    (sum / (3 * a.len()) as f32).sqrt()
}

#[test]
fn a_sixteenth_of_the_step_changes_the_image_by_under_1e_3_rmse() {
    let volume = PreparedVolume::new(&field(48, blobs), &RenderFromWorld::IDENTITY);
    let s = volume.reference_step() * 0.5;
    let coarse = VolumeParams {
        step: s,
        ..VolumeParams::DEFAULT
    };
    let fine = VolumeParams {
        step: s / 16.0,
        ..coarse
    };
    let eye = Vec3::new(0.4, 0.5, 3.0);
    let (a, b) = (
        image(&volume, &coarse, eye, (48, 36)),
        image(&volume, &fine, eye, (48, 36)),
    );
    let error = rmse(&a, &b);
    // Without opacity correction the finer step would be 16 times as opaque.
    let uncorrected = {
        let table = super::transfer::TransferTable::new(&coarse.transfer, (0.0, 1.0), 1.0);
        table.lookup(0.8)[3]
    };
    assert!(uncorrected > 0.0);
    eprintln!("step {s} against {}: linear RMSE {error:.2e}", s / 16.0);
    assert!(error <= 1e-3, "RMSE {error}");
    let visible = a
        .iter()
        .zip(&b)
        .filter(|(x, _)| (**x - background(Vec3::Z)).length() > 0.05);
    assert!(visible.count() > 100, "the volume is in the picture");
}

#[test]
fn skipping_empty_space_changes_no_sample() {
    // A transfer function that hides everything below 0.3: most macro-cells are skipped, many
    // leapt over, and most samples in the rest fall in cells the cell mask rejects.
    let p = |value, opacity| TransferPoint {
        value,
        color: [1.0, 0.7, 0.4],
        opacity,
    };
    let transfer =
        TransferFunction::new(TransferDomain::Data, &[p(0.3, 0.0), p(1.0, 0.6)]).unwrap();
    let params = VolumeParams {
        transfer,
        ..VolumeParams::DEFAULT
    };
    let volume = PreparedVolume::new(&field(64, blobs), &RenderFromWorld::IDENTITY);
    let tables = volume.tables(&params);
    for k in 0..200 {
        let a = k as f32 * 0.031;
        let eye = Vec3::new(3.0 * a.cos(), 0.3 * (k as f32 * 0.1).sin(), 3.0 * a.sin());
        let dir = (Vec3::new(0.1, -0.05, 0.02) * (k % 7) as f32 - eye).normalize();
        let skipped = volume.composite(&tables, (eye, dir), (0.0, 100.0), &mut Replicated);
        let every = volume.composite_every_sample(&tables, eye, dir, (0.0, 100.0));
        assert_eq!(skipped, every, "ray {k}");
    }
}

#[test]
fn extreme_transfer_functions_and_volumes_stay_finite_and_exact() {
    let volume = PreparedVolume::new(&field(9, blobs), &RenderFromWorld::IDENTITY);
    let eye = Vec3::new(0.0, 0.2, 3.0);
    let constant = |opacity| {
        let p = |value| TransferPoint {
            value,
            color: [0.2, 0.4, 0.8],
            opacity,
        };
        VolumeParams {
            transfer: TransferFunction::new(TransferDomain::Normalized, &[p(0.0), p(1.0)]).unwrap(),
            ..VolumeParams::DEFAULT
        }
    };
    // Transparent everywhere: exactly the backdrop. Opaque everywhere: exactly the colour
    // wherever a ray enters.
    let clear = image(&volume, &constant(0.0), eye, (16, 12));
    let opaque = image(&volume, &constant(1.0), eye, (16, 12));
    let mut entered = 0;
    for (i, (c, o)) in clear.iter().zip(&opaque).enumerate() {
        let (x, y) = (i % 16, i / 16);
        let sx = (x as f32 + 0.5) / 16.0 * 2.0 - 1.0;
        let sy = (y as f32 + 0.5) / 12.0 * 2.0 - 1.0;
        let forward = (-eye).normalize();
        let right = forward.cross(Vec3::Y).normalize();
        let dir = (forward + right * sx * 0.5 + right.cross(forward) * sy * 0.5).normalize();
        assert_eq!(*c, background(dir));
        if *o != background(dir) {
            assert!(
                (*o - Vec3::new(0.2, 0.4, 0.8)).abs().max_element() < 1e-6,
                "{o}"
            );
            entered += 1;
        }
    }
    assert!(entered > 50);
    // Opacity a hair above 0 and a hair below 1.
    for opacity in [1e-7, 1.0 - 1e-7] {
        for c in image(&volume, &constant(opacity), eye, (16, 12)) {
            assert!(
                c.is_finite() && c.min_element() >= 0.0 && c.max_element() <= 1.0,
                "{c}"
            );
        }
    }
}

#[test]
fn a_one_voxel_volume_is_a_cube_and_a_camera_inside_sees_around_it() {
    let one = Volume::new([1, 1, 1], [2.0; 3], [0.0; 3], VoxelType::U8, vec![7.0]).unwrap();
    let volume = PreparedVolume::new(&one, &RenderFromWorld::IDENTITY);
    let params = VolumeParams::DEFAULT;
    let tables = volume.tables(&params);
    // The cube spans -1..1: a ray through it is tinted, one beside it is not.
    let through = volume.composite(
        &tables,
        (Vec3::new(0.0, 0.0, -5.0), Vec3::Z),
        (0.0, 10.0),
        &mut Replicated,
    );
    let beside = volume.composite(
        &tables,
        (Vec3::new(1.5, 0.0, -5.0), Vec3::Z),
        (0.0, 10.0),
        &mut Replicated,
    );
    assert!(
        through[3] > 0.0 && through.iter().all(|c| c.is_finite()),
        "{through:?}"
    );
    assert_eq!(beside, [0.0; 4]);
    assert_eq!(volume.value_at(Vec3::new(0.9, -0.9, 0.5)), Some(7.0));
    // From inside, every direction sees the same stretch of volume up to the faces.
    let inside = PreparedVolume::new(&field(17, blobs), &RenderFromWorld::IDENTITY);
    let img = image(&inside, &params, Vec3::new(0.05, 0.0, 0.1), (12, 12));
    assert!(img.iter().all(|c| c.is_finite()));
    assert!(img
        .iter()
        .any(|c| (*c - background(Vec3::Z)).length() > 0.01));
}

#[test]
fn rays_along_cell_faces_see_what_their_neighbours_see() {
    // A field that varies along x only: rays along x on a face and just beside it agree.
    let v = field(9, |p| 0.5 + 0.5 * p.x);
    let volume = PreparedVolume::new(&v, &RenderFromWorld::IDENTITY);
    let tables = volume.tables(&VolumeParams::DEFAULT);
    let face = 0.25; // Spacing 0.25: y = 0.25 is a face between two rows of cells.
    for dir in [Vec3::X, Vec3::Y, Vec3::Z] {
        let start = Vec3::new(face, face, face) - dir * 3.0;
        let on = volume.composite(&tables, (start, dir), (0.0, 10.0), &mut Replicated);
        let off = volume.composite(
            &tables,
            (start + Vec3::splat(1e-4), dir),
            (0.0, 10.0),
            &mut Replicated,
        );
        for c in 0..4 {
            assert!(
                on[c].is_finite() && (on[c] - off[c]).abs() < 1e-3,
                "{dir}: {on:?} vs {off:?}"
            );
        }
        assert!(on[3] > 0.0);
        let iso = volume.iso_hit(&[0.6], (start, dir), (0.0, 10.0), &mut Replicated);
        if dir == Vec3::X {
            // 0.5 + 0.5 x = 0.6 at x = 0.2: 3.2 - 0.25 along the ray from x = -2.75.
            assert!((iso.unwrap().0 - 2.95).abs() < 1e-4, "{iso:?}");
        } else {
            assert_eq!(
                iso, None,
                "{dir}: a ray at x = 0.25 runs where the value is 0.625"
            );
        }
    }
}

#[test]
fn the_iso_surface_of_a_distance_field_is_its_sphere() {
    let volume = PreparedVolume::new(&field(33, |p| p.length()), &RenderFromWorld::IDENTITY);
    for k in 0..100 {
        let a = k as f32 * 0.37;
        let eye = Vec3::new(3.0 * a.cos(), (k as f32 * 0.05).sin(), 3.0 * a.sin());
        let dir = -eye.normalize();
        let (t, surface) = volume
            .iso_hit(&[0.9, 0.5], (eye, dir), (0.0, 10.0), &mut Replicated)
            .unwrap();
        // The nearer surface (0.9) is found first; trilinear interpolation of |p| is within a
        // hundredth of a spacing (1/16) of the sphere.
        assert_eq!(surface, 0);
        assert!((t - (eye.length() - 0.9)).abs() < 0.01, "ray {k}: t = {t}");
        let normal = volume.normal_at(eye + dir * t, Vec3::X, &mut Replicated);
        assert!(normal.dot(-dir) > 0.99, "ray {k}: normal {normal}");
    }
}

#[test]
fn a_thin_crossing_inside_one_cell_is_found() {
    // Along the cell's diagonal the field is 3s(1 - s): 0 where the ray enters and leaves,
    // 0.75 in the middle. Testing the ends (or a step of half the cell) misses an iso of 0.7.
    let corners = vec![0.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 0.0];
    let v = Volume::new([2, 2, 2], [1.0; 3], [0.0; 3], VoxelType::F32, corners).unwrap();
    let volume = PreparedVolume::new(&v, &RenderFromWorld::IDENTITY);
    let origin = Vec3::splat(-1.0);
    let dir = Vec3::ONE.normalize();
    let (t, _) = volume
        .iso_hit(&[0.7], (origin, dir), (0.0, 10.0), &mut Replicated)
        .expect("thin crossing");
    let s = (1.0 - (1.0f32 - 4.0 * 0.7 / 3.0).sqrt()) / 2.0;
    assert!((t - 3f32.sqrt() * (1.0 + s)).abs() < 1e-5, "t {t}");
    assert_eq!(
        volume.iso_hit(&[0.76], (origin, dir), (0.0, 10.0), &mut Replicated),
        None
    );
}

/// Triangles of the iso-surface of `volume` at `iso`, by marching tetrahedra (six per cell,
/// around the cell's main diagonal), in world coordinates.
fn triangulate(volume: &Volume, iso: f32) -> (Vec<glam::DVec3>, Vec<[u32; 3]>) {
    const TETS: [[usize; 4]; 6] = [
        [0, 1, 3, 7],
        [0, 3, 2, 7],
        [0, 2, 6, 7],
        [0, 6, 4, 7],
        [0, 4, 5, 7],
        [0, 5, 1, 7],
    ];
    let d = volume.dims();
    let (mut positions, mut triangles) = (Vec::new(), Vec::new());
    for z in 0..d[2] - 1 {
        for y in 0..d[1] - 1 {
            for x in 0..d[0] - 1 {
                let corner = |c: usize| [x + (c & 1), y + (c >> 1 & 1), z + (c >> 2 & 1)];
                for tet in TETS {
                    let p: Vec<[usize; 3]> = tet.iter().map(|&c| corner(c)).collect();
                    let v: Vec<f32> = p.iter().map(|&i| volume.at(i)).collect();
                    let inside: Vec<usize> = (0..4).filter(|&i| v[i] < iso).collect();
                    let outside: Vec<usize> = (0..4).filter(|&i| v[i] >= iso).collect();
                    let cut = |i: usize, j: usize| {
                        let f = ((iso - v[i]) / (v[j] - v[i])) as f64;
                        let at = |k: usize| glam::DVec3::from_array(p[k].map(|c| c as f64));
                        let idx = at(i) + (at(j) - at(i)) * f;
                        glam::DVec3::from_array(volume.world_of_index(idx.to_array()))
                    };
                    let mut emit = |a, b, c| {
                        let n = positions.len() as u32;
                        positions.extend([a, b, c]);
                        triangles.push([n, n + 1, n + 2]);
                    };
                    match (inside.len(), outside.len()) {
                        (1, 3) | (3, 1) => {
                            let (one, three) = if inside.len() == 1 {
                                (inside[0], &outside)
                            } else {
                                (outside[0], &inside)
                            };
                            emit(cut(one, three[0]), cut(one, three[1]), cut(one, three[2]));
                        }
                        (2, 2) => {
                            let (a, b, c, e) = (inside[0], inside[1], outside[0], outside[1]);
                            emit(cut(a, c), cut(a, e), cut(b, e));
                            emit(cut(a, c), cut(b, e), cut(b, c));
                        }
                        _ => {}
                    }
                }
            }
        }
    }
    (positions, triangles)
}

#[test]
fn the_direct_iso_surface_agrees_with_a_triangulated_one_within_a_voxel() {
    let volume = field(40, blobs);
    let spacing = volume.spacing()[0] as f32;
    let iso = 0.2;
    let (positions, triangles) = triangulate(&volume, iso);
    let frame = RenderFromWorld::IDENTITY;
    let mesh = Scene {
        positions: positions.iter().map(|&p| frame.point(p)).collect(),
        triangle_material: vec![0; triangles.len()],
        triangles,
        materials: vec![NEUTRAL],
        ..Scene::default()
    };
    let direct = Scene {
        volume: Some(volume),
        ..Scene::default()
    };
    let wall = WallLayout::grid(1, 1, 96, 72).unwrap();
    let grid = TileGrid::new(wall.clone());
    let camera = Camera::new(Vec3::new(0.5, 0.6, 2.0), Vec3::ZERO, Vec3::Y, 50.0).unwrap();
    let params = RenderParamsSpec {
        volume: VolumeParams {
            iso: IsoValues::new(&[iso]).unwrap(),
            ..VolumeParams::DEFAULT
        },
        ..RenderParamsSpec::INTERACTIVE
    }
    .build()
    .unwrap();
    let view = FrameView::new(0, &camera, params, 96, 72);
    let by_mesh = primary_aovs(&PreparedScene::new(&mesh), &view, &grid);
    let by_volume = primary_aovs(&PreparedScene::new(&direct), &view, &grid);
    let both: Vec<(f32, f32)> = by_mesh
        .depth
        .iter()
        .zip(&by_volume.depth)
        .filter(|(a, b)| a.is_finite() && b.is_finite())
        .map(|(a, b)| (*a, *b))
        .collect();
    let hits = |d: &[f32]| d.iter().filter(|x| x.is_finite()).count();
    assert!(
        both.len() > 1000,
        "{} pixels hit by both, {} by the mesh, {} by the volume",
        both.len(),
        hits(&by_mesh.depth),
        hits(&by_volume.depth)
    );
    let within = both
        .iter()
        .filter(|(a, b)| (a - b).abs() <= spacing)
        .count();
    eprintln!(
        "{within} of {} pixels ({:.2} %) within one voxel ({spacing})",
        both.len(),
        100.0 * within as f64 / both.len() as f64
    );
    assert!(
        within as f64 >= 0.99 * both.len() as f64,
        "{within} of {}",
        both.len()
    );
    // Neither sees the surface where the other sees none, beyond the silhouette's pixels.
    let only_one = by_mesh
        .depth
        .iter()
        .zip(&by_volume.depth)
        .filter(|(a, b)| a.is_finite() != b.is_finite())
        .count();
    assert!(
        only_one * 50 < both.len(),
        "{only_one} pixels differ in coverage"
    );
}

#[test]
fn a_volume_scene_renders_and_a_mesh_inside_it_hides_what_is_behind() {
    let mut scene = Scene {
        volume: Some(field(24, blobs)),
        ..Scene::default()
    };
    let bounds = scene.bounds();
    assert!(
        (bounds.min - Vec3::splat(-1.0)).length() < 1e-6,
        "{bounds:?}"
    );
    let camera = orbit_of(&bounds, 45.0).unwrap().camera_for_frame(0);
    let wall = WallLayout::grid(1, 1, 48, 32).unwrap();
    let grid = TileGrid::new(wall.clone());
    let view = FrameView::new(0, &camera, RenderParams::interactive(), 48, 32);
    let (volume_only, _) = render_tiles(&PreparedScene::new(&scene), &view, grid.tiles());
    // An opaque quad in the middle of the volume, facing the camera.
    let c = camera.eye().normalize();
    let (u, v) = (c.cross(Vec3::Y).normalize() * 0.5, Vec3::Y * 0.5);
    scene.positions = vec![-u - v, u - v, u + v, -u + v];
    scene.triangles = vec![[0, 1, 2], [0, 2, 3]];
    scene.triangle_material = vec![0, 0];
    scene.materials = vec![NEUTRAL];
    let (with_quad, _) = render_tiles(&PreparedScene::new(&scene), &view, grid.tiles());
    let differs = volume_only[0]
        .chunks(3)
        .zip(with_quad[0].chunks(3))
        .filter(|(a, b)| a != b)
        .count();
    assert!(
        differs > 50,
        "the quad shows through the volume in front of it"
    );
    assert!(
        volume_only[0]
            .chunks(3)
            .collect::<std::collections::HashSet<_>>()
            .len()
            > 20
    );
}

#[test]
fn the_probe_finds_the_iso_surface_or_where_the_volume_turns_opaque() {
    let volume = PreparedVolume::new(&field(33, |p| p.length()), &RenderFromWorld::IDENTITY);
    let eye = Vec3::new(0.0, 0.0, 3.0);
    let iso = VolumeParams {
        iso: IsoValues::new(&[0.5]).unwrap(),
        ..VolumeParams::DEFAULT
    };
    let (t, value) = volume.probe(&iso, eye, -Vec3::Z, (0.0, 10.0)).unwrap();
    assert!(
        (t - 2.5).abs() < 0.01 && (value - 0.5).abs() < 1e-3,
        "{t} {value}"
    );
    // Opaque below 0.3 (the middle of the sphere), clear above: half opacity inside |p| < 0.3.
    let p = |value, opacity| TransferPoint {
        value,
        color: [1.0; 3],
        opacity,
    };
    let transfer = TransferFunction::new(
        TransferDomain::Data,
        &[p(0.0, 1.0), p(0.3, 1.0), p(0.31, 0.0)],
    )
    .unwrap();
    let dvr = VolumeParams {
        transfer,
        ..VolumeParams::DEFAULT
    };
    let (t, value) = volume.probe(&dvr, eye, -Vec3::Z, (0.0, 10.0)).unwrap();
    assert!(value <= 0.31 && (t - 2.7).abs() < 0.05, "{t} {value}");
    assert_eq!(
        volume.probe(&dvr, Vec3::new(5.0, 0.0, 3.0), -Vec3::Z, (0.0, 10.0)),
        None
    );
}
