//! What each display shows: viewports. A display's framebuffer holds one view of the scene, or
//! two (side-by-side or top-bottom stereo), or a display shows one eye of a screen that another
//! display shows the other eye of (passive stereo, two projectors a screen). A viewport is one
//! eye's view drawn into a rectangle of one display's pixels: tiles never straddle two.

use serde::{Deserialize, Serialize};

/// How a stereo wall shows its two eyes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum StereoMode {
    /// One eye, the viewer's centre.
    #[default]
    Mono,
    /// Each display's left half shows the left eye, its right half the right eye (each at half
    /// the horizontal resolution), as 3D TVs and projectors take it.
    SideBySide,
    /// The top half the left eye, the bottom half the right.
    TopBottom,
    /// Two displays a screen: display 2k shows screen k to the left eye, 2k + 1 to the right
    /// (passive stereo with two projectors a screen).
    Displays,
}

impl StereoMode {
    /// Displays that show one screen.
    pub fn displays_per_screen(self) -> u32 {
        if self == StereoMode::Displays {
            2
        } else {
            1
        }
    }
}

/// Eye separation of a grid wall's stereo when none is given (`eye_separation = 0`, or no
/// `--eye-separation`), in scene units.
pub const DEFAULT_EYE_SEPARATION: f64 = 0.065;
/// Eye separation of a wall of physical screens when none is given, in millimetres.
pub const DEFAULT_EYE_SEPARATION_MM: f64 = 64.0;

/// Stereo: its mode and how far apart the eyes are.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Stereo {
    /// How the two eyes are shown; `mode = "side-by-side"` in a wall file's `[stereo]` table
    /// (`mono`, `side-by-side`, `top-bottom` or `displays`). Mono when absent.
    #[serde(default)]
    pub mode: StereoMode,
    /// Distance between the eyes: in scene units for a grid wall, in millimetres for a wall
    /// of physical screens (whose viewer says how millimetres map to the scene). 0: the
    /// default ([`DEFAULT_EYE_SEPARATION`] scene units; [`DEFAULT_EYE_SEPARATION_MM`]).
    #[serde(default)]
    pub eye_separation: f64,
}

/// Which eye a viewport is seen from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Eye {
    /// Midway between the eyes: what mono walls are seen from.
    Centre,
    /// The left eye, half an eye separation left of the centre.
    Left,
    /// The right eye, half an eye separation right of the centre.
    Right,
}

impl Eye {
    /// Where the eye sits along the viewer's right axis, in eye separations.
    pub fn offset(self) -> f64 {
        match self {
            Eye::Centre => 0.0,
            Eye::Left => -0.5,
            Eye::Right => 0.5,
        }
    }
}

/// A rectangle in the wall's pixels, and the part of the world it shows.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Viewport {
    /// The display whose framebuffer it is drawn into.
    pub display: crate::wall::DisplayId,
    /// Left edge of its pixels in the wall's image (the virtual image of a grid wall, the atlas
    /// of a wall of screens).
    pub x: u32,
    /// Top edge of its pixels in the wall's image.
    pub y: u32,
    /// Width in pixels: the display's, or half of it in side-by-side stereo.
    pub width: u32,
    /// Height in pixels: the display's, or half of it in top-bottom stereo.
    pub height: u32,
    /// The eye it is seen from.
    pub eye: Eye,
    /// The part of the world drawn into it.
    pub view: ViewSource,
}

/// The part of the world a viewport shows.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum ViewSource {
    /// A rectangle of the camera's one image (a grid wall, whose image is `width × height` of
    /// the layout, bezels included): left, top, width, height, in its pixels.
    Image([f64; 4]),
    /// A physical screen, seen from the viewer.
    Screen(crate::screens::ScreenGeometry),
}

/// Cuts a display's framebuffer `(x, y, width, height)` into the viewports `stereo` shows it
/// as, each with the view `view` gives for an eye and its share of the framebuffer (as
/// fractions: left, top, width, height of the whole).
pub fn viewports_of(
    display: crate::wall::DisplayId,
    rect: (u32, u32, u32, u32),
    mode: StereoMode,
    eye_of_display: Eye,
    view: impl Fn(Eye) -> ViewSource,
) -> Vec<Viewport> {
    let (x, y, w, h) = rect;
    let one = |eye, x, y, width, height| Viewport {
        display,
        x,
        y,
        width,
        height,
        eye,
        view: view(eye),
    };
    match mode {
        StereoMode::Mono | StereoMode::Displays => vec![one(eye_of_display, x, y, w, h)],
        StereoMode::SideBySide => {
            let left = w / 2;
            vec![
                one(Eye::Left, x, y, left, h),
                one(Eye::Right, x + left, y, w - left, h),
            ]
        }
        StereoMode::TopBottom => {
            let top = h / 2;
            vec![
                one(Eye::Left, x, y, w, top),
                one(Eye::Right, x, y + top, w, h - top),
            ]
        }
    }
}
