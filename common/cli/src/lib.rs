//! What Tessera's binaries share at their edge: command-line arguments for the wall, the
//! scene, the camera and the quality knobs (clap derive), their checks, and the log set-up.
//!
//! Every argument ends up in a `tessera-model` type through that type's validating constructor,
//! so the command line can give no value the network would refuse; each error names the flag.
//! It depends on clap, tracing-subscriber, image (PNG files, [`png`]) and `tessera-model`
//! only, so display nodes use it without compiling the renderer. Reading wall files
//! ([`wall_file`]) and writing images are here, at the edge, so the model does no file I/O.

#![warn(missing_docs)]

pub mod bytes;
pub mod iso_arg;
pub mod logging;
pub mod png;
pub mod procs;
pub mod reconnect;
pub mod transfer_file;
pub mod wall_file;

use clap::Args;
use glam::{DVec3, Vec3};
use std::path::PathBuf;
use tessera_model::camera::{check_fov, Camera, CameraError, CameraMode, DEFAULT_FOV_DEG};
use tessera_model::cut::{CutError, CutPlanes};
use tessera_model::local_origin::RenderFromWorld;
use tessera_model::params::{ParamsError, RenderParams, RenderParamsSpec, Shading, MAX_SPP};
use tessera_model::scene_spec::{SceneSpec, SceneSpecError};
use tessera_model::stereo::{Stereo, StereoMode, DEFAULT_EYE_SEPARATION};
use tessera_model::volume_params::VolumeParams;
use tessera_model::wall::{parse_size, WallError, WallLayout, WallSpec, DEFAULT_TILE_SIZE};
use tessera_model::window::WallFile;
use tessera_protocol::pixels::Compression;

/// A flag whose value was refused, named with its flag.
#[derive(Debug, thiserror::Error)]
pub enum ArgError {
    /// The wall flags or the wall file do not make a wall.
    #[error("{flag}")]
    Wall {
        /// The flag or flags at fault, such as `--screen` or `--wall-file`.
        flag: &'static str,
        /// Why the wall was refused.
        source: WallError,
    },
    /// `--scene` names no scene (a malformed `knot:SEGMENTS:SIDES`, for one).
    #[error("--scene")]
    Scene(#[from] SceneSpecError),
    /// The camera flags make no camera (the eye on the target, up along the view), or no orbit
    /// could be made around the scene.
    #[error("camera flags")]
    Camera(#[from] CameraError),
    /// More `--cut` planes than supported, or a degenerate one.
    #[error("--cut")]
    Cut(#[from] CutError),
    /// A quality knob (`--ao`, `--spp`, `--crop`, `--iso`, `--volume-step`) is out of its bounds.
    #[error("quality flags")]
    Params(#[from] ParamsError),
    /// Only one of `--eye` and `--target` was given.
    #[error("--eye and --target go together")]
    EyeWithoutTarget,
    /// `--transfer` names no preset or a file that does not hold a transfer function.
    #[error("--transfer")]
    Transfer(#[from] transfer_file::TransferFileError),
}

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
    /// Tile edge in pixels; tiles are the unit of load balancing (`--tile` is the old name).
    #[arg(
        long,
        alias = "tile",
        default_value_t = DEFAULT_TILE_SIZE,
        conflicts_with = "wall_file"
    )]
    pub tile_size: u32,
    /// Stereo: `side-by-side` (each display's left half the left eye, right half the right),
    /// `top-bottom`, or `displays` (two displays a screen: 2k the left eye of screen k, 2k+1
    /// the right, for passive stereo with two projectors a screen). A wall file says it in its
    /// `[stereo]` table.
    #[arg(long, value_enum, default_value_t = StereoArg::Mono, conflicts_with = "wall_file")]
    pub stereo: StereoArg,
    /// With --stereo: the distance between the eyes in scene units; the eyes' views meet at
    /// the camera's target.
    #[arg(
        long,
        default_value_t = DEFAULT_EYE_SEPARATION,
        requires = "stereo",
        value_parser = parse_separation
    )]
    pub eye_separation: f64,
    /// A TOML wall file: a grid (columns, rows, screen_width, screen_height, bezel, tile_size)
    /// or physical screens (a `[viewer]` and `[[screen]]` tables; see deploy/walls/).
    #[arg(long)]
    pub wall_file: Option<PathBuf>,
}

