use super::*;
use crate::sim::SimWall;
use glam::Vec3;
use tessera_model::camera::Camera;
use tessera_model::state::StateId;
use tessera_model::wall::WallSpec;
use tessera_protocol::{TileRange, ToNode};

pub(super) fn coordinator(tiles: u32, displays: u32, frames: u64) -> Coordinator {
    let camera = CameraMode::fixed(Camera::new(Vec3::Z, Vec3::ZERO, Vec3::Y, 45.0).unwrap());
    Coordinator::new(
        tiles,
        displays,
        camera,
        RenderParams::interactive(),
        Some(frames),
        BalanceConfig::default(),
    )
}

pub(super) fn drain(c: &mut Coordinator) -> Vec<Output> {
    std::iter::from_fn(|| c.poll_output()).collect()
}

pub(super) fn assigned_to(outputs: &[Output], node: RenderNodeId) -> Vec<TileRange> {
    outputs
        .iter()
        .filter_map(|o| match o {
            Output::ToRender(n, ToNode::Assign { tiles, .. }) if *n == node => Some(tiles.clone()),
            _ => None,
        })
        .flatten()
        .collect()
}

#[test]
fn whole_frames_present_on_every_display_with_the_right_pixels() {
    let mut sim = SimWall::new(
        7,
        WallSpec::grid(3, 2, 200, 120)
            .tile_size(32)
            .build()
            .unwrap(),
        4,
    );
    assert_eq!(sim.run_frames(5), 5);
    for d in 0..6 {
        assert_eq!(
            sim.presented(DisplayId(d)),
            (0..5).map(FrameId).collect::<Vec<_>>()
        );
    }
    assert!(sim.corrupt_frames().is_empty());
}

#[test]
fn a_render_node_that_disappears_mid_frame_does_not_stop_the_wall() {
    let mut sim = SimWall::new(
        11,
        WallSpec::grid(2, 2, 256, 128)
            .tile_size(32)
            .build()
            .unwrap(),
        3,
    );
    sim.kill_at(RenderNodeId(1), FrameId(2));
    assert_eq!(sim.run_frames(6), 6);
    assert_eq!(sim.live_render_nodes(), 2);
    for d in 0..4 {
        assert_eq!(
            sim.presented(DisplayId(d)),
            (0..6).map(FrameId).collect::<Vec<_>>()
        );
    }
    assert!(sim.corrupt_frames().is_empty());
}

#[test]
fn many_virtual_nodes_and_deaths() {
    let mut sim = SimWall::new(
        3,
        WallSpec::grid(8, 4, 256, 144)
            .tile_size(32)
            .build()
            .unwrap(),
        64,
    );
    for k in [5, 17, 40] {
        sim.kill_at(RenderNodeId(k), FrameId(k as u64 % 4));
    }
    assert_eq!(sim.run_frames(8), 8);
    assert_eq!(sim.live_render_nodes(), 61);
    assert!(sim.corrupt_frames().is_empty());
    for d in 0..32 {
        assert_eq!(sim.presented(DisplayId(d)).len(), 8);
    }
}

#[test]
fn first_assignment_is_a_static_contiguous_share_then_batches_shrink() {
    let mut c = coordinator(100, 1, 1);
    let now = Instant::now();
    for n in 0..2 {
        c.handle_render_joined(RenderNodeId(n), now);
    }
    c.start(now);
    let out = drain(&mut c);
    assert_eq!(
        assigned_to(&out, RenderNodeId(0)),
        vec![TileRange::new(0, 25).unwrap()]
    );
    assert_eq!(
        assigned_to(&out, RenderNodeId(1)),
        vec![TileRange::new(50, 75).unwrap()]
    );
    let mut sizes = Vec::new();
    loop {
        c.handle_tiles_done(RenderNodeId(0), FrameId(0), &[], true, now)
            .unwrap();
        let got: usize = assigned_to(&drain(&mut c), RenderNodeId(0))
            .iter()
            .map(|r| r.len())
            .sum();
        if got == 0 {
            break;
        }
        sizes.push(got);
    }
    assert_eq!(sizes.iter().sum::<usize>(), 50);
    assert!(sizes.windows(2).all(|w| w[0] >= w[1]), "{sizes:?}");
    assert!(sizes[0] > *sizes.last().unwrap());
}

