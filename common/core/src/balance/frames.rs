//! Book-keeping of one frame in flight: which tiles are unassigned, with whom, and done.

use super::BalanceError;
use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::time::Instant;
use tessera_model::wall::{DisplayId, TileId};
use tessera_protocol::{FrameId, FrameStart, RenderNodeId};

pub(super) struct InFlight {
    pub start: FrameStart,
    /// Tiles nobody has been given yet (or given back by a node that left).
    pool: VecDeque<TileId>,
    /// Tiles given to each node and not yet reported done.
    assigned: BTreeMap<RenderNodeId, BTreeSet<TileId>>,
    /// Tiles also given to a second node because the first was late with them: each is
    /// copied once at most.
    speculated: BTreeSet<TileId>,
    done: Vec<bool>,
    done_count: u32,
    /// Tiles each node rendered of this frame: how fast it is, against the others.
    done_by: BTreeMap<RenderNodeId, u32>,
    pub displays_complete: BTreeSet<DisplayId>,
    /// The displays that were there when the frame started: only they show it (one that
    /// rejoins later starts with a later frame).
    pub displays_expected: BTreeSet<DisplayId>,
    /// When it started, by the coordinator's clock.
    pub started_at: Option<Instant>,
    /// It renders a refinement pass: more samples or ambient-occlusion rays than its state.
    pub refinement_pass: bool,
}

impl InFlight {
    pub fn new(start: FrameStart, tile_count: u32) -> Self {
        InFlight {
            start,
            pool: (0..tile_count).map(TileId).collect(),
            assigned: BTreeMap::new(),
            speculated: BTreeSet::new(),
            done: vec![false; tile_count as usize],
            done_count: 0,
            done_by: BTreeMap::new(),
            displays_complete: BTreeSet::new(),
            displays_expected: BTreeSet::new(),
            started_at: None,
            refinement_pass: false,
        }
    }

    pub fn frame(&self) -> FrameId {
        self.start.frame
    }

    pub fn all_rendered(&self) -> bool {
        self.done_count as usize == self.done.len()
    }

    pub fn pool_is_empty(&self) -> bool {
        self.pool.is_empty()
    }

    pub fn done_by(&self) -> &BTreeMap<RenderNodeId, u32> {
        &self.done_by
    }

    /// Cuts the frame into one region per node, sized by the node's `weight` (equal weights,
    /// equal regions), and gives each node the first `static_fraction` of its region; the rest
    /// of every region stays in the pool, in order.
    pub fn static_shares(
        &mut self,
        nodes: &[(RenderNodeId, f64)],
        static_fraction: f32,
    ) -> Vec<Vec<TileId>> {
        let total = self.pool.len();
        let weight_sum: f64 = nodes.iter().map(|(_, w)| w.max(0.0)).sum();
        let equal = !(weight_sum.is_finite() && weight_sum > 0.0);
        let n = nodes.len().max(1);
        // Region k ends where the weights up to k reach their share of the frame. The small
        // bias keeps equal weights on the exact integer bounds `total · k / n`.
        let mut reached = 0.0;
        let mut bound = |k: usize, w: f64| -> usize {
            if equal {
                return total * (k + 1) / n;
            }
            reached += w.max(0.0);
            ((total as f64 * reached / weight_sum + 1e-9).floor() as usize).min(total)
        };
        let mut shares = vec![Vec::new(); nodes.len()];
        let mut rest = VecDeque::with_capacity(total);
        let mut lo = 0;
        for (k, &(node, weight)) in nodes.iter().enumerate() {
            let hi = if k + 1 == nodes.len() {
                total
            } else {
                bound(k, weight).max(lo)
            };
            let fixed = ((hi - lo) as f32 * static_fraction.clamp(0.0, 1.0)).round() as usize;
            for (i, &tile) in self.pool.range(lo..hi).enumerate() {
                if i < fixed {
                    shares[k].push(tile);
                } else {
                    rest.push_back(tile);
                }
            }
            self.assigned
                .entry(node)
                .or_default()
                .extend(shares[k].iter().copied());
            lo = hi;
        }
        self.pool = rest;
        shares
    }

    /// Guided self-scheduling: a batch is a share of what is left, so batches shrink as the
    /// frame nears its end and the last nodes to finish do not hold up the barrier.
    pub fn take_batch(
        &mut self,
        node: RenderNodeId,
        node_count: u32,
        min_batch: u32,
    ) -> Vec<TileId> {
        let size = (self.pool.len() as u32)
            .div_ceil(2 * node_count)
            .max(min_batch) as usize;
        let batch: Vec<TileId> = self.pool.drain(..size.min(self.pool.len())).collect();
        self.assigned
            .entry(node)
            .or_default()
            .extend(batch.iter().copied());
        batch
    }

