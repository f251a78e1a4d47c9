//! The built BVH on disk, keyed by the scene's content hash, so a second start of a render node
//! (or the next benchmark run) skips the build.
//!
//! The file is the raw node and triangle arrays behind a small header that ends in a BLAKE3
//! hash of everything after it; anything that does not check out (wrong magic, version, sizes,
//! hash, indices) is treated as absent and rebuilt. The hash is what catches damage that the
//! other checks cannot: a flipped bit in a bounding box or a vertex is still a well-formed
//! file, and trusting it would render wrong pixels on one node only.

use crate::bvh::node::{LeafTriangle, WideNode, EMPTY, WIDTH};
use crate::bvh::tree::Accel;
use crate::scene::Scene;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

const MAGIC: [u8; 4] = *b"TBVH";
/// Bumped whenever the node layout, the build or the file layout changes (2: payload hash;
/// 3: obvhs' parallel build, which makes another tree than its serial one; 4: the 8-wide tree,
/// collapsed by the SAH, in place of the binary one).
const FORMAT: u32 = 4;
/// Magic, format, three counts, then the payload's hash.
const HEADER: usize = 4 + 4 + 8 * 3 + 32;

/// Where cached BVHs go unless told otherwise: `$XDG_CACHE_HOME/tessera/bvh` or
/// `~/.cache/tessera/bvh`.
pub fn default_cache_dir() -> Option<PathBuf> {
    std::env::var_os("XDG_CACHE_HOME")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache")))
        .map(|d| d.join("tessera").join("bvh"))
}

fn cache_path(dir: &Path, scene: &Scene) -> PathBuf {
    let mut key = blake3::Hasher::new();
    key.update(&scene.content_hash());
    key.update(&FORMAT.to_le_bytes());
    key.update(Accel::preset_name(scene.triangles.len()).as_bytes());
    key.update(bytemuck::bytes_of(&crate::bvh::collapse::COSTS_KEY));
    dir.join(format!("{}.bvh", &key.finalize().to_hex()[..32]))
}

/// How the BVH was obtained.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Source {
    /// Built now (no cache folder, no cached file for this scene, or one that could not be read).
    Built,
    /// Read from the cache folder.
    Cached,
}

/// Loads the cached BVH of `scene` from `dir`, or builds it and stores it there. A cache that
/// cannot be written costs a warning, never the run.
pub fn load_or_build(scene: &Scene, dir: Option<&Path>) -> (Accel, Source) {
    let (accel, source, _) = load_or_build_timed(scene, dir);
    (accel, source)
}

/// [`load_or_build`], and how long the build itself took (zero when read from the cache;
/// storing the cache is not counted), for build-rate figures.
pub fn load_or_build_timed(scene: &Scene, dir: Option<&Path>) -> (Accel, Source, Duration) {
    let build = || {
        let t0 = Instant::now();
        let accel = Accel::build(scene);
        let took = t0.elapsed();
        (accel, took)
    };
    let Some(dir) = dir else {
        let (accel, took) = build();
        return (accel, Source::Built, took);
    };
    let path = cache_path(dir, scene);
    let opened = std::fs::File::open(&path).and_then(|f| Ok((f.metadata()?.len(), f)));
    if let Ok((len, file)) = opened {
        match decode(file, len, scene.triangles.len()) {
            Ok(accel) => return (accel, Source::Cached, Duration::ZERO),
            Err(why) => tracing::warn!(
                "ignoring the BVH cache {} ({why}); building it again",
                path.display()
            ),
        }
    }
    let (accel, took) = build();
    if let Err(e) = store(&accel, dir, &path) {
        tracing::warn!("cannot cache the BVH in {}: {e}", dir.display());
    }
    (accel, Source::Built, took)
}

/// A scene whose triangles and vertices were freed before its cached tree was read, and what
/// was measured of them first.
pub struct LeanScene {
    /// The scene without `positions` and `triangles` (when the tree came from the cache).
    pub scene: Scene,
    /// The tree.
    pub accel: Accel,
    /// [`Scene::bounds`], measured before the triangles were freed.
    pub bounds: crate::geometry::Bounds,
    /// Where the tree came from.
    pub source: Source,
    /// The material of each leaf slot, when the tree came from the cache: its scene index
    /// was mapped as it was read and not kept (`accel.scene_index` is empty then).
    pub slot_material: Option<Vec<u16>>,
}

