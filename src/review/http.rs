//! The review server: binds 127.0.0.1 only and answers a request only when its Host (and
//! Origin, required on POST) name that address, it carries the session's random token, and its
//! path is one of the exact routes below (no route takes a file path: frames are indices, export
//! files come from the manifest). Every refusal is logged without the token. No client can stall
//! it: headers must arrive within 5 s and 16 KiB, a body within 10 s and 1 MiB, every answer
//! closes its connection, a connection lives at most 2 minutes, at most 64 are open at once (more
//! are closed at once, the others still answered), and a stop ends it within half a second
//! whatever the clients do.
//!
//! HTTP crate: hyper 1 (HTTP/1 server only) on a one-thread tokio runtime, used only in this
//! file. tiny_http 0.12, used before, read request bodies on its worker threads with no time
//! limit and drained unread ones before closing (two connections announcing a body that never
//! came held both workers, and Ctrl-C, forever) and has no header timeout. hyper has the header
//! timeout and size limit built in, reads bodies asynchronously (bounded here by a timeout), and
//! dropping the runtime ends every connection. axum would add a router and tower layers that
//! these few exact routes do not need.

use super::{parse_steps, ApiError, ApiResult, Review};
use crate::error::{Error, Result};
use crate::source::FrameSize;
use http_body_util::{BodyExt, Full, Limited};
use hyper::body::{Body, Bytes, Incoming};
use hyper::header::{self, HeaderValue};
use hyper::http::request::Parts;
use hyper::{Method, Request, Response, StatusCode};
use hyper_util::rt::{TokioIo, TokioTimer};
use serde_json::{json, Value};
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::{watch, OwnedSemaphorePermit, Semaphore};

/// A response with its whole body in memory.
type Reply = Response<Full<Bytes>>;

/// Request bodies above this are refused.
const MAX_BODY: usize = 1 << 20;

/// Request line and headers above this are refused (431).
const MAX_HEAD: usize = 16 << 10;

/// A request's line and headers must arrive within this (counted from the connection's start).
const HEAD_TIME: Duration = Duration::from_secs(5);

/// A request's body must arrive within this (counted from the end of its headers).
const BODY_TIME: Duration = Duration::from_secs(10);

/// A connection is closed after this whatever it is doing (a client that never reads its answer).
const CONNECTION_TIME: Duration = Duration::from_secs(120);

/// Connections open at once; one more is closed as soon as it is accepted.
const MAX_CONNECTIONS: usize = 64;

/// How long a stop waits for answers in progress (a save being written) before it ends them.
const STOP_GRACE: Duration = Duration::from_millis(500);

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

/// What answers a request: the review, its token and its port.
struct Site {
    review: Review,
    token: String,
    port: u16,
}

/// A bound server, not yet answering.
pub struct Served {
    listener: std::net::TcpListener,
    runtime: tokio::runtime::Runtime,
    site: Arc<Site>,
    stop: Arc<watch::Sender<bool>>,
}

/// Stops a running server from another thread (a Ctrl-C handler).
#[derive(Clone)]
pub struct Stopper(Arc<watch::Sender<bool>>);

impl Stopper {
    /// Asks the server to stop: `serve` returns when the answers in progress end or time out.
    pub fn stop(&self) {
        self.0.send_replace(true);
    }
}

impl Served {
    /// Binds 127.0.0.1:`port` (0: a free port) with a new random token.
    pub fn bind(review: Review, port: u16) -> Result<Served> {
        let cannot = |e: std::io::Error| {
            Error::param("port", format!("cannot listen on 127.0.0.1:{port}: {e}"))
        };
        let listener = std::net::TcpListener::bind(("127.0.0.1", port)).map_err(cannot)?;
        listener.set_nonblocking(true).map_err(cannot)?;
        let port = listener.local_addr().map(|a| a.port()).unwrap_or(port);
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .map_err(cannot)?;
        let mut bytes = [0u8; 16];
        getrandom::fill(&mut bytes)
            .map_err(|e| Error::param("token", format!("no random source for a token: {e}")))?;
        Ok(Served {
            listener,
            runtime,
            site: Arc::new(Site {
                review,
                token: bytes.iter().map(|b| format!("{b:02x}")).collect(),
                port,
            }),
            stop: Arc::new(watch::channel(false).0),
        })
    }

    /// The page's address with the token.
    pub fn url(&self) -> String {
        format!(
            "http://127.0.0.1:{}/?token={}",
            self.site.port, self.site.token
        )
    }

