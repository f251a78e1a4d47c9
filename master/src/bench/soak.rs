//! `bench soak`: a local wall at full rate for `--minutes`, one render node killed (SIGKILL)
//! every `--kill-every` seconds and a new one started in its place, which joins the running
//! wall. Reports frames lost (goal 0), every process's resident memory each second (flat
//! after warm-up is the goal) and how long the wall took to present again after each kill.

use super::plot::Series;
use super::{connect_when_up, BenchArgs, Outputs, Plot};
use crate::control::ControlClient;
use crate::wall_run::{run_local_driven, Driver};
use anyhow::{bail, Context, Result};
use serde_json::json;
use std::collections::BTreeMap;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tessera_protocol::control::{ControlReply, ControlRequest};

/// What the driver saw while the wall ran.
#[derive(Default)]
struct SoakLog {
    /// (seconds since the wall started, process name, resident KiB).
    rss: Vec<(f64, String, u64)>,
    /// (seconds since the wall started, seconds until two more frames were presented).
    kills: Vec<(f64, f64)>,
    /// The render nodes started in place of the killed ones, reaped after the run.
    restarted: Vec<tokio::process::Child>,
}

/// The live children of `parent` and what each runs (`render-node`, `display-node`).
fn children(parent: u32) -> Vec<(u32, String)> {
    let mut found = Vec::new();
    for child in tessera_cli::procs::children_of(parent) {
        if child.zombie {
            continue;
        }
        let role = child.args.iter().find(|a| a.ends_with("-node")).cloned();
        let display = child
            .args
            .windows(2)
            .find(|w| w[0] == "--display")
            .map(|w| w[1].clone());
        match (role, display) {
            (Some(r), Some(d)) => found.push((child.pid, format!("{r} {d}"))),
            (Some(r), None) => found.push((child.pid, format!("{r} {}", child.pid))),
            _ => {}
        }
    }
    found
}

