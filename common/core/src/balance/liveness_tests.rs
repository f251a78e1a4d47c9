//! Deaths noticed by the coordinator's own clock: a virtual one, no sleep anywhere.

use super::tests::{assigned_to, drain};
use super::*;
use tessera_model::camera::Camera;
use tessera_model::wall::TileId;
use tessera_protocol::TileRange;

fn coordinator(tiles: u32, frames: u64) -> Coordinator {
    super::tests::coordinator(tiles, 1, frames)
}

#[test]
fn a_silent_node_is_suspected_at_the_deadline_its_tiles_move_and_it_dies_later() {
    let (alive, silent) = (RenderNodeId(0), RenderNodeId(1));
    let mut c = coordinator(16, 1);
    let t0 = Instant::now();
    let ms = |n: u64| t0 + Duration::from_millis(n);
    c.handle_render_joined(alive, t0);
    c.handle_render_joined(silent, t0);
    c.start(t0);
    let out = drain(&mut c);
    let mut mine = assigned_to(&out, alive);
    assert!(
        !assigned_to(&out, silent).is_empty(),
        "the silent node holds a share"
    );

    c.handle_heartbeat(alive, ms(100)).unwrap();
    c.handle_display_heartbeat(DisplayId(0), ms(100));
    // The quietest node sets the deadline: the silent one, heard last at the start.
    assert_eq!(c.poll_timeout(), Some(t0 + DEFAULT_NODE_DEADLINE));
    c.handle_timeout(ms(299));
    assert!(drain(&mut c).is_empty(), "nobody is late yet");
    c.handle_timeout(ms(300));
    let out = drain(&mut c);
    let suspected = Output::RenderSuspected {
        node: silent,
        silent: Duration::from_millis(300),
    };
    assert!(out.contains(&suspected), "{out:?}");
    assert!(
        !out.iter()
            .any(|o| matches!(o, Output::RenderTimedOut { .. })),
        "suspected, not dead: {out:?}"
    );

    // The living node renders everything, the suspected node's share included: copies.
    let mut rendered = 0;
    for step in 0..64 {
        if mine.is_empty() {
            break;
        }
        rendered += mine.iter().map(|r| r.len()).sum::<usize>();
        let at = ms(310 + step);
        c.handle_tiles_done(alive, FrameId(0), &mine, true, at)
            .unwrap();
        mine = assigned_to(&drain(&mut c), alive);
    }
    assert_eq!(rendered, 16);
    // Death: the acceptable pause past its rhythm, and a few spreads (the spread is at
    // least the minimum, as it beat only at its join).
    let pause = DEFAULT_ACCEPTABLE_PAUSE;
    c.handle_timeout(t0 + pause);
    let dead = |out: &[Output]| {
        out.iter()
            .any(|o| matches!(o, Output::RenderTimedOut { node, .. } if *node == silent))
    };
    assert!(!dead(&drain(&mut c)), "alive within the acceptable pause");
    let death = t0 + pause + Duration::from_millis(600);
    c.handle_timeout(death);
    let out = drain(&mut c);
    assert!(dead(&out), "{out:?}");
    assert_eq!(
        c.handle_heartbeat(silent, death + Duration::from_millis(1)),
        Err(BalanceError::UnknownNode(silent))
    );
}

#[test]
fn a_suspected_node_that_speaks_again_is_back_and_gets_a_share_again() {
    let (steady, paused) = (RenderNodeId(0), RenderNodeId(1));
    let mut c = coordinator(16, 3);
    let t0 = Instant::now();
    let ms = |n: u64| t0 + Duration::from_millis(n);
    c.handle_render_joined(steady, t0);
    c.handle_render_joined(paused, t0);
    c.start(t0);
    let _ = drain(&mut c);
    // Stopped for 600 ms: suspected at 300 ms, back at 600 ms, without a rejoin.
    for beat in 1..=12 {
        c.handle_heartbeat(steady, ms(50 * beat)).unwrap();
        c.handle_display_heartbeat(DisplayId(0), ms(50 * beat));
        c.handle_timeout(ms(50 * beat));
    }
    let out = drain(&mut c);
    assert!(out.contains(&Output::RenderSuspected {
        node: paused,
        silent: Duration::from_millis(300)
    }));
    c.handle_heartbeat(paused, ms(601)).unwrap();
    let out = drain(&mut c);
    assert!(
        out.contains(&Output::RenderBack {
            node: paused,
            silent: Duration::from_millis(601)
        }),
        "{out:?}"
    );
    assert!(c.render_nodes().any(|n| n == paused));
}

