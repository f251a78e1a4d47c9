//! Primary rays of the wall's camera: the map from pixels to ray directions (the one frustum of
//! a grid wall's virtual image, or an off-axis frustum per viewport: a physical screen seen
//! from the viewer, or one eye's view), and the default orbit around a scene.

use crate::geometry::Bounds;
use crate::isa::{isa_builds, Build, Isa};
use glam::Vec3;
use tessera_model::camera::{Camera, CameraError, CameraMode};

/// The default orbit around a scene's bounds, with the given field of view. A scene with
/// nothing in it (no finite bounds) is orbited around the origin at unit radius: there is
/// nothing to frame, but the camera must still be a valid one.
///
/// # Errors
/// As [`CameraMode::orbit`]: a bad field of view, or a scene too small for its distance from
/// the origin to place a camera around at single precision.
pub fn orbit_of(bounds: &Bounds, fov_y_deg: f32) -> Result<CameraMode, CameraError> {
    orbit_about_of(bounds, Vec3::Y, fov_y_deg)
}

/// [`orbit_of`] about the axis `up`: a scene's own up (`Scene::orbit`), such as a patient's
/// superior for a CT.
///
/// # Errors
/// As [`orbit_of`], and an axis that is no direction.
pub fn orbit_about_of(
    bounds: &Bounds,
    up: Vec3,
    fov_y_deg: f32,
) -> Result<CameraMode, CameraError> {
    let (center, diagonal) = (bounds.center(), bounds.diagonal().length());
    if !(center.is_finite() && diagonal.is_finite()) {
        return CameraMode::orbit_about(glam::Vec3::ZERO, 1.0, fov_y_deg, up);
    }
    CameraMode::orbit_about(center, (diagonal * 0.5).max(1e-6), fov_y_deg, up)
}

/// Maps pixels to primary-ray directions: the direction through the point `forward + right · sx
/// + up · sy` of the image, `sx` and `sy` running from -1 to 1 across and from 1 to -1 down
/// its pixels, which start at `(x0, y0)`.
#[derive(Clone, Copy, Debug)]
pub struct PixelRays {
    /// Where every ray starts: the camera's eye, in render coordinates.
    pub eye: Vec3,
    forward: Vec3,
    right: Vec3,
    up: Vec3,
    inv_width: f32,
    inv_height: f32,
    /// The first pixel of the image these rays cover (0 for the one image of a grid wall:
    /// subtracting 0 changes no bit, so its rays are what they were before viewports).
    x0: f32,
    y0: f32,
}

impl PixelRays {
    /// The primary-ray generator of `camera` for an image of `width × height` pixels.
    pub fn new(camera: &Camera, width: u32, height: u32) -> Self {
        let forward = (camera.target() - camera.eye()).normalize();
        let right = forward.cross(camera.up()).normalize();
        let up = right.cross(forward);
        let half_h = (camera.fov_y_deg().to_radians() * 0.5).tan();
        let half_w = half_h * width as f32 / height as f32;
        PixelRays {
            eye: camera.eye(),
            forward,
            right: right * half_w,
            up: up * half_h,
            inv_width: 2.0 / width as f32,
            inv_height: 2.0 / height as f32,
            x0: 0.0,
            y0: 0.0,
        }
    }

    /// Rays from `eye` through a rectangle of the world: its top-left corner `top_left`, the
    /// vector `across` its top edge, `down` its left edge (whole lengths), shown on the
    /// `width × height` pixels from `(x0, y0)` (an off-axis frustum: the rectangle need not
    /// face the eye square on).
    pub fn through(
        eye: Vec3,
        (top_left, across, down): (Vec3, Vec3, Vec3),
        (width, height): (u32, u32),
        (x0, y0): (u32, u32),
    ) -> Self {
        let centre = top_left + (across + down) * 0.5;
        PixelRays {
            eye,
            forward: centre - eye,
            right: across * 0.5,
            up: down * -0.5,
            inv_width: 2.0 / width as f32,
            inv_height: 2.0 / height as f32,
            x0: x0 as f32,
            y0: y0 as f32,
        }
    }

    /// Normalized direction through the centre of pixel `(x, y)`.
    #[inline(always)]
    pub fn direction(&self, x: u32, y: u32) -> Vec3 {
        self.direction_at(x, y, 0.5, 0.5)
    }