/// [`load_or_build`] for a render node, which needs the loaded mesh only to find and check
/// its tree: when the tree is cached, the scene's vertices and triangles are freed before the
/// file is read, so the two never coexist (on the dragon that was 18 of the load's 82 bytes
/// a triangle at its peak). A scene with texture coordinates or vertex colours keeps them (its
/// slots' colours are read through the triangles). If the cached file then proves unusable,
/// the scene is loaded again with `reload` and the tree built. `freed` runs once the mesh is
/// freed and before the tree is read: a render node returns the freed heap to the system there,
/// or the tree's arrays may land beside the hole instead of in it (a render node of a dragon
/// wall peaked at 66 or 76 MB from run to run, by where glibc put them).
///
/// # Errors
/// What `reload` returns.
pub fn load_lean<E>(
    mut scene: Scene,
    dir: Option<&Path>,
    reload: impl FnOnce() -> Result<Scene, E>,
    freed: impl FnOnce(),
) -> Result<LeanScene, E> {
    let bounds = scene.bounds();
    let colored = !scene.colors.uvs.is_empty() || !scene.colors.vertex.is_empty();
    let path = dir.map(|d| cache_path(d, &scene)).filter(|p| p.exists());
    let (Some(path), false) = (path, colored) else {
        let (accel, source) = load_or_build(&scene, dir);
        return Ok(LeanScene {
            scene,
            accel,
            bounds,
            source,
            slot_material: None,
        });
    };
    let triangles = scene.triangles.len();
    scene.positions = Vec::new();
    scene.triangles = Vec::new();
    freed();
    let mut slot_material = Vec::with_capacity(triangles);
    let mut map = |index: &[u32]| {
        slot_material.extend(index.iter().map(|&i| scene.triangle_material[i as usize]));
    };
    let read = std::fs::File::open(&path)
        .and_then(|f| Ok((f.metadata()?.len(), f)))
        .map_err(|e| e.to_string())
        .and_then(|(len, file)| {
            decode_mapping(file, len, triangles, Some(&mut map)).map_err(|e| e.to_string())
        });
    match read {
        Ok(accel) => Ok(LeanScene {
            scene,
            accel,
            bounds,
            source: Source::Cached,
            slot_material: Some(slot_material),
        }),
        Err(why) => {
            tracing::warn!(
                "ignoring the BVH cache {} ({why}); loading the scene again to build it",
                path.display()
            );
            drop(scene);
            let scene = reload()?;
            let (accel, source) = load_or_build(&scene, dir);
            Ok(LeanScene {
                scene,
                accel,
                bounds,
                source,
                slot_material: None,
            })
        }
    }
}

fn store(accel: &Accel, dir: &Path, path: &Path) -> std::io::Result<()> {
    use std::io::Write;
    std::fs::create_dir_all(dir)?;
    let payload: [&[u8]; 3] = [
        bytemuck::cast_slice(&accel.wide),
        bytemuck::cast_slice(&accel.triangles),
        bytemuck::cast_slice(&accel.scene_index),
    ];
    // The hash first, so the arrays go to the file as they are, without a copy of them all.
    let mut hasher = blake3::Hasher::new();
    for part in payload {
        hasher.update(part);
    }
    let mut header = Vec::with_capacity(HEADER);
    header.extend(MAGIC);
    header.extend(FORMAT.to_le_bytes());
    header.extend((accel.wide.len() as u64).to_le_bytes());
    header.extend((accel.triangles.len() as u64).to_le_bytes());
    header.extend((accel.max_depth() as u64).to_le_bytes());
    header.extend(hasher.finalize().as_bytes());
    // Write then rename, so a crash or a concurrent node never leaves a half file in place.
    let tmp = path.with_extension(format!("tmp{}", std::process::id()));
    let mut out = std::io::BufWriter::new(std::fs::File::create(&tmp)?);
    out.write_all(&header)?;
    for part in payload {
        out.write_all(part)?;
    }
    // No fsync: a file cut short by a crash fails its checksum and is rebuilt.
    out.into_inner().map_err(|e| e.into_error())?;
    std::fs::rename(&tmp, path)
}

/// Why a cache file was not used.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
enum Damage {
    #[error("not a BVH cache of this format")]
    Format,
    #[error("made for a scene of another size")]
    OtherScene,
    #[error("its length does not match its counts")]
    Length,
    #[error("its content does not match its checksum")]
    Checksum,
    #[error("an index is out of range")]
    Index,
}

