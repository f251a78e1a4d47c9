//! The error-vs-time experiment: for each quality knob, image error against a converged
//! reference, against the time a frame takes. Rendered in this process (the render nodes'
//! code, on all of this machine's cores), so the times are what one node spends per frame.
//!
//! Knobs: ambient-occlusion rays per hit (`ao`), samples per pixel (`spp`), progressive
//! passes (`passes`: pass k traces one new jittered sample per pixel and the display averages
//! all passes so far, in linear light, so error falls with the cumulative time), and for a
//! volume scene the ray-marching step (`step`, in units of the smallest voxel spacing, against
//! a reference at 1/32 of it).

use super::charts::{Chart, Labelled};
use super::plot::Series;
use super::{wrote, BenchArgs, Outputs};
use anyhow::{Context, Result};
use serde_json::json;
use std::path::Path;
use std::time::Instant;
use tessera_model::camera::Camera;
use tessera_model::image::RgbImage;
use tessera_model::params::{RenderParams, RenderParamsSpec};
use tessera_model::wall::{TileGrid, WallLayout};
use tessera_render::render_wall;
use tessera_render::scene::Scene;
use tessera_render::{FrameView, PreparedScene};

const AO_STEPS: [u32; 7] = [1, 2, 4, 8, 16, 32, 64];
const SPP_STEPS: [u32; 5] = [1, 2, 4, 8, 16];
const PASSES: u32 = 16;
/// Volume steps, in smallest voxel spacings; the reference marches at 1/32.
const STEP_FRACTIONS: [f64; 6] = [2.0, 1.0, 0.5, 0.25, 0.125, 0.0625];
const REFERENCE_STEP_FRACTION: f64 = 1.0 / 32.0;
/// Frame key of the references' samples (the camera is frame 0's either way).
const REFERENCE_KEY: u64 = 0x5eed_0000_0000;

/// Root-mean-square difference over the screens' pixels (bezels excluded), channels in [0, 1].
pub fn rmse(wall: &WallLayout, a: &RgbImage, b: &RgbImage) -> f64 {
    let (mut sum, mut count) = (0.0f64, 0u64);
    for s in wall.screens() {
        for y in s.y..s.y + s.height {
            let row =
                ((y * a.width + s.x) * 3) as usize..((y * a.width + s.x + s.width) * 3) as usize;
            for (p, q) in a.rgb[row.clone()].iter().zip(&b.rgb[row]) {
                let d = (*p as f64 - *q as f64) / 255.0;
                sum += d * d;
                count += 1;
            }
        }
    }
    (sum / count.max(1) as f64).sqrt()
}

/// Peak signal-to-noise ratio in dB for channels in [0, 1] (infinite for identical images).
pub fn psnr(rmse: f64) -> f64 {
    if rmse > 0.0 {
        -20.0 * rmse.log10()
    } else {
        f64::INFINITY
    }
}

struct Point {
    knob: &'static str,
    value: f64,
    ms: f64,
    rmse: f64,
}

pub fn error_vs_time(args: &BenchArgs, out: &Path) -> Result<()> {
    let run = &args.local.run;
    let wall = run.wall.layout()?;
    let scene = crate::args::load_scene(&run.scene)?;
    let settings = Settings::check(args, &scene)?;
    let renders =
        2 + AO_STEPS.len() + SPP_STEPS.len() + PASSES as usize + settings.step_params.len();
    let renderer = Renderer {
        prepared: PreparedScene::new(&scene),
        grid: TileGrid::new(wall.clone()),
        wall: &wall,
        camera: settings.camera,
        bar: indicatif::ProgressBar::new(renders as u64).with_style(
            indicatif::ProgressStyle::with_template(
                "{spinner} {msg} {pos}/{len} renders {elapsed_precise}",
            )
            .expect("valid template"),
        ),
    };
    let spacing = settings.spacing;
    let points = renderer.measure(args, settings);
    renderer.bar.finish_and_clear();
    write_outputs(args, out, &wall, spacing, &points)
}

/// Every render's settings, all checked before the first (long) render.
struct Settings {
    ao_reference_params: RenderParams,
    spp_reference_params: RenderParams,
    ao_params: Vec<RenderParams>,
    spp_params: Vec<RenderParams>,
    pass_params: Vec<RenderParams>,
    camera: Camera,
    /// The volume's smallest voxel spacing (None: the scene has no volume).
    spacing: Option<f64>,
    /// A setting per step of [`STEP_FRACTIONS`], then the reference's (empty without a volume).
    step_params: Vec<RenderParams>,
}