    /// Normalized direction through the point `(x + jx, y + jy)` of the image, `jx, jy` in
    /// [0, 1): the sub-pixel samples of supersampling.
    #[inline(always)]
    pub fn direction_at(&self, x: u32, y: u32, jx: f32, jy: f32) -> Vec3 {
        let sx = (x as f32 - self.x0 + jx) * self.inv_width - 1.0;
        let sy = 1.0 - (y as f32 - self.y0 + jy) * self.inv_height;
        (self.forward + self.right * sx + self.up * sy).normalize()
    }

    /// [`PixelRays::direction_at`] through the centres of the pixels `(px[i], py[i])` (given
    /// as floats), written to `dir[axis][i]`: the same operations in the same order, lane by
    /// lane, on the widest SIMD build this CPU runs (compiled for the baseline, four lanes at a
    /// time, this and the packet's setup around it were 4 % of an eye-light frame).
    #[inline(always)]
    pub(crate) fn directions_soa(&self, px: &[f32], py: &[f32], dir: &mut [[f32; 64]; 3]) {
        directions_on(Isa::best(), self, px, py, dir);
    }
}

isa_builds! {
    /// [`PixelRays::directions_soa`] on the build `isa`.
    fn directions_on<>(
        rays: &PixelRays,
        px: &[f32],
        py: &[f32],
        dir: &mut [[f32; 64]; 3],
    ) = directions_kernel on [Avx2, Avx512];
}

#[inline(always)]
fn directions_kernel<B: Build>(
    _: B,
    rays: &PixelRays,
    px: &[f32],
    py: &[f32],
    dir: &mut [[f32; 64]; 3],
) {
    let n = px.len().min(py.len()).min(64);
    for i in 0..n {
        let sx = (px[i] - rays.x0 + 0.5) * rays.inv_width - 1.0;
        let sy = 1.0 - (py[i] - rays.y0 + 0.5) * rays.inv_height;
        let x = rays.forward.x + rays.right.x * sx + rays.up.x * sy;
        let y = rays.forward.y + rays.right.y * sx + rays.up.y * sy;
        let z = rays.forward.z + rays.right.z * sx + rays.up.z * sy;
        let recip = 1.0 / (x * x + y * y + z * z).sqrt();
        dir[0][i] = x * recip;
        dir[1][i] = y * recip;
        dir[2][i] = z * recip;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every SIMD build's directions are the portable build's, bit for bit, over a block
    /// of 64 pixels of an off-centre camera (and a short block).
    #[test]
    fn every_build_gives_the_portable_directions() {
        let camera = Camera::new(
            Vec3::new(0.3, 1.7, 5.0),
            Vec3::new(0.1, 0.2, 0.0),
            Vec3::Y,
            37.0,
        )
        .unwrap();
        let rays = PixelRays::new(&camera, 1920, 1080);
        let px: Vec<f32> = (0..64).map(|i| (1000 + i % 8) as f32).collect();
        let py: Vec<f32> = (0..64).map(|i| (333 + i / 8) as f32).collect();
        for n in [64, 21] {
            let mut portable = [[0.0f32; 64]; 3];
            directions_on(Isa::Portable, &rays, &px[..n], &py[..n], &mut portable);
            assert_eq!(portable[1][0], rays.direction(1000, 333).y);
            for isa in Isa::available() {
                let mut got = [[0.0f32; 64]; 3];
                directions_on(isa, &rays, &px[..n], &py[..n], &mut got);
                let bits = |d: &[[f32; 64]; 3]| d.map(|a| a.map(f32::to_bits));
                assert_eq!(bits(&got), bits(&portable), "{isa:?}, {n} lanes");
            }
        }
    }

    #[test]
    fn centre_pixel_looks_at_target_and_row_zero_is_top() {
        let camera = Camera::new(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, Vec3::Y, 90.0).unwrap();
        let rays = PixelRays::new(&camera, 3, 3);
        assert!((rays.direction(1, 1) - Vec3::NEG_Z).length() < 1e-6);
        assert!(rays.direction(1, 0).y > 0.0);
        assert!(rays.direction(0, 1).x < 0.0);
    }

    #[test]
    fn the_orbit_honours_its_field_of_view() {
        let bounds = Bounds {
            min: Vec3::ZERO,
            max: Vec3::ONE,
        };
        let orbit = orbit_of(&bounds, 20.0).unwrap();
        assert_eq!(orbit.camera_for_frame(7).fov_y_deg(), 20.0);
        assert!(orbit_of(&bounds, 0.0).is_err());
    }

    #[test]
    fn an_empty_scene_still_gets_a_valid_orbit() {
        let empty = crate::scene::Scene::default().bounds();
        let orbit = orbit_of(&empty, 45.0).unwrap();
        assert!(orbit.camera_for_frame(0).eye().is_finite());
    }
}
