//! Raw voxels with a `.vol.toml` sidecar (`volume::raw`). The input is the sidecar, then a
//! NUL byte, then the voxel file it may name as `data.raw`.
#![no_main]

use libfuzzer_sys::fuzz_target;
use tessera_fuzz::{load_volume, names_outside_paths, scratch_file};

fuzz_target!(|data: &[u8]| {
    let (sidecar, voxels) = match data.iter().position(|&b| b == 0) {
        Some(at) => (&data[..at], &data[at + 1..]),
        None => (data, &[][..]),
    };
    if names_outside_paths(sidecar) {
        return;
    }
    scratch_file("data.raw", voxels);
    load_volume(&scratch_file("volume.vol.toml", sidecar));
});
