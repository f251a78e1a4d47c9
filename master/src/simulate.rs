//! `tessera-master simulate`: a whole wall in this process on a virtual clock, driving the real
//! load balancer and frame barrier (see `tessera_core::sim` for the model).

use anyhow::{bail, Context, Result};
use serde::Serialize;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};
use tessera_core::balance::BalanceConfig;
use tessera_core::sim::{near_square_wall, NodeSpeeds, PixelCheck, SimConfig, SimReport, SimWall};
use tessera_model::wall::{parse_size, WallLayout, DEFAULT_TILE_SIZE};
use tessera_protocol::{FrameId, RenderNodeId};

#[derive(clap::Args, Debug)]
pub struct SimulateArgs {
    /// Virtual render nodes.
    #[arg(long, default_value_t = 512)]
    render_nodes: u32,
    /// Virtual display nodes, one screen each, laid out as a near-square grid (64 → 8x8).
    #[arg(long, default_value_t = 64)]
    displays: u32,
    /// Frames to run.
    #[arg(long, default_value_t = 100)]
    frames: u64,
    /// Probability (0 ≤ p < 1) that one transmission of a message is lost; QUIC retransmits it
    /// after a timeout, so loss costs time, never data.
    #[arg(long, default_value_t = 0.0, value_parser = parse_loss)]
    loss: f64,
    /// Render node N dies shortly after frame F starts, holding unfinished tiles (N@F,
    /// repeatable; N counts from 0).
    #[arg(long = "kill", value_name = "N@F", value_parser = parse_kill)]
    kills: Vec<Kill>,
    /// Seed of the jitter, loss and node speeds: the same seed replays the same run.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// One-way latency of every link in microseconds (jitter adds up to half of it).
    #[arg(long, default_value_t = 50)]
    latency_us: u64,
    /// Pixels of one screen.
    #[arg(long, default_value = "1920x1080", value_parser = parse_screen)]
    screen: (u32, u32),
    /// Edge length of a tile in pixels (`--tile` as on `local`).
    #[arg(long, alias = "tile", default_value_t = DEFAULT_TILE_SIZE)]
    tile_size: u32,
    /// Microseconds the fastest render node takes for a full tile.
    #[arg(long, default_value_t = 100)]
    tile_us: u64,
    /// The slowest render node is up to this many times slower than the fastest (seeded,
    /// uniform in between; 1 = all alike).
    #[arg(long, default_value_t = 3.0, value_parser = parse_spread)]
    speed_spread: f64,
    /// Assemble and check every pixel of every screen instead of one pixel per tile (same
    /// messages and timing, much more memory and time on big walls).
    #[arg(long)]
    full_pixels: bool,
    /// Directory to write report.json into.
    #[arg(long)]
    out: Option<PathBuf>,
    /// A wall file (a grid, or physical screens such as deploy/walls/reality-deck.toml) in
    /// place of --displays, --screen and --tile-size.
    #[arg(long, conflicts_with_all = ["displays", "screen", "tile_size"])]
    wall_file: Option<PathBuf>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Kill {
    node: u32,
    frame: u64,
}

fn parse_loss(text: &str) -> Result<f64, String> {
    let p: f64 = text
        .parse()
        .map_err(|_| format!("`{text}` is not a number"))?;
    if !(0.0..1.0).contains(&p) {
        return Err(format!(
            "{p} is not a probability in [0, 1) (1 would lose every message for ever)"
        ));
    }
    Ok(p)
}

fn parse_kill(text: &str) -> Result<Kill, String> {
    let bad = || format!("`{text}` is not N@F (render node N dies at frame F), e.g. 5@10");
    let (n, f) = text.split_once('@').ok_or_else(bad)?;
    Ok(Kill {
        node: n.trim().parse().map_err(|_| bad())?,
        frame: f.trim().parse().map_err(|_| bad())?,
    })
}

fn parse_screen(text: &str) -> Result<(u32, u32), String> {
    let (w, h) = parse_size(text).map_err(|e| e.to_string())?;
    if w == 0 || h == 0 {
        return Err(format!("screen {w}x{h} has no pixels"));
    }
    Ok((w, h))
}

fn parse_spread(text: &str) -> Result<f64, String> {
    let s: f64 = text
        .parse()
        .map_err(|_| format!("`{text}` is not a number"))?;
    if !(1.0..=1000.0).contains(&s) {
        return Err(format!("{s} is not a speed ratio between 1 and 1000"));
    }
    Ok(s)
}

/// report.json: the simulator's figures and what produced them.
#[derive(Serialize)]
struct Report<'a> {
    #[serde(flatten)]
    sim: &'a SimReport,
    seed: u64,
    screen_width: u32,
    screen_height: u32,
    columns: u32,
    rows: u32,
    tile_size: u32,
    tile_us: u64,
    speed_spread: f64,
    kills: Vec<String>,
    /// Wall-clock seconds the simulation took on this machine.
    run_time_s: f64,
}