fn resident_kib(pid: u32) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = status.lines().find(|l| l.starts_with("VmRSS:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

async fn frames_presented(client: &mut ControlClient) -> Result<u64> {
    match client.ask(ControlRequest::Figures).await? {
        ControlReply::Figures(f) => Ok(f.frames_presented),
        _ => bail!("the master answered a figures request with something else"),
    }
}

fn soak_driver(
    length: Duration,
    kill_every: Duration,
    threads: u32,
    log: Arc<Mutex<SoakLog>>,
) -> Driver {
    Box::new(move |addr, cert_dir| {
        Box::pin(async move {
            let me = std::process::id();
            let soak = Soak {
                me,
                exe: std::env::current_exe()?,
                // The launcher's certificates lie side by side: a render node's serves a new one.
                render_certs: cert_dir
                    .parent()
                    .context("the control certificate has no parent directory")?
                    .join("render-0"),
                threads,
                log,
            };
            let mut client = connect_when_up(&addr, &cert_dir).await;
            wait_for_the_first_frame(&mut client).await?;
            let start = Instant::now();
            let mut next_kill = start + kill_every;
            let mut tick = tokio::time::interval(Duration::from_secs(1));
            loop {
                tick.tick().await;
                let t = start.elapsed().as_secs_f64();
                soak.sample_rss(t);
                if start.elapsed() >= length {
                    // The wall ends as on Ctrl-C: frames in flight finish, nodes report.
                    // SAFETY: kill only sends a signal, here to this process, and touches no
                    // memory.
                    unsafe { libc::kill(me as i32, libc::SIGINT) };
                    return Ok(());
                }
                if Instant::now() < next_kill {
                    continue;
                }
                next_kill += kill_every;
                soak.kill_and_replace(&mut client, &addr, t).await?;
            }
        })
    })
}

/// Waits until the wall presents its first frame: a render node killed while the nodes still
/// load the scene is a node that could not start, which ends a local wall (a busy machine
/// loads for longer than the first --kill-every). Bounded by the default --load-timeout; the
/// master ends the run, and this driver with it, at its own.
async fn wait_for_the_first_frame(client: &mut ControlClient) -> Result<()> {
    let deadline = Instant::now() + Duration::from_secs(600);
    while frames_presented(client).await? == 0 {
        if Instant::now() > deadline {
            bail!("the wall presented no frame in 600 s");
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    Ok(())
}

/// What the soak driver needs to measure the wall's processes and replace its render nodes.
struct Soak {
    /// This process: the master, whose children the nodes are.
    me: u32,
    exe: std::path::PathBuf,
    render_certs: std::path::PathBuf,
    threads: u32,
    log: Arc<Mutex<SoakLog>>,
}

impl Soak {
    /// The log, even if a panic elsewhere poisoned it.
    fn log(&self) -> std::sync::MutexGuard<'_, SoakLog> {
        self.log.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Logs every process's resident memory at `t` seconds.
    fn sample_rss(&self, t: f64) {
        let me = self.me;
        let mut sample = vec![(t, "master".to_string(), resident_kib(me).unwrap_or(0))];
        for (pid, name) in children(me) {
            sample.push((t, name, resident_kib(pid).unwrap_or(0)));
        }
        self.log().rss.extend(sample);
    }

    /// Kills a render node, starts another in its place, and logs how long the wall took to
    /// present two more frames; nothing if no render node is running.
    async fn kill_and_replace(&self, client: &mut ControlClient, addr: &str, t: f64) -> Result<()> {
        let Some((victim, _)) = children(self.me)
            .into_iter()
            .find(|(_, n)| n.starts_with("render-node"))
        else {
            return Ok(());
        };
        let before = frames_presented(client).await?;
        let killed = Instant::now();
        // SAFETY: kill only sends a signal and touches no memory; `victim` is a child of this
        // process, listed just above.
        unsafe { libc::kill(victim as i32, libc::SIGKILL) };
        let child = tokio::process::Command::new(&self.exe)
            .args([
                "render-node",
                "--master",
                addr,
                "--threads",
                &self.threads.to_string(),
            ])
            .arg("--cert-dir")
            .arg(&self.render_certs)
            .stdout(std::process::Stdio::null())
            .kill_on_drop(true)
            .spawn()
            .context("cannot start a render node in place of the killed one")?;
        self.log().restarted.push(child);
        // Recovered once two more frames are presented (bounded).
        let mut recovery = f64::NAN;
        for _ in 0..500 {
            if frames_presented(client).await? >= before + 2 {
                recovery = killed.elapsed().as_secs_f64();
                break;
            }
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        self.log().kills.push((t, recovery));
        Ok(())
    }
}

pub async fn soak(args: &BenchArgs, out: &Path) -> Result<()> {
    let length = Duration::from_secs_f64(args.minutes * 60.0);
    let kill_every = Duration::from_secs_f64(args.kill_every);
    let mut local = args.local.clone();
    local.run.frames = 0;
    let threads = local.threads.unwrap_or(1);
    let log = Arc::new(Mutex::new(SoakLog::default()));
    eprintln!(
        "bench: soak for {:.1} min, a render node killed and replaced every {:.0} s",
        args.minutes, args.kill_every
    );
    let driver = soak_driver(length, kill_every, threads, log.clone());
    let run = run_local_driven(&local, true, Some(driver)).await?;
    let report = run.ended.into_report().context("the soak run failed")?;
    let mut log = std::mem::take(&mut *log.lock().unwrap_or_else(|e| e.into_inner()));
    for child in &mut log.restarted {
        let _ = tokio::time::timeout(Duration::from_secs(10), child.wait()).await;
    }
    let lost = report
        .displays
        .iter()
        .map(|d| report.frames.saturating_sub(d.stats.frames_presented))
        .max()
        .unwrap_or(report.frames);
    write_outputs(out, &report, &log, lost)
}

/// Resident memory of one process, start (after a fifth of the run) against end.
fn growth(points: &[(f64, f64)], warm: f64) -> Option<(f64, f64)> {
    let after: Vec<f64> = points
        .iter()
        .filter(|(t, _)| *t >= warm)
        .map(|p| p.1)
        .collect();
    Some((*after.first()?, *after.last()?))
}

fn write_outputs(
    out: &Path,
    report: &crate::report::Report,
    log: &SoakLog,
    lost: u64,
) -> Result<()> {
    let end = log.rss.last().map_or(0.0, |r| r.0);
    let lasting = lasting_processes(log);
    let memory = memory_growth(&lasting, end);
    let recoveries: Vec<f64> = log.kills.iter().map(|k| k.1).collect();
    let worst = recoveries.iter().copied().fold(0.0, f64::max);
    let written = Outputs {
        csv: "soak.csv",
        header: "seconds,process,rss_kib",
        rows: log
            .rss
            .iter()
            .map(|(t, n, k)| format!("{t:.1},{n},{k}"))
            .collect(),
        plots: vec![Plot {
            file: "soak.svg",
            title: "resident memory over the soak",
            x_label: "seconds",
            y_label: "MiB",
            series: lasting
                .iter()
                .map(|(n, p)| Series {
                    name: n.to_string(),
                    points: p.clone(),
                })
                .collect(),
        }],
        report: json!({
            "experiment": "soak",
            "seconds": end,
            "frames": report.frames,
            "frames_lost": lost,
            "fps": report.fps,
            "render_nodes_killed": log.kills.len(),
            "recovery_s": recoveries,
            "recovery_s_max": worst,
            "memory": memory,
            "frame_ms": report.frame_ms,
            "tiles_speculated": report.tiles_speculated,
        }),
    }
    .write(out)?;
    println!(
        "soak: {:.0} s, {} frames at {:.1} fps, {lost} lost; {} render nodes killed and replaced, \
         longest recovery {:.3} s",
        end,
        report.frames,
        report.fps,
        log.kills.len(),
        worst
    );
    print_memory(&memory);
    println!("wrote {}, soak.csv and soak.svg", written[0].display());
    Ok(())
}

/// A line per process of [`memory_growth`]: its memory after warm-up and at the end.
fn print_memory(memory: &[serde_json::Value]) {
    for m in memory {
        println!(
            "  {}: {:.1} MiB after warm-up, {:.1} MiB at the end",
            m["process"].as_str().unwrap_or("?"),
            m["mib_after_warm_up"].as_f64().unwrap_or(0.0),
            m["mib_at_end"].as_f64().unwrap_or(0.0)
        );
    }
}

/// Resident MiB over time of the processes that lived through the run: the master and the
/// displays.
fn lasting_processes(log: &SoakLog) -> Vec<(&str, Vec<(f64, f64)>)> {
    let mut by_process: BTreeMap<&str, Vec<(f64, f64)>> = BTreeMap::new();
    for (t, name, kib) in &log.rss {
        by_process
            .entry(name)
            .or_default()
            .push((*t, *kib as f64 / 1024.0));
    }
    by_process
        .into_iter()
        .filter(|(n, _)| *n == "master" || n.starts_with("display-node"))
        .collect()
}

/// Each process's memory after warm-up (a fifth of the `end` seconds) and at the end.
fn memory_growth(lasting: &[(&str, Vec<(f64, f64)>)], end: f64) -> Vec<serde_json::Value> {
    lasting
        .iter()
        .filter_map(|(n, p)| {
            let (first, last) = growth(p, end * 0.2)?;
            Some(json!({"process": n, "mib_after_warm_up": first, "mib_at_end": last, "ratio": last / first}))
        })
        .collect()
}
