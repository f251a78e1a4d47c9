//! `tessera-master bench EXPERIMENT`: reproducible measurement runs on a local wall, each
//! writing `report.json`, a CSV and an SVG plot into `--out DIR` and printing a short table.

mod charts;
mod dsm;
mod error;
mod max_fps;
mod plot;
mod soak;
mod stiff;
mod transport;

use crate::args::LocalArgs;
use crate::control::ControlClient;
use crate::report::Report;
use crate::wall_run::{run_local, run_local_driven, Driver};
use anyhow::{bail, Context, Result};
use charts::Chart;
use plot::{line_plot, Series};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;
use tessera_model::camera::{Camera, CameraMode};
use tessera_model::state::StateChange;
use tessera_protocol::control::{ControlReply, ControlRequest};

#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Experiment {
    /// Frame rate against render nodes on a scene that costs nothing to render, beside the
    /// transport limit measured in the same run (Ize et al., §5.1).
    MaxFps,
    /// Camera change → present on every display, and the present skew across displays.
    Latency,
    /// Frames/s and load-balance efficiency against render nodes and threads.
    Scaling,
    /// Image error (RMSE, PSNR) against render time for each quality knob.
    ErrorVsTime,
    /// A wall at full rate for --minutes with a render node killed and replaced every
    /// --kill-every seconds: frames lost, resident memory over time, recovery times.
    Soak,
    /// Distributed shared memory against replicated data: frames/s against the cache size
    /// (--cache-fractions) and render nodes (--nodes), for each of --shadings, with cache
    /// misses, blocks read per frame and remote-read latency beside the QUIC round trip.
    Dsm,
    /// The scene moved to 10⁷ from the origin, its units changed (10⁻⁶ to 10⁶) and a volume's
    /// values scaled (10⁻³⁰ to 10³⁰): per case, the share of pixels that agree with the plain
    /// picture and the largest depth error.
    Stiff,
}

#[derive(clap::Args)]
pub struct BenchArgs {
    /// The experiment to run.
    #[arg(value_enum)]
    experiment: Experiment,
    /// The local wall (same flags as `local`); `--out DIR` is required.
    #[command(flatten)]
    local: LocalArgs,
    /// Render-node counts to run (max-fps, scaling), e.g. 1,2,4.
    #[arg(long, value_delimiter = ',', default_value = "1,2")]
    nodes: Vec<u32>,
    /// Threads per render node to run (scaling), e.g. 1,2.
    #[arg(long, value_delimiter = ',', default_value = "1,2")]
    thread_counts: Vec<u32>,
    /// Seconds of the bulk transfer that measures the transport limit (max-fps).
    #[arg(long, default_value_t = 3.0, value_parser = parse_transport_seconds)]
    transport_seconds: f64,
    /// error-vs-time: ambient-occlusion rays of the converged reference.
    #[arg(long, default_value_t = 256)]
    reference_ao: u32,
    /// error-vs-time: samples per pixel of the converged reference.
    #[arg(long, default_value_t = 64)]
    reference_spp: u32,
    /// latency: milliseconds between the scripted camera path's control commands.
    #[arg(long, default_value_t = 40, value_parser = clap::value_parser!(u64).range(1..=10_000))]
    command_ms: u64,
    /// soak: how long to run, in minutes.
    #[arg(long, default_value_t = 1.0, value_parser = parse_minutes)]
    minutes: f64,
    /// soak: seconds between render-node kills.
    #[arg(long, default_value_t = 10.0, value_parser = parse_transport_seconds)]
    kill_every: f64,
    /// dsm: each render node's cache as a share of the scene, e.g. 0.03125,0.125,1.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "0.03125,0.125,0.25,0.5,1"
    )]
    cache_fractions: Vec<f32>,
    /// dsm: runs of each configuration, taken in turn; each keeps its median frame rate.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=99))]
    repeats: u32,
    /// dsm: the shadings to measure, each against its own replicated run.
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        default_value = "cast,shadows,ao"
    )]
    shadings: Vec<dsm::Shading>,
}

fn parse_minutes(text: &str) -> Result<f64, String> {
    match text.trim().parse::<f64>() {
        Ok(m) if (0.05..=1440.0).contains(&m) => Ok(m),
        _ => Err(format!(
            "`{text}` is not a number of minutes from 0.05 to 1440"
        )),
    }
}

impl BenchArgs {
    fn command_every(&self) -> Duration {
        Duration::from_millis(self.command_ms)
    }
}

