//! Particles in distributed shared memory: their binary tree's nodes and the particles in the
//! tree's leaf order, each a region of blocks after the volume's bricks; the manifest keeps the
//! range of their attribute, which every node colours them by.

use super::layout::{item_blocks, Block, BlockLayout};
use crate::spheres::SphereAccel;
use serde::{Deserialize, Serialize};

/// What the manifest says of a scene's particles (their counts are in the layout).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ParticleEntry {
    /// The least and greatest finite attribute, which the ends of the colour map stand for;
    /// `None` when no particle has one.
    pub attribute_range: Option<[f32; 2]>,
}

impl ParticleEntry {
    /// The entry for `range` as a scene's particles give it (infinite ends when none is
    /// finite).
    pub fn of_range((lo, hi): (f32, f32)) -> ParticleEntry {
        ParticleEntry {
            attribute_range: (lo <= hi).then_some([lo, hi]),
        }
    }

    /// The range the shading maps, as [`ParticleEntry::of_range`] was given it.
    pub fn range(&self) -> (f32, f32) {
        self.attribute_range
            .map_or((f32::INFINITY, f32::NEG_INFINITY), |[lo, hi]| (lo, hi))
    }

    /// Whether the range is one a scene could give: finite, its ends in order.
    pub fn is_valid(&self) -> bool {
        self.attribute_range
            .is_none_or(|[lo, hi]| lo.is_finite() && hi.is_finite() && lo <= hi)
    }
}

/// The blocks of `spheres` laid out as `layout`: the tree's nodes, then the particles.
pub fn sphere_blocks(spheres: SphereAccel, layout: BlockLayout) -> impl Iterator<Item = Block> {
    let (nodes, particles) = spheres.into_parts();
    let bytes = layout.block_bytes;
    item_blocks(nodes, layout.sphere_nodes_per_block(), bytes).chain(item_blocks(
        particles,
        layout.spheres_per_block(),
        bytes,
    ))
}
