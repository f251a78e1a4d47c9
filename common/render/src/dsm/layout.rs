//! Block geometry: blocks of a fixed size hold 8-wide tree nodes, leaf triangles, a volume
//! brick, the particles' binary tree nodes or particles, in that order; a block's bytes are
//! 64-byte aligned so that nodes are read in place.

use crate::bvh::node::{BvhNode, LeafTriangle, WideNode};
use crate::scene::particles::Particle;
use serde::{Deserialize, Serialize};
use tessera_core::dsm::BlockId;

/// The default block size: about 8 KB, as Ize et al. (254 32-byte nodes or 226 triangles of
/// 36 bytes; here 32 8-wide nodes or 227 triangles).
pub const DEFAULT_BLOCK_BYTES: u32 = 8192;
/// The smallest block: whole sibling groups of 8 nodes must fit in one, and a leaf of 16
/// triangles must span at most two.
pub const MIN_BLOCK_BYTES: u32 = 2048;
/// The largest block: beyond it a miss fetches far more than a traversal reads.
pub const MAX_BLOCK_BYTES: u32 = 1 << 20;

/// 64 bytes, 64-byte aligned: what blocks are made of, so a block's bytes can be read as
/// nodes (which are 64-byte aligned) in place.
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C, align(64))]
pub struct Chunk(pub [u8; 64]);

/// One block's bytes: an allocation of its own, or a slot of a [`super::pool::BlockPool`],
/// which it gives back when dropped.
pub struct Block {
    chunks: Box<[Chunk]>,
    /// The pool the chunks go back to when the block is dropped (instead of being freed).
    pool: Option<std::sync::Arc<super::pool::BlockPool>>,
}

impl std::fmt::Debug for Block {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Block")
            .field("bytes", &(self.chunks.len() * 64))
            .field("pooled", &self.pool.is_some())
            .finish()
    }
}

impl Block {
    /// A block of `bytes` zero bytes, allocated on its own.
    pub fn zeroed(bytes: u32) -> Block {
        Block {
            chunks: vec![Chunk([0; 64]); (bytes / 64) as usize].into_boxed_slice(),
            pool: None,
        }
    }

    /// A block of `block_bytes` starting with `bytes`, the rest zero.
    pub fn filled(block_bytes: u32, bytes: &[u8]) -> Block {
        let mut block = Block::zeroed(block_bytes);
        block.bytes_mut()[..bytes.len()].copy_from_slice(bytes);
        block
    }

    /// A block over a pool's slot (see [`super::pool::BlockPool::take`]).
    pub(super) fn pooled(
        chunks: Box<[Chunk]>,
        pool: std::sync::Arc<super::pool::BlockPool>,
    ) -> Block {
        Block {
            chunks,
            pool: Some(pool),
        }
    }

    /// The block's bytes as 64-byte aligned chunks (nodes are read from these in place).
    pub fn chunks(&self) -> &[Chunk] {
        &self.chunks
    }

    /// The block's chunks, to be filled (a read from the block file writes into these).
    pub fn chunks_mut(&mut self) -> &mut [Chunk] {
        &mut self.chunks
    }

    /// The block's bytes, `block_bytes` of them.
    pub fn bytes(&self) -> &[u8] {
        bytemuck::cast_slice(&self.chunks)
    }

    /// The block's bytes, to be filled.
    pub fn bytes_mut(&mut self) -> &mut [u8] {
        bytemuck::cast_slice_mut(&mut self.chunks)
    }
}

impl Drop for Block {
    fn drop(&mut self) {
        if let Some(pool) = self.pool.take() {
            pool.give_back(std::mem::take(&mut self.chunks));
        }
    }
}

/// `items` in blocks of `block_bytes`, `per` of them a block (the last block's rest zero): how
/// every region of items (tree nodes, triangles, particles) becomes blocks.
pub fn item_blocks<T: bytemuck::Pod, S: AsRef<[T]>>(
    items: S,
    per: u32,
    block_bytes: u32,
) -> impl Iterator<Item = Block> {
    let per = per as usize;
    let blocks = items.as_ref().len().div_ceil(per);
    (0..blocks).map(move |b| {
        let items = items.as_ref();
        let region = &items[b * per..((b + 1) * per).min(items.len())];
        Block::filled(block_bytes, bytemuck::cast_slice(region))
    })
}

