//! A person's input at a display window, as it travels to the master: only what steering the
//! wall needs, in units that do not depend on the window's size.

use serde::{Deserialize, Serialize};

/// The keys that do something on a wall.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Key {
    /// Flies forward, along the viewing direction, one step (a fraction of the scene's size).
    W,
    /// Flies left one step.
    A,
    /// Flies back one step, away from the target.
    S,
    /// Flies right one step.
    D,
    /// Flies down one step, along the camera's `-up`.
    Q,
    /// Flies up one step, along the camera's `up`.
    E,
    /// Switch between orbiting a pivot and flying.
    F,
    /// Back to the home view.
    H,
    /// Show or hide the overlay.
    O,
    /// Shadows on or off.
    Digit1,
    /// Ambient-occlusion rays per hit: 0 → 4 → 16 → 0.
    Digit2,
    /// Samples per pixel: 1 → 2 → 4 → 8 → 1.
    Digit3,
    /// Fit the scene into the view, looking from where the camera looks now.
    Z,
}

/// A mouse button, as held in a drag or pressed in a click.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub enum Button {
    /// Orbits the pivot when dragged (turns the view, in fly mode).
    Left,
    /// Pans the view when dragged.
    Right,
    /// Pans the view when dragged, like [`Button::Right`].
    Middle,
}

/// Largest movement one event may carry, in screen heights (or scroll lines).
pub const MAX_MOVE: f32 = 100.0;

/// One input event. Mouse movements are in heights of the screen they happened on, so a drag
/// across one screen turns the view the same whatever its resolution.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub enum InputEvent {
    /// A key went down (`pressed`) or up; the master acts on presses only.
    Key {
        /// The key, by its physical position (where it sits on a US layout).
        key: Key,
        /// `true` when the key went down, `false` when it came up.
        pressed: bool,
    },
    /// The mouse moved by `(dx, dy)` with `button` held (x right, y down).
    Drag {
        /// The button held during the movement.
        button: Button,
        /// Rightward movement, in heights of the screen it happened on, within ±[`MAX_MOVE`].
        dx: f32,
        /// Downward movement, in heights of the screen it happened on, within ±[`MAX_MOVE`].
        dy: f32,
    },
    /// The wheel turned by `lines` (positive: away from the user, zoom in).
    Scroll {
        /// Wheel lines, within ±[`MAX_MOVE`].
        lines: f32,
    },
    /// A button pressed and released without a drag, at `(fx, fy)` of the screen (fractions
    /// of its width and height from the top left, each in 0..=1): the probe's click.
    Click {
        /// The button clicked; any button probes.
        button: Button,
        /// Horizontal position, 0 at the screen's left edge, 1 at its right.
        fx: f32,
        /// Vertical position, 0 at the screen's top edge, 1 at its bottom.
        fy: f32,
    },
}

#[derive(Deserialize)]
enum InputEventRaw {
    Key { key: Key, pressed: bool },
    Drag { button: Button, dx: f32, dy: f32 },
    Scroll { lines: f32 },
    Click { button: Button, fx: f32, fy: f32 },
}

/// An input event with a movement that is not a finite number within [`MAX_MOVE`].
#[derive(Debug, thiserror::Error, PartialEq)]
#[error("input movement {0} is not a finite number within ±{MAX_MOVE}")]
pub struct BadMove(pub f32);

fn check_move(v: f32) -> Result<f32, BadMove> {
    if v.is_finite() && v.abs() <= MAX_MOVE {
        Ok(v)
    } else {
        Err(BadMove(v))
    }
}

impl TryFrom<InputEventRaw> for InputEvent {
    type Error = BadMove;

    fn try_from(raw: InputEventRaw) -> Result<Self, BadMove> {
        Ok(match raw {
            InputEventRaw::Key { key, pressed } => InputEvent::Key { key, pressed },
            InputEventRaw::Drag { button, dx, dy } => InputEvent::Drag {
                button,
                dx: check_move(dx)?,
                dy: check_move(dy)?,
            },
            InputEventRaw::Scroll { lines } => InputEvent::Scroll {
                lines: check_move(lines)?,
            },
            InputEventRaw::Click { button, fx, fy } => {
                for v in [fx, fy] {
                    if !(0.0..=1.0).contains(&v) {
                        return Err(BadMove(v));
                    }
                }
                InputEvent::Click { button, fx, fy }
            }
        })
    }
}

impl<'de> Deserialize<'de> for InputEvent {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        crate::checked::deserialize::<D, InputEventRaw, Self>(d)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn movements_are_checked_on_arrival() {
        let ok = InputEvent::Drag {
            button: Button::Left,
            dx: 0.25,
            dy: -0.1,
        };
        let bytes = postcard::to_allocvec(&ok).unwrap();
        assert_eq!(postcard::from_bytes::<InputEvent>(&bytes).unwrap(), ok);
        let bad = InputEvent::Scroll { lines: f32::NAN };
        let bytes = postcard::to_allocvec(&bad).unwrap();
        let err = crate::checked::decode_for_test::<InputEvent>(&bytes).unwrap_err();
        assert!(err.to_string().contains("NaN"), "{err}");
        let outside = InputEvent::Click {
            button: Button::Left,
            fx: 1.5,
            fy: 0.5,
        };
        let bytes = postcard::to_allocvec(&outside).unwrap();
        assert!(crate::checked::decode_for_test::<InputEvent>(&bytes).is_err());
    }
}