/// Bounds of the simulation's flags: far beyond any wall, yet small enough that the virtual
/// clock (µs in a u64) and the event budget cannot overflow.
const MAX_RENDER_NODES: u32 = 100_000;
const MAX_FRAMES: u64 = 1_000_000;
/// Ten seconds, for latencies and per-tile times alike.
const MAX_MICROS: u64 = 10_000_000;

fn check(args: &SimulateArgs) -> Result<()> {
    for (flag, value, min, max) in [
        (
            "--render-nodes",
            args.render_nodes as u64,
            1,
            MAX_RENDER_NODES as u64,
        ),
        ("--displays", args.displays as u64, 1, u32::MAX as u64),
        ("--frames", args.frames, 1, MAX_FRAMES),
        ("--tile-size", args.tile_size as u64, 1, u32::MAX as u64),
        ("--tile-us", args.tile_us, 1, MAX_MICROS),
        ("--latency-us", args.latency_us, 0, MAX_MICROS),
    ] {
        if !(min..=max).contains(&value) {
            bail!("{flag} {value} must be from {min} to {max}");
        }
    }
    let mut killed = Vec::new();
    for k in &args.kills {
        if k.node >= args.render_nodes {
            bail!(
                "--kill {}@{}: there is no render node {} (nodes are 0..{})",
                k.node,
                k.frame,
                k.node,
                args.render_nodes
            );
        }
        if k.frame >= args.frames {
            bail!(
                "--kill {}@{}: frame {} is not one of the {} frames (0..{})",
                k.node,
                k.frame,
                k.frame,
                args.frames,
                args.frames
            );
        }
        if killed.contains(&k.node) {
            bail!("--kill: render node {} is killed twice", k.node);
        }
        killed.push(k.node);
    }
    if killed.len() >= args.render_nodes as usize {
        bail!(
            "--kill would kill all {} render nodes; at least one must survive to finish the frames",
            args.render_nodes
        );
    }
    Ok(())
}

pub fn simulate(args: SimulateArgs) -> Result<ExitCode> {
    check(&args)?;
    let wall = wall_of(&args)?;
    let t0 = Instant::now();
    let mut sim = SimWall::with_config(args.seed, wall.clone(), &config_of(&args));
    for k in &args.kills {
        sim.kill_at(RenderNodeId(k.node), FrameId(k.frame));
    }
    let mut progress = Progress::new(args.frames, t0);
    sim.run_frames_reporting(args.frames, |presented| {
        progress.update(presented, Instant::now())
    });
    progress.bar.finish_and_clear();
    let run_time_s = t0.elapsed().as_secs_f64();
    let r = sim.report();
    print_summary(&r, &wall, run_time_s);
    if let Some(dir) = &args.out {
        write_report(dir, &args, &wall, &r, run_time_s)?;
    }
    if r.frames_completed < r.frames_requested || r.corrupt_frames > 0 {
        bail!(
            "the simulated wall completed {} of {} frames with {} corrupt frames",
            r.frames_completed,
            r.frames_requested,
            r.corrupt_frames
        );
    }
    Ok(ExitCode::SUCCESS)
}

/// How far a run is, on stderr: a bar on a terminal; in a log (stderr not a terminal), a line
/// at each tenth of the frames and at least every [`Progress::EVERY`], so a long run shows it is
/// moving.
struct Progress {
    bar: indicatif::ProgressBar,
    terminal: bool,
    frames: u64,
    start: Instant,
    last_line: Instant,
    /// Tenths of the frames presented when the last line was written.
    tenths: u64,
}

