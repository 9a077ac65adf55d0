//! `keyframer review` over HTTP, as a browser or an attacker speaks to it: refusals (token, Host,
//! Origin, paths) logged without the token, bad requests that write nothing, a save equal to
//! `select` with the same steps and `--add`, the workflow save, a save after an outside change and
//! a reload, a clean stop on Ctrl-C, and answers and a stop within a second while fifty
//! connections stall.

use crate::browser::{Browser, Tab};
use crate::common::{json, keyframes, kf_loud, kf_ok, s, PAN_ANALYSIS};
use keyframer::report::timeline::KEYFRAME_RGB;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

/// A copy of the pan project (`common::pan_project`): a 4 s, 30 fps pan over a photo (320x240), selected with spacing 25
/// and blur at analysis width 160, frames 60 and 61 added by hand. Made once; each test copies
/// the clip and the project into its own folder (saving replaces the project).
pub fn pan_copy(dir: &Path) -> PathBuf {
    static MADE: OnceLock<PathBuf> = OnceLock::new();
    let made = MADE.get_or_init(|| {
        let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("review-fixture");
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        crate::common::pan_project(&dir);
        dir
    });
    std::fs::create_dir_all(dir).unwrap();
    for f in ["pan.mp4", "pan.json"] {
        // Keeps the modification time: the project's input fingerprint includes it.
        let ok = Command::new("cp")
            .arg("-p")
            .arg(made.join(f))
            .arg(dir.join(f))
            .status()
            .unwrap();
        assert!(ok.success());
    }
    dir.join("pan.json")
}

/// A running `keyframer review`, stopped with SIGINT on drop.
pub struct Served {
    pub child: Option<Child>,
    pub port: u16,
    pub token: String,
    /// The page's address with the token, as printed.
    #[allow(dead_code)]
    pub url: String,
    pub stderr: PathBuf,
}

impl Served {
    pub fn start(project: &Path, extra: &[&str]) -> Served {
        let stderr = project.with_extension("review-stderr.txt");
        let mut child = Command::new(env!("CARGO_BIN_EXE_keyframer"))
            .args(["review", s(project), "--port", "0"])
            .args(extra)
            .env("RUST_LOG", "warn")
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(&stderr).unwrap())
            .spawn()
            .unwrap();
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        let url = line
            .trim()
            .strip_prefix("review: ")
            .expect(&line)
            .to_string();
        let token = url.split("token=").nth(1).unwrap().to_string();
        let port = url
            .trim_start_matches("http://127.0.0.1:")
            .split('/')
            .next()
            .unwrap()
            .parse()
            .unwrap();
        Served {
            child: Some(child),
            port,
            token,
            url,
            stderr,
        }
    }

    /// One request with the token, the right Host and (for POST) the right Origin.
    pub fn call(
        &self,
        method: &str,
        path: &str,
        body: Option<&serde_json::Value>,
    ) -> (u16, serde_json::Value) {
        let host = format!("127.0.0.1:{}", self.port);
        let origin = format!("http://{host}");
        let mut headers = vec![
            ("Host", host.as_str()),
            ("X-Keyframer-Token", self.token.as_str()),
        ];
        if method == "POST" {
            headers.push(("Origin", origin.as_str()));
        }
        let body = body.map(|b| b.to_string());
        let (code, bytes) = raw(self.port, method, path, &headers, body.as_deref());
        (
            code,
            serde_json::from_slice(&bytes).unwrap_or(serde_json::Value::Null),
        )
    }

    /// Sends SIGINT and waits: the exit code and stderr.
    pub fn stop(&mut self) -> (i32, String) {
        let mut child = self.child.take().unwrap();
        sigint(&child);
        let status = child.wait().unwrap();
        (
            status.code().unwrap_or(-1),
            std::fs::read_to_string(&self.stderr).unwrap(),
        )
    }
}

impl Drop for Served {
    fn drop(&mut self) {
        if self.child.is_some() {
            self.stop();
        }
    }
}

fn sigint(child: &Child) {
    let sent = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(sent.success());
}

/// A raw HTTP/1.1 request; returns the status and the body.
pub fn raw(
    port: u16,
    method: &str,
    path: &str,
    headers: &[(&str, &str)],
    body: Option<&str>,
) -> (u16, Vec<u8>) {
    let mut tcp = TcpStream::connect(("127.0.0.1", port)).unwrap();
    let mut rq = format!("{method} {path} HTTP/1.1\r\nConnection: close\r\n");
    for (k, v) in headers {
        rq += &format!("{k}: {v}\r\n");
    }
    if let Some(b) = body {
        rq += &format!(
            "Content-Type: application/json\r\nContent-Length: {}\r\n",
            b.len()
        );
    }
    rq += "\r\n";
    rq += body.unwrap_or("");
    tcp.write_all(rq.as_bytes()).unwrap();
    let mut out = Vec::new();
    tcp.read_to_end(&mut out).unwrap();
    let split = out.windows(4).position(|w| w == b"\r\n\r\n").unwrap();
    let head = String::from_utf8_lossy(&out[..split]).to_string();
    let code = head.split(' ').nth(1).unwrap().parse().unwrap();
    let mut body = out[split + 4..].to_vec();
    if head
        .to_ascii_lowercase()
        .contains("transfer-encoding: chunked")
    {
        body = dechunk(&body);
    }
    (code, body)
}

fn dechunk(mut b: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    loop {
        let end = b.windows(2).position(|w| w == b"\r\n").unwrap();
        let n = usize::from_str_radix(std::str::from_utf8(&b[..end]).unwrap().trim(), 16).unwrap();
        if n == 0 {
            return out;
        }
        out.extend_from_slice(&b[end + 2..end + 2 + n]);
        b = &b[end + 4 + n..];
    }
}

fn steps(v: serde_json::Value) -> serde_json::Value {
    serde_json::json!({ "steps": v, "revision": 0 })
}

/// A request (method, path, headers, body) and the status it must get.
type Case<'a> = (
    &'a str,
    String,
    Vec<(&'a str, &'a str)>,
    Option<&'a str>,
    u16,
);

