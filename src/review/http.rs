//! The review server: binds 127.0.0.1 only and answers a request only when its Host (and
//! Origin, required on POST) name that address, it carries the session's random token, and its
//! path is one of the exact routes below (no route takes a file path: frames are indices, export
//! files come from the manifest). Every refusal is logged without the token. The HTTP crate
//! (tiny_http) is used only in this file.

use super::{parse_steps, ApiError, ApiResult, Review};
use crate::error::{Error, Result};
use crate::source::FrameSize;
use serde_json::{json, Value};
use std::io::Read;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;
use tiny_http::{Header, Method, Request, Response, Server};

/// A response with its whole body in memory.
type Reply = Response<std::io::Cursor<Vec<u8>>>;

/// Request bodies above this are refused.
const MAX_BODY: u64 = 1 << 20;

/// Worker threads answering requests (frame requests go on to the one decode thread).
const WORKERS: usize = 2;

/// The page and its assets, embedded in the binary.
const ASSETS: [(&str, &str, &str); 3] = [
    (
        "/",
        "text/html; charset=utf-8",
        include_str!("../../templates/review/index.html"),
    ),
    (
        "/assets/review.js",
        "text/javascript; charset=utf-8",
        include_str!("../../templates/review/review.js"),
    ),
    (
        "/assets/review.css",
        "text/css; charset=utf-8",
        include_str!("../../templates/review/review.css"),
    ),
];

/// A bound server, not yet answering.
pub struct Served {
    server: Arc<Server>,
    review: Arc<Review>,
    token: String,
    port: u16,
    stop: Arc<AtomicBool>,
}

/// Stops a running server from another thread (a Ctrl-C handler).
#[derive(Clone)]
pub struct Stopper {
    server: Arc<Server>,
    stop: Arc<AtomicBool>,
}

impl Stopper {
    pub fn stop(&self) {
        self.stop.store(true, Ordering::SeqCst);
        for _ in 0..WORKERS {
            self.server.unblock();
        }
    }
}

impl Served {
    /// Binds 127.0.0.1:`port` (0: a free port) with a new random token.
    pub fn bind(review: Review, port: u16) -> Result<Served> {
        let server = Server::http(("127.0.0.1", port))
            .map_err(|e| Error::param("port", format!("cannot listen on 127.0.0.1:{port}: {e}")))?;
        let port = (server.server_addr().to_ip())
            .map(|a| a.port())
            .unwrap_or(port);
        let mut bytes = [0u8; 16];
        getrandom::fill(&mut bytes)
            .map_err(|e| Error::param("token", format!("no random source for a token: {e}")))?;
        Ok(Served {
            server: Arc::new(server),
            review: Arc::new(review),
            token: bytes.iter().map(|b| format!("{b:02x}")).collect(),
            port,
            stop: Arc::new(AtomicBool::new(false)),
        })
    }

    /// The page's address with the token.
    pub fn url(&self) -> String {
        format!("http://127.0.0.1:{}/?token={}", self.port, self.token)
    }

    pub fn port(&self) -> u16 {
        self.port
    }

    pub fn token(&self) -> &str {
        &self.token
    }

    pub fn stopper(&self) -> Stopper {
        Stopper {
            server: self.server.clone(),
            stop: self.stop.clone(),
        }
    }

    /// Answers requests until stopped; each worker finishes the request it is answering. Frame
    /// requests queue for one decode thread (a seek far into a long video can take seconds), so
    /// step edits keep answering while frames decode.
    pub fn run(self) {
        let this = Arc::new(self);
        let (frames, queued) = std::sync::mpsc::channel::<Request>();
        let decoder = {
            let this = this.clone();
            std::thread::spawn(move || queued.iter().for_each(|rq| this.answer(rq)))
        };
        let workers: Vec<_> = (0..WORKERS)
            .map(|_| {
                let (this, frames) = (this.clone(), frames.clone());
                std::thread::spawn(move || {
                    while !this.stop.load(Ordering::SeqCst) {
                        match this.server.recv() {
                            Ok(rq) if rq.url().starts_with("/api/frame/") => {
                                if let Err(e) = frames.send(rq) {
                                    this.answer(e.0);
                                }
                            }
                            Ok(rq) => this.answer(rq),
                            Err(_) if this.stop.load(Ordering::SeqCst) => break,
                            Err(e) => log::warn!("review: {e}"),
                        }
                    }
                })
            })
            .collect();
        drop(frames);
        for w in workers.into_iter().chain([decoder]) {
            if w.join().is_err() {
                log::warn!("review: a worker thread panicked");
            }
        }
    }

