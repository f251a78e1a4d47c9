//! Composite `.scene.toml` files (`scene::composite`): the TOML, series patterns and lists,
//! and the parts they name, which lie ready in the scratch folder (a mesh, particles and
//! volumes), so that valid names reach the merging code.
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::sync::Once;
use tessera_fuzz::{load_scene_bytes, names_outside_paths, scratch_file};

const TRIANGLE_OBJ: &str = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
const PARTICLES_CSV: &str = "x,y,z,radius,attribute\n0,0,0,0.5,1\n2,0,0,0.25,3\n";
const SIDECAR: &str = "data = \"v.raw\"\ndims = [2, 2, 2]\ntype = \"u8\"\n";

fn parts() {
    static PARTS: Once = Once::new();
    PARTS.call_once(|| {
        scratch_file("m.obj", TRIANGLE_OBJ.as_bytes());
        scratch_file("p.csv", PARTICLES_CSV.as_bytes());
        scratch_file("v.raw", &[0, 10, 20, 30, 40, 50, 60, 70]);
        for name in ["v.vol.toml", "t0.vol.toml", "t1.vol.toml"] {
            scratch_file(name, SIDECAR.as_bytes());
        }
    });
}

fuzz_target!(|data: &[u8]| {
    if names_outside_paths(data) {
        return;
    }
    parts();
    load_scene_bytes("fuzzed.scene.toml", data);
});
