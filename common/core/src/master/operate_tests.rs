//! The console's side of the master without a network: a still wall snapshots what it shows
//! and answers once the files are written, a final snapshot waits for the last pass, a series
//! plays on its own clock, figures tell rest from rendering, and a change's answer names the
//! state and frame that carry it.

use super::tests::{at, join};
use super::*;
use crate::balance::Refinement;
use tessera_protocol::control::{ControlReply, ControlRequest, Playback};

const DISPLAY: PeerId = PeerId(1);
const RENDER: PeerId = PeerId(2);
const CONTROL: PeerId = PeerId(3);

/// A one-display, one-tile wall with a fixed camera that refines to 4 spp after one still
/// frame, its display, render node and a control client joined and ready at `base`.
fn still_wall(base: Instant, operator: OperatorConfig) -> Master {
    let wall = tessera_model::wall::WallSpec::grid(1, 1, 32, 32)
        .tile_size(32)
        .build()
        .unwrap();
    let camera = tessera_model::camera::Camera::new(
        glam::Vec3::Z * 3.0,
        glam::Vec3::ZERO,
        glam::Vec3::Y,
        45.0,
    )
    .unwrap();
    let cfg = MasterConfig {
        refinement: Some(Refinement::new(1, 4, 0).unwrap()),
        camera: CameraMode::fixed(camera),
        frames: None,
        operator,
        ..MasterConfig::new(wall, 1)
    };
    let mut master = Master::new(cfg, at(base, 0)).unwrap();
    let display = Role::Display {
        display: DisplayId(0),
        pixel_addr: "0.0.0.0:9100".parse().unwrap(),
    };
    master.handle_join(join(DISPLAY.0, display), at(base, 0));
    master.handle_join(join(RENDER.0, Role::Render { cores: 1 }), at(base, 0));
    master.handle_join(join(CONTROL.0, Role::Control), at(base, 0));
    master.handle_message(DISPLAY, FromNode::Ready, at(base, 0));
    master.handle_message(RENDER, FromNode::Ready, at(base, 0));
    master
}

/// Plays the render node and display for what the master sent, at `ms`, until it sends
/// nothing more; returns what it sent the display and the control client.
fn play(master: &mut Master, base: Instant, ms: u64) -> Vec<Transmit> {
    let mut kept = Vec::new();
    for _ in 0..1000 {
        let Some(t) = master.poll_transmit() else {
            return kept;
        };
        let now = at(base, ms);
        match (&t.msg, t.peer) {
            (ToNode::Assign { frame, tiles }, RENDER) if !tiles.is_empty() => {
                let done = FromNode::TilesDone {
                    frame: *frame,
                    tiles: tiles.clone(),
                    want_more: true,
                };
                master.handle_message(RENDER, done, now);
                let complete = FromNode::FrameComplete { frame: *frame };
                master.handle_message(DISPLAY, complete, now);
            }
            (ToNode::Present { frame }, DISPLAY) => {
                let shown = FromNode::Presented {
                    frame: *frame,
                    clock_ns: now.unix_ns,
                };
                master.handle_message(DISPLAY, shown, now);
            }
            (_, DISPLAY | CONTROL) => kept.push(t),
            _ => {}
        }
    }
    panic!("the master never stopped sending");
}

fn ask(master: &mut Master, base: Instant, ms: u64, request: ControlRequest) -> ControlReply {
    master.handle_local_control(request, at(base, ms))
}