    fn answer(&self, mut rq: Request) {
        let started = Instant::now();
        let (method, url) = (rq.method().clone(), rq.url().to_string());
        let path = url.split('?').next().unwrap_or("").to_string();
        let reply = (self.admit(&rq, &url)).and_then(|()| self.route(&mut rq, &method, &path));
        let response = match reply {
            Ok(r) => r,
            Err(e) => {
                if e.status < 500 {
                    let peer = rq.remote_addr().map(|a| a.to_string()).unwrap_or_default();
                    log::warn!("review: refused {method} {path} from {peer}: {}", e.error);
                } else {
                    log::error!("review: {method} {path}: {}", e.error);
                }
                json_reply(e.status, &e.body())
            }
        };
        if let Err(e) = respond_and_close(rq, response) {
            log::debug!("review: {method} {path}: {e}");
        }
        log::debug!("review: {method} {path} in {:?}", started.elapsed());
    }

    /// Host, Origin and token checks, and the path's form.
    fn admit(&self, rq: &Request, url: &str) -> ApiResult<()> {
        let own = [
            format!("127.0.0.1:{}", self.port),
            format!("localhost:{}", self.port),
        ];
        let header = |name: &'static str| {
            (rq.headers().iter())
                .find(|h| h.field.equiv(name))
                .map(|h| h.value.as_str().to_string())
        };
        if !header("Host").is_some_and(|h| own.contains(&h)) {
            return Err(ApiError::new(403, "foreign Host header"));
        }
        match header("Origin") {
            Some(o) if !own.iter().any(|h| o == format!("http://{h}")) => {
                return Err(ApiError::new(403, "cross-origin request"))
            }
            None if *rq.method() != Method::Get => {
                return Err(ApiError::new(403, "a POST needs an Origin header"))
            }
            _ => {}
        }
        if header("Sec-Fetch-Site").is_some_and(|s| s != "same-origin" && s != "none") {
            return Err(ApiError::new(403, "cross-site request"));
        }
        let lower = url.to_ascii_lowercase();
        let bad = ["..", "%2e", "%2f", "%5c", "\\", "//", "%00"];
        if bad.iter().any(|b| lower.contains(b)) {
            return Err(ApiError::new(400, "path not allowed"));
        }
        let path = url.split('?').next().unwrap_or("");
        let in_query = (path == "/"
            || path.starts_with("/assets/")
            || path.starts_with("/api/frame/")
            || path.starts_with("/api/export/"))
        .then(|| query(url, "token"))
        .flatten();
        let given = header("X-Keyframer-Token").or(in_query);
        match given {
            Some(t) if same(&t, &self.token) => Ok(()),
            Some(_) => Err(ApiError::new(401, "wrong token")),
            None => Err(ApiError::new(401, "no token")),
        }
    }

    fn route(&self, rq: &mut Request, method: &Method, path: &str) -> ApiResult<Reply> {
        let review = &self.review;
        let parts: Vec<&str> = path.trim_start_matches('/').split('/').collect();
        match (method, parts.as_slice()) {
            (Method::Get, _) if ASSETS.iter().any(|a| a.0 == path) => {
                let (_, mime, body) = ASSETS
                    .into_iter()
                    .find(|a| a.0 == path)
                    .unwrap_or(ASSETS[0]);
                let body = body.replace("{{TOKEN}}", &self.token);
                Ok(reply(200, mime, body.into_bytes()))
            }
            (Method::Get, ["api", "state"]) => Ok(json_reply(200, &review.state()?)),
            (Method::Get, ["api", "status"]) => Ok(json_reply(200, &review.status())),
            (Method::Post, ["api", "apply"]) => {
                let body = body(rq)?;
                let steps = parse_steps(&body["steps"])?;
                Ok(json_reply(
                    200,
                    &review.apply(&steps, view_of(&body["view"])?)?,
                ))
            }
            (Method::Post, ["api", "save"]) => {
                let body = body(rq)?;
                let steps = parse_steps(&body["steps"])?;
                let revision = body["revision"].as_u64().unwrap_or(u64::MAX);
                let revision = review.save(&steps, revision)?;
                let count = review.project().keyframes.len();
                let saved = review.path().display().to_string();
                Ok(json_reply(
                    200,
                    &json!({"saved": saved, "revision": revision, "count": count}),
                ))
            }
            (Method::Post, ["api", "save-workflow"]) => {
                let body = body(rq)?;
                let steps = parse_steps(&body["steps"])?;
                let force = body["force"].as_bool().unwrap_or(false);
                let saved = review.save_workflow(&steps, force)?;
                Ok(json_reply(200, &json!({"saved": saved})))
            }
            (Method::Get, ["api", "frame", index]) => {
                let index = index_of(index)?;
                let size = match query(rq.url(), "size").as_deref() {
                    Some("large") => FrameSize::Large,
                    _ => FrameSize::Strip,
                };
                let jpeg = review.frame(index, size)?;
                Ok(reply(200, "image/jpeg", jpeg.to_vec()))
            }
            (Method::Get, ["api", "export", kind, index]) => {
                let index = index_of(index)?;
                let file = review.export_file(kind, index)?;
                let bytes = std::fs::read(&file).map_err(|e| ApiError::new(404, e.to_string()))?;
                let mime = match file.extension().and_then(|e| e.to_str()) {
                    Some("png") => "image/png",
                    _ => "image/jpeg",
                };
                Ok(reply(200, mime, bytes))
            }
            _ => Err(ApiError::new(404, format!("no route {method} {path}"))),
        }
    }
}

