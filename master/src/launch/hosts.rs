//! The host file of `tessera-master launch`: how to reach each host over ssh, and which
//! render nodes and displays it runs. See `deploy/hosts/example.toml`.
//!
//! Every error names the file, the host (its position and address) and the field, because a
//! host file for a large wall is long and the same address may appear more than once.

use anyhow::{bail, Context, Result};
use serde::Deserialize;
use std::net::SocketAddr;
use std::path::Path;

/// The master's listening address when the host file gives none.
const DEFAULT_LISTEN: &str = "0.0.0.0:7400";
/// Where node certificates go on a host when the host file gives no `remote_dir`.
const DEFAULT_REMOTE_DIR: &str = "/tmp";
/// Most render nodes one host entry may start (each is a process of its own).
const MAX_RENDER_PER_HOST: u32 = 64;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawFile {
    #[serde(default)]
    master: RawMaster,
    #[serde(default)]
    ssh: RawSsh,
    #[serde(default)]
    host: Vec<toml::Table>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct RawMaster {
    address: Option<String>,
    listen: Option<String>,
}

/// What `[ssh]` sets for every host and a `[[host]]` may override.
#[derive(Deserialize, Default, Clone)]
#[serde(deny_unknown_fields)]
struct RawSsh {
    user: Option<String>,
    port: Option<u16>,
    options: Option<Vec<String>>,
    tessera: Option<String>,
    remote_dir: Option<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawHost {
    address: String,
    user: Option<String>,
    port: Option<u16>,
    options: Option<Vec<String>>,
    tessera: Option<String>,
    remote_dir: Option<String>,
    #[serde(default)]
    render: u32,
    threads: Option<u32>,
    #[serde(default)]
    render_args: Vec<String>,
    #[serde(default)]
    displays: Vec<u32>,
    display_port: Option<u16>,
    #[serde(default)]
    display_args: Vec<String>,
}

/// Where the master listens and the address the nodes dial it at.
#[derive(Debug, Clone)]
pub struct MasterPlace {
    /// Host name or IP the nodes reach the master at (the port is the one it listens on).
    pub address: String,
    pub listen: SocketAddr,
}

/// One `[[host]]`, with the `[ssh]` defaults applied.
#[derive(Debug, Clone)]
pub struct Host {
    /// Its position in the file, from 1, for messages.
    pub number: usize,
    /// What ssh connects to.
    pub address: String,
    pub user: Option<String>,
    pub port: Option<u16>,
    /// Further ssh options, as ssh's own arguments (`["-i", "KEY"]`, `["-o", "X=Y"]`).
    pub options: Vec<String>,
    /// Path of `tessera-master` on the host.
    pub tessera: String,
    /// Directory on the host under which the run's certificates are copied.
    pub remote_dir: String,
    /// Render nodes it runs.
    pub render: u32,
    pub threads: Option<u32>,
    pub render_args: Vec<String>,
    /// Display ids it shows.
    pub displays: Vec<u32>,
    /// The first display's port (the next display the next port); none: any free port.
    pub display_port: Option<u16>,
    pub display_args: Vec<String>,
}

impl Host {
    /// How messages name it: `host 2 (wall-a.example)`.
    pub fn label(&self) -> String {
        format!("host {} ({})", self.number, self.address)
    }
}

/// A whole host file.
#[derive(Debug, Clone)]
pub struct HostFile {
    pub master: MasterPlace,
    pub hosts: Vec<Host>,
}

/// One node of the wall, as the host file places it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum NodeRole {
    Render { threads: Option<u32> },
    Display { id: u32, port: Option<u16> },
}

/// A node to start: its certificate's name, the host (index into [`HostFile::hosts`]) and
/// its role.
#[derive(Debug, Clone)]
pub struct PlannedNode {
    pub name: String,
    pub host: usize,
    pub role: NodeRole,
}

impl HostFile {
    /// Reads and checks `path`; `tessera` is the path a host without one gets (this very
    /// executable's).
    ///
    /// # Errors
    /// The file cannot be read, is not TOML, has an unknown field, or a value is out of
    /// bounds; the message names the host and the field.
    pub fn load(path: &Path, tessera: &str) -> Result<HostFile> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read the host file {}", path.display()))?;
        Self::parse(&text, tessera).with_context(|| format!("host file {}", path.display()))
    }

    /// [`HostFile::load`] on text.
    ///
    /// # Errors
    /// As [`HostFile::load`].
    pub fn parse(text: &str, tessera: &str) -> Result<HostFile> {
        let raw: RawFile = toml::from_str(text).context(
            "not a host file: expected [master], [ssh] and [[host]] tables (see deploy/hosts/example.toml)",
        )?;
        let master = master_place(&raw.master)?;
        let ssh = raw.ssh;
        check_ssh_section(&ssh)?;
        if raw.host.is_empty() {
            bail!("no [[host]] entries: the wall needs hosts for its render nodes and displays");
        }
        let hosts = raw
            .host
            .into_iter()
            .enumerate()
            .map(|(i, table)| host(i + 1, table, &ssh, tessera))
            .collect::<Result<Vec<_>>>()?;
        if hosts.iter().all(|h| h.render == 0) {
            bail!("no host runs a render node: give one `render = N` (N at least 1)");
        }
        Ok(HostFile { master, hosts })
    }

    /// The nodes to start for a wall of `display_count` displays: render nodes named
    /// `render-0`, `render-1`... in file order, and `display-ID` for each display.
    ///
    /// # Errors
    /// A display id outside the wall, one named by two hosts, or one no host shows.
    pub fn plan(&self, display_count: u32) -> Result<Vec<PlannedNode>> {
        let mut shown_by: Vec<Option<&Host>> = vec![None; display_count as usize];
        let mut nodes = Vec::new();
        let mut render = 0u32;
        for (index, h) in self.hosts.iter().enumerate() {
            for _ in 0..h.render {
                nodes.push(PlannedNode {
                    name: format!("render-{render}"),
                    host: index,
                    role: NodeRole::Render { threads: h.threads },
                });
                render += 1;
            }
            for (k, &id) in h.displays.iter().enumerate() {
                let Some(slot) = shown_by.get_mut(id as usize) else {
                    bail!(
                        "{}: `displays` names display {id}, but the wall has {display_count} display(s), 0 to {} (check --wall or --wall-file)",
                        h.label(),
                        display_count.saturating_sub(1)
                    );
                };
                if let Some(other) = slot {
                    bail!(
                        "display {id} is in the `displays` of both {} and {}: a display runs on one host",
                        other.label(),
                        h.label()
                    );
                }
                *slot = Some(h);
                nodes.push(PlannedNode {
                    name: format!("display-{id}"),
                    host: index,
                    role: NodeRole::Display {
                        id,
                        port: display_port(h, k)?,
                    },
                });
            }
        }
        if let Some(missing) = shown_by.iter().position(Option::is_none) {
            bail!(
                "no host shows display {missing} of the {display_count}: add it to a host's `displays`"
            );
        }
        Ok(nodes)
    }

    /// Render nodes in all.
    pub fn render_nodes(&self) -> u32 {
        self.hosts.iter().map(|h| h.render).sum()
    }
}