#[test]
fn review_refuses_without_token_foreign_host_origin_and_paths() {
    let dir = tempfile::tempdir().unwrap();
    let project = pan_copy(dir.path());
    let mut srv = Served::start(&project, &[]);
    let own = format!("127.0.0.1:{}", srv.port);
    let origin = format!("http://{own}");
    let tok = srv.token.clone();
    let apply = r#"{"steps":[]}"#;
    let mut cases: Vec<Case> = vec![
        ("GET", "/api/state".into(), vec![("Host", &own)], None, 401),
        (
            "GET",
            "/api/state".into(),
            vec![("Host", &own), ("X-Keyframer-Token", "00ff")],
            None,
            401,
        ),
        (
            "GET",
            format!("/?token={}", "1".repeat(32)),
            vec![("Host", &own)],
            None,
            401,
        ),
        (
            "GET",
            "/api/state".into(),
            vec![("Host", "evil.example"), ("X-Keyframer-Token", &tok)],
            None,
            403,
        ),
        (
            "POST",
            "/api/apply".into(),
            vec![
                ("Host", &own),
                ("X-Keyframer-Token", &tok),
                ("Origin", "http://evil.example"),
            ],
            Some(apply),
            403,
        ),
        (
            "POST",
            "/api/apply".into(),
            vec![("Host", &own), ("X-Keyframer-Token", &tok)],
            Some(apply),
            403,
        ),
        (
            "GET",
            "/api/state".into(),
            vec![
                ("Host", &own),
                ("X-Keyframer-Token", &tok),
                ("Sec-Fetch-Site", "cross-site"),
            ],
            None,
            403,
        ),
    ];
    // Paths outside the routes, with the token: refused all the same.
    let paths = [
        ("/api/export/image/..%2f..%2fetc%2fpasswd", 400),
        ("/../etc/passwd", 400),
        ("//etc/passwd", 400),
        ("/etc/passwd", 404),
        ("/api/frame/-1.jpg", 404),
        ("/api/export/image/3", 404),
    ];
    let authed = vec![("Host", own.as_str()), ("X-Keyframer-Token", tok.as_str())];
    cases.extend(paths.map(|(p, code)| ("GET", p.to_string(), authed.clone(), None, code)));
    for (method, path, headers, body, want) in &cases {
        let (code, bytes) = raw(srv.port, method, path, headers, *body);
        assert_eq!(
            code,
            *want,
            "{method} {path} {headers:?}: {}",
            String::from_utf8_lossy(&bytes)
        );
        let v: serde_json::Value = serde_json::from_slice(&bytes).unwrap();
        assert!(
            v["error"].as_str().is_some_and(|e| !e.is_empty()),
            "{path}: {v}"
        );
    }
    // The token's own requests pass.
    let (code, state) = srv.call("GET", "/api/state", None);
    assert_eq!(code, 200, "{state}");
    assert_eq!(state["input"]["frames"], 120);
    let (code, _) = raw(
        srv.port,
        "GET",
        &format!("/?token={tok}"),
        &[("Host", &own), ("Origin", &origin)],
        None,
    );
    assert_eq!(code, 200);
    let (_, err) = srv.stop();
    let refused = err
        .lines()
        .filter(|l| l.contains("review: refused"))
        .count();
    assert_eq!(refused, cases.len(), "one log line per refusal:\n{err}");
    assert!(!err.contains(&tok), "the token is never logged:\n{err}");
}

