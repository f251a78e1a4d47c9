//! Sessions as files: `--record FILE` writes what every frame is rendered with, one JSON line
//! each time it changes, and `--replay FILE` drives a wall from such a file, each state landing
//! on the frame it was recorded at. `render --replay FILE --frame K` renders frame K of a
//! recorded session in one process, which must equal what the wall showed: every interactive
//! session is a regression test.
//!
//! A line is self-contained: the frame, the state's id on the recording wall, the camera mode
//! (a fixed camera or the orbit, so frame K's camera follows from it), every quality knob, the
//! cutting planes and the lights, and the concrete camera of that frame for a person to read.
//! Lines are checked on reading as everything from outside is: a bad line is an error naming
//! the file and the line.

use anyhow::{bail, Context, Result};
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::Path;
use tessera_core::master::standby::SessionLine;
use tessera_model::camera::Camera;
use tessera_model::state::{StateId, WallState};
use tessera_protocol::FrameStart;

/// One line of a session file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Recorded {
    pub frame: u64,
    pub state: StateId,
    /// Everything the frame renders with; what a replay applies.
    pub wall: WallState,
    /// The camera of `frame` itself (the orbit's position there), for reading; not replayed.
    pub camera_at_frame: Camera,
    /// On the line of the first frame a standby master started after taking the wall over:
    /// its term and how long the wall was dark. Absent on every other line.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub takeover: Option<RecordedTakeover>,
}

/// A takeover as the session record holds it (`serve --standby-of`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecordedTakeover {
    /// The term of the master that took over.
    pub term: u64,
    /// From the old master's last word to this master's first presented frame.
    pub dark_ms: u64,
}

/// Writes a session file as the wall runs, on a thread of its own: the master's loop only
/// hands it lines, so a slow or full disk never holds up a frame, a heartbeat or a control
/// answer. Dropping it waits for the lines handed so far to be written.
pub struct Recorder {
    /// Lines for the writer; `None` once dropped.
    lines: Option<std::sync::mpsc::Sender<Vec<u8>>>,
    /// The writer, which ends with the first error it meets.
    writer: Option<std::thread::JoinHandle<Result<()>>>,
    last: Option<WallState>,
    /// The last frame started, written or not: a takeover is marked on it.
    last_started: Option<Recorded>,
}

impl Recorder {
    /// Creates the file `path` (here, so that a path that cannot be written fails the start)
    /// and the writer thread.
    ///
    /// # Errors
    /// The file cannot be created, or the thread started.
    pub fn create(path: &Path) -> Result<Recorder> {
        let file = std::fs::File::create(path)
            .with_context(|| format!("cannot create the --record file {}", path.display()))?;
        let name = path.display().to_string();
        let (lines, rx) = std::sync::mpsc::channel::<Vec<u8>>();
        let writer = std::thread::Builder::new()
            .name("record".into())
            .spawn(move || {
                let mut out = std::io::BufWriter::new(file);
                for line in rx {
                    // Flushed line by line: a session cut short by a crash is still a session
                    // up to there.
                    out.write_all(&line)
                        .and_then(|()| out.flush())
                        .with_context(|| format!("cannot write the --record file {name}"))?;
                }
                Ok(())
            })?;
        Ok(Recorder {
            lines: Some(lines),
            writer: Some(writer),
            last: None,
            last_started: None,
        })
    }

    /// Frame `start` begins with state `wall` (its mode, as the frame start holds only the
    /// frame's camera): a line if anything it renders with differs from the line before.
    ///
    /// # Errors
    /// The writer met an error with an earlier line (the disk is full).
    pub fn frame(&mut self, start: &FrameStart, wall: WallState) -> Result<()> {
        // The frame's own parameters, which refinement passes may have raised above the state's.
        let wall = WallState {
            params: start.params,
            ..wall
        };
        let line = Recorded {
            frame: start.frame.0,
            state: start.state,
            wall,
            camera_at_frame: start.camera,
            takeover: None,
        };
        self.last_started = Some(line.clone());
        self.write(line)
    }

    /// Marks the takeover of term `term` on the last frame started (the first this master
    /// presented): always a line, even where the state is the line before's.
    ///
    /// # Errors
    /// As [`Recorder::frame`].
    pub fn takeover(&mut self, term: u64, dark: std::time::Duration) -> Result<()> {
        let Some(mut line) = self.last_started.clone() else {
            return Ok(());
        };
        line.takeover = Some(RecordedTakeover {
            term,
            dark_ms: dark.as_millis() as u64,
        });
        self.last = None;
        self.write(line)
    }

    /// Writes the lines a primary master recorded before this master took its wall over
    /// (`serve --standby-of`), so that one file holds the whole run's session.
    ///
    /// # Errors
    /// As [`Recorder::frame`].
    pub fn taken_over(&mut self, lines: &[SessionLine]) -> Result<()> {
        for l in lines {
            self.write(Recorded {
                frame: l.frame.0,
                state: l.state,
                wall: l.wall,
                camera_at_frame: l.camera_at_frame,
                takeover: None,
            })?;
        }
        Ok(())
    }

    /// Writes `line` unless it renders as the line before.
    fn write(&mut self, line: Recorded) -> Result<()> {
        if self.last == Some(line.wall) {
            return Ok(());
        }
        self.last = Some(line.wall);
        let mut bytes = serde_json::to_vec(&line)?;
        bytes.push(b'\n');
        let sent = self.lines.as_ref().is_some_and(|l| l.send(bytes).is_ok());
        if !sent {
            // The writer ended: only an error ends it while lines may still come.
            return self.finish();
        }
        Ok(())
    }

