//! Simulated walls that exercise the master's own decisions on a virtual clock: displays that
//! leave and rejoin under each policy, many control changes between two barriers, a shared
//! scene's ranks after a holder dies, and a refused change.

use super::*;
use crate::master::RunError;
use glam::Vec3;
use tessera_model::camera::{Camera, CameraMode};
use tessera_protocol::control::Refusal;
use tessera_protocol::dsm::DsmSpec;

fn two_displays() -> WallLayout {
    WallSpec::grid(2, 1, 256, 144)
        .tile_size(32)
        .build()
        .unwrap()
}

fn with_policy(display_loss: DisplayLoss) -> SimConfig {
    SimConfig {
        display_loss,
        ..SimConfig::new(4)
    }
}

/// Frames display 0 presented that display 1 did not.
fn missed_by_display_1(sim: &SimWall) -> Vec<FrameId> {
    let shown: Vec<FrameId> = sim.presented(DisplayId(1)).to_vec();
    sim.presented(DisplayId(0))
        .iter()
        .filter(|f| !shown.contains(f))
        .copied()
        .collect()
}

#[test]
fn a_display_that_rejoins_a_wall_going_on_shows_every_frame_from_its_first() {
    let mut sim = SimWall::with_config(3, two_displays(), &with_policy(DisplayLoss::GoOn));
    sim.display_leaves_at(DisplayId(1), FrameId(3), Some(30_000));
    assert_eq!(sim.run_frames(30), 30);
    let all: Vec<FrameId> = (0..30).map(FrameId).collect();
    assert_eq!(
        sim.presented(DisplayId(0)),
        &all[..],
        "the other display goes on"
    );
    let missed = missed_by_display_1(&sim);
    assert!(missed.len() >= 3, "30 ms away misses frames: {missed:?}");
    let back = sim
        .presented(DisplayId(1))
        .iter()
        .position(|f| f.0 > 3)
        .unwrap();
    let after: Vec<FrameId> = sim.presented(DisplayId(1))[back..].to_vec();
    let first = after[0].0;
    assert_eq!(after, (first..30).map(FrameId).collect::<Vec<_>>());
    assert!(sim.corrupt_frames().is_empty());
    let report = sim.take_outcome().expect("over").expect("a report");
    assert_eq!(report.displays_lost, 1);
    assert_eq!(report.frames_short_of_displays, missed.len() as u64);
    let lost: Vec<&str> = report.nodes_lost.iter().map(|l| l.node.as_str()).collect();
    assert_eq!(lost.len(), 1, "{:?}", report.nodes_lost);
    assert!(lost[0].starts_with("display 1 ("), "{lost:?}");
}

#[test]
fn a_killed_render_node_is_named_in_the_report_as_the_log_names_it() {
    let mut sim = SimWall::with_config(3, two_displays(), &SimConfig::new(3));
    sim.kill_at(RenderNodeId(1), FrameId(3));
    // Well past the master's finding it silent past its deadline (300 ms; a frame ~5 ms).
    assert_eq!(sim.run_frames(200), 200);
    let report = sim.take_outcome().expect("over").expect("a report");
    assert_eq!(report.render_nodes_lost, 1);
    let lost: Vec<&str> = report.nodes_lost.iter().map(|l| l.node.as_str()).collect();
    assert_eq!(lost.len(), 1, "{:?}", report.nodes_lost);
    assert!(lost[0].starts_with("render node 1 ("), "{lost:?}");
    assert!(!report.nodes_lost[0].reason.is_empty());
}

#[test]
fn a_wall_that_waits_for_a_lost_display_starts_no_frame_without_it() {
    let mut sim = SimWall::with_config(3, two_displays(), &with_policy(DisplayLoss::Wait));
    sim.display_leaves_at(DisplayId(1), FrameId(3), Some(30_000));
    assert_eq!(sim.run_frames(30), 30);
    let all: Vec<FrameId> = (0..30).map(FrameId).collect();
    assert_eq!(sim.presented(DisplayId(0)), &all[..]);
    // Only the frames already in flight when it left go on without it.
    let missed = missed_by_display_1(&sim);
    assert!(
        (1..=2).contains(&missed.len()),
        "frames in flight only: {missed:?}"
    );
    assert!(sim.corrupt_frames().is_empty());
    let report = sim.take_outcome().expect("over").expect("a report");
    assert_eq!(report.displays_lost, 1);
}