#[test]
fn silence_while_the_master_did_not_run_counts_against_nobody() {
    let node = RenderNodeId(0);
    let mut c = coordinator(4, 1);
    let t0 = Instant::now();
    c.handle_render_joined(node, t0);
    c.start(t0);
    let _ = drain(&mut c);
    // The master slept through its deadline by 3 s; the node's beats are queued behind it.
    let woke = t0 + Duration::from_secs(3);
    c.credit_blind_time(Duration::from_millis(2_800), woke);
    c.handle_timeout(woke);
    let out = drain(&mut c);
    assert!(
        !out.iter().any(|o| matches!(
            o,
            Output::RenderSuspected { .. } | Output::RenderTimedOut { .. }
        )),
        "{out:?}"
    );
}

#[test]
fn heartbeats_keep_a_busy_node_alive_however_long_its_batch_takes() {
    let node = RenderNodeId(0);
    let mut c = coordinator(4, 1);
    let t0 = Instant::now();
    c.handle_render_joined(node, t0);
    c.start(t0);
    let _ = drain(&mut c);
    // Ten seconds of rendering one batch, a heartbeat every 50 ms, the driver calling back
    // whenever the coordinator asked.
    let beat = tessera_protocol::HEARTBEAT_INTERVAL;
    let mut now = t0;
    for _ in 0..200 {
        now += beat;
        let due = c.poll_timeout().expect("a live node is timed");
        assert!(due > now, "the deadline stays ahead of the beats");
        c.handle_heartbeat(node, now).unwrap();
        c.handle_display_heartbeat(DisplayId(0), now);
        c.handle_timeout(now);
        assert!(!drain(&mut c)
            .iter()
            .any(|o| matches!(o, Output::RenderTimedOut { .. })));
    }
    assert_eq!(c.render_nodes().count(), 1);
}

#[test]
fn a_hung_node_that_still_beats_has_its_tiles_copied_after_its_lease() {
    let (quick, hung) = (RenderNodeId(0), RenderNodeId(1));
    let mut c = coordinator(16, 1);
    let t0 = Instant::now();
    let ms = |n: u64| t0 + Duration::from_millis(n);
    c.handle_render_joined(quick, t0);
    c.handle_render_joined(hung, t0);
    c.start(t0);
    let out = drain(&mut c);
    let mut mine = assigned_to(&out, quick);
    let held = assigned_to(&out, hung);
    // The quick node renders its share and everything left in the pool, in 2 ms steps,
    // before the hung node's lease ends.
    let mut at = 0;
    while !mine.is_empty() {
        at += 2;
        c.handle_tiles_done(quick, FrameId(0), &mine, true, ms(at))
            .unwrap();
        mine = assigned_to(&drain(&mut c), quick);
    }
    // Now it waits; the hung node beats but reports nothing. Its lease (the shortest, since it
    // never reported) ends 40 ms after it was given its share, long before the deadline.
    c.handle_heartbeat(hung, ms(at)).unwrap();
    c.handle_display_heartbeat(DisplayId(0), ms(at));
    let due = c.poll_timeout().unwrap();
    assert_eq!(
        due,
        t0 + speculate::MIN_LEASE.max(Duration::from_millis(at))
    );
    c.handle_timeout(due);
    let out = drain(&mut c);
    let copies = assigned_to(&out, quick);
    assert!(!copies.is_empty(), "{out:?}");
    assert!(!out
        .iter()
        .any(|o| matches!(o, Output::RenderTimedOut { .. })));
    // The quick node renders the copies (asking for more: the rest of the hung node's tiles).
    let mut copies = copies;
    for step in 0..32 {
        if copies.is_empty() {
            break;
        }
        c.handle_tiles_done(
            quick,
            FrameId(0),
            &copies,
            true,
            due + Duration::from_millis(step),
        )
        .unwrap();
        copies = assigned_to(&drain(&mut c), quick);
    }
    assert_eq!(
        c.speculated_tiles(),
        held.iter().map(|r| r.len()).sum::<usize>() as u64
    );
    c.handle_frame_complete(DisplayId(0), FrameId(0), due + Duration::from_millis(50))
        .unwrap();
    assert!(drain(&mut c).contains(&Output::Finished));
    // The hung node's report, when it comes, is a duplicate, not a protocol violation.
    c.handle_tiles_done(hung, FrameId(0), &held, false, ms(500))
        .unwrap();
}

