//! A scene prepared for distributed shared memory, on disk: its tree reordered and cut into
//! blocks ([`super::reorder`]), its triangles in leaf order, each block checksummed, and what
//! every node needs whole (materials, lights, the tree's depth) in a manifest.
//!
//! A folder holds `blocks.bin` (block k at byte k × block size), `checksums.bin` (the first 8
//! bytes of each block's BLAKE3 hash, little-endian), for a volume `volume.bin`
//! ([`super::volume`]), and `manifest.json`, written last, so a folder without one was never
//! finished. It is reused while the manifest names the same
//! scene content hash, format and block size.

use super::layout::{item_blocks, Block, BlockLayout, Chunk, LayoutError};
use super::particles::{sphere_blocks, ParticleEntry};
use super::reorder::reorder_for_blocks;
use super::volume::{
    brick_blocks, encode, largest_brick_bytes, series_blocks, series_steps, volume_path,
    VolumeEntry,
};
use crate::bvh::node::LeafTriangle;
use crate::bvh::Accel;
use crate::scene::{Light, Material, Scene};
use crate::slot_materials::SlotMaterials;
use crate::spheres::SphereAccel;
use crate::volume::{PreparedVolume, SharedVolume};
use serde::{Deserialize, Serialize};
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use tessera_core::dsm::{BlockId, Residency};
use tessera_model::local_origin::RenderFromWorld;

/// Bumped whenever the block contents or the files change.
pub const FORMAT: u32 = 3;

/// Blocks at the top of the tree that every node holds: 8 KB, the root and its first levels
/// (Ize et al. replicate the same, since every ray starts there).
pub const TOP_BLOCKS: u32 = 1;

/// What every render node of a shared scene holds whole, and where the blocks are.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    /// The format the folder was written in: [`FORMAT`] when it was prepared by this build.
    pub format: u32,
    /// The scene's content hash (hex), as [`Scene::content_hash`] gives it.
    pub scene_hash: String,
    /// Block size and how many blocks hold the tree's nodes and the leaf triangles.
    pub layout: BlockLayout,
    /// Depth of the binary tree the 8-wide one was collapsed from (sizes traversal stacks).
    pub max_depth: u32,
    /// Lower corner of the scene's bounding box, in render coordinates.
    pub bounds_min: [f32; 3],
    /// Upper corner of the scene's bounding box, in render coordinates.
    pub bounds_max: [f32; 3],
    /// Length of the bounding box's diagonal: the scale of ray offsets and AO reach.
    pub diagonal: f32,
    /// Where the render coordinates sit in the world, as [`Scene::render_from_world`].
    pub render_from_world: RenderFromWorld,
    /// The scene's materials, which `slot_materials` indexes.
    pub materials: Vec<Material>,
    /// The scene's lights, in render coordinates.
    pub lights: Vec<Light>,
    /// The material of each leaf slot, as runs (the render nodes hold no per-triangle array).
    pub slot_materials: SlotMaterials,
    /// Whether any material is transparent, as [`Scene::has_transparency`].
    pub blends: bool,
    /// The scene's volume, if it has one: its bricks are the layout's brick blocks, and what
    /// every node holds whole of it is in `volume.bin`.
    #[serde(default)]
    pub volume: Option<VolumeEntry>,
    /// Steps of the volume when it is a time series (0 when it is not): `volume.bin` holds
    /// each, their bricks one step after the other.
    #[serde(default)]
    pub series_steps: u32,
    /// The scene's particles, if it has any: their tree and themselves are the layout's
    /// sphere blocks.
    #[serde(default)]
    pub particles: Option<ParticleEntry>,
}

