//! Runaway frames cancelled, ordinary ones not: on a virtual clock.

use super::tests::{assigned_to, coordinator, drain};
use super::*;
use tessera_model::state::StateChange;

/// A one-node, one-display wall that has presented `frames` frames of 10 ms each; returns
/// the time after the last present and what is assigned now.
fn warmed_up(c: &mut Coordinator, node: RenderNodeId, t0: Instant, frames: u64) -> Instant {
    c.handle_render_joined(node, t0);
    c.start(t0);
    let mut out = drain(c);
    let mut now = t0;
    for f in 0..frames {
        let frame = FrameId(f);
        now += Duration::from_millis(10);
        loop {
            let mine: Vec<_> = assigned_to(&out, node);
            let ours: Vec<_> = out
                .iter()
                .filter_map(|o| match o {
                    Output::ToRender(_, ToNode::Assign { frame: af, tiles }) if *af == frame => {
                        Some(tiles.clone())
                    }
                    _ => None,
                })
                .flatten()
                .collect();
            if mine.is_empty() || ours.is_empty() {
                break;
            }
            c.handle_tiles_done(node, frame, &ours, true, now).unwrap();
            out = drain(c);
        }
        c.handle_frame_complete(DisplayId(0), frame, now).unwrap();
        out = drain(c);
    }
    now
}

fn cancelled(out: &[Output]) -> Vec<FrameId> {
    out.iter()
        .filter_map(|o| match o {
            Output::FrameCancelled { frame, .. } => Some(*frame),
            _ => None,
        })
        .collect()
}

#[test]
fn a_stale_frame_running_far_longer_than_the_others_is_cancelled_and_never_shown() {
    let node = RenderNodeId(0);
    let mut c = coordinator(8, 1, 1_000);
    let now = warmed_up(&mut c, node, Instant::now(), 5);
    // Frame 5 is in flight and its tiles never come back (a runaway quality).
    // Nothing is stale yet: nothing is cancelled, however long they run.
    let later = now + Duration::from_millis(1_100);
    c.handle_heartbeat(node, later).unwrap();
    c.handle_display_heartbeat(DisplayId(0), later);
    c.handle_timeout(later);
    assert!(cancelled(&drain(&mut c)).is_empty());
    // A correction is queued: the frames in flight are stale now, and past their time
    // (eight times the 10 ms frames before, at least a second).
    c.queue_change(StateChange::Spp(1), 0, later).unwrap();
    assert_eq!(c.poll_timeout(), Some(now + MIN_RUNAWAY));
    c.handle_timeout(later);
    let out = drain(&mut c);
    let gone = cancelled(&out);
    assert_eq!(gone, [FrameId(5)], "{out:?}");
    assert!(out.contains(&Output::ToDisplays(ToNode::Cancel { frame: FrameId(5) })));
    assert!(out.contains(&Output::ToRender(
        node,
        ToNode::Cancel { frame: FrameId(5) }
    )));
    assert!(
        !out.iter().any(|o| matches!(
            o,
            Output::FramePresented(_) | Output::ToDisplays(ToNode::Present { .. })
        )),
        "a cancelled frame is never presented: {out:?}"
    );
    // The next frame starts at once, with the correction.
    assert!(out.contains(&Output::FrameStarted(FrameId(6))), "{out:?}");
    assert!(out
        .iter()
        .any(|o| matches!(o, Output::StateApplied { frame, .. } if *frame == FrameId(6))));
}

#[test]
fn a_stale_frame_within_its_usual_time_is_left_to_finish() {
    let node = RenderNodeId(0);
    let mut c = coordinator(8, 1, 1_000);
    let now = warmed_up(&mut c, node, Instant::now(), 5);
    c.queue_change(StateChange::Spp(1), 0, now).unwrap();
    // Continuous motion: the frame in flight is stale but no slower than the others.
    c.handle_timeout(now + Duration::from_millis(900));
    assert!(cancelled(&drain(&mut c)).is_empty());
}

#[test]
fn an_interrupt_cancels_what_has_not_finished_after_its_grace() {
    let node = RenderNodeId(0);
    let mut c = coordinator(8, 1, 1_000);
    let now = warmed_up(&mut c, node, Instant::now(), 5);
    c.interrupt(now);
    c.handle_timeout(now + INTERRUPT_GRACE - Duration::from_millis(1));
    assert!(cancelled(&drain(&mut c)).is_empty(), "within its grace");
    c.handle_timeout(now + INTERRUPT_GRACE);
    let out = drain(&mut c);
    assert_eq!(cancelled(&out), [FrameId(5)]);
    assert!(out.contains(&Output::Finished), "{out:?}");
}