fn parse_transport_seconds(text: &str) -> Result<f64, String> {
    match text.trim().parse::<f64>() {
        Ok(s) if (0.1..=600.0).contains(&s) => Ok(s),
        _ => Err(format!(
            "`{text}` is not a number of seconds from 0.1 to 600"
        )),
    }
}

pub async fn bench(mut args: BenchArgs) -> Result<ExitCode> {
    // A measurement has nobody at a console, and its picture and figures would cost the
    // nodes work the run measures.
    args.local.no_console = true;
    let Some(out) = args.local.run.out.clone() else {
        bail!("bench needs --out DIR for its report, CSV and plot");
    };
    std::fs::create_dir_all(&out)
        .with_context(|| format!("cannot create --out {}", out.display()))?;
    if args.nodes.contains(&0) || args.thread_counts.contains(&0) {
        bail!("--nodes and --thread-counts must be at least 1");
    }
    match args.experiment {
        Experiment::Latency => latency(&args, &out).await?,
        Experiment::Scaling => scaling(&args, &out).await?,
        Experiment::MaxFps => max_fps::max_fps(&args, &out).await?,
        Experiment::ErrorVsTime => error::error_vs_time(&args, &out)?,
        Experiment::Soak => soak::soak(&args, &out).await?,
        Experiment::Dsm => dsm::dsm(&args, &out).await?,
        Experiment::Stiff => stiff::stiff(&args, &out)?,
    }
    Ok(ExitCode::SUCCESS)
}

/// Runs one local wall and returns its report; any failed node fails the experiment.
async fn wall_run(local: &LocalArgs, what: &str) -> Result<Report> {
    eprintln!("bench: {what}");
    checked_run(run_local(local, true).await?, what)
}

/// A run's report, or why there is none: interrupted, failed, or nodes lost on the way.
fn checked_run(run: crate::wall_run::LocalRun, what: &str) -> Result<Report> {
    let ended = run.ended;
    if ended.interrupted {
        bail!("interrupted during {what}");
    }
    let problems = ended.processes_failed.join("; ");
    let report = ended
        .into_report()
        .with_context(|| format!("{what} failed"))?;
    if !problems.is_empty() {
        bail!("{what}: nodes failed: {problems}");
    }
    Ok(report)
}

fn write_json(out: &Path, value: &serde_json::Value) -> Result<PathBuf> {
    let path = out.join("report.json");
    std::fs::write(&path, serde_json::to_string_pretty(value)?)
        .with_context(|| format!("cannot write {}", path.display()))?;
    Ok(path)
}

fn write_csv(path: &Path, header: &str, rows: &[String]) -> Result<()> {
    let mut text = String::from(header);
    text.push('\n');
    for row in rows {
        text.push_str(row);
        text.push('\n');
    }
    std::fs::write(path, text).with_context(|| format!("cannot write {}", path.display()))
}

/// One plot of an experiment: its file name in `--out`, title, axis labels and lines.
struct Plot<'a> {
    file: &'a str,
    title: &'a str,
    x_label: &'a str,
    y_label: &'a str,
    series: Vec<Series>,
}

/// What an experiment writes into `--out`: a CSV table, its plots and report.json.
struct Outputs<'a> {
    csv: &'a str,
    header: &'a str,
    rows: Vec<String>,
    plots: Vec<Plot<'a>>,
    report: serde_json::Value,
}

impl Outputs<'_> {
    /// Writes the CSV, the plots and report.json, in that order, and returns their paths in
    /// the order [`wrote`] lists them: report.json, the CSV, the plots.
    fn write(&self, out: &Path) -> Result<Vec<PathBuf>> {
        self.write_with(out, &[])
    }

    /// [`Outputs::write`], with `charts` (each a file name and its chart) after the plots.
    fn write_with(&self, out: &Path, charts: &[(&str, Chart)]) -> Result<Vec<PathBuf>> {
        let csv = out.join(self.csv);
        write_csv(&csv, self.header, &self.rows)?;
        let mut paths = vec![csv];
        for plot in &self.plots {
            let path = out.join(plot.file);
            line_plot(&path, plot.title, plot.x_label, plot.y_label, &plot.series)?;
            paths.push(path);
        }
        for (file, chart) in charts {
            let path = out.join(file);
            chart.draw(&path)?;
            paths.push(path);
        }
        paths.insert(0, write_json(out, &self.report)?);
        Ok(paths)
    }
}

fn wrote(paths: &[PathBuf]) {
    for p in paths {
        println!("wrote {}", p.display());
    }
}