#[test]
fn review_bad_request_writes_nothing_and_survives() {
    let dir = tempfile::tempdir().unwrap();
    let project = pan_copy(dir.path());
    let before = (
        std::fs::read(&project).unwrap(),
        std::fs::metadata(&project).unwrap().modified().unwrap(),
    );
    let srv = Served::start(&project, &[]);
    let cases = [
        (serde_json::json!("not a list"), None),
        (serde_json::json!([{"no-such-step": {}}]), Some(0)),
        (
            serde_json::json!([{"spacing": {"threshold": 30}}, {"every-nth": {"n": 0}}]),
            Some(1),
        ),
        (
            serde_json::json!([{"blur": {}}, {"spacing": {"threshold": 30}}]),
            Some(1),
        ),
        (
            serde_json::json!([{"spacing": {"threshold": 30, "bogus": 1}}]),
            Some(0),
        ),
    ];
    for path in ["/api/apply", "/api/save", "/api/save-workflow"] {
        for (bad, step) in &cases {
            let (code, v) = srv.call("POST", path, Some(&steps(bad.clone())));
            assert_eq!(code, 400, "{path} {bad}: {v}");
            assert!(v["error"].as_str().is_some(), "{v}");
            if step.is_some() {
                assert_eq!(v["step"].as_u64().map(|i| i as usize), *step, "{bad}: {v}");
            }
        }
    }
    let host = format!("127.0.0.1:{}", srv.port);
    let origin = format!("http://{host}");
    let hdr = [
        ("Host", host.as_str()),
        ("X-Keyframer-Token", srv.token.as_str()),
        ("Origin", origin.as_str()),
    ];
    let (code, _) = raw(srv.port, "POST", "/api/save", &hdr, Some("{not json"));
    assert_eq!(code, 400);
    for view in [
        r#"{"from": 2.5, "to": 40}"#,
        r#"{"from": 50, "to": 10}"#,
        r#""all""#,
    ] {
        let body = format!(r#"{{"steps": [], "view": {view}}}"#);
        let (code, bytes) = raw(srv.port, "POST", "/api/apply", &hdr, Some(&body));
        assert_eq!(
            code,
            400,
            "view {view}: {}",
            String::from_utf8_lossy(&bytes)
        );
    }
    let body = r#"{"steps": [], "view": {"from": 10, "to": 40}}"#;
    let (code, bytes) = raw(srv.port, "POST", "/api/apply", &hdr, Some(body));
    let v: serde_json::Value = serde_json::from_slice(&bytes).unwrap();
    assert_eq!(
        (
            code,
            v["layout"]["from"].as_u64(),
            v["layout"]["to"].as_u64()
        ),
        (200, Some(10), Some(40)),
        "{v}"
    );
    // A save with a stale revision is refused too.
    let (code, v) = srv.call(
        "POST",
        "/api/save",
        Some(&serde_json::json!({"steps": [], "revision": 7})),
    );
    assert_eq!(code, 409, "{v}");
    let after = (
        std::fs::read(&project).unwrap(),
        std::fs::metadata(&project).unwrap().modified().unwrap(),
    );
    assert!(before == after, "the project file is untouched");
    assert!(!project.with_file_name("pan.workflow.toml").exists());
    let (code, _) = srv.call("GET", "/api/state", None);
    assert_eq!(code, 200, "the server still answers");
}

#[test]
fn review_save_equals_select_with_add() {
    let dir = tempfile::tempdir().unwrap();
    let project = pan_copy(&dir.path().join("a"));
    let other = pan_copy(&dir.path().join("b"));
    let srv = Served::start(&project, &[]);
    let (_, state) = srv.call("GET", "/api/state", None);
    let keys: Vec<u64> = state["selection"]["keyframes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|k| k.as_u64().unwrap())
        .collect();
    assert_eq!(
        keys,
        json(&project)["keyframes"]
            .as_array()
            .unwrap()
            .iter()
            .map(|k| k.as_u64().unwrap())
            .collect::<Vec<_>>(),
        "the page starts from the project's own selection"
    );
    let f = (1..119).find(|f| !keys.contains(f) && f % 7 == 3).unwrap();
    let chain = serde_json::json!([
        {"spacing": {"threshold": 30}},
        {"blur": {}},
        {"manual": {"add": [60, 61, f]}}
    ]);
    let (code, sel) = srv.call("POST", "/api/apply", Some(&steps(chain.clone())));
    assert_eq!(code, 200, "{sel}");
    let (code, saved) = srv.call("POST", "/api/save", Some(&steps(chain.clone())));
    assert_eq!(code, 200, "{saved}");
    assert_eq!(saved["revision"], 1);
    let add = format!("60,61,{f}");
    let clip = other.with_file_name("pan.mp4");
    let mut args = vec![
        "select",
        s(&clip),
        "-o",
        s(&other),
        "--spacing",
        "30",
        "--blur",
        "--add",
        &add,
        "--force",
    ];
    args.extend(PAN_ANALYSIS);
    let out = kf_loud(&args);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success() && err.contains("nothing decoded"),
        "{err}"
    );
    let (mine, theirs) = (json(&project), json(&other));
    assert_eq!(mine, theirs, "review's save equals select with --add");
    assert!(mine["keyframes"]
        .as_array()
        .unwrap()
        .contains(&serde_json::json!(f)));
    assert_eq!(
        sel["keyframes"], mine["keyframes"],
        "apply showed what save wrote"
    );
    // A second save from a stale page is refused; the saved file stays.
    let (code, _) = srv.call("POST", "/api/save", Some(&steps(serde_json::json!([]))));
    assert_eq!(code, 409);
    assert_eq!(json(&project), theirs);
    // The workflow of the same steps: `workflow check` accepts it, a second save needs force.
    let (code, w) = srv.call("POST", "/api/save-workflow", Some(&steps(chain.clone())));
    assert_eq!(code, 200, "{w}");
    let wf = project.with_file_name("pan.workflow.toml");
    let text = std::fs::read_to_string(&wf).unwrap();
    assert!(
        text.contains("plugin = \"spacing\"") && text.contains(&format!("{f}")),
        "{text}"
    );
    kf_ok(&["workflow", "check", s(&wf)]);
    let (code, _) = srv.call("POST", "/api/save-workflow", Some(&steps(chain)));
    assert_eq!(code, 409);
}

#[test]
fn review_stops_cleanly_on_sigint() {
    let dir = tempfile::tempdir().unwrap();
    let project = pan_copy(dir.path());
    let mut srv = Served::start(&project, &[]);
    let (code, _) = srv.call("GET", "/api/status", None);
    assert_eq!(code, 200);
    let before: Vec<_> = crate::common::listing(dir.path());
    let (code, err) = srv.stop();
    assert_eq!(code, 0, "{err}");
    assert!(err.contains("review stopped"), "{err}");
    let after: Vec<_> = crate::common::listing(dir.path());
    assert_eq!(before, after, "nothing left beside the project");
}

/// Fifty connections that send a request's headers with `Content-Length: 100000` and no body,
/// held open: half without the token (refused before the body), half with it (the server waits
/// for their bodies).
fn stall(srv: &Served) -> Vec<TcpStream> {
    let host = format!("127.0.0.1:{}", srv.port);
    let authed = format!("X-Keyframer-Token: {}\r\n", srv.token);
    (0..50)
        .map(|i| {
            let mut tcp = TcpStream::connect(("127.0.0.1", srv.port)).unwrap();
            let token = if i % 2 == 0 { authed.as_str() } else { "" };
            let head = format!(
                "POST /api/save HTTP/1.1\r\nHost: {host}\r\nOrigin: http://{host}\r\n{token}\
                 Content-Type: application/json\r\nContent-Length: 100000\r\n\r\n"
            );
            tcp.write_all(head.as_bytes()).unwrap();
            tcp
        })
        .collect()
}

#[test]
fn review_answers_within_a_second_while_fifty_connections_stall() {
    let dir = tempfile::tempdir().unwrap();
    let project = pan_copy(dir.path());
    let srv = Served::start(&project, &[]);
    let stalled = stall(&srv);
    let (port, token) = (srv.port, srv.token.clone());
    let (tx, rx) = std::sync::mpsc::channel();
    let started = Instant::now();
    std::thread::spawn(move || {
        let host = format!("127.0.0.1:{port}");
        let headers = [("Host", host.as_str()), ("X-Keyframer-Token", &token)];
        let _ = tx.send(raw(port, "GET", "/api/state", &headers, None));
    });
    let answer = rx.recv_timeout(Duration::from_secs(1));
    let took = started.elapsed();
    let (code, body) = answer.unwrap_or_else(|e| {
        panic!("no answer to GET /api/state within 1 s while 50 connections stall ({e})")
    });
    assert_eq!(code, 200, "{}", String::from_utf8_lossy(&body));
    let state: serde_json::Value = serde_json::from_slice(&body).unwrap();
    assert_eq!(state["input"]["frames"], 120, "{took:?}");
    drop(stalled);
}

#[test]
fn review_stops_within_a_second_on_sigint_while_fifty_connections_stall() {
    let dir = tempfile::tempdir().unwrap();
    let project = pan_copy(dir.path());
    let mut srv = Served::start(&project, &[]);
    let (code, _) = srv.call("GET", "/api/status", None);
    assert_eq!(code, 200);
    let stalled = stall(&srv);
    // Time for the server to take the connections and read their headers.
    std::thread::sleep(Duration::from_millis(500));
    let mut child = srv.child.take().unwrap();
    let started = Instant::now();
    sigint(&child);
    let status = loop {
        match child.try_wait().unwrap() {
            Some(status) => break Some(status),
            None if started.elapsed() > Duration::from_secs(1) => break None,
            None => std::thread::sleep(Duration::from_millis(10)),
        }
    };
    let took = started.elapsed();
    if status.is_none() {
        child.kill().unwrap();
        child.wait().unwrap();
    }
    drop(stalled);
    let err = std::fs::read_to_string(&srv.stderr).unwrap();
    let status = status.unwrap_or_else(|| panic!("still running {took:?} after SIGINT:\n{err}"));
    assert_eq!(status.code(), Some(0), "{err}");
    assert!(err.contains("review stopped"), "{err}");
}

#[test]
fn review_saves_after_an_outside_change_once_the_page_reloads() {
    let dir = tempfile::tempdir().unwrap();
    let project = pan_copy(&dir.path().join("a"));
    let other = pan_copy(&dir.path().join("b"));
    let srv = Served::start(&project, &[]);
    let (code, first) = srv.call("GET", "/api/state", None);
    assert_eq!(code, 200, "{first}");
    // Another program replaces the project while the page is open.
    select_pan(&project, &["--spacing", "40", "--blur"]);
    let chain = serde_json::json!([{"spacing": {"threshold": 35}}, {"blur": {}}]);
    let (code, v) = srv.call("POST", "/api/save", Some(&steps(chain.clone())));
    assert_eq!(code, 409, "{v}");
    let msg = v["error"].as_str().unwrap();
    assert!(msg.contains("reload the page"), "{msg}");
    // The page's reload asks for the state again: it shows the project now on disk.
    let (code, state) = srv.call("GET", "/api/state", None);
    assert_eq!(code, 200, "{state}");
    assert_eq!(
        state["selection"]["keyframes"],
        json(&project)["keyframes"],
        "the reloaded page shows the file on disk"
    );
    assert_ne!(
        state["selection"]["keyframes"],
        first["selection"]["keyframes"]
    );
    let body = serde_json::json!({"steps": chain, "revision": state["revision"]});
    let (code, saved) = srv.call("POST", "/api/save", Some(&body));
    assert_eq!(code, 200, "{saved}");
    select_pan(&other, &["--spacing", "35", "--blur"]);
    assert_eq!(
        json(&project),
        json(&other),
        "the save after the reload equals select with the same steps"
    );
}

#[test]
fn review_serves_frames_and_the_export_files_of_its_manifest() {
    let dir = tempfile::tempdir().unwrap();
    let project = pan_copy(dir.path());
    let export = dir.path().join("exp");
    kf_ok(&["export", s(&project), "--out", s(&export)]);
    let srv = Served::start(&project, &["--export", s(&export)]);
    let host = format!("127.0.0.1:{}", srv.port);
    let get = |path: &str| {
        raw(
            srv.port,
            "GET",
            &format!("{path}?token={}", srv.token),
            &[("Host", &host)],
            None,
        )
    };
    let keys = crate::common::keyframes(&project);
    let (code, jpeg) = get(&format!("/api/export/image/{}", keys[1]));
    assert_eq!(code, 200);
    let manifest = json(&export.join("manifest.json"));
    let file = manifest["frames"][1]["file"].as_str().unwrap();
    assert_eq!(
        jpeg,
        std::fs::read(export.join("images").join(file)).unwrap(),
        "the manifest's file, byte for byte"
    );
    let (code, _) = get("/api/export/mask/0");
    assert_eq!(code, 404, "no masks were exported");
    let non_key = (0..120).find(|f| !keys.contains(f)).unwrap();
    assert_eq!(get(&format!("/api/export/image/{non_key}")).0, 404);
    // Frames decode on demand: a JPEG of the frame at the strip width (160 px).
    for (f, size, width) in [(119, "strip", 160), (3, "large", 320)] {
        let (code, bytes) = raw(
            srv.port,
            "GET",
            &format!("/api/frame/{f}.jpg?size={size}&token={}", srv.token),
            &[("Host", &host)],
            None,
        );
        assert_eq!(code, 200, "{}", String::from_utf8_lossy(&bytes));
        let img = image::load_from_memory(&bytes).unwrap();
        assert_eq!(img.width(), width, "frame {f} {size}");
    }
    assert_eq!(get("/api/frame/120.jpg").0, 404);
    // A changed input is not decoded from: the page says why.
    let clip = project.with_file_name("pan.mp4");
    std::fs::write(&clip, b"no longer the video").unwrap();
    let srv2 = Served::start(&project, &[]);
    let host2 = format!("127.0.0.1:{}", srv2.port);
    let (code, body) = raw(
        srv2.port,
        "GET",
        &format!("/api/frame/5.jpg?token={}", srv2.token),
        &[("Host", &host2)],
        None,
    );
    assert_eq!(code, 503, "{}", String::from_utf8_lossy(&body));
}

#[test]
fn bench_review_prints_its_table() {
    let dir = tempfile::tempdir().unwrap();
    let out = kf_ok(&[
        "bench",
        "review",
        "--review-frames",
        "600",
        "--dir",
        s(dir.path()),
    ]);
    for row in [
        "step chain on the cached series",
        "chain + timeline SVG",
        "POST /api/apply over HTTP",
    ] {
        assert!(out.contains(row), "{out}");
    }
    assert_eq!(
        crate::common::listing(dir.path()),
        vec!["review-bench.json".to_string()],
        "writes only its project into --dir"
    );
}

// ----- the page in headless Chromium ------------------------------------------------------------

/// How long the page may take for one step (load, one apply, one save).
const PAGE_WAIT: Duration = Duration::from_secs(20);

/// Opens the page of `srv` and waits until its first selection is drawn, failing on a script
/// error.
fn open_page<'b>(browser: &'b Browser, srv: &Served) -> Tab<'b> {
    let tab = browser.open(&srv.url);
    tab.wait_for(
        "document.body.dataset.ready || document.body.dataset.scriptError",
        PAGE_WAIT,
    )
    .unwrap();
    assert_clean(&tab);
    tab
}

