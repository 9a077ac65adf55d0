//! `farneback`: dense optical flow as cv::calcOpticalFlowFarneback computes it, in WGSL stages that
//! keep every intermediate on the device: per-level smoothing of the full-resolution image
//! (farneback_smooth), INTER_LINEAR resize (farneback_resize), polynomial expansion
//! (farneback_polyexp), matrix update (farneback_matrices) and windowed flow update
//! (farneback_flow). The OpenCV twin is `opencv` (the OpenCV call itself).

use crate::error::{CvContext, Error, Result};
use crate::gpu::{compute_pass, GpuContext};
pub use crate::params::FarnebackParams;
use bytemuck::{Pod, Zeroable};
use opencv::core::{Mat, Size};
use opencv::prelude::*;
use std::sync::Arc;

/// WGSL sources of the stages.
pub const SMOOTH_WGSL: &str = include_str!("../../shaders/farneback_smooth.wgsl");
/// INTER_LINEAR resize.
pub const RESIZE_WGSL: &str = include_str!("../../shaders/farneback_resize.wgsl");
/// Polynomial expansion.
pub const POLYEXP_WGSL: &str = include_str!("../../shaders/farneback_polyexp.wgsl");
/// Matrix update.
pub const MATRICES_WGSL: &str = include_str!("../../shaders/farneback_matrices.wgsl");
/// Flow update.
pub const FLOW_WGSL: &str = include_str!("../../shaders/farneback_flow.wgsl");

/// OpenCV's flags for the window type.
fn flags(p: &FarnebackParams) -> i32 {
    if p.gaussian {
        opencv::video::OPTFLOW_FARNEBACK_GAUSSIAN
    } else {
        0
    }
}

/// OpenCV twin: the flow from `prev` to `next` (8-bit gray), CV_32FC2. With `initial`, the flow
/// starts from it (OPTFLOW_USE_INITIAL_FLOW).
pub fn opencv(prev: &Mat, next: &Mat, p: &FarnebackParams, initial: Option<&Mat>) -> Result<Mat> {
    p.validate()?;
    let mut flow = match initial {
        Some(f) => f.try_clone().cv(|| "copy initial flow".into())?,
        None => Mat::default(),
    };
    let flags = flags(p)
        | if initial.is_some() {
            opencv::video::OPTFLOW_USE_INITIAL_FLOW
        } else {
            0
        };
    opencv::video::calc_optical_flow_farneback(
        prev,
        next,
        &mut flow,
        p.pyr_scale,
        p.levels as i32,
        p.winsize as i32,
        p.iterations as i32,
        p.poly_n as i32,
        p.poly_sigma,
        flags,
    )
    .cv(|| "calcOpticalFlowFarneback".into())?;
    Ok(flow)
}

/// One pyramid level as OpenCV derives it.
#[derive(Debug, Clone, PartialEq)]
pub struct Level {
    pub width: u32,
    pub height: u32,
    /// pyr_scale^k.
    pub scale: f64,
    /// Smoothing kernel applied to the full-resolution image before resizing (odd length).
    pub smooth: Vec<f32>,
}

/// OpenCV rounds with cvRound: to nearest, ties to even.
fn cv_round(v: f64) -> i64 {
    v.round_ties_even() as i64
}

/// cv::getGaussianKernel(n, sigma) as float taps.
fn gaussian_kernel(n: usize, sigma: f64) -> Vec<f32> {
    if sigma <= 0.0 && n == 3 {
        return vec![0.25, 0.5, 0.25];
    }
    let sigma = if sigma > 0.0 {
        sigma
    } else {
        ((n as f64 - 1.0) * 0.5 - 1.0) * 0.3 + 0.8
    };
    let scale2 = -0.5 / (sigma * sigma);
    let raw: Vec<f64> = (0..n)
        .map(|i| {
            let x = i as f64 - (n as f64 - 1.0) * 0.5;
            (scale2 * x * x).exp()
        })
        .collect();
    let sum: f64 = raw.iter().sum();
    raw.iter().map(|v| (v / sum) as f32).collect()
}

