//! A display's session on a virtual clock: every input a driver feeds it, and what comes out
//! in which order.

use super::display::*;
use crate::assemble::AssembleError;
use glam::Vec3;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tessera_model::camera::Camera;
use tessera_model::params::RenderParams;
use tessera_model::state::StateId;
use tessera_model::wall::{DisplayId, TileGrid, TileId, WallSpec};
use tessera_protocol::pixels::BatchSource;
use tessera_protocol::{FrameId, FrameStart, FromNode, RenderNodeId, ToNode};

const STATE: StateId = StateId(4);

fn t0() -> Instant {
    static BASE: std::sync::OnceLock<Instant> = std::sync::OnceLock::new();
    *BASE.get_or_init(Instant::now)
}

fn at_ms(ms: u64) -> Instant {
    t0() + Duration::from_millis(ms)
}

/// Display 1 of two 32×16 screens side by side in 16-pixel tiles: tiles 2 and 3, the second
/// 16 pixels right of the first.
fn display(save_frame: Option<FrameId>) -> (DisplaySession, [TileId; 2]) {
    let wall = WallSpec::grid(2, 1, 32, 16).tile_size(16).build().unwrap();
    let screen = wall.screen(DisplayId(1)).unwrap();
    let grid = Arc::new(TileGrid::new(wall));
    let mine = [grid.tiles()[2].id, grid.tiles()[3].id];
    let mut s = DisplaySession::new(grid, screen, save_frame);
    assert_eq!(drain(&mut s), vec![], "heartbeats are the link's");
    (s, mine)
}

fn drain(s: &mut DisplaySession) -> Vec<FromNode> {
    std::iter::from_fn(|| s.poll_transmit()).collect()
}

fn start(frame: u64) -> ToNode {
    let camera = Camera::new(Vec3::Z, Vec3::ZERO, Vec3::Y, 45.0).unwrap();
    ToNode::FrameStart(FrameStart::new(
        FrameId(frame),
        STATE,
        camera,
        RenderParams::interactive(),
    ))
}

fn source(node: u32, render_us: u32) -> BatchSource {
    BatchSource {
        node: RenderNodeId(node),
        render_us,
    }
}

/// Every tile of `frame` from render node 5, its frame started.
fn assemble(s: &mut DisplaySession, tiles: [TileId; 2], frame: u64) {
    s.handle_message(start(frame)).unwrap();
    for t in tiles {
        let rgb = vec![frame as u8; 16 * 16 * 3];
        s.handle_tile(FrameId(frame), STATE, t, &rgb, source(5, 1500))
            .unwrap();
    }
}

fn present_order(s: &mut DisplaySession) -> PresentOrder {
    match s.poll_event() {
        Some(DisplayEvent::Present(order)) => order,
        other => panic!("expected a present, got {other:?}"),
    }
}

#[test]
fn a_frame_is_reported_complete_once_and_shown_only_at_the_present() {
    let (mut s, tiles) = display(None);
    assemble(&mut s, tiles, 0);
    assert_eq!(
        drain(&mut s),
        vec![FromNode::FrameComplete { frame: FrameId(0) }]
    );
    assert!(s.poll_event().is_none(), "nothing shown before the present");
    // Frame 1 completes while 0 waits: it is reported once 0 is presented, before the
    // present's deadline is waited for.
    assemble(&mut s, tiles, 1);
    assert_eq!(drain(&mut s), vec![]);
    let deadline = 1_000_000_007;
    s.handle_message(ToNode::PresentAt {
        frame: FrameId(0),
        clock_ns: deadline,
    })
    .unwrap();
    assert_eq!(
        drain(&mut s),
        vec![FromNode::FrameComplete { frame: FrameId(1) }]
    );
    let order = present_order(&mut s);
    assert_eq!(order.shown.frame, FrameId(0));
    assert_eq!(order.deadline, Some(deadline));
    assert_eq!((order.shown.width, order.shown.height), (32, 16));
    assert!(order.save_as.is_empty());
    assert_eq!(s.presented(), 1);
}

