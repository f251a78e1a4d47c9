//! The stiff-case experiment: the user's scene moved far from the origin (to 10⁷), its units
//! changed (10⁻⁶ to 10⁶), and for a volume its values scaled (10⁻³⁰ to 10³⁰), each rendered
//! and compared with the plain picture: the share of pixels that agree (within two levels of
//! 255 on every channel), the largest depth difference over the scene's size, and the pixels
//! hit in one picture only. Rendered in this process, on the wall's whole virtual image, from
//! frame 0 of the orbit `local` starts with (see [`tessera_render::stiff`]).

use super::plot::Series;
use super::{wrote, BenchArgs, Outputs, Plot};
use anyhow::Result;
use serde_json::json;
use std::path::Path;
use tessera_model::params::RenderParams;
use tessera_render::scene::Scene;
use tessera_render::stiff::{
    agreement, cases, picture, transformed, transformed_params, Transform, View,
};

/// One case's figures: the change, and how its picture agrees with the plain one.
struct Case {
    change: Transform,
    pixels: f64,
    /// The largest depth error over the scene's size.
    depth: f64,
    hit_once: usize,
}

pub fn stiff(args: &BenchArgs, out: &Path) -> Result<()> {
    let run = &args.local.run;
    let wall = run.wall.layout()?;
    let scene = crate::args::load_scene(&run.scene)?;
    let params = run.quality.params(&scene.render_from_world)?;
    let size = (wall.width(), wall.height());
    let measured = measure(&scene, params, size);
    write_outputs(&run.scene.scene, size, &measured, out)
}

/// Renders every case of `scene` and prints each one's line as it comes.
fn measure(scene: &Scene, params: RenderParams, size: (u32, u32)) -> Vec<Case> {
    let view = View::of(scene);
    let plain = picture(scene, &view, params, size);
    let cases = cases(scene);
    let bar = indicatif::ProgressBar::new(cases.len() as u64);
    println!(
        "{:>18}  {:>13}  {:>18}  {:>13}",
        "case", "pixels agree", "depth error/size", "hit only once"
    );
    let mut measured = Vec::new();
    for t in cases {
        let Some(changed) = transformed(scene, t) else {
            continue;
        };
        let seen_params = transformed_params(params, t);
        let seen = picture(&changed, &view.transformed(t), seen_params, size);
        let agreed = agreement(&plain, &seen, t);
        let case = Case {
            change: t,
            pixels: agreed.pixels,
            depth: agreed.depth / view.size,
            hit_once: agreed.coverage,
        };
        bar.suspend(|| {
            println!(
                "{:>18}  {:>12.2}%  {:>18.2e}  {:>13}",
                t.to_string(),
                case.pixels * 100.0,
                case.depth,
                case.hit_once
            )
        });
        bar.inc(1);
        measured.push(case);
    }
    bar.finish_and_clear();
    measured
}

/// The CSV, the plot of agreement against each change's factor, and report.json.
fn write_outputs(scene: &str, size: (u32, u32), cases: &[Case], out: &Path) -> Result<()> {
    let mut series: Vec<Series> = ["offset", "extent", "values"]
        .map(|name| Series {
            name: name.into(),
            points: Vec::new(),
        })
        .into();
    for case in cases {
        let (family, factor) = match case.change {
            Transform::Offset(d) => (0, d),
            Transform::Extent(s) => (1, s),
            Transform::Values(s) => (2, s as f64),
        };
        series[family]
            .points
            .push((factor.log10(), case.pixels * 100.0));
    }
    let rows = cases
        .iter()
        .map(|c| format!("{},{},{:e},{}", c.change, c.pixels, c.depth, c.hit_once));
    let records = cases.iter().map(|c| {
        json!({
            "case": c.change.to_string(),
            "pixels_agree": c.pixels,
            "depth_error_over_size": c.depth,
            "pixels_hit_only_once": c.hit_once,
        })
    });
    let outputs = Outputs {
        csv: "stiff.csv",
        header: "case,pixels_agree,depth_error_over_size,pixels_hit_only_once",
        rows: rows.collect(),
        plots: vec![Plot {
            file: "stiff.svg",
            title: "pixels that agree with the plain picture",
            x_label: "log10 of the offset or factor",
            y_label: "% of pixels within 2 levels",
            series: series
                .into_iter()
                .filter(|s| !s.points.is_empty())
                .collect(),
        }],
        report: json!({
            "experiment": "stiff",
            "scene": scene,
            "image": [size.0, size.1],
            "cases": records.collect::<Vec<_>>(),
        }),
    };
    wrote(&outputs.write(out)?);
    Ok(())
}
