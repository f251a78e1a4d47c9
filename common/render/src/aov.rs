//! Arbitrary output values of primary rays: distance and primitive index per pixel, traced with
//! the same packets as the colour image so they describe exactly what is shown.

use crate::packet::{PacketHit, RayPacket, PACKET_RAYS};
use crate::{nearest_surface, FrameView, PreparedScene, PACKET};
use rayon::prelude::*;
use tessera_model::wall::{Tile, TileGrid};

/// Per-pixel AOVs of the whole virtual image, row-major, row 0 at the top.
pub struct Aovs {
    /// Width of the virtual image, in pixels.
    pub width: u32,
    /// Height of the virtual image, in pixels.
    pub height: u32,
    /// Distance from the eye along the normalized ray; +inf where nothing is hit (and behind
    /// bezels, where nothing is rendered).
    pub depth: Vec<f32>,
    /// Index of the scene triangle hit, as float; -1 for none.
    pub prim: Vec<f32>,
}

/// The AOVs of every tile of `grid`, from the same primary packets (cutting planes included)
/// as the colour image.
///
/// # Panics
/// On a scene slimmed for rendering ([`PreparedScene::slim_for_rendering`]), which has no
/// scene index to name primitives by.
pub fn primary_aovs(scene: &PreparedScene, view: &FrameView, grid: &TileGrid) -> Aovs {
    let layout = grid.layout();
    let (width, height) = (layout.width(), layout.height());
    let blocks: Vec<(u32, u32, u32, u32, &Tile)> = grid
        .tiles()
        .iter()
        .flat_map(|t| {
            (0..t.height.div_ceil(PACKET)).flat_map(move |py| {
                (0..t.width.div_ceil(PACKET)).map(move |px| {
                    (
                        t.x + px * PACKET,
                        t.y + py * PACKET,
                        PACKET.min(t.width - px * PACKET),
                        PACKET.min(t.height - py * PACKET),
                        t,
                    )
                })
            })
        })
        .collect();
    let traced: Vec<(RayPacket, [PacketHit; PACKET_RAYS])> = blocks
        .par_iter()
        .map_init(
            || scene.tracer(),
            |tracer, &(x, y, w, h, tile)| {
                let mut packet = RayPacket::primary(view.rays_for(tile), x, y, w, h);
                packet.clip(view.params.cuts());
                let mut hits = [PacketHit::MISS; PACKET_RAYS];
                tracer.closest_hits(&mut packet, &mut hits);
                (packet, hits)
            },
        )
        .collect();
    let mut aovs = Aovs {
        width,
        height,
        depth: vec![f32::INFINITY; (width * height) as usize],
        prim: vec![-1.0; (width * height) as usize],
    };
    let mut tracer = scene.tracer();
    for (&(x, y, w, h, _), (packet, hits)) in blocks.iter().zip(&traced) {
        for i in 0..(w * h) as usize {
            let at = ((y + i as u32 / w) * width + x + i as u32 % w) as usize;
            let ray = (packet.origin, packet.direction(i));
            let interval = (packet.t_min[i], packet.t_max[i]);
            if let Some(hit) = nearest_surface(scene, view, ray, interval, hits[i], &mut tracer) {
                aovs.depth[at] = hit.t();
                aovs.prim[at] = hit.scene_primitive(scene) as f32;
            }
        }
    }
    aovs
}

/// Writes one float channel as a little-endian grey PFM (rows stored bottom to top, as PFM
/// requires).
pub fn write_pfm(
    path: &std::path::Path,
    width: u32,
    height: u32,
    values: &[f32],
) -> std::io::Result<()> {
    use std::io::Write;
    let mut out = std::io::BufWriter::new(std::fs::File::create(path)?);
    write!(out, "Pf\n{width} {height}\n-1.0\n")?;
    for row in (0..height as usize).rev() {
        for v in &values[row * width as usize..(row + 1) * width as usize] {
            out.write_all(&v.to_le_bytes())?;
        }
    }
    out.flush()
}

/// Writes linear RGB as a little-endian colour PFM (rows bottom to top).
pub fn write_pfm_rgb(
    path: &std::path::Path,
    width: u32,
    height: u32,
    colors: &[glam::Vec3],
) -> std::io::Result<()> {
    use std::io::Write;
    let mut out = std::io::BufWriter::new(std::fs::File::create(path)?);
    write!(out, "PF\n{width} {height}\n-1.0\n")?;
    for row in (0..height as usize).rev() {
        for c in &colors[row * width as usize..(row + 1) * width as usize] {
            for v in c.to_array() {
                out.write_all(&v.to_le_bytes())?;
            }
        }
    }
    out.flush()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{Material, Scene};
    use tessera_model::camera::Camera;
    use tessera_model::params::RenderParams;
    use tessera_model::wall::WallSpec;

    use glam::Vec3;

    #[test]
    fn depth_and_prim_of_a_known_quad() {
        // A quad at z = 0 facing a camera at z = 5: the centre pixel is at distance 5.
        let scene = Scene {
            positions: vec![
                Vec3::new(-1.0, -1.0, 0.0),
                Vec3::new(1.0, -1.0, 0.0),
                Vec3::new(1.0, 1.0, 0.0),
                Vec3::new(-1.0, 1.0, 0.0),
            ],
            triangles: vec![[0, 1, 2], [0, 2, 3]],
            triangle_material: vec![0, 0],
            materials: vec![Material::lambert(Vec3::ONE)],
            ..Scene::default()
        };
        let prepared = PreparedScene::new(&scene);
        let wall = WallSpec::grid(1, 1, 33, 33).tile_size(16).build().unwrap();
        let camera = Camera::new(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, Vec3::Y, 60.0).unwrap();
        let view = FrameView::new(0, &camera, RenderParams::interactive(), 33, 33);
        let aovs = primary_aovs(&prepared, &view, &TileGrid::new(wall.clone()));
        let centre = (16 * 33 + 16) as usize;
        assert!(
            (aovs.depth[centre] - 5.0).abs() < 1e-5,
            "{}",
            aovs.depth[centre]
        );
        assert!(aovs.prim[centre] == 0.0 || aovs.prim[centre] == 1.0);
        // The corner pixel looks past the quad.
        assert_eq!(aovs.depth[0], f32::INFINITY);
        assert_eq!(aovs.prim[0], -1.0);
        // Distance along a normalized ray: an off-centre pixel on the quad is farther than 5.
        let off = (16 * 33 + 19) as usize;
        assert!(aovs.depth[off] > 5.0 && aovs.depth[off].is_finite());
    }
}
