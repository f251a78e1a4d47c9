//! The master's decisions without a network: joins refused by certificate, and what a
//! control client or a lost display does to the run. Whole walls run in `sim::tests`.

use super::membership::allowed;
use super::*;

#[test]
fn a_certificate_lets_its_holder_join_only_as_its_role_and_display() {
    use CertifiedRole::*;
    let render = Role::Render { cores: 1 };
    assert!(allowed(&render, &[Render], false));
    assert!(
        !allowed(&render, &[], false),
        "certificates from before roles"
    );
    assert!(!allowed(&render, &[Control], false));
    assert!(!allowed(&render, &[Display], true));
    let display = Role::Display {
        display: DisplayId(0),
        pixel_addr: "127.0.0.1:9".parse().unwrap(),
    };
    assert!(allowed(&display, &[Display], true));
    assert!(!allowed(&display, &[Display], false), "another display's");
    assert!(!allowed(&display, &[Render], false), "a render node's");
    assert!(!allowed(&display, &[], false));
    assert!(allowed(&Role::Control, &[Control], false));
    assert!(!allowed(&Role::Control, &[], false));
    assert!(!allowed(&Role::Control, &[Render], false));
    assert!(!allowed(&Role::Control, &[Master], false));
}

fn wall(displays: u32) -> WallLayout {
    tessera_model::wall::WallSpec::grid(displays, 1, 64, 64)
        .tile_size(32)
        .build()
        .unwrap()
}

pub(super) fn at(base: Instant, ms: u64) -> Now {
    Now {
        instant: base + Duration::from_millis(ms),
        unix_ns: 1_000_000_000_000 + ms * 1_000_000,
    }
}

pub(super) fn join(peer: u64, role: Role) -> Join {
    Join {
        peer: PeerId(peer),
        credentials: Credentials::for_role(&role),
        hello: Hello {
            version: tessera_protocol::PROTOCOL_VERSION,
            role,
            host: "test".into(),
        },
        remote: "10.0.0.9:4000".parse().unwrap(),
    }
}

fn display(d: u32) -> Role {
    Role::Display {
        display: DisplayId(d),
        pixel_addr: "0.0.0.0:9100".parse().unwrap(),
    }
}

fn sent(master: &mut Master) -> Vec<Transmit> {
    std::iter::from_fn(|| master.poll_transmit()).collect()
}

fn refusal(transmits: &[Transmit], peer: u64) -> Option<String> {
    transmits.iter().find_map(|t| match &t.msg {
        ToNode::Refused { reason } if t.peer == PeerId(peer) => Some(reason.clone()),
        _ => None,
    })
}

#[test]
fn a_node_of_another_protocol_version_is_refused_naming_both() {
    let base = Instant::now();
    let mut master = Master::new(MasterConfig::new(wall(1), 1), at(base, 0)).unwrap();
    let mut old = join(1, Role::Render { cores: 2 });
    old.hello.version = 1;
    master.handle_join(old, at(base, 1));
    let reason = refusal(&sent(&mut master), 1).expect("refused");
    assert!(reason.contains("protocol version 1"), "{reason}");
    assert_eq!(master.render_node_of(PeerId(1)), None);
}

#[test]
fn a_second_claim_on_a_display_and_a_display_off_the_wall_are_refused() {
    let base = Instant::now();
    let mut master = Master::new(MasterConfig::new(wall(2), 1), at(base, 0)).unwrap();
    master.handle_join(join(1, display(0)), at(base, 1));
    master.handle_join(join(2, display(0)), at(base, 2));
    master.handle_join(join(3, display(7)), at(base, 3));
    let transmits = sent(&mut master);
    assert_eq!(refusal(&transmits, 1), None);
    assert!(refusal(&transmits, 2).unwrap().contains("already joined"));
    assert!(refusal(&transmits, 3).unwrap().contains("does not exist"));
    // A render node's session names where each display's pixels go: its host's address for
    // an unspecified one.
    master.handle_join(join(4, display(1)), at(base, 4));
    master.handle_join(join(5, Role::Render { cores: 2 }), at(base, 5));
    let welcome = sent(&mut master).into_iter().find_map(|t| match t.msg {
        ToNode::Welcome { session, .. } if t.peer == PeerId(5) => Some(session),
        _ => None,
    });
    let addrs: Vec<SocketAddr> = welcome
        .expect("welcomed")
        .displays()
        .iter()
        .map(|d| d.addr)
        .collect();
    assert_eq!(addrs, ["10.0.0.9:9100".parse().unwrap(); 2]);
}

#[test]
fn nodes_missing_at_the_join_deadline_end_the_run_naming_them() {
    let base = Instant::now();
    let mut master = Master::new(MasterConfig::new(wall(2), 2), at(base, 0)).unwrap();
    master.handle_join(join(1, display(0)), at(base, 1));
    master.handle_message(PeerId(1), FromNode::Ready, at(base, 2));
    let deadline = master.poll_timeout().expect("the join deadline");
    assert_eq!(deadline, base + Duration::from_secs(30));
    master.handle_timeout(at(base, 30_000));
    match master.take_outcome() {
        Some(Err(RunError::JoinTimeout { missing, .. })) => {
            assert_eq!(
                missing,
                "displays not ready: [1]; render nodes ready: 0 of 2"
            )
        }
        other => panic!("{other:?}"),
    }
    assert!(master.is_done());
    // A failed run still has figures to write: none of frames here, but a report.
    let report = master.report_so_far();
    assert_eq!(report.frames, 0);
    assert!(report.nodes_lost.is_empty());
}

