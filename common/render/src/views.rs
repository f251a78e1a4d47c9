//! Each viewport's frustum: a part of the camera's one image (a grid wall, seen by one eye), or
//! a physical screen seen from the viewer, whose wall millimetres the camera places in the
//! scene (the viewer at the camera's eye; wall x, y and z along its right, up and back).

use crate::PixelRays;
use glam::{DVec3, Vec3};
use std::sync::Arc;
use tessera_model::camera::Camera;
use tessera_model::screens::{ScreenGeometry, Viewer};
use tessera_model::stereo::{ViewSource, Viewport};
use tessera_model::wall::WallLayout;

// One place for the defaults: `--eye-separation`'s help shows the same constant.
pub use tessera_model::stereo::{DEFAULT_EYE_SEPARATION, DEFAULT_EYE_SEPARATION_MM};

/// The camera's basis, in f64: where every viewport is placed from.
struct CameraBasis {
    eye: DVec3,
    forward: DVec3,
    right: DVec3,
    up: DVec3,
}

impl CameraBasis {
    fn of(camera: &Camera) -> CameraBasis {
        let forward = (camera.target() - camera.eye()).as_dvec3().normalize();
        let right = forward.cross(camera.up().as_dvec3()).normalize();
        CameraBasis {
            eye: camera.eye().as_dvec3(),
            forward,
            right,
            up: right.cross(forward),
        }
    }

    /// A wall vector (millimetres) in the scene, `scale` scene units a millimetre.
    fn vector(&self, v: [f64; 3], scale: f64) -> DVec3 {
        (self.right * v[0] + self.up * v[1] - self.forward * v[2]) * scale
    }
}

/// Each viewport's rays, or `None` when the wall is one image that the camera's one frustum
/// traces (a mono grid: its rays are exactly those of before viewports).
pub fn viewport_rays(camera: &Camera, wall: &WallLayout) -> Option<Arc<[PixelRays]>> {
    if wall.is_one_image() {
        return None;
    }
    let frame = CameraBasis::of(camera);
    let stereo = wall.stereo();
    Some(
        wall.viewports()
            .iter()
            .map(|v| match v.view {
                ViewSource::Image(rect) => {
                    let (w, h) = wall.image_size().expect("an image view is a grid's");
                    let sep = nonzero(stereo.eye_separation, DEFAULT_EYE_SEPARATION);
                    image_rays(camera, &frame, (w, h), rect, (v, sep))
                }
                ViewSource::Screen(screen) => {
                    let viewer = wall.viewer().expect("a screen view is a wall of screens'");
                    let sep = nonzero(stereo.eye_separation, DEFAULT_EYE_SEPARATION_MM);
                    screen_rays(&frame, viewer, &screen, (v, sep))
                }
            })
            .collect(),
    )
}

fn nonzero(v: f64, default: f64) -> f64 {
    if v > 0.0 && v.is_finite() {
        v
    } else {
        default
    }
}

/// Rays of the part `[x, y, w, h]` of the camera's `size` image, seen by the viewport's eye:
/// the image lies on the plane through the camera's target, where the eyes' views meet.
fn image_rays(
    camera: &Camera,
    frame: &CameraBasis,
    (width, height): (u32, u32),
    [x, y, w, h]: [f64; 4],
    (v, separation): (&Viewport, f64),
) -> PixelRays {
    let focus = (camera.target() - camera.eye())
        .as_dvec3()
        .length()
        .max(1e-9);
    let half_h = ((camera.fov_y_deg() as f64).to_radians() * 0.5).tan() * focus;
    let half_w = half_h * width as f64 / height as f64;
    let top_left = frame.eye + frame.forward * focus - frame.right * half_w + frame.up * half_h;
    let across = frame.right * (2.0 * half_w);
    let down = frame.up * (-2.0 * half_h);
    let corner = top_left + across * (x / width as f64) + down * (y / height as f64);
    let across = across * (w / width as f64);
    let down = down * (h / height as f64);
    let eye = frame.eye + frame.right * (separation * v.eye.offset());
    rays(eye, (corner, across, down), v)
}

/// Rays of a physical screen seen by the viewport's eye.
fn screen_rays(
    frame: &CameraBasis,
    viewer: Viewer,
    screen: &ScreenGeometry,
    (v, separation_mm): (&Viewport, f64),
) -> PixelRays {
    let scale = viewer.scene_units_per_m / 1000.0;
    let from_viewer = |p: [f64; 3]| {
        let d = [
            p[0] - viewer.position_mm[0],
            p[1] - viewer.position_mm[1],
            p[2] - viewer.position_mm[2],
        ];
        frame.eye + frame.vector(d, scale)
    };
    let corner = from_viewer(screen.origin);
    let across = frame.vector(screen.across, scale);
    let down = frame.vector(screen.down, scale);
    let eye = frame.eye + frame.right * (separation_mm * scale * v.eye.offset());
    rays(eye, (corner, across, down), v)
}

fn rays(eye: DVec3, (corner, across, down): (DVec3, DVec3, DVec3), v: &Viewport) -> PixelRays {
    let f = |d: DVec3| -> Vec3 { d.as_vec3() };
    // Relative to the eye before f32: a scene far from the origin keeps its precision.
    let e = f(eye);
    PixelRays::through(
        e,
        (e + f(corner - eye), f(across), f(down)),
        (v.width, v.height),
        (v.x, v.y),
    )
}