/// The port of the `k`th display of host `h`.
fn display_port(h: &Host, k: usize) -> Result<Option<u16>> {
    let Some(first) = h.display_port else {
        return Ok(None);
    };
    let port = u16::try_from(first as usize + k)
        .ok()
        .with_context(|| format!("{}: `display_port` {first} + {k} is past 65535", h.label()))?;
    Ok(Some(port))
}

fn master_place(raw: &RawMaster) -> Result<MasterPlace> {
    let listen_text = raw.listen.as_deref().unwrap_or(DEFAULT_LISTEN);
    let listen: SocketAddr = listen_text.parse().map_err(|_| {
        anyhow::anyhow!(
            "[master] listen = {listen_text:?} is not IP:PORT (such as \"0.0.0.0:7400\")"
        )
    })?;
    let address = match &raw.address {
        Some(a) => {
            check_word("[master] address", a)?;
            a.clone()
        }
        // A specific listening IP is where the nodes reach it; a wildcard says nothing.
        None if !listen.ip().is_unspecified() => listen.ip().to_string(),
        None => tessera_net::hostname(),
    };
    Ok(MasterPlace { address, listen })
}

fn check_ssh_section(ssh: &RawSsh) -> Result<()> {
    check_common("[ssh]", &ssh.user, ssh.port, &ssh.tessera, &ssh.remote_dir)
}

