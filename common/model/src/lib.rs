//! Tessera's domain model: what a wall is and what it shows, shared by every side of it.
//!
//! The wall's geometry and its tile grid ([`wall`]: a grid's virtual image, or physical
//! [`screens`] in millimetres, each with its own frustum; [`stereo`]: what each display shows,
//! one viewport an eye), where displays put their windows ([`window`]: wall files parsed and
//! checked from their text), and the state a frame is rendered with ([`state`], [`camera`],
//! [`params`], [`cut`], [`light`], [`scene_spec`], [`volume_params`], and [`local_origin`]:
//! where render coordinates sit in the world, for scenes far from the origin), window
//! [`input`], and whole-wall RGB [`image`]s. The messages that carry these between the master
//! and the nodes are `tessera-protocol`'s.
//!
//! Every type here that has an invariant is built through a validating constructor, and
//! deserializing goes through the same check ([`checked`]), so a value that breaks an invariant
//! never exists: a hostile or buggy peer gets a clear refusal, never a panic deeper in.
//!
//! It does no I/O: no file, socket, async runtime or command-line parser (reading wall files
//! and writing PNGs is `tessera-cli`'s), so the sans-IO core and the display nodes build on it.
//! It depends on serde, glam, toml and thiserror only.

#![warn(missing_docs)]

pub mod camera;
pub mod checked;
pub mod colormap;
pub mod cut;
pub mod image;
pub mod input;
pub mod light;
pub mod local_origin;
pub mod params;
pub mod scene_spec;
pub mod screens;
pub mod state;
pub mod stereo;
pub mod volume_params;
pub mod wall;
pub mod window;
