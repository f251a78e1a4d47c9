//! `tessera-master bench EXPERIMENT`: reproducible measurement runs on a local wall, each
//! writing `report.json`, a CSV and an SVG plot into `--out DIR` and printing a short table.

mod dsm;
mod error;
mod plot;
mod soak;
mod transport;

use crate::args::LocalArgs;
use crate::control::ControlClient;
use crate::report::Report;
use crate::wall_run::{run_local, run_local_driven, Driver};
use anyhow::{bail, Context, Result};
use plot::{line_plot, Series};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;
use tessera_model::camera::{Camera, CameraMode};
use tessera_model::state::StateChange;
use tessera_protocol::control::{ControlReply, ControlRequest};
use tessera_protocol::pixels::Compression;

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

pub async fn bench(args: BenchArgs) -> Result<ExitCode> {
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
        Experiment::MaxFps => max_fps(&args, &out).await?,
        Experiment::ErrorVsTime => error::error_vs_time(&args, &out)?,
        Experiment::Soak => soak::soak(&args, &out).await?,
        Experiment::Dsm => dsm::dsm(&args, &out).await?,
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
    if run.interrupted {
        bail!("interrupted during {what}");
    }
    let report = run.outcome.with_context(|| format!("{what} failed"))?;
    let problems: Vec<String> = run.lost.into_iter().chain(run.failures).collect();
    if !problems.is_empty() {
        bail!("{what}: nodes failed: {}", problems.join("; "));
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

fn wrote(paths: &[&Path]) {
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

/// Moves the camera along a circle about the scene through the control interface, one
/// command every `every`, for as long as the wall runs: each command's entry stamp is what
/// `input_latency_ms` measures from.
fn camera_path(every: Duration) -> Driver {
    Box::new(move |addr, cert_dir| {
        Box::pin(async move {
            // The wall takes a moment to start; a client that comes too early retries.
            let mut client = loop {
                match ControlClient::connect(&addr, &cert_dir).await {
                    Ok(c) => break c,
                    Err(_) => tokio::time::sleep(Duration::from_millis(100)).await,
                }
            };
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

async fn latency(args: &BenchArgs, out: &Path) -> Result<()> {
    let run = run_local_driven(&args.local, true, Some(camera_path(args.command_every()))).await?;
    let report = checked_run(run, "latency run")?;
    let t = &report.timing;
    if t.frames_measured == 0 {
        bail!("no frame was reported presented by every display");
    }
    let period = report.frame_period_ms;
    let rows: Vec<String> = t
        .per_frame
        .iter()
        .map(|f| format!("{},{:.4},{:.4}", f.frame, f.latency_ms, f.skew_ms))
        .collect();
    let csv = out.join("latency.csv");
    write_csv(&csv, "frame,latency_ms,skew_ms", &rows)?;
    let svg = out.join("latency.svg");
    let series = |name: &str, pick: fn(&crate::timing::FrameTiming) -> f64| Series {
        name: name.into(),
        points: t
            .per_frame
            .iter()
            .map(|f| (f.frame as f64, pick(f)))
            .collect(),
    };
    line_plot(
        &svg,
        "camera change → present on every display, and present skew",
        "frame",
        "ms",
        &[
            series("latency", |f| f.latency_ms),
            series("skew", |f| f.skew_ms),
        ],
    )?;
    let in_periods = if period > 0.0 {
        t.latency_ms.p95 / period
    } else {
        0.0
    };
    let input_in_periods = if period > 0.0 {
        t.input_latency_ms.p95 / period
    } else {
        0.0
    };
    let json = write_json(
        out,
        &json!({
            "experiment": "latency",
            "latency_ms": t.latency_ms,
            "input_latency_ms": t.input_latency_ms,
            "input_latency_p95_in_frame_periods": input_in_periods,
            "inputs_measured": t.inputs_measured,
            "skew_ms": t.skew_ms,
            "frame_period_ms": period,
            "latency_p95_in_frame_periods": in_periods,
            "frames_measured": t.frames_measured,
            "wire_bytes_per_pixel_byte": wire_ratio(&report),
            "run": report,
        }),
    )?;
    println!(
        "{:<10} {:>8} {:>8} {:>8} {:>8}",
        "ms", "p50", "p95", "p99", "max"
    );
    for (name, p) in [
        ("latency", &t.latency_ms),
        ("input", &t.input_latency_ms),
        ("skew", &t.skew_ms),
    ] {
        println!(
            "{name:<10} {:>8.3} {:>8.3} {:>8.3} {:>8.3}",
            p.p50, p.p95, p.p99, p.max
        );
    }
    println!(
        "frame period {period:.2} ms; latency p95 = {in_periods:.2} frame periods; {} frames measured",
        t.frames_measured
    );
    wrote(&[&json, &csv, &svg]);
    Ok(())
}

async fn scaling(args: &BenchArgs, out: &Path) -> Result<()> {
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
    let rows: Vec<String> = runs
        .iter()
        .map(|r| {
            format!(
                "{},{},{:.3},{:.4},{:.4}",
                r["render_nodes"],
                r["threads"],
                r["fps"].as_f64().unwrap_or(0.0),
                r["efficiency"].as_f64().unwrap_or(0.0),
                r["efficiency_min"].as_f64().unwrap_or(0.0)
            )
        })
        .collect();
    let csv = out.join("scaling.csv");
    write_csv(
        &csv,
        "render_nodes,threads,fps,efficiency,efficiency_min",
        &rows,
    )?;
    let series: Vec<Series> = args
        .thread_counts
        .iter()
        .map(|&t| Series {
            name: format!("{t} thread(s) per node"),
            points: runs
                .iter()
                .filter(|r| r["threads"] == t)
                .map(|r| {
                    (
                        r["render_nodes"].as_f64().unwrap_or(0.0),
                        r["fps"].as_f64().unwrap_or(0.0),
                    )
                })
                .collect(),
        })
        .collect();
    let svg = out.join("scaling.svg");
    line_plot(
        &svg,
        "frames/s against render nodes",
        "render nodes",
        "frames/s",
        &series,
    )?;
    let json = write_json(out, &json!({ "experiment": "scaling", "runs": runs }))?;
    println!(
        "{:>6} {:>8} {:>9} {:>11} {:>9}",
        "nodes", "threads", "fps", "efficiency", "min"
    );
    for r in &runs {
        println!(
            "{:>6} {:>8} {:>9.2} {:>10.1}% {:>8.1}%",
            r["render_nodes"].as_u64().unwrap_or(0),
            r["threads"].as_u64().unwrap_or(0),
            r["fps"].as_f64().unwrap_or(0.0),
            100.0 * r["efficiency"].as_f64().unwrap_or(0.0),
            100.0 * r["efficiency_min"].as_f64().unwrap_or(0.0)
        );
    }
    wrote(&[&json, &csv, &svg]);
    Ok(())
}

/// One max-fps wall run: its settings and what it measured.
#[derive(Clone, Copy)]
struct FpsRun {
    compress: Compression,
    nodes: u32,
    fps: f64,
    wire_per_frame: f64,
    wire_ratio: f64,
}

async fn max_fps(args: &BenchArgs, out: &Path) -> Result<()> {
    let displays = args.local.run.wall.layout()?.display_count();
    let mut runs = Vec::new();
    for compress in [Compression::None, Compression::Lz4] {
        for &nodes in &args.nodes {
            let mut local = args.local.clone();
            local.render_nodes = nodes;
            local.run.scene.scene = "empty".into();
            local.run.compress = compress.into();
            local.run.out = None;
            let what = format!("empty scene, {nodes} render node(s), compression {compress:?}");
            let report = wall_run(&local, &what).await?;
            let frames = report.frames.max(1) as f64;
            let wire: f64 = report
                .displays
                .iter()
                .map(|d| d.stats.wire_bytes_received as f64)
                .sum();
            runs.push(FpsRun {
                compress,
                nodes,
                fps: report.fps,
                wire_per_frame: wire / frames,
                wire_ratio: wire_ratio(&report),
            });
        }
    }
    eprintln!(
        "bench: bulk transfer over {displays} link(s) for {} s",
        args.transport_seconds
    );
    let bulk = transport::bulk_throughput(displays, args.transport_seconds, 256 * 1024).await?;
    let limit_of = |r: &FpsRun| bulk.wire_bytes_per_s / r.wire_per_frame.max(1.0);
    let best = |c: Compression| {
        runs.iter()
            .filter(|r| r.compress == c)
            .copied()
            .max_by(|a, b| a.fps.total_cmp(&b.fps))
            .context("no run")
    };
    let (raw, lz4) = (best(Compression::None)?, best(Compression::Lz4)?);
    let summary = |r: &FpsRun| {
        json!({
            "fps": r.fps,
            "render_nodes_at_best": r.nodes,
            "transport_limit_fps": limit_of(r),
            "ratio": r.fps / limit_of(r),
            "wire_bytes_per_frame": r.wire_per_frame,
            "wire_bytes_per_pixel_byte": r.wire_ratio,
        })
    };
    let name = |c: Compression| if c == Compression::Lz4 { "lz4" } else { "none" };
    let rows: Vec<String> = runs
        .iter()
        .map(|r| {
            format!(
                "{},{},{:.3},{:.0},{:.5},{:.3}",
                name(r.compress),
                r.nodes,
                r.fps,
                r.wire_per_frame,
                r.wire_ratio,
                limit_of(r)
            )
        })
        .collect();
    let csv = out.join("max-fps.csv");
    write_csv(
        &csv,
        "compression,render_nodes,fps,wire_bytes_per_frame,wire_bytes_per_pixel_byte,transport_limit_fps",
        &rows,
    )?;
    let mut series = Vec::new();
    for c in [Compression::None, Compression::Lz4] {
        let of = || runs.iter().filter(move |r| r.compress == c);
        series.push(Series {
            name: format!("fps, compression {}", name(c)),
            points: of().map(|r| (r.nodes as f64, r.fps)).collect(),
        });
        series.push(Series {
            name: format!("transport limit, compression {}", name(c)),
            points: of().map(|r| (r.nodes as f64, limit_of(r))).collect(),
        });
    }
    let svg = out.join("max-fps.svg");
    line_plot(
        &svg,
        "frame rate on an empty scene against the transport limit",
        "render nodes",
        "frames/s",
        &series,
    )?;
    let mut report = summary(&raw);
    report["experiment"] = json!("max-fps");
    report["lz4"] = summary(&lz4);
    report["bulk_transfer"] = json!(bulk);
    report["runs"] = runs
        .iter()
        .map(|r| {
            json!({
                "compression": name(r.compress), "render_nodes": r.nodes, "fps": r.fps,
                "wire_bytes_per_frame": r.wire_per_frame, "wire_bytes_per_pixel_byte": r.wire_ratio,
                "transport_limit_fps": limit_of(r),
            })
        })
        .collect();
    let json = write_json(out, &report)?;
    println!(
        "{:<6} {:>6} {:>9} {:>14} {:>10} {:>11}",
        "comp", "nodes", "fps", "wire B/frame", "wire/pixel", "limit fps"
    );
    for r in &runs {
        println!(
            "{:<6} {:>6} {:>9.1} {:>14.0} {:>10.4} {:>11.1}",
            name(r.compress),
            r.nodes,
            r.fps,
            r.wire_per_frame,
            r.wire_ratio,
            limit_of(r)
        );
    }
    println!(
        "bulk transfer: {:.1} MB/s over {displays} link(s); best fps / transport limit: {:.3} raw, {:.3} with lz4",
        bulk.wire_bytes_per_s / 1e6,
        raw.fps / limit_of(&raw),
        lz4.fps / limit_of(&lz4)
    );
    wrote(&[&json, &csv, &svg]);
    Ok(())
}
