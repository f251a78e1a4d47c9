//! The wall's geometry: grids, walls of screens, stereo, tiles and wall files.

use super::*;

#[test]
fn bezels_widen_the_virtual_image_but_own_no_pixels() {
    let wall = WallSpec::grid(2, 2, 480, 270).bezel(16).build().unwrap();
    assert_eq!((wall.width(), wall.height()), (976, 556));
    assert_eq!(wall.visible_pixels(), 4 * 480 * 270);
    let s3 = wall.screen(DisplayId(3)).unwrap();
    assert_eq!((s3.x, s3.y), (496, 286));
    assert!(wall.screen(DisplayId(4)).is_none());
}

#[test]
fn tiles_cover_each_screen_exactly_once_and_never_straddle() {
    let wall = WallSpec::grid(3, 2, 200, 130)
        .bezel(7)
        .tile_size(64)
        .build()
        .unwrap();
    let grid = TileGrid::new(wall.clone());
    let mut owner = vec![None; (wall.width() * wall.height()) as usize];
    for tile in grid.tiles() {
        let screen = wall.screen(tile.display).unwrap();
        assert!(tile.x >= screen.x && tile.x + tile.width <= screen.x + screen.width);
        assert!(tile.y >= screen.y && tile.y + tile.height <= screen.y + screen.height);
        for y in tile.y..tile.y + tile.height {
            for x in tile.x..tile.x + tile.width {
                let slot = &mut owner[(y * wall.width() + x) as usize];
                assert!(slot.is_none(), "pixel {x},{y} in two tiles");
                *slot = Some(tile.display);
            }
        }
    }
    for screen in wall.screens() {
        for y in screen.y..screen.y + screen.height {
            for x in screen.x..screen.x + screen.width {
                assert_eq!(owner[(y * wall.width() + x) as usize], Some(screen.id));
            }
        }
    }
    let covered = owner.iter().filter(|o| o.is_some()).count() as u64;
    assert_eq!(covered, wall.visible_pixels());
    for screen in wall.screens() {
        let tiles = grid.display_tiles(screen.id);
        assert!(tiles.iter().all(|t| t.display == screen.id));
        let pixels: usize = tiles.iter().map(Tile::pixel_count).sum();
        assert_eq!(pixels, (screen.width * screen.height) as usize);
    }
}

#[test]
fn shorthand_sizes_parse_and_reject_garbage() {
    assert_eq!(parse_size("2x2").unwrap(), (2, 2));
    assert_eq!(parse_size("480X270").unwrap(), (480, 270));
    for bad in ["2", "x2", "2x", "axb", "-1x2", ""] {
        assert!(parse_size(bad).is_err(), "{bad}");
    }
}

#[test]
fn wall_file_errors_name_the_field() {
    let err = WallLayout::from_toml(
        "columns = 2\nrows = 2\nscreen_width = 0\nscreen_height = 270\n",
        "w.toml",
    )
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("screen_width") && err.contains("w.toml"),
        "{err}"
    );
    let err = WallLayout::from_toml("columns = 2\nrows = 2\nscreen_width = 4\n", "w.toml")
        .unwrap_err()
        .to_string();
    assert!(err.contains("screen_height"), "{err}");
    let err = WallLayout::from_toml(
        "columns = 2\nrows = 2\nscreen_width = 4\nscreen_height = 4\nbezzel = 3\n",
        "w.toml",
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("bezzel"), "{err}");
    let err = WallLayout::from_toml(
        "columns = \"two\"\nrows = 2\nscreen_width = 4\nscreen_height = 4\n",
        "w.toml",
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("columns"), "{err}");
}

#[test]
fn file_and_shorthand_describe_the_same_wall() {
    let file = WallLayout::from_toml(
        "columns = 2\nrows = 2\nscreen_width = 480\nscreen_height = 270\nbezel = 16\n",
        "w.toml",
    )
    .unwrap();
    assert_eq!(
        file,
        WallSpec::grid(2, 2, 480, 270).bezel(16).build().unwrap()
    );
}

#[test]
fn absurd_walls_are_refused() {
    assert!(matches!(
        WallLayout::grid(40, 1, 1920, 1080),
        Err(WallError::TooLarge { .. })
    ));
}

#[test]
fn walls_whose_display_count_overflows_are_refused() {
    // 65536 × 65536 screens is 2^32 displays: a u32 count wraps to 0.
    let err = WallLayout::grid(65536, 65536, 1, 1).unwrap_err();
    assert!(
        matches!(err, WallError::TooManyDisplays { displays, .. } if displays == 1 << 32),
        "{err}"
    );
    assert!(err.to_string().contains("4294967296"), "{err}");
    assert!(WallLayout::grid(64, 64, 16, 16).is_ok());
    assert!(WallLayout::grid(65, 64, 16, 16).is_err());
}

#[test]
fn walls_whose_tile_count_overflows_are_refused() {
    // One screen of 65536 × 65536 pixels in 1-pixel tiles: 2^32 tile ids.
    let err = WallSpec::grid(1, 1, 65536, 65536)
        .tile_size(1)
        .build()
        .unwrap_err();
    assert!(matches!(err, WallError::TooManyTiles { .. }), "{err}");
    assert!(err.to_string().contains("larger tiles"), "{err}");
    // The same screen in the default 64-pixel tiles is exactly the limit.
    let wall = WallLayout::grid(1, 1, 65536, 65536).unwrap();
    assert_eq!(TileGrid::new(wall.clone()).len() as u64, MAX_TILES);
}

