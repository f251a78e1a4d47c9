//! Who holds which block: the interleaved placement of DeMarle et al., with optional
//! replicas, and the cache-line mapping of Ize et al. that wastes no line on resident blocks.

use super::DsmError;

/// A block's number: the scene is cut into fixed-size blocks `0..total`.
pub type BlockId = u32;

/// Which render node (rank 0..ranks) holds which block, and where.
///
/// Block k's primary owner is node `k mod N` (N = ranks), which keeps it at slot `k / N` of
/// its resident array, as DeMarle et al. do: interleaving spreads any contiguous region of the
/// scene, and so the misses of a view, over every node. With `replicas` r > 1, nodes
/// `(k + 1) mod N`, …, `(k + r − 1) mod N` hold it too, each in a section of its resident
/// array after its primary blocks, so that a node's death loses no block.
///
/// # Examples
///
/// ```
/// use tessera_core::dsm::Residency;
///
/// // 10 blocks over 3 nodes, each block held by two of them; this is node 1.
/// let r = Residency::new(10, 3, Some(1), 2).unwrap();
/// assert_eq!(r.owners(4).collect::<Vec<_>>(), [1, 2]); // primary on node 1 …
/// assert_eq!(r.resident_slot(4), Some(1)); // … at slot 4 / 3
/// assert_eq!(r.owners(0).collect::<Vec<_>>(), [0, 1]); // a replica on node 1 …
/// assert_eq!(r.resident_slot(0), Some(4)); // … after the 4 slots of primaries
/// assert!(!r.owns(2));
/// // Blocks 0, 2, 3, 5, … are not primary here; block 2 is the second of them.
/// assert_eq!(r.cache_line(2, 8), 1);
/// ```
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Residency {
    total: u32,
    ranks: u32,
    rank: Option<u32>,
    replicas: u32,
}

impl Residency {
    /// `total` blocks over `ranks` nodes, this node being `rank` (None: a node that owns
    /// nothing, e.g. one that joined late), each block held by `replicas` nodes (1 = no copy;
    /// 2 = a second owner).
    ///
    /// # Errors
    /// [`DsmError::NoRanks`] for 0 ranks, [`DsmError::RankOutOfRange`] for a rank not below
    /// `ranks`, [`DsmError::Replicas`] for 0 replicas or more than `ranks`.
    pub fn new(
        total: u32,
        ranks: u32,
        rank: Option<u32>,
        replicas: u32,
    ) -> Result<Residency, DsmError> {
        if ranks == 0 {
            return Err(DsmError::NoRanks);
        }
        if let Some(rank) = rank.filter(|&r| r >= ranks) {
            return Err(DsmError::RankOutOfRange { rank, ranks });
        }
        if replicas == 0 || replicas > ranks {
            return Err(DsmError::Replicas { replicas, ranks });
        }
        Ok(Residency {
            total,
            ranks,
            rank,
            replicas,
        })
    }

    /// Number of blocks.
    pub fn total(&self) -> u32 {
        self.total
    }

    /// Number of nodes the blocks are spread over.
    pub fn ranks(&self) -> u32 {
        self.ranks
    }

    /// This node's rank; `None` for a node that holds nothing.
    pub fn rank(&self) -> Option<u32> {
        self.rank
    }

    /// How many nodes hold each block.
    pub fn replicas(&self) -> u32 {
        self.replicas
    }

    /// The owners of block k, primary first: k mod N, then (k+1) mod N, … (`replicas` of
    /// them).
    pub fn owners(&self, k: BlockId) -> impl Iterator<Item = u32> {
        debug_assert!(k < self.total, "block {k} of {}", self.total);
        let n = u64::from(self.ranks);
        (0..u64::from(self.replicas)).map(move |i| ((u64::from(k) + i) % n) as u32)
    }

    /// Whether this node holds block k, as primary or as a replica.
    pub fn owns(&self, k: BlockId) -> bool {
        self.replica_index(k).is_some()
    }

