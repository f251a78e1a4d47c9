//! The pinhole camera of the whole wall and the default orbit.
//!
//! Convention (also in the README): pinhole at `eye`, looking at `target`, `up` roughly up,
//! `fov_y_deg` the vertical field of view of the whole virtual image (bezels included), one ray
//! through the centre `(x + 0.5, y + 0.5)` of each pixel, row 0 at the top.
//!
//! Both types are valid by construction: [`Camera::new`] and [`CameraMode::orbit`] check their
//! input, and deserializing goes through the same checks, so a camera from the network can
//! never give a NaN ray.

use glam::Vec3;
use serde::{Deserialize, Serialize};

/// Field of view (degrees) of the default orbit when none is given.
pub const DEFAULT_FOV_DEG: f32 = 45.0;

/// A pinhole camera; see the module documentation for the convention.
///
/// # Examples
///
/// ```
/// use glam::Vec3;
/// use tessera_model::camera::{Camera, CameraError};
///
/// let camera = Camera::new(Vec3::new(0.0, 1.0, 5.0), Vec3::ZERO, Vec3::Y, 40.0)?;
/// assert_eq!(camera.fov_y_deg(), 40.0);
/// assert_eq!(
///     Camera::new(Vec3::ONE, Vec3::ONE, Vec3::Y, 40.0),
///     Err(CameraError::EyeIsTarget([1.0; 3]))
/// );
/// assert!(Camera::new(Vec3::Z, Vec3::ZERO, Vec3::Y, 180.0).is_err());
/// # Ok::<(), CameraError>(())
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(into = "CameraSpec")]
pub struct Camera {
    eye: Vec3,
    target: Vec3,
    up: Vec3,
    fov_y_deg: f32,
}

/// A camera's fields as they travel, checked into a [`Camera`] on arrival.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
struct CameraSpec {
    eye: Vec3,
    target: Vec3,
    up: Vec3,
    fov_y_deg: f32,
}

impl TryFrom<CameraSpec> for Camera {
    type Error = CameraError;

    fn try_from(c: CameraSpec) -> Result<Self, CameraError> {
        Camera::new(c.eye, c.target, c.up, c.fov_y_deg)
    }
}

impl<'de> Deserialize<'de> for Camera {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        crate::checked::deserialize::<D, CameraSpec, Self>(d)
    }
}

impl From<Camera> for CameraSpec {
    fn from(c: Camera) -> Self {
        CameraSpec {
            eye: c.eye,
            target: c.target,
            up: c.up,
            fov_y_deg: c.fov_y_deg,
        }
    }
}

/// Why a camera or a camera mode was refused.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum CameraError {
    /// A position or direction has a NaN or infinite component.
    #[error("camera {field} {value:?} is not finite")]
    NotFinite {
        /// Which vector: `"eye"`, `"target"` or `"up"`.
        field: &'static str,
        /// The vector as given.
        value: [f32; 3],
    },
    /// `eye` and `target` coincide (or are so close that the viewing direction cannot be
    /// normalized), so there is no viewing direction; carries the eye.
    #[error("camera eye and target are the same point {0:?}")]
    EyeIsTarget([f32; 3]),
    /// `up` is parallel to the viewing direction (or too small), so the image's horizontal axis is
    /// undefined; carries `up`.
    #[error("camera up {0:?} is parallel to the viewing direction")]
    UpParallel([f32; 3]),
    /// The vertical field of view, in degrees, is not strictly between 0 and 180 (or is NaN).
    #[error("field of view {0} must be between 0 and 180 degrees (exclusive)")]
    BadFov(f32),
    /// The orbit radius, in world units, is zero, negative, infinite or NaN.
    #[error("orbit radius {0} must be finite and above 0")]
    BadRadius(f32),
    /// An orbit's axis is zero or not finite.
    #[error("orbit axis {0:?} must be a finite direction")]
    BadUp([f32; 3]),
    /// The orbit is so small next to its distance from the origin that, in `f32`, some frame's eye
    /// would round onto its target.
    #[error(
        "an orbit of radius {radius} around {center:?} cannot place a camera at single precision; move the scene nearer the origin or scale it up"
    )]
    OrbitTooSmall {
        /// The orbit's centre, in world units.
        center: [f32; 3],
        /// The orbit's radius, in world units.
        radius: f32,
    },
}

