//! `deploy/slurm/tessera-wall.sbatch` on a one-node Slurm cluster of the test's own: munged,
//! slurmctld and slurmd started in a temporary directory (their configuration, state, sockets
//! and ports all there and on loopback, nothing in /etc), a 2x1 wall submitted with
//! `sbatch --wait`, its report checked, and nothing left running. Needs root and Debian's
//! slurm-wlm and munge (which `.ci/run` installs); skipped, saying why, elsewhere.

use std::io::Read;
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::time::Duration;
use tessera_tests::*;

const TEST: &str = "slurm_runs_a_wall_from_the_batch_script";

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn free_port() -> u16 {
    let listener = TcpListener::bind("127.0.0.1:0").expect("bind a free port");
    listener.local_addr().unwrap().port()
}

/// A one-node cluster; dropping it (also when an assertion fails) cancels its jobs and stops
/// and reaps its three daemons.
struct Cluster {
    dir: tempfile::TempDir,
    conf: PathBuf,
    tools: Vec<PathBuf>,
    daemons: Vec<Proc>,
}

/// The tools, in the order [`Cluster::tool`] reads them.
const TOOLS: [&str; 7] = [
    "munged",
    "slurmctld",
    "slurmd",
    "sbatch",
    "sinfo",
    "scancel",
    "squeue",
];

impl Cluster {
    fn start(tools: Vec<PathBuf>) -> Cluster {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        for sub in ["state", "spool", "job"] {
            std::fs::create_dir(d.join(sub)).unwrap();
        }
        let mut key = vec![0u8; 128];
        std::fs::File::open("/dev/urandom")
            .and_then(|mut f| f.read_exact(&mut key))
            .expect("random bytes for the munge key");
        let key_path = d.join("munge.key");
        std::fs::write(&key_path, key).unwrap();
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&key_path, std::fs::Permissions::from_mode(0o600)).unwrap();
        let conf = d.join("slurm.conf");
        std::fs::write(&conf, slurm_conf(d)).unwrap();
        let mut cluster = Cluster {
            conf,
            tools,
            daemons: Vec::new(),
            dir,
        };
        let d = cluster.dir.path().to_path_buf();
        let p = |name: &str| d.join(name).display().to_string();
        let munged = Proc::start_program(
            cluster.tool("munged"),
            "munged",
            &[
                "--foreground",
                // As root, in a directory of the test's own, which munged would refuse.
                "--force",
                &format!("--socket={}", p("munge.sock")),
                &format!("--key-file={}", p("munge.key")),
                &format!("--log-file={}", p("munged.log")),
                &format!("--pid-file={}", p("munged.pid")),
                &format!("--seed-file={}", p("munged.seed")),
            ],
            &[],
        );
        assert!(
            wait_for(Duration::from_secs(20), || d.join("munge.sock").exists()),
            "munged made no socket"
        );
        cluster.daemons.push(munged);
        let conf = cluster.conf.display().to_string();
        let env = [("SLURM_CONF", conf.as_str())];
        let ctld = Proc::start_program(
            cluster.tool("slurmctld"),
            "slurmctld",
            &["-D", "-f", &conf],
            &env,
        );
        cluster.daemons.push(ctld);
        let slurmd = Proc::start_program(
            cluster.tool("slurmd"),
            "slurmd",
            &["-D", "-N", "tessera-test", "-f", &conf],
            &env,
        );
        cluster.daemons.push(slurmd);
        let idle = wait_for(Duration::from_secs(30), || {
            cluster
                .client("sinfo", &["-h", "-o", "%t"], &[], Duration::from_secs(15))
                .stdout
                .trim()
                == "idle"
        });
        assert!(idle, "the node never became idle:\n{}", cluster.logs());
        cluster
    }

    fn tool(&self, name: &str) -> &Path {
        let i = TOOLS.iter().position(|t| *t == name).expect("a known tool");
        &self.tools[i]
    }

    /// Runs a Slurm client command against this cluster within `limit`.
    fn client(&self, name: &str, args: &[&str], env: &[(&str, &str)], limit: Duration) -> Output {
        let conf = self.conf.display().to_string();
        let mut all = vec![("SLURM_CONF", conf.as_str())];
        all.extend(env);
        Proc::start_program(self.tool(name), name, args, &all).wait(limit)
    }

    fn logs(&self) -> String {
        let mut text = String::new();
        for log in ["slurmctld.log", "slurmd.log", "munged.log"] {
            let body = std::fs::read_to_string(self.dir.path().join(log)).unwrap_or_default();
            let tail: Vec<&str> = body.lines().rev().take(30).collect();
            text += &format!(
                "--- {log} (last lines, newest first)\n{}\n",
                tail.join("\n")
            );
        }
        text
    }
}

impl Drop for Cluster {
    fn drop(&mut self) {
        // A job still running would outlive slurmd (slurmstepd is not its child): cancel it
        // and wait, bounded, until the queue is empty.
        if self.daemons.len() == 3 {
            let _ = self.client(
                "scancel",
                &["--full", "--user", "root"],
                &[],
                Duration::from_secs(15),
            );
            wait_for(Duration::from_secs(30), || {
                self.client("squeue", &["-h"], &[], Duration::from_secs(15))
                    .stdout
                    .trim()
                    .is_empty()
            });
        }
        // slurmd, slurmctld, then munged: asked to stop, then killed (Proc's drop) and reaped.
        while let Some(daemon) = self.daemons.pop() {
            daemon.signal(libc::SIGTERM);
            wait_for(Duration::from_secs(10), || daemon.has_exited());
        }
    }
}

