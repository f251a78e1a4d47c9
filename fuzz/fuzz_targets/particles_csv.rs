//! Particle files, CSV (`scene::particles`), loaded as `--scene FILE.csv` loads them.
#![no_main]

use libfuzzer_sys::fuzz_target;
use tessera_fuzz::load_scene_bytes;

fuzz_target!(|data: &[u8]| {
    load_scene_bytes("particles.csv", data);
});