/// Checks a field of view in degrees: strictly between 0 and 180.
pub fn check_fov(fov_y_deg: f32) -> Result<(), CameraError> {
    if fov_y_deg > 0.0 && fov_y_deg < 180.0 {
        Ok(())
    } else {
        Err(CameraError::BadFov(fov_y_deg))
    }
}

impl Camera {
    /// A camera at `eye` looking at `target`, `up` roughly up, `fov_y_deg` the vertical field
    /// of view of the whole wall.
    ///
    /// # Errors
    /// A non-finite vector, `eye == target`, `up` parallel to the view, a field of view
    /// outside (0, 180).
    pub fn new(eye: Vec3, target: Vec3, up: Vec3, fov_y_deg: f32) -> Result<Self, CameraError> {
        for (field, v) in [("eye", eye), ("target", target), ("up", up)] {
            if !v.is_finite() {
                return Err(CameraError::NotFinite {
                    field,
                    value: v.to_array(),
                });
            }
        }
        let forward = target - eye;
        if forward.length_squared() == 0.0 || !forward.normalize().is_finite() {
            return Err(CameraError::EyeIsTarget(eye.to_array()));
        }
        let right = forward.normalize().cross(up);
        // NaN lengths fail the first test too: `up` was checked finite, but tiny values can
        // still underflow to a right vector that cannot be normalized.
        if right.length().is_nan() || right.length() < 1e-6 || !right.normalize().is_finite() {
            return Err(CameraError::UpParallel(up.to_array()));
        }
        check_fov(fov_y_deg)?;
        Ok(Camera {
            eye,
            target,
            up,
            fov_y_deg,
        })
    }

    /// Where the pinhole is, in world coordinates.
    pub fn eye(&self) -> Vec3 {
        self.eye
    }

    /// The point the camera looks at, in world coordinates: `target - eye` is the viewing
    /// direction.
    pub fn target(&self) -> Vec3 {
        self.target
    }

    /// Roughly up, as given: the image's vertical is `up` made orthogonal to the viewing direction.
    pub fn up(&self) -> Vec3 {
        self.up
    }

    /// Vertical field of view of the whole wall, in degrees.
    pub fn fov_y_deg(&self) -> f32 {
        self.fov_y_deg
    }
}

/// How the camera of each frame is chosen: fixed, or following the default orbit.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(into = "CameraModeSpec")]
pub struct CameraMode(Mode);

impl<'de> Deserialize<'de> for CameraMode {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        crate::checked::deserialize::<D, CameraModeSpec, Self>(d)
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Mode {
    Fixed(Camera),
    /// Circles `center` about the axis `up`, one degree per frame, far enough for a sphere of
    /// `radius` to fit the field of view.
    Orbit {
        center: Vec3,
        radius: f32,
        fov_y_deg: f32,
        up: Vec3,
    },
}

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
enum CameraModeSpec {
    Fixed(Camera),
    Orbit {
        center: Vec3,
        radius: f32,
        fov_y_deg: f32,
        // Sessions recorded before orbits had an axis turned about +y.
        #[serde(default = "y_up")]
        up: Vec3,
    },
}

fn y_up() -> Vec3 {
    Vec3::Y
}

impl TryFrom<CameraModeSpec> for CameraMode {
    type Error = CameraError;

    fn try_from(spec: CameraModeSpec) -> Result<Self, CameraError> {
        match spec {
            CameraModeSpec::Fixed(camera) => Ok(CameraMode::fixed(camera)),
            CameraModeSpec::Orbit {
                center,
                radius,
                fov_y_deg,
                up,
            } => CameraMode::orbit_about(center, radius, fov_y_deg, up),
        }
    }
}

impl From<CameraMode> for CameraModeSpec {
    fn from(mode: CameraMode) -> Self {
        match mode.0 {
            Mode::Fixed(camera) => CameraModeSpec::Fixed(camera),
            Mode::Orbit {
                center,
                radius,
                fov_y_deg,
                up,
            } => CameraModeSpec::Orbit {
                center,
                radius,
                fov_y_deg,
                up,
            },
        }
    }
}

impl CameraMode {
    /// The same camera for every frame.
    pub fn fixed(camera: Camera) -> Self {
        CameraMode(Mode::Fixed(camera))
    }

