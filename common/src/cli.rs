//! Command-line arguments shared by the binaries (wall, scene, camera), and their checks.

use crate::render::{Camera, CameraMode};
use crate::scene::{Scene, SceneSpec};
use crate::wall::{parse_size, WallLayout, DEFAULT_TILE_SIZE};
use anyhow::{bail, Context, Result};
use clap::Args;
use glam::Vec3;
use std::path::PathBuf;

/// The wall: either `--wall-file` or the `--wall/--screen/--bezel` shorthand.
#[derive(Args, Debug, Clone)]
pub struct WallArgs {
    /// Screens as COLUMNSxROWS, e.g. 2x2.
    #[arg(long, default_value = "2x2", conflicts_with = "wall_file")]
    pub wall: String,
    /// Pixels of one screen as WIDTHxHEIGHT.
    #[arg(long, default_value = "480x270", conflicts_with = "wall_file")]
    pub screen: String,
    /// Pixels hidden between neighbouring screens (mullion).
    #[arg(long, default_value_t = 0, conflicts_with = "wall_file")]
    pub bezel: u32,
    /// Tile edge in pixels; tiles are the unit of load balancing.
    #[arg(long, default_value_t = DEFAULT_TILE_SIZE, conflicts_with = "wall_file")]
    pub tile: u32,
    /// A TOML wall file (columns, rows, screen_width, screen_height, bezel, tile_size).
    #[arg(long)]
    pub wall_file: Option<PathBuf>,
}

impl WallArgs {
    pub fn layout(&self) -> Result<WallLayout> {
        if let Some(path) = &self.wall_file {
            return Ok(WallLayout::from_file(path)?);
        }
        let (columns, rows) = parse_size(&self.wall).context("--wall")?;
        let (w, h) = parse_size(&self.screen).context("--screen")?;
        let layout = WallLayout::grid(columns, rows, w, h)
            .with_bezel(self.bezel)
            .with_tile_size(self.tile);
        layout.validate()?;
        Ok(layout)
    }
}

/// The scene and the camera.
#[derive(Args, Debug, Clone)]
pub struct SceneArgs {
    /// `builtin` (a procedural knot over a floor), `gallery` (the knot among a mirror and
    /// glass), `empty` (a flat backdrop, nothing traced), `knot:SEGMENTS:SIDES`, a mesh path
    /// (OBJ, PLY, glTF/GLB) or particles (.csv, .tpart).
    #[arg(long, default_value = "builtin")]
    pub scene: String,
    /// Camera position X,Y,Z. With --target, fixes the camera; without, the camera orbits.
    #[arg(long, value_parser = parse_vec3, requires = "target", allow_hyphen_values = true)]
    pub eye: Option<Vec3>,
    /// Point the camera looks at, X,Y,Z.
    #[arg(long, value_parser = parse_vec3, requires = "eye", allow_hyphen_values = true)]
    pub target: Option<Vec3>,
    /// Up direction X,Y,Z.
    #[arg(long, value_parser = parse_vec3, default_value = "0,1,0", allow_hyphen_values = true)]
    pub up: Vec3,
    /// Vertical field of view of the whole wall, in degrees.
    #[arg(long, default_value_t = 45.0)]
    pub fov: f32,
}

pub fn parse_vec3(text: &str) -> Result<Vec3, String> {
    let parts: Vec<&str> = text.split(',').collect();
    if parts.len() != 3 {
        return Err(format!("`{text}` is not X,Y,Z"));
    }
    let mut v = [0f32; 3];
    for (slot, part) in v.iter_mut().zip(parts) {
        *slot = part
            .trim()
            .parse()
            .map_err(|_| format!("`{part}` in `{text}` is not a number"))?;
        if !slot.is_finite() {
            return Err(format!("`{part}` in `{text}` is not finite"));
        }
    }
    Ok(Vec3::from_array(v))
}

impl SceneArgs {
    pub fn spec(&self) -> Result<SceneSpec> {
        Ok(SceneSpec::from_arg(&self.scene)?)
    }

    /// The camera mode for a loaded scene: fixed if the flags say so, else the default orbit.
    pub fn camera_mode(&self, scene: &Scene) -> Result<CameraMode> {
        match (self.eye, self.target) {
            (Some(eye), Some(target)) => {
                let camera = Camera {
                    eye,
                    target,
                    up: self.up,
                    fov_y_deg: self.fov,
                };
                camera.validate().context("camera flags")?;
                Ok(CameraMode::Fixed(camera))
            }
            (None, None) => Ok(CameraMode::orbit_of(&scene.bounds())),
            _ => bail!("--eye and --target go together"),
        }
    }
}

