//! `bench max-fps`: frame rate on a scene that costs nothing to render, raw and with lz4, for
//! each render-node count, beside the transport limit a bulk transfer measures in the same run.

use super::plot::Series;
use super::transport::{self, Throughput};
use super::{wall_run, wire_ratio, wrote, BenchArgs, Outputs, Plot};
use anyhow::{Context, Result};
use serde_json::json;
use std::path::Path;
use tessera_protocol::pixels::Compression;

/// One max-fps wall run: its settings and what it measured.
#[derive(Clone, Copy)]
struct FpsRun {
    compress: Compression,
    nodes: u32,
    fps: f64,
    wire_per_frame: f64,
    wire_ratio: f64,
}

/// The runs and the bulk transfer, and what follows from both.
struct Measured {
    displays: u32,
    runs: Vec<FpsRun>,
    bulk: Throughput,
}

/// Name of a compression in the CSV, the report and the table.
fn name(c: Compression) -> &'static str {
    if c == Compression::Lz4 {
        "lz4"
    } else {
        "none"
    }
}

pub async fn max_fps(args: &BenchArgs, out: &Path) -> Result<()> {
    let displays = args.local.run.wall.layout()?.display_count();
    let runs = measure_runs(args).await?;
    eprintln!(
        "bench: bulk transfer over {displays} link(s) for {} s",
        args.transport_seconds
    );
    let bulk = transport::bulk_throughput(displays, args.transport_seconds, 256 * 1024).await?;
    let m = Measured {
        displays,
        runs,
        bulk,
    };
    let (raw, lz4) = (m.best(Compression::None)?, m.best(Compression::Lz4)?);
    let written = Outputs {
        csv: "max-fps.csv",
        header: "compression,render_nodes,fps,wire_bytes_per_frame,wire_bytes_per_pixel_byte,transport_limit_fps",
        rows: m.csv_rows(),
        plots: vec![Plot {
            file: "max-fps.svg",
            title: "frame rate on an empty scene against the transport limit",
            x_label: "render nodes",
            y_label: "frames/s",
            series: m.series(),
        }],
        report: m.report(&raw, &lz4),
    }
    .write(out)?;
    m.print_table(&raw, &lz4);
    wrote(&written);
    Ok(())
}

/// A wall on the empty scene for each compression and render-node count.
async fn measure_runs(args: &BenchArgs) -> Result<Vec<FpsRun>> {
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
    Ok(runs)
}

impl Measured {
    /// The frame rate the bulk transfer's bytes per second would carry at `r`'s frame size.
    fn limit_of(&self, r: &FpsRun) -> f64 {
        self.bulk.wire_bytes_per_s / r.wire_per_frame.max(1.0)
    }

    /// The fastest run with compression `c`.
    fn best(&self, c: Compression) -> Result<FpsRun> {
        self.runs
            .iter()
            .filter(|r| r.compress == c)
            .copied()
            .max_by(|a, b| a.fps.total_cmp(&b.fps))
            .context("no run")
    }

    /// One line a run: compression, nodes, fps, wire bytes per frame and pixel byte, limit.
    fn csv_rows(&self) -> Vec<String> {
        self.runs
            .iter()
            .map(|r| {
                format!(
                    "{},{},{:.3},{:.0},{:.5},{:.3}",
                    name(r.compress),
                    r.nodes,
                    r.fps,
                    r.wire_per_frame,
                    r.wire_ratio,
                    self.limit_of(r)
                )
            })
            .collect()
    }

    /// Frame rate and transport limit against render nodes, for each compression.
    fn series(&self) -> Vec<Series> {
        let mut series = Vec::new();
        for c in [Compression::None, Compression::Lz4] {
            let of = || self.runs.iter().filter(move |r| r.compress == c);
            series.push(Series {
                name: format!("fps, compression {}", name(c)),
                points: of().map(|r| (r.nodes as f64, r.fps)).collect(),
            });
            series.push(Series {
                name: format!("transport limit, compression {}", name(c)),
                points: of().map(|r| (r.nodes as f64, self.limit_of(r))).collect(),
            });
        }
        series
    }

    /// A best run against the transport limit, as report.json states it.
    fn summary(&self, r: &FpsRun) -> serde_json::Value {
        json!({
            "fps": r.fps,
            "render_nodes_at_best": r.nodes,
            "transport_limit_fps": self.limit_of(r),
            "ratio": r.fps / self.limit_of(r),
            "wire_bytes_per_frame": r.wire_per_frame,
            "wire_bytes_per_pixel_byte": r.wire_ratio,
        })
    }

    /// report.json: the best raw run's summary at the top, lz4's beside it, then every run.
    fn report(&self, raw: &FpsRun, lz4: &FpsRun) -> serde_json::Value {
        let mut report = self.summary(raw);
        report["experiment"] = json!("max-fps");
        report["lz4"] = self.summary(lz4);
        report["bulk_transfer"] = json!(self.bulk);
        report["runs"] = self
            .runs
            .iter()
            .map(|r| {
                json!({
                    "compression": name(r.compress), "render_nodes": r.nodes, "fps": r.fps,
                    "wire_bytes_per_frame": r.wire_per_frame, "wire_bytes_per_pixel_byte": r.wire_ratio,
                    "transport_limit_fps": self.limit_of(r),
                })
            })
            .collect();
        report
    }

    /// A line a run, then the bulk transfer and the best runs against its limit.
    fn print_table(&self, raw: &FpsRun, lz4: &FpsRun) {
        println!(
            "{:<6} {:>6} {:>9} {:>14} {:>10} {:>11}",
            "comp", "nodes", "fps", "wire B/frame", "wire/pixel", "limit fps"
        );
        for r in &self.runs {
            println!(
                "{:<6} {:>6} {:>9.1} {:>14.0} {:>10.4} {:>11.1}",
                name(r.compress),
                r.nodes,
                r.fps,
                r.wire_per_frame,
                r.wire_ratio,
                self.limit_of(r)
            );
        }
        println!(
            "bulk transfer: {:.1} MB/s over {} link(s); best fps / transport limit: {:.3} raw, {:.3} with lz4",
            self.bulk.wire_bytes_per_s / 1e6,
            self.displays,
            raw.fps / self.limit_of(raw),
            lz4.fps / self.limit_of(lz4)
        );
    }
}