/// The levels OpenCV uses for a `width` x `height` image, index 0 = full resolution.
pub fn levels(width: u32, height: u32, p: &FarnebackParams) -> Vec<Level> {
    const MIN_SIZE: f64 = 32.0;
    let mut n = 0;
    let mut scale = 1.0;
    while n < p.levels {
        scale *= p.pyr_scale;
        if f64::from(width) * scale < MIN_SIZE || f64::from(height) * scale < MIN_SIZE {
            break;
        }
        n += 1;
    }
    (0..=n)
        .map(|k| {
            let mut scale = 1.0;
            for _ in 0..k {
                scale *= p.pyr_scale;
            }
            let sigma = (1.0 / scale - 1.0) * 0.5;
            let size = ((cv_round(sigma * 5.0) | 1).max(3)) as usize;
            Level {
                width: cv_round(f64::from(width) * scale) as u32,
                height: cv_round(f64::from(height) * scale) as u32,
                scale,
                smooth: gaussian_kernel(size, sigma),
            }
        })
        .collect()
}

/// Polynomial-expansion weights as FarnebackPrepareGaussian computes them:
/// (g[0..=n], xg, xxg as f32) and (ig11, ig03, ig33, ig55).
pub fn poly_weights(n: u32, sigma: f64) -> (Vec<f32>, [f64; 4]) {
    let n = n as i64;
    let sigma = if sigma < f64::from(f32::EPSILON) {
        n as f64 * 0.3
    } else {
        sigma
    };
    let mut g = vec![0f32; (2 * n + 1) as usize];
    let mut s = 0.0f64;
    for x in -n..=n {
        let v = (-(x * x) as f64 / (2.0 * sigma * sigma)).exp() as f32;
        g[(x + n) as usize] = v;
        s += f64::from(v);
    }
    let s = 1.0 / s;
    let mut xg = vec![0f32; g.len()];
    let mut xxg = vec![0f32; g.len()];
    for x in -n..=n {
        let i = (x + n) as usize;
        g[i] = (f64::from(g[i]) * s) as f32;
        xg[i] = (x as f32) * g[i];
        xxg[i] = ((x * x) as f32) * g[i];
    }
    let mut gm = [[0f64; 6]; 6];
    for y in -n..=n {
        for x in -n..=n {
            let w = f64::from(g[(y + n) as usize]) * f64::from(g[(x + n) as usize]);
            let (xf, yf) = (x as f64, y as f64);
            gm[0][0] += w;
            gm[1][1] += w * xf * xf;
            gm[3][3] += w * xf * xf * xf * xf;
            gm[5][5] += w * xf * xf * yf * yf;
        }
    }
    gm[2][2] = gm[1][1];
    gm[0][3] = gm[1][1];
    gm[0][4] = gm[1][1];
    gm[3][0] = gm[1][1];
    gm[4][0] = gm[1][1];
    gm[4][4] = gm[3][3];
    gm[3][4] = gm[5][5];
    gm[4][3] = gm[5][5];
    let inv = invert6(gm);
    let mut kern = Vec::with_capacity(3 * (n as usize + 1));
    let c = n as usize;
    kern.extend_from_slice(&g[c..]);
    kern.extend_from_slice(&xg[c..]);
    kern.extend_from_slice(&xxg[c..]);
    (kern, [inv[1][1], inv[0][3], inv[3][3], inv[5][5]])
}

/// Inverse of a symmetric positive definite 6x6 matrix (Gauss-Jordan with partial pivoting).
fn invert6(a: [[f64; 6]; 6]) -> [[f64; 6]; 6] {
    let mut m = a;
    let mut inv = [[0f64; 6]; 6];
    for (i, row) in inv.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    for col in 0..6 {
        let piv = (col..6)
            .max_by(|&i, &j| m[i][col].abs().total_cmp(&m[j][col].abs()))
            .unwrap_or(col);
        m.swap(col, piv);
        inv.swap(col, piv);
        let d = m[col][col];
        for k in 0..6 {
            m[col][k] /= d;
            inv[col][k] /= d;
        }
        for r in 0..6 {
            if r != col {
                let f = m[r][col];
                for k in 0..6 {
                    m[r][k] -= f * m[col][k];
                    inv[r][k] -= f * inv[col][k];
                }
            }
        }
    }
    inv
}

