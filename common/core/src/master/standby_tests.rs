//! A primary and its standby on a virtual clock: the standby's snapshot follows the
//! primary's, and a master that takes over starts past every frame and state of the old one,
//! with its camera.

use super::standby::{Replica, ReplicaAck, Standby, StandbyConfig, StandbyEvent};
use super::tests::{at, join};
use super::*;
use proptest::prelude::*;
use tessera_protocol::control::{ControlRequest, ViewName};
use tessera_protocol::{FrameStart, TileRange};

fn config() -> MasterConfig {
    let wall = tessera_model::wall::WallSpec::grid(1, 1, 64, 64)
        .tile_size(32)
        .build()
        .unwrap();
    MasterConfig::new(wall, 1)
}

fn display_role() -> Role {
    Role::Display {
        display: DisplayId(0),
        pixel_addr: "0.0.0.0:9100".parse().unwrap(),
    }
}

/// What a test does to the wall at one step.
#[derive(Clone, Debug)]
enum Step {
    /// The render node reports every tile it holds done.
    Render,
    /// The display says it has every tile of the frames rendered.
    Complete,
    /// The display says it presented what it was told to.
    Present,
    /// A control client moves the camera to the `i`th place.
    Camera(u8),
    /// A control client saves the view under the `i`th name.
    SaveView(u8),
    /// A control client turns the overlay on or off.
    Overlay(bool),
    /// `ms` pass, and the master's timer fires if due.
    Wait(u16),
    /// What is in flight between primary and standby arrives.
    Deliver,
}

fn step() -> impl Strategy<Value = Step> {
    prop_oneof![
        4 => Just(Step::Render),
        3 => Just(Step::Complete),
        3 => Just(Step::Present),
        2 => (0u8..4).prop_map(Step::Camera),
        1 => (0u8..3).prop_map(Step::SaveView),
        1 => any::<bool>().prop_map(Step::Overlay),
        1 => (1u16..200).prop_map(Step::Wait),
        2 => Just(Step::Deliver),
    ]
}

/// A primary, its standby, a display (peer 1) and a render node (peer 2), and what is in
/// flight between them.
struct Pair {
    base: Instant,
    ms: u64,
    primary: Master,
    standby: Standby,
    to_standby: Vec<Replica>,
    to_primary: Vec<ReplicaAck>,
    assigned: Vec<(FrameId, Vec<TileRange>)>,
    rendered: Vec<FrameId>,
    to_present: Vec<FrameId>,
    /// Every frame start the primary sent the display.
    starts: Vec<FrameStart>,
}

impl Pair {
    fn new() -> Pair {
        let base = Instant::now();
        let now = at(base, 0);
        let mut primary = Master::new(config(), now).unwrap();
        let standby = Standby::new(StandbyConfig::default(), now.instant);
        let first = primary.attach_standby(now);
        let mut pair = Pair {
            base,
            ms: 0,
            primary,
            standby,
            to_standby: vec![first],
            to_primary: Vec::new(),
            assigned: Vec::new(),
            rendered: Vec::new(),
            to_present: Vec::new(),
            starts: Vec::new(),
        };
        pair.primary.handle_join(join(1, display_role()), now);
        pair.primary
            .handle_join(join(2, Role::Render { cores: 1 }), now);
        pair.primary.handle_message(PeerId(1), FromNode::Ready, now);
        pair.primary.handle_message(PeerId(2), FromNode::Ready, now);
        pair.drain();
        pair.deliver();
        pair
    }

    fn now(&self) -> Now {
        at(self.base, self.ms)
    }

    /// Collects what the primary sent, the standby's replicas held in flight.
    fn drain(&mut self) {
        while let Some(r) = self.primary.poll_replica() {
            self.to_standby.push(r);
        }
        while let Some(t) = self.primary.poll_transmit() {
            match t.msg {
                ToNode::Assign { frame, tiles } if !tiles.is_empty() => {
                    self.assigned.push((frame, tiles))
                }
                ToNode::FrameStart(start) if t.peer == PeerId(1) => self.starts.push(start),
                ToNode::Present { frame } => self.to_present.push(frame),
                _ => {}
            }
        }
        while let Some(event) = self.primary.poll_event() {
            if let MasterEvent::FrameRendered(frame) = event {
                self.rendered.push(frame);
            }
        }
        while self.primary.poll_close().is_some() {}
    }

