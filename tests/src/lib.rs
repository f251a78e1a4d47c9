//! Helpers for Tessera's end-to-end tests: find the built binaries, run them with a time bound,
//! and never leave a process behind.

#![warn(missing_docs)]

pub mod http;
pub mod webdriver;
pub mod xvfb;

use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Path of a workspace binary built next to the test executable.
pub fn bin(name: &str) -> PathBuf {
    let exe = std::env::current_exe().expect("test executable path");
    let deps = exe.parent().expect("deps dir");
    let dir = if deps.ends_with("deps") {
        deps.parent().expect("profile dir")
    } else {
        deps
    };
    let path = dir.join(name);
    assert!(
        path.exists(),
        "{} is missing: run the tests with `cargo test --workspace` (or nextest) so every binary is built",
        path.display()
    );
    path
}

/// Everything a child printed on one stream so far, collected by a thread of its own so that
/// a chatty child never blocks on a full pipe and a test can wait for a line to appear.
#[derive(Clone, Default)]
struct Captured {
    text: Arc<Mutex<String>>,
    /// Set once the stream reached its end (every writer closed it).
    done: Arc<AtomicBool>,
}

impl Captured {
    fn collect(stream: impl Read + Send + 'static) -> Captured {
        let captured = Captured::default();
        let (text, done) = (captured.text.clone(), captured.done.clone());
        std::thread::spawn(move || {
            let mut lines = BufReader::new(stream);
            let mut line = String::new();
            while lines.read_line(&mut line).is_ok_and(|n| n > 0) {
                text.lock().expect("capture lock").push_str(&line);
                line.clear();
            }
            done.store(true, Ordering::SeqCst);
        });
        captured
    }

    fn snapshot(&self) -> String {
        self.text.lock().expect("capture lock").clone()
    }

    /// The whole text once the stream has ended, or what there is after `limit` (a grandchild
    /// that outlived its parent can hold the pipe open).
    fn finish(&self, limit: Duration) -> String {
        wait_for(limit, || self.done.load(Ordering::SeqCst));
        self.snapshot()
    }
}

/// A child process that is killed and reaped when dropped, whatever the test does.
pub struct Proc {
    child: Option<Child>,
    /// What it was started as (a binary's name, a program's path), for failure messages.
    pub name: String,
    stdout: Captured,
    stderr: Captured,
    /// Where a process that would not finish was stuck, for the failure message.
    hang_report: String,
}

impl Proc {
    /// Starts the workspace binary `name` (found by [`bin`]) with `args`.
    pub fn start(name: &str, args: &[&str]) -> Proc {
        Self::start_with_env(name, args, &[])
    }

    /// [`Proc::start`] with the variables `env` set on top of the test's own environment.
    pub fn start_with_env(name: &str, args: &[&str], env: &[(&str, &str)]) -> Proc {
        Self::start_program(&bin(name), name, args, env)
    }

    /// Starts `program` in the working directory `dir`.
    pub fn start_in(program: &Path, dir: &Path, args: &[&str]) -> Proc {
        let name = program.display().to_string();
        Self::spawn(Command::new(program).current_dir(dir), &name, args, &[])
    }

    /// Starts any program (a script, say), not only a workspace binary.
    pub fn start_program(program: &Path, name: &str, args: &[&str], env: &[(&str, &str)]) -> Proc {
        Self::spawn(&mut Command::new(program), name, args, env)
    }

    fn spawn(cmd: &mut Command, name: &str, args: &[&str], env: &[(&str, &str)]) -> Proc {
        cmd.args(args)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        for (k, v) in env {
            cmd.env(k, v);
        }
        let mut child = cmd
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {name}: {e}"));
        let stdout = Captured::collect(child.stdout.take().expect("piped stdout"));
        let stderr = Captured::collect(child.stderr.take().expect("piped stderr"));
        Proc {
            child: Some(child),
            name: name.to_string(),
            stdout,
            stderr,
            hang_report: String::new(),
        }
    }

    /// Its process id.
    pub fn pid(&self) -> u32 {
        self.child.as_ref().expect("running").id()
    }

    /// Whether the process has already exited (it stays reapable for `wait`/`fail`).
    pub fn has_exited(&self) -> bool {
        let pid = self.pid() as i32;
        // SAFETY: siginfo_t is a plain C struct, for which all zero bytes are a valid value.
        let mut info: libc::siginfo_t = unsafe { std::mem::zeroed() };
        // WNOWAIT leaves the child to be reaped by `wait` later.
        // SAFETY: `info` is a live siginfo_t of ours that waitid only writes into; the call has
        // no other precondition.
        let r = unsafe {
            libc::waitid(
                libc::P_PID,
                pid as libc::id_t,
                &mut info,
                libc::WEXITED | libc::WNOHANG | libc::WNOWAIT,
            )
        };
        // SAFETY: si_pid reads a field of the union in `info`, which was zeroed and, if waitid
        // reported a child, filled by it with a child's record, which has that field.
        r == 0 && unsafe { info.si_pid() } == pid
    }

