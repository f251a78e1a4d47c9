//! PLY point clouds (`scene::points`: a vertex element and no faces), loaded as particles as
//! `--scene FILE.ply` loads them, and their sphere size taken from the spacing.
#![no_main]

use libfuzzer_sys::fuzz_target;
use tessera_fuzz::load_scene_bytes;

fuzz_target!(|data: &[u8]| {
    load_scene_bytes("points.ply", data);
});