fn host(number: usize, table: toml::Table, ssh: &RawSsh, tessera: &str) -> Result<Host> {
    // Named before the fields are checked, so that even a type error says which host.
    let name = match table.get("address") {
        Some(toml::Value::String(a)) => format!("host {number} ({a})"),
        _ => format!("host {number}"),
    };
    let raw: RawHost = toml::Value::Table(table)
        .try_into()
        .with_context(|| format!("[[host]] number {number}, {name}"))?;
    check_word(&format!("{name}: `address`"), &raw.address)?;
    check_common(&name, &raw.user, raw.port, &raw.tessera, &raw.remote_dir)?;
    if raw.render == 0 && raw.displays.is_empty() {
        bail!("{name} runs nothing: give it `render = N` or `displays = [ID, ...]`");
    }
    if raw.render > MAX_RENDER_PER_HOST {
        bail!(
            "{name}: `render = {}` is more than {MAX_RENDER_PER_HOST} render nodes on one host (one node uses every core; give it `threads` instead)",
            raw.render
        );
    }
    if let Some(t) = raw.threads {
        if t == 0 || t as usize > tessera_render_node::MAX_THREADS {
            bail!(
                "{name}: `threads = {t}` is not 1 to {}",
                tessera_render_node::MAX_THREADS
            );
        }
        if raw.render == 0 {
            bail!("{name}: `threads` is for render nodes, and it runs none (`render = N`)");
        }
    }
    if raw.display_port.is_some() && raw.displays.is_empty() {
        bail!("{name}: `display_port` is for displays, and it shows none (`displays = [...]`)");
    }
    if raw.display_port == Some(0) {
        bail!("{name}: `display_port = 0`: leave it out for any free port");
    }
    Ok(Host {
        number,
        address: raw.address,
        user: raw.user.or_else(|| ssh.user.clone()),
        port: raw.port.or(ssh.port),
        options: raw
            .options
            .or_else(|| ssh.options.clone())
            .unwrap_or_default(),
        tessera: raw
            .tessera
            .or_else(|| ssh.tessera.clone())
            .unwrap_or_else(|| tessera.to_string()),
        remote_dir: raw
            .remote_dir
            .or_else(|| ssh.remote_dir.clone())
            .unwrap_or_else(|| DEFAULT_REMOTE_DIR.to_string()),
        render: raw.render,
        threads: raw.threads,
        render_args: raw.render_args,
        displays: raw.displays,
        display_port: raw.display_port,
        display_args: raw.display_args,
    })
}

/// The fields `[ssh]` and `[[host]]` share.
fn check_common(
    name: &str,
    user: &Option<String>,
    port: Option<u16>,
    tessera: &Option<String>,
    remote_dir: &Option<String>,
) -> Result<()> {
    if let Some(u) = user {
        check_word(&format!("{name}: `user`"), u)?;
    }
    if port == Some(0) {
        bail!("{name}: `port = 0` is not an ssh port (leave it out for 22)");
    }
    if let Some(t) = tessera {
        check_path(&format!("{name}: `tessera`"), t)?;
    }
    if let Some(d) = remote_dir {
        check_path(&format!("{name}: `remote_dir`"), d)?;
    }
    Ok(())
}

/// A host or user name goes to ssh as an argument: one word, never an option.
fn check_word(what: &str, value: &str) -> Result<()> {
    if value.is_empty() {
        bail!("{what} is empty");
    }
    if value.starts_with('-') {
        bail!("{what} = {value:?} starts with '-', which ssh would read as an option");
    }
    if value.chars().any(|c| c.is_whitespace() || c.is_control()) {
        bail!("{what} = {value:?} holds a space or a control character");
    }
    Ok(())
}

