//! Camera paths: a few keyframes in a TOML file, interpolated into a camera for every frame
//! between the first and the last, so that a fly-through is written by hand rather than
//! recorded. A path is a session too: `render --replay PATH.toml` renders it (one frame with
//! `--frame K`, a movie with `--frames A..B`) and a wall's `--replay PATH.toml` plays it.
//!
//! ```toml
//! fps = 30                       # optional (default 30): the movie's rate, what `time` counts in
//! interpolation = "catmull-rom"  # optional: "catmull-rom" (default) or "linear"
//!
//! [[key]]
//! frame = 0                      # or `time = 0.0`, in seconds (frame = round(time × fps))
//! eye = [0.0, 1.0, 5.0]          # world coordinates, like --eye
//! target = [0.0, 0.0, 0.0]       # like --target
//! up = [0.0, 1.0, 0.0]           # optional: the previous key's, else +y
//! fov = 45.0                     # optional, degrees: the previous key's, else 45
//!
//! [[key]]
//! time = 2.0
//! eye = [5.0, 1.0, 0.0]
//! target = [0.0, 0.0, 0.0]
//! ```
//!
//! Keys come in strictly increasing frames; the path covers the frames from its first key to
//! its last, and a wall replaying it holds the last key's camera afterwards. Between keys the
//! eye and the target follow a Catmull-Rom spline through the keys (tangents from the
//! neighbouring keys, scaled by their spacing in frames, so unevenly spaced keys keep an even
//! speed; one-sided at the ends) or straight lines; `up` is interpolated linearly and
//! normalized; the field of view linearly. Every frame's camera is checked as a camera given
//! on the command line is: a path whose eye passes through its target, or whose up turns
//! parallel to the view, is refused, naming the frame and the keys it lies between.
//!
//! The quality, the cutting planes and the lights are not part of a path: they are the
//! flags' (`render`) or the wall's own.

use crate::record::{Recorded, Session};
use anyhow::{bail, Context, Result};
use glam::DVec3;
use serde::Deserialize;
use std::path::Path;
use tessera_model::camera::{Camera, CameraMode, DEFAULT_FOV_DEG};
use tessera_model::local_origin::RenderFromWorld;
use tessera_model::params::RenderParams;
use tessera_model::state::{StateId, WallState};

/// Frames a second of a path that names none, and of a movie of a recorded session.
pub const DEFAULT_FPS: u32 = 30;

/// Most frames one path may span (a day at 30 frames a second would be 2.6 million; a path
/// becomes one state a frame, so a typo of a frame number must not exhaust memory).
pub const MAX_PATH_FRAMES: u64 = 1_000_000;

/// How the eye and the target move between keys.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Interpolation {
    /// Straight lines from key to key (a corner at every key).
    Linear,
    /// A smooth curve through every key.
    #[default]
    CatmullRom,
}

/// The file as written.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct PathFile {
    fps: Option<u32>,
    #[serde(default)]
    interpolation: Interpolation,
    #[serde(default)]
    key: Vec<KeyFile>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct KeyFile {
    frame: Option<u64>,
    time: Option<f64>,
    eye: [f64; 3],
    target: [f64; 3],
    up: Option<[f64; 3]>,
    fov: Option<f64>,
}

/// One keyframe, checked: world coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Key {
    /// The frame the camera is exactly this one at.
    pub frame: u64,
    /// The pinhole, in world coordinates.
    pub eye: DVec3,
    /// The point looked at, in world coordinates.
    pub target: DVec3,
    /// Roughly up (unit length).
    pub up: DVec3,
    /// Vertical field of view, degrees.
    pub fov_y_deg: f64,
}

/// A camera path, read and checked (see the module documentation for the file).
#[derive(Clone, Debug, PartialEq)]
pub struct CameraPath {
    /// Frames a second the path was written for.
    pub fps: u32,
    /// How the eye and the target move between keys.
    pub interpolation: Interpolation,
    /// At least one key, in strictly increasing frames.
    pub keys: Vec<Key>,
}

/// Whether `path` names a camera path (a `.toml` file) rather than a recorded session.
pub fn is_camera_path(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("toml"))
}

