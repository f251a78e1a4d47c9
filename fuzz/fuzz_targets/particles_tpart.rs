//! Particle files, binary `.tpart` (`scene::particles`), loaded as `--scene FILE.tpart` loads them.
#![no_main]

use libfuzzer_sys::fuzz_target;
use tessera_fuzz::load_scene_bytes;

fuzz_target!(|data: &[u8]| {
    load_scene_bytes("particles.tpart", data);
});
