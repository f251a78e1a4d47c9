//! Speculative re-issue: an idle node gets a copy of the tiles of a node that is late with
//! them, so that one slow, hung or dead node does not hold every display at the barrier.
//!
//! A node's lease on its tiles is renewed by each report of tiles done; it runs out after
//! [`LEASE_GAPS`] times the node's usual time between reports (at least [`MIN_LEASE`]). Once
//! the pool is empty, a node that asks for work, or is waiting when a lease runs out, is given
//! up to half of the late node's uncopied tiles, newest first (the late node renders in order,
//! so those are the furthest from done). Whichever copy is reported first counts; displays
//! already drop a tile they have. A dead node's tiles thus move after its lease, a few of its
//! report intervals, long before its heartbeat deadline; a node that is merely slow costs some
//! duplicated tiles.

use super::*;

/// A lease is this many of the node's usual gaps between reports.
pub const LEASE_GAPS: u32 = 4;
/// The shortest lease: below it a pause of the scheduler would look like a death.
pub const MIN_LEASE: Duration = Duration::from_millis(40);

impl Coordinator {
    /// `node` reported tiles done at `now`: its lease is renewed and its pace learnt.
    pub(super) fn note_progress(&mut self, node: RenderNodeId, now: Instant) {
        if let Some(n) = self.nodes.get_mut(&node) {
            let gap = now.saturating_duration_since(n.last_progress);
            n.progress_gap = Some(match n.progress_gap {
                Some(old) => (old + gap) / 2,
                None => gap,
            });
            n.last_progress = now;
        }
    }

    /// `node` is about to be given tiles: if it held none, its lease starts now (the time it
    /// sat idle is no lateness).
    pub(super) fn note_given(&mut self, node: RenderNodeId, now: Instant) {
        let holds = self.in_flight.values().any(|f| f.holds(node));
        if let Some(n) = self.nodes.get_mut(&node).filter(|_| !holds) {
            n.last_progress = now;
        }
    }

    fn lease_end(&self, node: RenderNodeId) -> Option<Instant> {
        let n = self.nodes.get(&node)?;
        if self.liveness.is_suspected(node) {
            // Its lease ended when it fell silent, whatever its pace.
            return Some(n.last_progress);
        }
        let lease = n
            .progress_gap
            .map_or(MIN_LEASE, |gap| (gap * LEASE_GAPS).max(MIN_LEASE));
        Some(n.last_progress + lease)
    }

    /// The frame and node whose tiles `taker` would copy first (any node's, for no taker), and
    /// when that node's lease ends: the oldest frame with uncopied tiles held by another node,
    /// and of its holders the one whose lease ends first.
    fn candidate(&self, taker: Option<RenderNodeId>) -> Option<(FrameId, RenderNodeId, Instant)> {
        if !self.config.speculate {
            return None;
        }
        self.in_flight.iter().find_map(|(&frame, state)| {
            state
                .holders()
                .filter(|&h| Some(h) != taker && state.has_uncopied(h))
                .filter_map(|h| Some((frame, h, self.lease_end(h)?)))
                .min_by_key(|&(_, _, end)| end)
        })
    }

    /// When a waiting node could first be given a late node's tiles. Asked after every event,
    /// so it looks at the holders once or twice, not once per waiting node: the first
    /// candidate serves every waiting node but itself, and itself only its own next one.
    pub(super) fn next_speculation(&self) -> Option<Instant> {
        if self.waiting.is_empty() {
            return None;
        }
        let (_, first, end) = self.candidate(None)?;
        let others = self.waiting.iter().any(|&w| w != first);
        let own = self
            .waiting
            .contains(&first)
            .then(|| self.candidate(Some(first)).map(|(_, _, e)| e))
            .flatten();
        others.then_some(end).into_iter().chain(own).min()
    }

    /// Gives `taker` copies of a late node's tiles, if some node is late at `now`; true if
    /// it got any (and was told so).
    pub(super) fn speculate_for(&mut self, taker: RenderNodeId, now: Instant) -> bool {
        let Some((frame, late, _)) = self
            .candidate(Some(taker))
            .filter(|&(_, _, end)| end <= now)
        else {
            return false;
        };
        self.note_given(taker, now);
        let Some(state) = self.in_flight.get_mut(&frame) else {
            return false;
        };
        let copies = state.speculate(late, taker, state.uncopied(late).div_ceil(2));
        if copies.is_empty() {
            return false;
        }
        self.speculated_tiles += copies.len() as u64;
        self.outputs.push_back(Output::ToRender(
            taker,
            ToNode::Assign {
                frame,
                tiles: to_ranges(copies),
            },
        ));
        self.waiting.remove(&taker);
        true
    }

    /// Every waiting node takes over what late nodes hold, while any is late.
    pub(super) fn feed_speculation(&mut self, now: Instant) {
        let waiting: Vec<RenderNodeId> = self.waiting.iter().copied().collect();
        for node in waiting {
            self.speculate_for(node, now);
        }
    }

    /// Tiles given to a second node because the first was late with them, over the run.
    pub fn speculated_tiles(&self) -> u64 {
        self.speculated_tiles
    }
}
