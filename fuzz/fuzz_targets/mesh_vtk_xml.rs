//! VTK XML surfaces (`scene::vtk::xml`): PolyData `.vtp`, or UnstructuredGrid `.vtu` when the
//! input says so, with ascii, base64, appended and zlib data.
#![no_main]

use libfuzzer_sys::fuzz_target;
use tessera_fuzz::load_scene_bytes;

fuzz_target!(|data: &[u8]| {
    // The two share the reader; the name only picks which dataset type is expected.
    let grid = data.windows(16).any(|w| w == b"UnstructuredGrid");
    load_scene_bytes(if grid { "mesh.vtu" } else { "mesh.vtp" }, data);
});
