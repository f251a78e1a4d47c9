//! VTK XML image data (`volume::vti`): extents, placement, and the data arrays in every
//! layout (ascii, base64, appended raw or base64, zlib).
#![no_main]

use libfuzzer_sys::fuzz_target;
use tessera_fuzz::{load_volume, scratch_file};

fuzz_target!(|data: &[u8]| {
    // A .vti file names no other file.
    load_volume(&scratch_file("volume.vti", data));
});