/// Flow-window weights from the centre out (radius + 1 taps) and the final scale.
pub fn window_weights(winsize: u32, gaussian: bool) -> (Vec<f32>, f32) {
    let m = (winsize / 2) as usize;
    if !gaussian {
        return (
            vec![1.0; m + 1],
            (1.0 / f64::from(winsize * winsize)) as f32,
        );
    }
    let sigma = m as f64 * 0.3;
    let mut k = vec![1.0f32; m + 1];
    let mut s = 1.0f64;
    for (i, v) in k.iter_mut().enumerate().skip(1) {
        let t = (-((i * i) as f64) / (2.0 * sigma * sigma)).exp() as f32;
        *v = t;
        s += f64::from(t) * 2.0;
    }
    let s = 1.0 / s;
    for v in k.iter_mut() {
        *v = (f64::from(*v) * s) as f32;
    }
    (k, 1.0)
}

#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct SmoothParams {
    width: u32,
    height: u32,
    stride: u32,
    radius: u32,
}

#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct ResizeParams {
    src_w: u32,
    src_h: u32,
    dst_w: u32,
    dst_h: u32,
    channels: u32,
    pad0: u32,
    scale_x: f32,
    scale_y: f32,
    factor: f32,
    pad1: [f32; 3],
}

impl ResizeParams {
    /// INTER_LINEAR resize of `channels` channels from `src` to `dst`, values scaled by `factor`.
    fn new(src: (u32, u32), dst: &Level, channels: u32, factor: f32) -> ResizeParams {
        ResizeParams {
            src_w: src.0,
            src_h: src.1,
            dst_w: dst.width,
            dst_h: dst.height,
            channels,
            pad0: 0,
            scale_x: (1.0 / (f64::from(dst.width) / f64::from(src.0))) as f32,
            scale_y: (1.0 / (f64::from(dst.height) / f64::from(src.1))) as f32,
            factor,
            pad1: [0.0; 3],
        }
    }
}

#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct PolyParams {
    width: u32,
    height: u32,
    n: u32,
    pad: u32,
    ig: [f32; 4],
}

#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct SizeParams {
    width: u32,
    height: u32,
    pad: [u32; 2],
}

#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct FlowParams {
    width: u32,
    height: u32,
    radius: u32,
    pad0: u32,
    scale: f32,
    pad1: [f32; 3],
}

struct Pipes {
    smooth_rows: Arc<wgpu::ComputePipeline>,
    smooth_cols: Arc<wgpu::ComputePipeline>,
    resize: Arc<wgpu::ComputePipeline>,
    poly_cols: Arc<wgpu::ComputePipeline>,
    poly_rows: Arc<wgpu::ComputePipeline>,
    matrices: Arc<wgpu::ComputePipeline>,
    flow_cols: Arc<wgpu::ComputePipeline>,
    flow_rows: Arc<wgpu::ComputePipeline>,
}

/// Pixels per invocation of the running-sum box passes (RUN in farneback_flow.wgsl).
const BOX_RUN: u32 = 16;

/// Bind groups that compute one frame's expansion pyramid.
struct FrameSlot {
    gray: wgpu::Buffer,
    /// Per level: smooth rows, smooth cols, resize, poly cols, poly rows.
    levels: Vec<[wgpu::BindGroup; 5]>,
    /// Per level: the expansion R (5 x f32 per pixel).
    r: Vec<wgpu::Buffer>,
}

/// Bind groups of the flow iterations of one level for one (prev, next) slot order.
struct LevelFlow {
    matrices: wgpu::BindGroup,
    cols: wgpu::BindGroup,
    rows: wgpu::BindGroup,
    /// Upsampling of the coarser level's flow into this level (None at the coarsest).
    upsample: Option<wgpu::BindGroup>,
}

/// Number of frame slots: each holds one frame's expansion pyramid on the device, so a video's
/// frames are expanded once and flow runs between any two slots (previous frame, reference frame,
/// current frame).
pub const SLOTS: usize = 3;

