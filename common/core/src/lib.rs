//! Tessera's sans-IO core: the state machines of a wall, with no socket, clock or thread.
//!
//! [`master::Master`] (every decision of the master: membership and rejoin, the ranks of a
//! shared scene, control and window input, present deadlines, the display-loss policies, the
//! figures and the report) holds [`balance::Coordinator`] (the load balancer, frame barrier
//! and wall states);
//! [`assemble::FrameAssembler`] (a display's frames, never a mix of states),
//! [`worker::RenderWorker`] (a render node's queue), [`node::render::RenderSession`] and
//! [`node::display::DisplaySession`] (what a render node and a display do with each message of
//! the master, around the worker and the assembler) and [`master::navigate::Navigator`] (window
//! input to state changes) take messages and `now` and return messages, following quinn-proto's
//! `handle_*` / `poll_*` convention, so tests drive whole frames deterministically and
//! [`sim::SimWall`] runs hundreds of virtual nodes in one process. The node crates wrap them
//! in thin tokio + quinn driver loops. [`impair::Impairment`] is the model of the UDP
//! relay that impairs a test wall's network. [`dsm`] is the read-only distributed shared
//! memory through which render nodes share a scene larger than any one node's memory: who
//! holds which block, the cache their threads share, and the protocol that fetches the rest.
//!
//! It depends on `tessera-model` and `tessera-protocol` for the messages and on nothing that does I/O: no tokio,
//! quinn, socket or clap crate may enter its dependency tree (a test in `tests/` checks).

#![warn(missing_docs)]

pub mod assemble;
pub mod balance;
pub mod dsm;
pub mod impair;
pub mod master;
pub mod node;
pub mod sim;
pub mod worker;