/// Writes `response` with `Connection: close`, so that the browser opens a new connection for
/// its next request. tiny_http (0.12) serves each connection on one thread of its pool for as long
/// as the connection lives, and two connections accepted in quick succession can both be queued
/// for a single idle thread: the second then waits until some other connection closes (seen as
/// strip images of the page that never load). A connection per request ends each pool task as
/// soon as its answer is written. tiny_http refuses a `Connection` header in a `Response`, hence
/// the status line and headers written here.
fn respond_and_close(rq: Request, response: Reply) -> std::io::Result<()> {
    use std::io::Write;
    let status = response.status_code();
    let mut head = format!(
        "HTTP/1.1 {} {}\r\n",
        status.0,
        status.default_reason_phrase()
    );
    for h in response.headers() {
        head += &format!("{}: {}\r\n", h.field, h.value);
    }
    let body = response.into_reader().into_inner();
    head += &format!(
        "Content-Length: {}\r\nConnection: close\r\n\r\n",
        body.len()
    );
    let mut w = rq.into_writer();
    w.write_all(head.as_bytes())?;
    w.write_all(&body)?;
    w.flush()
}

/// The frames to show, `{"from": F, "to": T}` (absent or null: all of them).
fn view_of(v: &Value) -> ApiResult<Option<(usize, usize)>> {
    if v.is_null() {
        return Ok(None);
    }
    match (v["from"].as_u64(), v["to"].as_u64()) {
        (Some(a), Some(b)) if a <= b => Ok(Some((a as usize, b as usize))),
        _ => Err(ApiError::new(
            400,
            format!("view: give whole frame numbers from <= to, got {v}"),
        )),
    }
}

/// A frame index in a path segment (`12` or `12.jpg`).
fn index_of(s: &str) -> ApiResult<usize> {
    let digits = s.strip_suffix(".jpg").unwrap_or(s);
    digits
        .parse()
        .map_err(|_| ApiError::new(404, format!("`{s}` is not a frame index")))
}

/// The request's JSON body (at most [`MAX_BODY`] bytes).
fn body(rq: &mut Request) -> ApiResult<Value> {
    let mut text = Vec::new();
    let read = rq.as_reader().take(MAX_BODY + 1).read_to_end(&mut text);
    if read.is_err() || text.len() as u64 > MAX_BODY {
        return Err(ApiError::new(400, "request body unreadable or over 1 MiB"));
    }
    serde_json::from_slice(&text).map_err(|e| ApiError::new(400, format!("request body: {e}")))
}

/// The value of `key` in the URL's query.
fn query(url: &str, key: &str) -> Option<String> {
    let q = url.split_once('?')?.1;
    q.split('&')
        .filter_map(|kv| kv.split_once('='))
        .find(|(k, _)| *k == key)
        .map(|(_, v)| v.to_string())
}

/// Equal strings, compared in time independent of where they differ.
fn same(a: &str, b: &str) -> bool {
    a.len() == b.len() && a.bytes().zip(b.bytes()).fold(0u8, |d, (x, y)| d | (x ^ y)) == 0
}

fn header(name: &str, value: &str) -> Option<Header> {
    Header::from_bytes(name.as_bytes(), value.as_bytes()).ok()
}

fn reply(status: u16, mime: &str, body: Vec<u8>) -> Reply {
    let headers = [
        ("Content-Type", mime),
        (
            "Content-Security-Policy",
            "default-src 'self'; img-src 'self' blob: data:; style-src 'self'; frame-ancestors 'none'",
        ),
        ("Referrer-Policy", "no-referrer"),
        ("X-Content-Type-Options", "nosniff"),
        ("Cache-Control", "no-store"),
    ];
    let mut r = Response::from_data(body).with_status_code(status);
    for (k, v) in headers {
        if let Some(h) = header(k, v) {
            r.add_header(h);
        }
    }
    r
}

fn json_reply(status: u16, v: &Value) -> Reply {
    reply(status, "application/json", v.to_string().into_bytes())
}
