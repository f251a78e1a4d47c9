//! Steering the wall by hand: input events from any display window become state changes.
//!
//! Two modes, as in most viewers. **Orbit** (the default): a left drag turns the camera about
//! a pivot (the scene's centre), a right or middle drag pans, the wheel zooms. **Fly** (`F`
//! toggles): `W`/`S` forward and back, `A`/`D` sideways, `Q`/`E` down and up, a left drag
//! looks around. `H` goes back to the home view (the camera the wall started with, which
//! frames the scene), `Z` fits the scene into the view from where the camera looks; `1`
//! toggles shadows, `2` cycles ambient-occlusion rays (0 → 4 → 16), `3` samples per pixel
//! (1 → 2 → 4 → 8); `O` toggles the overlay.
//!
//! Speeds follow the scene and the clock, not the event rate: a wheel line moves a tenth of
//! the way to the target (never through it), and flying covers a fixed fraction per second of
//! the distance to the pivot, however fast a key repeats or frames come; so holding `W` slows
//! down as the scene comes close instead of flying into it.
//!
//! Like the rest of this crate it is a state machine with no I/O: the driver hands it each
//! event with the camera on the wall and the time at that moment and queues what it returns.

use glam::{Quat, Vec3};
use std::time::{Duration, Instant};
use tessera_model::camera::{Camera, CameraMode};
use tessera_model::input::{Button, InputEvent, Key};
use tessera_model::params::RenderParams;
use tessera_model::state::StateChange;

/// What an input event asks of the wall.
// A state change can carry a whole light set; actions live one at a time, on the stack.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum NavAction {
    /// Queue this change for the next frame barrier.
    Change(StateChange),
    /// Show or hide the overlay on every display.
    ToggleOverlay,
    /// Probe what the screen shows at `(fx, fy)` (fractions of its width and height).
    Probe {
        /// Across the screen, 0 at its left edge, 1 at its right.
        fx: f32,
        /// Down the screen, 0 at its top edge, 1 at its bottom.
        fy: f32,
    },
}

/// What a left drag does to the camera; `F` toggles between the two.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NavMode {
    /// A left drag turns the camera about the pivot (the default).
    Orbit,
    /// A left drag looks around from where the eye is.
    Fly,
}

/// Turns input events into state changes; see the module documentation for the controls.
///
/// # Examples
///
/// ```
/// use glam::Vec3;
/// use tessera_core::master::navigate::{NavAction, Navigator};
/// use tessera_model::camera::{Camera, CameraMode};
/// use tessera_model::input::{Button, InputEvent};
/// use tessera_model::params::RenderParams;
/// use tessera_model::state::StateChange;
///
/// let camera = Camera::new(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, Vec3::Y, 45.0).unwrap();
/// let mut nav = Navigator::new(CameraMode::fixed(camera), Vec3::ZERO, 1.0);
/// // Dragging a quarter of a screen height to the right turns the camera about the pivot.
/// let drag = InputEvent::Drag { button: Button::Left, dx: 0.25, dy: 0.0 };
/// let now = std::time::Instant::now();
/// let Some(NavAction::Change(StateChange::Camera(mode))) =
///     nav.handle(&drag, &camera, &RenderParams::interactive(), now)
/// else {
///     panic!("a drag moves the camera");
/// };
/// let moved = mode.fixed_camera().unwrap();
/// assert!((moved.eye().length() - 5.0).abs() < 1e-4, "same distance from the pivot");
/// assert!(moved.eye().x.abs() > 1.0, "but from another side");
/// ```
#[derive(Clone, Debug)]
pub struct Navigator {
    mode: NavMode,
    home: CameraMode,
    pivot: Vec3,
    /// Size of the scene (half its diagonal): the radius a fit frames, the closest zoom.
    scale: f32,
    /// When the last fly key moved the camera: a step covers the time since.
    last_fly: Option<Instant>,
}