    /// Sends signal `sig` (`libc::SIGINT`, say) to the process.
    pub fn signal(&self, sig: i32) {
        // SAFETY: kill only sends a signal and touches no memory of ours. The pid is our child's,
        // not yet reaped (the `Child` is still held), so it names no other process.
        unsafe {
            libc::kill(self.pid() as i32, sig);
        }
    }

    /// Waits, at most `limit`, for a line of the process's stderr that contains `needle`, and
    /// returns it. Fails the test (with everything printed so far) if the process exits first
    /// or the time runs out: the event a test waits for, never a guess of how long it takes.
    pub fn wait_for_stderr(&self, needle: &str, limit: Duration) -> String {
        let find = || {
            self.stderr
                .snapshot()
                .lines()
                .find(|l| l.contains(needle))
                .map(str::to_string)
        };
        let deadline = Instant::now() + limit;
        while Instant::now() < deadline {
            if let Some(line) = find() {
                return line;
            }
            if self.has_exited() {
                break;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        find().unwrap_or_else(|| {
            panic!(
                "{} printed no line with {needle:?} within {limit:?} (exited: {})\nstderr:\n{}",
                self.name,
                self.has_exited(),
                self.stderr.snapshot()
            )
        })
    }

    /// Everything the process printed on stderr so far.
    pub fn stderr_so_far(&self) -> String {
        self.stderr.snapshot()
    }

    /// Kills the process and panics with `why` and everything it printed.
    pub fn fail(mut self, why: &str) -> ! {
        let mut child = self.child.take().expect("running");
        let _ = child.kill();
        let _ = child.wait();
        let stderr = self.stderr.finish(Duration::from_secs(5));
        panic!("{why}\n{} stderr:\n{stderr}", self.name);
    }

    /// Waits up to `limit`; on time-out kills the process and panics with its output.
    pub fn wait(mut self, limit: Duration) -> Output {
        let mut child = self.child.take().expect("running");
        let deadline = Instant::now() + limit;
        let status = loop {
            if let Some(status) = child.try_wait().expect("try_wait") {
                break Some(status);
            }
            if Instant::now() > deadline {
                self.hang_report = stacks_of(child.id());
                let _ = child.kill();
                let _ = child.wait();
                break None;
            }
            std::thread::sleep(Duration::from_millis(20));
        };
        let stdout = self.stdout.finish(Duration::from_secs(5));
        let stderr = self.stderr.finish(Duration::from_secs(5));
        match status {
            Some(status) => Output {
                status,
                stdout,
                stderr,
            },
            None => panic!(
                "{} did not finish within {limit:?}\nstderr (its last 80 lines):\n{}\n{}",
                self.name,
                last_lines(&stderr, 80),
                self.hang_report
            ),
        }
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

/// What a process that finished left behind: its exit status and everything it printed.
pub struct Output {
    /// How it exited.
    pub status: ExitStatus,
    /// Everything it wrote to stdout.
    pub stdout: String,
    /// Everything it wrote to stderr.
    pub stderr: String,
}

impl Output {
    /// Fails the test, naming `what` and showing stderr, unless the process exited with 0.
    pub fn assert_success(&self, what: &str) {
        assert!(
            self.status.success(),
            "{what} failed with {}\nstderr:\n{}",
            self.status,
            self.stderr
        );
    }

    /// The process failed (non-zero exit, not killed by a signal such as a panic's abort) and
    /// said something containing every one of `words` on stderr.
    pub fn assert_refused(&self, what: &str, words: &[&str]) {
        assert!(
            !self.status.success() && self.status.code().is_some(),
            "{what}: expected a clean refusal, got {}\nstderr:\n{}",
            self.status,
            self.stderr
        );
        assert!(
            !self.stderr.contains("panicked"),
            "{what}: panicked\n{}",
            self.stderr
        );
        for word in words {
            assert!(
                self.stderr.contains(word),
                "{what}: stderr does not name {word:?}\n{}",
                self.stderr
            );
        }
    }
}

/// Every thread's stack of process `pid`, from gdb where it is installed: what a hung
/// process was waiting for, which its log alone rarely says.
fn stacks_of(pid: u32) -> String {
    let out = Command::new("timeout")
        .args([
            "30",
            "gdb",
            "-p",
            &pid.to_string(),
            "-batch",
            "-ex",
            "thread apply all bt 30",
        ])
        .stdin(Stdio::null())
        .output();
    match out {
        Ok(o) if o.status.success() => format!(
            "its threads when it was given up on:\n{}",
            last_lines(&String::from_utf8_lossy(&o.stdout), 300)
        ),
        _ => "(gdb is not there to say where it hung)".into(),
    }
}

fn last_lines(text: &str, n: usize) -> String {
    let lines: Vec<&str> = text.lines().collect();
    lines[lines.len().saturating_sub(n)..].join("\n")
}

/// Says, where the person running the tests sees it, that a test skipped and why: the test
/// harness keeps a passing test's `eprintln!` to itself, so this writes to stderr directly.
pub fn skip(test: &str, why: &str) {
    use std::io::Write;
    let _ = writeln!(std::io::stderr(), "SKIPPED {test}: {why}");
}

/// Runs a binary to completion within `limit`.
pub fn run(name: &str, args: &[&str], limit: Duration) -> Output {
    Proc::start(name, args).wait(limit)
}

/// The `--connect ADDR --cert-dir DIR` of the control command that a local wall prints when
/// it starts (waited for, bounded by `limit`).
pub fn control_args(master: &Proc, limit: Duration) -> Vec<String> {
    let line = master.wait_for_stderr("control with", limit);
    let command = line
        .split('`')
        .nth(1)
        .unwrap_or_else(|| panic!("no command between backquotes in {line:?}"));
    let args: Vec<String> = command
        .split_whitespace()
        .skip(2) // tessera-master control
        .map(str::to_string)
        .collect();
    assert_eq!(
        args.first().map(String::as_str),
        Some("--connect"),
        "{line}"
    );
    args
}

/// Runs `tessera-master control CONNECT COMMAND...` to completion within `limit`.
pub fn control(connect: &[String], command: &[&str], limit: Duration) -> Output {
    let mut args: Vec<&str> = vec!["control"];
    args.extend(connect.iter().map(String::as_str));
    args.extend(command);
    run("tessera-master", &args, limit)
}

/// Renders frame `frame` of the recorded session `record` in one process (`render --replay`,
/// on the wall `wall` describes) into a folder under `scratch`, and asserts that the wall's
/// `shown` image of that frame is the same, pixel for pixel.
pub fn assert_shows_replayed_frame(
    wall: &[&str],
    record: &Path,
    frame: u64,
    shown: &Path,
    scratch: &Path,
) {
    let reference = scratch.join(format!("replayed-frame-{frame}"));
    let frame_arg = frame.to_string();
    let mut args = vec!["render"];
    args.extend(wall);
    args.extend([
        "--replay",
        record.to_str().unwrap(),
        "--frame",
        &frame_arg,
        "--out",
        reference.to_str().unwrap(),
    ]);
    run("tessera-master", &args, Duration::from_secs(120)).assert_success("render --replay");
    assert_same_pixels(
        shown,
        &reference.join("wall.png"),
        &format!("frame {frame} against the replayed session"),
    );
}

/// Asserts that two PNG files hold the same image, pixel for pixel.
pub fn assert_same_pixels(shown: &Path, expected: &Path, what: &str) {
    let (w, h, a) = load_rgb(shown);
    let (ew, eh, b) = load_rgb(expected);
    assert_eq!((w, h), (ew, eh), "{what}: sizes differ");
    let differing = a.iter().zip(&b).filter(|(x, y)| x != y).count();
    assert_eq!(differing, 0, "{what}: {differing} bytes differ");
}

/// Reads an image file (PNG, say) as its width, height and 8-bit RGB bytes, row by row;
/// panics if it cannot.
pub fn load_rgb(path: &Path) -> (u32, u32, Vec<u8>) {
    let img = image::open(path)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()))
        .to_rgb8();
    (img.width(), img.height(), img.into_raw())
}

/// Reads and parses a JSON file (a report, say); panics if it cannot.
pub fn read_json(path: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(path)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
    serde_json::from_str(&text).expect("valid JSON")
}

/// PIDs of live processes whose command line contains `needle` (to prove nothing is orphaned).
pub fn processes_mentioning(needle: &str) -> Vec<u32> {
    tessera_cli::procs::processes()
        .into_iter()
        .filter(|p| p.pid != std::process::id() && !p.zombie && p.args.join(" ").contains(needle))
        .map(|p| p.pid)
        .collect()
}

/// The nodes `parent` started as `role` (`render-node`, `display-node`): its children whose
/// command line runs that subcommand.
pub fn children(parent: u32, role: &str) -> Vec<u32> {
    tessera_cli::procs::children_of(parent)
        .into_iter()
        .filter(|c| c.runs(role))
        .map(|c| c.pid)
        .collect()
}

/// Polls `check` every 50 ms until it holds or `limit` passes.
pub fn wait_for(limit: Duration, mut check: impl FnMut() -> bool) -> bool {
    let deadline = Instant::now() + limit;
    while Instant::now() < deadline {
        if check() {
            return true;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    check()
}

/// Writes `DIR/ramp.vol.toml`: 8³ u8 voxels 1 mm apart whose value is 10 × their x index, a
/// volume whose value under any point is known. Returns the sidecar's path.
pub fn write_ramp_volume(dir: &Path) -> PathBuf {
    let values: Vec<u8> = (0..512).map(|i| (i % 8) as u8 * 10).collect();
    std::fs::write(dir.join("ramp.raw"), values).unwrap();
    let sidecar = dir.join("ramp.vol.toml");
    std::fs::write(
        &sidecar,
        "data = \"ramp.raw\"\ndims = [8, 8, 8]\ntype = \"u8\"\nspacing = [1.0, 1.0, 1.0]\n",
    )
    .unwrap();
    sidecar
}

/// Writes three `n`³ u8 steps into `dir`, each a ball (200) of a different size in 0, and
/// `balls.scene.toml` naming them by pattern; returns the scene file.
pub fn write_ball_series(dir: &Path, n: usize) -> std::path::PathBuf {
    let middle = (n as f32 - 1.0) / 2.0;
    let scale = n as f32 / 16.0;
    for step in 0..3usize {
        let radius = (3.0 + 2.0 * step as f32) * scale;
        let values: Vec<u8> = (0..n * n * n)
            .map(|i| {
                let (x, y, z) = (i % n, i / n % n, i / (n * n));
                let d = ((x as f32 - middle).powi(2)
                    + (y as f32 - middle).powi(2)
                    + (z as f32 - middle).powi(2))
                .sqrt();
                if d < radius {
                    200
                } else {
                    0
                }
            })
            .collect();
        std::fs::write(dir.join(format!("ball{step}.raw")), values).unwrap();
        std::fs::write(
            dir.join(format!("ball{step}.vol.toml")),
            format!("data = \"ball{step}.raw\"\ndims = [{n}, {n}, {n}]\ntype = \"u8\"\nspacing = [1.0, 1.0, 1.0]\n"),
        )
        .unwrap();
    }
    let scene = dir.join("balls.scene.toml");
    std::fs::write(&scene, "series = \"ball*.vol.toml\"\n").unwrap();
    scene
}

/// Issues the certificate of node `name` from the cluster CA in `cluster` with
/// `tessera-master issue-cert`, its role read from the name: `display-N` is display N's,
/// `control...` a control client's, anything else a render node's. Returns its directory.
pub fn issue_cert(cluster: &Path, name: &str) -> String {
    let out = cluster.join(name);
    let mut args = vec![
        "issue-cert".to_string(),
        "--cluster-dir".into(),
        cluster.display().to_string(),
        "--name".into(),
        name.into(),
        "--out".into(),
        out.display().to_string(),
        "--role".into(),
    ];
    match name.strip_prefix("display-") {
        Some(id) => args.extend(["display".into(), "--display".into(), id.into()]),
        None if name.starts_with("control") => args.push("control".into()),
        None => args.push("render".into()),
    }
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    run("tessera-master", &args, Duration::from_secs(30)).assert_success("issue-cert");
    out.display().to_string()
}

/// Whether the tests run as root (what starting daemons such as sshd or slurmd needs).
pub fn is_root() -> bool {
    // SAFETY: geteuid has no preconditions and cannot fail.
    unsafe { libc::geteuid() == 0 }
}

/// Where `tool` is: on `$PATH`, or in `/usr/sbin` and `/sbin`, which a non-login root shell's
/// `$PATH` may lack.
pub fn find_tool(tool: &str) -> Option<PathBuf> {
    let path = std::env::var_os("PATH").unwrap_or_default();
    std::env::split_paths(&path)
        .chain(["/usr/sbin", "/sbin", "/usr/bin"].map(PathBuf::from))
        .map(|dir| dir.join(tool))
        .find(|p| p.is_file())
}

/// Finds every tool `test` needs. Where one is missing the test is skipped, saying which and
/// how to install it, except under CI (`CI=true`), whose `.ci/run` installs them: there a
/// missing tool fails the test. Returns the tools' paths in the order asked, or `None` to skip.
pub fn require_tools(test: &str, tools: &[&str], install: &str) -> Option<Vec<PathBuf>> {
    let found: Vec<Option<PathBuf>> = tools.iter().map(|t| find_tool(t)).collect();
    let missing: Vec<&str> = tools
        .iter()
        .zip(&found)
        .filter(|(_, f)| f.is_none())
        .map(|(t, _)| *t)
        .collect();
    if missing.is_empty() {
        return Some(found.into_iter().flatten().collect());
    }
    let why = format!("{} not installed ({install})", missing.join(", "));
    assert!(
        !std::env::var("CI").is_ok_and(|v| v == "true"),
        "CI=true but {test} cannot run: {why}; .ci/run should have installed it"
    );
    skip(test, &why);
    None
}
