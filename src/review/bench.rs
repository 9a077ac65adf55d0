//! `keyframer bench review`: how long a parameter change takes on a long project, on the server
//! (the step chain alone, then with the timeline drawn, then through HTTP on a free port). Times
//! are printed, never asserted (noisy machines); the target is 50 ms on the server.

use super::http::Served;
use super::{Review, ReviewSettings};
use crate::error::{Error, Result};
use crate::fsutil::Fingerprint;
use crate::params::{Backend, Metric, MovementSeries};
use crate::project::{Cache, InputRef, MovementCache, Project, SharpnessSeries, SCHEMA_VERSION};
use crate::source::{Metadata, SourceKind};
use crate::steps::{Step, Threshold};
use serde_json::json;
use std::io::{Read, Write};
use std::path::Path;
use std::time::Instant;

/// A deterministic project of `n` frames (1080p30): movement and Tenengrad scores from a linear
/// congruential generator, selected with spacing 200 px and the blur filter. Its input does not
/// exist (frames are not previewed in the bench).
pub fn synthetic_project(n: usize) -> Result<Project> {
    let mut seed: u64 = 0x9e37_79b9_7f4a_7c15;
    let mut next = move || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (seed >> 11) as f64 / (1u64 << 53) as f64
    };
    let movement: Vec<f64> = (0..n)
        .map(|i| if i == 0 { 0.0 } else { 2.0 + 8.0 * next() })
        .collect();
    let scores: Vec<f64> = (0..n).map(|_| 500.0 + 1000.0 * next()).collect();
    let request = crate::steps::defaults::movement();
    let metadata = Metadata {
        kind: SourceKind::Video,
        frame_count: n,
        frame_count_exact: true,
        fps: Some(30.0),
        width: 1920,
        height: 1080,
        duration_s: Some(n as f64 / 30.0),
        codec: Some("h264".into()),
        rotation_deg: 0,
    };
    let cache = Cache {
        timestamps_s: Some((0..n).map(|i| i as f64 / 30.0).collect()),
        sharpness: vec![SharpnessSeries {
            metric: Metric::Tenengrad,
            width: 1920,
            height: 1080,
            rows: None,
            backend: Backend::Opencv,
            scores,
        }],
        movement: vec![MovementCache {
            request,
            backend: Backend::Opencv,
            series: MovementSeries {
                width: request.analysis_width,
                height: request.analysis_width * 9 / 16,
                scale_to_full: 1920.0 / f64::from(request.analysis_width),
                values: movement,
            },
        }],
        ..Cache::default()
    };
    let steps = bench_steps(200.0, 0.8);
    let resolved = crate::select::Resolved::given(&steps, request);
    let input = Path::new("synthetic.mp4");
    let (keyframes, history) =
        crate::select::run_steps(input, &steps, &resolved, &cache, &metadata, &[])?;
    Ok(Project {
        schema_version: SCHEMA_VERSION,
        tool_version: env!("CARGO_PKG_VERSION").into(),
        input: InputRef {
            path: input.into(),
            kind: SourceKind::Video,
            fingerprint: Fingerprint {
                size: 0,
                mtime_s: 0,
                prefix_hash: String::new(),
            },
        },
        metadata,
        boundaries: crate::steps::boundaries(&steps),
        keyframes,
        history,
        cache,
        decode_problems: Vec::new(),
        damaged_frames: Vec::new(),
        preview: false,
        projection: Default::default(),
    })
}

fn bench_steps(spacing: f64, ratio: f64) -> Vec<Step> {
    vec![
        Step::Spacing {
            threshold: Threshold::Px(spacing),
        },
        Step::Blur {
            metric: None,
            window: None,
            ratio: Some(ratio),
            mode: None,
        },
    ]
}

/// Median, 95th percentile and maximum of `ms`.
fn stats(mut ms: Vec<f64>) -> (f64, f64, f64) {
    ms.sort_by(f64::total_cmp);
    let at = |q: f64| ms[((ms.len() - 1) as f64 * q).round() as usize];
    (at(0.5), at(0.95), at(1.0))
}

/// Runs the bench on a synthetic project of `frames` frames written into `dir`; returns the
/// table.
pub fn review(dir: &Path, frames: usize) -> Result<String> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let path = dir.join("review-bench.json");
    let _held = crate::output::check_file(&path, true, &crate::output::Inputs::none())?;
    synthetic_project(frames)?.save(&path, true)?;
    let settings = ReviewSettings {
        project: path.clone(),
        export: None,
        port: None,
    };
    let changes: Vec<Vec<Step>> = (0..40)
        .map(|i| match i % 2 {
            0 => bench_steps(150.0 + 5.0 * i as f64, 0.8),
            _ => bench_steps(200.0, 0.5 + 0.01 * i as f64),
        })
        .collect();
    let review = Review::open(&settings)?;
    let time = |f: &mut dyn FnMut(&[Step]) -> Result<()>| -> Result<(f64, f64, f64)> {
        let mut ms = Vec::new();
        for steps in &changes {
            let t = Instant::now();
            f(steps)?;
            ms.push(t.elapsed().as_secs_f64() * 1e3);
        }
        Ok(stats(ms))
    };
    let api = |e: super::ApiError| Error::param("review", e.error);
    let mut counts = Vec::new();
    let chain = time(&mut |s| {
        counts.push(review.select(s).map_err(api)?.keyframes.len());
        Ok(())
    })?;
    let (fewest, most) = (counts.iter().min(), counts.iter().max());
    let drawn = time(&mut |s| review.apply(s, None).map(|_| ()).map_err(api))?;
    let served = Served::bind(Review::open(&settings)?, 0)?;
    let (port, token) = (served.port(), served.token().to_string());
    let stopper = served.stopper();
    let server = std::thread::spawn(move || served.run());
    let http = time(&mut |s| post_apply(port, &token, s));
    stopper.stop();
    let _ = server.join();
    let http = http?;
    let row = |what: &str, (p50, p95, max): (f64, f64, f64)| {
        format!("| {what} | {p50:.2} | {p95:.2} | {max:.2} |\n")
    };
    Ok(format!(
        "review: {frames}-frame project, 40 parameter changes (spacing / blur ratio; {} to {} \
         keyframes), ms (target: under 50 on the server)\n\n| what | median | p95 | max |\n\
         |---|---|---|---|\n{}{}{}",
        fewest.unwrap_or(&0),
        most.unwrap_or(&0),
        row("step chain on the cached series", chain),
        row("chain + timeline SVG (Review::apply)", drawn),
        row("POST /api/apply over HTTP (localhost)", http),
    ))
}

/// One `/api/apply` through a TCP connection, as the page sends it.
fn post_apply(port: u16, token: &str, steps: &[Step]) -> Result<()> {
    let io = |e: std::io::Error| Error::param("review", format!("bench request: {e}"));
    let body = json!({ "steps": steps }).to_string();
    let mut tcp = std::net::TcpStream::connect(("127.0.0.1", port)).map_err(io)?;
    let rq = format!(
        "POST /api/apply HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nOrigin: http://127.0.0.1:{port}\r\n\
         X-Keyframer-Token: {token}\r\nContent-Type: application/json\r\nContent-Length: {}\r\n\
         Connection: close\r\n\r\n{body}",
        body.len()
    );
    tcp.write_all(rq.as_bytes()).map_err(io)?;
    let mut out = Vec::new();
    tcp.read_to_end(&mut out).map_err(io)?;
    match out.starts_with(b"HTTP/1.1 200") {
        true => Ok(()),
        false => Err(Error::param(
            "review",
            String::from_utf8_lossy(&out[..out.len().min(300)]),
        )),
    }
}