/// Degrees an orbit or a look turns per screen height dragged.
const DEGREES_PER_SCREEN: f32 = 180.0;
/// The fraction of the distance to the pivot a held fly key covers per second.
const FLY_PER_SECOND: f32 = 0.6;
/// The time a fly key event stands for: a first press is one key repeat (about 30 a second);
/// a pause longer than the longest is not flown through.
const FLY_EVENT: (Duration, Duration) = (Duration::from_millis(33), Duration::from_millis(100));
/// How much closer one wheel line (a notch) zooms.
const ZOOM_PER_LINE: f32 = 0.9;
/// The orbit stops this far (radians) short of the poles, where up and view would align.
const POLE_MARGIN: f32 = 0.02;

impl Navigator {
    /// A navigator whose home view is `home`, turning about `pivot` in a scene of size `scale`.
    pub fn new(home: CameraMode, pivot: Vec3, scale: f32) -> Self {
        Navigator {
            mode: NavMode::Orbit,
            home,
            pivot,
            scale: if scale.is_finite() && scale > 0.0 {
                scale
            } else {
                1.0
            },
            last_fly: None,
        }
    }

    /// A fixed camera looking at the pivot from where `camera` looks, far enough that the
    /// scene's bounding sphere fits its vertical field of view: "fit to data".
    pub fn fit(&self, camera: &Camera) -> Option<Camera> {
        let back = (camera.eye() - camera.target())
            .try_normalize()
            .unwrap_or(Vec3::Z);
        let distance = tessera_model::camera::fit_distance(self.scale, camera.fov_y_deg());
        Camera::new(
            self.pivot + back * distance,
            self.pivot,
            camera.up(),
            camera.fov_y_deg(),
        )
        .ok()
    }

    /// The mode input moves the camera in now.
    pub fn mode(&self) -> NavMode {
        self.mode
    }

    /// The action for `event` at `now`, given the camera on the wall and its quality knobs;
    /// `None` for events that do nothing (a key released, a move that would make no valid
    /// camera).
    pub fn handle(
        &mut self,
        event: &InputEvent,
        camera: &Camera,
        params: &RenderParams,
        now: Instant,
    ) -> Option<NavAction> {
        let moved = |c: Option<Camera>| {
            c.map(|c| NavAction::Change(StateChange::Camera(CameraMode::fixed(c))))
        };
        match *event {
            InputEvent::Key { pressed: false, .. } => None,
            InputEvent::Key { key, pressed: true } => match key {
                Key::F => {
                    self.mode = match self.mode {
                        NavMode::Orbit => NavMode::Fly,
                        NavMode::Fly => NavMode::Orbit,
                    };
                    None
                }
                Key::H => Some(NavAction::Change(StateChange::Camera(self.home))),
                Key::Z => moved(self.fit(camera)),
                Key::O => Some(NavAction::ToggleOverlay),
                Key::Digit1 => Some(NavAction::Change(StateChange::Shadows(!params.shadows()))),
                Key::Digit2 => Some(NavAction::Change(StateChange::AoSamples(
                    match params.ao_samples() {
                        0 => 4,
                        1..=4 => 16,
                        _ => 0,
                    },
                ))),
                Key::Digit3 => Some(NavAction::Change(StateChange::Spp(match params.spp() {
                    1 => 2,
                    2 | 3 => 4,
                    4..=7 => 8,
                    _ => 1,
                }))),
                Key::W | Key::A | Key::S | Key::D | Key::Q | Key::E => {
                    moved(self.fly(camera, key, now))
                }
            },
            InputEvent::Drag { button, dx, dy } => match (self.mode, button) {
                (NavMode::Orbit, Button::Left) => moved(self.orbit(camera, dx, dy)),
                (NavMode::Fly, Button::Left) => moved(look(camera, dx, dy)),
                (_, Button::Right | Button::Middle) => moved(pan(camera, dx, dy)),
            },
            InputEvent::Scroll { lines } => moved(self.zoom(camera, lines)),
            InputEvent::Click { fx, fy, .. } => Some(NavAction::Probe { fx, fy }),
        }
    }

