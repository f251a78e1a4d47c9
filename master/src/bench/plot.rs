//! SVG line plots of an experiment's figures (plotters, SVG backend), and what the special
//! charts of [`super::charts`] share: tick choice, number labels and a legend kept in its own
//! column beside the plot, so it never hides a point.

use anyhow::{anyhow, Result};
use plotters::coord::ranged1d::{DefaultFormatting, KeyPointHint};
use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::ops::Range;
use std::path::Path;

/// One named line of (x, y) points.
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
}

pub(super) const COLORS: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(148, 103, 189),
    RGBColor(255, 127, 14),
    RGBColor(23, 190, 207),
];

/// Size of every plot, in SVG pixels.
pub(super) const SIZE: (u32, u32) = (1000, 560);
/// Width of the legend column at the right of every plot.
const LEGEND_WIDTH: u32 = 240;

/// The drawing area of an SVG file.
pub(super) type Area<'a> = DrawingArea<SVGBackend<'a>, Shift>;

/// A plotters result as an anyhow one naming the file.
pub(super) trait Plotted<T> {
    fn at(self, path: &Path) -> Result<T>;
}

impl<T, E: std::fmt::Display> Plotted<T> for std::result::Result<T, E> {
    fn at(self, path: &Path) -> Result<T> {
        self.map_err(|e| anyhow!("plotting {}: {e}", path.display()))
    }
}

/// The plot's area (white, captioned) and the legend column beside it.
pub(super) fn areas<'a>(root: &Area<'a>, title: &str, path: &Path) -> Result<(Area<'a>, Area<'a>)> {
    root.fill(&WHITE).at(path)?;
    let titled = root.titled(title, ("sans-serif", 22)).at(path)?;
    Ok(titled.split_horizontally(SIZE.0 - LEGEND_WIDTH))
}

/// How a legend entry's line is drawn.
#[derive(Clone, Copy, PartialEq, Eq)]
pub(super) enum Line {
    Solid,
    Dashed,
    /// Points alone (the series is not a line).
    Without,
}

/// One line of a legend: its colour, its line and whether it has point markers.
pub(super) struct Entry {
    pub name: String,
    pub color: RGBColor,
    pub line: Line,
    pub marker: bool,
}

/// Draws `entries` down the legend column, each a sample of its line and its name, then the
/// `notes` below them.
pub(super) fn legend(area: &Area, entries: &[Entry], notes: &[&str], path: &Path) -> Result<()> {
    let style = ("sans-serif", 15).into_font().color(&BLACK);
    let (x0, x1) = (8, 44);
    for (i, e) in entries.iter().enumerate() {
        let y = 40 + 24 * i as i32;
        let dash = if e.line == Line::Dashed { 6 } else { x1 - x0 };
        if e.line != Line::Without {
            for x in (x0..x1).step_by(dash as usize + 4) {
                let segment = [(x, y), ((x + dash).min(x1), y)];
                area.draw(&PathElement::new(segment, e.color.stroke_width(2)))
                    .at(path)?;
            }
        }
        if e.marker {
            area.draw(&Circle::new(((x0 + x1) / 2, y), 4, e.color.filled()))
                .at(path)?;
        }
        area.draw(&Text::new(e.name.clone(), (x1 + 8, y - 8), style.clone()))
            .at(path)?;
    }
    let below = 40 + 24 * entries.len() as i32 + 12;
    for (i, note) in notes.iter().enumerate() {
        let at = (x0, below + 20 * i as i32);
        area.draw(&Text::new(note.to_string(), at, style.clone()))
            .at(path)?;
    }
    Ok(())
}

/// An axis (linear or log) whose ticks are exactly `ticks`: plotters' own choice puts ticks at
/// 1.5 render nodes.
pub(super) struct Ticked<R> {
    inner: R,
    ticks: Vec<f64>,
}

impl<R: Ranged<ValueType = f64>> Ranged for Ticked<R> {
    type FormatOption = DefaultFormatting;
    type ValueType = f64;

    fn range(&self) -> Range<f64> {
        self.inner.range()
    }

    fn map(&self, value: &f64, limit: (i32, i32)) -> i32 {
        self.inner.map(value, limit)
    }

    fn key_points<Hint: KeyPointHint>(&self, hint: Hint) -> Vec<f64> {
        if hint.weight().allow_light_points() {
            Vec::new()
        } else {
            self.ticks.clone()
        }
    }

    fn axis_pixel_range(&self, limit: (i32, i32)) -> Range<i32> {
        self.inner.axis_pixel_range(limit)
    }
}

/// A linear axis over `lo..hi` ticked at nice steps (whole numbers only when `whole`).
pub(super) fn linear_axis(lo: f64, hi: f64, whole: bool) -> Ticked<RangedCoordf64> {
    Ticked {
        inner: (lo..hi).into(),
        ticks: linear_ticks(lo, hi, whole),
    }
}

