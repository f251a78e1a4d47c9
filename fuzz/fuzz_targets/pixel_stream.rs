//! Render node → display pixel streams (`protocol::pixels`), read as a display reads them:
//! the stream header against the tiles the display owns, then each tile's header against its
//! geometry before its payload, raw or LZ4.
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::sync::OnceLock;
use tessera_protocol::pixels::{
    StreamHeader, TileHeader, STREAM_HEADER_LEN, TILE_HEADER_LEN,
};
use tessera_model::wall::{DisplayId, TileGrid, WallSpec};

/// A 2×1 wall whose screens are not multiples of the tile size, so edge tiles are short.
fn grid() -> &'static TileGrid {
    static GRID: OnceLock<TileGrid> = OnceLock::new();
    GRID.get_or_init(|| {
        TileGrid::new(
            WallSpec::grid(2, 1, 100, 70)
                .tile_size(32)
                .build()
                .expect("valid wall"),
        )
    })
}

fuzz_target!(|data: &[u8]| {
    let Some((&who, stream)) = data.split_first() else {
        return;
    };
    let grid = grid();
    let me = DisplayId(u32::from(who % 2));
    let Some(header) = stream.get(..STREAM_HEADER_LEN) else {
        return;
    };
    let header = header.try_into().expect("header length");
    let Ok(header) = StreamHeader::decode(header, grid.display_tiles(me).len() as u32) else {
        return;
    };
    let mut rest = &stream[STREAM_HEADER_LEN..];
    for _ in 0..header.tile_count {
        let Some((th, tail)) = rest.split_first_chunk::<TILE_HEADER_LEN>() else {
            return;
        };
        let th = TileHeader::decode(th);
        let Some(tile) = grid.tile(th.tile).filter(|t| t.display == me) else {
            return;
        };
        let expected = tile.pixel_count() * header.format.bytes_per_pixel();
        if header.compression.check_tile_len(&th, expected).is_err() {
            return;
        }
        let Some((payload, tail)) = tail.split_at_checked(th.byte_len as usize) else {
            return;
        };
        if let Ok(rgb) = header
            .compression
            .decode_tile(th.tile, payload.to_vec(), expected)
        {
            assert_eq!(rgb.len(), expected, "a decoded tile fills its geometry");
        }
        rest = tail;
    }
});