#[test]
fn a_lost_display_settles_its_tiles_and_the_others_go_on_presenting() {
    let camera = CameraMode::fixed(
        Camera::new(glam::Vec3::Z, glam::Vec3::ZERO, glam::Vec3::Y, 45.0).unwrap(),
    );
    // 8 tiles: 0..4 on display 0, 4..8 on display 1; two frames.
    let mut c = Coordinator::new(
        8,
        2,
        camera,
        RenderParams::interactive(),
        Some(2),
        BalanceConfig::default(),
    );
    c.set_tile_displays((0..8).map(|t| DisplayId(t / 4)).collect());
    let node = RenderNodeId(0);
    let t0 = Instant::now();
    c.handle_render_joined(node, t0);
    c.start(t0);
    let in_frame = |out: &[Output], frame: FrameId| -> Vec<TileRange> {
        out.iter()
            .filter_map(|o| match o {
                Output::ToRender(_, ToNode::Assign { frame: f, tiles }) if *f == frame => {
                    Some(tiles.clone())
                }
                _ => None,
            })
            .flatten()
            .collect()
    };
    let mut later = Vec::new();
    let first = in_frame(&drain(&mut c), FrameId(0));
    // Display 1 dies before the frame is rendered: the barrier waits for display 0 only.
    c.handle_display_left(DisplayId(1), t0);
    assert_eq!(c.live_displays().collect::<Vec<_>>(), vec![DisplayId(0)]);
    let mut mine = first;
    let mut rendered: Vec<TileId> = Vec::new();
    for _ in 0..16 {
        if mine.is_empty() {
            break;
        }
        rendered.extend(mine.iter().flat_map(|r| r.tiles()));
        c.handle_tiles_done(node, FrameId(0), &mine, true, t0)
            .unwrap();
        let out = drain(&mut c);
        later.extend(in_frame(&out, FrameId(1)));
        mine = in_frame(&out, FrameId(0));
    }
    assert!(rendered.len() <= 8);
    c.handle_frame_complete(DisplayId(0), FrameId(0), t0)
        .unwrap();
    let out = drain(&mut c);
    assert!(
        out.contains(&Output::ToDisplays(ToNode::Present { frame: FrameId(0) })),
        "{out:?}"
    );
    // Frame 1 hands out display 0's tiles only.
    let second: Vec<TileId> = assigned_to(&out, node)
        .iter()
        .flat_map(|r| r.tiles())
        .collect();
    assert!(second.iter().all(|t| t.0 < 4), "{second:?}");
    // What display 1 still says counts for nothing, and no error.
    c.handle_frame_complete(DisplayId(1), FrameId(0), t0)
        .unwrap();
}