/// Why a scene could not be prepared, or a prepared one not read.
#[derive(Debug, thiserror::Error)]
pub enum PrepareError {
    /// A step of a volume series could not be loaded.
    #[error("{path}: {reason}")]
    Step {
        /// The step's file.
        path: PathBuf,
        /// Why, in words.
        reason: String,
    },
    /// The block size is out of range, or the scene needs too many blocks.
    #[error(transparent)]
    Layout(#[from] LayoutError),
    /// A file of the prepared folder could not be created, written, opened or read.
    // `reason`, not `source`: an error chain would print a source a second time.
    #[error("{path}: {reason}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The operating system's error.
        reason: std::io::Error,
    },
    /// The manifest does not parse, is of another format or describes what cannot exist, or the
    /// block files are not as long as it says.
    #[error("{path}: not a manifest of a prepared scene: {reason}")]
    BadManifest {
        /// The manifest file.
        path: PathBuf,
        /// What is wrong, in words.
        reason: String,
    },
    /// The folder was prepared for another scene content or another block size.
    #[error("{path} is for scene {found}, not {expected}: prepare the scene again")]
    OtherScene {
        /// The manifest file.
        path: PathBuf,
        /// The manifest's scene hash and block size.
        found: String,
        /// The scene hash and block size asked for.
        expected: String,
    },
    /// A block read from the file does not match its checksum.
    #[error("block {block} of {path} does not match its checksum: the file is damaged; prepare the scene again")]
    Damaged {
        /// The blocks file.
        path: PathBuf,
        /// Which block.
        block: BlockId,
    },
}

fn io(path: &Path) -> impl Fn(std::io::Error) -> PrepareError + '_ {
    move |reason| PrepareError::Io {
        path: path.to_path_buf(),
        reason,
    }
}

/// The scene's content hash as the manifest writes it.
pub fn hash_hex(hash: &[u8; 32]) -> String {
    hash.iter().map(|b| format!("{b:02x}")).collect()
}

/// A block's checksum: the first 8 bytes of its BLAKE3 hash.
pub fn checksum(bytes: &[u8]) -> u64 {
    let hash = blake3::hash(bytes);
    u64::from_le_bytes(hash.as_bytes()[..8].try_into().expect("8 bytes"))
}

/// The blocks of a prepared scene, in order, each of them or why it could not be made.
pub type Blocks<'a> = Box<dyn Iterator<Item = Result<Block, PrepareError>> + 'a>;

/// The scene's blocks, in order, its manifest and what every node holds whole of its volume
/// (a step each for a series, none without a volume): what [`prepare`] writes, in memory. A
/// series' steps are loaded one at a time, once for the manifest and again as its blocks are
/// taken.
///
/// # Errors
/// A block size out of range, or smaller than a volume's bricks; a series step that cannot
/// be loaded (also as a block's error).
pub fn blocks_of<'a>(
    scene: &Scene,
    accel: &'a Accel,
    block_bytes: u32,
) -> Result<(Manifest, Vec<SharedVolume>, Blocks<'a>), PrepareError> {
    let ((steps, bricks, largest), volume_blocks) = volume_blocks(scene, block_bytes)?;
    let spheres = SphereAccel::build(&scene.particles);
    let (sphere_nodes, sphere_count) = spheres
        .as_ref()
        .map_or((0, 0), |s| (s.nodes().len() as u32, s.len() as u32));
    let layout = BlockLayout::new(
        block_bytes,
        accel.wide.len() as u32,
        accel.triangles.len() as u32,
        TOP_BLOCKS,
    )?
    .with_bricks(bricks, largest)?
    .with_spheres(sphere_nodes, sphere_count)?;
    let wide = reorder_for_blocks(&accel.wide, layout.nodes_per_block() as usize);
    let manifest = manifest_of(scene, accel, layout, &steps);
    let node_blocks = item_blocks(wide, layout.nodes_per_block(), block_bytes);
    let triangles: &[LeafTriangle] = &accel.triangles;
    let tri_blocks = item_blocks(triangles, layout.triangles_per_block(), block_bytes);
    let particles = spheres
        .into_iter()
        .flat_map(move |s| sphere_blocks(s, layout));
    let blocks = node_blocks
        .chain(tri_blocks)
        .map(Ok)
        .chain(volume_blocks)
        .chain(particles.map(Ok));
    Ok((manifest, steps, Box::new(blocks)))
}

