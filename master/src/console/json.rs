//! The console's JSON: the wall's status as an operator reads it (no internal tags, nothing
//! that does not apply to the scene), and the request bodies, each turned into the control
//! request the CLI would send, through the same checks.

use anyhow::{bail, Context, Result};
use glam::Vec3;
use serde::{Deserialize, Serialize};
use tessera_core::master::report::WallReport;
use tessera_model::camera::{Camera, CameraMode};
use tessera_model::light::{Light, Lights};
use tessera_model::state::StateChange;
use tessera_model::volume_params::{IsoValues, TransferFunction, TransferPoint, VolumeParams};
use tessera_model::wall::WallLayout;
use tessera_protocol::control::{ControlRequest, WallStatus};

/// The wall's status, as `GET /api/status` and `tessera-master control state` show it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct StatusView {
    pub frame: u64,
    pub state_id: u64,
    pub converged: bool,
    pub overlay: bool,
    pub wall: WallReport,
    pub camera: CameraView,
    pub quality: QualityView,
    pub cuts: Vec<[f32; 4]>,
    pub lights: Option<Vec<LightView>>,
    pub views: Vec<String>,
    pub volume: Option<VolumeView>,
    pub particles: Option<ParticlesView>,
}

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CameraView {
    pub eye: [f32; 3],
    pub target: [f32; 3],
    pub up: [f32; 3],
    pub fov: f32,
    pub orbit: bool,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct QualityView {
    pub shadows: bool,
    pub ao: u32,
    pub spp: u32,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase", deny_unknown_fields)]
pub enum LightView {
    Directional { towards: [f32; 3], intensity: f32 },
    Point { position: [f32; 3], intensity: f32 },
}

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct VolumeView {
    pub iso: Vec<f32>,
    pub step: f32,
    pub time_step: u32,
    pub steps: u32,
    pub playing: bool,
    pub speed: Option<f32>,
    pub range: Option<[f32; 2]>,
    pub transfer: TransferView,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TransferView {
    pub domain: tessera_model::volume_params::TransferDomain,
    pub points: Vec<TransferPoint>,
}

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ParticlesView {
    pub range: [f32; 2],
    pub crop: Option<[f32; 2]>,
    pub colormap: &'static str,
}

fn v3(v: Vec3) -> [f32; 3] {
    v.to_array()
}

impl StatusView {
    /// What `status` says of the wall `wall`; volume settings only where there is a volume.
    pub fn of(status: &WallStatus, wall: &WallLayout) -> StatusView {
        let state = &status.state;
        let params = &state.params;
        let camera = state.camera.camera_for_frame(status.frame);
        let volume = params.volume();
        let has_volume = status.volume_range.is_some() || status.series.is_some();
        StatusView {
            frame: status.frame,
            state_id: status.state_id.0,
            converged: status.converged,
            overlay: status.overlay,
            wall: WallReport::of(wall),
            camera: CameraView {
                eye: v3(camera.eye()),
                target: v3(camera.target()),
                up: v3(camera.up()),
                fov: camera.fov_y_deg(),
                orbit: state.camera.fixed_camera().is_none(),
            },
            quality: QualityView {
                shadows: params.shadows(),
                ao: params.ao_samples(),
                spp: params.spp(),
            },
            cuts: params
                .cuts()
                .planes()
                .iter()
                .map(|p| p.to_array())
                .collect(),
            lights: state
                .lights
                .map(|l| l.as_slice().iter().map(light_view).collect()),
            views: status
                .views
                .iter()
                .map(|v| v.as_str().to_string())
                .collect(),
            volume: has_volume.then(|| VolumeView {
                iso: volume.iso.as_slice().to_vec(),
                step: volume.step,
                time_step: volume.time_step,
                steps: status.series.map_or(1, |s| s.steps),
                playing: status.series.is_some_and(|s| s.playing),
                speed: status.series.and_then(|s| s.steps_per_second),
                range: status.volume_range,
                transfer: TransferView {
                    domain: volume.transfer.domain(),
                    points: volume.transfer.points().to_vec(),
                },
            }),
            particles: status.particle_range.map(|range| ParticlesView {
                range,
                crop: params.crop().map(|(a, b)| [a, b]),
                colormap: params.colormap().name(),
            }),
        }
    }
}

fn light_view(light: &Light) -> LightView {
    match *light {
        Light::Directional { towards, intensity } => LightView::Directional {
            towards: v3(towards),
            intensity,
        },
        Light::Point {
            position,
            intensity,
        } => LightView::Point {
            position: v3(position),
            intensity,
        },
    }
}

/// `POST /api/camera`: one of fit, home, orbit, or a whole camera.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraBody {
    #[serde(default)]
    pub fit: bool,
    #[serde(default)]
    pub home: bool,
    #[serde(default)]
    pub orbit: bool,
    pub eye: Option<[f32; 3]>,
    pub target: Option<[f32; 3]>,
    pub up: Option<[f32; 3]>,
    pub fov: Option<f32>,
}

/// `POST /api/quality`: the knobs given.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct QualityBody {
    pub shadows: Option<bool>,
    pub ao: Option<u32>,
    pub spp: Option<u32>,
}

/// `POST /api/cuts`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CutsBody {
    pub planes: Vec<[f32; 4]>,
}

