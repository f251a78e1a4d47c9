//! What the fuzz targets share: a scratch folder for loaders that only take a path, and the
//! guard that keeps fuzzed paths inside it.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// A folder of this process's own under the temp dir (`fuzz/run.sh` points `TMPDIR` at one it
/// removes afterwards), so parallel runs never read each other's files.
pub fn scratch_dir() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = std::env::temp_dir().join(format!("tessera-fuzz-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("scratch folder");
        dir
    })
}

/// Writes `bytes` as `name` in the scratch folder and returns its path.
pub fn scratch_file(name: &str, bytes: &[u8]) -> PathBuf {
    let path = scratch_dir().join(name);
    std::fs::write(&path, bytes).expect("scratch file");
    path
}

/// Whether an input could name a file outside the scratch folder: an absolute path (a `/` that
/// starts a word or a quoted string), a parent folder, or either percent-encoded. Loaders follow
/// the paths a file names (an OBJ's `mtllib`, NRRD's `data file`, a scene's parts), and one
/// mutation away from `data file: x.raw` is `/dev/zero`, which reads for ever; those inputs
/// are skipped rather than let the fuzzer wander the machine.
pub fn names_outside_paths(bytes: &[u8]) -> bool {
    let lower = bytes.to_ascii_lowercase();
    let absolute = lower.iter().enumerate().any(|(i, &b)| {
        (b == b'/' || b == b'\\')
            && (i == 0 || b" \t\r\n\"':=,[(".contains(&lower[i - 1]) || lower[i - 1] == b'\0')
    });
    absolute
        || lower.windows(2).any(|w| w == b"..")
        || lower
            .windows(3)
            .any(|w| w == b"%2f" || w == b"%5c" || w == b"%2e")
        || lower.windows(5).any(|w| w == b"file:")
}

/// Loads `bytes` as the scene file `name` (its extension picks the loader), as `--scene` does,
/// and checks that what loaded passes the scene's own validation again.
pub fn load_scene_bytes(name: &str, bytes: &[u8]) {
    use tessera_render::scene::Scene;
    use tessera_model::scene_spec::SceneSpec;
    let path = scratch_file(name, bytes);
    let spec = SceneSpec::from_arg(path.to_str().expect("scratch paths are UTF-8"))
        .expect("a scratch path is a valid scene name");
    if let Ok(scene) = Scene::load(&spec) {
        scene.validate(name).expect("a loaded scene stays valid");
    }
}

/// Loads the volume at `path` as `--scene` does and checks the invariants the renderer builds
/// on: one value per voxel, finite values and placement.
pub fn load_volume(path: &Path) {
    if let Ok(volume) = tessera_render::volume::load(path) {
        let [x, y, z] = volume.dims();
        assert_eq!(volume.values().len(), x * y * z);
        let (lo, hi) = volume.range();
        assert!(
            lo.is_finite() && hi.is_finite() && lo <= hi,
            "range {lo}..{hi}"
        );
        assert!(volume
            .world_corners()
            .iter()
            .flatten()
            .all(|c| c.is_finite()));
    }
}
