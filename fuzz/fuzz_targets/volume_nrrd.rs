//! NRRD volumes (`volume::nrrd`): header fields, raw and gzip encodings, attached data.
#![no_main]

use libfuzzer_sys::fuzz_target;
use tessera_fuzz::{load_volume, names_outside_paths, scratch_file};

fuzz_target!(|data: &[u8]| {
    // A `data file:` field may name a detached file: only ones in the scratch folder.
    if names_outside_paths(data) {
        return;
    }
    load_volume(&scratch_file("volume.nrrd", data));
});