#[test]
fn deserializing_a_wall_checks_it() {
    let bad = WallDescription::Grid {
        spec: WallSpec::grid(3, 0, 10, 10),
        stereo: Stereo::default(),
    };
    let json = serde_json::to_string(&bad).unwrap();
    let err = serde_json::from_str::<WallLayout>(&json)
        .unwrap_err()
        .to_string();
    assert!(err.contains("rows"), "{err}");
    let good = WallLayout::grid(3, 1, 10, 10).unwrap();
    let json = serde_json::to_string(&good).unwrap();
    assert_eq!(serde_json::from_str::<WallLayout>(&json).unwrap(), good);
}

fn screens_wall(stereo: crate::stereo::StereoMode) -> WallLayout {
    let text = format!(
        "tile_size = 32\n[viewer]\nposition_mm = [600.0, 300.0, 1000.0]\n\
         [stereo]\nmode = \"{}\"\n\
         [[screen]]\nresolution = [160, 90]\nx_mm = 0.0\ny_mm = 0.0\nwidth_mm = 400.0\nheight_mm = 225.0\n\
         [[screen]]\nresolution = [120, 96]\nrotation = 90\nx_mm = 420.0\ny_mm = 0.0\nwidth_mm = 240.0\nheight_mm = 300.0\n\
         [[screen]]\nresolution = [100, 60]\nbottom_left_mm = [680.0, 0.0, 0.0]\n\
         bottom_right_mm = [880.0, 0.0, 100.0]\ntop_left_mm = [680.0, 120.0, 0.0]\n",
        match stereo {
            crate::stereo::StereoMode::Mono => "mono",
            crate::stereo::StereoMode::SideBySide => "side-by-side",
            crate::stereo::StereoMode::TopBottom => "top-bottom",
            crate::stereo::StereoMode::Displays => "displays",
        }
    );
    WallLayout::from_toml(&text, "screens.toml").unwrap()
}

/// Every pixel of every display in exactly one tile of its display, and no two displays'
/// framebuffers sharing a pixel.
fn assert_tiles_cover_displays_once(wall: &WallLayout) {
    let grid = TileGrid::new(wall.clone());
    let mut owner = vec![None; (wall.width() * wall.height()) as usize];
    for tile in grid.tiles() {
        let v = &wall.viewports()[tile.viewport as usize];
        assert_eq!(v.display, tile.display);
        assert!(tile.x >= v.x && tile.x + tile.width <= v.x + v.width);
        assert!(tile.y >= v.y && tile.y + tile.height <= v.y + v.height);
        for y in tile.y..tile.y + tile.height {
            for x in tile.x..tile.x + tile.width {
                let slot = &mut owner[(y * wall.width() + x) as usize];
                assert!(slot.is_none(), "pixel {x},{y} in two tiles");
                *slot = Some(tile.display);
            }
        }
    }
    for screen in wall.screens() {
        let tiles = grid.display_tiles(screen.id);
        let pixels: usize = tiles.iter().map(Tile::pixel_count).sum();
        assert_eq!(
            pixels,
            (screen.width * screen.height) as usize,
            "{screen:?}"
        );
    }
    let covered = owner.iter().filter(|o| o.is_some()).count() as u64;
    assert_eq!(covered, wall.visible_pixels());
}

#[test]
fn a_wall_of_screens_lays_its_framebuffers_in_an_atlas_and_tiles_each() {
    use crate::stereo::{StereoMode, ViewSource};
    let wall = screens_wall(StereoMode::Mono);
    assert_eq!(wall.display_count(), 3);
    let sizes: Vec<(u32, u32)> = wall.screens().map(|s| (s.width, s.height)).collect();
    assert_eq!(sizes, vec![(160, 90), (120, 96), (100, 60)]);
    assert_eq!((wall.width(), wall.height()), (380, 96));
    assert!(wall.image_size().is_none() && !wall.is_one_image());
    assert!(wall
        .viewports()
        .iter()
        .all(|v| matches!(v.view, ViewSource::Screen(_))));
    assert_tiles_cover_displays_once(&wall);
    // It travels as its description and comes back the same.
    let json = serde_json::to_string(&wall).unwrap();
    assert_eq!(serde_json::from_str::<WallLayout>(&json).unwrap(), wall);
}

#[test]
fn stereo_splits_each_display_or_gives_each_eye_its_own() {
    use crate::stereo::{Eye, StereoMode};
    for mode in [StereoMode::SideBySide, StereoMode::TopBottom] {
        let wall = screens_wall(mode);
        assert_eq!(wall.display_count(), 3);
        let eyes: Vec<Eye> = wall.viewports().iter().map(|v| v.eye).collect();
        assert_eq!(eyes, [Eye::Left, Eye::Right].repeat(3), "{mode:?}");
        assert_tiles_cover_displays_once(&wall);
    }
    let wall = screens_wall(StereoMode::Displays);
    assert_eq!(wall.display_count(), 6);
    let eyes: Vec<Eye> = wall.viewports().iter().map(|v| v.eye).collect();
    assert_eq!(eyes, [Eye::Left, Eye::Right].repeat(3));
    assert_tiles_cover_displays_once(&wall);
    // A grid in passive stereo: each screen twice, the image as before.
    let stereo = crate::stereo::Stereo {
        mode: StereoMode::Displays,
        eye_separation: 0.0,
    };
    let grid = WallSpec::grid(2, 1, 64, 48)
        .bezel(8)
        .build_stereo(stereo)
        .unwrap();
    assert_eq!(grid.display_count(), 4);
    assert_eq!(grid.image_size(), Some((136, 48)));
    assert_tiles_cover_displays_once(&grid);
    // The mono grid is one image, traced by one frustum.
    assert!(WallSpec::grid(2, 1, 64, 48)
        .bezel(8)
        .build()
        .unwrap()
        .is_one_image());
}
