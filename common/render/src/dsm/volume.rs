//! A volume in distributed shared memory: its bricks, one a block after the triangles' blocks,
//! and what every render node holds whole of it (where it lies, its min/max grid: 1/512 of the
//! samples) in `volume.bin` beside the blocks, checked against the manifest's checksum.
//!
//! A time series is its steps one after the other: step `s`'s bricks follow step `s - 1`'s, and
//! `volume.bin` holds every step's placement and min/max grid, so a render node shows any step
//! from its blocks and fetches the next step's bricks while it shows this one.

use super::layout::Block;
use super::prepare::{checksum, PrepareError};
use crate::volume::{Bricks, PreparedVolume, SharedVolume, VolumeError};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use tessera_model::local_origin::RenderFromWorld;

/// What the manifest says of `volume.bin`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct VolumeEntry {
    /// Its length in bytes.
    pub bytes: u64,
    /// [`checksum`] of its bytes.
    pub checksum: u64,
}

/// The file holding what every render node keeps of a shared volume.
pub fn volume_path(dir: &Path) -> PathBuf {
    dir.join("volume.bin")
}

/// A shared volume's steps (one for a volume that is not a series) as `volume.bin` holds
/// them, and the manifest's entry for them.
pub fn encode(steps: &[SharedVolume]) -> (Vec<u8>, VolumeEntry) {
    let bytes = postcard::to_stdvec(steps).expect("a shared volume serializes");
    let entry = VolumeEntry {
        bytes: bytes.len() as u64,
        checksum: checksum(&bytes),
    };
    (bytes, entry)
}

/// Bytes of the largest brick of `bricks`.
pub fn largest_brick_bytes(bricks: &Bricks) -> u32 {
    let samples = (0..bricks.count()).map(|i| bricks.brick_len(i)).max();
    (samples.unwrap_or(0) * std::mem::size_of::<f32>()) as u32
}

/// The blocks of `volume`'s bricks, brick `i` at the start of the `i`-th, the rest zero.
pub fn brick_blocks(volume: PreparedVolume, block_bytes: u32) -> impl Iterator<Item = Block> {
    (0..volume.bricks().count()).map(move |i| {
        let bricks = volume.bricks();
        let samples = &bricks.local_samples(i)[..bricks.brick_len(i)];
        Block::filled(block_bytes, bytemuck::cast_slice(samples))
    })
}

/// Each step of the series `paths` as a node holds it whole, each step's bricks numbered on
/// from the last step's, with the bricks in all and the largest brick's bytes: what a first
/// pass over the files gives, one step in memory at a time.
///
/// # Errors
/// A step that cannot be loaded.
pub fn series_steps(
    paths: &[PathBuf],
    frame: &RenderFromWorld,
) -> Result<(Vec<SharedVolume>, u32, u32), PrepareError> {
    let mut steps: Vec<SharedVolume> = Vec::with_capacity(paths.len());
    let (mut bricks, mut largest) = (0u32, 0);
    for path in paths {
        let volume = load_step(path, frame)?;
        largest = largest.max(largest_brick_bytes(volume.bricks()));
        steps.push(SharedVolume {
            first_brick: bricks,
            ..volume.to_shared()
        });
        bricks = bricks.saturating_add(volume.bricks().count() as u32);
    }
    Ok((steps, bricks, largest))
}

/// Step `path` of a series, bricked in the render coordinates of `frame`.
fn load_step(path: &Path, frame: &RenderFromWorld) -> Result<PreparedVolume, PrepareError> {
    let volume = crate::volume::load(path).map_err(|e: VolumeError| PrepareError::Step {
        path: path.to_path_buf(),
        reason: e.to_string(),
    })?;
    Ok(PreparedVolume::new(&volume, frame))
}

/// The blocks of every step of the series `paths`, step after step, loaded again one at a
/// time (see [`series_steps`]).
pub fn series_blocks(
    paths: Vec<PathBuf>,
    frame: RenderFromWorld,
    block_bytes: u32,
) -> impl Iterator<Item = Result<Block, PrepareError>> {
    paths.into_iter().flat_map(move |path| {
        let blocks: Box<dyn Iterator<Item = Result<Block, PrepareError>>> =
            match load_step(&path, &frame) {
                Ok(volume) => Box::new(brick_blocks(volume, block_bytes).map(Ok)),
                Err(e) => Box::new(std::iter::once(Err(e))),
            };
        blocks
    })
}

/// What `dir`'s `volume.bin` holds (a step each, one for a volume that is not a series),
/// checked against `entry`.
///
/// # Errors
/// The file cannot be read, or is not what the manifest says.
pub fn load(dir: &Path, entry: &VolumeEntry) -> Result<Vec<SharedVolume>, PrepareError> {
    let path = volume_path(dir);
    let bytes = std::fs::read(&path).map_err(|reason| PrepareError::Io {
        path: path.clone(),
        reason,
    })?;
    let bad = |reason: String| PrepareError::BadManifest {
        path: path.clone(),
        reason,
    };
    if bytes.len() as u64 != entry.bytes || checksum(&bytes) != entry.checksum {
        return Err(bad(format!(
            "{} bytes that do not match the manifest's checksum: prepare the scene again",
            bytes.len()
        )));
    }
    postcard::from_bytes(&bytes).map_err(|e| bad(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bvh::Accel;
    use crate::dsm::prepare::{load_manifest, prepare, BlockFile};
    use crate::scene::Scene;

    #[test]
    fn a_prepared_volume_reads_back_brick_for_brick_and_a_flipped_bit_is_caught() {
        let dir = tempfile::tempdir().unwrap();
        let volume = crate::volume::render_tests::field(40, |p| p.x * p.y + p.z);
        let replicated = PreparedVolume::new(&volume, &Default::default());
        let scene = Scene {
            volume: Some(volume),
            ..Scene::default()
        };
        let accel = Accel::build(&scene);
        let block_bytes =
            crate::dsm::layout::brick_block_bytes(largest_brick_bytes(replicated.bricks()));
        let too_small = prepare(&scene, &accel, dir.path(), 8192, &mut |_, _| {});
        assert!(too_small.unwrap_err().to_string().contains("volume brick"));
        let manifest = prepare(&scene, &accel, dir.path(), block_bytes, &mut |_, _| {}).unwrap();
        let layout = load_manifest(dir.path(), None).unwrap().layout;
        assert_eq!(layout.brick_blocks, 8);
        let entry = manifest.volume.expect("the manifest names the volume");
        assert_eq!(load(dir.path(), &entry).unwrap(), [replicated.to_shared()]);
        let mut file = BlockFile::open(dir.path(), &manifest).unwrap();
        for i in 0..8 {
            let block = file.read(layout.first_brick_block() + i as u32).unwrap();
            let samples: &[f32] = bytemuck::cast_slice(block.bytes());
            let bricks = replicated.bricks();
            let want = &bricks.local_samples(i)[..bricks.brick_len(i)];
            assert_eq!(&samples[..want.len()], want, "brick {i}");
        }
        let path = volume_path(dir.path());
        let mut bytes = std::fs::read(&path).unwrap();
        let middle = bytes.len() / 2;
        bytes[middle] ^= 4;
        std::fs::write(&path, bytes).unwrap();
        assert!(load(dir.path(), &entry).is_err());
    }
}
