//! The control interface: what an operator's or a script's client asks a running wall, and
//! what it answers. Requests travel in [`crate::FromNode::Control`], answers in
//! [`crate::ToNode::ControlReply`], on the client's control stream to the master.
//!
//! Every value a request carries is checked by its type on arrival (cameras, cuts, lights),
//! and a change is checked against the state it would make before it is queued, so a bad
//! value comes back as [`ControlReply::Refused`] with the reason and the wall goes on.

use serde::{Deserialize, Serialize};
use tessera_model::input::InputEvent;
use tessera_model::state::{StateChange, StateId, WallState};

/// Longest name of a saved view.
pub const MAX_VIEW_NAME: usize = 64;

/// A saved view's name: 1 to [`MAX_VIEW_NAME`] letters, digits, `-`, `_` or `.`.
#[derive(Clone, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize)]
pub struct ViewName(String);

impl ViewName {
    /// The name `name`, checked.
    ///
    /// # Errors
    /// An empty or over-long name, or one with other characters.
    pub fn new(name: &str) -> Result<ViewName, ControlError> {
        let ok = !name.is_empty()
            && name.len() <= MAX_VIEW_NAME
            && name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || "-_.".contains(c));
        if ok {
            Ok(ViewName(name.to_string()))
        } else {
            Err(ControlError::BadViewName(name.chars().take(80).collect()))
        }
    }

    /// The name as text.
    pub fn as_str(&self) -> &str {
        &self.0
    }
}

impl TryFrom<String> for ViewName {
    type Error = ControlError;

    fn try_from(name: String) -> Result<Self, ControlError> {
        ViewName::new(&name)
    }
}

impl<'de> Deserialize<'de> for ViewName {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        tessera_model::checked::deserialize::<D, String, Self>(d)
    }
}

/// Why a value of the control interface was refused.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum ControlError {
    /// A view name is empty, longer than [`MAX_VIEW_NAME`], or holds a character other than a
    /// letter, a digit, `-`, `_` or `.`; carries its first 80 characters.
    #[error("view name {0:?} must be 1 to {MAX_VIEW_NAME} letters, digits, '-', '_' or '.'")]
    BadViewName(String),
}

/// What a control client asks.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum ControlRequest {
    /// Queue changes for the next frame barrier, all or none: they are checked in order
    /// against the state they build, and the first refusal refuses the lot.
    Change(Vec<StateChange>),
    /// The master's clock (ns since the Unix epoch), for the client to map its own onto it.
    Clock,
    /// The state frames render with now, and the one the next barrier applies.
    State,
    /// Live figures: frame rate, frame times, what each node has done.
    Figures,
    /// Keep the current camera under a name.
    SaveView(ViewName),
    /// Go back to a saved view (a change like any other).
    GotoView(ViewName),
    /// The names of the saved views.
    Views,
    /// Show or hide the displays' overlay (frame rate, who rendered each tile).
    Overlay(bool),
    /// Have every display save a frame as `display-<id>-frame-<K>.png` in its `--out`
    /// directory (the master puts them together as `wall-frame-<K>.png`): the frame shown now
    /// on a still (converged) wall, else the next frame to start; with `final_quality`, the
    /// first frame at the final quality of progressive refinement.
    Snapshot {
        /// Wait for the final quality (the camera must hold still).
        final_quality: bool,
    },
    /// Window input, as if a person had used a display's window (the console's picture):
    /// drags orbit and pan, the wheel zooms, keys do what they do in a window.
    Input(InputEvent),
    /// A time series' playback: play or pause, its speed, or a step forward or back (which
    /// pauses).
    Playback(Playback),
    /// The wall's state as an operator reads it: [`WallStatus`].
    Status,
    /// Which render node rendered each tile last: [`ControlReply::TileOwners`].
    TileOwners,
    /// Replay a recorded session from the next frame on: each state at its frame's offset
    /// from the session's first, at most [`MAX_REPLAYED`].
    Replay(Vec<(u64, WallState)>),
    /// A fixed camera that frames the whole scene, looking at its middle from where the
    /// camera looks now.
    Fit,
    /// The volume's data value and world position under wall pixel `(x, y)` (the virtual wall,
    /// bezels included, row 0 at the top), as the frames starting now show it.
    Probe {
        /// Column, in pixels from the wall image's left edge.
        x: u32,
        /// Row, in pixels from the wall image's top edge.
        y: u32,
    },
}