impl CameraPath {
    /// Reads and checks the camera path file `path`.
    ///
    /// # Errors
    /// The file cannot be read, is not TOML of this form (the error gives the line), or a key
    /// is wrong: the error names the file, the key (counted from 1) and the field.
    pub fn load(path: &Path) -> Result<CameraPath> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read the camera path {}", path.display()))?;
        Self::parse(&text).with_context(|| format!("camera path {}", path.display()))
    }

    /// Parses and checks a camera path's text.
    ///
    /// # Errors
    /// As [`CameraPath::load`], without the file's name.
    pub fn parse(text: &str) -> Result<CameraPath> {
        let file: PathFile = toml::from_str(text).map_err(|e| anyhow::anyhow!("{e}"))?;
        let fps = file.fps.unwrap_or(DEFAULT_FPS);
        if fps == 0 || fps > 1000 {
            bail!("fps {fps} must be between 1 and 1000");
        }
        if file.key.is_empty() {
            bail!("no [[key]]: a path needs at least one keyframe");
        }
        let mut keys: Vec<Key> = Vec::with_capacity(file.key.len());
        for (i, k) in file.key.iter().enumerate() {
            let key = check_key(k, keys.last(), fps).with_context(|| format!("key {}", i + 1))?;
            if let Some(last) = keys.last() {
                if key.frame <= last.frame {
                    bail!(
                        "key {}: frame {} does not come after key {}'s frame {}",
                        i + 1,
                        key.frame,
                        i,
                        last.frame
                    );
                }
                if key.frame - keys[0].frame >= MAX_PATH_FRAMES {
                    bail!(
                        "key {}: frame {} is more than {MAX_PATH_FRAMES} frames after the first key's {}",
                        i + 1,
                        key.frame,
                        keys[0].frame
                    );
                }
            }
            keys.push(key);
        }
        Ok(CameraPath {
            fps,
            interpolation: file.interpolation,
            keys,
        })
    }

    /// The frames the path covers: its first key's to its last key's, both included.
    pub fn frames(&self) -> std::ops::RangeInclusive<u64> {
        self.keys[0].frame..=self.keys[self.keys.len() - 1].frame
    }

    /// Eye, target, up (unit) and field of view at `frame`, in world coordinates; before the
    /// first key the first key's, after the last the last's.
    pub fn world_at(&self, frame: u64) -> Key {
        let keys = &self.keys;
        let i = keys.partition_point(|k| k.frame <= frame);
        if i == 0 {
            return keys[0];
        }
        if i == keys.len() {
            return keys[i - 1];
        }
        let (a, b) = (&keys[i - 1], &keys[i]);
        let span = (b.frame - a.frame) as f64;
        let t = (frame - a.frame) as f64 / span;
        let along = |p: fn(&Key) -> DVec3| match self.interpolation {
            Interpolation::Linear => p(a).lerp(p(b), t),
            Interpolation::CatmullRom => {
                let (ma, mb) = (self.tangent(i - 1, p), self.tangent(i, p));
                hermite(p(a), ma * span, p(b), mb * span, t)
            }
        };
        Key {
            frame,
            eye: along(|k| k.eye),
            target: along(|k| k.target),
            up: a.up.lerp(b.up, t).normalize_or_zero(),
            fov_y_deg: a.fov_y_deg + (b.fov_y_deg - a.fov_y_deg) * t,
        }
    }

    /// The velocity (per frame) of the spline at key `i`: from its neighbours' difference,
    /// one-sided at the ends.
    fn tangent(&self, i: usize, p: fn(&Key) -> DVec3) -> DVec3 {
        let keys = &self.keys;
        let (lo, hi) = (i.saturating_sub(1), (i + 1).min(keys.len() - 1));
        (p(&keys[hi]) - p(&keys[lo])) / (keys[hi].frame - keys[lo].frame) as f64
    }

    /// The camera of `frame`, in the render coordinates of `frame_of`.
    ///
    /// # Errors
    /// The interpolated camera is not one (eye on the target, up along the view): the error
    /// names the frame and the keys around it.
    pub fn camera_at(&self, frame: u64, frame_of: &RenderFromWorld) -> Result<Camera> {
        let k = self.world_at(frame);
        Camera::new(
            frame_of.point(k.eye),
            frame_of.point(k.target),
            k.up.as_vec3(),
            k.fov_y_deg as f32,
        )
        .with_context(|| {
            let i = self.keys.partition_point(|k| k.frame <= frame);
            format!(
                "the camera path's frame {frame} (between key {i} and key {}) is no camera",
                i + 1
            )
        })
    }

    /// The path as a session: a fixed camera a frame (a line wherever it changes), each
    /// with `params` and the scene's lights.
    ///
    /// # Errors
    /// A frame's camera is no camera (see [`CameraPath::camera_at`]).
    pub fn session(&self, frame_of: &RenderFromWorld, params: RenderParams) -> Result<Session> {
        let mut lines: Vec<Recorded> = Vec::new();
        for frame in self.frames() {
            let camera = self.camera_at(frame, frame_of)?;
            let wall = WallState {
                camera: CameraMode::fixed(camera),
                params,
                lights: None,
            };
            if lines.last().is_some_and(|l| l.wall == wall) {
                continue;
            }
            lines.push(Recorded {
                frame,
                state: StateId(lines.len() as u64),
                wall,
                camera_at_frame: camera,
                takeover: None,
            });
        }
        Ok(Session { lines })
    }
}

