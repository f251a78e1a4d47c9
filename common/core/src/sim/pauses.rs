//! A busy machine, simulated: the master, a render node or a display stops for a while (a
//! stopped process, a starved scheduler) and then goes on where it was. Whatever would have
//! happened to it meanwhile (a message arriving, its heartbeat timer, its render finishing)
//! happens when it wakes; what others send it waits. Heartbeats may also jitter.

use super::*;

/// Who an event happens to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Actor {
    /// The master (its messages in, its timer).
    Master,
    /// A render node.
    Render(RenderNodeId),
    /// A display.
    Display(DisplayId),
}

/// The spans each actor is stopped for, in virtual microseconds.
#[derive(Default)]
pub(super) struct Pauses {
    spans: BTreeMap<Actor, Vec<(u64, u64)>>,
}

impl Pauses {
    pub fn add(&mut self, actor: Actor, from_us: u64, until_us: u64) {
        self.spans
            .entry(actor)
            .or_default()
            .push((from_us, until_us));
    }

    /// When `actor`, if stopped at `at_us`, goes on.
    pub fn until(&self, actor: Actor, at_us: u64) -> Option<u64> {
        self.spans
            .get(&actor)?
            .iter()
            .filter(|&&(from, until)| from <= at_us && at_us < until)
            .map(|&(_, until)| until)
            .max()
    }
}

/// A connection the master closed, when, and whose.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Dropped {
    /// Virtual time of the close.
    pub at: Duration,
    /// The node whose connection it was.
    pub who: Actor,
}

impl SimWall {
    /// Stops `actor` at virtual time `at` for `length`, then lets it go on where it was.
    pub fn pause(&mut self, actor: Actor, at: Duration, length: Duration) {
        let from = at.as_micros() as u64;
        self.pauses
            .add(actor, from, from + length.as_micros() as u64);
    }

    /// Heartbeats come up to `jitter` later than their interval, seeded.
    pub fn jitter_heartbeats(&mut self, jitter: Duration) {
        self.beat_jitter_us = jitter.as_micros() as u64;
    }

    /// The connections the master closed (nodes it declared dead, or dropped otherwise).
    pub fn dropped(&self) -> &[Dropped] {
        &self.dropped
    }

    /// When render node `node` was killed, if it was.
    pub fn killed_at(&self, node: RenderNodeId) -> Option<Duration> {
        let clock = self.clocks.get(node.0 as usize)?;
        clock.died_at.map(Duration::from_micros)
    }

    /// The next heartbeat's delay: the interval and a seeded jitter.
    pub(super) fn beat_delay_us(&mut self) -> u64 {
        if self.beat_jitter_us == 0 {
            return HEARTBEAT_US;
        }
        HEARTBEAT_US + self.beat_rng.next_u64() % (self.beat_jitter_us + 1)
    }

    /// Who `event` happens to, if somebody who can be stopped.
    pub(super) fn actor_of(event: &Event) -> Option<Actor> {
        match event {
            Event::Heartbeat(node)
            | Event::ToRender(node, _)
            | Event::Rendered(node, ..)
            | Event::Delivered(node, ..) => Some(Actor::Render(*node)),
            Event::DisplayBeat(display)
            | Event::ToDisplay(_, display, _)
            | Event::Pixels { display, .. } => Some(Actor::Display(*display)),
            Event::FromRender(..) | Event::FromDisplay(..) | Event::FromControl(..) => {
                Some(Actor::Master)
            }
            _ => None,
        }
    }

    /// Records a connection the master closed.
    pub(super) fn note_close(&mut self, peer: PeerId) {
        let who = match self.peers.who(peer) {
            Some(peers::Who::Render(node)) => Actor::Render(node),
            Some(peers::Who::Display(display)) => Actor::Display(display),
            _ => return,
        };
        let at = Duration::from_micros(self.now_us);
        self.dropped.push(Dropped { at, who });
    }
}
