//! NIfTI-1 volumes (`volume::nifti` and the `nifti` crate): header, sform/qform placement,
//! scaling, voxel types.
#![no_main]

use libfuzzer_sys::fuzz_target;
use tessera_fuzz::{load_volume, scratch_file};

fuzz_target!(|data: &[u8]| {
    // Single-file `.nii` only: it names no other file, so needs no path guard.
    load_volume(&scratch_file("volume.nii", data));
});
