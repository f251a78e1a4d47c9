//! `tessera-render-node`: the render node as a program of its own, for render hosts. Everything
//! it does is in the library (`tessera_render_node`), which `tessera-master` also runs.

use clap::Parser;
use std::process::ExitCode;

fn main() -> ExitCode {
    tessera_cli::logging::init();
    tessera_render_node::main(tessera_render_node::Cli::parse())
}