    /// Where block k sits in this node's resident array, if it holds it: primary blocks at
    /// k / N (the paper's slot), the blocks it holds as the r-th replica after them, at
    /// r * ceil(total / N) + k / N.
    pub fn resident_slot(&self, k: BlockId) -> Option<usize> {
        let i = self.replica_index(k)?;
        Some(i as usize * self.section() + (k / self.ranks) as usize)
    }

    /// Length of the resident array: `replicas` sections of ceil(total / N) slots, the last
    /// slot of a section unused where N does not divide `total` evenly for this rank.
    pub fn resident_len(&self) -> usize {
        match self.rank {
            Some(_) => self.replicas as usize * self.section(),
            None => 0,
        }
    }

    /// The blocks this node holds, in slot order, with their slots.
    pub fn resident_blocks(&self) -> impl Iterator<Item = (usize, BlockId)> {
        let (n, total, section) = (self.ranks, self.total, self.section());
        let replicas = self.replicas;
        self.rank.into_iter().flat_map(move |rank| {
            (0..replicas).flat_map(move |i| {
                // The r-th replicas held here are the blocks whose primary is r nodes back.
                let first = (rank + n - i) % n;
                (first..total)
                    .step_by(n as usize)
                    .map(move |k| (i as usize * section + (k / n) as usize, k))
            })
        })
    }

    /// The cache line of a block this node does not hold, in a direct-mapped cache of `lines`
    /// lines: the paper's improved mapping (k - floor((k + N - rank) / N)) mod lines, so that
    /// no line is wasted on a block the node owns as primary; k mod lines for a node with no
    /// rank.
    ///
    /// The floor counts the primary blocks up to k, so the result is k's index among the
    /// blocks that are not primary here: with at least that many lines, every such block has
    /// a line of its own (DeMarle's k mod lines leaves 1/N of the lines unused). Replicas held
    /// here still take an index, as in the paper's one-owner layout. For a block held here as
    /// primary the value is meaningless; a cache of 0 lines gets line 0.
    pub fn cache_line(&self, k: BlockId, lines: usize) -> usize {
        if lines == 0 {
            return 0;
        }
        let k = i64::from(k);
        let index = match self.rank {
            Some(rank) => {
                let n = i64::from(self.ranks);
                k - (k + n - i64::from(rank)) / n
            }
            None => k,
        };
        index.rem_euclid(lines as i64) as usize
    }

    /// ceil(total / N): the slots of one section of the resident array.
    fn section(&self) -> usize {
        self.total.div_ceil(self.ranks) as usize
    }