#[test]
fn state_changes_wait_for_the_barrier() {
    let mut c = coordinator(4, 1, 3);
    let now = Instant::now();
    c.handle_render_joined(RenderNodeId(0), now);
    c.start(now);
    let first = drain(&mut c);
    let moved = Camera::new(Vec3::new(5.0, 0.0, 0.0), Vec3::ZERO, Vec3::Y, 30.0).unwrap();
    c.queue_change(StateChange::Camera(CameraMode::fixed(moved)), 1, now)
        .unwrap();
    // Many changes before one barrier make one state, and none is lost.
    for ao in 1..=999u32 {
        c.queue_change(StateChange::AoSamples(ao % 7), 1 + ao as u64, now)
            .unwrap();
    }
    // A change the budget refuses is refused now, at the caller, and queues nothing.
    c.queue_change(StateChange::Spp(4096), 0, now).unwrap();
    assert!(c
        .queue_change(StateChange::AoSamples(1024), 0, now)
        .is_err());
    c.queue_change(StateChange::Spp(1), 1001, now).unwrap();
    // Nothing is re-broadcast for the frame in flight.
    assert!(drain(&mut c).is_empty());
    let starts = |outs: &[Output]| -> Vec<FrameStart> {
        outs.iter()
            .filter_map(|o| match o {
                Output::ToDisplays(ToNode::FrameStart(s)) => Some(*s),
                _ => None,
            })
            .collect()
    };
    assert_ne!(starts(&first)[0].camera, moved);
    let mut outs = first;
    for _ in 0..10 {
        let mine = assigned_to(&outs, RenderNodeId(0));
        c.handle_tiles_done(RenderNodeId(0), FrameId(0), &mine, true, now)
            .unwrap();
        outs = drain(&mut c);
        if let Some(next) = starts(&outs).first() {
            assert_eq!(next.frame, FrameId(1));
            assert_eq!(next.camera, moved);
            assert_eq!(next.params.ao_samples(), 999 % 7);
            assert_eq!(next.state, StateId(1));
            let applied: Vec<_> = outs
                .iter()
                .filter_map(|o| match o {
                    Output::StateApplied {
                        changes, stamps, ..
                    } => Some((*changes, stamps.len())),
                    _ => None,
                })
                .collect();
            assert_eq!(applied, [(1002, 1002)], "1002 changes, one state");
            return;
        }
    }
    panic!("frame 1 never started");
}

#[test]
fn hostile_reports_are_errors_not_panics() {
    let mut c = coordinator(10, 2, 2);
    let now = Instant::now();
    c.handle_render_joined(RenderNodeId(0), now);
    c.handle_render_joined(RenderNodeId(1), now);
    c.start(now);
    let _ = drain(&mut c);
    // Node 0 owns tiles 0..3 statically; tile 7 belongs to node 1.
    assert!(matches!(
        c.handle_tiles_done(
            RenderNodeId(0),
            FrameId(0),
            &[TileRange::new(7, 8).unwrap()],
            false,
            now
        ),
        Err(BalanceError::NotAssigned { .. })
    ));
    assert!(c
        .handle_tiles_done(
            RenderNodeId(0),
            FrameId(0),
            &[TileRange::new(9, 4_000_000).unwrap()],
            false,
            now
        )
        .is_err());
    assert!(c
        .handle_tiles_done(RenderNodeId(9), FrameId(0), &[], false, now)
        .is_err());
    assert!(c
        .handle_tiles_done(RenderNodeId(0), FrameId(5), &[], false, now)
        .is_err());
    assert!(c
        .handle_frame_complete(DisplayId(2), FrameId(0), now)
        .is_err());
    assert!(c
        .handle_frame_complete(DisplayId(0), FrameId(9), now)
        .is_err());
}

#[test]
fn losing_every_render_node_is_reported_as_a_stall() {
    let mut c = coordinator(10, 1, 2);
    let now = Instant::now();
    c.handle_render_joined(RenderNodeId(0), now);
    c.start(now);
    let _ = drain(&mut c);
    c.handle_render_left(RenderNodeId(0), now);
    assert!(drain(&mut c).contains(&Output::Stalled));
}

#[test]
fn the_next_frame_starts_when_every_tile_is_handed_out_not_when_the_last_is_rendered() {
    let mut c = coordinator(8, 1, 5);
    let now = Instant::now();
    for n in 0..2 {
        c.handle_render_joined(RenderNodeId(n), now);
    }
    c.start(now);
    let first = drain(&mut c);
    assert!(first.contains(&Output::FrameStarted(FrameId(0))));
    // Node 0 takes the pool batch by batch without reporting any tile rendered.
    let mut outs = Vec::new();
    for _ in 0..8 {
        c.handle_tiles_done(RenderNodeId(0), FrameId(0), &[], true, now)
            .unwrap();
        outs = drain(&mut c);
        if outs.contains(&Output::FrameStarted(FrameId(1))) {
            break;
        }
    }
    assert!(
        outs.contains(&Output::FrameStarted(FrameId(1))),
        "frame 1 did not start once frame 0's pool was empty"
    );
    // Frame 0 is neither rendered nor presented: no third frame however much is asked for.
    for _ in 0..16 {
        c.handle_tiles_done(RenderNodeId(1), FrameId(0), &[], true, now)
            .unwrap();
        assert!(!drain(&mut c).contains(&Output::FrameStarted(FrameId(2))));
    }
}

