//! The bounding volume hierarchy, laid out by job as Embree's `kernels/bvh` is: the node
//! formats, the tree's memory, the node and leaf tests, the build, and one traversal per kind of
//! ray, each in its own file.
//!
//! Files use only files of lower layers (`use` lines go downwards; no two files use each
//! other), lowest first:
//!
//! 1. `node`: the node formats (binary, 8-wide), the leaf triangle, the hit.
//! 2. `memory` (where a traversal reads the tree: [`memory::TreeMemory`]), `collapse` (binary
//!    to 8-wide), `coincident` (groups of equal boxes), `node_test_ray` (a ray against a node's
//!    children), `leaf_ray` and `leaf_packet` (a leaf's triangles against a ray, or a packet).
//! 3. `node_test_packet` (a packet against a box or a node's children, on `node_test_ray`'s
//!    finite inverses), `tree` ([`Accel`]: the arrays, on `collapse` and `memory`) and
//!    `layout` (obvhs' binary tree laid out again depth first, split over the threads, with
//!    `memory`'s prefetch).
//! 4. `build` (obvhs' build, with `coincident`, `layout` and `collapse`) and `traverse_ray`
//!    (single rays).
//! 5. `cache` (the built tree on disk, on `build`) and `traverse_packet` (64-ray packets, which
//!    fall back to `traverse_ray`).
//!
//! Outside `bvh`, it uses only the crate's lower modules (`geometry`, `packet`, `isa`,
//! `scene`); the distributed shared memory (`dsm`) and the [`crate::Tracer`] build on it.

mod build;
pub mod cache;
mod coincident;
pub mod collapse;
mod layout;
mod leaf_packet;
mod leaf_ray;
pub mod memory;
pub mod node;
mod node_test_packet;
mod node_test_ray;
pub mod traverse_packet;
pub mod traverse_ray;
mod tree;

pub use tree::{Accel, TreeSah};