#[test]
fn the_sessions_frame_and_snapshots_are_saved_under_their_names() {
    let (mut s, tiles) = display(Some(FrameId(1)));
    s.handle_message(ToNode::SaveFrame { frame: FrameId(1) })
        .unwrap();
    s.handle_message(ToNode::SaveFrame { frame: FrameId(2) })
        .unwrap();
    let mut names = Vec::new();
    for frame in 0..3 {
        assemble(&mut s, tiles, frame);
        s.handle_message(ToNode::Present {
            frame: FrameId(frame),
        })
        .unwrap();
        names.push(present_order(&mut s).save_as);
    }
    assert_eq!(
        names,
        vec![
            vec![],
            vec!["display-1.png".to_string(), "display-1-frame-1.png".into()],
            vec!["display-1-frame-2.png".to_string()],
        ]
    );
}

#[test]
fn the_overlay_times_presents_on_the_clock_and_places_tiles_on_the_screen() {
    let (mut s, tiles) = display(None);
    for frame in 0..3 {
        assemble(&mut s, tiles, frame);
        if frame == 1 {
            s.handle_message(ToNode::Overlay { on: true }).unwrap();
            // A still wall shows the overlay too: the frame shown now is drawn again.
            assert!(matches!(s.poll_event(), Some(DisplayEvent::Redraw)));
        }
        s.handle_message(ToNode::Present {
            frame: FrameId(frame),
        })
        .unwrap();
        let order = present_order(&mut s);
        let overlay = s.handle_shown(&order, at_ms(20 * frame));
        match frame {
            0 => assert_eq!(overlay, None, "off until asked for"),
            1 => {
                let o = overlay.unwrap();
                assert_eq!((o.fps, o.frame_ms), (1.0 / 0.02, 20.0));
                let at: Vec<_> = o.tiles.iter().map(|t| (t.x, t.y, t.node, t.ms)).collect();
                assert_eq!(at, vec![(0, 0, 5, 1.5), (16, 0, 5, 1.5)]);
            }
            _ => {
                let o = overlay.unwrap();
                assert_eq!((o.fps, o.frame_ms), (2.0 / 0.04, 20.0));
            }
        }
    }
}

#[test]
fn a_still_display_saves_redraws_and_pictures_the_frame_it_shows_now() {
    let (mut s, tiles) = display(None);
    assert_eq!(s.overlay_now(at_ms(0)), None, "nothing shown yet");
    s.handle_message(ToNode::SaveFrame { frame: FrameId(0) })
        .unwrap();
    assemble(&mut s, tiles, 0);
    s.handle_message(ToNode::Present { frame: FrameId(0) })
        .unwrap();
    let order = present_order(&mut s);
    assert!(
        order.snapshot,
        "a snapshot is told to the master once written"
    );
    s.handle_shown(&order, at_ms(0));
    // No frame renders any more; the master asks for what is on screen.
    s.handle_message(ToNode::SaveShown { frame: FrameId(0) })
        .unwrap();
    s.handle_message(ToNode::SendThumbnail { factor: 4 })
        .unwrap();
    s.handle_message(ToNode::Overlay { on: true }).unwrap();
    let events: Vec<String> = std::iter::from_fn(|| s.poll_event())
        .map(|e| format!("{e:?}"))
        .collect();
    assert_eq!(
        events,
        [
            "SaveShown { frame: FrameId(0), name: \"display-1-frame-0.png\" }",
            "Thumbnail { factor: 4 }",
            "Redraw"
        ]
    );
    let overlay = s.overlay_now(at_ms(10)).expect("the overlay is on");
    assert_eq!(overlay.tiles.len(), 2, "the shown frame's tiles");
}

#[test]
fn a_present_of_an_incomplete_frame_breaks_the_swap_barrier() {
    let (mut s, tiles) = display(None);
    s.handle_message(start(0)).unwrap();
    s.handle_tile(FrameId(0), STATE, tiles[0], &[0; 16 * 16 * 3], source(1, 1))
        .unwrap();
    let err = s
        .handle_message(ToNode::Present { frame: FrameId(0) })
        .unwrap_err();
    assert_eq!(
        err,
        DisplaySessionError::SwapBarrier(AssembleError::Incomplete(FrameId(0)))
    );
    assert!(err
        .to_string()
        .starts_with("the master broke the swap barrier"));
    assert_eq!(s.presented(), 0);
}

#[test]
fn messages_for_render_nodes_are_refused_naming_them() {
    let (mut s, _) = display(None);
    let assign = ToNode::Assign {
        frame: FrameId(0),
        tiles: vec![],
    };
    let err = s.handle_message(assign).unwrap_err();
    assert_eq!(
        err.to_string(),
        "the master broke the protocol: it sent a display a assign message"
    );
    let late_start = s.handle_message(start(100)).unwrap_err();
    assert!(matches!(late_start, DisplaySessionError::FrameBarrier(_)));
}

