//! Tessera's core: everything that is not I/O glue.
//!
//! The protocol state machines here ([`balance`], [`assemble`]) are sans-IO: they take messages
//! and the current time and return messages, so tests and the simulator drive them without
//! sockets. The node crates wrap them in thin tokio + quinn driver loops.

pub mod accel;
pub mod geometry;
pub mod render;
pub mod scene;
pub mod wall;