    /// The port listened on (the one chosen when 0 was asked for).
    pub fn port(&self) -> u16 {
        self.site.port
    }

    /// The token every request must carry.
    pub fn token(&self) -> &str {
        &self.site.token
    }

    /// A handle that stops the server from another thread.
    pub fn stopper(&self) -> Stopper {
        Stopper(self.stop.clone())
    }

    /// Answers requests until stopped, each connection on its own task and each answer's work on
    /// tokio's blocking threads (frames decode one at a time behind the review's reader, so step
    /// edits keep answering while frames decode). A stop waits at most [`STOP_GRACE`] for answers
    /// in progress, then drops every connection.
    pub fn run(self) {
        let Served {
            listener,
            runtime,
            site,
            stop,
        } = self;
        let mut stopped = stop.subscribe();
        runtime.block_on(async move {
            let listener = match tokio::net::TcpListener::from_std(listener) {
                Ok(l) => l,
                Err(e) => return log::error!("review: {e}"),
            };
            let slots = Arc::new(Semaphore::new(MAX_CONNECTIONS));
            loop {
                let accepted = tokio::select! {
                    _ = stopped.wait_for(|s| *s) => break,
                    a = listener.accept() => a,
                };
                match accepted {
                    Ok((tcp, peer)) => match slots.clone().try_acquire_owned() {
                        Ok(slot) => drop(tokio::spawn(serve(site.clone(), tcp, peer, slot))),
                        Err(_) => log::warn!(
                            "review: refused a connection from {peer}: {MAX_CONNECTIONS} open"
                        ),
                    },
                    Err(e) => {
                        log::warn!("review: {e}");
                        tokio::time::sleep(Duration::from_millis(50)).await;
                    }
                }
            }
        });
        runtime.shutdown_timeout(STOP_GRACE);
    }
}

/// One connection: one request under the header and connection limits, then closed.
async fn serve(
    site: Arc<Site>,
    tcp: tokio::net::TcpStream,
    peer: SocketAddr,
    _slot: OwnedSemaphorePermit,
) {
    let answer = hyper::service::service_fn(move |rq| {
        let site = site.clone();
        async move { Ok::<_, std::convert::Infallible>(site.answer(rq, peer).await) }
    });
    let connection = hyper::server::conn::http1::Builder::new()
        .timer(TokioTimer::new())
        .header_read_timeout(HEAD_TIME)
        .max_header_size(MAX_HEAD)
        .keep_alive(false)
        .serve_connection(TokioIo::new(tcp), answer);
    match tokio::time::timeout(CONNECTION_TIME, connection).await {
        Ok(Ok(())) => {}
        Ok(Err(e)) => log::debug!("review: connection from {peer}: {e}"),
        Err(_) => log::warn!("review: closed the connection from {peer} after {CONNECTION_TIME:?}"),
    }
}

impl Site {
    async fn answer(self: Arc<Self>, rq: Request<Incoming>, peer: SocketAddr) -> Reply {
        let started = Instant::now();
        let (head, body) = rq.into_parts();
        let (method, url) = (head.method.clone(), head.uri.to_string());
        let path = url.split('?').next().unwrap_or("").to_string();
        let reply = match self.admit(&head, &url) {
            Ok(()) => {
                let body = match method {
                    Method::POST => read_body(body).await,
                    _ => Ok(Bytes::new()),
                };
                let (site, method, url) = (self.clone(), method.clone(), url.clone());
                tokio::task::spawn_blocking(move || site.route(&method, &url, body))
                    .await
                    .unwrap_or_else(|e| Err(ApiError::new(500, format!("answer failed: {e}"))))
            }
            Err(e) => Err(e),
        };
        let response = reply.unwrap_or_else(|e| {
            if e.status < 500 {
                log::warn!("review: refused {method} {path} from {peer}: {}", e.error);
            } else {
                log::error!("review: {method} {path}: {}", e.error);
            }
            json_reply(e.status, &e.body())
        });
        log::debug!("review: {method} {path} in {:?}", started.elapsed());
        response
    }

