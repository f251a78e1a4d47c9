//! OBJ meshes (`tobj` and the checks around it), loaded as `--scene FILE.obj` loads them.
#![no_main]

use libfuzzer_sys::fuzz_target;
use tessera_fuzz::{load_scene_bytes, names_outside_paths};

fuzz_target!(|data: &[u8]| {
    if names_outside_paths(data) {
        return;
    }
    load_scene_bytes("mesh.obj", data);
});