/// No script error marked by the page, none collected by the harness.
fn assert_clean(tab: &Tab) {
    assert_eq!(
        tab.eval("document.body.dataset.scriptError || null"),
        serde_json::Value::Null
    );
    assert_eq!(tab.errors(), Vec::<String>::new());
}

/// The keyframe count the page shows.
fn page_count(tab: &Tab) -> usize {
    let v = tab.eval("Number(document.getElementById('kf-count').dataset.count)");
    v.as_u64().expect("a count") as usize
}

/// Waits until the keyframe count the page shows is (`op` "===") or is no longer ("!==") `n`.
fn wait_count(tab: &Tab, op: &str, n: usize, within: Duration) {
    let js = format!("document.getElementById('kf-count').dataset.count {op} '{n}'");
    tab.wait_for(&js, within).unwrap();
}

/// How many selections the page has drawn.
fn redraws(tab: &Tab) -> u64 {
    let v = tab.eval("Number(document.body.dataset.redraws || 0)");
    v.as_u64().unwrap_or(0)
}

/// Types `value` into the step editor's input `name` of step `plugin` (replacing its text) and
/// presses Enter; waits until the page has drawn the selection this gives.
fn set_param(tab: &Tab, plugin: &str, name: &str, value: &str) {
    let before = redraws(tab);
    let sel = format!("#step-{plugin} [name={name}]");
    let found = tab.eval(&format!(
        "(el => {{ if (!el) return false; el.scrollIntoView(); el.focus(); el.select(); return true; }})(document.querySelector('{sel}'))"
    ));
    assert_eq!(found, serde_json::json!(true), "{sel} in the editor");
    tab.type_text(value);
    tab.key("Enter");
    tab.wait_for(
        &format!("Number(document.body.dataset.redraws || 0) > {before}"),
        PAGE_WAIT,
    )
    .unwrap();
}