/// What a node holds whole of `scene`'s volume (a step each for a series), its bricks in all
/// and the largest brick's bytes, and its brick blocks.
type VolumeBlocks = ((Vec<SharedVolume>, u32, u32), Blocks<'static>);

fn volume_blocks(scene: &Scene, block_bytes: u32) -> Result<VolumeBlocks, PrepareError> {
    let frame = scene.render_from_world;
    if !scene.series.is_empty() {
        let steps = series_steps(&scene.series, &frame)?;
        let blocks = series_blocks(scene.series.clone(), frame, block_bytes);
        return Ok((steps, Box::new(blocks)));
    }
    let Some(volume) = &scene.volume else {
        return Ok(((Vec::new(), 0, 0), Box::new(std::iter::empty())));
    };
    let volume = PreparedVolume::new(volume, &frame);
    let counts = (
        vec![volume.to_shared()],
        volume.bricks().count() as u32,
        largest_brick_bytes(volume.bricks()),
    );
    Ok((counts, Box::new(brick_blocks(volume, block_bytes).map(Ok))))
}

/// The manifest of `scene` laid out as `layout`, its volume (if any) shared as `steps`.
fn manifest_of(
    scene: &Scene,
    accel: &Accel,
    layout: BlockLayout,
    steps: &[SharedVolume],
) -> Manifest {
    let per_slot: Vec<u16> = accel
        .scene_index
        .iter()
        .map(|&i| scene.triangle_material[i as usize])
        .collect();
    let bounds = scene.bounds();
    Manifest {
        format: FORMAT,
        scene_hash: hash_hex(&scene.content_hash()),
        layout,
        max_depth: accel.max_depth() as u32,
        bounds_min: bounds.min.to_array(),
        bounds_max: bounds.max.to_array(),
        diagonal: bounds.diagonal().length(),
        render_from_world: scene.render_from_world,
        materials: material_colors_only(scene),
        lights: scene.lights.clone(),
        slot_materials: SlotMaterials::runs_of(&per_slot),
        blends: scene.has_transparency(),
        volume: (!steps.is_empty()).then(|| encode(steps).1),
        series_steps: if scene.series.is_empty() {
            0
        } else {
            steps.len() as u32
        },
        particles: (!scene.particles.is_empty())
            .then(|| ParticleEntry::of_range(scene.attribute_range())),
    }
}

/// The scene's materials without their textures: blocks hold the triangles' corners only, so
/// a shared scene is drawn in its materials' colours, and says so once.
fn material_colors_only(scene: &Scene) -> Vec<crate::scene::Material> {
    if !scene.colors.is_empty() {
        tracing::warn!(
            "scene {} has textures or vertex colours ({} textures, {} vertex colours); a shared \
             scene draws material colours only",
            &hash_hex(&scene.content_hash())[..12],
            scene.colors.textures.len(),
            scene.colors.vertex.len()
        );
    }
    let plain = |m: &crate::scene::Material| crate::scene::Material {
        texture: None,
        ..*m
    };
    scene.materials.iter().map(plain).collect()
}

/// The files of a prepared scene in `dir`.
pub fn manifest_path(dir: &Path) -> PathBuf {
    dir.join("manifest.json")
}

fn blocks_path(dir: &Path) -> PathBuf {
    dir.join("blocks.bin")
}

fn checksums_path(dir: &Path) -> PathBuf {
    dir.join("checksums.bin")
}

/// Writes `scene` (with its BVH `accel`, which must still hold its scene index) into `dir` as
/// blocks of `block_bytes`; `progress(done, total)` is called as blocks are written.
///
/// # Errors
/// What [`blocks_of`] refuses; a folder that cannot be written.
pub fn prepare(
    scene: &Scene,
    accel: &Accel,
    dir: &Path,
    block_bytes: u32,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<Manifest, PrepareError> {
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    // An old manifest goes first: until the new one is written the folder is unfinished.
    let manifest_file = manifest_path(dir);
    if manifest_file.exists() {
        std::fs::remove_file(&manifest_file).map_err(io(&manifest_file))?;
    }
    let (manifest, steps, blocks) = blocks_of(scene, accel, block_bytes)?;
    if !steps.is_empty() {
        let path = volume_path(dir);
        std::fs::write(&path, encode(&steps).0).map_err(io(&path))?;
    }
    let total = manifest.layout.total() as u64;
    let (blocks_file, sums_file) = (blocks_path(dir), checksums_path(dir));
    let mut out =
        std::io::BufWriter::new(std::fs::File::create(&blocks_file).map_err(io(&blocks_file))?);
    let mut sums = Vec::with_capacity(total as usize * 8);
    for (k, block) in blocks.enumerate() {
        let block = block?;
        out.write_all(block.bytes()).map_err(io(&blocks_file))?;
        sums.extend_from_slice(&checksum(block.bytes()).to_le_bytes());
        if k % 256 == 0 {
            progress(k as u64, total);
        }
    }
    out.flush().map_err(io(&blocks_file))?;
    std::fs::write(&sums_file, &sums).map_err(io(&sums_file))?;
    let text = serde_json::to_string_pretty(&manifest).expect("a manifest serializes");
    std::fs::write(&manifest_file, text).map_err(io(&manifest_file))?;
    progress(total, total);
    Ok(manifest)
}

/// A manifest from its JSON, checked to be of this format and to describe what can exist: a
/// layout whose counts follow from its sizes, valid materials and lights, and a material for
/// every slot that names one of them.
///
/// # Errors
/// What is wrong, in words.
pub fn parse_manifest(text: &str) -> Result<Manifest, String> {
    let manifest: Manifest = serde_json::from_str(text).map_err(|e| e.to_string())?;
    if manifest.format != FORMAT {
        return Err(format!(
            "format {}, this build reads {FORMAT}",
            manifest.format
        ));
    }
    let l = manifest.layout;
    let again = BlockLayout::new(l.block_bytes, l.node_count, l.triangle_count, l.top_blocks)
        .and_then(|again| again.with_bricks(l.brick_blocks, 0))
        .and_then(|again| again.with_spheres(l.sphere_node_count, l.sphere_count))
        .map_err(|e| e.to_string())?;
    if (l.brick_blocks > 0) != manifest.volume.is_some() {
        return Err("its brick blocks and its volume do not go together".into());
    }
    if manifest.series_steps > l.brick_blocks {
        return Err("its series has more steps than bricks".into());
    }
    let particles_ok = match manifest.particles {
        Some(p) => p.is_valid() && l.sphere_count > 0 && l.sphere_node_count > 0,
        None => l.sphere_count == 0 && l.sphere_node_count == 0,
    };
    if !particles_ok {
        return Err("its particle blocks and its particles do not go together".into());
    }
    if again != l {
        return Err("its block counts do not follow from its sizes".into());
    }
    for (i, m) in manifest.materials.iter().enumerate() {
        m.check().map_err(|e| format!("material {i} {e}"))?;
    }
    for (i, light) in manifest.lights.iter().enumerate() {
        let (at, intensity) = match *light {
            Light::Directional { towards, intensity } => (towards, intensity),
            Light::Point {
                position,
                intensity,
            } => (position, intensity),
        };
        if !(at.is_finite() && intensity.is_finite() && intensity >= 0.0) {
            return Err(format!(
                "light {i} is not finite or has a negative intensity"
            ));
        }
    }
    let known = manifest.materials.len();
    let names = |m: &u16| (*m as usize) < known;
    let slots_ok = match &manifest.slot_materials {
        SlotMaterials::PerSlot(m) => m.len() == l.triangle_count as usize && m.iter().all(names),
        SlotMaterials::Runs { starts, materials } => {
            starts.len() == materials.len()
                && starts.first().is_none_or(|&s| s == 0)
                && starts.windows(2).all(|w| w[0] < w[1])
                && materials.iter().all(names)
                && (l.triangle_count == 0 || !starts.is_empty())
        }
    };
    if !slots_ok {
        return Err(
            "its slots' materials do not cover the triangles or name a missing material".into(),
        );
    }
    let finite = manifest
        .bounds_min
        .iter()
        .chain(&manifest.bounds_max)
        .all(|v| v.is_finite())
        && manifest.diagonal.is_finite()
        && manifest.diagonal >= 0.0;
    if !finite {
        return Err("its bounds are not finite".into());
    }
    Ok(manifest)
}

/// The manifest in `dir`, checked to be of this format and, if given, of scene `expected`
/// (a content hash in hex) with blocks of `block_bytes`.
///
/// # Errors
/// No manifest, a damaged one, another format, scene or block size, or block files of the
/// wrong length.
pub fn load_manifest(dir: &Path, expected: Option<(&str, u32)>) -> Result<Manifest, PrepareError> {
    let path = manifest_path(dir);
    let text = std::fs::read_to_string(&path).map_err(io(&path))?;
    let bad = |reason: String| PrepareError::BadManifest {
        path: path.clone(),
        reason,
    };
    let manifest = parse_manifest(&text).map_err(bad)?;
    let layout = manifest.layout;
    if let Some((hash, block_bytes)) = expected {
        if manifest.scene_hash != hash || layout.block_bytes != block_bytes {
            return Err(PrepareError::OtherScene {
                path,
                found: format!(
                    "{} in blocks of {}",
                    manifest.scene_hash, layout.block_bytes
                ),
                expected: format!("{hash} in blocks of {block_bytes}"),
            });
        }
    }
    for (file, len) in [
        (blocks_path(dir), layout.total_bytes()),
        (checksums_path(dir), layout.total() as u64 * 8),
    ] {
        let found = std::fs::metadata(&file).map_err(io(&file))?.len();
        if found != len {
            return Err(bad(format!(
                "{} holds {found} bytes, not {len}",
                file.display()
            )));
        }
    }
    Ok(manifest)
}

/// What a node holds of a shared scene for good: the top of the tree and its own share.
pub type Share = (Box<[Chunk]>, Box<[Chunk]>);

/// Reads blocks from a prepared folder, checking each against its checksum.
pub struct BlockFile {
    dir: PathBuf,
    layout: BlockLayout,
    file: std::fs::File,
    sums: Vec<u64>,
}

impl BlockFile {
    /// Opens the blocks and checksums of the scene prepared in `dir` that `manifest` describes.
    ///
    /// # Errors
    /// The files cannot be opened or read.
    pub fn open(dir: &Path, manifest: &Manifest) -> Result<BlockFile, PrepareError> {
        let path = blocks_path(dir);
        let file = std::fs::File::open(&path).map_err(io(&path))?;
        let sums_file = checksums_path(dir);
        let raw = std::fs::read(&sums_file).map_err(io(&sums_file))?;
        let sums = raw
            .chunks_exact(8)
            .map(|c| u64::from_le_bytes(c.try_into().expect("8 bytes")))
            .collect();
        Ok(BlockFile {
            dir: dir.to_path_buf(),
            layout: manifest.layout,
            file,
            sums,
        })
    }

    /// Reads block `k` into `out` (one block's chunks).
    ///
    /// # Errors
    /// A read error, or a block that does not match its checksum.
    pub fn read_into(&mut self, k: BlockId, out: &mut [Chunk]) -> Result<(), PrepareError> {
        let path = blocks_path(&self.dir);
        let bytes: &mut [u8] = bytemuck::cast_slice_mut(out);
        self.file
            .seek(SeekFrom::Start(k as u64 * self.layout.block_bytes as u64))
            .and_then(|_| self.file.read_exact(bytes))
            .map_err(io(&path))?;
        if self.sums.get(k as usize) != Some(&checksum(bytes)) {
            return Err(PrepareError::Damaged { path, block: k });
        }
        Ok(())
    }

    /// Block `k`, on its own.
    ///
    /// # Errors
    /// See [`BlockFile::read_into`].
    pub fn read(&mut self, k: BlockId) -> Result<Block, PrepareError> {
        let mut block = Block::zeroed(self.layout.block_bytes);
        self.read_into(k, block.chunks_mut())?;
        Ok(block)
    }

    /// The top of the tree and this node's share (as `residency` gives it), each block
    /// checked; `progress(done, total)` as they are read.
    ///
    /// # Errors
    /// See [`BlockFile::read_into`].
    pub fn read_share(
        &mut self,
        residency: &Residency,
        progress: &mut dyn FnMut(u64, u64),
    ) -> Result<Share, PrepareError> {
        let per = (self.layout.block_bytes / 64) as usize;
        let mut top = vec![Chunk([0; 64]); self.layout.top_blocks as usize * per];
        for k in 0..self.layout.top_blocks {
            let at = k as usize * per;
            self.read_into(k, &mut top[at..at + per])?;
        }
        let mut share = vec![Chunk([0; 64]); residency.resident_len() * per];
        let total = residency.resident_blocks().count() as u64;
        for (done, (slot, k)) in residency.resident_blocks().enumerate() {
            self.read_into(k, &mut share[slot * per..(slot + 1) * per])?;
            if done % 256 == 0 {
                progress(done as u64, total);
            }
        }
        progress(total, total);
        Ok((top.into_boxed_slice(), share.into_boxed_slice()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::knot_scene;

    #[test]
    fn a_prepared_scene_reads_back_block_for_block_and_a_flipped_bit_is_caught() {
        let dir = tempfile::tempdir().unwrap();
        let scene = knot_scene(120, 16);
        let accel = Accel::build(&scene);
        let mut calls = 0;
        let manifest = prepare(&scene, &accel, dir.path(), 4096, &mut |_, _| calls += 1).unwrap();
        assert!(calls >= 2);
        let hash = hash_hex(&scene.content_hash());
        assert_eq!(
            load_manifest(dir.path(), Some((&hash, 4096))).unwrap(),
            manifest
        );
        assert!(matches!(
            load_manifest(dir.path(), Some((&hash, 8192))),
            Err(PrepareError::OtherScene { .. })
        ));
        let (_, _, blocks) = blocks_of(&scene, &accel, 4096).unwrap();
        let blocks: Vec<Block> = blocks.map(Result::unwrap).collect();
        let mut file = BlockFile::open(dir.path(), &manifest).unwrap();
        for (k, block) in blocks.iter().enumerate() {
            assert_eq!(
                file.read(k as u32).unwrap().bytes(),
                block.bytes(),
                "block {k}"
            );
        }
        // One bit of one triangle, flipped on disk.
        let path = dir.path().join("blocks.bin");
        let mut raw = std::fs::read(&path).unwrap();
        let k = manifest.layout.node_blocks as usize + 1;
        raw[k * 4096 + 100] ^= 4;
        std::fs::write(&path, raw).unwrap();
        let mut file = BlockFile::open(dir.path(), &manifest).unwrap();
        assert!(matches!(
            file.read(k as u32),
            Err(PrepareError::Damaged { block, .. }) if block == k as u32
        ));
    }

    #[test]
    fn a_manifest_naming_materials_it_lacks_or_uncovered_slots_is_refused() {
        let scene = knot_scene(24, 4);
        let accel = Accel::build(&scene);
        let (good, _, _) = blocks_of(&scene, &accel, 2048).unwrap();
        let text = |m: &Manifest| serde_json::to_string(m).unwrap();
        assert_eq!(parse_manifest(&text(&good)).unwrap(), good);
        let cases = [
            Manifest {
                slot_materials: SlotMaterials::PerSlot(vec![0; 3]),
                ..good.clone()
            },
            Manifest {
                slot_materials: SlotMaterials::Runs {
                    starts: vec![0],
                    materials: vec![7],
                },
                ..good.clone()
            },
            Manifest {
                slot_materials: SlotMaterials::Runs {
                    starts: vec![5, 2],
                    materials: vec![0, 0],
                },
                ..good.clone()
            },
            Manifest {
                diagonal: f32::NAN,
                ..good.clone()
            },
            Manifest {
                format: FORMAT + 1,
                ..good.clone()
            },
        ];
        for bad in cases {
            assert!(parse_manifest(&text(&bad)).is_err(), "{bad:?}");
        }
        let mut counts = good.clone();
        counts.layout.node_blocks += 1;
        assert!(parse_manifest(&text(&counts))
            .unwrap_err()
            .contains("block counts"));
    }

    #[test]
    fn particles_are_laid_out_after_the_triangles_and_their_range_kept() {
        let mut scene = knot_scene(16, 4);
        scene.particles = (0..1000)
            .map(|i| crate::scene::particles::Particle {
                center: glam::Vec3::new(i as f32, 0.0, 0.0),
                radius: 0.5,
                attribute: if i == 3 { f32::NAN } else { i as f32 },
            })
            .collect();
        let accel = Accel::build(&scene);
        let (manifest, _, blocks) = blocks_of(&scene, &accel, 2048).unwrap();
        let l = manifest.layout;
        assert_eq!((l.sphere_count, l.spheres_per_block()), (1000, 102));
        assert_eq!(l.sphere_blocks, 10);
        assert_eq!(
            l.first_sphere_node_block(),
            l.node_blocks + l.triangle_blocks
        );
        assert_eq!(blocks.count() as u32, l.total());
        let entry = manifest.particles.unwrap();
        assert_eq!(entry.range(), (0.0, 999.0));
        let text = serde_json::to_string(&manifest).unwrap();
        assert_eq!(parse_manifest(&text).unwrap(), manifest);
        let mut unpaired = manifest.clone();
        unpaired.particles = None;
        assert!(parse_manifest(&serde_json::to_string(&unpaired).unwrap()).is_err());
    }
}