/// `--stereo`.
#[derive(clap::ValueEnum, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum StereoArg {
    /// No stereo: one image, from the viewer's centre.
    #[default]
    Mono,
    /// Each display's left half the left eye, its right half the right.
    SideBySide,
    /// Each display's top half the left eye, its bottom half the right.
    TopBottom,
    /// Two displays a screen: display 2k the left eye of screen k, 2k+1 the right.
    Displays,
}

/// Refuses 0: a stereo model's 0 means "the default", which the flag already gives, so a 0
/// typed here would quietly become 0.065.
fn parse_separation(text: &str) -> Result<f64, String> {
    match text.trim().parse::<f64>() {
        Ok(d) if d.is_finite() && d > 0.0 => Ok(d),
        _ => Err(format!(
            "`{text}` is not a distance more than 0 (scene units; {DEFAULT_EYE_SEPARATION} without the flag)"
        )),
    }
}

impl WallArgs {
    /// The wall's layout, from the wall file or the shorthand flags (without where a wall
    /// file puts the displays' windows: see [`WallArgs::wall_file`]).
    pub fn layout(&self) -> Result<WallLayout, ArgError> {
        Ok(self.wall_file()?.layout)
    }

    /// The wall and, from a wall file, where its displays' windows go.
    pub fn wall_file(&self) -> Result<WallFile, ArgError> {
        let wall = |flag| move |source| ArgError::Wall { flag, source };
        if let Some(path) = &self.wall_file {
            return wall_file::read(path).map_err(wall("--wall-file"));
        }
        let (columns, rows) = parse_size(&self.wall).map_err(wall("--wall"))?;
        let (w, h) = parse_size(&self.screen).map_err(wall("--screen"))?;
        let mode = match self.stereo {
            StereoArg::Mono => StereoMode::Mono,
            StereoArg::SideBySide => StereoMode::SideBySide,
            StereoArg::TopBottom => StereoMode::TopBottom,
            StereoArg::Displays => StereoMode::Displays,
        };
        let stereo = Stereo {
            mode,
            eye_separation: self.eye_separation,
        };
        let layout = WallSpec::grid(columns, rows, w, h)
            .bezel(self.bezel)
            .tile_size(self.tile_size)
            .build_stereo(stereo)
            .map_err(wall("--wall/--screen/--bezel/--tile-size"))?;
        Ok(WallFile {
            layout,
            windows: Default::default(),
        })
    }
}

/// The scene and the camera.
#[derive(Args, Debug, Clone)]
pub struct SceneArgs {
    /// `builtin` (a procedural knot over a floor), `gallery` (the knot among a mirror and
    /// glass), `empty` (a flat backdrop, nothing traced), `knot:SEGMENTS:SIDES`, a mesh path
    /// (OBJ, PLY, glTF/GLB), particles (.csv, .tpart), a volume (.nrrd, .nhdr, .nii, .nii.gz,
    /// .vol.toml; see --iso and --transfer) or a .scene.toml naming several of them.
    #[arg(long, default_value = "builtin")]
    pub scene: String,
    /// Camera position X,Y,Z. With --target, fixes the camera; without, the camera orbits.
    /// World coordinates, read in f64 (a mesh far from the origin keeps its camera exact).
    #[arg(long, value_parser = parse_dvec3, requires = "target", allow_hyphen_values = true)]
    pub eye: Option<DVec3>,
    /// Point the camera looks at, X,Y,Z, in world coordinates.
    #[arg(long, value_parser = parse_dvec3, requires = "eye", allow_hyphen_values = true)]
    pub target: Option<DVec3>,
    /// Up direction X,Y,Z.
    #[arg(long, value_parser = parse_vec3, default_value = "0,1,0", allow_hyphen_values = true)]
    pub up: Vec3,
    /// Vertical field of view of the whole wall, in degrees (0 < FOV < 180), for a fixed
    /// camera and the orbit alike.
    #[arg(long, default_value_t = DEFAULT_FOV_DEG, value_parser = parse_fov, allow_hyphen_values = true)]
    pub fov: f32,
    /// Missing data: NaN or infinite voxels, and particles whose attribute is NaN. `missing`
    /// draws them as such (voxels transparent, no iso-surface through their cells, the count
    /// in the log; particles grey); `refuse` refuses such a scene, naming the first.
    #[arg(long = "nan", value_enum, default_value = "missing")]
    pub nan: NanPolicy,
}

