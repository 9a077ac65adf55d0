//! `bench`: side-by-side timings of the gpu and opencv backends in one run, reported as ms/frame
//! and their ratio. Never used as a timed assertion; this machine is noisy.

use crate::error::Result;
use crate::gpu::GpuContext;
use crate::kernels::sharpness::{score_opencv, Metric, SharpnessGpu};
use std::sync::Arc;
use std::time::Instant;

/// One row of the sharpness table.
#[derive(Debug, Clone, serde::Serialize)]
pub struct SharpnessRow {
    /// Frame width.
    pub width: u32,
    /// Frame height.
    pub height: u32,
    /// Metric timed.
    pub metric: String,
    /// OpenCV CPU, ms per frame.
    pub opencv_ms: f64,
    /// gpu backend (upload, kernels, readback), ms per frame.
    pub gpu_ms: f64,
}

/// Sizes the sharpness benchmark runs at.
pub const SHARPNESS_SIZES: [(u32, u32); 3] = [(640, 360), (1920, 1080), (3840, 2160)];

/// Times every metric at every size on `frames` frames (4 distinct synthetic frames, cycled).
pub fn sharpness(ctx: &Arc<GpuContext>, frames: usize) -> Result<Vec<SharpnessRow>> {
    let metrics = [
        Metric::Tenengrad,
        Metric::Laplacian { ksize: 1 },
        Metric::Laplacian { ksize: 3 },
    ];
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
            let mut gpu = SharpnessGpu::new(ctx.clone(), metric, w, h)?;
            gpu.scores(&list[..1])?; // warm-up: pipeline and first submission
            let t = Instant::now();
            gpu.scores(&list)?;
            let gpu_ms = t.elapsed().as_secs_f64() * 1e3 / frames as f64;
            rows.push(SharpnessRow {
                width: w,
                height: h,
                metric: metric.to_string(),
                opencv_ms,
                gpu_ms,
            });
        }
    }
    Ok(rows)
}

/// The table as text.
pub fn render_sharpness(adapter: &str, frames: usize, rows: &[SharpnessRow]) -> String {
    let mut s = format!(
        "sharpness, {frames} frames per cell, gpu = {adapter} (upload + kernels + readback)\n"
    );
    s += &format!(
        "{:>10} {:>13} {:>12} {:>12} {:>14}\n",
        "size", "metric", "opencv ms/f", "gpu ms/f", "opencv/gpu"
    );
    for r in rows {
        s += &format!(
            "{:>10} {:>13} {:>12.2} {:>12.2} {:>14.2}\n",
            format!("{}x{}", r.width, r.height),
            r.metric,
            r.opencv_ms,
            r.gpu_ms,
            r.opencv_ms / r.gpu_ms
        );
    }
    s
}