/// Per-frame quality knobs, the same for the wall and the reference render.
#[derive(Args, Debug, Clone)]
pub struct QualityArgs {
    /// Trace no shadow rays.
    #[arg(long)]
    pub no_shadows: bool,
    /// Ambient-occlusion rays per hit (0: none).
    #[arg(long, default_value_t = 0)]
    pub ao: u32,
    /// Draw only particles whose attribute is in LO,HI.
    #[arg(long, value_parser = parse_range, allow_hyphen_values = true)]
    pub crop: Option<(f32, f32)>,
    /// Cut away everything on the side NX,NY,NZ points to of the plane at distance D from the
    /// origin (points with N·p > D), to look inside a mesh. Repeat for up to 4 planes; e.g.
    /// `--cut 0,0,1,0` removes all with z > 0.
    #[arg(long = "cut", value_name = "NX,NY,NZ,D", value_parser = parse_plane, allow_hyphen_values = true)]
    pub cuts: Vec<(Vec3, f32)>,
    /// Samples per pixel: 1 traces the pixel centre; more average jittered sub-pixel samples
    /// (antialiasing), each with its own ambient-occlusion rays.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=4096))]
    pub spp: u32,
}

impl QualityArgs {
    /// # Errors
    /// More cutting planes than supported.
    pub fn params(&self) -> Result<crate::render::RenderParams> {
        Ok(crate::render::RenderParams {
            shadows: !self.no_shadows,
            ao_samples: self.ao,
            crop: self.crop,
            cuts: crate::render::CutPlanes::new(&self.cuts).context("--cut")?,
            spp: self.spp,
            ..crate::render::RenderParams::interactive()
        })
    }
}

fn parse_plane(text: &str) -> Result<(Vec3, f32), String> {
    let numbers: Vec<&str> = text.split(',').collect();
    let [x, y, z, d] = numbers[..] else {
        return Err(format!("`{text}` is not NX,NY,NZ,D (four numbers)"));
    };
    let mut values = [0f32; 4];
    for (value, word) in values.iter_mut().zip([x, y, z, d]) {
        *value = word
            .trim()
            .parse()
            .ok()
            .filter(|v: &f32| v.is_finite())
            .ok_or_else(|| format!("`{word}` in `{text}` is not a finite number"))?;
    }
    let normal = Vec3::new(values[0], values[1], values[2]);
    if normal == Vec3::ZERO {
        return Err(format!("`{text}`: the normal NX,NY,NZ must not be zero"));
    }
    Ok((normal, values[3]))
}

fn parse_range(text: &str) -> Result<(f32, f32), String> {
    let (a, b) = text
        .split_once(',')
        .ok_or_else(|| format!("`{text}` is not LO,HI"))?;
    let lo: f32 = a
        .trim()
        .parse()
        .map_err(|_| format!("`{a}` in `{text}` is not a number"))?;
    let hi: f32 = b
        .trim()
        .parse()
        .map_err(|_| format!("`{b}` in `{text}` is not a number"))?;
    if !(lo.is_finite() && hi.is_finite() && lo <= hi) {
        return Err(format!(
            "`{text}` is not a range of finite numbers with LO <= HI"
        ));
    }
    Ok((lo, hi))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crop_ranges_parse_and_garbage_is_explained() {
        assert_eq!(parse_range("-1,2.5").unwrap(), (-1.0, 2.5));
        assert!(parse_range("3,1").is_err());
        assert!(parse_range("1;2").unwrap_err().contains("LO,HI"));
        assert!(parse_range("1,nan").is_err());
    }

    #[test]
    fn planes_parse_and_garbage_is_explained() {
        assert_eq!(parse_plane("0,0,-1,2.5").unwrap(), (-Vec3::Z, 2.5));
        assert!(parse_plane("0,0,0,1").unwrap_err().contains("zero"));
        assert!(parse_plane("1,2,3").unwrap_err().contains("NX,NY,NZ,D"));
        assert!(parse_plane("1,x,3,4").unwrap_err().contains("`x`"));
    }

    #[test]
    fn vectors_parse_and_garbage_is_explained() {
        assert_eq!(parse_vec3("1,-2,3.5").unwrap(), Vec3::new(1.0, -2.0, 3.5));
        assert!(parse_vec3("1,2").unwrap_err().contains("X,Y,Z"));
        assert!(parse_vec3("1,b,3").unwrap_err().contains("`b`"));
        assert!(parse_vec3("1,inf,3").is_err());
    }
}