/// Decodes a cache file already in memory, as [`load_or_build`] would read it from disk for a
/// scene of `triangles` triangles; for the fuzz targets, which feed it bytes, not files.
///
/// # Errors
/// Why the bytes are not a usable cache (the reason [`load_or_build`] logs before rebuilding).
pub fn decode_bytes(bytes: &[u8], triangles: usize) -> Result<Accel, String> {
    decode(bytes, bytes.len() as u64, triangles).map_err(|e| e.to_string())
}

/// Reads a cache file of `len` bytes straight into the arrays (no copy of the whole file is
/// held: on a multi-million-triangle mesh that copy was the load's peak) and checks it.
fn decode(file: impl std::io::Read, len: u64, triangles: usize) -> Result<Accel, Damage> {
    decode_mapping(file, len, triangles, None)
}

/// What takes the scene index in pieces instead of keeping it (see [`decode_mapping`]).
type IndexMap<'a> = dyn FnMut(&[u32]) + 'a;

/// Slots read from the scene index at a time when it is mapped rather than kept.
const INDEX_CHUNK: usize = 1 << 16;

/// [`decode`]; with `map`, the scene index is handed to it in pieces, in slot order, and not
/// kept (the accelerator's `scene_index` is empty): a render node needs only what it maps to.
fn decode_mapping(
    mut file: impl std::io::Read,
    len: u64,
    triangles: usize,
    map: Option<&mut IndexMap<'_>>,
) -> Result<Accel, Damage> {
    let mut header = [0u8; HEADER];
    file.read_exact(&mut header).map_err(|_| Damage::Format)?;
    if header[..4] != MAGIC {
        return Err(Damage::Format);
    }
    let u32_at = |i: usize| u32::from_le_bytes(header[i..i + 4].try_into().expect("4 bytes"));
    let u64_at = |i: usize| u64::from_le_bytes(header[i..i + 8].try_into().expect("8 bytes"));
    if u32_at(4) != FORMAT {
        return Err(Damage::Format);
    }
    let (nodes, tris, depth) = (u64_at(8) as usize, u64_at(16) as usize, u64_at(24) as usize);
    if tris != triangles {
        return Err(Damage::OtherScene);
    }
    let sizes = nodes
        .checked_mul(std::mem::size_of::<WideNode>())
        .zip(tris.checked_mul(std::mem::size_of::<LeafTriangle>()))
        .zip(tris.checked_mul(4));
    let Some(((node_bytes, tri_bytes), index_bytes)) = sizes else {
        return Err(Damage::Length);
    };
    // Every sum checked: counts near 2^64 wrapped the total to the file's length once, and the
    // arrays were then allocated from the counts.
    let total = [node_bytes, tri_bytes, index_bytes]
        .into_iter()
        .try_fold(HEADER, usize::checked_add);
    if total.map(|l| l as u64) != Some(len) {
        return Err(Damage::Length);
    }
    let mut hasher = blake3::Hasher::new();
    let mut read = |bytes: &mut [u8]| -> Result<(), Damage> {
        file.read_exact(bytes).map_err(|_| Damage::Length)?;
        hasher.update(bytes);
        Ok(())
    };
    let mut nodes: Vec<WideNode> = vec![bytemuck::Zeroable::zeroed(); nodes];
    read(bytemuck::cast_slice_mut(&mut nodes))?;
    let mut leaf: Vec<LeafTriangle> = vec![bytemuck::Zeroable::zeroed(); tris];
    read(bytemuck::cast_slice_mut(&mut leaf))?;
    let in_range = |index: &[u32]| index.iter().all(|&i| (i as usize) < triangles);
    let mut all_in_range = true;
    let scene_index = match map {
        None => {
            let mut scene_index = vec![0u32; tris];
            read(bytemuck::cast_slice_mut(&mut scene_index))?;
            all_in_range = in_range(&scene_index);
            scene_index
        }
        Some(map) => {
            let mut chunk = vec![0u32; INDEX_CHUNK.min(tris)];
            for start in (0..tris).step_by(INDEX_CHUNK) {
                let piece = &mut chunk[..INDEX_CHUNK.min(tris - start)];
                read(bytemuck::cast_slice_mut(piece))?;
                all_in_range &= in_range(piece);
                if all_in_range {
                    map(piece);
                }
            }
            Vec::new()
        }
    };
    if hasher.finalize().as_bytes()[..] != header[HEADER - 32..] {
        return Err(Damage::Checksum);
    }
    if !is_tree(&nodes, leaf.len()) || !all_in_range {
        return Err(Damage::Index);
    }
    Ok(Accel::from_parts(nodes, leaf, scene_index, depth))
}