/// Remote paths are quoted for the remote shell, so `~` would not expand: absolute only.
fn check_path(what: &str, value: &str) -> Result<()> {
    if !value.starts_with('/') {
        bail!("{what} = {value:?} is not an absolute path (a remote `~` is not expanded)");
    }
    if value.chars().any(char::is_control) {
        bail!("{what} = {value:?} holds a control character");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const TESSERA: &str = "/opt/tessera-master";

    fn parse(text: &str) -> Result<HostFile> {
        HostFile::parse(text, TESSERA)
    }

    fn error(text: &str) -> String {
        format!("{:#}", parse(text).unwrap_err())
    }

    const TWO_HOSTS: &str = r#"
        [master]
        address = "head"
        [ssh]
        user = "wall"
        options = ["-i", "/k"]
        [[host]]
        address = "a"
        render = 2
        threads = 4
        [[host]]
        address = "b"
        port = 2222
        displays = [1, 0]
        display_port = 7401
        tessera = "/usr/bin/tessera-master"
    "#;

    #[test]
    fn defaults_and_overrides_apply_per_host() {
        let file = parse(TWO_HOSTS).unwrap();
        assert_eq!(file.master.address, "head");
        assert_eq!(file.master.listen, DEFAULT_LISTEN.parse().unwrap());
        let (a, b) = (&file.hosts[0], &file.hosts[1]);
        assert_eq!((a.user.as_deref(), a.port), (Some("wall"), None));
        assert_eq!(a.tessera, TESSERA);
        assert_eq!(a.remote_dir, DEFAULT_REMOTE_DIR);
        assert_eq!(b.port, Some(2222));
        assert_eq!(b.options, ["-i", "/k"]);
        assert_eq!(b.tessera, "/usr/bin/tessera-master");
        assert_eq!(file.render_nodes(), 2);
    }

    #[test]
    fn the_plan_names_every_node_and_numbers_display_ports() {
        let plan = parse(TWO_HOSTS).unwrap().plan(2).unwrap();
        let names: Vec<&str> = plan.iter().map(|n| n.name.as_str()).collect();
        assert_eq!(names, ["render-0", "render-1", "display-1", "display-0"]);
        assert_eq!(
            plan[2].role,
            NodeRole::Display {
                id: 1,
                port: Some(7401)
            }
        );
        assert_eq!(
            plan[3].role,
            NodeRole::Display {
                id: 0,
                port: Some(7402)
            }
        );
        assert_eq!(plan[0].role, NodeRole::Render { threads: Some(4) });
    }

    #[test]
    fn displays_must_match_the_wall() {
        let file = parse(TWO_HOSTS).unwrap();
        let e = format!("{:#}", file.plan(1).unwrap_err());
        assert!(e.contains("host 2 (b)") && e.contains("display 1"), "{e}");
        let e = format!("{:#}", file.plan(3).unwrap_err());
        assert!(e.contains("no host shows display 2"), "{e}");
        let twice = TWO_HOSTS.replace("threads = 4", "threads = 4\ndisplays = [0]");
        let e = format!("{:#}", parse(&twice).unwrap().plan(2).unwrap_err());
        assert!(
            e.contains("display 0") && e.contains("host 1 (a)") && e.contains("host 2 (b)"),
            "{e}"
        );
    }

    #[test]
    fn a_bad_field_is_named_with_its_host() {
        let e = error(&TWO_HOSTS.replace("port = 2222", "prot = 2222"));
        assert!(e.contains("host 2 (b)") && e.contains("prot"), "{e}");
        let e = error(&TWO_HOSTS.replace("port = 2222", "port = \"ssh\""));
        assert!(e.contains("host 2 (b)") && e.contains("port"), "{e}");
        let e = error(&TWO_HOSTS.replace("address = \"a\"", "address = \"-oProxyCommand=x\""));
        assert!(e.contains("`address`") && e.contains("option"), "{e}");
        let e = error(&TWO_HOSTS.replace("threads = 4", "threads = 0"));
        assert!(e.contains("host 1 (a)") && e.contains("threads = 0"), "{e}");
        let e = error(&TWO_HOSTS.replace("/usr/bin/tessera-master", "bin/tessera"));
        assert!(e.contains("`tessera`") && e.contains("absolute"), "{e}");
        let e = error(&TWO_HOSTS.replace("render = 2\n", ""));
        assert!(e.contains("host 1 (a) runs nothing"), "{e}");
        let e = error(&TWO_HOSTS.replace(
            "address = \"head\"",
            "address = \"head\"\nlisten = \"head:7400\"",
        ));
        assert!(e.contains("listen") && e.contains("IP:PORT"), "{e}");
        let e = error("[[host]]\naddress = \"a\"\ndisplays = [0]\n");
        assert!(e.contains("no host runs a render node"), "{e}");
        let e = error("[sssh]\n");
        assert!(e.contains("sssh"), "{e}");
    }

    #[test]
    fn the_master_address_defaults_to_a_specific_listening_ip() {
        let file =
            parse(&TWO_HOSTS.replace("address = \"head\"", "listen = \"10.0.0.1:7400\"")).unwrap();
        assert_eq!(file.master.address, "10.0.0.1");
    }
}