/// A block size that cannot be used.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum LayoutError {
    /// The block size (in bytes) is not from [`MIN_BLOCK_BYTES`] to [`MAX_BLOCK_BYTES`] or not a
    /// multiple of 256.
    #[error(
        "block size {0} bytes is not a multiple of 256 from {MIN_BLOCK_BYTES} to {MAX_BLOCK_BYTES}"
    )]
    BlockSize(u32),
    /// The scene needs this many blocks: more than 32-bit block ids can number.
    #[error("the scene needs {0} blocks; block ids are 32-bit")]
    TooManyBlocks(u64),
    /// A volume brick (this many bytes) does not fit a block of this size.
    #[error("a volume brick is {brick} bytes, more than a block of {block}: give a block size of at least {brick} bytes rounded up to 256 ({})", brick_block_bytes(*brick))]
    BrickTooLarge {
        /// The block size asked for.
        block: u32,
        /// The largest brick's bytes.
        brick: u32,
    },
}

/// The smallest block size that holds a brick of `brick` bytes.
pub fn brick_block_bytes(brick: u32) -> u32 {
    brick.div_ceil(256) * 256
}

/// Where the tree's nodes, the triangles, a volume's bricks and the particles sit in blocks:
/// nodes `0..node_count` in blocks `0..node_blocks`, [`BlockLayout::nodes_per_block`] to a
/// block, then triangles in the following `triangle_blocks`, then one brick a block, then the
/// particles' tree nodes and the particles (see [`BlockLayout::with_spheres`]). The first
/// `top_blocks` node blocks (the top of the tree, which every ray walks) are held by every
/// node.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct BlockLayout {
    /// Size of every block, in bytes: a multiple of 256 from [`MIN_BLOCK_BYTES`] to
    /// [`MAX_BLOCK_BYTES`].
    pub block_bytes: u32,
    /// 8-wide tree nodes in all.
    pub node_count: u32,
    /// Leaf triangles in all.
    pub triangle_count: u32,
    /// Blocks holding nodes: block ids `0..node_blocks`.
    pub node_blocks: u32,
    /// Blocks holding triangles, following the node blocks.
    pub triangle_blocks: u32,
    /// Node blocks every render node holds (the top of the tree), at most `node_blocks`.
    pub top_blocks: u32,
    /// Blocks holding a volume's bricks, one each, following the triangle blocks.
    #[serde(default)]
    pub brick_blocks: u32,
    /// Nodes of the particles' binary tree in all.
    #[serde(default)]
    pub sphere_node_count: u32,
    /// Particles in all, in the tree's leaf order.
    #[serde(default)]
    pub sphere_count: u32,
    /// Blocks holding the particles' tree nodes, following the bricks.
    #[serde(default)]
    pub sphere_node_blocks: u32,
    /// Blocks holding the particles, following their tree's nodes.
    #[serde(default)]
    pub sphere_blocks: u32,
}

impl BlockLayout {
    /// The layout of `node_count` nodes and `triangle_count` triangles in blocks of
    /// `block_bytes`, the first `top_blocks` of them replicated.
    ///
    /// # Errors
    /// A block size out of range or not a multiple of 256; more blocks than ids.
    pub fn new(
        block_bytes: u32,
        node_count: u32,
        triangle_count: u32,
        top_blocks: u32,
    ) -> Result<BlockLayout, LayoutError> {
        let sized = (MIN_BLOCK_BYTES..=MAX_BLOCK_BYTES).contains(&block_bytes);
        if !sized || !block_bytes.is_multiple_of(256) {
            return Err(LayoutError::BlockSize(block_bytes));
        }
        let nodes_per = block_bytes / std::mem::size_of::<WideNode>() as u32;
        let tris_per = block_bytes / std::mem::size_of::<LeafTriangle>() as u32;
        let node_blocks = node_count.div_ceil(nodes_per);
        let triangle_blocks = triangle_count.div_ceil(tris_per);
        let total = node_blocks as u64 + triangle_blocks as u64;
        if total >= u32::MAX as u64 {
            return Err(LayoutError::TooManyBlocks(total));
        }
        Ok(BlockLayout {
            block_bytes,
            node_count,
            triangle_count,
            node_blocks,
            triangle_blocks,
            top_blocks: top_blocks.min(node_blocks),
            brick_blocks: 0,
            sphere_node_count: 0,
            sphere_count: 0,
            sphere_node_blocks: 0,
            sphere_blocks: 0,
        })
    }

