//! A small synchronous client of the Chrome DevTools Protocol over one WebSocket per target
//! (`tungstenite`): starts Chromium with `--remote-debugging-port=0`, reads the `DevTools
//! listening on ws://…` line from its stderr, and sends commands, waiting for each answer
//! (events are skipped). The browser is killed when `Chromium` drops.

use serde_json::{json, Value};
use std::io::{BufRead, BufReader};
use std::net::TcpStream;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;
use tungstenite::{Message, WebSocket};

/// How long one command may take before the test fails.
const ANSWER_TIMEOUT: Duration = Duration::from_secs(30);

/// A running headless Chromium and its browser-level connection.
pub struct Chromium {
    child: Child,
    /// `host:port` of the DevTools server.
    address: String,
    browser: Connection,
    _profile: tempfile::TempDir,
}

/// One WebSocket to a DevTools endpoint (the browser, or one page).
pub struct Connection {
    socket: WebSocket<TcpStream>,
    next_id: u64,
}

impl Chromium {
    /// Starts `program` headless (no sandbox, a fresh profile) with `args` added.
    pub fn start(program: &str, args: &[&str]) -> Result<Chromium, String> {
        let profile = tempfile::tempdir().map_err(|e| format!("profile folder: {e}"))?;
        let mut child = Command::new(program)
            .args([
                "--headless",
                "--no-sandbox",
                "--remote-debugging-port=0",
                "--no-first-run",
                "--no-default-browser-check",
                "--disable-gpu",
                "--disable-background-networking",
                "--disable-sync",
                "--disable-extensions",
                "--force-color-profile=srgb",
            ])
            .arg(format!("--user-data-dir={}", profile.path().display()))
            .args(args)
            .arg("about:blank")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| format!("start {program}: {e}"))?;
        // Read stderr on a thread (it must keep being drained) and hand over the first ws:// URL.
        let stderr = child.stderr.take().ok_or("no stderr")?;
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                if let Some(url) = line.strip_prefix("DevTools listening on ") {
                    let _ = tx.send(url.trim().to_string());
                }
            }
        });
        let url = match rx.recv_timeout(ANSWER_TIMEOUT) {
            Ok(url) => url,
            Err(_) => {
                let _ = child.kill();
                let _ = child.wait();
                return Err(format!("{program} printed no DevTools URL"));
            }
        };
        let address = url
            .strip_prefix("ws://")
            .and_then(|rest| rest.split('/').next())
            .ok_or_else(|| format!("unexpected DevTools URL {url}"))?
            .to_string();
        let mut chromium = Chromium {
            child,
            address,
            browser: Connection {
                socket: connect_to(&url)?,
                next_id: 0,
            },
            _profile: profile,
        };
        // The first answer proves the connection works.
        chromium.browser.call("Browser.getVersion", json!({}))?;
        Ok(chromium)
    }

    /// A new page target and a connection to it.
    pub fn new_page(&mut self) -> Result<(String, Connection), String> {
        let r = self
            .browser
            .call("Target.createTarget", json!({"url": "about:blank"}))?;
        let id = r["targetId"].as_str().ok_or("no targetId")?.to_string();
        let url = format!("ws://{}/devtools/page/{id}", self.address);
        let page = Connection {
            socket: connect_to(&url)?,
            next_id: 0,
        };
        Ok((id, page))
    }

    /// Closes a page target.
    pub fn close_page(&mut self, id: &str) -> Result<(), String> {
        self.browser
            .call("Target.closeTarget", json!({"targetId": id}))
            .map(|_| ())
    }
}

impl Drop for Chromium {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn connect_to(url: &str) -> Result<WebSocket<TcpStream>, String> {
    let address = url
        .strip_prefix("ws://")
        .and_then(|rest| rest.split('/').next())
        .ok_or_else(|| format!("not a ws:// URL: {url}"))?;
    let stream = TcpStream::connect(address).map_err(|e| format!("connect {address}: {e}"))?;
    stream
        .set_read_timeout(Some(ANSWER_TIMEOUT))
        .map_err(|e| format!("{e}"))?;
    let (socket, _) =
        tungstenite::client(url, stream).map_err(|e| format!("WebSocket to {url}: {e}"))?;
    Ok(socket)
}

impl Connection {
    /// Sends `method` with `params` and returns its `result`, or the protocol's error message.
    pub fn call(&mut self, method: &str, params: Value) -> Result<Value, String> {
        self.next_id += 1;
        let id = self.next_id;
        let text = json!({"id": id, "method": method, "params": params}).to_string();
        self.socket
            .send(Message::text(text))
            .map_err(|e| format!("send {method}: {e}"))?;
        loop {
            let message = self
                .socket
                .read()
                .map_err(|e| format!("answer to {method}: {e}"))?;
            let Message::Text(text) = message else {
                continue;
            };
            let answer: Value =
                serde_json::from_str(&text).map_err(|e| format!("answer to {method}: {e}"))?;
            if answer["id"].as_u64() != Some(id) {
                continue; // an event, or the answer to an earlier call
            }
            if let Some(error) = answer.get("error") {
                return Err(format!("{method}: {error}"));
            }
            return Ok(answer["result"].clone());
        }
    }
}
