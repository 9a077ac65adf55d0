//! keyframer-gpu-bench: times keyframer's GPU path on synthetic frames (no video, no OpenCV):
//! gray + INTER_AREA + Tenengrad / Laplacian frames/s, Farneback pairs/s at the analysis widths,
//! the whole per-frame analysis of `select --stationary --blur --spacing` on the gpu backend
//! with 1 and more streams on one device, and the device counters per frame. A table on stdout,
//! `--json FILE` for machines; device time from timestamp queries where the adapter has them.

mod bench;
mod clock;

use bench::{select_parts, Bench, Measure, Recorded};
use clap::Parser;
use keyframer::analysis::analysis_size;
use keyframer::gpu::{GpuContext, PerFrame};
use keyframer::params::Metric;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;

/// Flags.
#[derive(Parser, Debug)]
#[command(name = "keyframer-gpu-bench", version, about)]
struct Args {
    /// Frames (Farneback: pairs) per measurement and stream.
    #[arg(long, default_value_t = 240)]
    frames: usize,
    /// Frame sizes of the sharpness and whole-analysis runs: `1080p`, `4k` or `WxH`, comma-separated.
    #[arg(long, default_value = "1080p,4k", value_delimiter = ',')]
    sizes: Vec<String>,
    /// Farneback analysis widths (16:9), comma-separated.
    #[arg(long, default_value = "320,640,1280", value_delimiter = ',')]
    widths: Vec<u32>,
    /// Analysis width of the whole analysis (and of the sharpness runs' resize).
    #[arg(long, default_value_t = 640)]
    analysis_width: u32,
    /// Streams of the whole analysis, comma-separated (each a thread with its own engine).
    #[arg(long, default_value = "1,4", value_delimiter = ',')]
    streams: Vec<usize>,
    /// Adapter (case-insensitive substring of its name; else KEYFRAMER_ADAPTER, else the best).
    #[arg(long)]
    adapter: Option<String>,
    /// Frames (from the first) whose results each run records in the JSON, to be checked
    /// against the OpenCV twins where OpenCV is (`reference/gpu-bench/`).
    #[arg(long, default_value_t = 24)]
    record: usize,
    /// Also write the results as JSON to this file.
    #[arg(long)]
    json: Option<PathBuf>,
}

/// The adapter as the JSON names it.
#[derive(serde::Serialize)]
struct Adapter {
    name: String,
    driver: String,
    driver_info: String,
    backend: String,
    device_type: String,
}

/// The JSON report.
#[derive(serde::Serialize)]
struct Report {
    tool: &'static str,
    version: &'static str,
    adapter: Adapter,
    /// `timestamp` (device time from timestamp queries) or `wall`.
    timing: &'static str,
    frames: usize,
    analysis_width: u32,
    kernels: Vec<Measure>,
    analysis: Vec<Measure>,
    /// The first frames' results of each sharpness and analysis run.
    results: Vec<Recorded>,
}

fn size_of(name: &str) -> Result<(u32, u32), String> {
    match name.to_ascii_lowercase().as_str() {
        "1080p" => Ok((1920, 1080)),
        "4k" => Ok((3840, 2160)),
        other => other
            .split_once('x')
            .and_then(|(w, h)| Some((w.parse().ok()?, h.parse().ok()?)))
            .filter(|&(w, h): &(u32, u32)| w > 0 && h > 0)
            .ok_or_else(|| format!("--sizes: `{name}` is not 1080p, 4k or WxH")),
    }
}