/// A log axis over `lo..hi` (both positive) ticked at powers of ten (and 2 and 5 times them
/// over a short range).
pub(super) fn log_axis(lo: f64, hi: f64) -> Ticked<LogCoord<f64>> {
    Ticked {
        inner: (lo..hi).log_scale().into(),
        ticks: log_ticks(lo, hi),
    }
}

/// A number as a tick label: no trailing zeros, no exponent for the sizes plots show.
pub(super) fn number(v: f64) -> String {
    if v == 0.0 {
        return "0".into();
    }
    // Four significant digits, then the zeros trimmed.
    let magnitude = v.abs().log10().floor() as i32;
    let decimals = (3 - magnitude).clamp(0, 9) as usize;
    let text = format!("{v:.decimals$}");
    if text.contains('.') {
        text.trim_end_matches('0').trim_end_matches('.').into()
    } else {
        text
    }
}

/// The largest step of 1, 2 or 5 × 10^k that cuts `span` into at most `most` steps.
fn nice_step(span: f64, most: usize) -> f64 {
    let rough = span / most as f64;
    let decade = 10f64.powf(rough.log10().floor());
    [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|m| m * decade)
        .find(|step| span / step <= most as f64)
        .unwrap_or(10.0 * decade)
}

/// Ticks at multiples of a nice step within `lo..=hi`; whole numbers only when `whole`
/// (render-node counts: a tick at 1.5 nodes means nothing).
pub(super) fn linear_ticks(lo: f64, hi: f64, whole: bool) -> Vec<f64> {
    let mut step = nice_step((hi - lo).max(f64::MIN_POSITIVE), 10);
    if whole {
        step = step.max(1.0).round();
    }
    let first = (lo / step).ceil() as i64;
    let last = (hi / step).floor() as i64;
    (first..=last).map(|k| k as f64 * step).collect()
}

/// Ticks of a log axis over `lo..=hi` (both positive): each power of ten, with 2 and 5 times
/// it where the range spans no more than three decades.
pub(super) fn log_ticks(lo: f64, hi: f64) -> Vec<f64> {
    let (a, b) = (lo.log10().floor() as i32, hi.log10().ceil() as i32);
    let fine = hi / lo <= 1000.0;
    let mut ticks = Vec::new();
    for e in a..=b {
        let decade = 10f64.powi(e);
        for m in [1.0, 2.0, 5.0] {
            let v = m * decade;
            if (m == 1.0 || fine) && v >= lo * (1.0 - 1e-9) && v <= hi * (1.0 + 1e-9) {
                ticks.push(v);
            }
        }
    }
    ticks
}

/// The smallest and largest of `values`, or `None` for none (non-finite ones skipped).
pub(super) fn extent(values: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    values
        .filter(|v| v.is_finite())
        .fold(None, |acc, v| match acc {
            None => Some((v, v)),
            Some((lo, hi)) => Some((lo.min(v), hi.max(v))),
        })
}

/// A range around `lo..hi` with `share` of its span either side (one unit when empty).
pub(super) fn padded(lo: f64, hi: f64, share: f64) -> (f64, f64) {
    let span = if hi > lo { hi - lo } else { 1.0 };
    (lo - share * span, hi + share * span)
}

/// Writes a line plot of `series` to `path`: axes fitted to the data (y from zero), x ticks at
/// whole numbers when every x is one, the legend beside the plot.
pub fn line_plot(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
) -> Result<()> {
    let points = || series.iter().flat_map(|s| s.points.iter());
    let (x0, x1) = extent(points().map(|p| p.0)).unwrap_or((0.0, 1.0));
    let whole = points().all(|p| p.0.fract() == 0.0);
    let (x0, x1) = padded(x0, x1, 0.03);
    let y1 = extent(points().map(|p| p.1)).map_or(0.0, |e| e.1.max(0.0));
    let y1 = if y1 > 0.0 { y1 * 1.1 } else { 1.0 };
    let root = SVGBackend::new(path, SIZE).into_drawing_area();
    let (plot, side) = areas(&root, title, path)?;
    let mut chart = ChartBuilder::on(&plot)
        .margin(16)
        .x_label_area_size(44)
        .y_label_area_size(70)
        .build_cartesian_2d(linear_axis(x0, x1, whole), linear_axis(0.0, y1, false))
        .at(path)?;
    chart
        .configure_mesh()
        .x_desc(x_label)
        .y_desc(y_label)
        .x_label_formatter(&|v| number(*v))
        .y_label_formatter(&|v| number(*v))
        .draw()
        .at(path)?;
    let mut entries = Vec::new();
    for (i, s) in series.iter().enumerate() {
        let color = COLORS[i % COLORS.len()];
        let line = LineSeries::new(s.points.iter().copied(), color.stroke_width(2));
        chart.draw_series(line).at(path)?;
        let dots = s.points.iter().map(|&p| Circle::new(p, 3, color.filled()));
        chart.draw_series(dots).at(path)?;
        entries.push(Entry {
            name: s.name.clone(),
            color,
            line: Line::Solid,
            marker: true,
        });
    }
    legend(&side, &entries, &[], path)?;
    root.present().at(path)?;
    Ok(())
}

