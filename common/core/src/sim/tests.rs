use super::*;

fn small_wall() -> WallLayout {
    WallSpec::grid(4, 2, 256, 144)
        .tile_size(32)
        .build()
        .unwrap()
}

fn lossy(loss: f64) -> SimConfig {
    SimConfig {
        loss,
        speeds: NodeSpeeds::Spread {
            fastest_us: 100,
            spread: 4.0,
        },
        ..SimConfig::new(24)
    }
}

fn run(
    seed: u64,
    layout: WallLayout,
    config: &SimConfig,
    kills: &[(u32, u64)],
    frames: u64,
) -> SimWall {
    let mut sim = SimWall::with_config(seed, layout, config);
    for &(node, frame) in kills {
        sim.kill_at(RenderNodeId(node), FrameId(frame));
    }
    sim.run_frames(frames);
    sim
}

#[test]
fn every_frame_reaches_every_live_display_under_loss_and_two_deaths() {
    let frames = 12;
    let sim = run(21, small_wall(), &lossy(0.05), &[(3, 2), (17, 5)], frames);
    let all: Vec<FrameId> = (0..frames).map(FrameId).collect();
    for d in 0..small_wall().display_count() {
        assert_eq!(sim.presented(DisplayId(d)), all, "display {d}");
    }
    assert!(
        sim.corrupt_frames().is_empty(),
        "{:?}",
        sim.corrupt_frames()
    );
    assert_eq!(sim.live_render_nodes(), 22);
    let report = sim.report();
    assert_eq!(report.frames_completed, frames);
    assert_eq!(report.render_nodes_killed, 2);
    assert!(
        report.retransmissions > 0,
        "no message was lost: {report:?}"
    );
    assert!(report.efficiency > 0.0 && report.efficiency <= 1.0);
}

#[test]
fn loss_costs_time_but_no_frame() {
    let frames = 10;
    let clean = run(4, small_wall(), &lossy(0.0), &[], frames).report();
    let lossy = run(4, small_wall(), &lossy(0.1), &[], frames).report();
    assert_eq!(clean.retransmissions, 0);
    assert!(lossy.retransmissions > 0);
    assert_eq!(lossy.frames_completed, frames);
    assert!(
        lossy.elapsed_s > clean.elapsed_s,
        "loss {} s, none {} s",
        lossy.elapsed_s,
        clean.elapsed_s
    );
}

#[test]
fn the_same_seed_replays_the_same_run() {
    let a = run(8, small_wall(), &lossy(0.05), &[(5, 1)], 6);
    let b = run(8, small_wall(), &lossy(0.05), &[(5, 1)], 6);
    assert_eq!(a.report(), b.report());
    assert_eq!(a.virtual_time(), b.virtual_time());
    for d in 0..small_wall().display_count() {
        assert_eq!(a.presented(DisplayId(d)), b.presented(DisplayId(d)));
    }
    let other = run(9, small_wall(), &lossy(0.05), &[(5, 1)], 6);
    assert_ne!(a.virtual_time(), other.virtual_time());
}

#[test]
fn one_pixel_per_tile_runs_exactly_like_full_pixels() {
    let full = run(13, small_wall(), &lossy(0.05), &[(2, 1)], 5);
    let thumb_config = SimConfig {
        pixels: PixelCheck::OnePerTile,
        ..lossy(0.05)
    };
    let thumb = run(13, small_wall(), &thumb_config, &[(2, 1)], 5);
    assert_eq!(full.report(), thumb.report());
    assert!(thumb.corrupt_frames().is_empty());
}