    /// Turns the eye about the pivot: yaw about the up axis, pitch about the camera's right.
    fn orbit(&self, camera: &Camera, dx: f32, dy: f32) -> Option<Camera> {
        let up = camera.up().normalize_or_zero();
        let offset = camera.eye() - self.pivot;
        let yaw = Quat::from_axis_angle(up, -(dx * DEGREES_PER_SCREEN).to_radians());
        let offset = yaw * offset;
        let right = offset.cross(up).normalize_or_zero();
        // Keep the pitch short of the poles, where the view would line up with up.
        let elevation = offset.normalize_or_zero().dot(up).clamp(-1.0, 1.0).asin();
        let limit = std::f32::consts::FRAC_PI_2 - POLE_MARGIN;
        let wanted = (elevation + (dy * DEGREES_PER_SCREEN).to_radians()).clamp(-limit, limit);
        let pitch = Quat::from_axis_angle(right, wanted - elevation);
        let eye = self.pivot + pitch * offset;
        let target = self.pivot + yaw * (camera.target() - self.pivot);
        Camera::new(eye, target, camera.up(), camera.fov_y_deg()).ok()
    }

    /// One fly step: as far as [`FLY_PER_SECOND`] goes in the time since the last one, of the
    /// distance to the pivot (but at least a thousandth of the scene, so the pivot itself can
    /// be flown past slowly).
    fn fly(&mut self, camera: &Camera, key: Key, now: Instant) -> Option<Camera> {
        let elapsed = self
            .last_fly
            .map_or(FLY_EVENT.0, |last| now.saturating_duration_since(last))
            .min(FLY_EVENT.1);
        self.last_fly = Some(now);
        let forward = (camera.target() - camera.eye()).normalize_or_zero();
        let up = camera.up().normalize_or_zero();
        let right = forward.cross(up).normalize_or_zero();
        let distance = (camera.eye() - self.pivot).length().max(self.scale * 1e-3);
        let step = distance * FLY_PER_SECOND * elapsed.as_secs_f32();
        let delta = match key {
            Key::W => forward,
            Key::S => -forward,
            Key::D => right,
            Key::A => -right,
            Key::E => up,
            Key::Q => -up,
            _ => return None,
        } * step;
        translate(camera, delta)
    }

    /// Moves the eye towards the target, never closer than a thousandth of the scene.
    fn zoom(&self, camera: &Camera, lines: f32) -> Option<Camera> {
        let offset = camera.eye() - camera.target();
        let distance = offset.length();
        let wanted = (distance * ZOOM_PER_LINE.powf(lines)).max(self.scale * 1e-3);
        let eye = camera.target() + offset * (wanted / distance);
        Camera::new(eye, camera.target(), camera.up(), camera.fov_y_deg()).ok()
    }
}

/// Fly mode's mouse look: the view direction turns about the eye.
fn look(camera: &Camera, dx: f32, dy: f32) -> Option<Camera> {
    let up = camera.up().normalize_or_zero();
    let view = camera.target() - camera.eye();
    let yaw = Quat::from_axis_angle(up, -(dx * DEGREES_PER_SCREEN).to_radians());
    let right = view.cross(up).normalize_or_zero();
    let pitch = Quat::from_axis_angle(right, -(dy * DEGREES_PER_SCREEN).to_radians());
    let turned = pitch * (yaw * view);
    // A look straight up or down would make no camera; stay where it was.
    if turned.normalize_or_zero().dot(up).abs() > 0.999 {
        return None;
    }
    Camera::new(
        camera.eye(),
        camera.eye() + turned,
        camera.up(),
        camera.fov_y_deg(),
    )
    .ok()
}

/// Moves eye and target together in the view plane, as far as the drag covers at the
/// target's distance, so the point under the mouse follows it.
fn pan(camera: &Camera, dx: f32, dy: f32) -> Option<Camera> {
    let view = camera.target() - camera.eye();
    let up = camera.up().normalize_or_zero();
    let right = view.cross(up).normalize_or_zero();
    let true_up = right.cross(view).normalize_or_zero();
    // One screen height spans 2·tan(fov/2)·distance at the target.
    let height = 2.0 * (camera.fov_y_deg().to_radians() * 0.5).tan() * view.length();
    translate(camera, (right * -dx + true_up * dy) * height)
}

