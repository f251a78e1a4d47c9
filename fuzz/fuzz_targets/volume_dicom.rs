//! DICOM series (`volume::dicom` and dicom-rs): a folder of slices. The input is one or more
//! slice files joined by the marker below, so the fuzzer mutates series as well as slices.
#![no_main]

use libfuzzer_sys::fuzz_target;
use tessera_fuzz::{load_volume, scratch_dir};

const SLICE_BREAK: &[u8] = b"--TESSERA-FUZZ-SLICE--";
/// More slices than this only repeats what the first few test.
const MAX_SLICES: usize = 8;

fn slices(mut data: &[u8]) -> Vec<&[u8]> {
    let mut out = Vec::new();
    while out.len() + 1 < MAX_SLICES {
        let Some(at) = data
            .windows(SLICE_BREAK.len())
            .position(|w| w == SLICE_BREAK)
        else {
            break;
        };
        out.push(&data[..at]);
        data = &data[at + SLICE_BREAK.len()..];
    }
    out.push(data);
    out
}

fuzz_target!(|data: &[u8]| {
    let dir = scratch_dir().join("series");
    // A fresh folder each run: slices left from a longer input must not join this series.
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("series folder");
    for (i, slice) in slices(data).into_iter().enumerate() {
        std::fs::write(dir.join(format!("slice{i}.dcm")), slice).expect("slice file");
    }
    load_volume(&dir);
});
