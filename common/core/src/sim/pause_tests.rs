//! A busy machine over a long run: heartbeats that jitter and random pauses of up to 2 s of
//! every node and of the master, over 10,000 frames. Nobody paused is declared dead, and a
//! node that really died is, within the bound.

use super::*;
use tessera_model::wall::WallSpec;

/// Pauses of up to 2 s for `actor`, one every 1 to 6 s of virtual time until `until`; how many.
fn random_pauses(sim: &mut SimWall, rng: &mut Rng, actor: Actor, until: Duration) -> u32 {
    let (mut at, mut count) = (Duration::from_millis(500), 0);
    loop {
        at += Duration::from_secs_f64(1.0 + 5.0 * rng.unit());
        if at > until {
            return count;
        }
        count += 1;
        let length = Duration::from_secs_f64(0.05 + 1.95 * rng.unit());
        sim.pause(actor, at, length);
    }
}

#[test]
fn ten_thousand_frames_of_pauses_and_jitter_kill_nobody_but_the_dead() {
    let wall = WallSpec::grid(2, 1, 64, 64).tile_size(32).build().unwrap();
    let config = SimConfig {
        pixels: PixelCheck::OnePerTile,
        ..SimConfig::new(4)
    };
    let mut sim = SimWall::with_config(11, wall, &config);
    sim.jitter_heartbeats(Duration::from_millis(30));
    let mut rng = Rng::new(5);
    // The run takes some 22 s of virtual time: pauses all through it.
    let until = Duration::from_secs(20);
    let actors = [
        Actor::Master,
        Actor::Display(DisplayId(0)),
        Actor::Display(DisplayId(1)),
    ]
    .into_iter()
    .chain((0..4).map(|n| Actor::Render(RenderNodeId(n))));
    let pauses: u32 = actors
        .map(|actor| random_pauses(&mut sim, &mut rng, actor, until))
        .sum();
    let dead = RenderNodeId(3);
    sim.kill_at(dead, FrameId(5_000));
    let frames = 10_000;
    assert_eq!(sim.run_frames(frames), frames);
    let all: Vec<FrameId> = (0..frames).map(FrameId).collect();
    for d in 0..2 {
        assert_eq!(sim.presented(DisplayId(d)), &all[..], "display {d}");
    }
    assert!(sim.corrupt_frames().is_empty());
    let dropped = sim.dropped().to_vec();
    assert_eq!(
        dropped.iter().map(|d| d.who).collect::<Vec<_>>(),
        [Actor::Render(dead)],
        "false deaths: {dropped:?}"
    );
    let killed = sim.killed_at(dead).expect("killed");
    let delay = dropped[0].at - killed;
    eprintln!(
        "{frames} frames and {pauses} pauses in {:?} of virtual time: the killed node was declared dead {delay:?} after its death",
        sim.virtual_time()
    );
    // The served default's acceptable pause (3 s) past a rhythm whose spread the pauses
    // widened: a few spreads of a second at most.
    assert!(
        delay > Duration::from_secs(3) && delay < Duration::from_secs(5),
        "{delay:?}"
    );
}
