//! Wall files (`window::WallFile`, `wall::WallSpec`): the wall's TOML, its `[[window]]`
//! placements, and the tile grid a valid wall makes, as the master builds it.
#![no_main]

use libfuzzer_sys::fuzz_target;
use tessera_model::wall::TileGrid;
use tessera_model::window::WallFile;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(file) = WallFile::from_toml(text, "fuzz.toml") {
        for (display, placement) in &file.windows {
            assert!(*display < file.layout.display_count());
            placement
                .check()
                .expect("an accepted placement stays valid");
        }
        let grid = TileGrid::new(file.layout);
        let screens = grid.layout().display_count();
        assert!((0..screens).all(|d| !grid
            .display_tiles(tessera_model::wall::DisplayId(d))
            .is_empty()));
    }
});
