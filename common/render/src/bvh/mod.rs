//! The bounding volume hierarchy.

pub mod cache;
mod coincident;
mod leaf_packet;
mod leaf_ray;
pub mod memory;
pub mod traverse_packet;
pub mod traverse_ray;
pub mod tree;
pub use tree::Accel;
