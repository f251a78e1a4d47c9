//! What a render node and a display node do with each message of a session, without the
//! sockets: [`render::RenderSession`] and [`display::DisplaySession`].
//!
//! A session runs from the master's welcome to its shutdown. Its driver loop (in the node
//! crates) reads the clock and moves bytes: it hands a session each message from the master,
//! each finished batch or tile and each timer that fires, with `now`, and then carries out what
//! the session's `poll_*` methods return, in the order they document. Every decision in
//! between (which tiles to render next, when to ask for more, which volume step a batch needs,
//! which display to give up on, what a present shows, what to report) is taken
//! here, so a test runs a whole session on a virtual clock.

pub mod display;
pub mod render;
pub mod term;

#[cfg(test)]
mod display_tests;
#[cfg(test)]
mod render_tests;
