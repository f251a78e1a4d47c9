//! The material of each leaf slot of the BVH.

use serde::{Deserialize, Serialize};

/// Which material each leaf slot's triangle has: one index per slot (replicated scenes), or
/// runs of equal indices in slot order (shared scenes, whose render nodes hold no per-triangle
/// array: the leaf order keeps a mesh's materials together, so runs are few).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum SlotMaterials {
    /// The material index of every slot, by slot.
    PerSlot(Vec<u16>),
    /// Runs of slots with the same material.
    Runs {
        /// First slot of each run, ascending, the first 0.
        starts: Vec<u32>,
        /// The material index of each run.
        materials: Vec<u16>,
    },
}

impl SlotMaterials {
    /// The material index of `slot`.
    #[inline]
    pub fn of(&self, slot: u32) -> u16 {
        match self {
            SlotMaterials::PerSlot(m) => m[slot as usize],
            SlotMaterials::Runs { starts, materials } => {
                let run = starts.partition_point(|&s| s <= slot).saturating_sub(1);
                materials.get(run).copied().unwrap_or(0)
            }
        }
    }

    /// The same materials as runs.
    pub fn runs_of(per_slot: &[u16]) -> SlotMaterials {
        let (mut starts, mut materials) = (Vec::new(), Vec::new());
        for (slot, &m) in per_slot.iter().enumerate() {
            if materials.last() != Some(&m) {
                starts.push(slot as u32);
                materials.push(m);
            }
        }
        SlotMaterials::Runs { starts, materials }
    }

    /// Bytes held (for memory reports).
    pub fn bytes(&self) -> usize {
        match self {
            SlotMaterials::PerSlot(m) => std::mem::size_of_val(&m[..]),
            SlotMaterials::Runs { starts, materials } => {
                std::mem::size_of_val(&starts[..]) + std::mem::size_of_val(&materials[..])
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn runs_give_every_slot_its_own_material() {
        let per_slot = vec![3, 3, 3, 0, 0, 7, 3, 3, 1];
        let runs = SlotMaterials::runs_of(&per_slot);
        assert_eq!(
            runs,
            SlotMaterials::Runs {
                starts: vec![0, 3, 5, 6, 8],
                materials: vec![3, 0, 7, 3, 1]
            }
        );
        let plain = SlotMaterials::PerSlot(per_slot.clone());
        for slot in 0..per_slot.len() as u32 {
            assert_eq!(runs.of(slot), per_slot[slot as usize], "slot {slot}");
            assert_eq!(plain.of(slot), per_slot[slot as usize]);
        }
    }
}