impl Progress {
    const EVERY: Duration = Duration::from_secs(5);

    fn new(frames: u64, start: Instant) -> Progress {
        let terminal = std::io::stderr().is_terminal();
        let bar = if terminal {
            indicatif::ProgressBar::new(frames).with_style(
                indicatif::ProgressStyle::with_template(
                    "simulate: {bar:40} {pos}/{len} frames presented {elapsed_precise}",
                )
                .expect("valid template"),
            )
        } else {
            indicatif::ProgressBar::hidden()
        };
        Progress {
            bar,
            terminal,
            frames,
            start,
            last_line: start,
            tenths: 0,
        }
    }

    /// `presented` frames are done at `now`.
    fn update(&mut self, presented: u64, now: Instant) {
        self.bar.set_position(presented);
        if !self.terminal {
            if let Some(line) = self.line(presented, now) {
                eprintln!("{line}");
            }
        }
    }

    /// The log line due at `now` with `presented` frames done, if one is.
    fn line(&mut self, presented: u64, now: Instant) -> Option<String> {
        let tenths = presented.saturating_mul(10) / self.frames.max(1);
        if tenths <= self.tenths && now.duration_since(self.last_line) < Self::EVERY {
            return None;
        }
        self.tenths = self.tenths.max(tenths);
        self.last_line = now;
        Some(format!(
            "simulate: {presented} of {} frames presented ({} %), {:.1} s",
            self.frames,
            presented.saturating_mul(100) / self.frames.max(1),
            now.duration_since(self.start).as_secs_f64()
        ))
    }
}

/// The wall of --wall-file, or else a near-square grid of --displays screens.
fn wall_of(args: &SimulateArgs) -> Result<WallLayout> {
    let (width, height) = args.screen;
    Ok(match &args.wall_file {
        Some(path) => tessera_cli::wall_file::read_layout(path)?,
        None => near_square_wall(args.displays, width, height, args.tile_size)
            .with_context(|| format!("a wall of {} displays of {width}x{height}", args.displays))?,
    })
}

/// The simulator's model as the flags set it.
fn config_of(args: &SimulateArgs) -> SimConfig {
    SimConfig {
        render_nodes: args.render_nodes,
        speeds: NodeSpeeds::Spread {
            fastest_us: args.tile_us,
            spread: args.speed_spread,
        },
        latency_us: args.latency_us,
        loss: args.loss,
        pixels: if args.full_pixels {
            PixelCheck::Full
        } else {
            PixelCheck::OnePerTile
        },
        balance: BalanceConfig::default(),
        ..SimConfig::new(args.render_nodes)
    }
}

/// The wall's shape and a line for each of the run's figures.
fn print_summary(r: &SimReport, wall: &WallLayout, run_time_s: f64) {
    let shape = match wall.grid_spec() {
        Some(g) => format!(
            "a {}x{} grid of {}x{}",
            g.columns, g.rows, g.screen_width, g.screen_height
        ),
        None => format!(
            "screens of {:.2} gigapixels in all",
            wall.visible_pixels() as f64 / 1e9
        ),
    };
    println!(
        "simulated {} render nodes, {} displays ({shape}, {} tiles of {} px a frame), {} frames",
        r.render_nodes,
        r.displays,
        r.tiles_per_frame,
        wall.tile_size(),
        r.frames_requested
    );
    for (name, value) in summary_rows(r, run_time_s) {
        println!("  {name:<20} {value}");
    }
}