fn run(args: &Args) -> Result<Report, String> {
    let sizes = args
        .sizes
        .iter()
        .map(|s| size_of(s))
        .collect::<Result<Vec<_>, _>>()?;
    if args.frames == 0 || args.streams.contains(&0) || args.widths.contains(&0) {
        return Err("--frames, --streams and --widths must be positive".into());
    }
    let ctx = GpuContext::with_options(
        args.adapter.as_deref(),
        wgpu::Features::TIMESTAMP_QUERY,
        |_, _| {},
    )
    .map_err(|e| e.to_string())?;
    let ctx = Arc::new(ctx);
    let clock = clock::Clock::new(&ctx);
    let timing = if clock.is_some() { "timestamp" } else { "wall" };
    let info = ctx.info.clone();
    eprintln!(
        "keyframer-gpu-bench: {} ({:?}, {} {}), timing: {timing}",
        info.name, info.backend, info.driver, info.driver_info
    );
    let b = Bench {
        ctx,
        clock,
        frames: args.frames,
        record: args.record,
        adapter: args.adapter.clone(),
    };
    let e = |e: keyframer::Error| e.to_string();
    let (mut kernels, mut results) = (Vec::new(), Vec::new());
    for &size in &sizes {
        let small = analysis_size(size.0, size.1, args.analysis_width);
        kernels.push(b.upload(size).map_err(e)?);
        show(kernels.last());
        kernels.push(b.upload_buffer(size).map_err(e)?);
        show(kernels.last());
        kernels.push(b.upload_write_texture(size).map_err(e)?);
        show(kernels.last());
        for metric in [Metric::Tenengrad, Metric::Laplacian { ksize: 3 }] {
            let (m, r) = b.sharpness(metric, size, small).map_err(e)?;
            kernels.push(m);
            results.push(r);
            show(kernels.last());
            kernels.push(b.resident(metric, size, small).map_err(e)?);
            show(kernels.last());
        }
    }
    for &w in &args.widths {
        kernels.push(b.farneback(w).map_err(e)?);
        show(kernels.last());
    }
    let mut analysis = Vec::new();
    for &size in &sizes {
        let [blur, spacing, (name, full)] = select_parts(size.0, args.analysis_width);
        // The stages one by one on one stream (each row's cost minus the one before is the
        // stage's), then the whole analysis on each number of streams.
        for (part, req) in [blur, spacing] {
            analysis.push(b.analysis((part, size), &req, 1, false).map_err(e)?.0);
            show(analysis.last());
        }
        for &streams in &args.streams {
            let (m, r) = b.analysis((name, size), &full, streams, false).map_err(e)?;
            analysis.push(m);
            show(analysis.last());
            if streams == args.streams[0] {
                results.push(r);
            }
            if streams > 1 {
                let own = ("analysis, own devices", size);
                analysis.push(b.analysis(own, &full, streams, true).map_err(e)?.0);
                show(analysis.last());
            }
        }
    }
    Ok(Report {
        tool: "keyframer-gpu-bench",
        version: env!("CARGO_PKG_VERSION"),
        adapter: Adapter {
            name: info.name,
            driver: info.driver,
            driver_info: info.driver_info,
            backend: format!("{:?}", info.backend),
            device_type: format!("{:?}", info.device_type),
        },
        timing,
        frames: args.frames,
        analysis_width: args.analysis_width,
        kernels,
        analysis,
        results,
    })
}

/// Progress on stderr, one line per measurement.
fn show(m: Option<&Measure>) {
    if let Some(m) = m {
        eprintln!("  {} {} x{}: {:.1}/s", m.name, m.size, m.streams, m.per_s);
    }
}

/// The table on stdout.
fn table(r: &Report) -> String {
    let mut out = format!(
        "{} ({}, {} {}), timing: {}, {} frames per run\n",
        r.adapter.name,
        r.adapter.backend,
        r.adapter.driver,
        r.adapter.driver_info,
        r.timing,
        r.frames
    );
    out += &format!(
        "{:<24} {:>10} {:>7} {:>6} {:>10} {:>10} {:>10}{}\n",
        "run",
        "size",
        "streams",
        "count",
        "wall ms/f",
        "dev ms/f",
        "per s",
        PerFrame::HEADER
    );
    for m in r.kernels.iter().chain(&r.analysis) {
        let per = |s: f64| s * 1e3 / m.count.max(1) as f64;
        let dev = m
            .device_s
            .map_or("-".to_string(), |d| format!("{:.3}", per(d)));
        out += &format!(
            "{:<24} {:>10} {:>7} {:>6} {:>10.3} {:>10} {:>10.1}{}\n",
            m.name,
            m.size,
            m.streams,
            m.count,
            per(m.wall_s),
            dev,
            m.per_s,
            m.per_frame.columns()
        );
    }
    out
}

fn main() -> ExitCode {
    let args = Args::parse();
    let report = match run(&args) {
        Ok(r) => r,
        Err(e) => {
            eprintln!("keyframer-gpu-bench: {e}");
            return ExitCode::FAILURE;
        }
    };
    print!("{}", table(&report));
    if let Some(path) = &args.json {
        let text = serde_json::to_string_pretty(&report).unwrap_or_default();
        if let Err(e) = std::fs::write(path, text + "\n") {
            eprintln!("keyframer-gpu-bench: {}: {e}", path.display());
            return ExitCode::FAILURE;
        }
    }
    ExitCode::SUCCESS
}