/// Most states a replayed session may hold.
pub const MAX_REPLAYED: usize = 100_000;

/// A tile no render node has rendered yet, in [`ControlReply::TileOwners`].
pub const NO_OWNER: u32 = u32::MAX;

/// Slowest and fastest playback of a time series, in steps per second.
pub const PLAYBACK_SPEEDS: std::ops::RangeInclusive<f32> = 0.1..=60.0;

/// A change to a time series' playback; what is `None` stays.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Playback {
    /// Play (`true`) or pause.
    pub playing: Option<bool>,
    /// Steps per second, within [`PLAYBACK_SPEEDS`]; `None` keeps it.
    pub steps_per_second: Option<f32>,
    /// Steps to move by, forward or back (wrapping around the series); pauses.
    pub step_by: Option<i32>,
}

/// A time series' playback, as [`WallStatus`] reports it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SeriesStatus {
    /// Steps in the series.
    pub steps: u32,
    /// Whether it plays.
    pub playing: bool,
    /// Steps per second while it plays; `None`: a step each frame.
    pub steps_per_second: Option<f32>,
}

/// The wall as an operator reads it: what it shows, and what it is doing.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct WallStatus {
    /// The last frame started.
    pub frame: u64,
    /// The id of the state frames render with now.
    pub state_id: StateId,
    /// The state once every queued change is applied.
    pub state: WallState,
    /// Whether the wall reached the final quality and renders nothing until something changes.
    pub converged: bool,
    /// Whether the displays draw the overlay.
    pub overlay: bool,
    /// The saved views, sorted.
    pub views: Vec<ViewName>,
    /// The time series' playback; `None` without a series.
    pub series: Option<SeriesStatus>,
    /// The volume's value range, where the scene has a volume.
    pub volume_range: Option<[f32; 2]>,
    /// The particles' attribute range, where the scene has particles.
    pub particle_range: Option<[f32; 2]>,
}

/// What a probe found under a pixel.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ProbeHit {
    /// World coordinates of the point the ray sees.
    pub world: [f64; 3],
    /// The volume's value there, in the data's own units.
    pub value: f32,
    /// Distance from the eye along the ray.
    pub distance: f32,
}

/// The master's answer to one request.
// The state answer (two whole states) is the largest; answers live one at a time.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum ControlReply {
    /// Changes queued; they take effect at the next barrier.
    Queued {
        /// How many changes were queued: all those of the request.
        changes: u32,
        /// The id the wall's state will have once they are applied.
        state_id: StateId,
        /// The first frame that can show them: the next to start.
        frame: u64,
    },
    /// The answer to [`ControlRequest::Clock`].
    Clock {
        /// The master's clock when it answered, in ns since the Unix epoch.
        master_ns: u64,
    },
    /// The answer to [`ControlRequest::State`].
    State {
        /// The last frame started.
        frame: u64,
        /// The id of the state frames render with now.
        id: StateId,
        /// The state frames render with now.
        current: WallState,
        /// The state the next barrier applies: `current` with every queued change.
        next: WallState,
    },
    /// The answer to [`ControlRequest::Figures`].
    Figures(LiveFigures),
    /// The answer to [`ControlRequest::Views`]: the saved views' names, sorted.
    Views(Vec<ViewName>),
    /// The frame the displays save (or saved, on a still wall).
    Snapshot {
        /// Its number.
        frame: u64,
        /// Whether it is the frame shown now (a still wall); else a frame to come.
        shown: bool,
    },
    /// The answer to [`ControlRequest::Status`].
    Status(WallStatus),
    /// The render node that last rendered each tile, by tile id; [`NO_OWNER`] for a tile
    /// not rendered yet.
    TileOwners(Vec<u32>),
    /// What the probed pixel shows of the volume; None where its ray sees none.
    Probe(Option<ProbeHit>),
    /// Done, nothing to say.
    Done,
    /// Not done, and why.
    Refused(Refusal),
}