/// The summary's lines: a figure's name and its values.
fn summary_rows(r: &SimReport, run_time_s: f64) -> [(&'static str, String); 8] {
    let b = r.busy_fraction;
    [
        (
            "frames completed",
            format!("{} of {} on every display", r.frames_completed, r.frames_requested),
        ),
        (
            "balance efficiency",
            format!(
                "{:.2} % mean, {:.2} % min",
                100.0 * r.efficiency,
                100.0 * r.efficiency_min
            ),
        ),
        (
            "busy fraction",
            format!(
                "min {:.3}  p10 {:.3}  p50 {:.3}  p90 {:.3}  max {:.3}",
                b.min, b.p10, b.p50, b.p90, b.max
            ),
        ),
        (
            "virtual time",
            format!(
                "{:.4} s to the last present, {:.1} frames/s",
                r.elapsed_s, r.fps
            ),
        ),
        (
            "network",
            format!(
                "{} messages, {} retransmissions (loss {}, latency {} us)",
                r.messages, r.retransmissions, r.loss, r.latency_us
            ),
        ),
        (
            "node deaths",
            format!(
                "{} killed; {} duplicate tiles, {} late tiles ({} from live nodes), {} pixel batches lost with their sender",
                r.render_nodes_killed,
                r.duplicate_tiles,
                r.late_tiles,
                r.late_tiles_from_live_nodes,
                r.pixel_batches_lost_with_sender
            ),
        ),
        ("corrupt frames", r.corrupt_frames.to_string()),
        (
            "run time",
            format!("{run_time_s:.2} s wall clock, {} events", r.events),
        ),
    ]
}

/// Writes report.json into `dir`, creating it.
fn write_report(
    dir: &Path,
    args: &SimulateArgs,
    wall: &WallLayout,
    r: &SimReport,
    run_time_s: f64,
) -> Result<()> {
    std::fs::create_dir_all(dir)
        .with_context(|| format!("cannot create --out {}", dir.display()))?;
    let (screen_width, screen_height) = args.screen;
    let report = Report {
        sim: r,
        seed: args.seed,
        screen_width,
        screen_height,
        columns: wall.columns(),
        rows: wall.rows(),
        tile_size: wall.tile_size(),
        tile_us: args.tile_us,
        speed_spread: args.speed_spread,
        kills: args
            .kills
            .iter()
            .map(|k| format!("{}@{}", k.node, k.frame))
            .collect(),
        run_time_s,
    };
    let path = dir.join("report.json");
    std::fs::write(&path, serde_json::to_string_pretty(&report)?)
        .with_context(|| format!("cannot write {}", path.display()))?;
    eprintln!("wrote {}", path.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn simulate_shows_progress_in_a_log_each_tenth_and_every_five_seconds() {
        let t0 = Instant::now();
        let mut p = Progress::new(200, t0);
        let at = |s: u64| t0 + Duration::from_secs(s);
        assert_eq!(p.line(5, at(1)), None, "under a tenth, under 5 s");
        let line = p.line(20, at(2)).expect("a tenth of the frames");
        assert!(line.contains("20 of 200 frames presented (10 %)"), "{line}");
        assert_eq!(p.line(21, at(3)), None, "the same tenth");
        let slow = p.line(22, at(8)).expect("5 s since the last line");
        assert!(
            slow.contains("22 of 200") && slow.contains("8.0 s"),
            "{slow}"
        );
        assert!(p.line(200, at(9)).unwrap().contains("(100 %)"));
    }

    #[test]
    fn kills_and_losses_are_parsed_or_refused_with_the_reason() {
        assert_eq!(parse_kill("5@10"), Ok(Kill { node: 5, frame: 10 }));
        assert!(parse_kill("5").unwrap_err().contains("N@F"));
        assert!(parse_kill("x@1").is_err());
        assert_eq!(parse_loss("0.01"), Ok(0.01));
        assert!(parse_loss("1").unwrap_err().contains("[0, 1)"));
        assert!(parse_loss("-0.1").is_err());
        assert!(parse_loss("NaN").is_err());
    }

    #[test]
    fn the_tile_flag_is_named_as_on_local_and_a_wall_file_sets_the_tile() {
        use clap::Parser;
        #[derive(Parser)]
        struct Cli {
            #[command(flatten)]
            sim: SimulateArgs,
        }
        let parse = |args: &[&str]| Cli::try_parse_from(std::iter::once("t").chain(args.to_vec()));
        assert_eq!(parse(&[]).unwrap().sim.tile_size, DEFAULT_TILE_SIZE);
        assert_eq!(parse(&["--tile-size", "32"]).unwrap().sim.tile_size, 32);
        assert_eq!(parse(&["--tile", "16"]).unwrap().sim.tile_size, 16);
        // It used to be ignored beside a wall file, which sets the tiles itself.
        assert!(parse(&["--wall-file", "w.toml", "--tile-size", "32"]).is_err());
    }
}