    /// This layout with `bricks` volume bricks of at most `brick_bytes` bytes after the
    /// triangles, one a block.
    ///
    /// # Errors
    /// A brick larger than a block; more blocks than ids.
    pub fn with_bricks(self, bricks: u32, brick_bytes: u32) -> Result<BlockLayout, LayoutError> {
        if bricks > 0 && brick_bytes > self.block_bytes {
            return Err(LayoutError::BrickTooLarge {
                block: self.block_bytes,
                brick: brick_bytes,
            });
        }
        BlockLayout {
            brick_blocks: bricks,
            ..self
        }
        .counted()
    }

    /// This layout with a binary tree of `node_count` nodes over `sphere_count` particles
    /// after the bricks: [`BlockLayout::sphere_nodes_per_block`] nodes a block, then
    /// [`BlockLayout::spheres_per_block`] particles a block.
    ///
    /// # Errors
    /// More blocks than ids.
    pub fn with_spheres(
        self,
        node_count: u32,
        sphere_count: u32,
    ) -> Result<BlockLayout, LayoutError> {
        let laid = BlockLayout {
            sphere_node_count: node_count,
            sphere_count,
            ..self
        };
        BlockLayout {
            sphere_node_blocks: node_count.div_ceil(laid.sphere_nodes_per_block()),
            sphere_blocks: sphere_count.div_ceil(laid.spheres_per_block()),
            ..laid
        }
        .counted()
    }

    /// This layout, if its blocks can all be numbered.
    fn counted(self) -> Result<BlockLayout, LayoutError> {
        let total = [
            self.node_blocks,
            self.triangle_blocks,
            self.brick_blocks,
            self.sphere_node_blocks,
            self.sphere_blocks,
        ]
        .iter()
        .map(|&b| b as u64)
        .sum::<u64>();
        if total >= u32::MAX as u64 {
            return Err(LayoutError::TooManyBlocks(total));
        }
        Ok(self)
    }

    /// The block of the particles' tree node 0.
    pub fn first_sphere_node_block(&self) -> BlockId {
        self.first_brick_block() + self.brick_blocks
    }

    /// The block of particle 0 (in leaf order).
    pub fn first_sphere_block(&self) -> BlockId {
        self.first_sphere_node_block() + self.sphere_node_blocks
    }

    /// How many of the particles' binary tree nodes a block holds.
    pub fn sphere_nodes_per_block(&self) -> u32 {
        self.block_bytes / std::mem::size_of::<BvhNode>() as u32
    }

    /// How many particles a block holds.
    pub fn spheres_per_block(&self) -> u32 {
        self.block_bytes / std::mem::size_of::<Particle>() as u32
    }

    /// The block of brick 0.
    pub fn first_brick_block(&self) -> BlockId {
        self.node_blocks + self.triangle_blocks
    }

    /// How many 8-wide nodes a block holds.
    pub fn nodes_per_block(&self) -> u32 {
        self.block_bytes / std::mem::size_of::<WideNode>() as u32
    }

    /// How many leaf triangles a block holds.
    pub fn triangles_per_block(&self) -> u32 {
        self.block_bytes / std::mem::size_of::<LeafTriangle>() as u32
    }

    /// Blocks in all.
    pub fn total(&self) -> u32 {
        self.first_sphere_block() + self.sphere_blocks
    }

