//! The BVH cache file (`accel_cache`): header, counts, arrays and the index checks that
//! traversal relies on.
#![no_main]

use libfuzzer_sys::fuzz_target;

/// Magic, format, three u64 counts, then the payload's BLAKE3 hash (as `accel_cache` writes).
const HASH_AT: usize = 4 + 4 + 8 * 3;
const HEADER: usize = HASH_AT + 32;

fuzz_target!(|data: &[u8]| {
    let mut file = data.to_vec();
    // A mutated file almost never matches its checksum; mending it lets the fuzzer reach the
    // checks behind it, which are what stands between a damaged file and traversal.
    if file.len() >= HEADER {
        let hash = blake3::hash(&file[HEADER..]);
        file[HASH_AT..HEADER].copy_from_slice(hash.as_bytes());
    }
    // The scene's triangle count, as the header claims it: the loader compares the two first.
    let triangles = file.get(16..24).map_or(0, |b| {
        u64::from_le_bytes(b.try_into().expect("8 bytes")) as usize
    });
    if let Ok(accel) = tessera_render::bvh::cache::decode_bytes(&file, triangles) {
        assert_eq!(accel.triangles.len(), triangles);
        assert_eq!(accel.scene_index.len(), triangles);
    }
});