    /// Host, Origin and token checks, and the path's form.
    fn admit(&self, rq: &Parts, url: &str) -> ApiResult<()> {
        let own = [
            format!("127.0.0.1:{}", self.port),
            format!("localhost:{}", self.port),
        ];
        let header = |name: &str| {
            (rq.headers.get(name))
                .and_then(|v| v.to_str().ok())
                .map(str::to_string)
        };
        if !header("Host").is_some_and(|h| own.contains(&h)) {
            return Err(ApiError::new(403, "foreign Host header"));
        }
        match header("Origin") {
            Some(o) if !own.iter().any(|h| o == format!("http://{h}")) => {
                return Err(ApiError::new(403, "cross-origin request"))
            }
            None if rq.method != Method::GET => {
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

    /// The answer of an admitted request (`body`: a POST's, as read).
    fn route(&self, method: &Method, url: &str, body: ApiResult<Bytes>) -> ApiResult<Reply> {
        let review = &self.review;
        let path = url.split('?').next().unwrap_or("");
        let parts: Vec<&str> = path.trim_start_matches('/').split('/').collect();
        match (method, parts.as_slice()) {
            (&Method::GET, _) if ASSETS.iter().any(|a| a.0 == path) => {
                let (_, mime, body) = ASSETS
                    .into_iter()
                    .find(|a| a.0 == path)
                    .unwrap_or(ASSETS[0]);
                let body = body.replace("{{TOKEN}}", &self.token);
                Ok(reply(200, mime, body.into_bytes()))
            }
            (&Method::GET, ["api", "state"]) => Ok(json_reply(200, &review.state()?)),
            (&Method::GET, ["api", "status"]) => Ok(json_reply(200, &review.status())),
            (&Method::POST, ["api", "apply"]) => {
                let body = json_of(body)?;
                let steps = parse_steps(&body["steps"])?;
                Ok(json_reply(
                    200,
                    &review.apply(&steps, view_of(&body["view"])?)?,
                ))
            }
            (&Method::POST, ["api", "save"]) => {
                let body = json_of(body)?;
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
            (&Method::POST, ["api", "save-workflow"]) => {
                let body = json_of(body)?;
                let steps = parse_steps(&body["steps"])?;
                let force = body["force"].as_bool().unwrap_or(false);
                let saved = review.save_workflow(&steps, force)?;
                Ok(json_reply(200, &json!({"saved": saved})))
            }
            (&Method::GET, ["api", "frame", index]) => {
                let index = index_of(index)?;
                let size = match query(url, "size").as_deref() {
                    Some("large") => FrameSize::Large,
                    _ => FrameSize::Strip,
                };
                let jpeg = review.frame(index, size)?;
                Ok(reply(200, "image/jpeg", jpeg.to_vec()))
            }
            (&Method::GET, ["api", "export", kind, index]) => {
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

/// A request body, read within [`BODY_TIME`] and at most [`MAX_BODY`] bytes.
async fn read_body(body: Incoming) -> ApiResult<Bytes> {
    let over = || ApiError::new(400, "request body unreadable or over 1 MiB");
    if body.size_hint().lower() > MAX_BODY as u64 {
        return Err(over());
    }
    match tokio::time::timeout(BODY_TIME, Limited::new(body, MAX_BODY).collect()).await {
        Ok(Ok(collected)) => Ok(collected.to_bytes()),
        Ok(Err(_)) => Err(over()),
        Err(_) => Err(ApiError::new(
            408,
            format!("request body not sent within {BODY_TIME:?}"),
        )),
    }
}

/// A request body's JSON.
fn json_of(body: ApiResult<Bytes>) -> ApiResult<Value> {
    serde_json::from_slice(&body?).map_err(|e| ApiError::new(400, format!("request body: {e}")))
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

/// A complete answer; it closes its connection.
fn reply(status: u16, mime: &'static str, body: Vec<u8>) -> Reply {
    let headers = [
        (header::CONTENT_TYPE, mime),
        (
            header::CONTENT_SECURITY_POLICY,
            "default-src 'self'; img-src 'self' blob: data:; style-src 'self'; frame-ancestors 'none'",
        ),
        (header::REFERRER_POLICY, "no-referrer"),
        (header::X_CONTENT_TYPE_OPTIONS, "nosniff"),
        (header::CACHE_CONTROL, "no-store"),
        (header::CONNECTION, "close"),
    ];
    let mut r = Response::new(Full::new(Bytes::from(body)));
    *r.status_mut() = StatusCode::from_u16(status).unwrap_or(StatusCode::INTERNAL_SERVER_ERROR);
    for (k, v) in headers {
        r.headers_mut().insert(k, HeaderValue::from_static(v));
    }
    r
}

fn json_reply(status: u16, v: &Value) -> Reply {
    reply(status, "application/json", v.to_string().into_bytes())
}