/// Key `k` checked, its missing `up` and `fov` taken from the key before.
fn check_key(k: &KeyFile, before: Option<&Key>, fps: u32) -> Result<Key> {
    let frame = match (k.frame, k.time) {
        (Some(frame), None) => frame,
        (None, Some(time)) if time.is_finite() && time >= 0.0 => {
            let frame = (time * f64::from(fps)).round();
            if frame >= (MAX_PATH_FRAMES * 1000) as f64 {
                bail!("`time` {time} is too late");
            }
            frame as u64
        }
        (None, Some(time)) => bail!("`time` {time} must be a number of seconds, 0 or more"),
        (Some(_), Some(_)) => bail!("give `frame` or `time`, not both"),
        (None, None) => bail!("`frame` or `time` is missing"),
    };
    let vector = |field: &str, v: [f64; 3]| {
        let v = DVec3::from_array(v);
        if v.is_finite() {
            Ok(v)
        } else {
            Err(anyhow::anyhow!("`{field}` {v} is not finite"))
        }
    };
    let eye = vector("eye", k.eye)?;
    let target = vector("target", k.target)?;
    let up = match k.up {
        Some(up) => {
            let up = vector("up", up)?;
            if up.length() < 1e-9 {
                bail!("`up` {up} has no direction");
            }
            up.normalize()
        }
        None => before.map_or(DVec3::Y, |b| b.up),
    };
    let fov_y_deg = k
        .fov
        .unwrap_or_else(|| before.map_or(f64::from(DEFAULT_FOV_DEG), |b| b.fov_y_deg));
    if !(fov_y_deg > 0.0 && fov_y_deg < 180.0) {
        bail!("`fov` {fov_y_deg} must be between 0 and 180 degrees (exclusive)");
    }
    if (target - eye).length() == 0.0 {
        bail!("`eye` and `target` are the same point {eye}");
    }
    if (target - eye).normalize().cross(up).length() < 1e-6 {
        bail!("`up` {up} is parallel to the view from `eye` to `target`");
    }
    Ok(Key {
        frame,
        eye,
        target,
        up,
        fov_y_deg,
    })
}

/// The cubic Hermite curve from `a` (velocity `ma`) to `b` (velocity `mb`) at `t` in [0, 1].
fn hermite(a: DVec3, ma: DVec3, b: DVec3, mb: DVec3, t: f64) -> DVec3 {
    let (t2, t3) = (t * t, t * t * t);
    a * (2.0 * t3 - 3.0 * t2 + 1.0)
        + ma * (t3 - 2.0 * t2 + t)
        + b * (-2.0 * t3 + 3.0 * t2)
        + mb * (t3 - t2)
}

/// What `--replay FILE` names: a recorded session, or a camera path (a `.toml` file).
pub enum Replay {
    /// A session file written by `--record`.
    Session(Session),
    /// A camera path, which becomes a session once the scene's frame and the quality are known.
    Path(CameraPath),
}

impl Replay {
    /// Reads `path`: a camera path if it ends in `.toml`, else a session.
    ///
    /// # Errors
    /// The file cannot be read or is not a valid session or path.
    pub fn load(path: &Path) -> Result<Replay> {
        if is_camera_path(path) {
            CameraPath::load(path).map(Replay::Path)
        } else {
            Session::load(path).map(Replay::Session)
        }
    }