/// Farneback flow on the GPU for frames of one size.
pub struct FarnebackGpu {
    ctx: Arc<GpuContext>,
    params: FarnebackParams,
    levels: Vec<Level>,
    pipes: Pipes,
    slots: Vec<FrameSlot>,
    /// Per ordered slot pair (from, to): per level bind groups.
    flows: Vec<((usize, usize), Vec<LevelFlow>)>,
    flow: Vec<wgpu::Buffer>,
    pad: Vec<u8>,
}

fn groups16(w: u32, h: u32) -> (u32, u32) {
    (w.div_ceil(16), h.div_ceil(16))
}

impl FarnebackGpu {
    /// Allocates everything for `width` x `height` 8-bit gray frames.
    pub fn new(
        ctx: Arc<GpuContext>,
        params: FarnebackParams,
        width: u32,
        height: u32,
    ) -> Result<Self> {
        params.validate()?;
        if width < 2 || height < 2 {
            return Err(Error::param(
                "frame size",
                "Farneback needs at least 2x2 pixels",
            ));
        }
        let levels = levels(width, height, &params);
        let full = u64::from(width) * u64::from(height);
        if full * 20 > ctx.limits.max_storage_buffer_binding_size {
            return Err(Error::Gpu(format!(
                "Farneback at {width}x{height} needs {} MiB buffers; this adapter binds at most {} MiB (use a smaller analysis resolution)",
                (full * 20) >> 20,
                ctx.limits.max_storage_buffer_binding_size >> 20
            )));
        }
        let p = |name: &str, src: &str, entry: &str| ctx.pipeline(name, src, entry);
        let flow_entries = if params.gaussian {
            ("cols", "rows")
        } else {
            ("box_cols", "box_rows")
        };
        let pipes = Pipes {
            smooth_rows: p("farneback_smooth", SMOOTH_WGSL, "rows")?,
            smooth_cols: p("farneback_smooth", SMOOTH_WGSL, "cols")?,
            resize: p("farneback_resize", RESIZE_WGSL, "main")?,
            poly_cols: p("farneback_polyexp", POLYEXP_WGSL, "cols")?,
            poly_rows: p("farneback_polyexp", POLYEXP_WGSL, "rows")?,
            matrices: p("farneback_matrices", MATRICES_WGSL, "main")?,
            flow_cols: p("farneback_flow", FLOW_WGSL, flow_entries.0)?,
            flow_rows: p("farneback_flow", FLOW_WGSL, flow_entries.1)?,
        };
        // Shared scratch buffers (full-resolution sized; passes run one after another).
        let tmp = ctx.storage_buffer("smooth tmp", full * 4);
        let smoothed = ctx.storage_buffer("smoothed", full * 4);
        let img = ctx.storage_buffer("level image", full * 4);
        let rows3 = ctx.storage_buffer("polyexp rows", full * 12);
        let m = ctx.storage_buffer("matrices", full * 20);
        let vsum = ctx.storage_buffer("window sums", full * 20);
        let f32_buffer = |label: &str, w: &[f32]| {
            ctx.buffer_init(label, wgpu::BufferUsages::STORAGE, bytemuck::cast_slice(w))
        };
        let (kern, ig) = poly_weights(params.poly_n, params.poly_sigma);
        let kern_buf = f32_buffer("poly kernel", &kern);
        let (win, win_scale) = window_weights(params.winsize, params.gaussian);
        // The box window (box_cols, box_rows) binds no weights: entry 3 only when gaussian.
        let win_entries = if params.gaussian { 4 } else { 3 };
        let win_buf = f32_buffer("window weights", &win);

        let flow: Vec<wgpu::Buffer> = levels
            .iter()
            .map(|l| ctx.storage_buffer("flow", u64::from(l.width) * u64::from(l.height) * 8))
            .collect();

        let bind = |pipe: &wgpu::ComputePipeline, entries: &[(u32, &wgpu::Buffer)]| {
            ctx.bind("farneback", pipe, entries)
        };
        let make_slot = |_: usize| -> FrameSlot {
            let gray = ctx.storage_buffer("gray upload", full);
            let r: Vec<wgpu::Buffer> = levels
                .iter()
                .map(|l| {
                    ctx.storage_buffer("expansion", u64::from(l.width) * u64::from(l.height) * 20)
                })
                .collect();
            let level_groups = levels
                .iter()
                .zip(&r)
                .map(|(l, r_buf)| {
                    let radius = (l.smooth.len() / 2) as u32;
                    let smooth_w = f32_buffer("smooth weights", &l.smooth);
                    let sp = ctx.uniform(
                        "smooth params",
                        &SmoothParams {
                            width,
                            height,
                            stride: width,
                            radius,
                        },
                    );
                    let rp = ctx.uniform(
                        "resize params",
                        &ResizeParams::new((width, height), l, 1, 1.0),
                    );
                    let pp = ctx.uniform(
                        "polyexp params",
                        &PolyParams {
                            width: l.width,
                            height: l.height,
                            n: params.poly_n,
                            pad: 0,
                            ig: [ig[0] as f32, ig[1] as f32, ig[2] as f32, ig[3] as f32],
                        },
                    );
                    [
                        bind(
                            &pipes.smooth_rows,
                            &[(0, &gray), (1, &tmp), (3, &smooth_w), (4, &sp)],
                        ),
                        bind(
                            &pipes.smooth_cols,
                            &[(1, &tmp), (2, &smoothed), (3, &smooth_w), (4, &sp)],
                        ),
                        bind(&pipes.resize, &[(0, &smoothed), (1, &img), (2, &rp)]),
                        bind(
                            &pipes.poly_cols,
                            &[(0, &img), (1, &rows3), (3, &kern_buf), (4, &pp)],
                        ),
                        bind(
                            &pipes.poly_rows,
                            &[(1, &rows3), (2, r_buf), (3, &kern_buf), (4, &pp)],
                        ),
                    ]
                })
                .collect();
            FrameSlot {
                gray,
                levels: level_groups,
                r,
            }
        };
        let slots: Vec<FrameSlot> = (0..SLOTS).map(make_slot).collect();

        let make_flows = |prev: &FrameSlot, next: &FrameSlot| -> Vec<LevelFlow> {
            levels
                .iter()
                .enumerate()
                .map(|(k, l)| {
                    let sz = ctx.uniform(
                        "level size",
                        &SizeParams {
                            width: l.width,
                            height: l.height,
                            pad: [0; 2],
                        },
                    );
                    let fp = ctx.uniform(
                        "flow params",
                        &FlowParams {
                            width: l.width,
                            height: l.height,
                            radius: params.winsize / 2,
                            pad0: 0,
                            scale: win_scale,
                            pad1: [0.0; 3],
                        },
                    );
                    let upsample = levels.get(k + 1).map(|c| {
                        let up = ctx.uniform(
                            "flow upsample params",
                            &ResizeParams::new(
                                (c.width, c.height),
                                l,
                                2,
                                (1.0 / params.pyr_scale) as f32,
                            ),
                        );
                        bind(&pipes.resize, &[(0, &flow[k + 1]), (1, &flow[k]), (2, &up)])
                    });
                    let cols = [(0, &m), (1, &vsum), (4, &fp), (3, &win_buf)];
                    let rows = [(1, &vsum), (2, &flow[k]), (4, &fp), (3, &win_buf)];
                    LevelFlow {
                        matrices: ctx.bind(
                            "farneback",
                            &pipes.matrices,
                            &[
                                (0, &prev.r[k]),
                                (1, &next.r[k]),
                                (2, &flow[k]),
                                (3, &m),
                                (4, &sz),
                            ],
                        ),
                        cols: bind(&pipes.flow_cols, &cols[..win_entries]),
                        rows: bind(&pipes.flow_rows, &rows[..win_entries]),
                        upsample,
                    }
                })
                .collect()
        };
        let mut flows = Vec::new();
        for from in 0..SLOTS {
            for to in (0..SLOTS).filter(|&t| t != from) {
                flows.push(((from, to), make_flows(&slots[from], &slots[to])));
            }
        }
        Ok(FarnebackGpu {
            ctx,
            params,
            levels,
            pipes,
            slots,
            flows,
            flow,
            pad: Vec::new(),
        })
    }

