//! Processes and the processes a process started, read from Linux's `/proc`: what a local wall's master
//! watches of its nodes (the soak benchmark's victims and memory samples) and what the tests
//! check is gone when a wall ends. Elsewhere the list is empty.

/// A process, its parent and its command line.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Process {
    /// Its process id.
    pub pid: u32,
    /// Its parent's process id (0 for one the kernel started); `None` if `/proc` did not say.
    pub parent: Option<u32>,
    /// Exited, not yet reaped.
    pub zombie: bool,
    /// Its command line, word by word. Empty for a moment after the process execs: the
    /// parent of a vfork-style spawn resumes once the new image is mapped, before the kernel
    /// has set its arguments, so one just started may be listed without them.
    pub args: Vec<String>,
}

impl Process {
    /// Whether one of its words is `word` (a subcommand such as `render-node`).
    pub fn runs(&self, word: &str) -> bool {
        self.args.iter().any(|a| a == word)
    }
}

/// The children of `parent` now.
pub fn children_of(parent: u32) -> Vec<Process> {
    let mut found = processes();
    found.retain(|p| p.parent == Some(parent));
    found
}

/// Every process now (those that end while the list is read are left out).
pub fn processes() -> Vec<Process> {
    let mut found = Vec::new();
    for entry in std::fs::read_dir("/proc").into_iter().flatten().flatten() {
        let Ok(pid) = entry.file_name().to_string_lossy().parse::<u32>() else {
            continue;
        };
        let Ok(stat) = std::fs::read_to_string(entry.path().join("stat")) else {
            continue;
        };
        // The fields after the command name, which may hold spaces and parentheses.
        let after = stat.rsplit_once(") ").map_or("", |(_, rest)| rest);
        let mut fields = after.split_whitespace();
        let (state, parent) = (fields.next(), fields.next().and_then(|p| p.parse().ok()));
        let cmdline = std::fs::read(entry.path().join("cmdline")).unwrap_or_default();
        let args = String::from_utf8_lossy(&cmdline)
            .split_terminator('\0')
            .map(str::to_string)
            .collect();
        found.push(Process {
            pid,
            parent,
            zombie: state == Some("Z"),
            args,
        });
    }
    found
}

/// The UDP ports process `pid`'s sockets are bound to: how a local wall's launcher tells which
/// of its children the master saw join from `127.0.0.1:PORT` (a QUIC endpoint is one UDP
/// socket). Empty for a process that is gone, or off Linux.
pub fn udp_ports(pid: u32) -> Vec<u16> {
    let proc_dir = std::path::PathBuf::from(format!("/proc/{pid}"));
    let inodes: Vec<u64> = std::fs::read_dir(proc_dir.join("fd"))
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|fd| std::fs::read_link(fd.path()).ok())
        .filter_map(|target| {
            let target = target.to_string_lossy().into_owned();
            target
                .strip_prefix("socket:[")?
                .strip_suffix(']')?
                .parse()
                .ok()
        })
        .collect();
    let mut ports = Vec::new();
    for table in ["udp", "udp6"] {
        let text = std::fs::read_to_string(proc_dir.join("net").join(table)).unwrap_or_default();
        // `sl local_address rem_address st tx_queue:rx_queue tr:tm->when retrnsmt uid timeout
        // inode ...`, the address as HEXIP:HEXPORT.
        for line in text.lines().skip(1) {
            let fields: Vec<&str> = line.split_whitespace().collect();
            let (Some(local), Some(inode)) = (fields.get(1), fields.get(9)) else {
                continue;
            };
            let port = local
                .rsplit_once(':')
                .and_then(|(_, p)| u16::from_str_radix(p, 16).ok());
            if let (Some(port), Ok(inode)) = (port, inode.parse::<u64>()) {
                if inodes.contains(&inode) {
                    ports.push(port);
                }
            }
        }
    }
    ports
}

#[cfg(all(test, target_os = "linux"))]
mod tests {
    use super::*;

    #[test]
    fn a_started_child_is_found_with_its_arguments_and_then_as_a_zombie() {
        let mut child = std::process::Command::new("sleep")
            .arg("30")
            .spawn()
            .expect("sleep");
        let me = std::process::id();
        // Listed with its arguments once the kernel has set them (see `Process::args`), within
        // a bounded wait; never as anything but a live child.
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
        loop {
            let found = children_of(me);
            let it = found.iter().find(|c| c.pid == child.id()).expect("listed");
            assert!(!it.zombie, "{it:?}");
            if it.runs("30") {
                break;
            }
            assert!(it.args.is_empty(), "{it:?}");
            assert!(std::time::Instant::now() < deadline, "never its arguments");
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        child.kill().unwrap();
        // Killed but not reaped: a zombie, within a bounded wait for the kernel to say so.
        while !children_of(me)
            .iter()
            .any(|c| c.pid == child.id() && c.zombie)
        {
            assert!(std::time::Instant::now() < deadline, "never a zombie");
            std::thread::sleep(std::time::Duration::from_millis(10));
        }
        child.wait().unwrap();
        assert!(!children_of(me).iter().any(|c| c.pid == child.id()));
    }

    #[test]
    fn the_ports_of_this_process_udp_sockets_are_found() {
        let socket = std::net::UdpSocket::bind("127.0.0.1:0").expect("a UDP socket");
        let port = socket.local_addr().unwrap().port();
        assert!(udp_ports(std::process::id()).contains(&port));
        drop(socket);
        assert!(!udp_ports(std::process::id()).contains(&port));
    }
}