fn slurm_conf(dir: &Path) -> String {
    let host = std::fs::read_to_string("/proc/sys/kernel/hostname")
        .unwrap()
        .trim()
        .to_string();
    let short = host.split('.').next().unwrap().to_string();
    let cpus = std::thread::available_parallelism().map_or(1, |n| n.get());
    let d = dir.display();
    format!(
        "ClusterName=tessera-test
SlurmctldHost={short}(127.0.0.1)
SlurmctldPort={ctld}
SlurmdPort={slurmd}
AuthType=auth/munge
AuthInfo=socket={d}/munge.sock
CredType=cred/munge
SlurmUser=root
SlurmdUser=root
StateSaveLocation={d}/state
SlurmdSpoolDir={d}/spool
SlurmctldPidFile={d}/slurmctld.pid
SlurmdPidFile={d}/slurmd.pid
SlurmctldLogFile={d}/slurmctld.log
SlurmdLogFile={d}/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
SchedulerType=sched/builtin
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
MpiDefault=none
ReturnToService=2
NodeName=tessera-test NodeHostname={short} NodeAddr=127.0.0.1 CPUs={cpus} State=UNKNOWN
PartitionName=wall Nodes=tessera-test Default=YES MaxTime=10 State=UP OverSubscribe=YES
",
        ctld = free_port(),
        slurmd = free_port(),
    )
}

#[test]
fn slurm_runs_a_wall_from_the_batch_script() {
    slurm_wall(false);
}

/// `TESSERA_STANDBY=1`: rank 1 runs a standby master that follows the primary's whole run and
/// leaves with it, and the nodes are given both masters.
#[test]
fn slurm_runs_a_wall_with_a_standby_master() {
    slurm_wall(true);
}

/// Runs a 2x1 wall of 20 frames from the batch script, with a standby master or without.
fn slurm_wall(standby: bool) {
    if !is_root() {
        skip(
            TEST,
            "not root (munged, slurmctld and slurmd run as root here)",
        );
        return;
    }
    let Some(tools) = require_tools(TEST, &TOOLS, "apt-get install slurm-wlm munge") else {
        return;
    };
    let cluster = Cluster::start(tools);
    let job_dir = cluster.dir.path().join("job");
    let script = repo().join("deploy/slurm/tessera-wall.sbatch");
    let master = bin("tessera-master");
    let frames = 20u64;
    let ntasks = format!("--ntasks={}", 4 + u32::from(standby));
    let o = cluster.client(
        "sbatch",
        &[
            "--wait",
            // 1 master [+ 1 standby] + 1 render node + 2 displays on a node of fewer cores.
            &ntasks,
            "--overcommit",
            "--time=2",
            &format!("--chdir={}", job_dir.display()),
            &format!("--output={}/slurm-%j.out", job_dir.display()),
            script.to_str().unwrap(),
        ],
        &[
            ("TESSERA_BIN", master.to_str().unwrap()),
            ("TESSERA_WALL", "2x1"),
            ("TESSERA_SCREEN", "160x90"),
            ("TESSERA_FRAMES", &frames.to_string()),
            ("TESSERA_THREADS", "1"),
            // The kernel picks the master's port: nothing else on this machine is disturbed.
            ("TESSERA_PORT", "0"),
            ("TESSERA_JOIN_TIMEOUT", "60"),
            ("TESSERA_STANDBY", if standby { "1" } else { "0" }),
        ],
        Duration::from_secs(150),
    );
    let job_id = o
        .stdout
        .split_whitespace()
        .last()
        .and_then(|w| w.parse::<u64>().ok())
        .unwrap_or_else(|| panic!("no job id from sbatch: {}\n{}", o.stdout, o.stderr));
    let job_out =
        std::fs::read_to_string(job_dir.join(format!("slurm-{job_id}.out"))).unwrap_or_default();
    let run_dir = job_dir.join(format!("tessera-{job_id}"));
    let master_log = std::fs::read_to_string(run_dir.join("logs/master.log")).unwrap_or_default();
    assert!(
        o.status.success(),
        "the job failed ({}): {}\njob output:\n{job_out}\nmaster log:\n{master_log}\n{}",
        o.status,
        o.stderr,
        cluster.logs()
    );

    let report = read_json(&run_dir.join("out/report.json"));
    assert_eq!(report["frames"].as_u64(), Some(frames), "{job_out}");
    let displays = report["displays"].as_array().unwrap();
    assert_eq!(displays.len(), 2);
    for d in displays {
        assert_eq!(d["frames_presented"].as_u64(), Some(frames), "{d}");
    }
    assert_eq!(report["render_nodes"].as_array().unwrap().len(), 1);
    assert!(job_out.contains("report:"), "{job_out}");
    if standby {
        let log = std::fs::read_to_string(run_dir.join("logs/standby.log")).unwrap_or_default();
        assert!(master_log.contains("standby master at"), "{master_log}");
        assert!(log.contains("the primary's run is over"), "{log}");
    }
    // The run's CA and certificates are gone with the job.
    assert!(!run_dir.join("certs").exists() && !run_dir.join("cluster").exists());
    // Every node's command line names its certificate in the run directory.
    let run_path = run_dir.display().to_string();
    let gone = wait_for(Duration::from_secs(20), || {
        processes_mentioning(&run_path).is_empty()
            && processes_mentioning("deploy/slurm/rank.sh").is_empty()
    });
    assert!(
        gone,
        "processes left behind: {:?} {:?}",
        processes_mentioning(&run_path),
        processes_mentioning("deploy/slurm/rank.sh")
    );
    drop(cluster);
}
