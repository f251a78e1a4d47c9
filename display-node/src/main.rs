//! `tessera-display-node`: the display node as a program of its own, for display hosts.
//! Everything it does is in the library (`tessera_display_node`), which `tessera-master` also
//! runs.

use clap::Parser;
use std::process::ExitCode;

fn main() -> ExitCode {
    tessera_cli::logging::init();
    tessera_display_node::main(tessera_display_node::Cli::parse())
}
