//! `bench`: side-by-side timings of the gpu and opencv backends in one run, reported as ms/frame
//! and their ratio. Never used as a timed assertion; this machine is noisy.

use crate::error::Result;
use crate::gpu::{GpuContext, PerFrame};
use crate::kernels::sharpness::{score_opencv, SharpnessGpu};
use crate::params::Metric;
use std::sync::Arc;
use std::time::Instant;

/// One row of a table: a case (sharpness metric, Farneback parameter set) at one size, timed per
/// item (a frame for sharpness, a frame pair for Farneback).
#[derive(Debug, Clone, serde::Serialize)]
pub struct Row {
    /// Frame width in pixels.
    pub width: u32,
    /// Frame height in pixels.
    pub height: u32,
    /// Metric, or Farneback parameter set label.
    pub case: String,
    /// OpenCV CPU (cv::calcOpticalFlowFarneback for flow), ms per item.
    pub opencv_ms: f64,
    /// Rows per invocation of the gpu kernel's strip passes (its strip shape).
    pub strip_rows: u32,
    /// gpu backend, ms per item: sharpness uploads, runs its kernels and reads back; Farneback
    /// streams a video (one pyramid per new frame, flow, no readback).
    pub gpu_ms: f64,
    /// What the gpu backend asked of the device, per item.
    pub per_frame: PerFrame,
}

impl Row {
    /// The row of `case` at `size` whose gpu work `gpu` (`n` items) is timed and counted here.
    fn timed(
        ctx: &GpuContext,
        n: usize,
        (width, height): (u32, u32),
        (case, opencv_ms, strip_rows): (String, f64, u32),
        gpu: impl FnOnce() -> Result<()>,
    ) -> Result<Row> {
        let (t, before) = (Instant::now(), ctx.counts());
        gpu()?;
        Ok(Row {
            width,
            height,
            case,
            opencv_ms,
            strip_rows,
            gpu_ms: t.elapsed().as_secs_f64() * 1e3 / n as f64,
            per_frame: PerFrame::of(ctx.counts() - before, n),
        })
    }
}

/// Sizes the sharpness benchmark runs at.
pub const SHARPNESS_SIZES: [(u32, u32); 3] = [(640, 360), (1920, 1080), (3840, 2160)];

/// Times every metric at every size on `frames` frames (4 distinct synthetic frames, cycled),
/// the gpu kernels once per strip height in `shapes` (empty: the adapter's choice), each after
/// one warm-up batch (first touches of its textures), so the times are the steady state of a
/// long video.
pub fn sharpness(ctx: &Arc<GpuContext>, frames: usize, shapes: &[u32]) -> Result<Vec<Row>> {
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
                let case = (metric.to_string(), opencv_ms, strip_rows);
                let run = || gpu.scores(&list).map(drop);
                rows.push(Row::timed(ctx, frames, (w, h), case, run)?);
            }
        }
    }
    Ok(rows)
}

/// The table as text.
pub fn render_sharpness(adapter: &str, frames: usize, rows: &[Row]) -> String {
    let title = format!(
        "sharpness, {frames} frames per cell, gpu = {adapter} (upload + kernels + readback, after a warm-up batch)\n"
    );
    let heads = ["metric", "opencv ms/f", "gpu ms/f"];
    render(title, heads, [13, 5, 14], 2, rows)
}

/// `rows` under `title`: columns headed `heads` (case, opencv, gpu), the case, strip rows and
/// ratio columns `widths` wide, times with `precision` decimals.
fn render(
    title: String,
    heads: [&str; 3],
    [c, r, q]: [usize; 3],
    precision: usize,
    rows: &[Row],
) -> String {
    let mut s = title;
    s += &format!(
        "{:>10} {:>c$} {:>12} {:>r$} {:>12} {:>q$}{}\n",
        "size",
        heads[0],
        heads[1],
        "rows",
        heads[2],
        "opencv/gpu",
        PerFrame::HEADER
    );
    for x in rows {
        s += &format!(
            "{:>10} {:>c$} {:>12.precision$} {:>r$} {:>12.precision$} {:>q$.2}{}\n",
            format!("{}x{}", x.width, x.height),
            x.case,
            x.opencv_ms,
            x.strip_rows,
            x.gpu_ms,
            x.opencv_ms / x.gpu_ms,
            x.per_frame.columns()
        );
    }
    s
}