    /// Stops the writer once it has written what it was handed, and says how it went.
    fn finish(&mut self) -> Result<()> {
        self.lines = None;
        match self.writer.take().map(std::thread::JoinHandle::join) {
            Some(Ok(result)) => result,
            Some(Err(_)) => bail!("the --record writer panicked"),
            None => Ok(()),
        }
    }
}

impl Drop for Recorder {
    fn drop(&mut self) {
        if let Err(e) = self.finish() {
            tracing::error!("{e:#}");
        }
    }
}

/// A session file, read and checked.
#[derive(Clone, Debug)]
pub struct Session {
    pub lines: Vec<Recorded>,
}

impl Session {
    pub fn load(path: &Path) -> Result<Session> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read the session file {}", path.display()))?;
        let mut lines: Vec<Recorded> = Vec::new();
        for (n, line) in text.lines().enumerate() {
            if line.trim().is_empty() {
                continue;
            }
            let recorded: Recorded = serde_json::from_str(line)
                .with_context(|| format!("{}: line {}", path.display(), n + 1))?;
            // A takeover's mark may come on a frame already written: it stands for it.
            if let Some(last) = lines.last_mut() {
                if recorded.frame == last.frame && recorded.takeover.is_some() {
                    *last = recorded;
                    continue;
                }
                if recorded.frame <= last.frame {
                    bail!(
                        "{}: line {}: frame {} does not come after frame {}",
                        path.display(),
                        n + 1,
                        recorded.frame,
                        last.frame
                    );
                }
            }
            lines.push(recorded);
        }
        if lines.is_empty() {
            bail!("the session file {} records no frame", path.display());
        }
        Ok(Session { lines })
    }

    /// The state each recorded frame starts with, for the master to replay.
    pub fn changes(&self) -> Vec<(tessera_protocol::FrameId, WallState)> {
        self.lines
            .iter()
            .map(|l| (tessera_protocol::FrameId(l.frame), l.wall))
            .collect()
    }

    /// The state frame `frame` was rendered with: the last line at or before it.
    pub fn state_at(&self, frame: u64) -> Result<WallState> {
        self.lines
            .iter()
            .rev()
            .find(|l| l.frame <= frame)
            .map(|l| l.wall)
            .with_context(|| {
                format!(
                    "the session starts at frame {}, after frame {frame}",
                    self.lines[0].frame
                )
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;
    use tessera_model::camera::CameraMode;
    use tessera_model::params::RenderParams;
    use tessera_protocol::FrameId;

    fn start(frame: u64, state: u64, ao: u32) -> (FrameStart, WallState) {
        let camera = Camera::new(Vec3::Z, Vec3::ZERO, Vec3::Y, 45.0).unwrap();
        let params = tessera_model::params::RenderParamsSpec {
            ao_samples: ao,
            ..RenderParams::interactive().spec()
        }
        .build()
        .unwrap();
        let wall = WallState {
            camera: CameraMode::fixed(camera),
            params,
            lights: None,
        };
        (
            FrameStart::new(FrameId(frame), StateId(state), camera, params),
            wall,
        )
    }

    /// A standby's record: the takeover marks the frame it first presented, even one with the
    /// state of the line before, and the file still loads and replays.
    #[test]
    fn a_takeover_is_marked_on_its_frame_and_the_session_still_loads() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.jsonl");
        let mut rec = Recorder::create(&path).unwrap();
        for frame in [0, 16] {
            let (s, w) = start(frame, frame, 0);
            rec.frame(&s, w).unwrap();
        }
        rec.takeover(1, std::time::Duration::from_millis(612))
            .unwrap();
        drop(rec);
        let session = Session::load(&path).unwrap();
        assert_eq!(session.lines.len(), 2);
        assert_eq!(
            session.lines[1].takeover,
            Some(RecordedTakeover {
                term: 1,
                dark_ms: 612
            })
        );
        assert!(session.lines[0].takeover.is_none());
    }

    #[test]
    fn a_recorded_session_reads_back_and_answers_for_every_frame() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.jsonl");
        let mut rec = Recorder::create(&path).unwrap();
        for (frame, state, ao) in [(0, 0, 0), (1, 0, 0), (2, 0, 0), (3, 1, 4), (4, 1, 4)] {
            let (s, w) = start(frame, state, ao);
            rec.frame(&s, w).unwrap();
        }
        drop(rec);
        let text = std::fs::read_to_string(&path).unwrap();
        assert_eq!(
            text.lines().count(),
            2,
            "a line per change, not per frame:\n{text}"
        );
        let session = Session::load(&path).unwrap();
        assert_eq!(session.state_at(2).unwrap().params.ao_samples(), 0);
        assert_eq!(session.state_at(3).unwrap().params.ao_samples(), 4);
        assert_eq!(session.state_at(99).unwrap().params.ao_samples(), 4);
    }

    #[test]
    fn bad_lines_are_errors_naming_the_line() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.jsonl");
        let mut rec = Recorder::create(&path).unwrap();
        let (s, w) = start(0, 0, 0);
        rec.frame(&s, w).unwrap();
        drop(rec);
        let good = std::fs::read_to_string(&path).unwrap();
        let bad = good.replace("\"ao_samples\":0", "\"ao_samples\":4000000000");
        std::fs::write(
            &path,
            format!("{good}{}", bad.replace("\"frame\":0", "\"frame\":5")),
        )
        .unwrap();
        let err = format!("{:#}", Session::load(&path).unwrap_err());
        assert!(
            err.contains("line 2") && err.contains("4000000000"),
            "{err}"
        );
        std::fs::write(&path, format!("{good}{good}")).unwrap();
        let err = format!("{:#}", Session::load(&path).unwrap_err());
        assert!(err.contains("does not come after"), "{err}");
    }
}