#[test]
fn a_rejoined_display_is_waited_for_from_the_next_frame_not_by_frames_in_flight() {
    let camera = CameraMode::fixed(
        Camera::new(glam::Vec3::Z, glam::Vec3::ZERO, glam::Vec3::Y, 45.0).unwrap(),
    );
    let config = BalanceConfig {
        static_fraction: 1.0,
        ..BalanceConfig::default()
    };
    let mut c = Coordinator::new(8, 2, camera, RenderParams::interactive(), Some(3), config);
    c.set_tile_displays((0..8).map(|t| DisplayId(t / 4)).collect());
    let node = RenderNodeId(0);
    let t0 = Instant::now();
    c.handle_render_joined(node, t0);
    c.start(t0);
    let all = [TileRange::new(0, 8).unwrap()];
    // Frames 0 and 1 start with both displays (all tiles handed out at once); display 1 dies
    // and is back before either is presented: a quick restart.
    let _ = drain(&mut c);
    c.handle_display_left(DisplayId(1), t0);
    c.handle_display_joined(DisplayId(1), t0);
    for f in 0..2 {
        c.handle_tiles_done(node, FrameId(f), &all, false, t0)
            .unwrap();
        // The frames in flight present on display 0 alone: display 1 never saw them start.
        c.handle_frame_complete(DisplayId(0), FrameId(f), t0)
            .unwrap();
        let out = drain(&mut c);
        assert!(
            out.contains(&Output::ToDisplays(ToNode::Present { frame: FrameId(f) })),
            "{out:?}"
        );
        if f == 0 {
            // Frame 2 starts with display 1 again: all 8 tiles.
            let frame2: usize = out
                .iter()
                .filter_map(|o| match o {
                    Output::ToRender(_, ToNode::Assign { frame, tiles })
                        if *frame == FrameId(2) =>
                    {
                        Some(tiles.iter().map(|r| r.len()).sum::<usize>())
                    }
                    _ => None,
                })
                .sum();
            assert_eq!(frame2, 8, "{out:?}");
        }
    }
    // Frame 2 waits for both displays.
    c.handle_tiles_done(node, FrameId(2), &all, false, t0)
        .unwrap();
    c.handle_frame_complete(DisplayId(0), FrameId(2), t0)
        .unwrap();
    let present2 = Output::ToDisplays(ToNode::Present { frame: FrameId(2) });
    assert!(!drain(&mut c).contains(&present2));
    c.handle_frame_complete(DisplayId(1), FrameId(2), t0)
        .unwrap();
    assert!(drain(&mut c).contains(&present2));
}

#[test]
fn without_speculation_a_late_node_keeps_its_tiles_until_its_deadline() {
    let camera = CameraMode::fixed(
        Camera::new(glam::Vec3::Z, glam::Vec3::ZERO, glam::Vec3::Y, 45.0).unwrap(),
    );
    let config = BalanceConfig {
        speculate: false,
        ..BalanceConfig::default()
    };
    let mut c = Coordinator::new(16, 1, camera, RenderParams::interactive(), Some(1), config);
    let (quick, late) = (RenderNodeId(0), RenderNodeId(1));
    let t0 = Instant::now();
    c.handle_render_joined(quick, t0);
    c.handle_render_joined(late, t0);
    c.start(t0);
    let mut mine = assigned_to(&drain(&mut c), quick);
    let mut at = t0;
    while !mine.is_empty() {
        at += Duration::from_millis(2);
        c.handle_tiles_done(quick, FrameId(0), &mine, true, at)
            .unwrap();
        mine = assigned_to(&drain(&mut c), quick);
    }
    // Waiting, with the late node far past any lease: nothing is copied, and the next thing
    // timed is a deadline.
    let later = t0 + Duration::from_millis(200);
    c.handle_heartbeat(late, later).unwrap();
    c.handle_heartbeat(quick, later).unwrap();
    c.handle_display_heartbeat(DisplayId(0), later);
    c.handle_timeout(later);
    assert!(assigned_to(&drain(&mut c), quick).is_empty());
    assert_eq!(c.speculated_tiles(), 0);
    assert_eq!(c.poll_timeout(), Some(later + DEFAULT_NODE_DEADLINE));
}