/// The camera moved by `delta`, eye and target together.
fn translate(camera: &Camera, delta: Vec3) -> Option<Camera> {
    Camera::new(
        camera.eye() + delta,
        camera.target() + delta,
        camera.up(),
        camera.fov_y_deg(),
    )
    .ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera() -> Camera {
        Camera::new(Vec3::new(0.0, 1.0, 5.0), Vec3::ZERO, Vec3::Y, 45.0).unwrap()
    }

    fn nav() -> Navigator {
        Navigator::new(CameraMode::fixed(camera()), Vec3::ZERO, 2.0)
    }

    fn camera_of(action: Option<NavAction>) -> Camera {
        match action {
            Some(NavAction::Change(StateChange::Camera(mode))) => mode.fixed_camera().unwrap(),
            other => panic!("not a camera change: {other:?}"),
        }
    }

    const P: RenderParams = RenderParams::interactive();

    fn now() -> Instant {
        Instant::now()
    }

    #[test]
    fn orbiting_keeps_the_distance_and_stops_short_of_the_pole() {
        let mut nav = nav();
        let c = camera_of(nav.handle(
            &InputEvent::Drag {
                button: Button::Left,
                dx: 0.5,
                dy: 0.0,
            },
            &camera(),
            &P,
            now(),
        ));
        assert!((c.eye().length() - camera().eye().length()).abs() < 1e-4);
        // Half a screen is 90 degrees: from +z to the side.
        assert!(
            c.eye().z.abs() < 0.05 && c.eye().x.abs() > 4.0,
            "{:?}",
            c.eye()
        );
        // Dragging far up ends just short of straight above, still a valid camera.
        let c = camera_of(nav.handle(
            &InputEvent::Drag {
                button: Button::Left,
                dx: 0.0,
                dy: 5.0,
            },
            &camera(),
            &P,
            now(),
        ));
        assert!(c.eye().normalize().y > 0.99, "{:?}", c.eye());
    }

    #[test]
    fn panning_moves_eye_and_target_together_and_zoom_approaches() {
        let mut nav = nav();
        let c = camera_of(nav.handle(
            &InputEvent::Drag {
                button: Button::Right,
                dx: 0.1,
                dy: 0.0,
            },
            &camera(),
            &P,
            now(),
        ));
        let d0 = camera().target() - camera().eye();
        assert!(((c.target() - c.eye()) - d0).length() < 1e-4);
        assert!(c.target().x < 0.0, "dragging right moves the view left");
        let c = camera_of(nav.handle(&InputEvent::Scroll { lines: 3.0 }, &camera(), &P, now()));
        let (before, after) = (camera().eye().length(), c.eye().length());
        assert!((after / before - 0.9f32.powi(3)).abs() < 1e-3);
        // Zooming far in stops before the target.
        let c = camera_of(nav.handle(&InputEvent::Scroll { lines: 100.0 }, &camera(), &P, now()));
        assert!(c.eye().length() > 0.0);
    }

    #[test]
    fn fly_mode_moves_with_the_keys_and_f_toggles_it() {
        let mut nav = nav();
        let press = |key| InputEvent::Key { key, pressed: true };
        assert_eq!(nav.handle(&press(Key::F), &camera(), &P, now()), None);
        assert_eq!(nav.mode(), NavMode::Fly);
        let c = camera_of(nav.handle(&press(Key::W), &camera(), &P, now()));
        let forward = (camera().target() - camera().eye()).normalize();
        // A first press is one key repeat's worth of flight: 0.6 × 1/30 s of the distance.
        let step = camera().eye().length() * 0.6 * 0.033;
        assert!(((c.eye() - camera().eye()) - forward * step).length() < 1e-5);
        let released = InputEvent::Key {
            key: Key::W,
            pressed: false,
        };
        assert_eq!(nav.handle(&released, &camera(), &P, now()), None);
        nav.handle(&press(Key::F), &camera(), &P, now());
        assert_eq!(nav.mode(), NavMode::Orbit);
    }

    #[test]
    fn holding_w_for_a_second_slows_down_before_the_scene_at_any_key_rate() {
        // The scene is a sphere of radius 2 about the origin, seen from where a fit puts it.
        let start = Camera::new(Vec3::new(0.0, 0.0, 6.0), Vec3::ZERO, Vec3::Y, 45.0).unwrap();
        let mut reached = Vec::new();
        for repeats_per_second in [10u32, 30, 120] {
            let mut nav = nav();
            nav.handle(
                &InputEvent::Key {
                    key: Key::F,
                    pressed: true,
                },
                &start,
                &P,
                now(),
            );
            let t0 = Instant::now();
            let mut c = start;
            for i in 1..=repeats_per_second {
                let at = t0 + Duration::from_secs_f64(f64::from(i) / f64::from(repeats_per_second));
                let press = InputEvent::Key {
                    key: Key::W,
                    pressed: true,
                };
                c = camera_of(nav.handle(&press, &c, &P, at));
            }
            reached.push(c.eye().z);
        }
        for z in &reached {
            assert!(*z > 2.0, "flew into the scene within a second: {reached:?}");
            assert!(*z < 4.0, "hardly moved: {reached:?}");
        }
        let spread = reached.iter().cloned().fold(f32::MIN, f32::max)
            - reached.iter().cloned().fold(f32::MAX, f32::min);
        assert!(spread < 0.3, "speed depends on the key rate: {reached:?}");
    }

    #[test]
    fn z_fits_the_scene_and_wheel_notches_never_pass_the_target() {
        let mut nav = nav();
        let far = Camera::new(Vec3::new(0.0, 0.0, 50.0), Vec3::X, Vec3::Y, 45.0).unwrap();
        let press = InputEvent::Key {
            key: Key::Z,
            pressed: true,
        };
        let fit = camera_of(nav.handle(&press, &far, &P, now()));
        assert_eq!(fit.target(), Vec3::ZERO, "looks at the pivot");
        let half = (2.0 / fit.eye().length()).asin().to_degrees();
        assert!(
            half < 22.5 && half > 18.0,
            "the sphere of radius 2 fills the view: {half}"
        );
        let mut c = fit;
        for _ in 0..5 {
            c = camera_of(nav.handle(&InputEvent::Scroll { lines: 1.0 }, &c, &P, now()));
        }
        let ratio = c.eye().length() / fit.eye().length();
        assert!(
            (ratio - 0.9f32.powi(5)).abs() < 1e-3,
            "a tenth per notch: {ratio}"
        );
        assert!(
            c.eye().length() > 2.0,
            "five notches stay outside the scene"
        );
    }

    #[test]
    fn keys_toggle_quality_go_home_and_toggle_the_overlay() {
        let mut nav = nav();
        let press = |key| InputEvent::Key { key, pressed: true };
        assert_eq!(
            nav.handle(&press(Key::Digit1), &camera(), &P, now()),
            Some(NavAction::Change(StateChange::Shadows(false)))
        );
        assert_eq!(
            nav.handle(&press(Key::Digit2), &camera(), &P, now()),
            Some(NavAction::Change(StateChange::AoSamples(4)))
        );
        assert_eq!(
            nav.handle(&press(Key::Digit3), &camera(), &P, now()),
            Some(NavAction::Change(StateChange::Spp(2)))
        );
        assert_eq!(
            nav.handle(&press(Key::H), &camera(), &P, now()),
            Some(NavAction::Change(StateChange::Camera(CameraMode::fixed(
                camera()
            ))))
        );
        assert_eq!(
            nav.handle(&press(Key::O), &camera(), &P, now()),
            Some(NavAction::ToggleOverlay)
        );
    }
}
