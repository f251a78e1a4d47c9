//! Static shares by speed: each node's share of a frame's static tiles follows how many
//! tiles it rendered of the last presented frames.

use super::*;

impl Coordinator {
    /// Smooths each live node's tile count of a presented frame into its speed estimate. A
    /// reclaimed node's tiles count for whoever rendered them.
    pub(super) fn learn_speeds(&mut self, frame: &InFlight) {
        for node in self.nodes.keys() {
            let count = f64::from(frame.done_by().get(node).copied().unwrap_or(0));
            self.tiles_per_frame
                .entry(*node)
                .and_modify(|w| *w = 0.5 * *w + 0.5 * count)
                .or_insert(count);
        }
    }

    /// Every live node with its weight for static shares; a node with no presented frame yet
    /// counts as the mean of the others (all alike before the first present).
    pub(super) fn weighted_nodes(&self) -> Vec<(RenderNodeId, f64)> {
        let known: Vec<f64> = self
            .nodes
            .keys()
            .filter_map(|n| self.tiles_per_frame.get(n).copied())
            .collect();
        let mean = if known.is_empty() {
            1.0
        } else {
            known.iter().sum::<f64>() / known.len() as f64
        };
        self.nodes
            .keys()
            .map(|n| (*n, self.tiles_per_frame.get(n).copied().unwrap_or(mean)))
            .collect()
    }

    /// Who takes a static share of a new frame, with weights, and the suspected nodes that
    /// do not (unless every node is suspected: then nobody is better placed).
    pub(super) fn share_holders(&self) -> (Vec<(RenderNodeId, f64)>, Vec<RenderNodeId>) {
        let (live, suspected): (Vec<_>, Vec<_>) = self
            .weighted_nodes()
            .into_iter()
            .partition(|&(n, _)| !self.liveness.is_suspected(n));
        if live.is_empty() {
            return (suspected, Vec::new());
        }
        (live, suspected.into_iter().map(|(n, _)| n).collect())
    }
}