impl Settings {
    /// The settings `args` give for `scene`, each checked.
    fn check(args: &BenchArgs, scene: &Scene) -> Result<Settings> {
        let run = &args.local.run;
        let base = run.quality.params(&scene.render_from_world)?.spec();
        let knobs = |change: &dyn Fn(&mut RenderParamsSpec)| -> Result<RenderParams> {
            let mut spec = base;
            change(&mut spec);
            Ok(spec.build()?)
        };
        let ao_reference_params =
            knobs(&|s| s.ao_samples = args.reference_ao).context("--reference-ao")?;
        let spp_reference_params =
            knobs(&|s| s.spp = args.reference_spp).context("--reference-spp")?;
        let ao_params = AO_STEPS
            .iter()
            .map(|&ao| knobs(&|s| s.ao_samples = ao))
            .collect::<Result<Vec<_>>>()
            .context("the ambient-occlusion steps with these flags")?;
        let spp_params = SPP_STEPS
            .iter()
            .map(|&spp| knobs(&|s| s.spp = spp))
            .collect::<Result<Vec<_>>>()
            .context("the samples-per-pixel steps with these flags")?;
        let pass_params = (0..PASSES)
            .map(|pass| {
                knobs(&|s| {
                    s.spp = 1;
                    s.first_sample = pass;
                })
            })
            .collect::<Result<Vec<_>>>()?;
        let camera = run
            .scene
            .camera_mode(&scene.render_from_world, |fov| scene.orbit(fov))?
            .camera_for_frame(0);
        let spacing = scene
            .volume
            .as_ref()
            .map(|v| v.spacing().into_iter().fold(f64::INFINITY, f64::min));
        // The volume's step knob: steps in world units, checked like the others.
        let step_params = match spacing {
            Some(unit) => STEP_FRACTIONS
                .iter()
                .chain([&REFERENCE_STEP_FRACTION])
                .map(|f| knobs(&|s| s.volume.step = (unit * f) as f32))
                .collect::<Result<Vec<_>>>()?,
            None => Vec::new(),
        };
        Ok(Settings {
            ao_reference_params,
            spp_reference_params,
            ao_params,
            spp_params,
            pass_params,
            camera,
            spacing,
            step_params,
        })
    }
}

/// Renders and times frames of the wall in this process, counting them on a progress bar.
struct Renderer<'a> {
    prepared: PreparedScene,
    grid: TileGrid,
    wall: &'a WallLayout,
    camera: Camera,
    bar: indicatif::ProgressBar,
}

impl Renderer<'_> {
    /// The image under frame key `key`, and the milliseconds it took.
    fn render_keyed(&self, key: u64, params: RenderParams, what: String) -> (RgbImage, f64) {
        self.bar.set_message(what);
        let view = FrameView::for_wall(key, &self.camera, params, self.wall);
        let t0 = Instant::now();
        let image = render_wall(&self.prepared, &view, &self.grid);
        let ms = t0.elapsed().as_secs_f64() * 1000.0;
        self.bar.inc(1);
        (image, ms)
    }

    /// A measured image: frame 0's samples.
    fn render(&self, params: RenderParams, what: String) -> (RgbImage, f64) {
        self.render_keyed(0, params, what)
    }

    /// A reference image. Its samples are drawn under another frame key: sharing the measured
    /// images' first samples would make their error look smaller than it is.
    fn reference(&self, params: RenderParams, what: String) -> RgbImage {
        self.render_keyed(REFERENCE_KEY, params, what).0
    }

    /// Every knob's points, in the order of the table: ao, spp, passes, step.
    fn measure(&self, args: &BenchArgs, s: Settings) -> Vec<Point> {
        let ao_reference = self.reference(
            s.ao_reference_params,
            format!("ao reference ({} rays)", args.reference_ao),
        );
        let spp_reference = self.reference(
            s.spp_reference_params,
            format!("spp reference ({} samples)", args.reference_spp),
        );
        let ao = AO_STEPS.map(f64::from);
        let mut points = self.knob("ao", &ao, s.ao_params, &ao_reference);
        let spp = SPP_STEPS.map(f64::from);
        points.extend(self.knob("spp", &spp, s.spp_params, &spp_reference));
        points.extend(self.passes(s.pass_params, &spp_reference));
        if let Some((reference_params, steps)) = s.step_params.split_last() {
            let step_reference = self.render(*reference_params, "step reference".into()).0;
            points.extend(self.knob("step", &STEP_FRACTIONS, steps.to_vec(), &step_reference));
        }
        points
    }

    /// A point for each of a knob's `values`, rendered with its `params`.
    fn knob(
        &self,
        knob: &'static str,
        values: &[f64],
        params: Vec<RenderParams>,
        reference: &RgbImage,
    ) -> Vec<Point> {
        values
            .iter()
            .zip(params)
            .map(|(&value, params)| {
                let (image, ms) = self.render(params, format!("{knob} {value}"));
                Point {
                    knob,
                    value,
                    ms,
                    rmse: rmse(self.wall, &image, reference),
                }
            })
            .collect()
    }

    /// Progressive passes: what a display shows after each, against the time of all so far.
    fn passes(&self, params: Vec<RenderParams>, reference: &RgbImage) -> Vec<Point> {
        // A linear-light running sum of the passes' images, as a display would blend.
        let mut linear = vec![0f64; (self.wall.width() * self.wall.height() * 3) as usize];
        let mut total_ms = 0.0;
        let mut points = Vec::new();
        for (pass, params) in (0..PASSES).zip(params) {
            let (image, ms) = self.render(params, format!("pass {}", pass + 1));
            total_ms += ms;
            for (acc, &v) in linear.iter_mut().zip(&image.rgb) {
                let c = v as f64 / 255.0;
                *acc += c * c;
            }
            let shown = RgbImage {
                width: image.width,
                height: image.height,
                rgb: linear
                    .iter()
                    .map(|&s| ((s / (pass + 1) as f64).sqrt() * 255.0 + 0.5) as u8)
                    .collect(),
            };
            points.push(Point {
                knob: "passes",
                value: (pass + 1) as f64,
                ms: total_ms,
                rmse: rmse(self.wall, &shown, reference),
            });
        }
        points
    }
}