/// What a scene's missing data (NaN or infinite values) does: see [`SceneArgs::nan`].
#[derive(clap::ValueEnum, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum NanPolicy {
    /// Drawn as missing data.
    #[default]
    Missing,
    /// The scene is refused.
    Refuse,
}

/// A flag's value that does not parse, with what was expected.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
#[error("{0}")]
pub struct BadValue(String);

fn bad(text: String) -> BadValue {
    BadValue(text)
}

impl From<String> for BadValue {
    fn from(text: String) -> Self {
        BadValue(text)
    }
}

fn parse_fov(text: &str) -> Result<f32, BadValue> {
    let fov: f32 = text
        .trim()
        .parse()
        .map_err(|_| format!("`{text}` is not a number of degrees"))?;
    check_fov(fov).map_err(|e| e.to_string())?;
    Ok(fov)
}

/// Parses `X,Y,Z` into a vector of finite numbers.
pub fn parse_vec3(text: &str) -> Result<Vec3, BadValue> {
    let v = parse_dvec3(text)?.as_vec3();
    if !v.is_finite() {
        return Err(bad(format!("`{text}` is out of the f32 range")));
    }
    Ok(v)
}

/// Parses `X,Y,Z` into a vector of finite f64 numbers (world coordinates).
pub fn parse_dvec3(text: &str) -> Result<DVec3, BadValue> {
    let parts: Vec<&str> = text.split(',').collect();
    if parts.len() != 3 {
        return Err(bad(format!("`{text}` is not X,Y,Z")));
    }
    let mut v = [0f64; 3];
    for (slot, part) in v.iter_mut().zip(parts) {
        *slot = part
            .trim()
            .parse()
            .map_err(|_| format!("`{part}` in `{text}` is not a number"))?;
        if !slot.is_finite() {
            return Err(bad(format!("`{part}` in `{text}` is not finite")));
        }
    }
    Ok(DVec3::from_array(v))
}

impl SceneArgs {
    /// What `--scene` names, checked but not loaded (a path is not opened here).
    pub fn spec(&self) -> Result<SceneSpec, ArgError> {
        Ok(SceneSpec::from_arg(&self.scene)?)
    }

    /// The camera mode in render coordinates: fixed if the flags say so (their world
    /// coordinates moved by `frame`, the scene's), else `orbit`, the default orbit around the
    /// loaded scene made with [`SceneArgs::fov`] (the renderer's `orbit_of`).
    pub fn camera_mode(
        &self,
        frame: &RenderFromWorld,
        orbit: impl FnOnce(f32) -> Result<CameraMode, CameraError>,
    ) -> Result<CameraMode, ArgError> {
        match (self.eye, self.target) {
            (Some(eye), Some(target)) => Ok(CameraMode::fixed(Camera::new(
                frame.point(eye),
                frame.point(target),
                self.up,
                self.fov,
            )?)),
            (None, None) => Ok(orbit(self.fov)?),
            _ => Err(ArgError::EyeWithoutTarget),
        }
    }
}

