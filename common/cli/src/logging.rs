//! Log set-up shared by the binaries: to stderr, `RUST_LOG` filters (default `info`), colours
//! only on a terminal so that logs captured by a launcher or a test stay plain text.

use std::io::IsTerminal;

/// Installs this process's log subscriber; call it once (a second call panics), first thing
/// in `main`.
pub fn init() {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_target(false)
        .with_ansi(std::io::stderr().is_terminal())
        .with_writer(std::io::stderr)
        .init();
}