    fn encode_pyramid(&self, enc: &mut wgpu::CommandEncoder, slot: usize) {
        let full = &self.levels[0];
        let mut pass = compute_pass(enc, "farneback pyramid");
        for (l, g) in self.levels.iter().zip(&self.slots[slot].levels) {
            let f = groups16(full.width, full.height);
            let lg = groups16(l.width, l.height);
            let steps: [(&wgpu::ComputePipeline, (u32, u32)); 5] = [
                (&self.pipes.smooth_rows, f),
                (&self.pipes.smooth_cols, f),
                (&self.pipes.resize, lg),
                (&self.pipes.poly_cols, lg),
                (&self.pipes.poly_rows, lg),
            ];
            for ((pipe, groups), bg) in steps.into_iter().zip(g) {
                self.ctx.dispatch(&mut pass, pipe, bg, groups);
            }
        }
    }

    fn encode_flow(&self, enc: &mut wgpu::CommandEncoder, from: usize, to: usize, initial: bool) {
        let Some((_, per_level)) = self.flows.iter().find(|(k, _)| *k == (from, to)) else {
            return;
        };
        let top = self.levels.len() - 1;
        if !initial {
            enc.clear_buffer(&self.flow[top], 0, None);
        }
        let mut pass = compute_pass(enc, "farneback flow");
        for k in (0..=top).rev() {
            let l = &self.levels[k];
            let lf = &per_level[k];
            let (x, y) = groups16(l.width, l.height);
            if let Some(up) = &lf.upsample {
                self.ctx.dispatch(&mut pass, &self.pipes.resize, up, (x, y));
            }
            self.ctx
                .dispatch(&mut pass, &self.pipes.matrices, &lf.matrices, (x, y));
            let (cx, cy, rx, ry) = if self.params.gaussian {
                (x, y, x, y)
            } else {
                (
                    l.width.div_ceil(16),
                    l.height.div_ceil(BOX_RUN).div_ceil(16),
                    l.width.div_ceil(BOX_RUN).div_ceil(16),
                    l.height.div_ceil(16),
                )
            };
            for i in 0..self.params.iterations {
                self.ctx
                    .dispatch(&mut pass, &self.pipes.flow_cols, &lf.cols, (cx, cy));
                self.ctx
                    .dispatch(&mut pass, &self.pipes.flow_rows, &lf.rows, (rx, ry));
                if i + 1 < self.params.iterations {
                    self.ctx
                        .dispatch(&mut pass, &self.pipes.matrices, &lf.matrices, (x, y));
                }
            }
        }
    }

