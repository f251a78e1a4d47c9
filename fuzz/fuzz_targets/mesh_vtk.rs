//! Legacy VTK files, ASCII or BINARY (`scene::vtk::legacy`), loaded as `--scene FILE.vtk` loads
//! them.
#![no_main]

use libfuzzer_sys::fuzz_target;
use tessera_fuzz::load_scene_bytes;

fuzz_target!(|data: &[u8]| {
    // A legacy file names no other file.
    load_scene_bytes("mesh.vtk", data);
});
