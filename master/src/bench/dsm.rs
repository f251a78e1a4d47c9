//! `bench dsm`: the shape of Ize et al.'s Table 1 and Figure 3 on a local wall. For each
//! shading (ray casting, with shadows, with ambient occlusion) and each render-node count, the
//! scene replicated and then shared at each cache size, in the same run: frames per second,
//! the share of block reads that missed, blocks read per frame, the render threads' time idle
//! waiting for blocks and the packets set aside for them, remote-read latency
//! (avg/min/max/p99) beside the QUIC round trip measured on the same connections, and the
//! frame rate relative to replicated.

use super::plot::Series;
use super::{wall_run, wrote, BenchArgs, Outputs, Plot};
use crate::dsm_data::DataMode;
use crate::report::Report;
use anyhow::{bail, Result};
use serde_json::json;
use std::path::Path;

/// A shading of the experiment: what its rays are.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Shading {
    /// Primary rays only (no shadows).
    Cast,
    /// Primary and shadow rays.
    Shadows,
    /// Primary, shadow and 4 ambient-occlusion rays a hit.
    Ao,
}

impl Shading {
    fn name(self) -> &'static str {
        match self {
            Shading::Cast => "ray cast",
            Shading::Shadows => "shadows",
            Shading::Ao => "AO",
        }
    }
}

/// One measured wall.
struct Row {
    shading: Shading,
    nodes: u32,
    /// None: replicated.
    cache: Option<f32>,
    report: Report,
    replicated_fps: f64,
}

impl Row {
    fn ratio(&self) -> f64 {
        if self.replicated_fps > 0.0 {
            self.report.fps / self.replicated_fps
        } else {
            0.0
        }
    }

    fn cache_label(&self) -> String {
        self.cache.map_or("replicated".into(), |c| c.to_string())
    }

    /// fps, ratio, miss %, blocks read per frame, the render threads' share of time idle
    /// waiting for blocks, packets set aside per frame, a miss's average wait, remote-read
    /// avg/min/max/p99 µs and the round trip µs: the columns of the table and of the CSV.
    fn figures(&self) -> [f64; 12] {
        let d = self.report.dsm.unwrap_or_default();
        [
            self.report.fps,
            self.ratio(),
            d.miss_percent,
            d.blocks_read_per_frame,
            d.wait_percent,
            d.parked as f64 / self.report.frames.max(1) as f64,
            d.miss_wait_avg_us,
            d.remote_read_avg_us,
            d.remote_read_min_us,
            d.remote_read_max_us,
            d.remote_read_p99_us,
            d.round_trip_us,
        ]
    }

    fn csv(&self) -> String {
        let peak_rss = self
            .report
            .render_nodes
            .iter()
            .map(|n| n.stats.max_rss_bytes)
            .max();
        let places = [3, 3, 4, 0, 2, 1, 1, 1, 1, 1, 1, 1];
        let numbers = places
            .iter()
            .zip(self.figures())
            .map(|(&p, f)| format!("{f:.p$}"))
            .collect::<Vec<_>>()
            .join(",");
        format!(
            "{},{},{},{numbers},{}",
            self.shading.name(),
            self.nodes,
            self.cache_label(),
            peak_rss.unwrap_or(0)
        )
    }
}

/// The wall `args` describe, with `nodes` render nodes, shaded as `shading`, replicated
/// (`cache` None) or shared with a cache of that share of the scene.
async fn measure(
    args: &BenchArgs,
    shading: Shading,
    nodes: u32,
    cache: Option<f32>,
) -> Result<Report> {
    let mut local = args.local.clone();
    local.render_nodes = nodes;
    local.run.out = None;
    local.run.quality.no_shadows = shading == Shading::Cast;
    local.run.quality.ao = if shading == Shading::Ao { 4 } else { 0 };
    match cache {
        None => local.run.data.data = DataMode::Replicated,
        Some(f) => {
            local.run.data.data = DataMode::Dsm;
            local.run.data.cache_fraction = Some(f);
        }
    }
    let what = match cache {
        None => format!("{}, {nodes} render nodes, replicated", shading.name()),
        Some(f) => format!("{}, {nodes} render nodes, cache {f}", shading.name()),
    };
    wall_run(&local, &what).await
}