/// The CSV, the plot and report.json, then the table.
fn write_outputs(
    args: &BenchArgs,
    out: &Path,
    wall: &WallLayout,
    spacing: Option<f64>,
    points: &[Point],
) -> Result<()> {
    let rows: Vec<String> = points
        .iter()
        .map(|p| {
            format!(
                "{},{},{:.3},{:.6},{:.3}",
                p.knob,
                p.value,
                p.ms,
                p.rmse,
                psnr(p.rmse)
            )
        })
        .collect();
    let written = Outputs {
        csv: "error-vs-time.csv",
        header: "knob,value,time_ms,rmse,psnr_db",
        rows,
        plots: Vec::new(),
        report: json!({
            "experiment": "error-vs-time",
            "wall": { "width": wall.width(), "height": wall.height() },
            "reference": {
                "ao": args.reference_ao,
                "spp": args.reference_spp,
                "step_spacings": spacing.map(|_| REFERENCE_STEP_FRACTION),
            },
            "threads": std::thread::available_parallelism().map_or(1, |n| n.get()),
            "points": points.iter().map(|p| json!({
                "knob": p.knob, "value": p.value, "time_ms": p.ms, "rmse": p.rmse,
                "psnr_db": if p.rmse > 0.0 { json!(psnr(p.rmse)) } else { json!(null) },
            })).collect::<Vec<_>>(),
        }),
    }
    .write_with(out, &[("error-vs-time.svg", chart(points))])?;
    print_table(points);
    wrote(&written);
    Ok(())
}

/// A line of labelled points for each knob measured, in the order of the table, and the
/// 1/√N guide through the first samples-per-pixel point (the knob that is Monte Carlo's N).
fn chart(points: &[Point]) -> Chart {
    let knobs = ["ao", "spp", "passes", "step"];
    let measured = knobs
        .iter()
        .filter(|k| points.iter().any(|p| p.knob == **k));
    let series = measured.map(|&k| {
        let of_knob = || points.iter().filter(move |p| p.knob == k);
        Labelled {
            series: Series {
                name: knob_name(k).into(),
                points: of_knob().map(|p| (p.ms, p.rmse)).collect(),
            },
            labels: of_knob().map(|p| point_label(k, p.value)).collect(),
        }
    });
    let first_spp = points.iter().find(|p| p.knob == "spp");
    Chart::Error {
        series: series.collect(),
        guide: first_spp.map(|p| (p.ms, p.rmse)),
    }
}

/// What a knob's line is called in the legend.
fn knob_name(knob: &str) -> &str {
    match knob {
        "ao" => "AO rays per hit (ao)",
        "spp" => "samples per pixel (spp)",
        "passes" => "progressive passes",
        "step" => "volume step (voxel spacings)",
        other => other,
    }
}

/// A point's label: the knob's setting there.
fn point_label(knob: &str, value: f64) -> String {
    match knob {
        "ao" => format!("AO {value}"),
        "spp" => format!("{value} spp"),
        "passes" if value == 1.0 => "1 pass".into(),
        "passes" => format!("{value} passes"),
        "step" => format!("step {value}"),
        other => format!("{other} {value}"),
    }
}

/// A line a point: knob, value, time, RMSE and PSNR.
fn print_table(points: &[Point]) {
    println!(
        "{:<7} {:>6} {:>10} {:>9} {:>9}",
        "knob", "value", "ms/frame", "RMSE", "PSNR dB"
    );
    for p in points {
        println!(
            "{:<7} {:>6} {:>10.1} {:>9.5} {:>9.2}",
            p.knob,
            p.value,
            p.ms,
            p.rmse,
            psnr(p.rmse)
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_model::wall::WallSpec;

    #[test]
    fn rmse_ignores_bezels_and_psnr_follows() {
        let wall = WallSpec::grid(2, 1, 2, 1).bezel(2).build().unwrap();
        let black = RgbImage::black(wall.width(), wall.height());
        let mut other = black.clone();
        // A bezel pixel differs: no error. Then one channel of one screen pixel by 255.
        other.rgb[2 * 3] = 255;
        assert_eq!(rmse(&wall, &black, &other), 0.0);
        other.rgb[0] = 255;
        let e = rmse(&wall, &black, &other);
        assert!((e - (1.0f64 / 12.0).sqrt()).abs() < 1e-12, "{e}");
        assert!((psnr(0.1) - 20.0).abs() < 1e-9);
        assert!(psnr(0.0).is_infinite());
    }
}
