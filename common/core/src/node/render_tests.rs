//! A render node's session on a virtual clock: every input a driver feeds it, and what comes
//! out in which order.

use super::render::*;
use crate::worker::WorkerError;
use glam::Vec3;
use std::time::{Duration, Instant};
use tessera_model::camera::Camera;
use tessera_model::params::{RenderParams, RenderParamsSpec};
use tessera_model::state::StateId;
use tessera_model::volume_params::VolumeParams;
use tessera_model::wall::{DisplayId, TileId};
use tessera_protocol::{to_ranges, FrameId, FrameStart, FromNode, RenderNodeId, TileRange, ToNode};

/// The virtual clock's zero.
fn t0() -> Instant {
    static BASE: std::sync::OnceLock<Instant> = std::sync::OnceLock::new();
    *BASE.get_or_init(Instant::now)
}

fn at_ms(ms: u64) -> Instant {
    t0() + Duration::from_millis(ms)
}

fn setup() -> RenderSetup {
    RenderSetup {
        node: RenderNodeId(7),
        tile_count: 100,
        threads: 2,
        shared: false,
        volume: None,
        displays: vec![DisplayId(0), DisplayId(1)],
    }
}

/// A session, which says nothing until it is asked something (heartbeats are the link's).
fn session(setup: RenderSetup) -> RenderSession {
    let mut s = RenderSession::new(setup, t0());
    assert_eq!(drain(&mut s), vec![]);
    s
}

fn drain(s: &mut RenderSession) -> Vec<FromNode> {
    std::iter::from_fn(|| s.poll_transmit()).collect()
}

fn start_with(frame: u64, params: RenderParams) -> ToNode {
    let camera = Camera::new(Vec3::Z, Vec3::ZERO, Vec3::Y, 45.0).unwrap();
    ToNode::FrameStart(FrameStart::new(FrameId(frame), StateId(0), camera, params))
}

fn start(frame: u64) -> ToNode {
    start_with(frame, RenderParams::interactive())
}

fn at_step(frame: u64, time_step: u32) -> ToNode {
    let volume = VolumeParams {
        time_step,
        ..VolumeParams::default()
    };
    let params = RenderParamsSpec {
        volume,
        ..RenderParamsSpec::INTERACTIVE
    }
    .build()
    .unwrap();
    start_with(frame, params)
}

fn assign(frame: u64, start: u32, end: u32) -> ToNode {
    ToNode::Assign {
        frame: FrameId(frame),
        tiles: vec![TileRange::new(start, end).unwrap()],
    }
}

fn ids(tiles: &[TileId]) -> Vec<u32> {
    tiles.iter().map(|t| t.0).collect()
}

fn done(tiles: usize, took_ms: u64) -> BatchDone {
    let took = Duration::from_millis(took_ms);
    BatchDone {
        tiles,
        rays: 100 * tiles as u64,
        took,
        batch_took: took,
    }
}

#[test]
fn one_batch_at_a_time_and_more_work_asked_for_while_the_threads_are_free() {
    let mut s = session(setup());
    s.handle_message(start(0), t0()).unwrap();
    assert_eq!(s.poll_batch(t0()), None, "nothing queued yet");
    assert_eq!(drain(&mut s), vec![], "no request before the frame's share");
    s.handle_message(assign(0, 0, 5), t0()).unwrap();
    let order = s.poll_batch(t0()).unwrap();
    assert_eq!(
        (order.start.frame, ids(&order.tiles)),
        (FrameId(0), vec![0, 1])
    );
    assert!(order.prefetch.is_empty() && order.volume_step.is_none());
    // Three left, below the low water of two per thread: ask with the batch taken.
    let request = FromNode::TilesDone {
        frame: FrameId(0),
        tiles: vec![],
        want_more: true,
    };
    assert_eq!(drain(&mut s), vec![request]);
    assert!(s.is_rendering());
    assert_eq!(s.poll_batch(at_ms(1)), None, "the threads are busy");
    let source = s.handle_rendered(done(2, 3));
    assert_eq!((source.node, source.render_us), (RenderNodeId(7), 1500));
    assert_eq!(ids(&s.poll_batch(at_ms(3)).unwrap().tiles), vec![2, 3]);
    assert_eq!(drain(&mut s), vec![], "one request outstanding at most");
}