#[test]
fn too_few_tiles_for_the_nodes_shows_as_low_efficiency() {
    let config = SimConfig::new(16);
    // 4 tiles for 16 nodes: most nodes have nothing to do.
    let starved = run(
        1,
        WallSpec::grid(1, 1, 64, 64).tile_size(32).build().unwrap(),
        &config,
        &[],
        5,
    );
    let fed = run(
        1,
        WallSpec::grid(2, 2, 512, 256)
            .tile_size(32)
            .build()
            .unwrap(),
        &config,
        &[],
        5,
    );
    let (s, f) = (starved.report(), fed.report());
    assert_eq!((s.frames_completed, f.frames_completed), (5, 5));
    assert!(s.efficiency > 0.0 && f.efficiency <= 1.0);
    assert!(
        s.efficiency < 0.5 && f.efficiency > s.efficiency + 0.3,
        "starved {s:?}\nfed {f:?}"
    );
}

#[test]
fn seeded_speeds_spread_between_the_fastest_and_spread_times_it() {
    let config = SimConfig {
        speeds: NodeSpeeds::Spread {
            fastest_us: 100,
            spread: 3.0,
        },
        ..SimConfig::new(200)
    };
    let sim = SimWall::with_config(5, small_wall(), &config);
    let times: Vec<u64> = sim.clocks.iter().map(|c| c.tile_us).collect();
    assert!(times.iter().all(|t| (100..=300).contains(t)), "{times:?}");
    let (lo, hi) = (times.iter().min().unwrap(), times.iter().max().unwrap());
    assert!(*lo < 130 && *hi > 270, "{lo}..{hi}");
    let listed = SimConfig {
        speeds: NodeSpeeds::List(vec![100, 400]),
        ..SimConfig::new(3)
    };
    let sim = SimWall::with_config(5, small_wall(), &listed);
    let times: Vec<u64> = sim.clocks.iter().map(|c| c.tile_us).collect();
    assert_eq!(times, vec![100, 400, 100]);
}

#[test]
fn near_square_walls_have_exactly_the_displays_asked_for() {
    for (displays, columns, rows) in [(1, 1, 1), (8, 4, 2), (7, 7, 1), (12, 4, 3), (64, 8, 8)] {
        let wall = near_square_wall(displays, 1920, 1080, 64).unwrap();
        assert_eq!((wall.columns(), wall.rows()), (columns, rows), "{displays}");
        assert_eq!(wall.display_count(), displays);
    }
}

#[test]
fn static_shares_follow_node_speed_so_a_tenfold_spread_still_balances() {
    // 32 nodes whose slowest is ten times slower than the fastest, 4,608 tiles a frame. With
    // equal static shares the slow nodes' halves held up every frame: 78 % efficiency here.
    let config = SimConfig {
        speeds: NodeSpeeds::Spread {
            fastest_us: 100,
            spread: 10.0,
        },
        pixels: PixelCheck::OnePerTile,
        ..SimConfig::new(32)
    };
    let sim = run(
        3,
        WallSpec::grid(4, 2, 1024, 576)
            .tile_size(32)
            .build()
            .unwrap(),
        &config,
        &[],
        30,
    );
    let report = sim.report();
    assert_eq!(report.frames_completed, 30);
    assert!(report.efficiency > 0.95, "{report:?}");
}

#[test]
fn a_wall_whose_state_changes_every_frame_never_presents_a_mixed_frame() {
    // Every frame its own state, nodes dying and 2 % loss: tiles re-rendered after a death
    // carry their frame's state, every display checks each tile against its frame's start,
    // and the pixels (a function of frame, state and tile) show any mix as a corrupt frame.
    let config = SimConfig {
        change_every_frame: true,
        ..lossy(0.02)
    };
    let sim = run(23, small_wall(), &config, &[(3, 2), (11, 5), (17, 8)], 12);
    let all: Vec<FrameId> = (0..12).map(FrameId).collect();
    for d in 0..8 {
        assert_eq!(sim.presented(DisplayId(d)), &all[..], "display {d}");
    }
    assert!(
        sim.corrupt_frames().is_empty(),
        "{:?}",
        sim.corrupt_frames()
    );
    let states: Vec<StateId> = all.iter().map(|f| sim.frame_states()[f]).collect();
    assert!(
        states.windows(2).all(|w| w[0] < w[1]),
        "each frame a new state: {states:?}"
    );
    assert!(sim.changes_applied() >= 11);
}
