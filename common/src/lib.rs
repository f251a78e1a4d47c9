//! Tessera's core: everything that is not I/O glue.
//!
//! The protocol state machines here ([`balance`], [`assemble`]) are sans-IO: they take messages
//! and the current time and return messages, so tests and the simulator drive them without
//! sockets. The node crates wrap them in thin tokio + quinn driver loops.

// Packets are structures of arrays: a lane index addresses several arrays at once, which is
// clearer as `for i in 0..n` than as zipped iterators.
#![allow(clippy::needless_range_loop)]

pub mod accel;
pub mod accel_cache;
pub mod accel_packet;
pub mod assemble;
pub mod balance;
pub mod cli;
pub mod geometry;
pub mod image_io;
pub mod logging;
pub mod net;
pub mod protocol;
pub mod render;
pub mod scene;
pub mod sim;
pub mod spheres;
pub mod wall;
pub mod worker;
