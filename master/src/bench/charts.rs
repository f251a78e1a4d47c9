//! The charts that a plain line plot reads badly: error against time on log-log axes with each
//! point named and a 1/√N guide, scaling beside its ideal with each point's efficiency, and
//! latency with input latency over it and skew on an axis of its own.

use super::plot::{
    areas, extent, legend, linear_axis, log_axis, number, padded, Area, Entry, Line, Plotted,
    Series, Ticked, COLORS, SIZE,
};
use anyhow::Result;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use std::path::Path;

/// A series whose points each carry a label ("4 spp", "AO 16").
pub struct Labelled {
    pub series: Series,
    pub labels: Vec<String>,
}

/// A chart of an experiment, drawn to its own file.
pub enum Chart {
    /// RMSE against ms per frame for each knob, on log-log axes, and the 1/√N guide through
    /// `guide` (the first point of the samples-per-pixel line).
    Error {
        series: Vec<Labelled>,
        guide: Option<(f64, f64)>,
    },
    /// Frames/s against render nodes, a series a thread count.
    Scaling(Vec<Series>),
    /// Per-frame latency, each input's latency at its frame, and per-frame skew.
    Latency {
        latency: Vec<(f64, f64)>,
        input: Vec<(f64, f64)>,
        skew: Vec<(f64, f64)>,
    },
}

impl Chart {
    /// Draws the chart into the SVG file `path`.
    pub fn draw(&self, path: &Path) -> Result<()> {
        match self {
            Chart::Error { series, guide } => error_chart(path, series, *guide),
            Chart::Scaling(series) => scaling_chart(path, series),
            Chart::Latency {
                latency,
                input,
                skew,
            } => latency_chart(path, latency, input, skew),
        }
    }
}

const FONT: (&str, u32) = ("sans-serif", 13);

/// Where a label's text starts, in pixels from its point.
const LABEL_OFFSET: (i32, i32) = (6, -16);

/// A label's box in pixels, to keep labels off each other: a label that would cover one
/// already drawn is left out (16 progressive passes crowd their last decade).
fn overlaps(placed: &[(i32, i32, i32)], at: (i32, i32), width: i32) -> bool {
    placed
        .iter()
        .any(|&(x, y, w)| at.0 < x + w && x < at.0 + width && (at.1 - y).abs() < 14)
}

/// RMSE against time, log-log: each knob a line of labelled points, and the 1/√N slope that
/// Monte Carlo error follows, dashed through `guide`.
fn error_chart(path: &Path, series: &[Labelled], guide: Option<(f64, f64)>) -> Result<()> {
    let points = || series.iter().flat_map(|s| s.series.points.iter());
    let (x0, x1) = extent(points().map(|p| p.0).filter(|&x| x > 0.0)).unwrap_or((1.0, 10.0));
    let (y0, y1) = extent(points().map(|p| p.1).filter(|&y| y > 0.0)).unwrap_or((0.01, 0.1));
    let (x0, x1) = (x0 / 1.3, x1 * 1.6);
    let (y0, y1) = (y0 / 1.4, y1 * 1.4);
    let root = SVGBackend::new(path, SIZE).into_drawing_area();
    let title = "image error against render time per frame (log-log)";
    let (plot, side) = areas(&root, title, path)?;
    let mut chart = ChartBuilder::on(&plot)
        .margin(16)
        .x_label_area_size(44)
        .y_label_area_size(70)
        .build_cartesian_2d(log_axis(x0, x1), log_axis(y0, y1))
        .at(path)?;
    chart
        .configure_mesh()
        .x_desc("ms per frame (log scale)")
        .y_desc("RMSE (log scale)")
        .x_label_formatter(&|v| number(*v))
        .y_label_formatter(&|v| number(*v))
        .draw()
        .at(path)?;
    let mut entries = Vec::new();
    let mut placed = Vec::new();
    // Points that a log axis cannot place (an error of 0) are left out of their line.
    for (i, s) in series.iter().enumerate() {
        let color = COLORS[i % COLORS.len()];
        let kept: Vec<(f64, f64)> = s
            .series
            .points
            .iter()
            .copied()
            .filter(|p| p.0 > 0.0 && p.1 > 0.0)
            .collect();
        chart
            .draw_series(LineSeries::new(kept.iter().copied(), color.stroke_width(2)))
            .at(path)?;
        chart
            .draw_series(kept.iter().map(|&p| Circle::new(p, 4, color.filled())))
            .at(path)?;
        for (&p, label) in s.series.points.iter().zip(&s.labels) {
            if !(p.0 > 0.0 && p.1 > 0.0) {
                continue;
            }
            let at = chart.backend_coord(&p);
            let at = (at.0 + LABEL_OFFSET.0, at.1 + LABEL_OFFSET.1);
            let width = 7 * label.chars().count() as i32;
            if overlaps(&placed, at, width) {
                continue;
            }
            placed.push((at.0, at.1, width));
            let text = Text::new(label.clone(), LABEL_OFFSET, FONT.into_font().color(&color));
            chart.draw_series([EmptyElement::at(p) + text]).at(path)?;
        }
        entries.push(Entry {
            name: s.series.name.clone(),
            color,
            line: Line::Solid,
            marker: true,
        });
    }
    if let Some(through) = guide.filter(|p| p.0 > 0.0 && p.1 > 0.0) {
        entries.push(root_n_guide(
            &mut chart,
            through,
            ((x0, x1), (y0, y1)),
            path,
        )?);
    }
    legend(&side, &entries, &[], path)?;
    root.present().at(path)?;
    Ok(())
}