#[test]
fn waiting_for_a_lost_display_starts_no_frame_until_it_is_back() {
    let camera = CameraMode::fixed(
        Camera::new(glam::Vec3::Z, glam::Vec3::ZERO, glam::Vec3::Y, 45.0).unwrap(),
    );
    let limit = Duration::from_secs(5);
    let config = BalanceConfig {
        static_fraction: 1.0,
        wait_for_lost_displays: Some(limit),
        ..BalanceConfig::default()
    };
    let mut c = Coordinator::new(8, 2, camera, RenderParams::interactive(), Some(4), config);
    c.set_tile_displays((0..8).map(|t| DisplayId(t / 4)).collect());
    let node = RenderNodeId(0);
    let t0 = Instant::now();
    let ms = |n: u64| t0 + Duration::from_millis(n);
    c.handle_render_joined(node, t0);
    c.start(t0);
    let all = [TileRange::new(0, 8).unwrap()];
    let started = |out: &[Output]| -> Vec<FrameId> {
        out.iter()
            .filter_map(|o| match o {
                Output::FrameStarted(f) => Some(*f),
                _ => None,
            })
            .collect()
    };
    assert_eq!(started(&drain(&mut c)), vec![FrameId(0), FrameId(1)]);
    // Display 1 is lost with frames 0 and 1 in flight: display 0 still shows both.
    c.handle_display_left(DisplayId(1), ms(10));
    assert_eq!(c.awaited_displays().collect::<Vec<_>>(), vec![DisplayId(1)]);
    for f in 0..2 {
        c.handle_tiles_done(node, FrameId(f), &all, true, ms(20))
            .unwrap();
        c.handle_frame_complete(DisplayId(0), FrameId(f), ms(20))
            .unwrap();
    }
    let out = drain(&mut c);
    assert!(out.contains(&Output::FramePresented(FrameId(1))), "{out:?}");
    // ...and then nothing starts, however long the wait, short of the limit.
    assert!(started(&out).is_empty(), "{out:?}");
    assert!(c.poll_timeout().is_some_and(|t| t <= ms(10) + limit));
    for at in [100, 1_000, 4_000] {
        c.handle_heartbeat(node, ms(at)).unwrap();
        c.handle_display_heartbeat(DisplayId(0), ms(at));
        c.handle_timeout(ms(at));
        let out = drain(&mut c);
        assert!(started(&out).is_empty(), "at {at} ms: {out:?}");
    }
    // Back: the next frames start at once, with both displays' tiles, and wait for both.
    c.handle_display_joined(DisplayId(1), ms(4_500));
    let out = drain(&mut c);
    assert_eq!(started(&out), vec![FrameId(2), FrameId(3)], "{out:?}");
    let handed: usize = assigned_to(&out, node).iter().map(|r| r.len()).sum();
    assert_eq!(handed, 16, "all 8 tiles of each frame");
    c.handle_tiles_done(node, FrameId(2), &all, false, ms(4_510))
        .unwrap();
    c.handle_frame_complete(DisplayId(0), FrameId(2), ms(4_510))
        .unwrap();
    let present2 = Output::FramePresented(FrameId(2));
    assert!(!drain(&mut c).contains(&present2));
    c.handle_frame_complete(DisplayId(1), FrameId(2), ms(4_520))
        .unwrap();
    assert!(drain(&mut c).contains(&present2));
}

#[test]
fn a_lost_display_not_back_within_the_wait_is_reported_once() {
    let camera = CameraMode::fixed(
        Camera::new(glam::Vec3::Z, glam::Vec3::ZERO, glam::Vec3::Y, 45.0).unwrap(),
    );
    let limit = Duration::from_secs(2);
    let config = BalanceConfig {
        wait_for_lost_displays: Some(limit),
        node_deadline: Duration::from_secs(60),
        ..BalanceConfig::default()
    };
    let mut c = Coordinator::new(8, 2, camera, RenderParams::interactive(), None, config);
    c.set_tile_displays((0..8).map(|t| DisplayId(t / 4)).collect());
    let t0 = Instant::now();
    c.handle_render_joined(RenderNodeId(0), t0);
    c.start(t0);
    let _ = drain(&mut c);
    c.handle_display_left(DisplayId(0), t0);
    assert_eq!(c.poll_timeout(), Some(t0 + limit));
    c.handle_timeout(t0 + limit - Duration::from_millis(1));
    assert!(!drain(&mut c)
        .iter()
        .any(|o| matches!(o, Output::DisplayNotBack { .. })));
    c.handle_timeout(t0 + limit);
    let out = drain(&mut c);
    assert!(
        out.contains(&Output::DisplayNotBack {
            display: DisplayId(0),
            waited: limit
        }),
        "{out:?}"
    );
    c.handle_timeout(t0 + limit * 2);
    assert!(!drain(&mut c)
        .iter()
        .any(|o| matches!(o, Output::DisplayNotBack { .. })));
}