#[test]
fn a_still_wall_saves_what_it_shows_and_a_client_hears_once_the_files_are_written() {
    let base = Instant::now();
    let mut master = still_wall(base, OperatorConfig::default());
    play(&mut master, base, 10);
    assert!(
        master.coordinator.is_converged(),
        "refined to the final pass"
    );
    let shown = master.coordinator.presented() - 1;
    let figures = ask(&mut master, base, 5_000, ControlRequest::Figures);
    let ControlReply::Figures(f) = figures else {
        panic!("{figures:?}")
    };
    assert!(f.idle, "a converged wall rests");
    assert!(
        f.rendering_s < 1.0,
        "its rest is not rendering: {}",
        f.rendering_s
    );

    let request = FromNode::Control {
        id: 7,
        request: ControlRequest::Snapshot {
            final_quality: false,
        },
        stamp_ns: 0,
    };
    master.handle_message(CONTROL, request, at(base, 5_000));
    let sent = play(&mut master, base, 5_000);
    let to_display: Vec<&ToNode> = sent
        .iter()
        .filter(|t| t.peer == DISPLAY)
        .map(|t| &t.msg)
        .collect();
    assert_eq!(
        to_display,
        [&ToNode::SaveShown {
            frame: FrameId(shown)
        }]
    );
    assert!(
        sent.iter().all(|t| t.peer != CONTROL),
        "no answer before the files exist"
    );

    let saved = FromNode::Saved {
        frame: FrameId(shown),
        ok: true,
    };
    master.handle_message(DISPLAY, saved, at(base, 5_100));
    let sent = play(&mut master, base, 5_100);
    let answer = ToNode::ControlReply {
        id: 7,
        reply: ControlReply::Snapshot {
            frame: shown,
            shown: true,
        },
    };
    assert!(
        sent.iter().any(|t| t.peer == CONTROL && t.msg == answer),
        "{sent:?}"
    );
    assert_eq!(
        master.poll_console(),
        Some(ConsoleEvent::SnapshotSaved {
            frame: FrameId(shown),
            displays: vec![(DisplayId(0), true)],
        })
    );
}

#[test]
fn a_final_snapshot_waits_for_the_last_pass_and_an_orbit_never_gets_one() {
    let base = Instant::now();
    let mut master = still_wall(base, OperatorConfig::default());
    // A change restarts refinement; the snapshot asked now takes its final pass.
    let reply = ask(
        &mut master,
        base,
        0,
        ControlRequest::Change(vec![StateChange::Spp(1)]),
    );
    assert!(matches!(reply, ControlReply::Queued { .. }), "{reply:?}");
    let reply = ask(
        &mut master,
        base,
        0,
        ControlRequest::Snapshot {
            final_quality: true,
        },
    );
    assert!(
        matches!(reply, ControlReply::Snapshot { shown: false, .. }),
        "{reply:?}"
    );
    let sent = play(&mut master, base, 10);
    let saves: Vec<FrameId> = sent
        .iter()
        .filter_map(|t| match t.msg {
            ToNode::SaveFrame { frame } => Some(frame),
            _ => None,
        })
        .collect();
    let last = FrameId(master.coordinator.presented() - 1);
    assert_eq!(saves, [last], "only the converged frame is saved");

    let orbit = CameraMode::orbit(glam::Vec3::ZERO, 3.0, 45.0).unwrap();
    ask(
        &mut master,
        base,
        20,
        ControlRequest::Change(vec![StateChange::Camera(orbit)]),
    );
    let reply = ask(
        &mut master,
        base,
        20,
        ControlRequest::Snapshot {
            final_quality: true,
        },
    );
    assert_eq!(reply, ControlReply::Refused(Refusal::NeverStill));
}

#[test]
fn a_series_plays_on_its_own_clock_steps_and_refuses_what_does_not_apply() {
    let base = Instant::now();
    let series = OperatorConfig {
        series_steps: Some(4),
        ..OperatorConfig::default()
    };
    let mut master = still_wall(base, series);
    play(&mut master, base, 10);
    let step = |m: &Master| m.coordinator.next_state().params.volume().time_step;
    let play_at = |speed| {
        ControlRequest::Playback(Playback {
            playing: Some(true),
            steps_per_second: speed,
            step_by: None,
        })
    };
    let reply = ask(&mut master, base, 100, play_at(Some(2.0)));
    assert_eq!(reply, ControlReply::Done);
    assert_eq!(
        master.series_timer(),
        Some(base + Duration::from_millis(600))
    );
    master.handle_timeout(at(base, 600));
    assert_eq!(step(&master), 1, "a step after half a second");
    play(&mut master, base, 600);
    master.handle_timeout(at(base, 1_100));
    assert_eq!(step(&master), 2);

    let back = ControlRequest::Playback(Playback {
        step_by: Some(-3),
        ..Playback::default()
    });
    assert!(matches!(
        ask(&mut master, base, 1_200, back),
        ControlReply::Queued { .. }
    ));
    assert_eq!(step(&master), 3, "2 - 3 wraps round 4 steps");
    assert_eq!(master.series_timer(), None, "a step pauses");

    let fast = ask(&mut master, base, 1_300, play_at(Some(500.0)));
    assert_eq!(fast, ControlReply::Refused(Refusal::BadSpeed(500.0)));
    let mut volume = *master.coordinator.next_state().params.volume();
    volume.time_step = 4;
    let outside = ask(
        &mut master,
        base,
        1_300,
        ControlRequest::Change(vec![StateChange::Volume(volume)]),
    );
    assert!(
        matches!(&outside, ControlReply::Refused(Refusal::BadChange { reason, .. }) if reason.contains("4 steps")),
        "{outside:?}"
    );

    let mut plain = still_wall(base, OperatorConfig::default());
    let none = ask(&mut plain, base, 0, play_at(None));
    assert_eq!(none, ControlReply::Refused(Refusal::NoSeries));
}