/// `POST /api/lights`: the scene's own, or these.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightsBody {
    #[serde(default)]
    pub scene: bool,
    pub lights: Option<Vec<LightView>>,
}

/// `POST /api/volume`: what is given changes.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VolumeBody {
    pub iso: Option<Vec<f32>>,
    pub step: Option<f32>,
    pub time_step: Option<u32>,
    pub transfer: Option<TransferView>,
    pub preset: Option<String>,
}

/// `POST /api/particles`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ParticlesBody {
    pub colormap: String,
}

/// `POST /api/playback`.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlaybackBody {
    pub playing: Option<bool>,
    pub speed: Option<f32>,
    pub step: Option<i32>,
}

/// The request of a camera body, `now` being the camera on the wall and `home` the one it
/// started with.
pub fn camera_request(body: &CameraBody, now: &Camera, home: CameraMode) -> Result<ControlRequest> {
    use tessera_model::input::{InputEvent, Key};
    let chosen = [body.fit, body.home, body.orbit]
        .iter()
        .filter(|b| **b)
        .count();
    let explicit = body.eye.is_some() || body.target.is_some() || body.up.is_some();
    if chosen + usize::from(explicit || body.fov.is_some()) != 1 {
        bail!("give one of fit, home, orbit, or eye/target/up/fov");
    }
    if body.fit {
        return Ok(ControlRequest::Fit);
    }
    if body.home {
        // The window's key: the same navigator decides what home is.
        let key = Key::H;
        return Ok(ControlRequest::Input(InputEvent::Key {
            key,
            pressed: true,
        }));
    }
    let mode = if body.orbit {
        home
    } else {
        let or = |v: Option<[f32; 3]>, d: Vec3| v.map_or(d, Vec3::from_array);
        let camera = Camera::new(
            or(body.eye, now.eye()),
            or(body.target, now.target()),
            or(body.up, now.up()),
            body.fov.unwrap_or(now.fov_y_deg()),
        )
        .context("camera")?;
        CameraMode::fixed(camera)
    };
    Ok(change(StateChange::Camera(mode)))
}

fn change(c: StateChange) -> ControlRequest {
    ControlRequest::Change(vec![c])
}

/// The request of a quality body.
pub fn quality_request(body: &QualityBody) -> Result<ControlRequest> {
    crate::control::quality(body.shadows, body.ao, body.spp, None)
}

/// The request of a cuts body.
pub fn cuts_request(body: &CutsBody) -> Result<ControlRequest> {
    let planes: Vec<(Vec3, f64)> = body
        .planes
        .iter()
        .map(|p| (Vec3::new(p[0], p[1], p[2]), p[3] as f64))
        .collect();
    Ok(change(crate::control::cuts(&planes, planes.is_empty())?))
}

/// The request of a lights body.
pub fn lights_request(body: &LightsBody) -> Result<ControlRequest> {
    let lights: Vec<Light> = match (&body.lights, body.scene) {
        (None, true) => return Ok(change(StateChange::Lights(None))),
        (Some(lights), false) => lights
            .iter()
            .map(|l| match *l {
                LightView::Directional { towards, intensity } => {
                    Light::directional(Vec3::from_array(towards), intensity)
                }
                LightView::Point {
                    position,
                    intensity,
                } => Light::Point {
                    position: Vec3::from_array(position),
                    intensity,
                },
            })
            .collect(),
        _ => bail!("give either scene: true or lights"),
    };
    Ok(change(StateChange::Lights(Some(
        Lights::new(&lights).context("lights")?,
    ))))
}

/// The request of a volume body, changing `volume` (the settings after the next barrier).
pub fn volume_request(body: &VolumeBody, mut volume: VolumeParams) -> Result<ControlRequest> {
    if body.transfer.is_some() && body.preset.is_some() {
        bail!("give transfer or preset, not both");
    }
    if let Some(iso) = &body.iso {
        volume.iso = IsoValues::new(iso).context("iso")?;
    }
    if let Some(step) = body.step {
        volume.step = step;
    }
    if let Some(t) = body.time_step {
        volume.time_step = t;
    }
    if let Some(name) = &body.preset {
        volume.transfer = TransferFunction::preset_named(name)
            .with_context(|| format!("preset {name:?}: the presets are ramp, ct-bone, ct-skin"))?;
    }
    if let Some(t) = &body.transfer {
        volume.transfer = TransferFunction::new(t.domain, &t.points).context("transfer")?;
    }
    volume.check().context("volume")?;
    Ok(change(StateChange::Volume(volume)))
}