/// Reading plots back in tests: their text elements.
#[cfg(test)]
pub(super) mod read {
    /// Every `<text>` element: its x, y and text (entities decoded).
    pub fn texts(svg: &str) -> Vec<(f64, f64, String)> {
        let mut out = Vec::new();
        for part in svg.split("<text").skip(1) {
            let Some((attrs, rest)) = part.split_once('>') else {
                continue;
            };
            let text = rest.split("</text>").next().unwrap_or("");
            let attr = |name: &str| -> f64 {
                let key = format!(" {name}=\"");
                attrs
                    .split(&key)
                    .nth(1)
                    .and_then(|v| v.split('"').next())
                    .and_then(|v| v.parse().ok())
                    .unwrap_or(f64::NAN)
            };
            let text = text
                .trim()
                .replace("&lt;", "<")
                .replace("&gt;", ">")
                .replace("&amp;", "&");
            out.push((attr("x"), attr("y"), text));
        }
        out
    }

    /// The numeric labels on the bottom row of ticks (the x axis): (x position, value),
    /// left to right. The x axis's labels are the numbers lowest in the picture but for
    /// the axis descriptions, which are not numbers.
    pub fn x_ticks(svg: &str) -> Vec<(f64, f64)> {
        let numbers: Vec<(f64, f64, f64)> = texts(svg)
            .into_iter()
            .filter_map(|(x, y, t)| Some((x, y, t.trim().parse::<f64>().ok()?)))
            .collect();
        let bottom = numbers.iter().map(|n| n.1).fold(f64::MIN, f64::max);
        let mut ticks: Vec<(f64, f64)> = numbers
            .iter()
            .filter(|n| (n.1 - bottom).abs() < 1.0)
            .map(|n| (n.0, n.2))
            .collect();
        ticks.sort_by(|a, b| a.0.total_cmp(&b.0));
        ticks
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_an_svg_with_the_labels() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("p.svg");
        let series = [Series {
            name: "fps".into(),
            points: vec![(1.0, 10.0), (2.0, 19.0)],
        }];
        line_plot(&path, "frames/s", "render nodes", "fps", &series).unwrap();
        let svg = std::fs::read_to_string(&path).unwrap();
        assert!(
            svg.starts_with("<svg") && svg.contains("render nodes") && svg.contains("<polyline"),
            "{svg}"
        );
    }

    #[test]
    fn node_counts_get_whole_number_ticks_not_1_point_5() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("p.svg");
        let series = [Series {
            name: "fps".into(),
            points: vec![(1.0, 10.0), (2.0, 19.0)],
        }];
        line_plot(&path, "frames/s", "render nodes", "fps", &series).unwrap();
        let svg = std::fs::read_to_string(&path).unwrap();
        let ticks: Vec<f64> = read::x_ticks(&svg).iter().map(|t| t.1).collect();
        assert_eq!(ticks, [1.0, 2.0], "{svg}");
        assert_eq!(
            linear_ticks(0.7, 8.3, true),
            (1..=8).map(f64::from).collect::<Vec<_>>()
        );
        assert_eq!(linear_ticks(1.0, 64.0, true)[..3], [10.0, 20.0, 30.0]);
        assert_eq!(linear_ticks(0.0, 0.5, false)[..3], [0.0, 0.05, 0.1]);
    }

    #[test]
    fn the_legend_stands_beside_the_plot_not_over_its_data() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("p.svg");
        let series = [Series {
            name: "a line named here".into(),
            points: vec![(0.0, 0.0), (100.0, 100.0)],
        }];
        line_plot(&path, "t", "x", "y", &series).unwrap();
        let svg = std::fs::read_to_string(&path).unwrap();
        let texts = read::texts(&svg);
        let name = texts.iter().find(|t| t.2 == "a line named here").unwrap();
        let rightmost_tick = read::x_ticks(&svg).last().unwrap().0;
        assert!(
            name.0 > rightmost_tick && name.0 > (SIZE.0 - LEGEND_WIDTH) as f64,
            "{name:?} {rightmost_tick}"
        );
    }

    #[test]
    fn numbers_and_log_ticks_read_plainly() {
        assert_eq!(number(2.0), "2");
        assert_eq!(number(0.05), "0.05");
        assert_eq!(number(0.002), "0.002");
        assert_eq!(number(1500.0), "1500");
        assert_eq!(number(2.5), "2.5");
        assert_eq!(log_ticks(3.0, 4000.0), [10.0, 100.0, 1000.0]);
        assert_eq!(log_ticks(9.0, 310.0), [10.0, 20.0, 50.0, 100.0, 200.0]);
        assert_eq!(log_ticks(0.02, 0.3), [0.02, 0.05, 0.1, 0.2]);
    }
}