/// Wire bytes over pixel bytes of the whole run, all displays together.
fn wire_ratio(report: &Report) -> f64 {
    let wire: u64 = report
        .displays
        .iter()
        .map(|d| d.stats.wire_bytes_received)
        .sum();
    let pixels: f64 = report
        .displays
        .iter()
        .map(|d| d.stats.pixels_owned as f64 * 3.0 * d.stats.frames_presented as f64)
        .sum();
    if pixels > 0.0 {
        wire as f64 / pixels
    } else {
        0.0
    }
}

/// Mean and lowest busy/elapsed over the render nodes.
fn efficiency(report: &Report) -> (f64, f64) {
    let shares: Vec<f64> = report
        .render_nodes
        .iter()
        .filter(|r| r.stats.elapsed_s > 0.0)
        .map(|r| r.stats.busy_s / r.stats.elapsed_s)
        .collect();
    if shares.is_empty() {
        return (0.0, 0.0);
    }
    let mean = shares.iter().sum::<f64>() / shares.len() as f64;
    (mean, shares.iter().copied().fold(f64::INFINITY, f64::min))
}

/// A control client of the wall at `addr`: the wall takes a moment to start, and a client
/// that comes too early retries.
async fn connect_when_up(addr: &str, cert_dir: &Path) -> ControlClient {
    loop {
        match ControlClient::connect(addr, cert_dir).await {
            Ok(c) => return c,
            Err(_) => tokio::time::sleep(Duration::from_millis(100)).await,
        }
    }
}

/// Moves the camera along a circle about the scene through the control interface, one
/// command every `every`, for as long as the wall runs: each command's entry stamp is what
/// `input_latency_ms` measures from.
fn camera_path(every: Duration) -> Driver {
    Box::new(move |addr, cert_dir| {
        Box::pin(async move {
            let mut client = connect_when_up(&addr, &cert_dir).await;
            let ControlReply::State { current, frame, .. } =
                client.ask(ControlRequest::State).await?
            else {
                bail!("the master answered a state request with something else");
            };
            let start = current.camera.camera_for_frame(frame);
            let center = start.target();
            let offset = start.eye() - center;
            for step in 0u32.. {
                tokio::time::sleep(every).await;
                let angle = step as f32 * 0.02;
                let eye = center + glam::Quat::from_rotation_y(angle) * offset;
                let camera = Camera::new(eye, center, start.up(), start.fov_y_deg())?;
                let change = StateChange::Camera(CameraMode::fixed(camera));
                client.ask(ControlRequest::Change(vec![change])).await?;
            }
            Ok(())
        })
    })
}

/// `ms` in frame periods of `period` ms (0 where the period is unknown).
fn in_frame_periods(ms: f64, period: f64) -> f64 {
    if period > 0.0 {
        ms / period
    } else {
        0.0
    }
}

async fn latency(args: &BenchArgs, out: &Path) -> Result<()> {
    let run = run_local_driven(&args.local, true, Some(camera_path(args.command_every()))).await?;
    let report = checked_run(run, "latency run")?;
    let t = &report.timing;
    if t.frames_measured == 0 {
        bail!("no frame was reported presented by every display");
    }
    let period = report.frame_period_ms;
    let in_periods = in_frame_periods(t.latency_ms.p95, period);
    let written = Outputs {
        csv: "latency.csv",
        header: "frame,latency_ms,skew_ms",
        rows: t
            .per_frame
            .iter()
            .map(|f| format!("{},{:.4},{:.4}", f.frame, f.latency_ms, f.skew_ms))
            .collect(),
        plots: Vec::new(),
        report: json!({
            "experiment": "latency",
            "latency_ms": t.latency_ms,
            "input_latency_ms": t.input_latency_ms,
            "input_latency_p95_in_frame_periods": in_frame_periods(t.input_latency_ms.p95, period),
            "inputs_measured": t.inputs_measured,
            "skew_ms": t.skew_ms,
            "frame_period_ms": period,
            "latency_p95_in_frame_periods": in_periods,
            "frames_measured": t.frames_measured,
            "wire_bytes_per_pixel_byte": wire_ratio(&report),
            "run": report,
        }),
    }
    .write_with(out, &[("latency.svg", latency_chart(t))])?;
    print_latency(t, period, in_periods);
    wrote(&written);
    Ok(())
}