#[test]
fn a_bad_tile_is_refused_and_leaves_nothing_behind() {
    let (mut s, tiles) = display(None);
    let short = s.handle_tile(FrameId(0), STATE, tiles[0], &[0; 3], source(1, 1));
    assert!(matches!(short, Err(AssembleError::WrongLength { .. })));
    let other = s.handle_tile(
        FrameId(0),
        STATE,
        TileId(0),
        &[0; 16 * 16 * 3],
        source(1, 1),
    );
    assert_eq!(other, Err(AssembleError::NotMine(0)));
    assert_eq!(drain(&mut s), vec![]);
}

#[test]
fn pings_are_answered_and_the_shutdown_reports_the_sessions_figures() {
    let (mut s, tiles) = display(None);
    s.handle_message(ToNode::Ping { seq: 9 }).unwrap();
    assert!(matches!(
        s.poll_event(),
        Some(DisplayEvent::Pong { seq: 9 })
    ));
    assemble(&mut s, tiles, 0);
    // A copy of a tile, from a node that was thought late.
    s.handle_tile(FrameId(0), STATE, tiles[0], &[0; 16 * 16 * 3], source(2, 1))
        .unwrap();
    s.handle_message(ToNode::Present { frame: FrameId(0) })
        .unwrap();
    let _ = present_order(&mut s);
    s.handle_message(ToNode::Shutdown).unwrap();
    assert!(matches!(s.poll_event(), Some(DisplayEvent::Shutdown)));
    let stats = s.stats();
    assert_eq!(
        (
            stats.pixels_owned,
            stats.frames_presented,
            stats.duplicate_tiles
        ),
        (32 * 16, 1, 1)
    );
}

#[test]
fn the_overlay_carries_the_frames_colour_map_and_crop_and_the_particle_range() {
    let wall = WallSpec::grid(2, 1, 32, 16).tile_size(16).build().unwrap();
    let screen = wall.screen(DisplayId(1)).unwrap();
    let grid = Arc::new(TileGrid::new(wall));
    let tiles = [grid.tiles()[2].id, grid.tiles()[3].id];
    let mut s = DisplaySession::new(grid, screen, None).with_particle_range(Some([-3.0, 7.5]));
    let params = tessera_model::params::RenderParamsSpec {
        colormap: tessera_model::colormap::ColorMap::Magma,
        crop: Some((0.0, 2.0)),
        ..tessera_model::params::RenderParamsSpec::INTERACTIVE
    }
    .build()
    .unwrap();
    let camera = Camera::new(Vec3::Z, Vec3::ZERO, Vec3::Y, 45.0).unwrap();
    s.handle_message(ToNode::FrameStart(FrameStart::new(
        FrameId(0),
        STATE,
        camera,
        params,
    )))
    .unwrap();
    for t in tiles {
        s.handle_tile(FrameId(0), STATE, t, &[0; 16 * 16 * 3], source(5, 1500))
            .unwrap();
    }
    s.handle_message(ToNode::Overlay { on: true }).unwrap();
    s.handle_message(ToNode::Present { frame: FrameId(0) })
        .unwrap();
    assert!(matches!(s.poll_event(), Some(DisplayEvent::Redraw)));
    let order = present_order(&mut s);
    let overlay = s.handle_shown(&order, at_ms(0)).expect("the overlay is on");
    let status = overlay.status.expect("the frame's start is known");
    assert_eq!(status.colormap, tessera_model::colormap::ColorMap::Magma);
    assert_eq!(status.crop, Some((0.0, 2.0)));
    assert_eq!(overlay.particles, Some([-3.0, 7.5]));
    assert_eq!(s.status_of(FrameId(0)), Some(status));
    // A scene without particles has no legend.
    let (mut plain, tiles) = display(None);
    assemble(&mut plain, tiles, 0);
    plain.handle_message(ToNode::Overlay { on: true }).unwrap();
    plain
        .handle_message(ToNode::Present { frame: FrameId(0) })
        .unwrap();
    let _ = plain.poll_event();
    let order = present_order(&mut plain);
    let overlay = plain.handle_shown(&order, at_ms(0)).unwrap();
    assert_eq!(overlay.particles, None);
    assert_eq!(
        overlay.status.unwrap().colormap,
        tessera_model::colormap::ColorMap::Viridis
    );
}