/// The JSON paths where `a` and `b` differ, with both values (short).
fn differences(a: &serde_json::Value, b: &serde_json::Value, at: &str) -> Vec<String> {
    use serde_json::Value;
    match (a, b) {
        (Value::Object(x), Value::Object(y)) => {
            let mut keys: Vec<&String> = x.keys().chain(y.keys()).collect();
            keys.sort();
            keys.dedup();
            (keys.into_iter())
                .flat_map(|k| {
                    let null = Value::Null;
                    let (u, v) = (x.get(k).unwrap_or(&null), y.get(k).unwrap_or(&null));
                    differences(u, v, &format!("{at}.{k}"))
                })
                .collect()
        }
        (Value::Array(x), Value::Array(y)) if x.len() == y.len() => (x.iter().zip(y))
            .enumerate()
            .flat_map(|(i, (u, v))| differences(u, v, &format!("{at}[{i}]")))
            .collect(),
        _ if a == b => vec![],
        _ => {
            let short = |v: &Value| v.to_string().chars().take(200).collect::<String>();
            vec![format!("{at}: {} vs {}", short(a), short(b))]
        }
    }
}

/// The centre of the element `selector` in viewport pixels (scrolled into view first).
fn centre(tab: &Tab, selector: &str) -> (f64, f64) {
    let v = tab.eval(&format!(
        "(el => {{ el.scrollIntoView({{block: 'center'}}); const r = el.getBoundingClientRect(); return [r.left + r.width / 2, r.top + r.height / 2]; }})(document.querySelector('{selector}'))"
    ));
    (v[0].as_f64().unwrap(), v[1].as_f64().unwrap())
}

/// Runs `select` on the pan clip beside `project` with the steps `flags` and the fixture's
/// analysis, replacing `project`; it must reuse the cache.
fn select_pan(project: &Path, flags: &[&str]) {
    let clip = project.with_file_name("pan.mp4");
    let mut args = vec!["select", s(&clip), "-o", s(project), "--force"];
    args.extend(flags);
    args.extend(PAN_ANALYSIS);
    let out = kf_loud(&args);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success() && err.contains("nothing decoded"),
        "{err}"
    );
}

#[test]
fn review_page_threshold_change_gives_select_count() {
    let Some(browser) = Browser::launch() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let project = pan_copy(&dir.path().join("a"));
    let other = pan_copy(&dir.path().join("b"));
    select_pan(&other, &["--spacing", "40", "--blur", "--add", "60,61"]);
    let want = keyframes(&other).len();
    let srv = Served::start(&project, &[]);
    let tab = open_page(&browser, &srv);
    let first = page_count(&tab);
    assert_eq!(first, keyframes(&project).len(), "the project's own count");
    assert_ne!(
        first, want,
        "spacing 40 must change the count for this test to see it"
    );
    set_param(&tab, "spacing", "threshold", "40");
    wait_count(&tab, "!==", first, PAGE_WAIT);
    assert_eq!(page_count(&tab), want, "the page's count is select's");
    assert_clean(&tab);
}

