//! The scene in distributed shared memory (Ize et al. 2011, §4): its 8-wide tree, leaf
//! triangles and volume bricks cut into fixed-size blocks, spread over the render nodes, and
//! read by the same traversals and volume marches that read replicated arrays.
//!
//! * [`layout`]: the block geometry: which block and offset hold a node or a triangle.
//! * [`reorder`]: tree nodes written so that a block holds a coherent subtree, siblings
//!   adjacent (§4.1); triangles stay in BVH leaf order with their own corners (§4.2).
//! * [`prepare`]: a scene prepared once into block files with a checksum per block and a
//!   manifest, reused while the scene's content is the same.
//! * [`tree`]: [`tree::DsmTree`], what a render node renders from: the replicated top of the tree, its resident
//!   share, the direct-mapped cache of `tessera_core::dsm`, and a fetch of what is in
//!   neither, which a render thread either waits for or, as the frame loop does
//!   (`crate::parking`), asks for and comes back to once it landed.
//! * `reader`: [`DsmReader`], one thread's view of it, the
//!   [`crate::bvh::memory::TreeMemory`] a traversal reads and the
//!   [`crate::volume::BrickSource`] a volume march reads; when it parks its misses, a block
//!   that is not here reads as a stand-in no ray enters or hits (a brick as none, which a
//!   march passes), and the trace is void.
//! * [`volume`]: a volume's bricks, one a block after the triangles, and what every node holds
//!   whole of it (where it lies, its min/max grid) in a file of its own.
//! * [`particles`]: the particles' binary tree and the particles, two regions of blocks after
//!   the bricks, read through [`crate::spheres::SphereSource`].
//!
//! * [`series`]: a time series, every step's bricks one step after the other, the next
//!   step's fetched ahead while one is shown.

pub mod layout;
pub mod particles;
pub mod pool;
pub mod prepare;
mod reader;
pub mod reorder;
pub mod series;
pub mod tree;
pub mod volume;

pub use layout::{Block, BlockLayout, Chunk, LayoutError};

/// What a render node takes besides the scene it holds (its code, threads' stacks, QUIC and
/// socket buffers, frame buffers, the allocator's slack), which a memory budget must leave
/// room for before the block cache: measured as the peak resident memory of a render node
/// rendering an empty scene: 17-20 MiB on a 2x2 wall at 1 and 2 threads (debug and release
/// builds alike), rounded up.
pub const NODE_OVERHEAD_BYTES: u64 = 32 << 20;
pub use prepare::{Manifest, PrepareError};
pub use reader::{DsmReader, Pins};
pub use tree::{BlockFetch, DsmTree, DsmTreeStats, Landing, PinLimits};

use crate::bvh::Accel;
use crate::PreparedScene;

impl PreparedScene {
    /// A scene whose triangles, tree, volume bricks and particles are in shared memory: what
    /// its manifest holds whole (materials, lights, the slots' materials, the particles'
    /// attribute range), what `volume.bin` holds of its volume, and its blocks as this node
    /// holds them.
    pub fn from_shared(
        manifest: &Manifest,
        tree: DsmTree,
        volume: Option<crate::volume::SharedVolume>,
    ) -> PreparedScene {
        PreparedScene {
            // Only its depth is used: it sizes the traversal stacks.
            accel: Accel::from_parts(
                Vec::new(),
                Vec::new(),
                Vec::new(),
                manifest.max_depth as usize,
            ),
            shared: Some(tree),
            slot_material: manifest.slot_materials.clone(),
            // Textures and vertex colours stay with replicated scenes (see `prepare`).
            colors: None,
            materials: manifest.materials.clone(),
            blends: manifest.blends,
            lights: manifest.lights.clone(),
            diagonal: manifest.diagonal,
            spheres: manifest
                .particles
                .map(|_| crate::spheres::SphereAccel::shared(manifest.layout.sphere_count)),
            attribute_range: manifest
                .particles
                .map_or((f32::INFINITY, f32::NEG_INFINITY), |p| p.range()),
            volume: volume.map(|v| std::sync::Arc::new(crate::volume::PreparedVolume::shared(v))),
        }
    }
}

#[cfg(test)]
mod tests;