pub async fn dsm(args: &BenchArgs, out: &Path) -> Result<()> {
    if args.cache_fractions.iter().any(|&f| !(f > 0.0 && f <= 1.0)) {
        bail!("--cache-fractions must lie in (0, 1]");
    }
    let mut caches: Vec<Option<f32>> = vec![None];
    caches.extend(args.cache_fractions.iter().map(|&f| Some(f)));
    let mut rows = Vec::new();
    for &shading in &args.shadings {
        for &nodes in &args.nodes {
            rows.extend(measure_caches(args, shading, nodes, &caches).await?);
        }
    }
    print_table(&rows);
    let first = args.shadings.first().copied().unwrap_or(Shading::Cast);
    let by_nodes_title = format!("frames per second against render nodes ({})", first.name());
    let written = Outputs {
        csv: "dsm.csv",
        header: "shading,render_nodes,cache,fps,fps_vs_replicated,miss_percent,blocks_read_per_frame,wait_percent,parked_per_frame,miss_wait_avg_us,remote_read_avg_us,remote_read_min_us,remote_read_max_us,remote_read_p99_us,round_trip_us,max_rss_bytes",
        rows: rows.iter().map(Row::csv).collect(),
        plots: vec![
            Plot {
                file: "dsm.svg",
                title: "shared over replicated frame rate against the cache (log2 of its share: -3 = 1/8)",
                x_label: "log2(cache / scene)",
                y_label: "fps shared / fps replicated",
                series: by_cache(&rows),
            },
            Plot {
                file: "fps-vs-nodes.svg",
                title: &by_nodes_title,
                x_label: "render nodes",
                y_label: "fps",
                series: by_nodes(&rows, &caches, first),
            },
        ],
        report: json!({
            "experiment": "dsm",
            "scene": args.local.run.scene.scene,
            "repeats": args.repeats,
            "runs": rows.iter().map(|r| json!({
                "shading": r.shading.name(),
                "render_nodes": r.nodes,
                "cache_fraction": r.cache,
                "fps": r.report.fps,
                "fps_vs_replicated": r.ratio(),
                "dsm": r.report.dsm,
                "run": r.report,
            })).collect::<Vec<_>>(),
        }),
    }
    .write(out)?;
    wrote(&written);
    Ok(())
}

/// A row for each of `caches` (replicated first) with `nodes` render nodes shaded as
/// `shading`, each the median of `--repeats` runs.
async fn measure_caches(
    args: &BenchArgs,
    shading: Shading,
    nodes: u32,
    caches: &[Option<f32>],
) -> Result<Vec<Row>> {
    // Every configuration once per round, in turn, so that a slow spell of a shared machine
    // falls on all of them; each keeps its median run.
    let mut runs: Vec<Vec<Report>> = caches.iter().map(|_| Vec::new()).collect();
    for _ in 0..args.repeats {
        for (i, &cache) in caches.iter().enumerate() {
            runs[i].push(measure(args, shading, nodes, cache).await?);
        }
    }
    let medians: Vec<Report> = runs.into_iter().map(median).collect();
    let replicated_fps = medians[0].fps;
    Ok(medians
        .into_iter()
        .zip(caches)
        .map(|(report, &cache)| Row {
            shading,
            nodes,
            cache,
            report,
            replicated_fps,
        })
        .collect())
}

/// Shared over replicated frame rate against log2 of the cache, a line per shading and
/// render-node count.
fn by_cache(rows: &[Row]) -> Vec<Series> {
    rows.iter()
        .filter(|r| r.cache.is_none())
        .map(|base| Series {
            name: format!("{}, {} nodes", base.shading.name(), base.nodes),
            points: rows
                .iter()
                .filter(|r| r.shading == base.shading && r.nodes == base.nodes)
                .filter_map(|r| Some(((r.cache? as f64).log2(), r.ratio())))
                .collect(),
        })
        .collect()
}

/// Frame rate against render nodes of the shading `first`, a line per cache.
fn by_nodes(rows: &[Row], caches: &[Option<f32>], first: Shading) -> Vec<Series> {
    caches
        .iter()
        .map(|&c| Series {
            name: c.map_or("replicated".into(), |f| format!("cache {f}")),
            points: rows
                .iter()
                .filter(|r| r.shading == first && r.cache == c)
                .map(|r| (r.nodes as f64, r.report.fps))
                .collect(),
        })
        .collect()
}

/// The run of median frame rate.
fn median(mut runs: Vec<Report>) -> Report {
    runs.sort_by(|a, b| a.fps.total_cmp(&b.fps));
    let mid = runs.len() / 2;
    runs.swap_remove(mid)
}

/// Table 1's columns, one line a wall.
fn print_table(rows: &[Row]) {
    let columns = [
        ("fps", 7, 2),
        ("ratio", 6, 2),
        ("miss %", 8, 3),
        ("reads/fr", 9, 0),
        ("idle %", 7, 1),
        ("park/fr", 8, 0),
        ("wait µs", 8, 0),
        ("avg µs", 8, 0),
        ("min µs", 7, 0),
        ("max µs", 8, 0),
        ("p99 µs", 8, 0),
        ("rtt µs", 7, 0),
    ];
    let names: String = columns
        .iter()
        .map(|&(n, w, _)| format!(" {n:>w$}"))
        .collect();
    println!("{:<9} {:>5} {:>10}{names}", "shading", "nodes", "cache");
    for r in rows {
        let numbers: String = columns
            .iter()
            .zip(r.figures())
            .map(|(&(_, w, p), f)| format!(" {f:>w$.p$}"))
            .collect();
        println!(
            "{:<9} {:>5} {:>10}{numbers}",
            r.shading.name(),
            r.nodes,
            r.cache_label()
        );
    }
}