#[test]
fn review_page_click_adds_keyframe_and_save_finds_it() {
    let Some(browser) = Browser::launch() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let project = pan_copy(&dir.path().join("a"));
    let other = pan_copy(&dir.path().join("b"));
    let srv = Served::start(&project, &[]);
    let tab = open_page(&browser, &srv);
    let second = open_page(&browser, &srv);
    let keys = keyframes(&project);
    let first = page_count(&tab);
    assert_eq!(first, keys.len());
    // A frame between two keyframes, away from both (at 120 frames a frame is 9 px wide).
    let f = (2..118)
        .find(|f| !keys.contains(f) && !keys.contains(&(f - 1)) && !keys.contains(&(f + 1)))
        .unwrap();
    tab.eval("document.getElementById('timeline').scrollIntoView()");
    let x = tab.eval(&format!("kfTest.frameX({f})")).as_f64().unwrap();
    let y = tab
        .eval("(r => r.top + r.height / 4)(document.querySelector('#timeline svg').getBoundingClientRect())")
        .as_f64()
        .unwrap();
    assert_eq!(
        tab.eval(&format!("kfTest.frameAt({x})")),
        serde_json::json!(f),
        "the page maps the x back to frame {f}"
    );
    tab.click(x, y);
    wait_count(&tab, "===", first + 1, PAGE_WAIT);
    assert!(tab
        .eval("kfTest.keyframes()")
        .as_array()
        .unwrap()
        .contains(&serde_json::json!(f)));
    assert_eq!(tab.eval("document.body.dataset.dirty"), "1", "unsaved");
    let (sx, sy) = centre(&tab, "#save");
    tab.click(sx, sy);
    tab.wait_for("document.body.dataset.revision === '1'", PAGE_WAIT)
        .unwrap();
    assert_clean(&tab);

    let saved = json(&project);
    assert!(
        saved["keyframes"]
            .as_array()
            .unwrap()
            .contains(&serde_json::json!(f)),
        "frame {f} saved: {}",
        saved["keyframes"]
    );
    let add = format!("60,61,{f}");
    select_pan(&other, &["--spacing", "25", "--blur", "--add", &add]);
    let theirs = json(&other);
    assert!(
        saved == theirs,
        "the page's save differs from select --add at {:?}",
        differences(&saved, &theirs, "")
    );

    // The other tab sees the save at its next poll.
    wait_count(&second, "===", first + 1, Duration::from_secs(3));
    assert_eq!(second.eval("document.body.dataset.revision"), "1");
    assert_clean(&second);
}

#[test]
fn review_page_screenshot_shows_timeline() {
    let Some(browser) = Browser::launch() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let project = pan_copy(dir.path());
    let srv = Served::start(&project, &[]);
    let tab = open_page(&browser, &srv);
    // The preview of the cursor's frame, decoded on demand, and the strip.
    tab.wait_for(
        "(im => im.complete && im.naturalWidth > 0)(document.getElementById('preview-image'))",
        PAGE_WAIT,
    )
    .unwrap();
    let strip_loaded = tab.wait_for(
        "[...document.querySelectorAll('#strip img')].every(im => im.complete && im.naturalWidth > 0)",
        PAGE_WAIT,
    );
    assert!(
        strip_loaded.is_ok(),
        "{strip_loaded:?}: {}",
        tab.eval("JSON.stringify([...document.querySelectorAll('#strip img')].map(im => [im.src.replace(/token=.*/, ''), im.complete, im.naturalWidth, im.getBoundingClientRect().width]))")
    );
    let strip = tab.eval("document.querySelectorAll('#strip img').length");
    assert!(strip.as_u64().unwrap() >= 2, "strip frames: {strip}");
    let png = tab.screenshot_png();
    if let Some(path) = std::env::var_os("KEYFRAMER_README_SHOT") {
        std::fs::write(&path, &png).unwrap();
        eprintln!("screenshot written to {}", Path::new(&path).display());
    }
    let img = image::load_from_memory(&png).unwrap().to_rgb8();
    let var = crate::report::luminance_variance(&img);
    assert!(var > 100.0, "screenshot looks blank (variance {var:.1})");
    let r = tab.eval(
        "(r => [r.left, r.top, r.right, r.bottom])(document.getElementById('timeline').getBoundingClientRect())",
    );
    let b: Vec<u32> = (0..4)
        .map(|i| r[i].as_f64().unwrap().round().max(0.0) as u32)
        .collect();
    let (x1, y1) = (b[2].min(img.width()), b[3].min(img.height()));
    assert!(x1 > b[0] + 100 && y1 > b[1] + 50, "timeline box {b:?}");
    let keyframe_pixels = (b[0]..x1)
        .flat_map(|x| (b[1]..y1).map(move |y| (x, y)))
        .filter(|&(x, y)| {
            let p = img.get_pixel(x, y).0;
            (0..3).all(|c| (i32::from(p[c]) - i32::from(KEYFRAME_RGB[c])).abs() <= 12)
        })
        .count();
    assert!(
        keyframe_pixels > 100,
        "{keyframe_pixels} keyframe-coloured pixels in the timeline box {b:?}"
    );
    assert_clean(&tab);
}