    /// Which of k's owners this node is (0: primary), if it is one.
    fn replica_index(&self, k: BlockId) -> Option<u32> {
        let rank = self.rank?;
        if k >= self.total {
            return None;
        }
        let i = (rank + self.ranks - k % self.ranks) % self.ranks;
        (i < self.replicas).then_some(i)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::collections::BTreeSet;

    /// (total, ranks, rank, replicas), rank and replicas valid for ranks.
    fn layouts() -> impl Strategy<Value = (u32, u32, Option<u32>, u32)> {
        (0u32..300, 1u32..12).prop_flat_map(|(total, ranks)| {
            (
                Just(total),
                Just(ranks),
                proptest::option::weighted(0.9, 0..ranks),
                1..=ranks,
            )
        })
    }

    #[test]
    fn invalid_layouts_are_refused() {
        assert_eq!(Residency::new(8, 0, None, 1), Err(DsmError::NoRanks));
        assert_eq!(
            Residency::new(8, 4, Some(4), 1),
            Err(DsmError::RankOutOfRange { rank: 4, ranks: 4 })
        );
        assert_eq!(
            Residency::new(8, 4, Some(0), 0),
            Err(DsmError::Replicas {
                replicas: 0,
                ranks: 4
            })
        );
        assert_eq!(
            Residency::new(8, 4, Some(0), 5),
            Err(DsmError::Replicas {
                replicas: 5,
                ranks: 4
            })
        );
        assert!(Residency::new(0, 4, None, 4).is_ok());
    }

    #[test]
    fn the_papers_example_two_nodes_and_two_lines_node_0_uses_both_lines() {
        let r = Residency::new(16, 2, Some(0), 1).unwrap();
        let lines: BTreeSet<usize> = (0..16)
            .filter(|&k| !r.owns(k))
            .map(|k| r.cache_line(k, 2))
            .collect();
        assert_eq!(lines, BTreeSet::from([0, 1]));
        // DeMarle's k mod 2 puts every remote block (the odd ones) on line 1.
        let old: BTreeSet<u32> = (0..16).filter(|&k| !r.owns(k)).map(|k| k % 2).collect();
        assert_eq!(old, BTreeSet::from([1]));
    }

    #[test]
    fn a_node_without_rank_holds_nothing_and_maps_k_mod_lines() {
        let r = Residency::new(20, 4, None, 2).unwrap();
        assert!((0..20).all(|k| !r.owns(k) && r.resident_slot(k).is_none()));
        assert_eq!(r.resident_len(), 0);
        assert_eq!(r.resident_blocks().count(), 0);
        assert_eq!(r.cache_line(13, 5), 3);
    }

    proptest! {
        #[test]
        fn every_block_has_exactly_replicas_distinct_owners(
            (total, ranks, _rank, replicas) in layouts()
        ) {
            for k in 0..total {
                let owners: Vec<u32> = Residency::new(total, ranks, None, replicas)
                    .unwrap()
                    .owners(k)
                    .collect();
                prop_assert_eq!(owners[0], k % ranks);
                let distinct: BTreeSet<u32> = owners.iter().copied().collect();
                prop_assert_eq!(distinct.len(), replicas as usize);
                // And each owner agrees that it holds the block.
                for &o in &owners {
                    let there = Residency::new(total, ranks, Some(o), replicas).unwrap();
                    prop_assert!(there.owns(k));
                }
                let holders = (0..ranks)
                    .filter(|&r| Residency::new(total, ranks, Some(r), replicas).unwrap().owns(k))
                    .count();
                prop_assert_eq!(holders, replicas as usize);
            }
        }

        #[test]
        fn resident_slot_is_a_bijection_between_held_blocks_and_used_slots(
            (total, ranks, rank, replicas) in layouts()
        ) {
            let r = Residency::new(total, ranks, rank, replicas).unwrap();
            let listed: Vec<(usize, BlockId)> = r.resident_blocks().collect();
            let held: Vec<BlockId> = (0..total).filter(|&k| r.owns(k)).collect();
            prop_assert_eq!(listed.len(), held.len());
            prop_assert!(listed.windows(2).all(|w| w[0].0 < w[1].0), "slot order");
            for &(slot, k) in &listed {
                prop_assert!(slot < r.resident_len());
                prop_assert_eq!(r.resident_slot(k), Some(slot));
            }
            let blocks: BTreeSet<BlockId> = listed.iter().map(|&(_, k)| k).collect();
            prop_assert_eq!(blocks, held.into_iter().collect::<BTreeSet<_>>());
        }

        #[test]
        fn a_cache_as_large_as_the_non_primary_blocks_holds_them_all_at_once(
            (total, ranks, rank, replicas) in layouts(), extra in 0usize..3
        ) {
            let r = Residency::new(total, ranks, rank, replicas).unwrap();
            let remote: Vec<BlockId> = (0..total)
                .filter(|&k| rank.is_none_or(|me| k % ranks != me))
                .collect();
            let lines = remote.len() + extra;
            let used: BTreeSet<usize> = remote.iter().map(|&k| r.cache_line(k, lines)).collect();
            prop_assert_eq!(used.len(), remote.len());
            prop_assert!(used.iter().all(|&l| l < lines.max(1)));
        }
    }
}
