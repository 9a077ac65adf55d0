//! `bench`: side-by-side timings of the gpu and opencv backends in one run, reported as ms/frame
//! and their ratio. Never used as a timed assertion; this machine is noisy.

use crate::error::Result;
use crate::gpu::{GpuContext, PerFrame};
use crate::kernels::sharpness::{score_opencv, Metric, SharpnessGpu};
use std::sync::Arc;
use std::time::Instant;

/// One row of the sharpness table.
#[derive(Debug, Clone, serde::Serialize)]
pub struct SharpnessRow {
    pub width: u32,
    pub height: u32,
    pub metric: String,
    /// OpenCV CPU, ms per frame.
    pub opencv_ms: f64,
    /// Rows per invocation of the gpu kernel (its strip shape).
    pub strip_rows: u32,
    /// gpu backend (upload, kernels, readback), ms per frame.
    pub gpu_ms: f64,
    /// What the gpu backend asked of the device, per frame.
    pub per_frame: PerFrame,
}

/// Sizes the sharpness benchmark runs at.
pub const SHARPNESS_SIZES: [(u32, u32); 3] = [(640, 360), (1920, 1080), (3840, 2160)];

/// Times every metric at every size on `frames` frames (4 distinct synthetic frames, cycled),
/// the gpu kernels once per strip height in `shapes` (empty: the adapter's choice), each after
/// one warm-up batch (first touches of its textures), so the times are the steady state of a
/// long video.
pub fn sharpness(
    ctx: &Arc<GpuContext>,
    frames: usize,
    shapes: &[u32],
) -> Result<Vec<SharpnessRow>> {
    let metrics = [
        Metric::Tenengrad,
        Metric::Laplacian { ksize: 1 },
        Metric::Laplacian { ksize: 3 },
    ];
    let own = [crate::kernels::strip::strip_rows_for(ctx)];
    let shapes = if shapes.is_empty() { &own[..] } else { shapes };
    let frames = frames.max(1);
    let mut rows = Vec::new();
    for (w, h) in SHARPNESS_SIZES {
        let distinct: Vec<opencv::core::Mat> = (0..4)
            .map(|s| crate::synthetic::pattern(w as i32, h as i32, s))
            .collect::<Result<_>>()?;
        let list: Vec<&opencv::core::Mat> = (0..frames).map(|i| &distinct[i % 4]).collect();
        for metric in metrics {
            let t = Instant::now();
            for f in &list {
                score_opencv(f, metric)?;
            }
            let opencv_ms = t.elapsed().as_secs_f64() * 1e3 / frames as f64;
            for &strip_rows in shapes {
                let mut gpu =
                    SharpnessGpu::with_strip_rows(ctx.clone(), metric, (w, h), strip_rows)?;
                gpu.scores(&list[..gpu.batch_size().min(frames)])?; // warm-up
                let (t, before) = (Instant::now(), ctx.counts());
                gpu.scores(&list)?;
                let gpu_ms = t.elapsed().as_secs_f64() * 1e3 / frames as f64;
                rows.push(SharpnessRow {
                    width: w,
                    height: h,
                    metric: metric.to_string(),
                    opencv_ms,
                    strip_rows,
                    gpu_ms,
                    per_frame: PerFrame::of(ctx.counts() - before, frames),
                });
            }
        }
    }
    Ok(rows)
}

/// The table as text.
pub fn render_sharpness(adapter: &str, frames: usize, rows: &[SharpnessRow]) -> String {
    let mut s = format!(
        "sharpness, {frames} frames per cell, gpu = {adapter} (upload + kernels + readback, after a warm-up batch)\n"
    );
    s += &format!(
        "{:>10} {:>13} {:>12} {:>5} {:>12} {:>14}{}\n",
        "size",
        "metric",
        "opencv ms/f",
        "rows",
        "gpu ms/f",
        "opencv/gpu",
        PerFrame::HEADER
    );
    for r in rows {
        s += &format!(
            "{:>10} {:>13} {:>12.2} {:>5} {:>12.2} {:>14.2}{}\n",
            format!("{}x{}", r.width, r.height),
            r.metric,
            r.opencv_ms,
            r.strip_rows,
            r.gpu_ms,
            r.opencv_ms / r.gpu_ms,
            r.per_frame.columns()
        );
    }
    s
}