/// Times the similarity step's descriptor totals (descriptor.wgsl against its OpenCV twin) at
/// the analysis sizes of [`FLOW_SIZES`] on `frames` frames (4 distinct synthetic frames, cycled),
/// each backend after one warm-up frame; the resize to the analysis size, shared by both, is
/// left out. The gpu does one upload, dispatch and read-back per frame, as the analysis does.
pub fn descriptor(ctx: &Arc<GpuContext>, frames: usize) -> Result<Vec<Row>> {
    use crate::kernels::descriptor::{opencv, DescriptorGpu};
    let frames = frames.max(1);
    let mut rows = Vec::new();
    for (w, h) in FLOW_SIZES {
        let distinct: Vec<opencv::core::Mat> = (0..4)
            .map(|s| crate::synthetic::pattern(w as i32, h as i32, s))
            .collect::<Result<_>>()?;
        opencv(&distinct[0])?;
        let t = Instant::now();
        for i in 0..frames {
            opencv(&distinct[i % 4])?;
        }
        let opencv_ms = t.elapsed().as_secs_f64() * 1e3 / frames as f64;
        let mut gpu = DescriptorGpu::new(ctx.clone(), (w, h))?;
        gpu.totals(&distinct[0])?;
        let case = ("grid-hog-colour".to_string(), opencv_ms, 0);
        rows.push(Row::timed(ctx, frames, (w, h), case, || {
            (0..frames).try_for_each(|i| gpu.totals(&distinct[i % 4]).map(drop))
        })?);
    }
    Ok(rows)
}

/// The descriptor table as text.
pub fn render_descriptor(adapter: &str, frames: usize, rows: &[Row]) -> String {
    let title = format!(
        "descriptor, {frames} frames per cell, gpu = {adapter} (upload + kernel + readback per frame; rows: not a strip kernel)\n"
    );
    let heads = ["descriptor", "opencv ms/f", "gpu ms/f"];
    render(title, heads, [15, 4, 12], 3, rows)
}

/// Sizes the Farneback benchmark runs at.
pub const FLOW_SIZES: [(u32, u32); 3] = [(320, 180), (640, 360), (1280, 720)];

/// The two gray synthetic frames the Farneback benchmarks cycle through at `w` x `h`.
pub fn flow_frames(w: u32, h: u32) -> Result<Vec<opencv::core::Mat>> {
    (0..2)
        .map(|s| {
            crate::synthetic::pattern(w as i32, h as i32, s)
                .and_then(|m| crate::kernels::gray::opencv(&m))
        })
        .collect()
}

/// The Farneback benchmarks' parameter sets: OpenCV's tutorial ones and a heavier set.
pub fn flow_params() -> [(&'static str, crate::params::FarnebackParams); 2] {
    let tutorial = crate::params::FarnebackParams::default();
    let heavy = crate::params::FarnebackParams {
        levels: 5,
        winsize: 13,
        iterations: 10,
        poly_n: 5,
        poly_sigma: 1.1,
        ..tutorial
    };
    [("tutorial", tutorial), ("l5 w13 i10 n5 s1.1", heavy)]
}

/// Times Farneback with OpenCV's tutorial parameters and with (levels 5, winsize 13,
/// iterations 10, poly_n 5, poly_sigma 1.1) at every size over `pairs` frame pairs; the gpu once
/// per strip height in `shapes` (empty: the adapter's choice).
pub fn flow(ctx: &Arc<GpuContext>, pairs: usize, shapes: &[u32]) -> Result<Vec<Row>> {
    use crate::kernels::farneback::{self, FarnebackGpu};
    let pairs = pairs.max(1);
    let own = [farneback::strip_rows_for(ctx)];
    let shapes = if shapes.is_empty() { &own[..] } else { shapes };
    let mut rows = Vec::new();
    for (w, h) in FLOW_SIZES {
        let frames = flow_frames(w, h)?;
        for (label, p) in flow_params() {
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
                let case = (label.into(), opencv_ms, strip_rows);
                rows.push(Row::timed(ctx, pairs, (w, h), case, || {
                    for i in 0..pairs {
                        let (from, to) = (i % 2, (i + 1) % 2);
                        gpu.load(to, &frames[to])?;
                        gpu.flow_between(from, to)?;
                    }
                    ctx.wait()
                })?);
            }
        }
    }
    Ok(rows)
}