/// Whether `nodes` is a tree that traversal can trust: leaves within the `leaves` triangles,
/// and every inner child after its parent, in range, and no other node's child (so what hangs
/// from the root has no cycle and no shared subtree). In range alone was not enough: a node
/// that was its own child sent traversal round for ever (found by
/// `fuzz/fuzz_targets/bvh_cache.rs`).
fn is_tree(nodes: &[WideNode], leaves: usize) -> bool {
    let mut has_parent = vec![false; nodes.len()];
    for (index, node) in nodes.iter().enumerate() {
        for k in (0..WIDTH).filter(|&k| node.count[k] != EMPTY) {
            let (child, count) = (node.child[k] as usize, node.count[k] as usize);
            if count > 0 {
                if child.checked_add(count).is_none_or(|end| end > leaves) {
                    return false;
                }
                continue;
            }
            if child <= index || child >= nodes.len() || has_parent[child] {
                return false;
            }
            has_parent[child] = true;
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::knot_scene;

    #[test]
    fn second_load_comes_from_the_cache_and_matches_the_build() {
        let dir = tempfile::tempdir().unwrap();
        let scene = knot_scene(128, 16);
        let (built, first) = load_or_build(&scene, Some(dir.path()));
        let (cached, second) = load_or_build(&scene, Some(dir.path()));
        assert_eq!((first, second), (Source::Built, Source::Cached));
        assert_eq!(built.scene_index, cached.scene_index);
        assert_eq!(
            bytemuck::cast_slice::<_, u8>(&built.wide),
            bytemuck::cast_slice::<_, u8>(&cached.wide)
        );
        assert_eq!(
            bytemuck::cast_slice::<_, u8>(&built.triangles),
            bytemuck::cast_slice::<_, u8>(&cached.triangles)
        );
    }

    /// A render node's load: with the tree cached, the scene comes back without its vertices
    /// and triangles and the tree is the built one; with the file damaged, the scene is
    /// loaded again and the tree rebuilt.
    #[test]
    fn a_lean_load_frees_the_mesh_before_reading_the_cache_and_reloads_when_it_must() {
        let dir = tempfile::tempdir().unwrap();
        let scene = || knot_scene(64, 8);
        let reload = || Ok::<_, ()>(scene());
        let first = load_lean(scene(), Some(dir.path()), reload, || ()).unwrap();
        assert_eq!(first.source, Source::Built);
        assert!(!first.scene.triangles.is_empty());
        let second = load_lean(scene(), Some(dir.path()), reload, || ()).unwrap();
        assert_eq!(second.source, Source::Cached);
        assert!(second.scene.triangles.is_empty() && second.scene.positions.is_empty());
        assert!(second.accel.scene_index.is_empty(), "mapped, not kept");
        let by_slot: Vec<u16> = (first.accel.scene_index.iter())
            .map(|&i| first.scene.triangle_material[i as usize])
            .collect();
        assert_eq!(second.slot_material, Some(by_slot));
        assert_eq!(second.bounds, scene().bounds());
        assert_eq!(
            bytemuck::cast_slice::<_, u8>(&second.accel.wide),
            bytemuck::cast_slice::<_, u8>(&first.accel.wide)
        );
        let path = cache_path(dir.path(), &scene());
        let mut bytes = std::fs::read(&path).unwrap();
        bytes[HEADER] ^= 0x01;
        std::fs::write(&path, &bytes).unwrap();
        let mut reloaded = false;
        let third = load_lean(
            scene(),
            Some(dir.path()),
            || {
                reloaded = true;
                reload()
            },
            || (),
        )
        .unwrap();
        assert!(reloaded, "a damaged cache needs the mesh again");
        assert_eq!(third.source, Source::Built);
        assert_eq!(third.scene.triangles.len(), scene().triangles.len());
    }

    #[test]
    fn another_scene_or_a_damaged_file_is_rebuilt() {
        let dir = tempfile::tempdir().unwrap();
        let scene = knot_scene(64, 8);
        load_or_build(&scene, Some(dir.path()));
        let other = knot_scene(64, 9);
        assert_eq!(load_or_build(&other, Some(dir.path())).1, Source::Built);
        for entry in std::fs::read_dir(dir.path()).unwrap() {
            let path = entry.unwrap().path();
            let mut bytes = std::fs::read(&path).unwrap();
            let last = bytes.len() - 1;
            bytes[last] = 0xff; // a scene index far out of range
            bytes[40] ^= 0x55;
            std::fs::write(&path, &bytes).unwrap();
        }
        let (accel, source) = load_or_build(&scene, Some(dir.path()));
        assert_eq!(source, Source::Built);
        assert_eq!(accel.triangles.len(), scene.triangles.len());
    }

    #[test]
    fn a_cache_whose_content_does_not_match_its_checksum_is_rebuilt() {
        let dir = tempfile::tempdir().unwrap();
        let scene = knot_scene(64, 8);
        let (built, _) = load_or_build(&scene, Some(dir.path()));
        let path = cache_path(dir.path(), &scene);
        let good = std::fs::read(&path).unwrap();
        assert!(decode(&good[..], good.len() as u64, scene.triangles.len()).is_ok());

        // One low mantissa bit of the root's bounding box: a well-formed file with every
        // index in range, which the checks before the checksum accepted and rendered from.
        let mut flipped = good.clone();
        flipped[HEADER] ^= 0x01;
        assert_eq!(
            decode(&flipped[..], flipped.len() as u64, scene.triangles.len()).err(),
            Some(Damage::Checksum)
        );
        std::fs::write(&path, &flipped).unwrap();
        let (rebuilt, source) = load_or_build(&scene, Some(dir.path()));
        assert_eq!(source, Source::Built);
        assert_eq!(
            bytemuck::cast_slice::<_, u8>(&rebuilt.wide),
            bytemuck::cast_slice::<_, u8>(&built.wide)
        );
        // ...and the rebuild replaced the damaged file.
        assert_eq!(std::fs::read(&path).unwrap(), good);
        assert_eq!(load_or_build(&scene, Some(dir.path())).1, Source::Cached);
    }

    /// A cache file of wide nodes, each its slots' (child, count) (the rest empty), and
    /// `triangles` zero triangles, its hash made to match, so only the checks behind the hash
    /// can refuse it.
    fn file_of(nodes: &[&[(u32, u32)]], triangles: usize) -> Vec<u8> {
        let wide: Vec<WideNode> = nodes
            .iter()
            .map(|slots| {
                let mut node = crate::bvh::node::BLANK;
                for (k, &(child, count)) in slots.iter().enumerate() {
                    (node.child[k], node.count[k]) = (child, count);
                }
                node
            })
            .collect();
        let mut payload = bytemuck::cast_slice::<_, u8>(&wide).to_vec();
        payload.resize(payload.len() + triangles * (36 + 4), 0);
        header(&[nodes.len() as u64, triangles as u64, 0], &payload)
    }

    fn header(counts: &[u64; 3], payload: &[u8]) -> Vec<u8> {
        let mut file = MAGIC.to_vec();
        file.extend(FORMAT.to_le_bytes());
        counts.iter().for_each(|c| file.extend(c.to_le_bytes()));
        file.extend(blake3::hash(payload).as_bytes());
        file.extend(payload);
        file
    }

    #[test]
    fn a_node_that_is_its_own_child_is_refused_not_walked_for_ever() {
        let refused = Some("an index is out of range");
        // The root its own child: traversal looped.
        let looped = file_of(&[&[(0, 0)]], 0);
        assert_eq!(decode_bytes(&looped, 0).err().as_deref(), refused);
        // A child that is the root again, and two parents sharing a child: a cycle, a blow-up.
        let back = file_of(&[&[(1, 0)], &[(0, 0), (0, 1)]], 1);
        assert_eq!(decode_bytes(&back, 1).err().as_deref(), refused);
        let shared = file_of(&[&[(1, 0), (2, 0)], &[(3, 0)], &[(3, 0)], &[(0, 1)]], 1);
        assert_eq!(decode_bytes(&shared, 1).err().as_deref(), refused);
        // A leaf past the triangles, and one whose end wraps.
        let past = file_of(&[&[(0, 2)]], 1);
        assert_eq!(decode_bytes(&past, 1).err().as_deref(), refused);
        let wraps = file_of(&[&[(u32::MAX - 1, 3)]], 1);
        assert_eq!(decode_bytes(&wraps, 1).err().as_deref(), refused);
        let tree = file_of(&[&[(1, 0), (2, 0)], &[(0, 1)], &[(0, 1)]], 1);
        assert!(decode_bytes(&tree, 1).is_ok());
    }

    #[test]
    fn counts_whose_byte_total_wraps_are_refused_before_allocating() {
        // 2^56 nodes of 256 bytes and one triangle wrap the total to 72 bytes: the file's own
        // length, so the node array would be allocated from the count.
        let file = header(&[1 << 56, 1, 0], &[0; 8]);
        assert_eq!(file.len(), 72);
        assert_eq!(
            decode_bytes(&file, 1).err().as_deref(),
            Some("its length does not match its counts")
        );
    }
}