#[test]
fn review_page_disables_steps_the_cache_lacks() {
    let Some(browser) = Browser::launch() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let pan = pan_copy(dir.path());
    let project = dir.path().join("blur.json");
    let clip = pan.with_file_name("pan.mp4");
    let mut args = vec!["select", s(&clip), "-o", s(&project), "--blur"];
    args.extend(PAN_ANALYSIS);
    kf_ok(&args);
    assert_eq!(
        json(&project)["cache"]["movement"],
        serde_json::json!([]),
        "no movement cached"
    );
    let srv = Served::start(&project, &[]);
    let tab = open_page(&browser, &srv);
    let (cx, cy) = centre(&tab, "#step-spacing [name=enabled]");
    let before = redraws(&tab);
    tab.click(cx, cy);
    tab.wait_for(
        &format!("Number(document.body.dataset.redraws) > {before}"),
        PAGE_WAIT,
    )
    .unwrap();
    let row = tab.eval(
        "(f => [f.className, (f.querySelector('code') || {}).textContent || ''])(document.getElementById('step-spacing'))",
    );
    assert_eq!(row[0], "disabled", "{row}");
    let code = row[1].as_str().unwrap();
    assert!(
        code.contains("keyframer select") && code.contains("--spacing"),
        "{code}"
    );
    assert_clean(&tab);

    // Keyboard (the focus is on the checkbox just clicked): → moves the cursor, k toggles the
    // keyframe there, Ctrl+Z undoes it.
    let info = || tab.eval("document.getElementById('view-info').textContent");
    let at = info();
    assert!(at.as_str().unwrap().starts_with("frame 0"), "{at}");
    tab.key("ArrowRight");
    tab.wait_for(
        "document.getElementById('view-info').textContent.startsWith('frame 1')",
        PAGE_WAIT,
    )
    .unwrap();
    let count = page_count(&tab);
    tab.key("k");
    wait_count(&tab, "!==", count, PAGE_WAIT);
    let toggled = page_count(&tab);
    assert_eq!(toggled.abs_diff(count), 1, "k toggles one keyframe");
    tab.key("Control+z");
    wait_count(&tab, "===", count, PAGE_WAIT);
    // + zooms in around the cursor (frame 1) to half the frames, 0 shows every frame again.
    tab.key("+");
    let view = "(m => m && [Number(m[1]), Number(m[2])])(document.getElementById('view-info').textContent.match(/view (\\d+)–(\\d+)$/))";
    tab.wait_for(
        &format!("(v => v && v[0] <= 1 && v[1] >= 1 && v[1] - v[0] < 80)({view})"),
        PAGE_WAIT,
    )
    .unwrap();
    tab.key("0");
    tab.wait_for(
        "document.getElementById('view-info').textContent.endsWith('view 0–119')",
        PAGE_WAIT,
    )
    .unwrap();
    assert_clean(&tab);
}

#[test]
fn review_redraw_time_is_printed() {
    let Some(browser) = Browser::launch() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let project = dir.path().join("synthetic.json");
    keyframer::review::bench::synthetic_project(10_000)
        .unwrap()
        .save(&project, true)
        .unwrap();
    let srv = Served::start(&project, &[]);
    let tab = open_page(&browser, &srv);
    assert_eq!(
        tab.eval("document.getElementById('kf-count').textContent.includes('10000 frames')"),
        serde_json::json!(true)
    );
    let (mut redraw, mut server) = (Vec::new(), Vec::new());
    for i in 0..10 {
        set_param(&tab, "spacing", "threshold", &format!("{}", 150 + 10 * i));
        redraw.push(tab.eval("window.kfLastRedrawMs").as_f64().unwrap());
        server.push(tab.eval("window.kfLastServerMs").as_f64().unwrap());
    }
    assert_clean(&tab);
    let stats = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        (v[v.len() / 2], v[v.len() - 1])
    };
    let ((rm, rx), (sm, sx)) = (stats(&mut redraw), stats(&mut server));
    println!(
        "review page, 10000 frames, 10 threshold changes: redraw median {rm:.1} ms, max {rx:.1} ms; \
         server median {sm:.1} ms, max {sx:.1} ms"
    );
}

/// A step that refuses for a reason of its own (footprint-overlap with no field of view: the
/// telemetry has no focal length, the camera is unknown) makes the answer that error, with no
/// `select` command (it would fail the same way); a step over positions the input lacks is left
/// out with its reason and no command either (`select` reads the same telemetry); a series
/// `select` measures (a sharpness metric not cached) is left out with the command.
#[test]
fn review_shows_a_steps_own_refusal_and_offers_select_only_when_it_would_work() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("flight");
    crate::common::scene_ok(&[
        s(&dir),
        "--size",
        "160x90",
        "--fps",
        "30",
        "--seconds",
        "4",
        "--blur-samples",
        "1",
        "--pitch",
        "90",
    ]);
    let srt = dir.join("video.SRT");
    let text = crate::telemetry::without_focal(&std::fs::read_to_string(&srt).unwrap());
    assert!(!text.contains("focal_len"));
    std::fs::write(&srt, text).unwrap();
    let project = tmp.path().join("p.json");
    let video = dir.join("video.mp4");
    kf_ok(&[
        "select",
        s(&video),
        "-o",
        s(&project),
        "--geo-distance",
        "5",
    ]);
    let positions = &json(&project)["cache"]["telemetry"]["positions"];
    assert!(positions[0].is_object(), "{positions}");
    let srv = Served::start(&project, &[]);
    let apply = |steps: serde_json::Value| {
        srv.call(
            "POST",
            "/api/apply",
            Some(&serde_json::json!({ "steps": steps })),
        )
    };
    let (code, v) = apply(serde_json::json!([{"footprint-overlap": {"percent": 80}}]));
    assert_eq!(code, 400, "{}", v["steps_state"]);
    let error = v["error"].as_str().unwrap();
    assert!(
        error.contains("no field of view") && error.contains("give --hfov"),
        "{v}"
    );
    assert!(!v.to_string().contains("keyframer select"), "{v}");
    assert_eq!(v["step"].as_u64(), Some(0), "{v}");
    let (code, v) = apply(serde_json::json!([{"footprint-overlap": {"percent": 80, "hfov": 70}}]));
    assert_eq!(code, 200, "{}", v["error"]);
    assert_eq!(v["steps_state"][0]["enabled"], true, "{}", v["steps_state"]);
    let (code, v) = apply(serde_json::json!([{"blur": {"metric": "laplacian-k3"}}]));
    assert_eq!(code, 200, "{}", v["error"]);
    let state = &v["steps_state"][0];
    assert_eq!(state["enabled"], false, "{state}");
    let command = state["command"].as_str().unwrap();
    assert!(
        command.contains("keyframer select") && command.contains("--blur"),
        "{state}"
    );

    let pan = pan_copy(&tmp.path().join("pan"));
    let srv = Served::start(&pan, &[]);
    let body = serde_json::json!({"steps": [{"geo-distance": {"metres": 5}}]});
    let (code, v) = srv.call("POST", "/api/apply", Some(&body));
    assert_eq!(code, 200, "{}", v["error"]);
    let state = &v["steps_state"][0];
    assert_eq!(state["enabled"], false, "{state}");
    assert!(
        state["reason"].as_str().unwrap().contains("--telemetry"),
        "{state}"
    );
    assert!(state["command"].is_null(), "{state}");
}

