//! STL meshes, binary or ASCII (`scene::stl`), loaded as `--scene FILE.stl` loads them.
#![no_main]

use libfuzzer_sys::fuzz_target;
use tessera_fuzz::load_scene_bytes;

fuzz_target!(|data: &[u8]| {
    // STL names no other file.
    load_scene_bytes("mesh.stl", data);
});
