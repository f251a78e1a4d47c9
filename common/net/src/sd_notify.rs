//! systemd's readiness protocol (`sd_notify(3)`): a node run by a `Type=notify` unit says
//! `READY=1` once it has joined its master and is ready for frames, and `STOPPING=1` when it
//! leaves, so that `systemctl start` returns when the node is really usable and units ordered
//! after it start then.
//!
//! The protocol is one datagram of `KEY=VALUE` lines to the `AF_UNIX` socket named by
//! `$NOTIFY_SOCKET` (a path, or an abstract name written with a leading `@`); a dozen lines of
//! std, so no crate for it. Outside systemd the variable is unset and every call does nothing.

use std::ffi::OsStr;
use std::io;
use std::os::unix::ffi::OsStrExt;
use std::os::unix::net::{SocketAddr, UnixDatagram};

/// The variable systemd sets for a `Type=notify` service.
pub const NOTIFY_SOCKET: &str = "NOTIFY_SOCKET";

/// Sends `state` (newline-separated `KEY=VALUE` lines, such as `"READY=1\nSTATUS=..."`) to
/// the service manager named by `$NOTIFY_SOCKET`. Returns `Ok(false)` without sending when
/// the variable is unset (the process is not a systemd service), `Ok(true)` once sent.
///
/// # Errors
/// The variable names no usable socket, or the datagram could not be sent.
pub fn notify(state: &str) -> io::Result<bool> {
    notify_with(std::env::var_os(NOTIFY_SOCKET).as_deref(), state)
}

/// [`notify`] with the socket given instead of read from the environment (`None`: not under
/// systemd, nothing sent).
///
/// # Errors
/// As [`notify`].
pub fn notify_with(socket: Option<&OsStr>, state: &str) -> io::Result<bool> {
    let Some(socket) = socket.filter(|s| !s.is_empty()) else {
        return Ok(false);
    };
    let addr = socket_addr(socket)?;
    let sender = UnixDatagram::unbound()?;
    let sent = sender.send_to_addr(state.as_bytes(), &addr)?;
    if sent != state.len() {
        return Err(io::Error::new(
            io::ErrorKind::WriteZero,
            format!(
                "only {sent} of {} bytes reached {NOTIFY_SOCKET}={}",
                state.len(),
                socket.to_string_lossy()
            ),
        ));
    }
    Ok(true)
}

/// Tells systemd the node is ready, with `status` as the line `systemctl status` shows. A
/// failure is logged, never fatal: the node works the same without a service manager.
pub fn ready(status: &str) {
    send_logged(&format!("READY=1\nSTATUS={}", one_line(status)));
}

/// Tells systemd the node is shutting down (it left its master's wall).
pub fn stopping(status: &str) {
    send_logged(&format!("STOPPING=1\nSTATUS={}", one_line(status)));
}

/// Updates the status line alone (waiting for a lost master, say).
pub fn status(status: &str) {
    send_logged(&format!("STATUS={}", one_line(status)));
}

fn send_logged(state: &str) {
    if let Err(e) = notify(state) {
        tracing::warn!(
            "cannot tell systemd {:?} through {NOTIFY_SOCKET}: {e} (the node goes on)",
            state.lines().next().unwrap_or_default()
        );
    }
}

/// A newline would start another `KEY=VALUE` line of the message.
fn one_line(text: &str) -> String {
    text.replace(['\n', '\r'], " ")
}

fn socket_addr(socket: &OsStr) -> io::Result<SocketAddr> {
    let bytes = socket.as_bytes();
    match bytes.first() {
        Some(b'/') => SocketAddr::from_pathname(socket),
        Some(b'@') => abstract_addr(&bytes[1..]),
        _ => Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            format!(
                "{NOTIFY_SOCKET}={} is neither an absolute path nor an abstract name (@NAME); \
                 other kinds (vsock:) are not supported",
                socket.to_string_lossy()
            ),
        )),
    }
}

#[cfg(target_os = "linux")]
fn abstract_addr(name: &[u8]) -> io::Result<SocketAddr> {
    use std::os::linux::net::SocketAddrExt;
    SocketAddr::from_abstract_name(name)
}

#[cfg(not(target_os = "linux"))]
fn abstract_addr(_name: &[u8]) -> io::Result<SocketAddr> {
    Err(io::Error::new(
        io::ErrorKind::Unsupported,
        "abstract socket names exist on Linux only",
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    fn receive(socket: &UnixDatagram) -> String {
        socket
            .set_read_timeout(Some(Duration::from_secs(5)))
            .unwrap();
        let mut buf = [0u8; 512];
        let n = socket.recv(&mut buf).expect("a datagram within 5 s");
        String::from_utf8(buf[..n].to_vec()).unwrap()
    }

    #[test]
    fn a_path_socket_receives_the_state() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("notify");
        let systemd = UnixDatagram::bind(&path).unwrap();
        assert!(notify_with(Some(path.as_os_str()), "READY=1\nSTATUS=joined").unwrap());
        assert_eq!(receive(&systemd), "READY=1\nSTATUS=joined");
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn an_abstract_socket_is_written_with_an_at_sign() {
        use std::os::linux::net::SocketAddrExt;
        let name = format!("tessera-sd-notify-test-{}", std::process::id());
        let addr = SocketAddr::from_abstract_name(name.as_bytes()).unwrap();
        let systemd = UnixDatagram::bind_addr(&addr).unwrap();
        let env = format!("@{name}");
        assert!(notify_with(Some(OsStr::new(&env)), "STOPPING=1").unwrap());
        assert_eq!(receive(&systemd), "STOPPING=1");
    }

    #[test]
    fn without_the_variable_nothing_is_sent() {
        assert!(!notify_with(None, "READY=1").unwrap());
        assert!(!notify_with(Some(OsStr::new("")), "READY=1").unwrap());
    }

    #[test]
    fn a_socket_that_is_not_a_path_is_named_in_the_error() {
        let e = notify_with(Some(OsStr::new("vsock:2:1234")), "READY=1").unwrap_err();
        assert!(e.to_string().contains("vsock:2:1234"), "{e}");
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("nobody-listens");
        assert!(notify_with(Some(missing.as_os_str()), "READY=1").is_err());
    }

    #[test]
    fn a_status_stays_on_one_line() {
        assert_eq!(one_line("a\nb\rc"), "a b c");
    }
}