#[test]
fn a_shared_scene_fetches_the_blocks_of_a_batch_and_the_next_together() {
    let mut s = session(RenderSetup {
        shared: true,
        ..setup()
    });
    s.handle_message(start(0), t0()).unwrap();
    s.handle_message(assign(0, 10, 15), t0()).unwrap();
    let order = s.poll_batch(t0()).unwrap();
    assert_eq!(ids(&order.tiles), vec![10, 11]);
    assert_eq!(ids(&order.prefetch), vec![10, 11, 12, 13]);
}

#[test]
fn a_volume_step_is_loaded_only_when_a_frame_shows_another_and_the_series_loops() {
    let mut s = session(RenderSetup {
        volume: Some(VolumeSteps { steps: 4, shown: 1 }),
        ..setup()
    });
    let mut step_of = |frame: u64, time_step: u32| {
        s.handle_message(at_step(frame, time_step), t0()).unwrap();
        s.handle_message(assign(frame, 0, 1), t0()).unwrap();
        let order = s.poll_batch(t0()).unwrap();
        s.handle_rendered(done(1, 1));
        order.volume_step
    };
    assert_eq!(step_of(0, 1), None, "the scene holds step 1 already");
    assert_eq!(step_of(1, 2), Some(2));
    assert_eq!(step_of(2, 2), None);
    assert_eq!(
        step_of(3, 5),
        Some(1),
        "step 5 of a 4-step series is step 1"
    );
    assert_eq!(s.volume(), Some(VolumeSteps { steps: 4, shown: 1 }));
}

#[test]
fn block_holders_go_to_the_fetcher_of_a_shared_scene_and_break_a_replicated_one() {
    let holders = ToNode::BlockHolders {
        rank: Some(0),
        holders: vec![],
    };
    let mut replicated = session(setup());
    let err = replicated.handle_message(holders.clone(), t0());
    assert_eq!(err, Err(RenderSessionError::HoldersForReplicatedScene));
    assert_eq!(replicated.poll_event(), None);
    let mut shared = session(RenderSetup {
        shared: true,
        ..setup()
    });
    shared.handle_message(holders, t0()).unwrap();
    assert_eq!(shared.poll_event(), Some(RenderEvent::BlockHolders(vec![])));
}

#[test]
fn messages_for_displays_are_refused_naming_them() {
    let mut s = session(setup());
    let err = s
        .handle_message(ToNode::Present { frame: FrameId(0) }, t0())
        .unwrap_err();
    assert_eq!(
        err,
        RenderSessionError::Worker(WorkerError::NotForRenderNodes("present"))
    );
    assert!(err.to_string().contains("a present message"), "{err}");
}