/// Per-frame quality knobs, the same for the wall and the reference render.
#[derive(Args, Debug, Clone)]
pub struct QualityArgs {
    /// Trace no shadow rays.
    #[arg(long)]
    pub no_shadows: bool,
    /// Ambient-occlusion rays per hit (0: none; at most 1024).
    #[arg(long, default_value_t = 0)]
    pub ao: u32,
    /// Draw only particles whose attribute is in LO,HI.
    #[arg(long, value_parser = parse_range, allow_hyphen_values = true)]
    pub crop: Option<(f32, f32)>,
    /// Particles: the colour map of their attribute (viridis, magma, coolwarm, greys).
    #[arg(long, default_value = "viridis", value_parser = parse_colormap)]
    pub colormap: tessera_model::colormap::ColorMap,
    /// Cut away everything on the side NX,NY,NZ points to of the plane at distance D from the
    /// origin (points with N·p > D), to look inside a mesh. Repeat for up to 4 planes; e.g.
    /// `--cut 0,0,1,0` removes all with z > 0.
    #[arg(long = "cut", value_name = "NX,NY,NZ,D", value_parser = parse_plane, allow_hyphen_values = true)]
    pub cuts: Vec<(Vec3, f64)>,
    /// Samples per pixel: 1 traces the pixel centre; more average jittered sub-pixel samples
    /// (antialiasing), each with its own ambient-occlusion rays.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=MAX_SPP as i64))]
    pub spp: u32,
    /// Volumes: draw the direct iso-surface at this value, in the data's own units (e.g.
    /// Hounsfield units for CT) instead of the transfer function. Repeat for up to 4 surfaces.
    /// COLOUR is a name (bone, skin, red, green, blue, yellow, white, grey) or R,G,B from 0
    /// to 1, OPACITY from 0 to 1; by default each surface has its own colour and, with
    /// several, all but the highest value's are translucent (0.4) so the inner one shows.
    #[arg(long = "iso", value_name = "VALUE[:COLOUR[:OPACITY]]", value_parser = iso_arg::parse_iso, allow_hyphen_values = true)]
    pub iso: Vec<iso_arg::IsoArg>,
    /// Volumes: ray-marching step in world units (those of the voxel spacing); 0 picks half the
    /// smallest spacing. Opacity is corrected for the step, so the look stays the same.
    #[arg(long, default_value_t = 0.0)]
    pub volume_step: f32,
    /// Volumes: the transfer function, a preset (ramp, ct-bone, ct-skin) or a TOML file of
    /// points (see deploy/volumes/README.md).
    #[arg(long, default_value = "ramp")]
    pub transfer: String,
    /// Volumes: which step of a time series to show (see `series` in a .scene.toml).
    #[arg(long, default_value_t = 0)]
    pub time_step: u32,
    /// Draw missing data (NaN or infinite voxels; particles with a NaN attribute) opaque in
    /// this linear colour R,G,B (0 to 1 each) instead of transparent (particles: grey).
    #[arg(long, value_name = "R,G,B", value_parser = parse_color)]
    pub nan_color: Option<Vec3>,
    /// How hits are lit: `full` (headlight, lights, shadows, the other knobs) or `eyelight`
    /// (|N·D| times the base colour and nothing else, as Embree's viewer draws).
    #[arg(long, default_value = "full", value_parser = parse_shading)]
    pub shading: Shading,
}

/// Parses a shading mode's name (`full`, `eyelight`).
pub fn parse_shading(text: &str) -> Result<Shading, String> {
    text.parse()
}

/// Parses a colour map's name.
pub fn parse_colormap(text: &str) -> Result<tessera_model::colormap::ColorMap, String> {
    text.parse()
        .map_err(|e: tessera_model::colormap::UnknownColorMap| e.to_string())
}

/// Parses `R,G,B`, each component from 0 to 1.
fn parse_color(text: &str) -> Result<Vec3, BadValue> {
    let c = parse_vec3(text)?;
    if c.min_element() < 0.0 || c.max_element() > 1.0 {
        return Err(bad(format!("`{text}` is not R,G,B with each from 0 to 1")));
    }
    Ok(c)
}

impl QualityArgs {
    /// # Errors
    /// More cutting planes than supported, or knobs out of their bounds
    /// ([`tessera_model::params`]). Cutting planes are given in world coordinates and moved by
    /// `frame`, the scene's.
    pub fn params(&self, frame: &RenderFromWorld) -> Result<RenderParams, ArgError> {
        let cuts: Vec<(Vec3, f32)> = self
            .cuts
            .iter()
            .map(|&(n, d)| (n, frame.plane_distance(n, d)))
            .collect();
        let iso_params = iso_arg::iso_params(&self.iso).map_err(ParamsError::from)?;
        Ok(RenderParamsSpec {
            shadows: !self.no_shadows,
            ao_samples: self.ao,
            crop: self.crop,
            colormap: self.colormap,
            shading: self.shading,
            cuts: CutPlanes::new(&cuts)?,
            spp: self.spp,
            volume: VolumeParams {
                step: self.volume_step,
                iso: iso_params.0,
                iso_looks: iso_params.1,
                transfer: transfer_file::transfer_function(&self.transfer)?,
                time_step: self.time_step,
                missing_color: self.nan_color.map(|c| c.to_array()),
                ..VolumeParams::DEFAULT
            },
            ..RenderParamsSpec::INTERACTIVE
        }
        .build()?)
    }
}

