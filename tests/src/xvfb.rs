//! A private X server for the tests that open windows: started on a display number of its
//! own, waited for (its socket appears), killed and reaped when dropped. Where the tools are
//! missing the test is skipped, saying so, except under CI (`CI=true`), where that fails.

use crate::{skip, wait_for};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::Duration;

/// A private X server, running; killed and reaped when dropped.
pub struct Xvfb {
    child: Child,
    /// `:N`, for `DISPLAY`.
    pub display: String,
}

fn have(tool: &str) -> bool {
    Command::new("sh")
        .args(["-c", &format!("command -v {tool}")])
        .stdout(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

/// `deploy/xvfb-screenshot.sh`, which installs the tools and grabs a window.
pub fn screenshot_script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/xvfb-screenshot.sh")
}

impl Xvfb {
    /// An X server with one `size` screen (e.g. "800x600"), or `None` (after saying why)
    /// where `tools` are not installed and the test may skip.
    pub fn start(test: &str, size: &str, tools: &[&str]) -> Option<Xvfb> {
        let missing: Vec<&str> = ["Xvfb"]
            .iter()
            .chain(tools)
            .copied()
            .filter(|t| !have(t))
            .collect();
        if !missing.is_empty() {
            let msg = format!("{missing:?} not installed (run deploy/xvfb-screenshot.sh install)");
            assert!(
                std::env::var("CI").is_err(),
                "CI is set, so this may not skip: {msg}"
            );
            skip(test, &msg);
            return None;
        }
        // A server that dies while it starts (once in CI: the first Xvfb after its install,
        // started beside two others) is started again on another number; what it said is
        // printed, and after three such deaths the test fails with it.
        let mut deaths = Vec::new();
        for _ in 0..3 {
            match Self::start_once(size) {
                Ok(xvfb) => return Some(xvfb),
                Err(why) => {
                    eprintln!("{test}: {why}");
                    deaths.push(why);
                }
            }
        }
        panic!("Xvfb did not start: {deaths:#?}");
    }

    /// One server, ready to take clients, or why not (its own words where it said any).
    fn start_once(size: &str) -> Result<Xvfb, String> {
        // Tests of one binary run in parallel: a number per server of this process, skipping
        // numbers whose socket another server (a leftover, another test binary) holds.
        static NEXT: AtomicU32 = AtomicU32::new(0);
        let number = (0..64)
            .map(|_| 100 + (std::process::id() % 200) * 4 + NEXT.fetch_add(1, Ordering::SeqCst))
            .find(|n| !Path::new(&format!("/tmp/.X11-unix/X{n}")).exists())
            .expect("a free X display number");
        let display = format!(":{number}");
        let log = tempfile::NamedTempFile::new().expect("a file for Xvfb's messages");
        let child = Command::new("Xvfb")
            .args([
                display.as_str(),
                "-screen",
                "0",
                &format!("{size}x24"),
                "-nolisten",
                "tcp",
                // An X server resets when its last client leaves: the readiness probe below
                // is one, and a display that connected during the reset was refused ("Failed
                // to open connection to X server"; once in CI, reproduced under load).
                "-noreset",
            ])
            .stdout(Stdio::null())
            .stderr(log.reopen().expect("Xvfb's log"))
            .spawn()
            .expect("start Xvfb");
        let mut xvfb = Xvfb { child, display };
        let socket = format!("/tmp/.X11-unix/X{number}");
        // The socket appears before the server has set itself up (its keyboard map among
        // other things), and a server that then fails leaves it behind: ready is when a
        // client's connection is accepted.
        let ready = wait_for(Duration::from_secs(10), || {
            accepts_a_client(&socket) || !matches!(xvfb.child.try_wait(), Ok(None))
        });
        let said = || std::fs::read_to_string(log.path()).unwrap_or_default();
        match xvfb.child.try_wait() {
            Ok(None) if ready => Ok(xvfb),
            Ok(None) => Err(format!(
                "Xvfb on {} took no client within 10 s: {}",
                xvfb.display,
                said()
            )),
            _ => Err(format!(
                "Xvfb on {} exited at start: {}",
                xvfb.display,
                said()
            )),
        }
    }

    /// Runs an X client (xdotool, xwininfo) on this server and returns its stdout.
    pub fn client(&self, program: &str, args: &[&str]) -> String {
        let out = Command::new(program)
            .args(args)
            .env("DISPLAY", &self.display)
            .output()
            .unwrap_or_else(|e| panic!("cannot run {program}: {e}"));
        assert!(
            out.status.success(),
            "{program} {args:?} failed: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout).into_owned()
    }

    /// Waits for a mapped window titled `title` and returns `xwininfo`'s description of it,
    /// or `None` if none appeared within `limit` or `alive` says the program that would open it
    /// is gone (its output then says why, at once instead of after `limit`).
    pub fn window(&self, title: &str, limit: Duration, alive: impl Fn() -> bool) -> Option<String> {
        let mut info = String::new();
        let found = wait_for(limit, || {
            if !alive() {
                return true;
            }
            let out = Command::new("xwininfo")
                .args(["-name", title])
                .env("DISPLAY", &self.display)
                .output();
            info = out.map_or_else(
                |_| String::new(),
                |o| String::from_utf8_lossy(&o.stdout).into_owned(),
            );
            info.contains("IsViewable")
        });
        (found && info.contains("IsViewable")).then_some(info)
    }

    /// Grabs the window titled `title` into `shot` until it shows exactly `expected` (RGB,
    /// `width`×`height`), for at most `limit`; on failure returns what the last grab showed.
    /// Polling is needed because a window presents a saved frame shortly after it is saved.
    pub fn wait_for_window_image(
        &self,
        title: &str,
        (width, height, expected): (u32, u32, &[u8]),
        shot: &Path,
        limit: Duration,
    ) -> Result<(), String> {
        let mut last = String::from("no grab succeeded");
        let matched = wait_for(limit, || {
            let grabbed = Command::new("bash")
                .arg(screenshot_script())
                .args(["grab", title, shot.to_str().unwrap()])
                .env("DISPLAY", &self.display)
                .status()
                .is_ok_and(|s| s.success());
            if !grabbed {
                return false;
            }
            let (w, h, pixels) = crate::load_rgb(shot);
            let differing = pixels.iter().zip(expected).filter(|(a, b)| a != b).count();
            last = format!("{w}x{h}, {differing} bytes differ");
            (w, h) == (width, height) && differing == 0
        });
        if matched {
            Ok(())
        } else {
            Err(last)
        }
    }
}

/// A number `xwininfo` prints after `label` (e.g. "Absolute upper-left X:").
pub fn xwininfo_field(info: &str, label: &str) -> i64 {
    info.lines()
        .find_map(|l| l.trim().strip_prefix(label))
        .and_then(|v| v.trim().parse().ok())
        .unwrap_or_else(|| panic!("no {label:?} in:\n{info}"))
}

/// Whether the X server at unix socket `socket` accepts a connection: the setup request of the
/// X protocol (little-endian, version 11.0, no authorization), answered with success (1).
fn accepts_a_client(socket: &str) -> bool {
    use std::io::{Read, Write};
    let Ok(mut stream) = std::os::unix::net::UnixStream::connect(socket) else {
        return false;
    };
    let _ = stream.set_read_timeout(Some(Duration::from_secs(2)));
    let setup = [b'l', 0, 11, 0, 0, 0, 0, 0, 0, 0, 0, 0];
    let mut answer = [0u8; 1];
    stream.write_all(&setup).is_ok() && stream.read_exact(&mut answer).is_ok() && answer[0] == 1
}

impl Drop for Xvfb {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
