//! A minimal HTTP/1.1 client for the console's tests (one request a connection), and a
//! local wall with its console, found through the state folder it writes.

use crate::{wait_for, Proc};
use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// An HTTP answer: its status code and body.
#[derive(Debug)]
pub struct Answer {
    /// The status code.
    pub status: u16,
    /// The body's bytes.
    pub body: Vec<u8>,
}

impl Answer {
    /// The body as text.
    pub fn text(&self) -> String {
        String::from_utf8_lossy(&self.body).into_owned()
    }

    /// The body as JSON; panics if it is not.
    pub fn json(&self) -> serde_json::Value {
        serde_json::from_slice(&self.body)
            .unwrap_or_else(|e| panic!("not JSON ({e}): {}", self.text()))
    }
}

/// Sends `method path` to `addr` with `body` (JSON) and, if given, the bearer `token`; reads
/// the whole answer (bounded by a 30 s timeout on each read).
pub fn request(
    addr: &str,
    method: &str,
    path: &str,
    token: Option<&str>,
    body: Option<&str>,
) -> Answer {
    let mut stream = connect(addr);
    request_on(&mut stream, addr, method, path, token, body)
}

fn connect(addr: &str) -> TcpStream {
    let stream = TcpStream::connect(addr).unwrap_or_else(|e| panic!("cannot reach {addr}: {e}"));
    stream
        .set_read_timeout(Some(Duration::from_secs(30)))
        .unwrap();
    stream
}

/// A `GET` of `path` over HTTPS, trusting the cluster CA of the node certificate in
/// `cert_dir` and presenting that certificate if `present`.
pub fn request_tls(
    addr: &str,
    cert_dir: &Path,
    present: bool,
    path: &str,
    token: Option<&str>,
) -> Answer {
    let id = tessera_net::cluster::NodeIdentity::load(cert_dir).expect("a node certificate");
    let config = tessera_net::quic::https_client_config(&id, present).expect("a TLS client");
    let name =
        rustls::pki_types::ServerName::try_from(tessera_net::cluster::CLUSTER_SERVER_NAME).unwrap();
    let conn = rustls::ClientConnection::new(std::sync::Arc::new(config), name).unwrap();
    let mut tls = rustls::StreamOwned::new(conn, connect(addr));
    request_on(&mut tls, addr, "GET", path, token, None)
}

fn request_on<S: Read + Write>(
    stream: &mut S,
    addr: &str,
    method: &str,
    path: &str,
    token: Option<&str>,
    body: Option<&str>,
) -> Answer {
    let mut head = format!("{method} {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n");
    if let Some(t) = token {
        head.push_str(&format!("Authorization: Bearer {t}\r\n"));
    }
    let body = body.unwrap_or("");
    if !body.is_empty() || method == "POST" {
        head.push_str(&format!(
            "Content-Type: application/json\r\nContent-Length: {}\r\n",
            body.len()
        ));
    }
    head.push_str("\r\n");
    stream.write_all(head.as_bytes()).unwrap();
    stream.write_all(body.as_bytes()).unwrap();
    let raw = read_answer(stream);
    let split = raw
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .unwrap_or_else(|| panic!("no header end in {:?}", String::from_utf8_lossy(&raw)));
    let headers = String::from_utf8_lossy(&raw[..split]).to_string();
    let status = headers
        .split_whitespace()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no status in {headers:?}"));
    let mut body = raw[split + 4..].to_vec();
    if headers
        .to_ascii_lowercase()
        .contains("transfer-encoding: chunked")
    {
        body = unchunk(&body);
    }
    Answer { status, body }
}

/// Reads an answer whole: to the end its Content-Length or last chunk says, not to the
/// connection's end, which a server that keeps connections open (chromedriver) never sends.
fn read_answer(stream: &mut impl Read) -> Vec<u8> {
    let mut raw = Vec::new();
    let mut buf = [0u8; 64 * 1024];
    loop {
        let n = stream.read(&mut buf).expect("an answer within 30 s");
        raw.extend_from_slice(&buf[..n]);
        if n == 0 || is_whole(&raw) {
            return raw;
        }
    }
}

fn is_whole(raw: &[u8]) -> bool {
    let Some(split) = raw.windows(4).position(|w| w == b"\r\n\r\n") else {
        return false;
    };
    let headers = String::from_utf8_lossy(&raw[..split]).to_ascii_lowercase();
    let body = &raw[split + 4..];
    if let Some(len) = headers
        .lines()
        .find_map(|l| l.strip_prefix("content-length:"))
        .and_then(|v| v.trim().parse::<usize>().ok())
    {
        return body.len() >= len;
    }
    headers.contains("transfer-encoding: chunked") && body.ends_with(b"0\r\n\r\n")
}

fn unchunk(mut data: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    while let Some(end) = data.windows(2).position(|w| w == b"\r\n") {
        let size =
            usize::from_str_radix(String::from_utf8_lossy(&data[..end]).trim(), 16).unwrap_or(0);
        if size == 0 {
            break;
        }
        out.extend_from_slice(&data[end + 2..end + 2 + size]);
        data = &data[end + 2 + size + 2..];
    }
    out
}

/// A local wall started with its own state folder, and its console's address and token.
pub struct ConsoleWall {
    /// The master process.
    pub master: Proc,
    /// The console's HOST:PORT.
    pub addr: String,
    /// The console's token.
    pub token: String,
    /// The console's URL with the token, as `local` printed it.
    pub url: String,
    /// The state folder (`TESSERA_STATE_DIR`) the wall wrote its file in.
    pub state_dir: PathBuf,
}

impl ConsoleWall {
    /// Starts `tessera-master local ARGS` with the state folder `dir/state`, and waits
    /// (bounded by `limit`) for the file that names its console.
    pub fn start(dir: &Path, args: &[&str], limit: Duration) -> ConsoleWall {
        let state_dir = dir.join("state");
        let mut all = vec!["local"];
        all.extend(args);
        let master = Proc::start_with_env(
            "tessera-master",
            &all,
            &[("TESSERA_STATE_DIR", state_dir.to_str().unwrap())],
        );
        let file = state_dir.join("local/wall.json");
        let read = || -> Option<serde_json::Value> {
            serde_json::from_str(&std::fs::read_to_string(&file).ok()?).ok()
        };
        if !wait_for(limit, || read().is_some() || master.has_exited()) || read().is_none() {
            master.fail("the local wall never wrote its console's file");
        }
        let wall = read().unwrap();
        let url = wall["console_url"]
            .as_str()
            .expect("a console URL")
            .to_string();
        let addr = url
            .trim_start_matches("http://")
            .split('/')
            .next()
            .unwrap()
            .to_string();
        let token = wall["token"].as_str().expect("a token").to_string();
        ConsoleWall {
            master,
            addr,
            token,
            url,
            state_dir,
        }
    }

    /// `GET path` with the token.
    pub fn get(&self, path: &str) -> Answer {
        request(&self.addr, "GET", path, Some(&self.token), None)
    }

    /// `POST path` with the token and `body`.
    pub fn post(&self, path: &str, body: &str) -> Answer {
        request(&self.addr, "POST", path, Some(&self.token), Some(body))
    }
}
