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
use tessera_render::stiff::{
    agreement, cases, picture, transformed, transformed_params, Transform, View,
};

pub fn stiff(args: &BenchArgs, out: &Path) -> Result<()> {
    let run = &args.local.run;
    let wall = run.wall.layout()?;
    let scene = crate::args::load_scene(&run.scene)?;
    let params = run.quality.params(&scene.render_from_world)?;
    let size = (wall.width(), wall.height());
    let view = View::of(&scene);
    let plain = picture(&scene, &view, params, size);
    let cases = cases(&scene);
    let bar = indicatif::ProgressBar::new(cases.len() as u64);
    println!(
        "{:>18}  {:>13}  {:>18}  {:>13}",
        "case", "pixels agree", "depth error/size", "hit only once"
    );
    let (mut rows, mut records) = (Vec::new(), Vec::new());
    let mut series: Vec<Series> = ["offset", "extent", "values"]
        .map(|name| Series {
            name: name.into(),
            points: Vec::new(),
        })
        .into();
    for t in cases {
        let Some(changed) = transformed(&scene, t) else {
            continue;
        };
        let seen = picture(
            &changed,
            &view.transformed(t),
            transformed_params(params, t),
            size,
        );
        let agreed = agreement(&plain, &seen, t);
        let depth = agreed.depth / view.size;
        bar.suspend(|| {
            println!(
                "{:>18}  {:>12.2}%  {:>18.2e}  {:>13}",
                t.to_string(),
                agreed.pixels * 100.0,
                depth,
                agreed.coverage
            )
        });
        bar.inc(1);
        let (family, factor) = match t {
            Transform::Offset(d) => (0, d),
            Transform::Extent(s) => (1, s),
            Transform::Values(s) => (2, s as f64),
        };
        series[family]
            .points
            .push((factor.log10(), agreed.pixels * 100.0));
        rows.push(format!(
            "{t},{},{depth:e},{}",
            agreed.pixels, agreed.coverage
        ));
        records.push(json!({
            "case": t.to_string(),
            "pixels_agree": agreed.pixels,
            "depth_error_over_size": depth,
            "pixels_hit_only_once": agreed.coverage,
        }));
    }
    bar.finish_and_clear();
    let outputs = Outputs {
        csv: "stiff.csv",
        header: "case,pixels_agree,depth_error_over_size,pixels_hit_only_once",
        rows,
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
            "scene": run.scene.scene,
            "image": [size.0, size.1],
            "cases": records,
        }),
    };
    wrote(&outputs.write(out)?);
    Ok(())
}