/// One row of the Farneback table.
#[derive(Debug, Clone, serde::Serialize)]
pub struct FlowRow {
    pub width: u32,
    pub height: u32,
    /// Parameter set label.
    pub params: String,
    /// cv::calcOpticalFlowFarneback, ms per frame pair.
    pub opencv_ms: f64,
    /// Rows per invocation of the pyramid's strip passes.
    pub strip_rows: u32,
    /// gpu backend streaming a video (one pyramid per new frame, flow, no readback), ms per pair.
    pub gpu_ms: f64,
    /// What the gpu backend asked of the device, per pair.
    pub per_frame: PerFrame,
}

/// Sizes the Farneback benchmark runs at.
pub const FLOW_SIZES: [(u32, u32); 3] = [(320, 180), (640, 360), (1280, 720)];

/// Times Farneback with OpenCV's tutorial parameters and with (levels 5, winsize 13,
/// iterations 10, poly_n 5, poly_sigma 1.1) at every size over `pairs` frame pairs; the gpu once
/// per strip height in `shapes` (empty: the adapter's choice).
pub fn flow(ctx: &Arc<GpuContext>, pairs: usize, shapes: &[u32]) -> Result<Vec<FlowRow>> {
    use crate::kernels::farneback::{self, FarnebackGpu, FarnebackParams};
    let pairs = pairs.max(1);
    let own = [farneback::strip_rows_for(ctx)];
    let shapes = if shapes.is_empty() { &own[..] } else { shapes };
    let tutorial = FarnebackParams::default();
    let heavy = FarnebackParams {
        levels: 5,
        winsize: 13,
        iterations: 10,
        poly_n: 5,
        poly_sigma: 1.1,
        ..tutorial
    };
    let mut rows = Vec::new();
    for (w, h) in FLOW_SIZES {
        let frames: Vec<opencv::core::Mat> = (0..2)
            .map(|s| {
                crate::synthetic::pattern(w as i32, h as i32, s)
                    .and_then(|m| crate::kernels::gray::opencv(&m))
            })
            .collect::<Result<_>>()?;
        for (label, p) in [("tutorial", tutorial), ("l5 w13 i10 n5 s1.1", heavy)] {
            let t = Instant::now();
            for i in 0..pairs {
                farneback::opencv(&frames[i % 2], &frames[(i + 1) % 2], &p, None)?;
            }
            let opencv_ms = t.elapsed().as_secs_f64() * 1e3 / pairs as f64;
            for &strip_rows in shapes {
                let mut gpu = FarnebackGpu::with_strip_rows(ctx.clone(), p, w, h, strip_rows)?;
                gpu.load(0, &frames[0])?;
                gpu.load(1, &frames[1])?;
                gpu.flow_between(0, 1)?;
                gpu.read_flow()?; // warm-up
                let (t, before) = (Instant::now(), ctx.counts());
                for i in 0..pairs {
                    let (from, to) = (i % 2, (i + 1) % 2);
                    gpu.load(to, &frames[to])?;
                    gpu.flow_between(from, to)?;
                }
                ctx.wait()?;
                let gpu_ms = t.elapsed().as_secs_f64() * 1e3 / pairs as f64;
                rows.push(FlowRow {
                    width: w,
                    height: h,
                    params: label.into(),
                    opencv_ms,
                    strip_rows,
                    gpu_ms,
                    per_frame: PerFrame::of(ctx.counts() - before, pairs),
                });
            }
        }
    }
    Ok(rows)
}

/// The Farneback table as text.
pub fn render_flow(adapter: &str, pairs: usize, rows: &[FlowRow]) -> String {
    let mut s = format!(
        "farneback, {pairs} pairs per cell, gpu = {adapter} (streaming: one pyramid per frame + flow)\n"
    );
    s += &format!(
        "{:>10} {:>20} {:>12} {:>6} {:>12} {:>12}{}\n",
        "size",
        "params",
        "opencv ms",
        "rows",
        "gpu ms",
        "opencv/gpu",
        PerFrame::HEADER
    );
    for r in rows {
        s += &format!(
            "{:>10} {:>20} {:>12.1} {:>6} {:>12.1} {:>12.2}{}\n",
            format!("{}x{}", r.width, r.height),
            r.params,
            r.opencv_ms,
            r.strip_rows,
            r.gpu_ms,
            r.opencv_ms / r.gpu_ms,
            r.per_frame.columns()
        );
    }
    s
}