    /// Everything in flight between the two arrives, until nothing more is.
    fn deliver(&mut self) {
        while !self.to_standby.is_empty() || !self.to_primary.is_empty() {
            let now = self.now();
            for r in std::mem::take(&mut self.to_standby) {
                self.standby.handle_replica(r, now.instant).unwrap();
            }
            self.standby.handle_heartbeat(now.instant);
            while let Some(ack) = self.standby.poll_ack() {
                self.to_primary.push(ack);
            }
            for ack in std::mem::take(&mut self.to_primary) {
                self.primary.handle_replica_ack(ack, now);
            }
            self.drain();
        }
    }

    fn apply(&mut self, step: &Step) {
        let now = self.now();
        match step {
            Step::Render => {
                for (frame, tiles) in std::mem::take(&mut self.assigned) {
                    let msg = FromNode::TilesDone {
                        frame,
                        tiles,
                        want_more: true,
                    };
                    self.primary.handle_message(PeerId(2), msg, now);
                }
            }
            Step::Complete => {
                for frame in std::mem::take(&mut self.rendered) {
                    let msg = FromNode::FrameComplete { frame };
                    self.primary.handle_message(PeerId(1), msg, now);
                }
            }
            Step::Present => {
                for frame in std::mem::take(&mut self.to_present) {
                    let clock_ns = now.unix_ns;
                    let msg = FromNode::Presented { frame, clock_ns };
                    self.primary.handle_message(PeerId(1), msg, now);
                }
            }
            Step::Camera(i) => {
                let change = StateChange::Camera(camera(*i));
                let request = ControlRequest::Change(vec![change]);
                self.primary.handle_local_control(request, now);
            }
            Step::SaveView(i) => {
                let name = ViewName::new(&format!("view-{i}")).unwrap();
                self.primary
                    .handle_local_control(ControlRequest::SaveView(name), now);
            }
            Step::Overlay(on) => {
                self.primary
                    .handle_local_control(ControlRequest::Overlay(*on), now);
            }
            Step::Wait(ms) => {
                self.ms += u64::from(*ms);
                // Both nodes keep beating: a wait is the clock, not a death.
                let now = self.now();
                self.primary
                    .handle_message(PeerId(2), FromNode::Heartbeat, now);
                self.primary
                    .handle_message(PeerId(1), FromNode::Heartbeat, now);
                if self
                    .primary
                    .poll_timeout()
                    .is_some_and(|t| t <= now.instant)
                {
                    self.primary.handle_timeout(now);
                }
            }
            Step::Deliver => self.deliver(),
        }
        self.drain();
    }
}

fn camera(i: u8) -> CameraMode {
    let eye = glam::Vec3::new(f32::from(i), 1.0, 5.0);
    CameraMode::fixed(Camera::new(eye, glam::Vec3::ZERO, glam::Vec3::Y, 45.0).unwrap())
}

/// The master that takes over from the standby, its nodes rejoined and ready, and the first
/// frame it starts.
fn take_over(pair: &mut Pair) -> (Master, FrameStart) {
    pair.ms += 10;
    let now = pair.now();
    pair.standby.handle_primary_closed(now.instant);
    let Some(StandbyEvent::TakeOver(snapshot)) = pair.standby.poll_event() else {
        panic!("the standby took over");
    };
    let mut master = Master::take_over(config(), *snapshot, now).unwrap();
    master.handle_join(join(11, display_role()), now);
    master.handle_join(join(12, Role::Render { cores: 1 }), now);
    master.handle_message(PeerId(11), FromNode::Ready, now);
    master.handle_message(PeerId(12), FromNode::Ready, now);
    let first = std::iter::from_fn(|| master.poll_transmit())
        .find_map(|t| match t.msg {
            ToNode::FrameStart(start) if t.peer == PeerId(11) => Some(start),
            _ => None,
        })
        .expect("the new master starts a frame once its nodes are ready");
    (master, first)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn the_standby_holds_the_primary_snapshot_after_any_events(
        steps in proptest::collection::vec(step(), 0..80)
    ) {
        let mut pair = Pair::new();
        for step in &steps {
            pair.apply(step);
            if pair.to_standby.is_empty() && pair.to_primary.is_empty() {
                let held = pair.standby.snapshot().cloned();
                prop_assert_eq!(held, Some(pair.primary.standby_snapshot()));
            }
        }
        pair.deliver();
        let held = pair.standby.snapshot().cloned();
        prop_assert_eq!(held, Some(pair.primary.standby_snapshot()));
    }

    #[test]
    fn a_takeover_at_any_point_starts_past_the_old_frames_with_the_camera(
        steps in proptest::collection::vec(step(), 0..80)
    ) {
        let mut pair = Pair::new();
        for step in &steps {
            pair.apply(step);
        }
        // The primary dies: what it had not delivered to its standby is lost.
        let camera_then = pair.primary.next_state().camera;
        let delivered = pair.to_standby.is_empty();
        let (master, first) = take_over(&mut pair);
        for old in &pair.starts {
            prop_assert!(first.frame > old.frame, "{first:?} after {old:?}");
            prop_assert!(first.state > old.state, "{first:?} after {old:?}");
        }
        prop_assert_eq!(master.term(), 1);
        if delivered {
            // The standby held the primary's last word: the camera is where it was.
            let expected = camera_then.camera_for_frame(first.frame.0);
            prop_assert_eq!(first.camera, expected);
        }
    }
}