    /// Uploads `gray` into `slot` and computes its expansion pyramid on the device.
    pub fn load(&mut self, slot: usize, gray: &Mat) -> Result<()> {
        if slot >= SLOTS {
            return Err(Error::param("slot", format!("must be below {SLOTS}")));
        }
        let (w, h) = (self.levels[0].width, self.levels[0].height);
        let buf = &self.slots[slot].gray;
        let what = "Farneback (8-bit gray)";
        self.ctx
            .upload_mat(buf, gray, opencv::core::CV_8UC1, w, h, what, &mut self.pad)?;
        let mut enc = self.ctx.encoder("farneback pyramid");
        self.encode_pyramid(&mut enc, slot);
        self.ctx.queue.submit([enc.finish()]);
        Ok(())
    }

    /// Copies an 8-bit gray image of the level-0 size already on the device (4 pixels per u32,
    /// rows not padded, e.g. from resize_area) into `slot` and computes its expansion pyramid.
    pub fn load_buffer(&mut self, slot: usize, gray: &wgpu::Buffer) -> Result<()> {
        if slot >= SLOTS {
            return Err(Error::param("slot", format!("must be below {SLOTS}")));
        }
        let bytes = (u64::from(self.levels[0].width) * u64::from(self.levels[0].height))
            .next_multiple_of(4);
        if gray.size() < bytes {
            return Err(Error::param(
                "gray buffer",
                "smaller than the level-0 image",
            ));
        }
        let mut enc = self.ctx.encoder("farneback pyramid");
        enc.copy_buffer_to_buffer(gray, 0, &self.slots[slot].gray, 0, bytes);
        self.encode_pyramid(&mut enc, slot);
        self.ctx.queue.submit([enc.finish()]);
        Ok(())
    }