    /// An orbit about the +y axis through `center` that keeps a sphere of `radius` (half the
    /// diagonal of the scene's bounds, say) in the field of view, one degree per frame; see
    /// [`CameraMode::orbit_about`].
    ///
    /// # Errors
    /// As [`CameraMode::orbit_about`].
    pub fn orbit(center: Vec3, radius: f32, fov_y_deg: f32) -> Result<Self, CameraError> {
        Self::orbit_about(center, radius, fov_y_deg, Vec3::Y)
    }

    /// An orbit about the axis `up` through `center`, one degree per frame, looking at `center`
    /// from a little above (26.6°) and far enough that the whole sphere of `radius` fits the
    /// vertical field of view: the scene is framed at every frame, not cropped.
    ///
    /// # Errors
    /// A bad field of view, radius or axis, or an orbit so small next to its distance from
    /// the origin that some frame's eye would round onto its target.
    pub fn orbit_about(
        center: Vec3,
        radius: f32,
        fov_y_deg: f32,
        up: Vec3,
    ) -> Result<Self, CameraError> {
        check_fov(fov_y_deg)?;
        if !(radius.is_finite() && radius > 0.0) {
            return Err(CameraError::BadRadius(radius));
        }
        let up = up
            .try_normalize()
            .ok_or(CameraError::BadUp(up.to_array()))?;
        let mode = CameraMode(Mode::Orbit {
            center,
            radius,
            fov_y_deg,
            up,
        });
        // The orbit repeats every 360 frames: checking each camera once covers every frame.
        for frame in 0..360 {
            let c = mode.orbit_camera(frame);
            if Camera::new(c.eye, c.target, c.up, c.fov_y_deg).is_err() {
                return Err(CameraError::OrbitTooSmall {
                    center: center.to_array(),
                    radius,
                });
            }
        }
        Ok(mode)
    }

    /// The fixed camera, if this mode has one.
    pub fn fixed_camera(&self) -> Option<Camera> {
        match self.0 {
            Mode::Fixed(camera) => Some(camera),
            Mode::Orbit { .. } => None,
        }
    }

    /// The camera of frame `frame`: a pure function of the mode and the frame number, so the
    /// single-process reference and the wall agree on every frame.
    pub fn camera_for_frame(&self, frame: u64) -> Camera {
        match self.0 {
            Mode::Fixed(camera) => camera,
            Mode::Orbit { .. } => self.orbit_camera(frame),
        }
    }