#[test]
fn the_standby_never_takes_over_while_heartbeats_arrive_within_the_bound() {
    let base = Instant::now();
    let cfg = StandbyConfig {
        heartbeat_interval: Duration::from_millis(50),
        failure_bound: Duration::from_millis(500),
    };
    let mut standby = Standby::new(cfg, base);
    let snapshot = Pair::new().primary.standby_snapshot();
    standby
        .handle_replica(Replica::whole(snapshot.clone()), base)
        .unwrap();
    // Beats every 400 ms for a minute, the timer fired whenever asked and more often.
    for i in 1..=150u64 {
        let now = base + Duration::from_millis(400 * i);
        standby.handle_timeout(now);
        standby.handle_heartbeat(now);
        let due = standby.poll_timeout().expect("a timer while it waits");
        assert_eq!(due, now + cfg.failure_bound);
        standby.handle_timeout(due - Duration::from_millis(1));
        assert_eq!(standby.poll_event(), None, "beat {i}");
    }
    // Then silence: at the bound it takes over, with what it held, once.
    let last = base + Duration::from_millis(400 * 150);
    standby.handle_timeout(last + cfg.failure_bound);
    assert_eq!(
        standby.poll_event(),
        Some(StandbyEvent::TakeOver(Box::new(snapshot)))
    );
    assert!(standby.is_done());
    standby.handle_timeout(last + cfg.failure_bound * 2);
    assert_eq!(standby.poll_event(), None);
}

#[test]
fn a_replica_of_lines_the_standby_never_got_is_refused() {
    let base = Instant::now();
    let mut standby = Standby::new(StandbyConfig::default(), base);
    let mut replica = Replica::whole(Pair::new().primary.standby_snapshot());
    replica.session_from = 3;
    assert!(standby.handle_replica(replica, base).is_err());
    assert!(standby.snapshot().is_none());
}

#[test]
fn a_primary_with_a_standby_runs_no_further_than_it_acknowledged() {
    let mut pair = Pair::new();
    // Acknowledgements stop reaching the primary: it runs up to the horizon, then waits.
    let horizon = pair.standby.snapshot().unwrap().horizon;
    for _ in 0..400 {
        for step in [Step::Render, Step::Complete, Step::Present] {
            pair.apply(&step);
        }
    }
    let last = pair.starts.last().unwrap().frame;
    assert_eq!(last.0 + 1, horizon.0, "it ran to the horizon, no further");
    pair.deliver();
    pair.apply(&Step::Render);
    assert!(
        pair.starts.last().unwrap().frame >= horizon,
        "acknowledged, it goes on"
    );
}

#[test]
fn the_report_of_a_taken_over_run_covers_both_masters() {
    let mut pair = Pair::new();
    for _ in 0..40 {
        for step in [Step::Render, Step::Complete, Step::Present, Step::Wait(16)] {
            pair.apply(&step);
        }
    }
    pair.deliver();
    let before = pair.primary.frames_presented();
    assert!(before > 0);
    let (mut master, _) = take_over(&mut pair);
    master.record_takeover_dark(Duration::from_millis(700));
    let report = master.report_so_far();
    assert_eq!(
        report.frames, before,
        "no frame of the new master presented yet"
    );
    assert_eq!(report.takeovers.len(), 1);
    assert_eq!(report.takeovers[0].dark_ms, Some(700.0));
    assert_eq!(report.takeovers[0].term, 1);
    assert!(report.frame_ms.max > 0.0, "the old master's frame times");
}