#[test]
fn volume_changes_a_scene_cannot_take_are_refused_naming_why() {
    let base = Instant::now();
    let mut mesh = still_wall(base, OperatorConfig::default());
    let mut volume = *mesh.coordinator.next_state().params.volume();
    volume.iso = tessera_model::volume_params::IsoValues::new(&[300.0]).unwrap();
    let iso = ask(
        &mut mesh,
        base,
        0,
        ControlRequest::Change(vec![StateChange::Volume(volume)]),
    );
    assert!(
        matches!(&iso, ControlReply::Refused(Refusal::BadChange { reason, .. }) if reason.contains("no volume")),
        "{iso:?}"
    );
    let one = OperatorConfig {
        volume_range: Some([0.0, 1.0]),
        ..OperatorConfig::default()
    };
    let mut single = still_wall(base, one);
    let mut volume = *single.coordinator.next_state().params.volume();
    volume.time_step = 1000;
    let step = ask(
        &mut single,
        base,
        0,
        ControlRequest::Change(vec![StateChange::Volume(volume)]),
    );
    assert!(
        matches!(&step, ControlReply::Refused(Refusal::BadChange { reason, .. }) if reason.contains("not a series")),
        "{step:?}"
    );
    volume.time_step = 0;
    volume.iso = tessera_model::volume_params::IsoValues::new(&[0.5]).unwrap();
    let fine = ask(
        &mut single,
        base,
        0,
        ControlRequest::Change(vec![StateChange::Volume(volume)]),
    );
    assert!(matches!(fine, ControlReply::Queued { .. }), "{fine:?}");
}

/// The (frame, state) of every frame start the display was sent.
fn starts(sent: &[Transmit]) -> Vec<(u64, u64)> {
    sent.iter()
        .filter_map(|t| match (&t.msg, t.peer) {
            (ToNode::FrameStart(s), DISPLAY) => Some((s.frame.0, s.state.0)),
            _ => None,
        })
        .collect()
}

#[test]
fn a_change_names_the_state_and_frame_that_carry_it_even_when_it_starts_one_at_once() {
    let base = Instant::now();
    let mut master = still_wall(base, OperatorConfig::default());
    play(&mut master, base, 10);
    assert!(master.coordinator.is_converged(), "a resting wall");
    let (rested, _) = master.coordinator.state();
    // A converged wall starts a frame with the change inside the request.
    let first = ask(
        &mut master,
        base,
        20,
        ControlRequest::Change(vec![StateChange::Spp(2)]),
    );
    // With that frame in flight, the next change waits for the next barrier.
    let second = ask(
        &mut master,
        base,
        20,
        ControlRequest::Change(vec![StateChange::Spp(3)]),
    );
    let sent = play(&mut master, base, 30);
    let [ControlReply::Queued {
        state_id: a,
        frame: fa,
        ..
    }, ControlReply::Queued {
        state_id: b,
        frame: fb,
        ..
    }] = [first.clone(), second.clone()]
    else {
        panic!("{first:?} {second:?}")
    };
    assert_eq!(a.0, rested.0 + 1, "{first:?}");
    assert_eq!(b.0, rested.0 + 2, "{second:?}");
    let starts = starts(&sent);
    for (frame, state) in [(fa, a.0), (fb, b.0)] {
        let first_with = starts.iter().find(|&&(_, s)| s == state);
        assert_eq!(first_with, Some(&(frame, state)), "{starts:?}");
    }
}