/// A project `reconstruct` made (its history ends with the recorded step, frame F added): the
/// page shows the step as recorded with its frame and reason, the timeline draws F in the added
/// colour, and toggling the other steps (another chain, a manual removal of F) keeps F and the
/// record; a save writes both.
/// The pan project in `dir` as if `reconstruct` had added frame F (a frame it does not keep,
/// 30..90): F joins its keyframes and the recorded step ends its history. Returns the project,
/// F, the reason and the history entry.
fn with_recorded_reconstruct(dir: &Path) -> (PathBuf, u64, String, serde_json::Value) {
    let project = pan_copy(dir);
    let mut p = json(&project);
    let keys: Vec<u64> = p["keyframes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|k| k.as_u64().unwrap())
        .collect();
    let f = (30..90).find(|f| !keys.contains(f)).unwrap();
    let reason = format!("repairs keyframes {}–{} (split): test", f - 1, f + 1);
    let mut with_f = keys.clone();
    with_f.push(f);
    with_f.sort_unstable();
    p["keyframes"] = serde_json::json!(with_f);
    let step = serde_json::json!({
        "plugin": "reconstruct",
        "params": {
            "rounds": 2,
            "added": [{"frame": f, "round": 1, "reason": reason}],
            "colmap_version": "COLMAP 3.8",
            "options": ["--max-rounds 4"],
        },
        "kept": with_f.len(),
    });
    p["history"].as_array_mut().unwrap().push(step.clone());
    std::fs::write(&project, serde_json::to_string_pretty(&p).unwrap()).unwrap();
    (project, f, reason, step)
}

#[test]
fn review_keeps_the_frames_reconstruct_added() {
    let dir = tempfile::tempdir().unwrap();
    let (project, f, reason, step) = with_recorded_reconstruct(dir.path());
    let with_f = json(&project)["keyframes"].clone();
    let srv = Served::start(&project, &[]);
    let (code, state) = srv.call("GET", "/api/state", None);
    assert_eq!(code, 200, "{state}");
    let sel = &state["selection"];
    assert_eq!(sel["keyframes"], with_f, "{sel}");
    let rec = &sel["recorded"][0];
    assert_eq!(rec["plugin"], "reconstruct", "{sel}");
    assert_eq!(rec["added"][0]["frame"], f);
    assert_eq!(rec["added"][0]["reason"], reason.as_str());
    assert!(rec["note"].as_str().unwrap().contains("stay"), "{rec}");
    assert_eq!(sel["history"].as_array().unwrap().last().unwrap(), &step);
    // The editable steps are the project's others; the recorded one is not among them.
    let editable = state["steps"].clone();
    assert!(!editable.to_string().contains("reconstruct"), "{editable}");

    // Other steps toggled: blur off, and F removed by hand; F and the record stay.
    let chain = serde_json::json!([
        {"spacing": {"threshold": 30}},
        {"manual": {"remove": [f]}}
    ]);
    let (code, applied) = srv.call("POST", "/api/apply", Some(&steps(chain.clone())));
    assert_eq!(code, 200, "{applied}");
    let kf: Vec<u64> = applied["keyframes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|k| k.as_u64().unwrap())
        .collect();
    assert!(kf.contains(&f), "{kf:?}");
    assert_eq!(applied["recorded"][0]["added"][0]["frame"], f);
    let svg = applied["timeline_svg"].as_str().unwrap();
    let added = format!(r#"<g class="kf added" data-frame="{f}""#);
    assert_eq!(svg.matches(r#"<g class="kf added""#).count(), 1, "{svg}");
    assert!(svg.contains(&added) && svg.contains(&reason), "{svg}");

    // A save keeps the frame and the record after the steps that ran.
    let (code, saved) = srv.call("POST", "/api/save", Some(&steps(chain)));
    assert_eq!(code, 200, "{saved}");
    let after = json(&project);
    assert_eq!(after["keyframes"], applied["keyframes"]);
    let history = after["history"].as_array().unwrap();
    assert_eq!(history.last().unwrap()["plugin"], "reconstruct");
    assert_eq!(history.last().unwrap()["params"], step["params"]);
    assert_eq!(history.last().unwrap()["kept"], kf.len());
}

/// The page lists the recorded `reconstruct` step with its frame and reason, draws the frame in
/// the added colour, and a `k` on that frame says it stays instead of removing it.
#[test]
fn review_page_shows_the_recorded_reconstruct_step() {
    let Some(browser) = Browser::launch() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let (project, f, reason, _) = with_recorded_reconstruct(dir.path());
    let srv = Served::start(&project, &[]);
    let tab = open_page(&browser, &srv);
    let row = tab.eval(&format!(
        "(r => r && [r.className, r.querySelector('legend').textContent, (r.querySelector('li[data-frame=\"{f}\"]') || {{}}).textContent || ''])(document.getElementById('step-reconstruct'))"
    ));
    assert_eq!(row[0], "recorded", "{row}");
    assert!(row[1].as_str().unwrap().contains("1 added"), "{row}");
    let item = row[2].as_str().unwrap();
    assert!(
        item.contains(&format!("frame {f}")) && item.contains(&reason),
        "{row}"
    );
    let bar = tab.eval(&format!(
        "!!document.querySelector('#timeline g.kf.added[data-frame=\"{f}\"]')"
    ));
    assert_eq!(bar, serde_json::json!(true), "the added frame's bar");
    // The list moves the cursor to the frame; `k` there keeps it and says why.
    let count = page_count(&tab);
    let (cx, cy) = centre(&tab, &format!("#step-reconstruct li[data-frame=\"{f}\"]"));
    tab.click(cx, cy);
    tab.wait_for(
        &format!("document.getElementById('view-info').textContent.startsWith('frame {f}')"),
        PAGE_WAIT,
    )
    .unwrap();
    tab.key("k");
    tab.wait_for(
        "document.getElementById('status').textContent.includes('stays')",
        PAGE_WAIT,
    )
    .unwrap();
    assert_eq!(page_count(&tab), count);
    assert_clean(&tab);
}