/// A chart on log-log axes.
type LogLog<'a, 'b> =
    ChartContext<'a, SVGBackend<'b>, Cartesian2d<Ticked<LogCoord<f64>>, Ticked<LogCoord<f64>>>>;

/// The dashed line error = ty·√(tx/x) through `(tx, ty)`, kept inside the axes' ranges, and
/// its legend entry.
fn root_n_guide(
    chart: &mut LogLog,
    (tx, ty): (f64, f64),
    ((x0, x1), (y0, y1)): ((f64, f64), (f64, f64)),
    path: &Path,
) -> Result<Entry> {
    let lo = x0.max(tx * (ty / y1).powi(2));
    let hi = x1.min(tx * (ty / y0).powi(2));
    let guide = [lo, hi].map(|x| (x, ty * (tx / x).sqrt()));
    let style = BLACK.mix(0.6).stroke_width(1);
    chart
        .draw_series(DashedLineSeries::new(guide, 8, 5, style))
        .at(path)?;
    Ok(Entry {
        name: "1/√N (time ∝ samples N)".into(),
        color: RGBColor(90, 90, 90),
        line: Line::Dashed,
        marker: false,
    })
}

/// Each series' points in node order, whatever order --nodes gave: the ideal starts from the
/// fewest nodes.
fn in_node_order(series: &[Series]) -> Vec<Series> {
    series
        .iter()
        .map(|s| {
            let mut points = s.points.clone();
            points.sort_by(|a, b| a.0.total_cmp(&b.0));
            Series {
                name: s.name.clone(),
                points,
            }
        })
        .collect()
}

/// Frames/s against render nodes: each thread count's measured line, its ideal (linear
/// speedup from its fewest nodes, dashed) and each point's efficiency (speedup ÷ nodes).
fn scaling_chart(path: &Path, series: &[Series]) -> Result<()> {
    let sorted = in_node_order(series);
    let series = &sorted[..];
    let ideal = |s: &Series| -> Vec<(f64, f64)> {
        let Some(&(n0, f0)) = s.points.first() else {
            return Vec::new();
        };
        s.points.iter().map(|&(n, _)| (n, f0 * n / n0)).collect()
    };
    let all = || {
        series
            .iter()
            .flat_map(|s| s.points.iter().copied().chain(ideal(s)))
    };
    let (x0, x1) = extent(all().map(|p| p.0)).unwrap_or((1.0, 2.0));
    let (x0, x1) = padded(x0, x1, 0.06);
    let y1 = extent(all().map(|p| p.1)).map_or(1.0, |e| e.1.max(1e-9) * 1.15);
    let root = SVGBackend::new(path, SIZE).into_drawing_area();
    let (plot, side) = areas(&root, "frames/s against render nodes", path)?;
    let mut chart = ChartBuilder::on(&plot)
        .margin(16)
        .x_label_area_size(44)
        .y_label_area_size(70)
        .build_cartesian_2d(linear_axis(x0, x1, true), linear_axis(0.0, y1, false))
        .at(path)?;
    chart
        .configure_mesh()
        .x_desc("render nodes")
        .y_desc("frames/s")
        .x_label_formatter(&|v| number(*v))
        .y_label_formatter(&|v| number(*v))
        .draw()
        .at(path)?;
    let mut entries = Vec::new();
    for (i, s) in series.iter().enumerate() {
        let color = COLORS[i % COLORS.len()];
        let ideal = ideal(s);
        let style = color.mix(0.7).stroke_width(2);
        chart
            .draw_series(DashedLineSeries::new(ideal.iter().copied(), 8, 5, style))
            .at(path)?;
        chart
            .draw_series(LineSeries::new(
                s.points.iter().copied(),
                color.stroke_width(2),
            ))
            .at(path)?;
        chart
            .draw_series(s.points.iter().map(|&p| Circle::new(p, 4, color.filled())))
            .at(path)?;
        let labels = s.points.iter().zip(&ideal).map(|(&p, &(_, best))| {
            let share = if best > 0.0 { 100.0 * p.1 / best } else { 0.0 };
            let font = FONT.into_font().color(&color);
            EmptyElement::at(p) + Text::new(format!("{share:.0} %"), (6, 4), font)
        });
        chart.draw_series(labels).at(path)?;
        entries.push(Entry {
            name: s.name.clone(),
            color,
            line: Line::Solid,
            marker: true,
        });
        entries.push(Entry {
            name: format!("ideal: linear from {} node(s)", number(ideal[0].0)),
            color,
            line: Line::Dashed,
            marker: false,
        });
    }
    let notes = [
        "% at each point: efficiency,",
        "speedup ÷ nodes (100 % = ideal)",
    ];
    legend(&side, &entries, &notes, path)?;
    root.present().at(path)?;
    Ok(())
}

