//! What every side of the wall shares: wall geometry, the messages on the wire, and the state
//! they carry (cameras, render parameters, cutting planes, scene names), plus whole-wall images.
//!
//! Every type here that has an invariant is built through a validating constructor, and
//! deserializing goes through the same check ([`checked`]), so a value that breaks an invariant
//! never exists: a hostile or buggy peer gets a clear refusal, never a panic deeper in.
//!
//! It depends on serialization and image crates only (serde, postcard, toml, glam, lz4_flex,
//! image): no async runtime, socket or command-line parser, so the sans-IO core can use it.

pub mod camera;
pub mod checked;
pub mod control;
pub mod cut;
pub mod image;
pub mod input;
pub mod light;
pub mod local_frame;
pub mod params;
pub mod protocol;
pub mod scene_spec;
pub mod screens;
pub mod state;
pub mod stereo;
pub mod volume_params;
pub mod wall;
pub mod window;