#[test]
fn a_lost_display_is_forgotten_once_and_its_tiles_go_back_before_the_report() {
    let mut s = session(setup());
    s.handle_message(start(0), t0()).unwrap();
    s.handle_message(assign(0, 0, 40), t0()).unwrap();
    let order = s.poll_batch(t0()).unwrap();
    assert_eq!(drain(&mut s), vec![], "the queue is long");
    s.handle_rendered(done(order.tiles.len(), 1));
    let lost = vec![(DisplayId(1), LinkId(1), "reset".to_string())];
    s.handle_delivery(
        FrameId(0),
        &[TileId(0)],
        vec![TileId(1)],
        lost.clone(),
        at_ms(2),
    );
    assert_eq!(
        s.poll_event(),
        Some(RenderEvent::ForgetDisplay {
            display: DisplayId(1),
            link: LinkId(1),
            reason: "reset".into()
        })
    );
    let sent = drain(&mut s);
    assert_eq!(
        sent,
        vec![
            FromNode::TilesReturned {
                frame: FrameId(0),
                tiles: vec![TileRange::new(1, 2).unwrap()]
            },
            FromNode::TilesDone {
                frame: FrameId(0),
                tiles: vec![TileRange::new(0, 1).unwrap()],
                want_more: false
            },
        ]
    );
    // Batches sent since still fail on it: nothing more to forget, the tiles still go back.
    s.handle_delivery(FrameId(0), &[], vec![TileId(2)], lost.clone(), at_ms(3));
    assert_eq!(s.poll_event(), None);
    // It rejoined and was reached on a new link: lost again, it is forgotten again.
    let addr = "127.0.0.1:9".parse().unwrap();
    let moved = ToNode::DisplayAt {
        display: DisplayId(1),
        addr,
    };
    s.handle_message(moved, at_ms(4)).unwrap();
    assert_eq!(
        s.poll_event(),
        Some(RenderEvent::ConnectDisplay {
            display: DisplayId(1),
            addr,
            link: LinkId(2)
        })
    );
    assert!(s.handle_display_reached(DisplayId(1), LinkId(2)));
    let lost = vec![(DisplayId(1), LinkId(2), "reset".to_string())];
    s.handle_delivery(FrameId(0), &[], vec![TileId(3)], lost, at_ms(5));
    assert!(matches!(
        s.poll_event(),
        Some(RenderEvent::ForgetDisplay { .. })
    ));
}

#[test]
fn the_shutdown_reports_the_sessions_tiles_rays_and_seconds() {
    let mut s = session(setup());
    s.handle_message(start(0), t0()).unwrap();
    s.handle_message(assign(0, 0, 2), t0()).unwrap();
    let order = s.poll_batch(t0()).unwrap();
    s.handle_rendered(done(order.tiles.len(), 250));
    s.handle_message(ToNode::Shutdown, at_ms(2000)).unwrap();
    assert_eq!(s.poll_event(), Some(RenderEvent::Shutdown));
    let stats = s.stats(at_ms(2000));
    assert_eq!((stats.tiles, stats.rays), (2, 200));
    assert_eq!((stats.busy_s, stats.elapsed_s), (0.25, 2.0));
}

/// What reaches a render node while displays restart: each display's old link fails (a
/// delivery on it ends in error), the master gives its new address, and the new link is up.
#[derive(Clone, Copy, Debug)]
enum Rejoin {
    OldFails(u32),
    NewAddr(u32),
    NewUp(u32),
}

/// Every order of `events` in which a display's new link comes up only after its address.
fn causal_orders(events: &[Rejoin]) -> Vec<Vec<Rejoin>> {
    if events.is_empty() {
        return vec![vec![]];
    }
    let mut orders = Vec::new();
    for (i, &first) in events.iter().enumerate() {
        let waits =
            |e: &Rejoin| matches!((first, *e), (Rejoin::NewUp(a), Rejoin::NewAddr(b)) if a == b);
        if events.iter().any(waits) {
            continue;
        }
        let mut rest = events.to_vec();
        rest.remove(i);
        for mut tail in causal_orders(&rest) {
            tail.insert(0, first);
            orders.push(tail);
        }
    }
    orders
}

/// A driver's map of connections, kept as the real one keeps it from the session's events.
#[derive(Default)]
struct Links {
    up: std::collections::BTreeMap<DisplayId, LinkId>,
    connecting: std::collections::BTreeMap<DisplayId, LinkId>,
}

impl Links {
    fn apply_events(&mut self, s: &mut RenderSession) {
        while let Some(event) = s.poll_event() {
            match event {
                RenderEvent::ConnectDisplay { display, link, .. } => {
                    self.connecting.insert(display, link);
                }
                RenderEvent::ForgetDisplay { display, link, .. } => {
                    if self.up.get(&display) == Some(&link) {
                        self.up.remove(&display);
                    }
                }
                other => panic!("unexpected {other:?}"),
            }
        }
    }
}

