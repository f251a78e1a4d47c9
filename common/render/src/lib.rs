//! Tessera's renderer: scenes and their loaders, the BVH, 64-ray packets and shading. Render
//! nodes and the master's reference render link it; display nodes never compile it.
//!
//! A frame is rendered by [`render_tiles`] from a [`PreparedScene`] (the scene and its BVH) and
//! a [`FrameView`] (camera rays and [`tessera_model::params::RenderParams`]). Every pixel is a
//! pure function of those and the pixel, so any render node draws a tile byte for byte as the
//! single-process reference ([`render_wall`]) does.
//!
//! The BVH is [`bvh`], laid out by job as Embree's `kernels/bvh`: node formats, tree memory,
//! node and leaf tests, build, cache, and one traversal each for single rays and for packets,
//! whose files use one another in one direction only (the layers are in its documentation).
//! Above it, [`Tracer`] picks the memory a render thread reads the tree from (this process's
//! arrays or the distributed shared memory, [`dsm`]), and shading traces through a `Tracer`:
//! `frame` renders tiles, `shade` and `shadow_packet` both work from `surface_hit` (what a ray
//! hit, and the geometry there) and not from each other, all of them from `prepared` (the
//! scene and the frame they trace with, which uses none of them), and [`aov`] draws the AOVs. The SIMD
//! build of the traversals, and of `lanes` (the eye light's colours and the 8-bit encoding of
//! `frame`), is chosen at run time, the same way for every entry point (`isa_builds!` in
//! [`isa`]).
//!
//! Coordinates are read in f64 and moved near the render origin before they become f32
//! (meshes, particles, volumes and scenes of several alike); volume values keep their scale
//! but normals are computed scale-free, and NaN is missing data. [`stiff`] renders any scene
//! moved, rescaled and with its values scaled, against its plain picture (`bench stiff`).
//!
//! It depends on `tessera-model` for the state it renders with (camera, parameters, scene name,
//! wall geometry) and on compute and file-format crates (obvhs, rayon, tobj, gltf, ply-rs);
//! never on an async runtime, socket or command-line crate.

#![warn(missing_docs)]
// Packets are structures of arrays: a lane index addresses several arrays at once, which is
// clearer as `for i in 0..n` than as zipped iterators.
#![allow(clippy::needless_range_loop)]

pub mod aov;
pub mod bench;
pub mod bvh;
mod cancel;
pub mod dsm;
mod frame;
pub mod geometry;
pub mod isa;
mod lanes;
pub mod packet;
mod parking;
mod pixel_rays;
mod prepared;
mod reference;
pub mod sampling;
pub mod scene;
mod shade;
mod shadow_packet;
mod slot_colors;
pub mod slot_materials;
pub mod spheres;
pub mod stiff;
mod surface_hit;
mod tracer;
mod views;
pub mod volume;

#[cfg(test)]
mod render_tests;
#[cfg(test)]
mod stiff_tests;

pub use cancel::Cancel;
pub use frame::{render_tiles, render_tiles_footprints, render_tiles_linear, PACKET};
pub use pixel_rays::{orbit_of, PixelRays};
pub use prepared::{FrameView, PreparedScene, RayCounts};
pub use reference::{render_wall, render_wall_linear};
pub use shade::{background, encode_srgb_ish, Shader, MAX_DEPTH};
pub use surface_hit::{nearest_surface, offset_origin, surface, SurfaceHit};
pub use tracer::Tracer;