/// The Farneback table as text.
pub fn render_flow(adapter: &str, pairs: usize, rows: &[Row]) -> String {
    let title = format!(
        "farneback, {pairs} pairs per cell, gpu = {adapter} (streaming: one pyramid per frame + flow)\n"
    );
    let heads = ["params", "opencv ms", "gpu ms"];
    render(title, heads, [20, 6, 12], 1, rows)
}

/// One row of the host Farneback table: OpenCV's call against keyframer's host Farneback
/// (`farneback::host`, bit-identical) at one size and parameter set, ms.
#[derive(Debug, Clone, serde::Serialize)]
pub struct HostFlowRow {
    /// Frame width in pixels.
    pub width: u32,
    /// Frame height in pixels.
    pub height: u32,
    /// Farneback parameter set label.
    pub case: String,
    /// cv::calcOpticalFlowFarneback, per pair.
    pub opencv_ms: f64,
    /// Host: both frames expanded and the flow, per pair (as the OpenCV call does).
    pub host_pair_ms: f64,
    /// Host: one frame's pyramid of expansions.
    pub expand_ms: f64,
    /// Host: the flow between two expanded frames.
    pub flow_ms: f64,
}

impl HostFlowRow {
    /// Pairs per frame of `select --stationary` (every frame against its reference, every
    /// second frame against the previous stride point).
    pub const STATIONARY_PAIRS: f64 = 1.5;

    /// A stationary frame's Farneback with OpenCV (1.5 calls) over the host's (one expansion,
    /// 1.5 flows), i.e. the CPU the expansion reuse saves.
    pub fn stationary_ratio(&self) -> f64 {
        (self.opencv_ms * Self::STATIONARY_PAIRS)
            / (self.expand_ms + self.flow_ms * Self::STATIONARY_PAIRS)
    }
}

/// Times OpenCV's Farneback against the host one ([`crate::kernels::farneback::host`]) at every
/// size of [`FLOW_SIZES`] over `pairs` pairs of two synthetic frames, with OpenCV's tutorial
/// parameters and the heavier set of [`flow`], one thread, after a warm-up pair each.
pub fn flow_host(pairs: usize) -> Result<Vec<HostFlowRow>> {
    use crate::kernels::farneback::{self, host};
    let pairs = pairs.max(1);
    let mut rows = Vec::new();
    for (w, h) in FLOW_SIZES {
        let frames = flow_frames(w, h)?;
        for (label, p) in flow_params() {
            let per = |t: Instant| t.elapsed().as_secs_f64() * 1e3 / pairs as f64;
            farneback::opencv(&frames[0], &frames[1], &p, None)?;
            let t = Instant::now();
            for i in 0..pairs {
                farneback::opencv(&frames[i % 2], &frames[(i + 1) % 2], &p, None)?;
            }
            let opencv_ms = per(t);
            let expander = host::Expander::new(&p)?;
            let expanded = [expander.expand(&frames[0])?, expander.expand(&frames[1])?];
            host::flow(&expanded[0], &expanded[1])?;
            let t = Instant::now();
            for i in 0..pairs {
                let a = expander.expand(&frames[i % 2])?;
                let b = expander.expand(&frames[(i + 1) % 2])?;
                host::flow(&a, &b)?;
            }
            let host_pair_ms = per(t);
            let t = Instant::now();
            for i in 0..pairs {
                expander.expand(&frames[i % 2])?;
            }
            let expand_ms = per(t);
            let t = Instant::now();
            for i in 0..pairs {
                host::flow(&expanded[i % 2], &expanded[(i + 1) % 2])?;
            }
            let flow_ms = per(t);
            rows.push(HostFlowRow {
                width: w,
                height: h,
                case: label.into(),
                opencv_ms,
                host_pair_ms,
                expand_ms,
                flow_ms,
            });
        }
    }
    Ok(rows)
}