#[test]
fn a_quick_display_restart_keeps_its_new_link_in_every_order_of_events() {
    // Display 0 restarts within a second; display 1 rejoins too, its old link's failure
    // late. Old links are 0 and 1, as the setup numbers them.
    let events = [
        Rejoin::OldFails(0),
        Rejoin::NewAddr(0),
        Rejoin::NewUp(0),
        Rejoin::NewAddr(1),
        Rejoin::NewUp(1),
        Rejoin::OldFails(1),
    ];
    let orders = causal_orders(&events);
    assert_eq!(
        orders.len(),
        180,
        "6! orders, each new link after its address"
    );
    for order in orders {
        let mut s = session(setup());
        let mut links = Links {
            up: [(DisplayId(0), LinkId(0)), (DisplayId(1), LinkId(1))].into(),
            ..Links::default()
        };
        s.handle_message(start(0), t0()).unwrap();
        s.handle_message(assign(0, 0, 40), t0()).unwrap();
        for (ms, &event) in (1..).zip(&order) {
            match event {
                Rejoin::OldFails(d) => {
                    let lost = vec![(DisplayId(d), LinkId(d.into()), "timed out".into())];
                    s.handle_delivery(FrameId(0), &[], vec![], lost, at_ms(ms));
                }
                Rejoin::NewAddr(d) => {
                    let addr = format!("127.0.0.1:{}", 9000 + d).parse().unwrap();
                    let moved = ToNode::DisplayAt {
                        display: DisplayId(d),
                        addr,
                    };
                    s.handle_message(moved, at_ms(ms)).unwrap();
                }
                Rejoin::NewUp(d) => {
                    let link = links.connecting[&DisplayId(d)];
                    assert!(s.handle_display_reached(DisplayId(d), link), "{order:?}");
                    links.up.insert(DisplayId(d), link);
                }
            }
            links.apply_events(&mut s);
        }
        let new = links.connecting.clone();
        assert_eq!(links.up, new, "the new links survive {order:?}");
        for (&display, &link) in &new {
            assert_eq!(s.link(display), Some(link), "{order:?}");
        }
        // A batch of tiles on both displays is delivered over the new links and reported.
        drain(&mut s);
        let order_tiles = s.poll_batch(at_ms(10)).unwrap().tiles;
        s.handle_rendered(done(order_tiles.len(), 1));
        s.handle_delivery(FrameId(0), &order_tiles, vec![], vec![], at_ms(11));
        links.apply_events(&mut s);
        let reported = drain(&mut s).into_iter().any(|m| {
            matches!(m, FromNode::TilesDone { tiles, .. } if tiles == to_ranges(order_tiles.clone()))
        });
        assert!(reported, "{order:?}");
    }
}

#[test]
fn a_late_connection_to_an_older_address_is_refused() {
    let mut s = session(setup());
    let mut links = Links::default();
    for port in [9001, 9002] {
        let addr = format!("127.0.0.1:{port}").parse().unwrap();
        s.handle_message(
            ToNode::DisplayAt {
                display: DisplayId(1),
                addr,
            },
            t0(),
        )
        .unwrap();
    }
    links.apply_events(&mut s);
    let newest = links.connecting[&DisplayId(1)];
    assert_eq!(newest, LinkId(3));
    assert!(s.handle_display_reached(DisplayId(1), newest));
    assert!(!s.handle_display_reached(DisplayId(1), LinkId(2)), "stale");
    assert_eq!(s.link(DisplayId(1)), Some(newest));
    // The old link's failure, however late, leaves the new one alone.
    let lost = vec![(DisplayId(1), LinkId(1), "timed out".into())];
    s.handle_delivery(FrameId(0), &[], vec![TileId(1)], lost, at_ms(1));
    assert_eq!(s.poll_event(), None);
    assert_eq!(s.link(DisplayId(1)), Some(newest));
}
