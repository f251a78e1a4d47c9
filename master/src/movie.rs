//! Movies: `render --frames A..B --out DIR` renders every frame of a range in this process into
//! `DIR/frame-000123.png` (numbered by frame, six digits or more), from the flags' camera (the
//! orbit turns a degree a frame), a recorded session or a camera path (`--replay`); `--mp4
//! FILE` then encodes them with the system's `ffmpeg`. Each frame is the very image `render
//! --frame K` writes as `wall.png`.
//!
//! The scene is prepared once, and again only where a frame's state selects another step of
//! the scene's volume series (nothing else of a prepared scene depends on the state).

use crate::args::RenderArgs;
use crate::reference::{prepare, series_step, view_of, Setup};
use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Instant;
use tessera_cli::png::PngFile;
use tessera_model::wall::TileGrid;

/// `--frames`: the frames `first..end` (`end` not included).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameRange {
    /// The first frame rendered.
    pub first: u64,
    /// The frame after the last one rendered.
    pub end: u64,
}

impl FrameRange {
    /// How many frames the range holds (at least one).
    pub fn len(&self) -> u64 {
        self.end - self.first
    }

    /// Every frame of the range, in order.
    pub fn iter(&self) -> std::ops::Range<u64> {
        self.first..self.end
    }
}

/// Parses `--frames`: `A..B` is frames A to B-1, as a Rust range; `A..=B` includes B.
///
/// # Errors
/// Not of that form, B before A, or an empty range; clap names `--frames` with the message.
pub fn parse_frames(text: &str) -> Result<FrameRange, String> {
    let number = |s: &str, what: &str| {
        s.trim()
            .parse::<u64>()
            .map_err(|_| format!("{what} {s:?} of {text:?} is not a frame number (A..B or A..=B)"))
    };
    let (a, b, inclusive) = if let Some((a, b)) = text.split_once("..=") {
        (a, b, true)
    } else if let Some((a, b)) = text.split_once("..") {
        (a, b, false)
    } else {
        return Err(format!(
            "{text:?} is not a range: A..B (B not included) or A..=B"
        ));
    };
    let (first, last) = (number(a, "the start")?, number(b, "the end")?);
    if last < first {
        return Err(format!("{text:?} ends at {last}, before its start {first}"));
    }
    let end = if inclusive {
        last.checked_add(1)
            .ok_or_else(|| format!("{text:?} ends past the last frame number"))?
    } else {
        last
    };
    if end == first {
        return Err(format!(
            "{text:?} is empty (A..B leaves B out; {first}..={first} is frame {first} alone)"
        ));
    }
    Ok(FrameRange { first, end })
}

/// The PNG of frame `frame` in `dir`.
pub fn frame_file(dir: &Path, frame: u64) -> PathBuf {
    dir.join(format!("frame-{frame:06}.png"))
}

/// `render --frames`: every frame into `--out`, then the `--mp4` movie if asked.
///
/// # Errors
/// `--mp4` without `ffmpeg` on the PATH (said before anything renders), a replayed file
/// without a state for the first frame, a frame that cannot be written, ffmpeg failing.
pub fn render_movie(args: RenderArgs) -> Result<()> {
    let range = args.frames.context("render_movie needs --frames")?;
    let ffmpeg = match &args.mp4 {
        Some(_) => Some(find_on_path("ffmpeg").with_context(|| {
            format!(
                "--mp4 needs ffmpeg on the PATH (apt-get install ffmpeg); nothing was rendered: \
                 without --mp4 the PNGs alone go to {}",
                args.out.display()
            )
        })?),
        None => None,
    };
    let setup = Setup::load(&args, range.first)?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create --out {}", args.out.display()))?;
    let t0 = Instant::now();
    render_frames(&setup, range, &args.out)?;
    eprintln!(
        "rendered frames {}..={} of a {} ({}) in {:.1} s into {}",
        range.first,
        range.end - 1,
        setup.wall_size(),
        setup.scene_size(),
        t0.elapsed().as_secs_f64(),
        args.out.display()
    );
    if let (Some(ffmpeg), Some(mp4)) = (ffmpeg, &args.mp4) {
        let fps = args
            .fps
            .or(setup.fps)
            .unwrap_or(crate::camera_path::DEFAULT_FPS);
        encode(&ffmpeg, &args.out, range, fps, mp4)?;
        eprintln!(
            "wrote {} ({} frames at {fps} a second)",
            mp4.display(),
            range.len()
        );
    }
    Ok(())
}

