//! A WebDriver client for the console's browser test: Debian's `chromedriver` driving
//! headless `chromium`, spoken over plain HTTP with [`crate::http::request`]. The driver and
//! its browser end with the [`Browser`] (the session deleted, the driver killed and reaped).

use crate::http::request;
use crate::{find_tool, wait_for, Proc};
use serde_json::{json, Value};
use std::path::Path;
use std::time::Duration;

/// The key WebDriver names an element by in its answers.
const ELEMENT: &str = "element-6066-11e4-a52e-4f735466cecf";

/// A headless chromium under chromedriver, with one session.
pub struct Browser {
    /// Held for its drop, which kills and reaps chromedriver.
    _driver: Proc,
    addr: String,
    session: String,
}

impl Browser {
    /// Starts chromedriver and a headless chromium with a fresh profile in `profile`; `None`
    /// (said on stderr) where either is not installed.
    pub fn start(profile: &Path, limit: Duration) -> Option<Browser> {
        let driver_bin = find_tool("chromedriver")?;
        let chromium = find_tool("chromium")?;
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .expect("a free port")
            .port();
        let port_arg = format!("--port={port}");
        let driver = Proc::start_program(&driver_bin, "chromedriver", &[&port_arg], &[]);
        let addr = format!("127.0.0.1:{port}");
        let up = || std::net::TcpStream::connect(&addr).is_ok();
        if !wait_for(limit, || up() || driver.has_exited()) || !up() {
            driver.fail("chromedriver never listened");
        }
        let args = [
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-background-networking",
            "--no-first-run",
            "--window-size=1400,1000",
            &format!("--user-data-dir={}", profile.display()),
        ];
        let caps = json!({ "capabilities": { "alwaysMatch": {
            "browserName": "chrome",
            "goog:chromeOptions": { "binary": chromium, "args": args }
        }}});
        let a = request(&addr, "POST", "/session", None, Some(&caps.to_string()));
        let v = a.json();
        let Some(session) = v["value"]["sessionId"].as_str() else {
            driver.fail(&format!("no session: {v}"));
        };
        Some(Browser {
            session: session.to_string(),
            _driver: driver,
            addr,
        })
    }

    /// A command of the session: `method` on `/session/ID/path` with `body`; its `value`.
    pub fn call(&self, method: &str, path: &str, body: Value) -> Value {
        let path = format!("/session/{}{path}", self.session);
        let body = (method == "POST").then(|| body.to_string());
        let a = request(&self.addr, method, &path, None, body.as_deref());
        let v = a.json();
        assert_eq!(a.status, 200, "{method} {path}: {v}");
        v["value"].clone()
    }

    /// Opens `url`.
    pub fn open(&self, url: &str) {
        self.call("POST", "/url", json!({ "url": url }));
    }

    /// Runs `script` (a function body; `return` gives its value) in the page.
    pub fn eval(&self, script: &str) -> Value {
        self.call(
            "POST",
            "/execute/sync",
            json!({ "script": script, "args": [] }),
        )
    }

    /// The element `css` selects, as WebDriver names it.
    pub fn element(&self, css: &str) -> Value {
        let v = self.call(
            "POST",
            "/element",
            json!({ "using": "css selector", "value": css }),
        );
        json!({ ELEMENT: v[ELEMENT].clone() })
    }

    /// Clicks the element `css` selects.
    pub fn click(&self, css: &str) {
        let id = self.element(css)[ELEMENT].as_str().unwrap().to_string();
        self.call("POST", &format!("/element/{id}/click"), json!({}));
    }

    /// Replaces what the input `css` selects holds with `text`.
    pub fn type_into(&self, css: &str, text: &str) {
        let id = self.element(css)[ELEMENT].as_str().unwrap().to_string();
        self.call("POST", &format!("/element/{id}/clear"), json!({}));
        self.call(
            "POST",
            &format!("/element/{id}/value"),
            json!({ "text": text }),
        );
    }

    /// Drags the mouse with its left button from the middle of the element `css` selects by
    /// `(dx, dy)` pixels, in `steps` moves.
    pub fn drag(&self, css: &str, dx: i32, dy: i32, steps: i32) {
        let element = self.element(css);
        let mut actions = vec![
            json!({ "type": "pointerMove", "duration": 0, "origin": element, "x": 0, "y": 0 }),
            json!({ "type": "pointerDown", "button": 0 }),
        ];
        for _ in 0..steps {
            actions.push(
                json!({ "type": "pointerMove", "duration": 50, "origin": "pointer",
                "x": dx / steps, "y": dy / steps }),
            );
        }
        actions.push(json!({ "type": "pointerUp", "button": 0 }));
        let body = json!({ "actions": [{ "type": "pointer", "id": "mouse",
            "parameters": { "pointerType": "mouse" }, "actions": actions }] });
        self.call("POST", "/actions", body);
    }

    /// The page as a PNG, written to `path`.
    pub fn screenshot(&self, path: &Path) {
        use base64::Engine;
        let v = self.call("GET", "/screenshot", json!({}));
        let png = base64::engine::general_purpose::STANDARD
            .decode(v.as_str().expect("base64"))
            .expect("a base64 PNG");
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir).unwrap();
        }
        std::fs::write(path, png).unwrap();
    }
}

impl Drop for Browser {
    fn drop(&mut self) {
        // Chromium quits with its session; the driver is killed and reaped by its Proc.
        let path = format!("/session/{}", self.session);
        let _ = std::panic::catch_unwind(|| request(&self.addr, "DELETE", &path, None, None));
    }
}