/// A chart of frames (`x`) against 0..`ms` milliseconds, described by `desc` (y, then x: none
/// for the upper panel, which shares the lower one's).
type Panel<'a, 'b> =
    ChartContext<'a, SVGBackend<'b>, Cartesian2d<Ticked<RangedCoordf64>, Ticked<RangedCoordf64>>>;

fn panel<'a, 'b>(
    area: &'a Area<'b>,
    (x0, x1): (f64, f64),
    ms: f64,
    (y_desc, x_desc): (&str, &str),
    path: &Path,
) -> Result<Panel<'a, 'b>> {
    let ms = if ms > 0.0 { ms } else { 1.0 };
    let mut chart = ChartBuilder::on(area)
        .margin(12)
        .x_label_area_size(if x_desc.is_empty() { 24 } else { 40 })
        .y_label_area_size(70)
        .build_cartesian_2d(linear_axis(x0, x1, true), linear_axis(0.0, ms, false))
        .at(path)?;
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .x_label_formatter(&|v| number(*v))
        .y_label_formatter(&|v| number(*v))
        .draw()
        .at(path)?;
    Ok(chart)
}

/// Latency of each frame and of each input (at its frame) over the top panel, skew on its
/// own axis below: skew is a fraction of a millisecond where latency is tens.
fn latency_chart(
    path: &Path,
    latency: &[(f64, f64)],
    input: &[(f64, f64)],
    skew: &[(f64, f64)],
) -> Result<()> {
    let root = SVGBackend::new(path, SIZE).into_drawing_area();
    let title = "camera change → present on every display, and present skew";
    let (plot, side) = areas(&root, title, path)?;
    let frames = latency.iter().chain(input).chain(skew).map(|p| p.0);
    let (x0, x1) = extent(frames).unwrap_or((0.0, 1.0));
    let (x0, x1) = padded(x0, x1, 0.02);
    let (top, bottom) = plot.split_vertically(SIZE.1 * 58 / 100);
    let ms_top = extent(latency.iter().chain(input).map(|p| p.1)).map_or(1.0, |e| e.1 * 1.1);
    let ms_bottom = extent(skew.iter().map(|p| p.1)).map_or(1.0, |e| e.1 * 1.15);
    let (lat, inp, sk) = (COLORS[0], COLORS[1], COLORS[2]);
    let mut upper = panel(&top, (x0, x1), ms_top, ("latency (ms)", ""), path)?;
    upper
        .draw_series(LineSeries::new(
            latency.iter().copied(),
            lat.stroke_width(2),
        ))
        .at(path)?;
    upper
        .draw_series(input.iter().map(|&p| Circle::new(p, 3, inp.filled())))
        .at(path)?;
    let mut lower = panel(&bottom, (x0, x1), ms_bottom, ("skew (ms)", "frame"), path)?;
    lower
        .draw_series(LineSeries::new(skew.iter().copied(), sk.stroke_width(2)))
        .at(path)?;
    let entry = |name: String, color, line| Entry {
        name,
        color,
        line,
        marker: line == Line::Without,
    };
    let input_name = match input.len() {
        0 => "input → presented (none)".to_string(),
        n => format!("input → presented ({n})"),
    };
    let entries = [
        entry("frame start → presented".into(), lat, Line::Solid),
        entry(input_name, inp, Line::Without),
        entry("skew, lower panel".into(), sk, Line::Solid),
    ];
    legend(
        &side,
        &entries,
        &["upper: latency, ms", "lower: skew, ms"],
        path,
    )?;
    root.present().at(path)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::super::plot::read;
    use super::*;

    /// Draws `chart` and returns its SVG (kept in $TESSERA_KEEP_PLOTS/`name` if that is set).
    fn drawn(chart: &Chart, name: &str) -> String {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(name);
        chart.draw(&path).unwrap();
        if let Ok(keep) = std::env::var("TESSERA_KEEP_PLOTS") {
            std::fs::copy(&path, Path::new(&keep).join(name)).unwrap();
        }
        std::fs::read_to_string(&path).unwrap()
    }

    fn labelled(name: &str, points: Vec<(f64, f64)>, label: fn(f64) -> String) -> Labelled {
        Labelled {
            labels: (0..points.len()).map(|k| label((1 << k) as f64)).collect(),
            series: Series {
                name: name.into(),
                points,
            },
        }
    }

    fn error_chart_of_two_knobs() -> Chart {
        let spp: Vec<(f64, f64)> = (0..5)
            .map(|k| (12.0 * (1 << k) as f64, 0.08 / ((1 << k) as f64).sqrt()))
            .collect();
        let ao: Vec<(f64, f64)> = (0..7)
            .map(|k| (9.0 + 3.0 * (1 << k) as f64, 0.05 / (1.0 + k as f64)))
            .collect();
        Chart::Error {
            guide: Some(spp[0]),
            series: vec![
                labelled("AO rays per hit (ao)", ao, |v| format!("AO {v}")),
                labelled("samples per pixel (spp)", spp, |v| format!("{v} spp")),
            ],
        }
    }

    #[test]
    fn error_vs_time_is_log_log_with_each_point_labelled_and_a_root_n_guide() {
        let svg = drawn(&error_chart_of_two_knobs(), "error-vs-time.svg");
        let ticks = read::x_ticks(&svg);
        assert!(ticks.len() >= 3, "{ticks:?}");
        // A log axis: equal ratios of value sit equal distances apart.
        let per_decade: Vec<f64> = ticks
            .windows(2)
            .map(|w| (w[1].0 - w[0].0) / (w[1].1 / w[0].1).log10())
            .collect();
        for d in &per_decade {
            assert!((d / per_decade[0] - 1.0).abs() < 0.03, "{ticks:?}");
        }
        let texts: Vec<String> = read::texts(&svg).into_iter().map(|t| t.2).collect();
        for label in [
            "1 spp",
            "16 spp",
            "AO 1",
            "AO 64",
            "1/√N (time ∝ samples N)",
        ] {
            assert!(
                texts.iter().any(|t| t == label),
                "{label} missing: {texts:?}"
            );
        }
        assert!(texts.iter().any(|t| t.contains("log scale")), "{texts:?}");
    }

    #[test]
    fn scaling_ticks_whole_node_counts_with_the_ideal_and_each_efficiency() {
        let chart = Chart::Scaling(vec![Series {
            name: "1 thread(s) per node".into(),
            points: vec![(1.0, 10.0), (2.0, 18.0), (4.0, 30.0)],
        }]);
        let svg = drawn(&chart, "scaling.svg");
        let ticks: Vec<f64> = read::x_ticks(&svg).iter().map(|t| t.1).collect();
        assert_eq!(ticks, [1.0, 2.0, 3.0, 4.0]);
        let texts: Vec<String> = read::texts(&svg).into_iter().map(|t| t.2).collect();
        for label in ["100 %", "90 %", "75 %", "ideal: linear from 1 node(s)"] {
            assert!(
                texts.iter().any(|t| t == label),
                "{label} missing: {texts:?}"
            );
        }
    }

    #[test]
    fn latency_plots_input_latency_and_skew_on_its_own_axis_beside_the_legend() {
        let frames = 0..40u32;
        let chart = Chart::Latency {
            latency: frames
                .clone()
                .map(|f| (f as f64, 20.0 + (f % 7) as f64))
                .collect(),
            input: frames
                .clone()
                .step_by(4)
                .map(|f| (f as f64, 31.0))
                .collect(),
            skew: frames
                .map(|f| (f as f64, 0.1 + 0.02 * (f % 5) as f64))
                .collect(),
        };
        let svg = drawn(&chart, "latency.svg");
        let texts = read::texts(&svg);
        let has = |label: &str| texts.iter().any(|t| t.2 == label);
        assert!(has("input → presented (10)"), "{texts:?}");
        assert!(has("latency (ms)") && has("skew (ms)"), "{texts:?}");
        // Skew's own axis reads tenths of a millisecond, latency's tens.
        assert!(has("0.1") && has("30"), "{texts:?}");
        let legend = texts.iter().find(|t| t.2.starts_with("input")).unwrap();
        let rightmost_tick = read::x_ticks(&svg).last().unwrap().0;
        assert!(legend.0 > rightmost_tick + 20.0, "{legend:?}");
    }
}
