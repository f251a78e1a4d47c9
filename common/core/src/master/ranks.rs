//! A shared scene's ranks: the first render nodes to join each hold a rank's share of the
//! blocks; the master tells every render node its rank and where the holders answer, and
//! again whenever a holder comes or goes. A rank whose holder is lost is taken by the next
//! render node to join, which loads that share from the prepared files.

use super::*;
use std::collections::BTreeSet;
use tessera_protocol::dsm::BlockHolder;

/// Which render node holds each rank, and where it answers for its blocks.
#[derive(Default)]
pub(super) struct Ranks {
    rank_of: BTreeMap<RenderNodeId, u32>,
    addr: BTreeMap<u32, SocketAddr>,
}

impl Ranks {
    /// Each rank held, its holder and where it answers (once it said).
    pub(super) fn held(&self) -> Vec<(u32, RenderNodeId, Option<SocketAddr>)> {
        self.rank_of
            .iter()
            .map(|(&node, &rank)| (rank, node, self.addr.get(&rank).copied()))
            .collect()
    }

    fn list(&self) -> Vec<BlockHolder> {
        self.addr
            .iter()
            .map(|(&rank, &addr)| BlockHolder { rank, addr })
            .collect()
    }
}

/// Why a render node's word about its blocks was refused.
#[derive(Debug, thiserror::Error)]
#[error("said where it serves blocks, but it holds no rank")]
pub(super) struct NoRank;

impl Master {
    fn rank_count(&self) -> Option<u32> {
        match &self.cfg.data {
            DataSpec::Dsm(spec) => Some(spec.ranks),
            DataSpec::Replicated => None,
        }
    }

    /// The lowest rank nobody holds, for a render node from `host` that just joined (none
    /// when the scene is replicated or every rank is held). After a takeover, a rank its host
    /// held under the old master comes first: the node likely has its blocks loaded.
    pub(super) fn take_rank(&mut self, node: RenderNodeId, host: &str) -> Option<u32> {
        let ranks = self.rank_count()?;
        let held: BTreeSet<u32> = self.ranks.rank_of.values().copied().collect();
        let free = |r: &u32| *r < ranks && !held.contains(r);
        let former = self
            .former_ranks
            .iter()
            .find(|h| h.host == host && free(&h.rank));
        let rank = match former {
            Some(h) => h.rank,
            None => (0..ranks).find(free)?,
        };
        self.ranks.rank_of.insert(node, rank);
        Some(rank)
    }

    /// Tells render node `node` (at `peer`) its rank and where the holders are.
    pub(super) fn send_holders(&mut self, peer: PeerId, node: RenderNodeId) {
        if self.rank_count().is_none() {
            return;
        }
        let rank = self.ranks.rank_of.get(&node).copied();
        let holders = self.ranks.list();
        self.send(peer, ToNode::BlockHolders { rank, holders });
    }

    fn broadcast_holders(&mut self) {
        let renders: Vec<(RenderNodeId, PeerId)> =
            self.renders.iter().map(|(&n, &p)| (n, p)).collect();
        for (node, peer) in renders {
            self.send_holders(peer, node);
        }
    }

    /// Render node `node` answers for its rank's blocks at `addr` (an unspecified IP: where
    /// the master sees it, `remote`).
    pub(super) fn blocks_at(
        &mut self,
        node: RenderNodeId,
        addr: SocketAddr,
        remote: SocketAddr,
    ) -> Result<(), NoRank> {
        let rank = *self.ranks.rank_of.get(&node).ok_or(NoRank)?;
        let addr = if addr.ip().is_unspecified() {
            SocketAddr::new(remote.ip(), addr.port())
        } else {
            addr
        };
        tracing::info!(
            "render node {} serves rank {rank}'s blocks at {addr}",
            node.0
        );
        self.ranks.addr.insert(rank, addr);
        self.broadcast_holders();
        Ok(())
    }

    /// Render node `node` (described as `who`) is gone: its rank is free for the next node
    /// to join, and the others are told, so that they ask its blocks' other owner or read
    /// them from the prepared files.
    pub(super) fn lose_rank(&mut self, node: RenderNodeId, who: &str) {
        let Some(rank) = self.ranks.rank_of.remove(&node) else {
            return;
        };
        self.ranks.addr.remove(&rank);
        let replicas = match &self.cfg.data {
            DataSpec::Dsm(spec) => spec.replicas,
            DataSpec::Replicated => 1,
        };
        if replicas > 1 {
            tracing::warn!("{who} held rank {rank}: its blocks' other owners answer for them");
        } else {
            tracing::warn!(
                "{who} held rank {rank}, the only owner of its blocks: the other render nodes read them from the prepared files (--replicas 2 keeps a second owner)"
            );
        }
        self.broadcast_holders();
    }
}
