//! PLY meshes, ascii or binary (`ply-rs-bw`), loaded as `--scene FILE.ply` loads them.
#![no_main]

use libfuzzer_sys::fuzz_target;
use tessera_fuzz::load_scene_bytes;

fuzz_target!(|data: &[u8]| {
    // PLY names no other file, so binary bodies need no path guard.
    load_scene_bytes("mesh.ply", data);
});