#[test]
fn while_someone_steers_the_next_frame_waits_for_the_rendered_one_or_carries_a_change() {
    let now = Instant::now();
    let held = |hold_while_steering: bool| {
        let mut c = coordinator(8, 1, 10);
        c.config.hold_while_steering = hold_while_steering;
        c.handle_render_joined(RenderNodeId(0), now);
        // Someone steered: frame 0 starts with the change.
        c.queue_change(StateChange::Spp(2), 1, now).unwrap();
        c.start(now);
        let _ = drain(&mut c);
        // Node 0 takes frame 0's whole pool, rendering none of it yet.
        for _ in 0..8 {
            c.handle_tiles_done(RenderNodeId(0), FrameId(0), &[], true, now)
                .unwrap();
        }
        let _ = drain(&mut c);
        c
    };
    let mut c = held(true);
    assert_eq!(c.frames_in_flight(), 1, "frame 1 waits for the next change");
    c.queue_change(StateChange::Spp(1), 2, now).unwrap();
    assert_eq!(
        c.frames_in_flight(),
        2,
        "a waiting change starts it at once"
    );
    assert_eq!(
        held(false).frames_in_flight(),
        2,
        "pipelined as always when asked"
    );
}

#[test]
fn a_change_drops_the_refinement_pass_in_flight_and_starts_its_frame_at_once() {
    let now = Instant::now();
    let mut c = coordinator(8, 1, 10);
    // Refining from the first frame: frame 0 is a pass of twice the samples.
    c.set_refinement(Some(Refinement::new(0, 8, 0).unwrap()));
    c.handle_render_joined(RenderNodeId(0), now);
    c.start(now);
    let first = drain(&mut c);
    assert!(first.contains(&Output::FrameStarted(FrameId(0))));
    c.queue_change(StateChange::Shadows(false), 1, now).unwrap();
    let out = drain(&mut c);
    assert!(
        out.iter().any(|o| matches!(
            o,
            Output::FrameCancelled {
                frame: FrameId(0),
                refinement: true,
                ..
            }
        )),
        "the stale pass is dropped: {out:?}"
    );
    assert!(
        out.contains(&Output::FrameStarted(FrameId(1))),
        "the change's frame starts at once"
    );
    // A frame at the state's own quality is not dropped by a change.
    let mut plain = coordinator(8, 1, 10);
    plain.handle_render_joined(RenderNodeId(0), now);
    plain.start(now);
    let _ = drain(&mut plain);
    plain
        .queue_change(StateChange::Shadows(false), 1, now)
        .unwrap();
    let out = drain(&mut plain);
    assert!(
        !out.iter()
            .any(|o| matches!(o, Output::FrameCancelled { .. })),
        "{out:?}"
    );
}

#[test]
fn a_node_that_joins_mid_frame_gets_the_start_and_an_empty_share() {
    let mut c = coordinator(40, 1, 2);
    let now = Instant::now();
    c.handle_render_joined(RenderNodeId(0), now);
    c.start(now);
    let _ = drain(&mut c);
    c.handle_render_joined(RenderNodeId(1), now);
    let out = drain(&mut c);
    let to_late: Vec<&ToNode> = out
        .iter()
        .filter_map(|o| match o {
            Output::ToRender(RenderNodeId(1), msg) => Some(msg),
            _ => None,
        })
        .collect();
    assert!(matches!(to_late[0], ToNode::FrameStart(s) if s.frame == FrameId(0)));
    assert_eq!(
        to_late[1],
        &ToNode::Assign {
            frame: FrameId(0),
            tiles: Vec::new()
        }
    );
    // Its first request is served from the pool.
    c.handle_tiles_done(RenderNodeId(1), FrameId(0), &[], true, now)
        .unwrap();
    assert!(!assigned_to(&drain(&mut c), RenderNodeId(1)).is_empty());
}

fn assigned_in(outputs: &[Output], node: RenderNodeId, frame: FrameId) -> Vec<TileRange> {
    outputs
        .iter()
        .filter_map(|o| match o {
            Output::ToRender(n, ToNode::Assign { frame: f, tiles })
                if *n == node && *f == frame =>
            {
                Some(tiles.clone())
            }
            _ => None,
        })
        .flatten()
        .collect()
}