    /// Bytes of every block together.
    pub fn total_bytes(&self) -> u64 {
        self.total() as u64 * self.block_bytes as u64
    }

    /// Whether every node holds block `k` (the top of the tree).
    #[inline(always)]
    pub fn is_top(&self, k: BlockId) -> bool {
        k < self.top_blocks
    }
}

/// Division by a divisor fixed at start, as a multiply and a shift: a traversal finds the
/// block of every node and triangle it reads, and two hardware divisions per read (by the nodes
/// and the triangles a block holds, which the block size sets at run time) cost more than the
/// lookup they serve.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FastDiv {
    d: u32,
    m: u64,
    s: u32,
    /// For a power of two (the nodes of a block of a power-of-two size), the shift that
    /// divides: a read of a node then waits on one shift, not a multiplication and a second
    /// one for the remainder (a traversal's next node waits on that arithmetic).
    shift: Option<u32>,
}

impl FastDiv {
    /// Division by `d`.
    ///
    /// # Panics
    /// For a divisor of 0.
    pub fn new(d: u32) -> FastDiv {
        assert!(d > 0, "division by zero");
        // s = 32 + ceil(log2 d) and m = floor(2^s / d) + 1 give floor(n / d) for every
        // 32-bit n (the round-up method of Granlund and Montgomery).
        let s = 32 + (32 - (d - 1).leading_zeros());
        let m = ((1u128 << s) / d as u128 + 1) as u64;
        let shift = d.is_power_of_two().then(|| d.trailing_zeros());
        FastDiv { d, m, s, shift }
    }

    /// `(n / d, n % d)`.
    #[inline(always)]
    pub fn div_rem(&self, n: u32) -> (u32, u32) {
        if let Some(shift) = self.shift {
            return (n >> shift, n & (self.d - 1));
        }
        let q = ((n as u128 * self.m as u128) >> self.s) as u32;
        (q, n - q * self.d)
    }
}

/// Block `k`'s bytes read as nodes.
#[inline(always)]
pub fn nodes_of(bytes: &[Chunk]) -> &[WideNode] {
    bytemuck::cast_slice(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_8_kib_block_holds_32_nodes_or_227_triangles() {
        let l = BlockLayout::new(8192, 100, 1000, 1).unwrap();
        assert_eq!((l.nodes_per_block(), l.triangles_per_block()), (32, 227));
        assert_eq!((l.node_blocks, l.triangle_blocks), (4, 5));
        // Node 33 is the second of block 1; triangle slot 230 the fourth of the second
        // triangle block, block 5 (4 node blocks come first).
        assert_eq!(FastDiv::new(l.nodes_per_block()).div_rem(33), (1, 1));
        let (b, at) = FastDiv::new(l.triangles_per_block()).div_rem(230);
        assert_eq!((l.node_blocks + b, at), (5, 3));
        assert!(l.is_top(0) && !l.is_top(1));
    }

    #[test]
    fn fast_division_is_division() {
        let mut n: u32 = 0x9e37_79b9;
        for d in [
            1,
            2,
            3,
            7,
            8,
            32,
            227,
            255,
            256,
            4096,
            29127,
            u32::MAX / 3,
            u32::MAX,
        ] {
            let f = FastDiv::new(d);
            for probe in [0, 1, d - 1, d, d.wrapping_add(1), u32::MAX, u32::MAX - 1] {
                assert_eq!(f.div_rem(probe), (probe / d, probe % d), "{probe} / {d}");
            }
            for _ in 0..20_000 {
                n ^= n << 13;
                n ^= n >> 17;
                n ^= n << 5;
                assert_eq!(f.div_rem(n), (n / d, n % d), "{n} / {d}");
            }
        }
    }

    #[test]
    fn block_sizes_out_of_range_are_refused() {
        for bad in [0, 1024, 3000, 8193, 2 << 20] {
            assert_eq!(
                BlockLayout::new(bad, 1, 1, 1),
                Err(LayoutError::BlockSize(bad))
            );
        }
    }
}