/// How render nodes pack tiles, as a flag (`--compress none|lz4`).
#[derive(clap::ValueEnum, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum CompressArg {
    /// Raw pixels: no CPU spent, as many bytes as pixels.
    #[default]
    None,
    /// Each tile an LZ4 block (or raw where LZ4 does not make it shorter): for links slower
    /// than the render nodes.
    Lz4,
}

impl From<Compression> for CompressArg {
    fn from(compression: Compression) -> Self {
        match compression {
            Compression::None => CompressArg::None,
            Compression::Lz4 => CompressArg::Lz4,
        }
    }
}

impl From<CompressArg> for Compression {
    fn from(arg: CompressArg) -> Self {
        match arg {
            CompressArg::None => Compression::None,
            CompressArg::Lz4 => Compression::Lz4,
        }
    }
}

/// Parses `NX,NY,NZ,D`: a plane's non-zero normal and its offset, all finite.
pub fn parse_plane(text: &str) -> Result<(Vec3, f64), BadValue> {
    let numbers: Vec<&str> = text.split(',').collect();
    let [x, y, z, d] = numbers[..] else {
        return Err(bad(format!("`{text}` is not NX,NY,NZ,D (four numbers)")));
    };
    let mut values = [0f64; 4];
    for (value, word) in values.iter_mut().zip([x, y, z, d]) {
        *value = word
            .trim()
            .parse()
            .ok()
            .filter(|v: &f64| v.is_finite() && v.abs() < f32::MAX as f64)
            .ok_or_else(|| format!("`{word}` in `{text}` is not a finite number"))?;
    }
    let normal = DVec3::new(values[0], values[1], values[2]).as_vec3();
    if normal == Vec3::ZERO {
        return Err(bad(format!(
            "`{text}`: the normal NX,NY,NZ must not be zero"
        )));
    }
    Ok((normal, values[3]))
}