#[test]
fn displays_present_at_one_instant_on_their_own_clocks_after_the_margin() {
    let base = Instant::now();
    let cfg = MasterConfig {
        present_margin: Duration::from_millis(20),
        frames: Some(1),
        ..MasterConfig::new(wall(1), 1)
    };
    let mut master = Master::new(cfg, at(base, 0)).unwrap();
    master.handle_join(join(1, display(0)), at(base, 1));
    master.handle_join(join(2, Role::Render { cores: 1 }), at(base, 1));
    master.handle_message(PeerId(1), FromNode::Ready, at(base, 2));
    // The display's clock runs 5 ms ahead of the master's: its pong says so.
    for seq in 0..timing::PINGS {
        let pong = FromNode::Pong {
            seq,
            clock_ns: at(base, 2).unix_ns + 5_000_000,
        };
        master.handle_message(PeerId(1), pong, at(base, 2));
    }
    master.handle_message(PeerId(2), FromNode::Ready, at(base, 3));
    // The render node renders what it is given until the frame is done.
    let mut transmits = sent(&mut master);
    for _ in 0..8 {
        let tiles: Vec<tessera_protocol::TileRange> = transmits
            .iter()
            .filter_map(|t| match &t.msg {
                ToNode::Assign { frame, tiles } if *frame == FrameId(0) => Some(tiles.clone()),
                _ => None,
            })
            .flatten()
            .collect();
        if tiles.is_empty() {
            break;
        }
        let done = FromNode::TilesDone {
            frame: FrameId(0),
            tiles,
            want_more: true,
        };
        master.handle_message(PeerId(2), done, at(base, 10));
        transmits = sent(&mut master);
    }
    let complete = FromNode::FrameComplete { frame: FrameId(0) };
    master.handle_message(PeerId(1), complete, at(base, 11));
    let present = sent(&mut master).into_iter().find_map(|t| match t.msg {
        ToNode::PresentAt { frame, clock_ns } => Some((t.peer, frame, clock_ns)),
        _ => None,
    });
    let expected = at(base, 11).unix_ns + 20_000_000 + 5_000_000;
    assert_eq!(present, Some((PeerId(1), FrameId(0), expected)));
}

#[test]
fn a_render_node_joining_while_a_display_rejoins_is_welcomed_once() {
    let base = Instant::now();
    let mut master = Master::new(MasterConfig::new(wall(2), 1), at(base, 0)).unwrap();
    master.handle_join(join(1, display(0)), at(base, 1));
    master.handle_join(join(2, display(1)), at(base, 1));
    master.handle_join(join(3, Role::Render { cores: 1 }), at(base, 1));
    for peer in 1..=3 {
        master.handle_message(PeerId(peer), FromNode::Ready, at(base, 2));
    }
    assert!(master.record.started.is_some(), "the wall runs");
    master.handle_closed(PeerId(2), "restarted", at(base, 10));
    // A render node joins while display 1 is away; it loads (not ready) as the display
    // comes back.
    master.handle_join(join(4, Role::Render { cores: 1 }), at(base, 11));
    master.handle_join(join(5, display(1)), at(base, 12));
    let welcomes = sent(&mut master)
        .iter()
        .filter(|t| t.peer == PeerId(4) && matches!(t.msg, ToNode::Welcome { .. }))
        .count();
    assert_eq!(welcomes, 1);
}

#[test]
fn nodes_that_joined_in_time_may_load_past_the_join_timeout_until_the_load_timeout() {
    let base = Instant::now();
    let cfg = MasterConfig {
        load_timeout: Duration::from_secs(120),
        ..MasterConfig::new(wall(1), 2)
    };
    let mut master = Master::new(cfg, at(base, 0)).unwrap();
    master.handle_join(join(1, display(0)), at(base, 1));
    master.handle_message(PeerId(1), FromNode::Ready, at(base, 2));
    master.handle_join(join(2, Role::Render { cores: 2 }), at(base, 3));
    assert_eq!(
        master.poll_timeout(),
        Some(base + Duration::from_secs(30)),
        "one render node has yet to join: the join timeout holds"
    );
    master.handle_join(join(3, Role::Render { cores: 2 }), at(base, 1_000));
    let loading = base + Duration::from_millis(1_000) + Duration::from_secs(120);
    assert_eq!(master.poll_timeout(), Some(loading), "now the load timeout");
    let step = tessera_protocol::LoadStep::BuildingBvh { triangles: 5 };
    master.handle_message(PeerId(2), FromNode::Ready, at(base, 20_000));
    master.handle_message(
        PeerId(3),
        FromNode::Loading {
            step,
            elapsed_s: 40,
        },
        at(base, 41_000),
    );
    master.handle_timeout(at(base, 60_000));
    assert!(!master.is_done(), "past the join timeout, still loading");
    master.handle_timeout(at(base, 121_000));
    match master.take_outcome() {
        Some(Err(RunError::LoadTimeout { waited, missing })) => {
            assert_eq!(waited, Duration::from_secs(120));
            assert_eq!(
                missing,
                "displays not ready: []; render nodes ready: 1 of 2; \
                 render node 1: building the BVH of 5 triangles (40 s)"
            );
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_wall_whose_nodes_load_in_time_starts() {
    let base = Instant::now();
    let mut master = Master::new(MasterConfig::new(wall(1), 1), at(base, 0)).unwrap();
    master.handle_join(join(1, display(0)), at(base, 1));
    master.handle_join(join(2, Role::Render { cores: 2 }), at(base, 2));
    master.handle_message(PeerId(1), FromNode::Ready, at(base, 3));
    master.handle_timeout(at(base, 40_000));
    assert!(!master.is_done(), "joined in time, loading");
    master.handle_message(PeerId(2), FromNode::Ready, at(base, 50_000));
    assert_eq!(master.poll_event(), Some(MasterEvent::Started));
}