/// Latency and skew against the frame, and each input's latency at the frame that showed it.
fn latency_chart(t: &crate::timing::TimingSummary) -> Chart {
    let per_frame = |pick: fn(&crate::timing::FrameTiming) -> f64| {
        t.per_frame
            .iter()
            .map(|f| (f.frame as f64, pick(f)))
            .collect()
    };
    Chart::Latency {
        latency: per_frame(|f| f.latency_ms),
        input: t.per_input.iter().map(|&(f, ms)| (f as f64, ms)).collect(),
        skew: per_frame(|f| f.skew_ms),
    }
}

/// The percentiles of latency, input latency and skew, then the latency in frame periods.
fn print_latency(t: &crate::timing::TimingSummary, period: f64, in_periods: f64) {
    println!(
        "{:<20} {:>8} {:>8} {:>8} {:>8}",
        "ms", "p50", "p95", "p99", "max"
    );
    let parts = &t.input_parts;
    for (name, p) in [
        ("latency", &t.latency_ms),
        ("input", &t.input_latency_ms),
        ("  entry -> master", &parts.entry_to_master_ms),
        ("  master -> barrier", &parts.master_to_barrier_ms),
        ("  barrier -> present", &parts.barrier_to_present_ms),
        ("skew", &t.skew_ms),
    ] {
        println!(
            "{name:<20} {:>8.3} {:>8.3} {:>8.3} {:>8.3}",
            p.p50, p.p95, p.p99, p.max
        );
    }
    println!(
        "input p95 = {:.2} frame periods",
        in_frame_periods(t.input_latency_ms.p95, period)
    );
    println!(
        "frame period {period:.2} ms; latency p95 = {in_periods:.2} frame periods; {} frames measured",
        t.frames_measured
    );
}

async fn scaling(args: &BenchArgs, out: &Path) -> Result<()> {
    let runs = scaling_runs(args).await?;
    let num = |r: &serde_json::Value, key: &str| r[key].as_f64().unwrap_or(0.0);
    let rows: Vec<String> = runs
        .iter()
        .map(|r| {
            format!(
                "{},{},{:.3},{:.4},{:.4}",
                r["render_nodes"],
                r["threads"],
                num(r, "fps"),
                num(r, "efficiency"),
                num(r, "efficiency_min")
            )
        })
        .collect();
    let series: Vec<Series> = args
        .thread_counts
        .iter()
        .map(|&t| Series {
            name: format!("{t} thread(s) per node"),
            points: runs
                .iter()
                .filter(|r| r["threads"] == t)
                .map(|r| (num(r, "render_nodes"), num(r, "fps")))
                .collect(),
        })
        .collect();
    let written = Outputs {
        csv: "scaling.csv",
        header: "render_nodes,threads,fps,efficiency,efficiency_min",
        rows,
        plots: Vec::new(),
        report: json!({ "experiment": "scaling", "runs": runs }),
    }
    .write_with(out, &[("scaling.svg", Chart::Scaling(series))])?;
    print_scaling(&runs);
    wrote(&written);
    Ok(())
}

/// A wall for each thread count and render-node count: its frame rate and efficiency.
async fn scaling_runs(args: &BenchArgs) -> Result<Vec<serde_json::Value>> {
    let mut runs = Vec::new();
    for &threads in &args.thread_counts {
        for &nodes in &args.nodes {
            let mut local = args.local.clone();
            local.render_nodes = nodes;
            local.threads = Some(threads);
            local.run.out = None;
            let report = wall_run(
                &local,
                &format!("{nodes} render node(s) × {threads} thread(s)"),
            )
            .await?;
            let (mean, min) = efficiency(&report);
            runs.push(json!({
                "render_nodes": nodes,
                "threads": threads,
                "fps": report.fps,
                "frame_ms": report.frame_ms,
                "efficiency": mean,
                "efficiency_min": min,
            }));
        }
    }
    Ok(runs)
}

/// A line a run: nodes, threads, frame rate and efficiency (mean and lowest).
fn print_scaling(runs: &[serde_json::Value]) {
    println!(
        "{:>6} {:>8} {:>9} {:>11} {:>9}",
        "nodes", "threads", "fps", "efficiency", "min"
    );
    for r in runs {
        println!(
            "{:>6} {:>8} {:>9.2} {:>10.1}% {:>8.1}%",
            r["render_nodes"].as_u64().unwrap_or(0),
            r["threads"].as_u64().unwrap_or(0),
            r["fps"].as_f64().unwrap_or(0.0),
            100.0 * r["efficiency"].as_f64().unwrap_or(0.0),
            100.0 * r["efficiency_min"].as_f64().unwrap_or(0.0)
        );
    }
}
