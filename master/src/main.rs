//! `tessera-master`: everything it does is in the library (`tessera_master`).

use clap::Parser;
use std::process::ExitCode;

fn main() -> ExitCode {
    tessera_cli::logging::init();
    tessera_master::main(tessera_master::Cli::parse())
}