#[test]
fn a_node_that_renders_more_of_a_frame_gets_a_larger_static_share_later() {
    let mut c = coordinator(100, 1, 4);
    let now = Instant::now();
    let (fast, slow) = (RenderNodeId(0), RenderNodeId(1));
    c.handle_render_joined(fast, now);
    c.handle_render_joined(slow, now);
    c.start(now);
    let mut out = drain(&mut c);
    let count = |tiles: &[TileRange]| tiles.iter().map(|r| r.len()).sum::<usize>();
    assert_eq!(count(&assigned_in(&out, fast, FrameId(0))), 25);
    assert_eq!(count(&assigned_in(&out, slow, FrameId(0))), 25);
    // The slow node renders only its static shares; the fast one everything else. The display
    // reports a frame complete once every tile of it is rendered.
    let mut second_frame_share = None;
    let mut rendered = [0; 3];
    for _ in 0..200 {
        for frame in (0..3).map(FrameId) {
            for node in [slow, fast] {
                let tiles = assigned_in(&out, node, frame);
                if !tiles.is_empty() {
                    c.handle_tiles_done(node, frame, &tiles, false, now)
                        .unwrap();
                    rendered[frame.0 as usize] += count(&tiles);
                }
            }
            if rendered[frame.0 as usize] == 100 {
                c.handle_frame_complete(DisplayId(0), frame, now).unwrap();
            }
        }
        c.handle_tiles_done(fast, FrameId(0), &[], true, now)
            .unwrap();
        out = drain(&mut c);
        if out.contains(&Output::FrameStarted(FrameId(2))) {
            second_frame_share = Some((
                count(&assigned_in(&out, fast, FrameId(2))),
                count(&assigned_in(&out, slow, FrameId(2))),
            ));
            break;
        }
    }
    let (fast_share, slow_share) = second_frame_share.expect("frame 2 started");
    // Frame 0 went 75 : 25, so the static half of frame 2 follows suit (each half rounded).
    assert!(
        (50..=51).contains(&(fast_share + slow_share)),
        "{fast_share} + {slow_share}"
    );
    assert!(fast_share >= 2 * slow_share, "{fast_share} : {slow_share}");
}

/// Renders and presents every frame the coordinator starts, with one node and one display,
/// until it starts no more or `limit` frames; returns the frame starts in order.
fn run_frames(c: &mut Coordinator, limit: usize, now: Instant) -> Vec<FrameStart> {
    let node = RenderNodeId(0);
    let mut starts = Vec::new();
    let mut outs = drain(c);
    for _ in 0..limit * 20 {
        for o in &outs {
            if let Output::ToDisplays(ToNode::FrameStart(s)) = o {
                starts.push(*s);
            }
        }
        let mine = assigned_to(&outs, node);
        let frames: Vec<FrameId> = outs
            .iter()
            .filter_map(|o| match o {
                Output::ToRender(_, ToNode::Assign { frame, tiles }) if !tiles.is_empty() => {
                    Some(*frame)
                }
                _ => None,
            })
            .collect();
        let Some(&frame) = frames.first() else {
            break;
        };
        c.handle_tiles_done(node, frame, &mine, true, now).unwrap();
        c.handle_frame_complete(DisplayId(0), frame, now).unwrap();
        outs = drain(c);
        if starts.len() >= limit {
            break;
        }
    }
    starts
}

#[test]
fn a_still_view_refines_to_the_final_quality_then_renders_nothing_until_a_change() {
    let now = Instant::now();
    let mut c = coordinator(3, 1, 1_000);
    c.set_frame_limit(None);
    c.set_refinement(Some(Refinement::new(2, 4, 2).unwrap()));
    c.handle_render_joined(RenderNodeId(0), now);
    c.start(now);
    let starts = run_frames(&mut c, 50, now);
    let quality: Vec<(u32, u32)> = starts
        .iter()
        .map(|s| (s.params.spp(), s.params.ao_samples()))
        .collect();
    assert_eq!(
        quality,
        [(1, 0), (1, 0), (2, 2), (4, 2)],
        "two still frames, two passes, then nothing"
    );
    assert_eq!(c.next_frame(), FrameId(4));
    // A change renders again, interactive first.
    c.queue_change(StateChange::Shadows(false), 1, now).unwrap();
    let starts = run_frames(&mut c, 2, now);
    assert_eq!(starts[0].frame, FrameId(4));
    assert!(!starts[0].params.shadows() && starts[0].params.spp() == 1);
}