/// Renders `range` into `dir`, preparing the scene again only where the series step changes.
fn render_frames(setup: &Setup, range: FrameRange, dir: &Path) -> Result<()> {
    let bar = indicatif::ProgressBar::new(range.len()).with_style(
        indicatif::ProgressStyle::with_template("frame {pos}/{len} {per_sec} eta {eta}")
            .expect("valid template"),
    );
    let grid = TileGrid::new(setup.wall.clone());
    let mut prepared = None;
    for frame in range.iter() {
        let state = setup.state_at(frame)?;
        let step = series_step(&setup.scene, &state.params);
        let scene = match prepared.take() {
            Some((ready, s)) if s == step => ready,
            _ => prepare(&setup.scene, &state.params)?,
        };
        let view = view_of(frame, &state, &setup.wall);
        let image = tessera_render::render_wall(&scene, &view, &grid);
        let path = frame_file(dir, frame);
        image
            .save_png(&path)
            .with_context(|| format!("frame {frame}"))?;
        prepared = Some((scene, step));
        bar.inc(1);
    }
    bar.finish_and_clear();
    Ok(())
}

/// The executable `name` in a directory of `$PATH`, as a shell would find it.
fn find_on_path(name: &str) -> Option<PathBuf> {
    use std::os::unix::fs::PermissionsExt;
    let path = std::env::var_os("PATH")?;
    std::env::split_paths(&path)
        .filter(|dir| !dir.as_os_str().is_empty())
        .map(|dir| dir.join(name))
        .find(|p| {
            std::fs::metadata(p).is_ok_and(|m| m.is_file() && m.permissions().mode() & 0o111 != 0)
        })
}

/// Encodes `dir`'s frames of `range` into the H.264 MP4 `mp4` at `fps` with `ffmpeg`.
fn encode(ffmpeg: &Path, dir: &Path, range: FrameRange, fps: u32, mp4: &Path) -> Result<()> {
    let pattern = dir.join("frame-%06d.png");
    let output = Command::new(ffmpeg)
        .args(["-hide_banner", "-loglevel", "error", "-y"])
        .args(["-framerate", &fps.to_string()])
        .args(["-start_number", &range.first.to_string()])
        .arg("-i")
        .arg(&pattern)
        // Frames left in DIR by a longer earlier run must not join the movie.
        .args(["-frames:v", &range.len().to_string()])
        // yuv420p, which every player reads, needs even sides; a wall's may be odd.
        .args(["-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2"])
        .args(["-c:v", "libx264", "-pix_fmt", "yuv420p"])
        .arg(mp4)
        .stdin(Stdio::null())
        .output()
        .with_context(|| format!("cannot run {}", ffmpeg.display()))?;
    if !output.status.success() {
        bail!(
            "{} failed ({}) encoding {}; the PNGs are in {}:\n{}",
            ffmpeg.display(),
            output.status,
            mp4.display(),
            dir.display(),
            String::from_utf8_lossy(&output.stderr).trim_end()
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_ranges_are_half_open_or_inclusive_and_never_empty() {
        assert_eq!(parse_frames("3..6"), Ok(FrameRange { first: 3, end: 6 }));
        assert_eq!(parse_frames("3..=6"), Ok(FrameRange { first: 3, end: 7 }));
        assert_eq!(parse_frames("5..=5").map(|r| r.len()), Ok(1));
        for (bad, words) in [
            ("5..5", "empty"),
            ("6..3", "before its start"),
            ("6..=3", "before its start"),
            ("3-6", "not a range"),
            ("a..6", "the start \"a\""),
            ("3..", "the end \"\""),
            ("0..=18446744073709551615", "past the last"),
        ] {
            let e = parse_frames(bad).unwrap_err();
            assert!(e.contains(words), "{bad}: {e}");
        }
    }

    #[test]
    fn frames_are_numbered_with_six_digits_or_more() {
        let dir = Path::new("out");
        assert_eq!(frame_file(dir, 123), Path::new("out/frame-000123.png"));
        assert_eq!(frame_file(dir, 1234567), Path::new("out/frame-1234567.png"));
    }
}