    /// The frames a second it was made for, where it says (a path does, a session does not).
    pub fn fps(&self) -> Option<u32> {
        match self {
            Replay::Session(_) => None,
            Replay::Path(path) => Some(path.fps),
        }
    }

    /// The first frame it has a state for.
    pub fn first_frame(&self) -> u64 {
        match self {
            Replay::Session(s) => s.lines[0].frame,
            Replay::Path(p) => *p.frames().start(),
        }
    }

    /// As a session: a path's cameras in the render coordinates of `frame_of`, with `params`.
    ///
    /// # Errors
    /// A path's frame has no valid camera.
    pub fn session(self, frame_of: &RenderFromWorld, params: RenderParams) -> Result<Session> {
        match self {
            Replay::Session(s) => Ok(s),
            Replay::Path(p) => p.session(frame_of, params),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TWO_KEYS: &str = r#"
        interpolation = "linear"
        [[key]]
        frame = 10
        eye = [0.0, 0.0, 10.0]
        target = [0.0, 0.0, 0.0]
        fov = 30.0
        [[key]]
        frame = 20
        eye = [10.0, 0.0, 10.0]
        target = [2.0, 0.0, 0.0]
        up = [0.0, 0.0, -3.0]
        fov = 50.0
    "#;

    fn err(text: &str) -> String {
        format!("{:#}", CameraPath::parse(text).unwrap_err())
    }

    #[test]
    fn a_camera_path_interpolates_its_keys_into_every_frame() {
        let path = CameraPath::parse(TWO_KEYS).unwrap();
        assert_eq!((path.fps, path.frames()), (DEFAULT_FPS, 10..=20));
        let mid = path.world_at(15);
        assert_eq!(mid.eye, DVec3::new(5.0, 0.0, 10.0));
        assert_eq!(mid.target, DVec3::new(1.0, 0.0, 0.0));
        assert_eq!(mid.fov_y_deg, 40.0);
        let up = DVec3::new(0.0, 0.5, -0.5).normalize();
        assert!((mid.up - up).length() < 1e-12, "{}", mid.up);
        // Before the first key and after the last, the path holds.
        assert_eq!(
            path.world_at(0),
            Key {
                frame: 10,
                ..path.keys[0]
            }
        );
        assert_eq!(
            path.world_at(99),
            Key {
                frame: 20,
                ..path.keys[1]
            }
        );
        let session = path
            .session(&RenderFromWorld::new(DVec3::X), RenderParams::interactive())
            .unwrap();
        assert_eq!(session.lines.len(), 11, "a line a frame: the camera moves");
        let camera = session.state_at(15).unwrap().camera.camera_for_frame(15);
        assert_eq!(
            camera.eye(),
            glam::Vec3::new(4.0, 0.0, 10.0),
            "in render coordinates"
        );
        assert_eq!(camera.fov_y_deg(), 40.0);
        assert!(session.state_at(9).is_err(), "the path starts at frame 10");
    }

    /// A path of keys with these frames and eye x coordinates, looking down -z.
    fn along_x(interpolation: &str, keys: &[(u64, f64)]) -> CameraPath {
        let keys: String = keys
            .iter()
            .map(|(f, x)| {
                format!("[[key]]\nframe = {f}\neye = [{x}, 0.0, 5.0]\ntarget = [{x}, 0.0, 0.0]\n")
            })
            .collect();
        CameraPath::parse(&format!("interpolation = \"{interpolation}\"\n{keys}")).unwrap()
    }

    #[test]
    fn a_catmull_rom_path_passes_through_its_keys_smoothly() {
        let even = along_x("catmull-rom", &[(0, 0.0), (10, 10.0), (20, 20.0)]);
        for key in &even.keys {
            assert_eq!(even.world_at(key.frame).eye, key.eye);
        }
        // Keys on a line at an even speed: the curve is the line, at that speed.
        for f in 0..=20 {
            assert!(
                (even.world_at(f).eye.x - f as f64).abs() < 1e-9,
                "frame {f}"
            );
        }
        // The speed changes at key 2 (1 then 2 a frame): a spline's velocity is continuous
        // there, straight lines' jumps.
        let step = |path: &CameraPath, f: u64| path.world_at(f).eye.x - path.world_at(f - 1).eye.x;
        let keys = [(0, 0.0), (10, 10.0), (20, 30.0)];
        let smooth = along_x("catmull-rom", &keys);
        let (before, after) = (step(&smooth, 10), step(&smooth, 11));
        assert!((after - before).abs() < 0.25, "{before} then {after}");
        assert!(
            ((before + after) / 2.0 - 1.5).abs() < 0.01,
            "{before} then {after}"
        );
        let linear = along_x("linear", &keys);
        assert_eq!((step(&linear, 10), step(&linear, 11)), (1.0, 2.0));
    }

    #[test]
    fn time_keys_count_in_the_paths_fps() {
        let path = CameraPath::parse(
            "fps = 24\n[[key]]\ntime = 0.5\neye = [0, 0, 1]\ntarget = [0, 0, 0]\n\
             [[key]]\ntime = 2.0\neye = [0, 0, 2]\ntarget = [0, 0, 0]\n",
        )
        .unwrap();
        assert_eq!(path.frames(), 12..=48);
        assert_eq!(path.keys[1].fov_y_deg, f64::from(DEFAULT_FOV_DEG));
    }

    #[test]
    fn bad_camera_paths_are_refused_naming_the_key_and_the_field() {
        let key = "eye = [0, 0, 1]\ntarget = [0, 0, 0]";
        for (text, words) in [
            (format!("[[key]]\nframe = 0\n{key}\nfov = 190"), &["key 1", "`fov` 190"][..]),
            (format!("[[key]]\nframe = 0\n{key}\n[[key]]\nframe = 5\neye = [1, 2, 3]\ntarget = [1, 2, 3]"), &["key 2", "same point"]),
            (format!("[[key]]\nframe = 0\n{key}\nup = [0, 0, 2]"), &["key 1", "`up`", "parallel"]),
            (format!("[[key]]\nframe = 3\n{key}\n[[key]]\nframe = 3\n{key}"), &["key 2", "does not come after"]),
            (format!("[[key]]\n{key}"), &["key 1", "`frame` or `time`"]),
            (format!("[[key]]\nframe = 0\ntime = 1.0\n{key}"), &["key 1", "not both"]),
            (format!("[[key]]\ntime = -1.0\n{key}"), &["key 1", "`time` -1"]),
            (format!("[[key]]\nframe = 0\n{key}\n[[key]]\nframe = 9000000\n{key}"), &["key 2", "more than"]),
            (format!("[[key]]\nframe = 0\n{key}\nzoom = 2"), &["zoom"]),
            (format!("fps = 0\n[[key]]\nframe = 0\n{key}"), &["fps 0"]),
            ("fps = 30".to_string(), &["no [[key]]"]),
        ] {
            let e = err(&text);
            for word in words {
                assert!(e.contains(word), "{text:?}: {e:?} does not name {word:?}");
            }
        }
    }

    #[test]
    fn a_path_whose_eye_crosses_its_target_is_refused_naming_the_frame() {
        let path = CameraPath::parse(
            "interpolation = \"linear\"\n\
             [[key]]\nframe = 0\neye = [0, 0, 1]\ntarget = [0, 0, 0]\n\
             [[key]]\nframe = 4\neye = [0, 0, -1]\ntarget = [0, 0, 0]\n",
        )
        .unwrap();
        let e = format!(
            "{:#}",
            path.session(&RenderFromWorld::IDENTITY, RenderParams::interactive())
                .unwrap_err()
        );
        assert!(
            e.contains("frame 2") && e.contains("key 1 and key 2"),
            "{e}"
        );
    }

    #[test]
    fn replay_tells_a_camera_path_from_a_session_by_its_extension() {
        assert!(is_camera_path(Path::new("fly.path.toml")));
        assert!(is_camera_path(Path::new("FLY.TOML")));
        assert!(!is_camera_path(Path::new("session.jsonl")));
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("fly.path.toml");
        std::fs::write(&file, TWO_KEYS).unwrap();
        let replay = Replay::load(&file).unwrap();
        assert_eq!(
            (replay.fps(), replay.first_frame()),
            (Some(DEFAULT_FPS), 10)
        );
        std::fs::write(&file, "[[key]]\nframe = 0\n").unwrap();
        let e = format!("{:#}", Replay::load(&file).err().unwrap());
        assert!(e.contains("fly.path.toml") && e.contains("eye"), "{e}");
    }
}