    /// The orbit's camera of `frame`, unchecked: [`CameraMode::orbit`] checked all 360.
    fn orbit_camera(&self, frame: u64) -> Camera {
        let Mode::Orbit {
            center,
            radius,
            fov_y_deg,
            up,
        } = self.0
        else {
            unreachable!("only orbits have orbit cameras");
        };
        let (across, toward) = orbit_plane(up);
        let angle = 0.6 + (frame % 360) as f32 * std::f32::consts::PI / 180.0;
        let direction = (across * angle.sin() + up * 0.5 + toward * angle.cos()).normalize();
        Camera {
            eye: center + direction * fit_distance(radius, fov_y_deg),
            target: center,
            up,
            fov_y_deg,
        }
    }
}

/// How far from a sphere's centre of `radius` a camera of vertical field of view `fov_y_deg`
/// must be for the whole sphere to fit, with a 5 % margin. The wall's width is never the
/// narrower side on the walls we know; a portrait wall would crop at its sides.
pub fn fit_distance(radius: f32, fov_y_deg: f32) -> f32 {
    let half = (fov_y_deg.to_radians() * 0.5).clamp(0.01, 1.5);
    radius / half.sin() * 1.05
}

/// Two directions across the orbit's axis `up` (unit): +x and +z about +y, and for any other
/// axis the same turned onto it, so that an orbit about +z (a patient's superior) starts from
/// the same side of the data as one about +y.
fn orbit_plane(up: Vec3) -> (Vec3, Vec3) {
    let seed = if up.x.abs() < 0.9 { Vec3::X } else { Vec3::Y };
    let across = (seed - up * seed.dot(up)).normalize();
    (across, across.cross(up))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera() -> Camera {
        Camera::new(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, Vec3::Y, 90.0).unwrap()
    }

    #[test]
    fn bad_cameras_are_refused() {
        let c = camera();
        assert!(Camera::new(c.eye, c.eye, c.up, 90.0).is_err());
        assert!(matches!(
            Camera::new(c.eye, c.target, Vec3::Z, 90.0),
            Err(CameraError::UpParallel(_))
        ));
        for fov in [0.0, 180.0, -1.0, f32::NAN, f32::INFINITY] {
            assert!(
                matches!(
                    Camera::new(c.eye, c.target, c.up, fov),
                    Err(CameraError::BadFov(_))
                ),
                "{fov}"
            );
        }
        let nan = Vec3::new(f32::NAN, 0.0, 5.0);
        assert!(Camera::new(nan, c.target, c.up, 90.0).is_err());
    }

    #[test]
    fn orbit_cameras_are_valid_and_keep_their_fov() {
        let mode = CameraMode::orbit(Vec3::ONE, 3.0, 30.0).unwrap();
        for frame in [0, 1, 89, 359, 360, u64::MAX] {
            let c = mode.camera_for_frame(frame);
            assert_eq!(Camera::new(c.eye, c.target, c.up, c.fov_y_deg), Ok(c));
            assert_eq!(c.fov_y_deg(), 30.0);
        }
        assert!(CameraMode::orbit(Vec3::ONE, 3.0, 180.0).is_err());
        assert!(CameraMode::orbit(Vec3::ONE, 0.0, 45.0).is_err());
        assert!(CameraMode::orbit(Vec3::ONE, f32::INFINITY, 45.0).is_err());
        assert!(CameraMode::orbit_about(Vec3::ONE, 1.0, 45.0, Vec3::ZERO).is_err());
    }

    #[test]
    fn the_default_orbit_keeps_the_whole_sphere_in_view_at_every_frame() {
        for (fov, up) in [
            (45.0, Vec3::Y),
            (30.0, Vec3::Z),
            (60.0, Vec3::new(1.0, 1.0, 0.0)),
        ] {
            let mode = CameraMode::orbit_about(Vec3::new(3.0, -2.0, 1.0), 2.0, fov, up).unwrap();
            for frame in [0, 45, 90, 200, 359] {
                let c = mode.camera_for_frame(frame);
                let to_centre = Vec3::new(3.0, -2.0, 1.0) - c.eye();
                // The sphere's angular radius seen from the eye is under half the fov.
                let half_angle = (2.0 / to_centre.length()).asin().to_degrees();
                assert!(
                    half_angle < fov * 0.5,
                    "frame {frame}: {half_angle} of {fov}"
                );
                assert!(c.up().dot(up.normalize()) > 0.999, "turns about its axis");
                // Seen from a little above, never from below or from the pole.
                let elevation = (-to_centre).normalize().dot(up.normalize());
                assert!((0.3..0.6).contains(&elevation), "{elevation}");
            }
        }
    }

    #[test]
    fn an_orbit_too_small_for_its_distance_is_refused() {
        // At 1e8 from the origin, f32 steps are 8 units: a 1e-3 orbit puts the eye on the target.
        assert!(matches!(
            CameraMode::orbit(Vec3::splat(1e8), 1e-3, 45.0),
            Err(CameraError::OrbitTooSmall { .. })
        ));
        assert!(CameraMode::orbit(Vec3::splat(1e3), 1e-3, 45.0).is_ok());
    }

    #[test]
    fn deserializing_checks_the_camera() {
        let good = camera();
        let bytes = postcard::to_allocvec(&good).unwrap();
        assert_eq!(postcard::from_bytes::<Camera>(&bytes).unwrap(), good);
        let bad = CameraSpec {
            fov_y_deg: 0.0,
            ..good.into()
        };
        let bytes = postcard::to_allocvec(&bad).unwrap();
        assert!(postcard::from_bytes::<Camera>(&bytes).is_err());
    }
}
