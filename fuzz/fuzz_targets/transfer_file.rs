//! `--transfer FILE.toml` transfer-function files (`tessera_cli::transfer_file`).
#![no_main]

use libfuzzer_sys::fuzz_target;
use tessera_cli::transfer_file::transfer_function;
use tessera_fuzz::scratch_file;

fuzz_target!(|data: &[u8]| {
    let path = scratch_file("transfer.toml", data);
    let _ = transfer_function(path.to_str().expect("scratch paths are UTF-8"));
});