/// The host Farneback table as text.
pub fn render_flow_host(pairs: usize, rows: &[HostFlowRow]) -> String {
    let mut s = format!(
        "farneback on the host, {pairs} pairs per cell, one thread (host = keyframer's, bit-identical to opencv; stationary = a `--stationary` frame: {} pairs)\n",
        HostFlowRow::STATIONARY_PAIRS
    );
    s += &format!(
        "{:>10} {:>20} {:>10} {:>10} {:>10} {:>10} {:>12} {:>16}\n",
        "size",
        "params",
        "opencv ms",
        "host ms",
        "expand ms",
        "flow ms",
        "opencv/host",
        "stationary o/h"
    );
    for x in rows {
        s += &format!(
            "{:>10} {:>20} {:>10.2} {:>10.2} {:>10.2} {:>10.2} {:>12.2} {:>16.2}\n",
            format!("{}x{}", x.width, x.height),
            x.case,
            x.opencv_ms,
            x.host_pair_ms,
            x.expand_ms,
            x.flow_ms,
            x.opencv_ms / x.host_pair_ms,
            x.stationary_ratio()
        );
    }
    s
}

/// ERP size and view size of the remap benchmark: 4K ERP to 6 cube faces of 1024².
pub const REMAP_SIZES: ((u32, u32), u32) = ((3840, 1920), 1024);

/// Times rendering the 6 cube faces (90°, 1024²) of a 3840x1920 BGR frame, bilinear and
/// bicubic, over `frames` frames (2 distinct, cycled): OpenCV's cv::remap per face against the
/// gpu (upload, 6 dispatches, readback of all faces), after one warm-up frame.
pub fn remap(ctx: &Arc<GpuContext>, frames: usize) -> Result<Vec<Row>> {
    use crate::equirect::Interp;
    use crate::equirect::{view_map, ViewSet};
    use crate::kernels::remap::{opencv as cv_remap, RemapGpu, Table};
    let ((w, h), size) = REMAP_SIZES;
    let frames = frames.max(1);
    let distinct: Vec<opencv::core::Mat> = (0..2)
        .map(|s| crate::synthetic::pattern(w as i32, h as i32, s))
        .collect::<Result<_>>()?;
    let tables: Vec<Table> = ViewSet::Cube
        .views(90.0, size)
        .iter()
        .map(|v| {
            let (xs, ys) = view_map(v, (w, h));
            Table::new((size, size), xs, ys)
        })
        .collect::<Result<_>>()?;
    let mut rows = Vec::new();
    for interp in [Interp::Bilinear, Interp::Bicubic] {
        let t = Instant::now();
        for i in 0..frames {
            for table in &tables {
                cv_remap(&distinct[i % 2], table, interp)?;
            }
        }
        let opencv_ms = t.elapsed().as_secs_f64() * 1e3 / frames as f64;
        let gpu = RemapGpu::new(ctx.clone(), (w, h), 3, interp, &tables)?;
        gpu.render(&distinct[0])?; // warm-up
        let case = (format!("{interp:?}").to_lowercase(), opencv_ms, 0);
        rows.push(Row::timed(ctx, frames, (w, h), case, || {
            for i in 0..frames {
                gpu.render(&distinct[i % 2])?;
            }
            Ok(())
        })?);
    }
    Ok(rows)
}

/// The remap table as text.
pub fn render_remap(adapter: &str, frames: usize, rows: &[Row]) -> String {
    let title = format!(
        "remap, ERP 3840x1920 BGR -> 6 x 1024x1024 cube faces, {frames} frames per cell, gpu = {adapter} (upload + 6 views + readback)\n"
    );
    let heads = ["interp", "opencv ms/f", "gpu ms/f"];
    render(title, heads, [9, 4, 10], 1, rows)
}
