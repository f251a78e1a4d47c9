//! Where a local wall leaves what a second terminal needs to steer it: the master's address,
//! a control certificate and the console's address and token, in this user's state folder
//! (`$TESSERA_STATE_DIR`, else `$XDG_STATE_HOME/tessera`, else `~/.local/state/tessera`),
//! so that `tessera-master control` finds them without being told. The newest local wall's
//! file wins; it is removed when that wall ends.

use anyhow::{bail, Context, Result};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// What `local` writes and `control` reads.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LocalWall {
    /// The master's QUIC address, HOST:PORT.
    pub connect: String,
    /// The control certificate's folder.
    pub cert_dir: PathBuf,
    /// The console's address with its token, if one is served.
    pub console_url: Option<String>,
    /// The console's token, for `Authorization: Bearer`.
    pub token: Option<String>,
    /// The master's process id: a file left by a wall that died is told from a live one.
    pub pid: u32,
}

/// This user's Tessera state folder.
pub fn state_dir() -> Result<PathBuf> {
    if let Some(dir) = std::env::var_os("TESSERA_STATE_DIR") {
        return Ok(PathBuf::from(dir));
    }
    if let Some(dir) = std::env::var_os("XDG_STATE_HOME").filter(|d| !d.is_empty()) {
        return Ok(PathBuf::from(dir).join("tessera"));
    }
    let home = std::env::var_os("HOME")
        .context("neither TESSERA_STATE_DIR, XDG_STATE_HOME nor HOME is set")?;
    Ok(PathBuf::from(home).join(".local/state/tessera"))
}

/// The local wall's file, and the folder this process's control certificate goes in.
pub fn local_paths() -> Result<(PathBuf, PathBuf)> {
    let dir = state_dir()?.join("local");
    let control = dir.join(format!("control-{}", std::process::id()));
    Ok((dir.join("wall.json"), control))
}

impl LocalWall {
    /// Writes the file (readable by this user only); removed when the guard drops.
    pub fn write(&self) -> Result<Written> {
        use std::io::Write;
        use std::os::unix::fs::OpenOptionsExt;
        let (path, _) = local_paths()?;
        let dir = path.parent().expect("a file in a folder");
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
        sweep_stale(dir);
        let text = serde_json::to_string_pretty(self)?;
        let mut file = std::fs::OpenOptions::new()
            .write(true)
            .create(true)
            .truncate(true)
            .mode(0o600)
            .open(&path)
            .with_context(|| format!("cannot write {}", path.display()))?;
        file.write_all(text.as_bytes())?;
        Ok(Written {
            path,
            pid: self.pid,
            cert_dir: self.cert_dir.clone(),
        })
    }

    /// The running local wall's file.
    ///
    /// # Errors
    /// No file (no local wall runs), one that does not parse, or one of a wall whose master
    /// is gone.
    pub fn read() -> Result<LocalWall> {
        let (path, _) = local_paths()?;
        let text = std::fs::read_to_string(&path).with_context(|| {
            format!(
                "no local wall found ({} cannot be read): start one with `tessera-master local`, or give --connect and --cert-dir",
                path.display()
            )
        })?;
        let wall: LocalWall = serde_json::from_str(&text)
            .with_context(|| format!("{} is not a local wall's file", path.display()))?;
        if !std::path::Path::new(&format!("/proc/{}", wall.pid)).exists() {
            bail!(
                "the local wall of {} (master pid {}) is not running anymore",
                path.display(),
                wall.pid
            );
        }
        Ok(wall)
    }
}

/// Removes the control certificates of local walls whose master is gone without cleaning up
/// (killed): `control-<pid>` folders whose process no longer runs.
fn sweep_stale(dir: &std::path::Path) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some(pid) = name
            .to_str()
            .and_then(|n| n.strip_prefix("control-"))
            .and_then(|p| p.parse::<u32>().ok())
        else {
            continue;
        };
        if !std::path::Path::new(&format!("/proc/{pid}")).exists() {
            let _ = std::fs::remove_dir_all(entry.path());
        }
    }
}

/// Removes the file when dropped, if it is still this process's.
pub struct Written {
    pub path: PathBuf,
    pid: u32,
    cert_dir: PathBuf,
}

impl Drop for Written {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.cert_dir);
        let ours = std::fs::read_to_string(&self.path)
            .ok()
            .and_then(|t| serde_json::from_str::<LocalWall>(&t).ok())
            .is_some_and(|w| w.pid == self.pid);
        if ours {
            let _ = std::fs::remove_file(&self.path);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_killed_walls_control_certificate_is_swept_and_a_live_ones_kept() {
        let dir = tempfile::tempdir().unwrap();
        // Above any kernel's pid_max: never a live process.
        let dead = dir.path().join("control-999999999");
        let live = dir.path().join(format!("control-{}", std::process::id()));
        let other = dir.path().join("wall.json");
        for d in [&dead, &live] {
            std::fs::create_dir_all(d).unwrap();
        }
        std::fs::write(&other, "{}").unwrap();
        sweep_stale(dir.path());
        assert!(!dead.exists() && live.exists() && other.exists());
    }
}