#[test]
fn a_stale_master_steps_down_when_a_node_follows_a_newer_term() {
    let mut pair = Pair::new();
    let now = pair.now();
    pair.primary
        .handle_message(PeerId(2), FromNode::StaleMaster { seen: 1 }, now);
    assert!(pair.primary.is_done());
    let closes: Vec<_> = std::iter::from_fn(|| pair.primary.poll_close()).collect();
    assert!(
        closes.contains(&(PeerId(1), CloseReason::SteppedDown)),
        "{closes:?}"
    );
    assert_eq!(
        pair.primary.take_outcome().unwrap().unwrap_err(),
        RunError::SteppedDown { term: 0, seen: 1 }
    );
}

#[test]
fn a_node_saying_an_older_term_is_newer_is_closed_not_obeyed() {
    let mut pair = Pair::new();
    let now = pair.now();
    pair.primary
        .handle_message(PeerId(2), FromNode::StaleMaster { seen: 0 }, now);
    let closes: Vec<_> = std::iter::from_fn(|| pair.primary.poll_close()).collect();
    assert_eq!(closes, [(PeerId(2), CloseReason::ProtocolViolation)]);
    // Its only render node gone, the run may stall; it does not step down.
    let outcome = pair.primary.take_outcome();
    assert!(
        !matches!(outcome, Some(Err(RunError::SteppedDown { .. }))),
        "{outcome:?}"
    );
}

#[test]
fn replicas_survive_their_encoding() {
    let mut pair = Pair::new();
    for step in [Step::Camera(2), Step::Render, Step::Complete, Step::Present] {
        pair.apply(&step);
    }
    let replica = Replica::whole(pair.primary.standby_snapshot());
    let msg = super::standby::ToStandby::Replica(Box::new(replica));
    let bytes = super::standby::encode(&msg).unwrap();
    let back: super::standby::ToStandby = super::standby::decode(&bytes).unwrap();
    assert_eq!(back, msg);
}

/// Regression: a display that joined a master that took the wall over was sent its first
/// frame (the horizon, not 0) without a word, and refused it as too far ahead.
#[test]
fn a_display_joining_a_taken_over_wall_is_told_its_first_frame_before_it() {
    let mut pair = Pair::new();
    pair.ms += 10;
    let now = pair.now();
    pair.standby.handle_primary_closed(now.instant);
    let Some(StandbyEvent::TakeOver(snapshot)) = pair.standby.poll_event() else {
        panic!("the standby took over");
    };
    let mut master = Master::take_over(config(), *snapshot, now).unwrap();
    master.handle_join(join(11, display_role()), now);
    master.handle_join(join(12, Role::Render { cores: 1 }), now);
    master.handle_message(PeerId(11), FromNode::Ready, now);
    master.handle_message(PeerId(12), FromNode::Ready, now);
    let to_display: Vec<ToNode> = std::iter::from_fn(|| master.poll_transmit())
        .filter(|t| t.peer == PeerId(11))
        .map(|t| t.msg)
        .filter(|m| matches!(m, ToNode::StartAt { .. } | ToNode::FrameStart(_)))
        .collect();
    let [ToNode::StartAt { frame: from }, ToNode::FrameStart(first), ..] = &to_display[..] else {
        panic!("expected StartAt then FrameStart, got {to_display:?}");
    };
    assert!(from.0 > 0, "a taken-over wall starts past frame 0");
    assert_eq!(*from, first.frame);
    // A master of a fresh run says nothing of the kind: its displays start at frame 0.
    let now = at(Instant::now(), 0);
    let mut first_master = Master::new(config(), now).unwrap();
    first_master.handle_join(join(1, display_role()), now);
    first_master.handle_message(PeerId(1), FromNode::Ready, now);
    let start_at = std::iter::from_fn(|| first_master.poll_transmit())
        .any(|t| matches!(t.msg, ToNode::StartAt { .. }));
    assert!(!start_at);
}