    pub fn mark_done(
        &mut self,
        node: RenderNodeId,
        tiles: impl Iterator<Item = TileId>,
    ) -> Result<(), BalanceError> {
        let frame = self.frame();
        let assigned = self.assigned.entry(node).or_default();
        for tile in tiles {
            if !assigned.remove(&tile) {
                return Err(BalanceError::NotAssigned {
                    node,
                    frame,
                    tile: tile.0,
                });
            }
            let slot = &mut self.done[tile.0 as usize];
            if !*slot {
                *slot = true;
                self.done_count += 1;
                *self.done_by.entry(node).or_default() += 1;
            }
        }
        Ok(())
    }

    /// A node left: what it had not finished goes back to the front of the pool (unless
    /// another node holds a copy already).
    pub fn reclaim(&mut self, node: RenderNodeId) {
        if let Some(tiles) = self.assigned.remove(&node) {
            for tile in tiles.into_iter().rev() {
                let copied = self.assigned.values().any(|held| held.contains(&tile));
                if !self.done[tile.0 as usize] && !copied {
                    self.pool.push_front(tile);
                }
            }
        }
    }

    /// Whether `node` holds unfinished tiles of this frame.
    pub fn holds(&self, node: RenderNodeId) -> bool {
        self.assigned
            .get(&node)
            .is_some_and(|held| !held.is_empty())
    }

    /// How many unfinished tiles `node` holds that nobody else has a copy of.
    pub fn uncopied(&self, node: RenderNodeId) -> usize {
        self.assigned
            .get(&node)
            .map_or(0, |held| held.iter().filter(|t| self.copyable(**t)).count())
    }

    /// The nodes holding unfinished tiles.
    pub fn holders(&self) -> impl Iterator<Item = RenderNodeId> + '_ {
        self.assigned
            .iter()
            .filter(|(_, held)| !held.is_empty())
            .map(|(node, _)| *node)
    }

    /// `node` gives back `tiles` it could not deliver: those it held and nobody finished go
    /// to the front of the pool (unless another node holds a copy).
    pub fn give_back(&mut self, node: RenderNodeId, tiles: impl Iterator<Item = TileId>) {
        let Some(held) = self.assigned.get_mut(&node) else {
            return;
        };
        let returned: Vec<TileId> = tiles.filter(|t| held.remove(t)).collect();
        for tile in returned.into_iter().rev() {
            let copied = self.assigned.values().any(|h| h.contains(&tile));
            if !self.done[tile.0 as usize] && !copied {
                self.pool.push_front(tile);
            }
        }
    }

    /// Tiles no display will show (theirs is gone): settled without rendering, taken out of
    /// the pool; a node that holds one may still report it, as a duplicate.
    pub fn drop_tiles(&mut self, tiles: &[TileId]) {
        let mut dropped = 0;
        for t in tiles {
            let slot = &mut self.done[t.0 as usize];
            if !*slot {
                *slot = true;
                dropped += 1;
            }
        }
        self.done_count += dropped;
        let done = &self.done;
        self.pool.retain(|t| !done[t.0 as usize]);
    }

    /// Whether `node` holds unfinished tiles nobody else has a copy of.
    pub fn has_uncopied(&self, node: RenderNodeId) -> bool {
        self.assigned
            .get(&node)
            .is_some_and(|held| held.iter().any(|t| self.copyable(*t)))
    }

    /// Neither done nor copied already.
    fn copyable(&self, tile: TileId) -> bool {
        !self.done[tile.0 as usize] && !self.speculated.contains(&tile)
    }

    /// Gives `to` a copy of up to `max` of `from`'s unfinished tiles that nobody has a copy of
    /// yet (the last ones first: `from` renders its tiles in order, so those are the furthest
    /// from done). Whichever node reports a tile first counts; the other's report is a
    /// harmless duplicate.
    pub fn speculate(&mut self, from: RenderNodeId, to: RenderNodeId, max: usize) -> Vec<TileId> {
        let Some(held) = self.assigned.get(&from) else {
            return Vec::new();
        };
        let copies: Vec<TileId> = held
            .iter()
            .rev()
            .filter(|t| self.copyable(**t))
            .take(max)
            .copied()
            .collect();
        self.speculated.extend(copies.iter().copied());
        self.assigned
            .entry(to)
            .or_default()
            .extend(copies.iter().copied());
        let mut copies = copies;
        copies.reverse();
        copies
    }
}