#[test]
fn a_wall_that_stops_for_a_lost_display_ends_naming_it() {
    let mut sim = SimWall::with_config(3, two_displays(), &with_policy(DisplayLoss::Stop));
    sim.display_leaves_at(DisplayId(1), FrameId(3), Some(30_000));
    let presented = sim.run_frames(30);
    assert!(presented < 30, "{presented} frames");
    match sim.take_outcome() {
        Some(Err(RunError::DisplayLost { who, .. })) => assert!(who.starts_with("display 1")),
        other => panic!("the run should end with the lost display, not {other:?}"),
    }
}

fn camera(client: u32, k: u32) -> CameraMode {
    let eye = Vec3::new(client as f32, k as f32 * 0.01, 5.0);
    CameraMode::fixed(Camera::new(eye, Vec3::ZERO, Vec3::Y, 45.0).unwrap())
}

#[test]
fn a_thousand_changes_from_two_controllers_between_barriers_all_land_and_the_last_wins() {
    let mut sim = SimWall::with_config(5, two_displays(), &SimConfig::new(4));
    for k in 0..500 {
        for client in 0..2 {
            let change = StateChange::Camera(camera(client, k));
            sim.control_at(FrameId(2), client, ControlRequest::Change(vec![change]));
        }
    }
    assert_eq!(sim.run_frames(12), 12);
    let answers = sim.control_answers();
    assert_eq!(answers.len(), 1000, "every request answered");
    assert!(answers
        .iter()
        .all(|a| matches!(a.reply, ControlReply::Queued { changes: 1, .. })));
    assert_eq!(sim.changes_applied(), 1000, "none lost");
    // Each client's requests arrive in order; the last to arrive of either is the camera now.
    let now = sim.master().next_state().camera;
    assert!(
        now == camera(0, 499) || now == camera(1, 499),
        "the latest camera wins: {now:?}"
    );
    assert!(sim.corrupt_frames().is_empty());
}

#[test]
fn a_change_with_a_bad_value_is_refused_without_touching_the_state() {
    let mut sim = SimWall::with_config(5, two_displays(), &SimConfig::new(2));
    let changes = vec![StateChange::Spp(2), StateChange::Spp(0)];
    sim.control_at(FrameId(2), 0, ControlRequest::Change(changes));
    assert_eq!(sim.run_frames(8), 8);
    match sim.control_answers() {
        [answer] => assert!(
            matches!(
                answer.reply,
                ControlReply::Refused(Refusal::BadChange {
                    index: 2,
                    count: 2,
                    ..
                })
            ),
            "{answer:?}"
        ),
        other => panic!("one answer expected: {other:?}"),
    }
    assert_eq!(sim.changes_applied(), 0);
    let states: std::collections::BTreeSet<StateId> =
        sim.frame_states().values().copied().collect();
    assert_eq!(
        states.len(),
        1,
        "every frame in the first state: {states:?}"
    );
}

#[test]
fn a_dead_holders_rank_goes_to_the_next_render_node_to_join() {
    let shared = DsmSpec {
        dir: "prepared".into(),
        block_bytes: 8192,
        ranks: 2,
        replicas: 1,
        memory_budget: None,
        cache_fraction: None,
    };
    let config = SimConfig {
        data: DataSpec::Dsm(shared),
        ..SimConfig::new(3)
    };
    let mut sim = SimWall::with_config(9, two_displays(), &config);
    sim.kill_at(RenderNodeId(0), FrameId(3));
    // Well after the master found it dead (its heartbeats' rhythm plus the acceptable pause,
    // about 3.6 s; a frame takes ~5 ms). Suspected, it kept its rank.
    sim.render_node_joins_at(FrameId(1000));
    assert_eq!(sim.run_frames(1100), 1100);
    assert!(sim.virtual_time() > Duration::from_secs(4));
    let ranks = sim.ranks();
    assert_eq!(ranks.get(&RenderNodeId(1)), Some(&Some(1)));
    assert_eq!(ranks.get(&RenderNodeId(2)), Some(&None), "two ranks, held");
    assert_eq!(
        ranks.get(&RenderNodeId(3)),
        Some(&Some(0)),
        "the newcomer takes the dead holder's rank"
    );
    assert!(sim.corrupt_frames().is_empty());
}
