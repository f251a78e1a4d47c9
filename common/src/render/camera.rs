//! The pinhole camera of the whole wall and the default orbit.
//!
//! Convention (also in the README): pinhole at `eye`, looking at `target`, `up` roughly up,
//! `fov_y_deg` the vertical field of view of the whole virtual image (bezels included), one ray
//! through the centre `(x + 0.5, y + 0.5)` of each pixel, row 0 at the top.

use crate::geometry::Bounds;
use glam::Vec3;
use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Camera {
    pub eye: Vec3,
    pub target: Vec3,
    pub up: Vec3,
    pub fov_y_deg: f32,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum CameraError {
    #[error("camera {field} {value:?} is not finite")]
    NotFinite {
        field: &'static str,
        value: [f32; 3],
    },
    #[error("camera eye and target are the same point {0:?}")]
    EyeIsTarget([f32; 3]),
    #[error("camera up {0:?} is parallel to the viewing direction")]
    UpParallel([f32; 3]),
    #[error("camera fov {0} must be between 0 and 180 degrees")]
    BadFov(f32),
}

/// How the camera of each frame is chosen: fixed, or following the default orbit.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum CameraMode {
    Fixed(Camera),
    /// Circles `center` at a distance scaled by `radius`, one degree per frame.
    Orbit {
        center: Vec3,
        radius: f32,
    },
}

impl CameraMode {
    /// The default orbit around a scene's bounds.
    pub fn orbit_of(bounds: &Bounds) -> Self {
        CameraMode::Orbit {
            center: bounds.center(),
            radius: (bounds.diagonal().length() * 0.5).max(1e-6),
        }
    }

    /// The camera of frame `frame`: a pure function of the mode and the frame number, so the
    /// single-process reference and the wall agree on every frame.
    pub fn camera_for_frame(&self, frame: u64) -> Camera {
        match *self {
            CameraMode::Fixed(camera) => camera,
            CameraMode::Orbit { center, radius } => {
                let angle = 0.6 + (frame % 360) as f32 * std::f32::consts::PI / 180.0;
                let offset = Vec3::new(angle.sin(), 0.5, angle.cos()) * (radius * 1.2);
                Camera {
                    eye: center + offset,
                    target: center - Vec3::Y * (radius * 0.08),
                    up: Vec3::Y,
                    fov_y_deg: 45.0,
                }
            }
        }
    }
}

impl Camera {
    pub fn validate(&self) -> Result<(), CameraError> {
        for (field, v) in [("eye", self.eye), ("target", self.target), ("up", self.up)] {
            if !v.is_finite() {
                return Err(CameraError::NotFinite {
                    field,
                    value: v.to_array(),
                });
            }
        }
        let forward = self.target - self.eye;
        if forward.length_squared() == 0.0 || !forward.normalize().is_finite() {
            return Err(CameraError::EyeIsTarget(self.eye.to_array()));
        }
        let right = forward.normalize().cross(self.up);
        if right.length() < 1e-6 {
            return Err(CameraError::UpParallel(self.up.to_array()));
        }
        if !(self.fov_y_deg > 0.0 && self.fov_y_deg < 180.0) {
            return Err(CameraError::BadFov(self.fov_y_deg));
        }
        Ok(())
    }

    /// The primary-ray generator for an image of `width × height` pixels.
    pub fn rays_for(&self, width: u32, height: u32) -> PixelRays {
        let forward = (self.target - self.eye).normalize();
        let right = forward.cross(self.up).normalize();
        let up = right.cross(forward);
        let half_h = (self.fov_y_deg.to_radians() * 0.5).tan();
        let half_w = half_h * width as f32 / height as f32;
        PixelRays {
            eye: self.eye,
            forward,
            right: right * half_w,
            up: up * half_h,
            inv_width: 2.0 / width as f32,
            inv_height: 2.0 / height as f32,
        }
    }
}

/// Maps virtual-image pixels to primary-ray directions.
#[derive(Clone, Copy, Debug)]
pub struct PixelRays {
    pub eye: Vec3,
    forward: Vec3,
    right: Vec3,
    up: Vec3,
    inv_width: f32,
    inv_height: f32,
}

impl PixelRays {
    /// Normalized direction through the centre of pixel `(x, y)`.
    #[inline(always)]
    pub fn direction(&self, x: u32, y: u32) -> Vec3 {
        self.direction_at(x, y, 0.5, 0.5)
    }

    /// Normalized direction through the point `(x + jx, y + jy)` of the image, `jx, jy` in
    /// [0, 1): the sub-pixel samples of supersampling.
    #[inline(always)]
    pub fn direction_at(&self, x: u32, y: u32, jx: f32, jy: f32) -> Vec3 {
        let sx = (x as f32 + jx) * self.inv_width - 1.0;
        let sy = 1.0 - (y as f32 + jy) * self.inv_height;
        (self.forward + self.right * sx + self.up * sy).normalize()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera() -> Camera {
        Camera {
            eye: Vec3::new(0.0, 0.0, 5.0),
            target: Vec3::ZERO,
            up: Vec3::Y,
            fov_y_deg: 90.0,
        }
    }

    #[test]
    fn centre_pixel_looks_at_target_and_row_zero_is_top() {
        let rays = camera().rays_for(3, 3);
        assert!((rays.direction(1, 1) - Vec3::NEG_Z).length() < 1e-6);
        assert!(rays.direction(1, 0).y > 0.0);
        assert!(rays.direction(0, 1).x < 0.0);
    }

    #[test]
    fn bad_cameras_are_refused() {
        let mut c = camera();
        c.target = c.eye;
        assert!(c.validate().is_err());
        let mut c = camera();
        c.up = Vec3::Z;
        assert!(matches!(c.validate(), Err(CameraError::UpParallel(_))));
        let mut c = camera();
        c.fov_y_deg = 180.0;
        assert!(c.validate().is_err());
        let mut c = camera();
        c.eye.x = f32::NAN;
        assert!(c.validate().is_err());
        assert!(camera().validate().is_ok());
    }

    #[test]
    fn orbit_cameras_are_valid() {
        let mode = CameraMode::Orbit {
            center: Vec3::ONE,
            radius: 3.0,
        };
        for frame in [0, 1, 89, 359, 360, u64::MAX] {
            mode.camera_for_frame(frame).validate().unwrap();
        }
    }
}
