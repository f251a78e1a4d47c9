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
        // Tests of one binary run in parallel: a number per server of this process, skipping
        // numbers whose socket another server (a leftover, another test binary) holds.
        static NEXT: AtomicU32 = AtomicU32::new(0);
        let number = (0..64)
            .map(|_| 100 + (std::process::id() % 200) * 4 + NEXT.fetch_add(1, Ordering::SeqCst))
            .find(|n| !Path::new(&format!("/tmp/.X11-unix/X{n}")).exists())
            .expect("a free X display number");
        let display = format!(":{number}");
        let child = Command::new("Xvfb")
            .args([
                display.as_str(),
                "-screen",
                "0",
                &format!("{size}x24"),
                "-nolisten",
                "tcp",
            ])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("start Xvfb");
        let mut xvfb = Xvfb { child, display };
        let socket = format!("/tmp/.X11-unix/X{number}");
        assert!(
            wait_for(Duration::from_secs(10), || Path::new(&socket).exists()),
            "Xvfb did not start on {}",
            xvfb.display
        );
        // A server that found its display taken exits at once; the socket is then another's.
        assert!(
            matches!(xvfb.child.try_wait(), Ok(None)),
            "Xvfb on {} exited at start",
            xvfb.display
        );
        Some(xvfb)
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
    /// or `None` if none appeared within `limit`.
    pub fn window(&self, title: &str, limit: Duration) -> Option<String> {
        let mut info = String::new();
        let found = wait_for(limit, || {
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
        found.then_some(info)
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

impl Drop for Xvfb {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