/// Why the master refused a control request; the state is then unchanged.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, thiserror::Error)]
pub enum Refusal {
    /// The run keeps at most `max` saved views.
    #[error("{max} views are saved already; reuse a name")]
    ViewsFull {
        /// Saved views the run keeps at most.
        max: u32,
    },
    /// [`ControlRequest::GotoView`] named a view that was never saved.
    #[error("there is no view named {}", .0.as_str())]
    NoSuchView(ViewName),
    /// The run keeps at most `max` outstanding snapshots.
    #[error("this run has taken its {max} snapshots")]
    SnapshotsFull {
        /// Snapshots the run takes at most.
        max: u32,
    },
    /// A replayed session with more than [`MAX_REPLAYED`] states.
    #[error("a replayed session holds at most {MAX_REPLAYED} states")]
    ReplayTooLong,
    /// Playback, but the scene is no time series.
    #[error("the scene is not a time series: there is nothing to play")]
    NoSeries,
    /// A playback speed outside [`PLAYBACK_SPEEDS`].
    #[error("a speed of {0} steps per second is outside 0.1 to 60")]
    BadSpeed(f32),
    /// A snapshot at the final quality, but the camera orbits and never holds still.
    #[error(
        "the camera orbits, so the wall never reaches its final quality; set a fixed camera first"
    )]
    NeverStill,
    /// A window input event the navigator refused.
    #[error("input refused: {0}")]
    BadInput(String),
    /// A probe, but the scene has no volume (or the master cannot probe it).
    #[error("the scene has no volume to probe")]
    NoVolume,
    /// A probe of a pixel outside the wall's image.
    #[error("pixel {x},{y} is outside the {width}x{height} wall")]
    OutsideWall {
        /// Column of the pixel asked for.
        x: u32,
        /// Row of the pixel asked for.
        y: u32,
        /// Width of the wall's image, in pixels.
        width: u32,
        /// Height of the wall's image, in pixels.
        height: u32,
    },
    /// Change `index` (from 1) of `count` would break the state's bounds; `reason` is the
    /// bound's own message.
    #[error("change {index} of {count}: {reason}")]
    BadChange {
        /// Which change of the request, from 1.
        index: u32,
        /// Changes in the request.
        count: u32,
        /// Why, in the bound's own words.
        reason: String,
    },
}

/// A running wall's figures, as the control interface reports them.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LiveFigures {
    /// Frames the wall has presented since the run began.
    pub frames_presented: u64,
    /// Frames presented over the last second of rendering: a still wall's idle time does not
    /// count (see `idle`).
    pub fps: f64,
    /// Whether the wall is still: at its final quality, rendering nothing until something
    /// changes.
    pub idle: bool,
    /// Seconds the wall spent rendering since the run began: the time frames were in flight.
    pub rendering_s: f64,
    /// Time between the last two presents, in milliseconds (0 before there are two).
    pub frame_ms_last: f64,
    /// Mean time between presents over the last second, in milliseconds.
    pub frame_ms_mean: f64,
    /// State changes the frame barriers have applied since the run began.
    pub changes_applied: u64,
    /// Each render node connected now.
    pub render_nodes: Vec<NodeFigures>,
    /// Each display connected now, by display id.
    pub displays: Vec<DisplayFigures>,
}

/// A render node's figures, as [`LiveFigures`] reports them.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct NodeFigures {
    /// Its render node id.
    pub id: u32,
    /// Host name it gave in its hello.
    pub host: String,
    /// Threads it renders with.
    pub cores: u32,
    /// Tiles it reported rendered since it joined.
    pub tiles: u64,
    /// Rays it traced, as its last progress said.
    pub rays: Option<u64>,
    /// Its peak resident memory in MiB, as its last progress said.
    pub peak_mib: Option<f64>,
    /// Reads of a shared scene that missed its memory, as its last progress said.
    pub dsm_misses: Option<u64>,
}

/// A display's figures, as [`LiveFigures`] reports them.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DisplayFigures {
    /// Its display id.
    pub id: u32,
    /// Host name it gave in its hello.
    pub host: String,
    /// Frames it has presented, as it reported them.
    pub frames_presented: u64,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn view_names_are_checked_on_arrival() {
        assert!(ViewName::new("front-1.2_a").is_ok());
        for bad in ["", "a b", "../etc", &"x".repeat(65)] {
            assert!(ViewName::new(bad).is_err(), "{bad:?}");
        }
        let bytes = postcard::to_allocvec(&"no spaces".to_string()).unwrap();
        assert!(crate::codec::decode::<ViewName>(&bytes).is_err());
    }
}