    /// Computes the flow from the frame in slot `from` to the frame in slot `to` into
    /// [`FarnebackGpu::flow_buffer`].
    pub fn flow_between(&mut self, from: usize, to: usize) -> Result<()> {
        self.flow_between_from(from, to, None)
    }

    /// As [`FarnebackGpu::flow_between`], starting from `initial` (CV_32FC2, full resolution) as
    /// OPTFLOW_USE_INITIAL_FLOW does: resized to the coarsest level with INTER_AREA and scaled.
    pub fn flow_between_from(
        &mut self,
        from: usize,
        to: usize,
        initial: Option<&Mat>,
    ) -> Result<()> {
        if from >= SLOTS || to >= SLOTS || from == to {
            return Err(Error::param(
                "slots",
                format!("need two distinct slots below {SLOTS}"),
            ));
        }
        let mut enc = self.ctx.encoder("farneback flow");
        if let Some(init) = initial {
            let top = self
                .levels
                .last()
                .ok_or_else(|| Error::Gpu("no pyramid levels".into()))?;
            let full = &self.levels[0];
            if init.typ() != opencv::core::CV_32FC2
                || (init.cols() as u32, init.rows() as u32) != (full.width, full.height)
            {
                return Err(Error::param(
                    "initial flow",
                    format!("must be {}x{} CV_32FC2", full.width, full.height),
                ));
            }
            let mut small = Mat::default();
            opencv::imgproc::resize(
                init,
                &mut small,
                Size::new(top.width as i32, top.height as i32),
                0.0,
                0.0,
                opencv::imgproc::INTER_AREA,
            )
            .cv(|| "resize initial flow".into())?;
            let mut scaled = Mat::default();
            small
                .convert_to(&mut scaled, opencv::core::CV_32FC2, top.scale, 0.0)
                .cv(|| "scale initial flow".into())?;
            let bytes = scaled.data_bytes().cv(|| "initial flow bytes".into())?;
            self.ctx
                .queue
                .write_buffer(&self.flow[self.levels.len() - 1], 0, bytes);
        }
        self.encode_flow(&mut enc, from, to, initial.is_some());
        self.ctx.queue.submit([enc.finish()]);
        Ok(())
    }

    /// The full-resolution flow buffer (2 x f32 per pixel) of the last pair.
    pub fn flow_buffer(&self) -> &wgpu::Buffer {
        &self.flow[0]
    }

    /// Reads back the flow of the last pair as CV_32FC2.
    pub fn read_flow(&self) -> Result<Mat> {
        let (w, h) = (self.levels[0].width, self.levels[0].height);
        let bytes = self
            .ctx
            .read_back(&self.flow[0], u64::from(w) * u64::from(h) * 8)?;
        let floats: &[f32] = bytemuck::cast_slice(&bytes);
        let mut m = Mat::new_rows_cols_with_default(
            h as i32,
            w as i32,
            opencv::core::CV_32FC2,
            opencv::core::Scalar::all(0.0),
        )
        .cv(|| "allocate flow".into())?;
        m.data_typed_mut::<opencv::core::Vec2f>()
            .cv(|| "flow data".into())?
            .iter_mut()
            .zip(floats.chunks_exact(2))
            .for_each(|(d, s)| *d = opencv::core::Vec2f::from([s[0], s[1]]));
        Ok(m)
    }

    /// The flow from `prev` to `next` (8-bit gray), read back as CV_32FC2.
    pub fn flow(&mut self, prev: &Mat, next: &Mat) -> Result<Mat> {
        self.flow_from(prev, next, None)
    }

    /// As [`FarnebackGpu::flow`], optionally starting from an initial flow.
    pub fn flow_from(&mut self, prev: &Mat, next: &Mat, initial: Option<&Mat>) -> Result<Mat> {
        self.load(0, prev)?;
        self.load(1, next)?;
        self.flow_between_from(0, 1, initial)?;
        self.read_flow()
    }
}

/// Resizes `m` to `size` with INTER_AREA (for analysis resolution on the opencv side).
/// The twin is `resize_area::opencv`; the gpu backend runs `resize_area` on the device for
/// integer factors.
pub fn resize_area(m: &Mat, size: Size) -> Result<Mat> {
    super::resize_area::opencv(m, size)
}