/// Parses `LO,HI`: finite numbers with LO <= HI.
pub fn parse_range(text: &str) -> Result<(f32, f32), BadValue> {
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
        return Err(bad(format!(
            "`{text}` is not a range of finite numbers with LO <= HI"
        )));
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
        assert!(parse_range("1;2").unwrap_err().0.contains("LO,HI"));
        assert!(parse_range("1,nan").is_err());
    }

    #[test]
    fn planes_parse_and_garbage_is_explained() {
        assert_eq!(parse_plane("0,0,-1,2.5").unwrap(), (-Vec3::Z, 2.5));
        assert!(parse_plane("0,0,0,1").unwrap_err().0.contains("zero"));
        assert!(parse_plane("1,2,3").unwrap_err().0.contains("NX,NY,NZ,D"));
        assert!(parse_plane("1,x,3,4").unwrap_err().0.contains("`x`"));
    }

    #[test]
    fn vectors_parse_and_garbage_is_explained() {
        assert_eq!(parse_vec3("1,-2,3.5").unwrap(), Vec3::new(1.0, -2.0, 3.5));
        assert!(parse_vec3("1,2").unwrap_err().0.contains("X,Y,Z"));
        assert!(parse_vec3("1,b,3").unwrap_err().0.contains("`b`"));
        assert!(parse_vec3("1,inf,3").is_err());
    }

    #[test]
    fn a_field_of_view_of_0_or_180_is_refused() {
        // Both used to be accepted and, with the orbit camera, silently ignored.
        for bad in ["0", "180", "-5", "nan", "inf", "wide"] {
            assert!(parse_fov(bad).is_err(), "{bad}");
        }
        assert_eq!(parse_fov("60"), Ok(60.0));
    }

    #[test]
    fn the_orbit_gets_the_field_of_view_of_the_flags() {
        use clap::Parser;
        #[derive(Parser)]
        struct Cli {
            #[command(flatten)]
            scene: SceneArgs,
        }
        let cli = Cli::try_parse_from(["t", "--fov", "30"]).unwrap();
        let mut asked = None;
        cli.scene
            .camera_mode(&RenderFromWorld::IDENTITY, |fov| {
                asked = Some(fov);
                CameraMode::orbit(Vec3::ZERO, 1.0, fov)
            })
            .unwrap();
        assert_eq!(asked, Some(30.0));
        assert!(Cli::try_parse_from(["t", "--fov", "0"]).is_err());
    }

    #[test]
    fn a_world_camera_far_away_is_exact_in_render_coordinates() {
        use clap::Parser;
        #[derive(Parser)]
        struct Cli {
            #[command(flatten)]
            scene: SceneArgs,
        }
        let cli = Cli::try_parse_from([
            "t",
            "--eye",
            "1000000.3,1000000,1000002.7",
            "--target",
            "1000000,1000000,1000000",
        ])
        .unwrap();
        let frame = RenderFromWorld::new(DVec3::splat(1e6));
        let camera = cli
            .scene
            .camera_mode(&frame, |_| unreachable!("a fixed camera"))
            .unwrap()
            .camera_for_frame(0);
        assert_eq!(camera.eye(), Vec3::new(0.3, 0.0, 2.7));
        assert_eq!(camera.target(), Vec3::ZERO);
    }

    #[derive(clap::Parser)]
    struct WallCli {
        #[command(flatten)]
        wall: WallArgs,
    }

    fn wall_cli(args: &[&str]) -> Result<WallCli, clap::Error> {
        use clap::Parser;
        WallCli::try_parse_from(std::iter::once("t").chain(args.iter().copied()))
    }

    #[test]
    fn eye_separation_help_default_and_wall_agree() {
        use clap::CommandFactory;
        // The help said "default 0.065" beside clap's "[default: 0]", and an explicit 0 became
        // 0.065 in the renderer.
        let help = WallCli::command().render_long_help().to_string();
        let flag = help
            .split("--eye-separation")
            .nth(1)
            .expect("the flag is in the help");
        let shown = flag
            .split("[default: ")
            .nth(1)
            .and_then(|d| d.split(']').next());
        assert_eq!(
            shown,
            Some(DEFAULT_EYE_SEPARATION.to_string().as_str()),
            "{help}"
        );
        let stereo = |args: &[&str]| wall_cli(args).unwrap().wall.layout().unwrap().stereo();
        let given = stereo(&["--stereo", "side-by-side"]);
        assert_eq!(given.eye_separation, DEFAULT_EYE_SEPARATION);
        let given = stereo(&["--stereo", "top-bottom", "--eye-separation", "0.1"]);
        assert_eq!(given.eye_separation, 0.1);
        let err = wall_cli(&["--stereo", "displays", "--eye-separation", "0"]);
        let err = err.err().expect("0 is refused").to_string();
        assert!(err.contains("more than 0"), "{err}");
    }

    #[test]
    fn tile_size_is_the_flag_and_tile_its_old_name() {
        use clap::CommandFactory;
        let size = |args: &[&str]| wall_cli(args).unwrap().wall.layout().unwrap().tile_size();
        assert_eq!(size(&["--tile-size", "32"]), 32);
        assert_eq!(size(&["--tile", "16"]), 16);
        assert_eq!(size(&[]), DEFAULT_TILE_SIZE);
        let help = WallCli::command().render_help().to_string();
        assert!(help.contains("--tile-size <TILE_SIZE>"), "{help}");
    }

    #[test]
    fn four_billion_ao_rays_are_refused_naming_the_value() {
        use clap::Parser;
        #[derive(Parser)]
        struct Cli {
            #[command(flatten)]
            quality: QualityArgs,
        }
        let cli = Cli::try_parse_from(["t", "--ao", "4000000000"]).unwrap();
        let err = cli.quality.params(&RenderFromWorld::IDENTITY).unwrap_err();
        let why = std::error::Error::source(&err).unwrap().to_string();
        assert!(
            err.to_string().contains("quality") && why.contains("4000000000"),
            "{why}"
        );
    }
}
