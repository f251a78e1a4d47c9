//! A prepared scene's manifest (`dsm::prepare`): JSON naming the block layout, materials,
//! lights and the slots' materials. What it accepts must describe a layout that exists.
#![no_main]

use libfuzzer_sys::fuzz_target;
use tessera_render::dsm::prepare::parse_manifest;

fuzz_target!(|text: &[u8]| {
    let Ok(text) = std::str::from_utf8(text) else {
        return;
    };
    if let Ok(manifest) = parse_manifest(text) {
        let layout = manifest.layout;
        assert!(layout.total_bytes() >= layout.triangle_count as u64 * 36);
        assert!(layout.top_blocks <= layout.node_blocks);
        for slot in [0, layout.triangle_count.saturating_sub(1)] {
            let _ = manifest.slot_materials.of(slot);
        }
    }
});
