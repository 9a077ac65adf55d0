//! `farneback`: dense optical flow as cv::calcOpticalFlowFarneback computes it, in WGSL stages that
//! keep every intermediate on the device: the level images and their polynomial expansions
//! (farneback_pyramid), the flow iterations (farneback_flow), and the copy of a slot's expansion
//! pyramid into another (copy); flows and copies can be gated by sizes the device writes. The
//! OpenCV twin is `opencv` (the OpenCV call itself).

#[cfg(feature = "opencv")]
use crate::error::CvContext;
use crate::error::{Error, Result};
use crate::gpu::{compute_pass, Gate, GpuContext, HostImage};
use crate::params::FarnebackParams;
use bytemuck::{Pod, Zeroable};
#[cfg(feature = "opencv")]
use opencv::{
    core::{Mat, Size},
    prelude::*,
};
use std::sync::Arc;
use wgpu::TextureFormat;

#[cfg(feature = "opencv")]
pub mod host;

/// WGSL of the pyramid stages (level images and expansions), after its prelude.
pub const PYRAMID_WGSL: &str = concat!(
    include_str!("../../shaders/border.wgsl"),
    include_str!("../../shaders/farneback_pyramid.wgsl")
);
/// WGSL of the flow iterations (matrices, windows, solve), after its prelude.
pub const FLOW_WGSL: &str = concat!(
    include_str!("../../shaders/border.wgsl"),
    include_str!("../../shaders/farneback_flow.wgsl")
);
/// Texture copy (a slot's expansion pyramid into another).
pub const COPY_WGSL: &str = include_str!("../../shaders/copy.wgsl");

/// OpenCV twin: the flow from `prev` to `next` (8-bit gray), CV_32FC2. With `initial`, the flow
/// starts from it (OPTFLOW_USE_INITIAL_FLOW).
#[cfg(feature = "opencv")]
pub fn opencv(prev: &Mat, next: &Mat, p: &FarnebackParams, initial: Option<&Mat>) -> Result<Mat> {
    p.validate()?;
    let initial_copy = initial.map(Mat::try_clone).transpose();
    let mut flow = initial_copy
        .cv(|| "copy initial flow".into())?
        .unwrap_or_default();
    let mut flags = initial.map_or(0, |_| opencv::video::OPTFLOW_USE_INITIAL_FLOW);
    if p.gaussian {
        flags |= opencv::video::OPTFLOW_FARNEBACK_GAUSSIAN;
    }
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
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
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
            let scale = (0..k).fold(1.0, |s, _| s * p.pyr_scale);
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

/// FarnebackPrepareGaussian's taps over -n..=n: g (normalised Gaussian), x*g and x*x*g, in f32
/// with OpenCV's arithmetic (each tap's exponential in f64, the products in f32).
pub(crate) fn poly_taps(n: u32, sigma: f64) -> [Vec<f32>; 3] {
    let n = i64::from(n);
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
    [g, xg, xxg]
}

/// FarnebackPrepareGaussian's 6x6 moment matrix G of the taps `g` (over -n..=n): each term a
/// product in f32, summed in f64, as OpenCV writes it.
pub(crate) fn poly_moments(g: &[f32]) -> [[f64; 6]; 6] {
    let n = (g.len() / 2) as i64;
    let mut gm = [[0f64; 6]; 6];
    for y in -n..=n {
        for x in -n..=n {
            let w = g[(y + n) as usize] * g[(x + n) as usize];
            let (xf, yf) = (x as f32, y as f32);
            gm[0][0] += f64::from(w);
            gm[1][1] += f64::from(w * xf * xf);
            gm[3][3] += f64::from(w * xf * xf * xf * xf);
            gm[5][5] += f64::from(w * xf * xf * yf * yf);
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
    gm
}

/// Polynomial-expansion weights as FarnebackPrepareGaussian computes them:
/// (g[0..=n], xg, xxg as f32) and (ig11, ig03, ig33, ig55).
pub fn poly_weights(n: u32, sigma: f64) -> (Vec<f32>, [f64; 4]) {
    let [g, xg, xxg] = poly_taps(n, sigma);
    let inv = invert6(poly_moments(&g));
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

/// cv::resize's source step per destination pixel (x, y) from `src` to `dst` (as f32, the
/// shaders' `scale_x`, `scale_y`).
fn resize_steps(src: (u32, u32), dst: (u32, u32)) -> (f32, f32) {
    let step = |s: u32, d: u32| (1.0 / (f64::from(d) / f64::from(s))) as f32;
    (step(src.0, dst.0), step(src.1, dst.1))
}

/// Uniform parameters of one pyramid level (`PyrParams` in farneback_pyramid.wgsl).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct PyrParams {
    src_w: u32,
    src_h: u32,
    dst_w: u32,
    dst_h: u32,
    radius: u32,
    strip_rows: u32,
    poly_n: u32,
    pad0: u32,
    scale_x: f32,
    scale_y: f32,
    pad1: [f32; 2],
    ig: [f32; 4],
    poly: [[f32; 4]; 8],
}

/// Uniform parameters of one level's flow dispatches (`FlowParams` in farneback_flow.wgsl).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable, Default)]
struct FlowParams {
    width: u32,
    height: u32,
    radius: u32,
    halo: u32,
    strip_rows: u32,
    run: u32,
    /// start: 0 zero flow, 1 resize `flow_in`.
    mode: u32,
    /// Window passes: 0 write M, 1 write the level's flow (into M's texture), 2 write the final
    /// flow.
    last: u32,
    src_w: u32,
    src_h: u32,
    flow_stride: u32,
    flow_offset: u32,
    scale: f32,
    factor: f32,
    scale_x: f32,
    scale_y: f32,
}

/// Texels of replicated border left and right of a level image (HALO in farneback_pyramid.wgsl).
const HALO: u32 = 2;

/// Smoothing taps a level's uniform holds (`Taps` in farneback_pyramid.wgsl).
const MAX_TAPS: usize = 1024;

/// Texels per invocation of the horizontal window pass.
const FLOW_RUN: u32 = 8;

/// Texels of replicated border left and right of the vertical window sums: the horizontal
/// window reads radius + 1 pixels beyond a texel and one texel more.
fn window_halo(winsize: u32) -> u32 {
    (winsize / 2 + 1) / 4 + 2
}

/// Texels (four pixels each) of a row of `w` pixels.
fn texels(w: u32) -> u32 {
    w.div_ceil(4)
}

/// A texture usable as a shader input and a storage output.
fn texture(
    ctx: &GpuContext,
    label: &str,
    (w, h): (u32, u32),
    format: wgpu::TextureFormat,
) -> wgpu::Texture {
    ctx.texture(
        label,
        (w.max(1), h.max(1)),
        format,
        wgpu::TextureUsages::TEXTURE_BINDING
            | wgpu::TextureUsages::STORAGE_BINDING
            | wgpu::TextureUsages::COPY_DST,
    )
}

/// A uniform of [`MAX_TAPS`] taps (`Taps` in the shaders, the tap in x) starting with `values`.
fn taps_uniform(ctx: &GpuContext, label: &str, values: &[f32]) -> wgpu::Buffer {
    let mut taps = vec![[0f32; 4]; MAX_TAPS];
    for (t, v) in taps.iter_mut().zip(values) {
        t[0] = *v;
    }
    let bytes = bytemuck::cast_slice(&taps);
    ctx.buffer_init(label, wgpu::BufferUsages::UNIFORM, bytes)
}

fn view(t: &wgpu::Texture) -> wgpu::TextureView {
    t.create_view(&Default::default())
}

/// A view of a new Rgba32Float [`texture`].
fn float_view(ctx: &GpuContext, label: &str, size: (u32, u32)) -> wgpu::TextureView {
    view(&texture(ctx, label, size, TextureFormat::Rgba32Float))
}

/// A binding of a texture view.
fn tv(v: &wgpu::TextureView) -> wgpu::BindingResource<'_> {
    wgpu::BindingResource::TextureView(v)
}

struct Pipes {
    level0: Arc<wgpu::ComputePipeline>,
    vsmooth: Arc<wgpu::ComputePipeline>,
    hsmooth: Arc<wgpu::ComputePipeline>,
    polyexp: Arc<wgpu::ComputePipeline>,
    start: Arc<wgpu::ComputePipeline>,
    /// Vertical and horizontal window (box or Gaussian).
    vwin: Arc<wgpu::ComputePipeline>,
    hwin: Arc<wgpu::ComputePipeline>,
    copy: Arc<wgpu::ComputePipeline>,
}

impl Pipes {
    fn new(ctx: &GpuContext, params: &FarnebackParams) -> Result<Pipes> {
        let pyramid = |entry: &str| ctx.pipeline("farneback_pyramid", PYRAMID_WGSL, entry);
        let flow = |entry: &str| ctx.pipeline("farneback_flow", FLOW_WGSL, entry);
        let polyexp = ["polyexp5", "polyexp7"][usize::from(params.poly_n == 7)];
        let hbox = ["hbox0", "hbox1", "hbox2", "hbox3"][(params.winsize / 2 % 4) as usize];
        let (cols, rows) = if params.gaussian {
            ("vgauss", "hgauss")
        } else {
            ("vbox", hbox)
        };
        Ok(Pipes {
            level0: pyramid("level0")?,
            vsmooth: pyramid("vsmooth")?,
            hsmooth: pyramid("hsmooth")?,
            polyexp: pyramid(polyexp)?,
            start: flow("start")?,
            vwin: flow(cols)?,
            hwin: flow(rows)?,
            copy: ctx.pipeline("copy", COPY_WGSL, "main")?,
        })
    }
}

/// The pyramid's scratch shared by the slots (passes run one after another): the gray frame as
/// a texture, each level's image and (below level 0) the vertical part of its smoothing, each
/// level's uniforms, and the bind groups of the smoothing (vsmooth, hsmooth per level > 0).
struct PyramidScratch {
    gray: wgpu::TextureView,
    images: Vec<wgpu::TextureView>,
    params: Vec<wgpu::Buffer>,
    smooth: Vec<[wgpu::BindGroup; 2]>,
}

impl PyramidScratch {
    fn new(
        ctx: &GpuContext,
        pipes: &Pipes,
        levels: &[Level],
        p: &FarnebackParams,
        strip_rows: u32,
    ) -> Result<PyramidScratch> {
        let (w, h) = (levels[0].width, levels[0].height);
        let gray = view(&texture(
            ctx,
            "gray",
            (texels(w), h),
            TextureFormat::Rgba8Uint,
        ));
        let (kern, ig) = poly_weights(p.poly_n, p.poly_sigma);
        let n = p.poly_n as usize;
        let mut poly = [[0f32; 4]; 8];
        for (k, t) in poly.iter_mut().enumerate().take(n + 1) {
            *t = [kern[k], kern[n + 1 + k], kern[2 * (n + 1) + k], 0.0];
        }
        let mut images = Vec::new();
        let mut params = Vec::new();
        let mut smooth = Vec::new();
        for (k, l) in levels.iter().enumerate() {
            let radius = l.smooth.len() / 2;
            if radius + 2 > MAX_TAPS {
                return Err(Error::gpu(format!("Farneback level {k} smooths with {} taps; the shaders hold {MAX_TAPS} (use a smaller analysis resolution)", 2 * radius + 1)));
            }
            let (scale_x, scale_y) = resize_steps((w, h), (l.width, l.height));
            let u = ctx.uniform(
                "pyramid params",
                &PyrParams {
                    src_w: w,
                    src_h: h,
                    dst_w: l.width,
                    dst_h: l.height,
                    radius: radius as u32,
                    strip_rows,
                    poly_n: p.poly_n,
                    scale_x,
                    scale_y,
                    ig: ig.map(|v| v as f32),
                    poly,
                    ..PyrParams::zeroed()
                },
            );
            let image = float_view(ctx, "level image", (texels(l.width) + 2 * HALO, l.height));
            if k > 0 {
                let taps = taps_uniform(ctx, "smoothing taps", &l.smooth[radius..]);
                let vert = float_view(ctx, "vertical smoothing", (texels(w), 2 * l.height));
                let b = |pipe: &wgpu::ComputePipeline,
                         input: &wgpu::TextureView,
                         output: &wgpu::TextureView,
                         at: u32| {
                    ctx.bind_resources(
                        "farneback pyramid",
                        pipe,
                        &[
                            (at, tv(input)),
                            (1, tv(output)),
                            (6, u.as_entire_binding()),
                            (7, taps.as_entire_binding()),
                        ],
                    )
                };
                smooth.push([
                    b(&pipes.vsmooth, &gray, &vert, 3),
                    b(&pipes.hsmooth, &vert, &image, 4),
                ]);
            }
            images.push(image);
            params.push(u);
        }
        Ok(PyramidScratch {
            gray,
            images,
            params,
            smooth,
        })
    }
}

/// One frame's expansion pyramid on the device and the bind groups that compute it.
struct FrameSlot {
    gray: wgpu::Buffer,
    /// Per level: the expansion (Rgba32Float, two texels per pixel: channels 0..3, then channel
    /// 4 of the pixel and of its right neighbour).
    r: Vec<wgpu::TextureView>,
    level0: wgpu::BindGroup,
    polyexp: Vec<wgpu::BindGroup>,
}

impl FrameSlot {
    fn new(
        ctx: &GpuContext,
        pipes: &Pipes,
        levels: &[Level],
        scratch: &PyramidScratch,
    ) -> FrameSlot {
        let (w, h) = (levels[0].width, levels[0].height);
        let gray = ctx.storage_buffer("gray upload", u64::from(w) * u64::from(h));
        let level0 = ctx.bind_resources(
            "farneback pyramid",
            &pipes.level0,
            &[
                (0, gray.as_entire_binding()),
                (1, tv(&scratch.images[0])),
                (2, tv(&scratch.gray)),
                (6, scratch.params[0].as_entire_binding()),
            ],
        );
        let r: Vec<_> = levels
            .iter()
            .map(|l| float_view(ctx, "expansion", (2 * l.width, l.height)))
            .collect();
        let polyexp = (0..levels.len())
            .map(|k| {
                ctx.bind_resources(
                    "farneback pyramid",
                    &pipes.polyexp,
                    &[
                        (4, tv(&scratch.images[k])),
                        (1, tv(&r[k])),
                        (6, scratch.params[k].as_entire_binding()),
                    ],
                )
            })
            .collect();
        FrameSlot {
            gray,
            r,
            level0,
            polyexp,
        }
    }
}

/// One level's flow scratch shared by the slot pairs (flows run one after another): M and the
/// level's flow, the vertical window sums, at the coarsest level the initial flow (textures),
/// the uniforms of the start (resize the coarser flow; at the coarsest level: zero, or the
/// initial flow) and of the window passes (`mid` writes M, `last` the flow), and the vertical
/// window's bind group.
struct LevelScratch {
    m: wgpu::TextureView,
    vs: wgpu::TextureView,
    initial: Option<(wgpu::Texture, wgpu::TextureView)>,
    start: wgpu::Buffer,
    start_initial: Option<wgpu::Buffer>,
    mid: wgpu::Buffer,
    last: wgpu::Buffer,
    vwin: wgpu::BindGroup,
}

impl LevelScratch {
    fn new(
        ctx: &GpuContext,
        pipes: &Pipes,
        levels: &[Level],
        k: usize,
        p: &FarnebackParams,
        strip_rows: u32,
        taps: &wgpu::Buffer,
    ) -> LevelScratch {
        let l = &levels[k];
        let (n, h) = (texels(l.width), l.height);
        let radius = p.winsize / 2;
        let halo = window_halo(p.winsize);
        let m = float_view(ctx, "matrices and flow", (7 * n, h));
        let vs = float_view(ctx, "window sums", (5 * (n + 2 * halo), h));
        let base = FlowParams {
            width: l.width,
            height: l.height,
            radius,
            halo,
            strip_rows,
            run: FLOW_RUN,
            scale: window_weights(p.winsize, p.gaussian).1,
            ..Default::default()
        };
        let uniform = |v: FlowParams| ctx.uniform("flow params", &v);
        // From the flow in texels 7 t + 5, 7 t + 6 of the coarser level's M (the initial flow: 2 t,
        // 2 t + 1).
        let resize_from = |c: &Level, factor: f32, flow_stride: u32, flow_offset: u32| {
            let (scale_x, scale_y) = resize_steps((c.width, c.height), (l.width, l.height));
            uniform(FlowParams {
                mode: 1,
                src_w: c.width,
                src_h: c.height,
                flow_stride,
                flow_offset,
                factor,
                scale_x,
                scale_y,
                ..base
            })
        };
        let (start, start_initial) = match levels.get(k + 1) {
            Some(c) => (resize_from(c, (1.0 / p.pyr_scale) as f32, 7, 5), None),
            None => (uniform(base), Some(resize_from(l, 1.0, 2, 0))),
        };
        let initial = start_initial.as_ref().map(|_| {
            let t = texture(ctx, "initial flow", (2 * n, h), TextureFormat::Rgba32Float);
            let v = view(&t);
            (t, v)
        });
        let mid = uniform(base);
        let last = uniform(FlowParams {
            last: if k == 0 { 2 } else { 1 },
            ..base
        });
        let mut entries = vec![(4, tv(&m)), (7, tv(&vs)), (11, mid.as_entire_binding())];
        if p.gaussian {
            entries.push((12, taps.as_entire_binding()));
        }
        let vwin = ctx.bind_resources("farneback flow", &pipes.vwin, &entries);
        LevelScratch {
            m,
            vs,
            initial,
            start,
            start_initial,
            mid,
            last,
            vwin,
        }
    }
}

/// Bind groups of one level's flow for one (prev, next) slot order: the start (with the
/// initial flow at the coarsest level), the horizontal window writing M or the flow, and the
/// copy of prev's expansion into next's.
struct LevelFlow {
    start: wgpu::BindGroup,
    start_initial: Option<wgpu::BindGroup>,
    hmid: wgpu::BindGroup,
    hlast: wgpu::BindGroup,
    copy: wgpu::BindGroup,
}

impl LevelFlow {
    fn new(fb: &FarnebackGpu, k: usize, (from, to): (usize, usize)) -> LevelFlow {
        let (prev, next) = (&fb.slots[from], &fb.slots[to]);
        let s = &fb.level_scratch[k];
        let r = [(0, tv(&prev.r[k])), (1, tv(&next.r[k])), (5, tv(&s.m))];
        // The flow the start reads: the coarser level's (in its M texture) or the initial one.
        let flow_in = match (fb.level_scratch.get(k + 1), &s.initial) {
            (Some(c), _) => &c.m,
            (None, Some((_, v))) => v,
            (None, None) => &s.m,
        };
        let start = |u: &wgpu::Buffer, flow: &wgpu::TextureView| {
            let mut e = r.to_vec();
            e.extend([(8, tv(flow)), (11, u.as_entire_binding())]);
            fb.ctx.bind_resources("farneback flow", &fb.pipes.start, &e)
        };
        let hwin = |u: &wgpu::Buffer| {
            let mut e = r.to_vec();
            e.extend([
                (6, tv(&s.vs)),
                (10, fb.flow_out.as_entire_binding()),
                (11, u.as_entire_binding()),
            ]);
            if fb.params.gaussian {
                e.push((12, fb.taps.as_entire_binding()));
            }
            fb.ctx.bind_resources("farneback flow", &fb.pipes.hwin, &e)
        };
        LevelFlow {
            start: start(&s.start, flow_in),
            start_initial: s.start_initial.as_ref().map(|u| start(u, flow_in)),
            hmid: hwin(&s.mid),
            hlast: hwin(&s.last),
            copy: fb.ctx.bind_resources(
                "farneback copy",
                &fb.pipes.copy,
                &[(0, tv(&prev.r[k])), (1, tv(&next.r[k]))],
            ),
        }
    }
}

/// Number of frame slots: each holds one frame's expansion pyramid on the device, so a video's
/// frames are expanded once and flow runs between any two slots (previous frame, reference frame,
/// current frame).
pub const SLOTS: usize = 3;

/// Rows per invocation of the pyramid's strip passes on `ctx`'s adapter: software adapters run
/// each invocation on a CPU SIMD lane and gain from long strips (fewer re-read window rows);
/// hardware GPUs need many short strips for occupancy.
pub fn strip_rows_for(ctx: &GpuContext) -> u32 {
    if ctx.summary().software {
        16
    } else {
        4
    }
}

/// Farneback flow on the GPU for frames of one size.
pub struct FarnebackGpu {
    ctx: Arc<GpuContext>,
    params: FarnebackParams,
    levels: Vec<Level>,
    pipes: Pipes,
    strip_rows: u32,
    scratch: PyramidScratch,
    slots: Vec<FrameSlot>,
    level_scratch: Vec<LevelScratch>,
    /// Gaussian window taps (uniform, bound when `params.gaussian`).
    taps: wgpu::Buffer,
    /// Per ordered slot pair (from, to): per level bind groups.
    flows: Vec<((usize, usize), Vec<LevelFlow>)>,
    /// The full-resolution flow (2 x f32 per pixel).
    flow_out: wgpu::Buffer,
    pad: Vec<u8>,
}

/// One dispatch: its kind (for profiles), pipeline, bind group and workgroups.
#[derive(Clone, Copy)]
struct Step<'a>(
    &'static str,
    &'a wgpu::ComputePipeline,
    &'a wgpu::BindGroup,
    (u32, u32),
);

impl FarnebackGpu {
    /// Allocates everything for `width` x `height` 8-bit gray frames.
    pub fn new(
        ctx: Arc<GpuContext>,
        params: FarnebackParams,
        width: u32,
        height: u32,
    ) -> Result<Self> {
        let strip_rows = strip_rows_for(&ctx);
        Self::with_strip_rows(ctx, params, width, height, strip_rows)
    }

    /// As [`FarnebackGpu::new`] with `strip_rows` rows per invocation of the strip passes (for
    /// `bench`).
    pub fn with_strip_rows(
        ctx: Arc<GpuContext>,
        params: FarnebackParams,
        width: u32,
        height: u32,
        strip_rows: u32,
    ) -> Result<Self> {
        params.validate()?;
        if width < 2 || height < 2 {
            let msg = "Farneback needs at least 2x2 pixels";
            return Err(Error::param("frame size", msg));
        }
        let levels = levels(width, height, &params);
        let full = u64::from(width) * u64::from(height);
        let max = ctx.limits.max_texture_dimension_2d;
        if full * 20 > ctx.limits.max_storage_buffer_binding_size || width > max || height > max {
            return Err(Error::gpu(format!(
                "Farneback at {width}x{height} needs {} MiB buffers and {width}x{height} textures; this adapter binds at most {} MiB and {max}x{max} (use a smaller analysis resolution)",
                (full * 20) >> 20,
                ctx.limits.max_storage_buffer_binding_size >> 20
            )));
        }
        let strip_rows = strip_rows.max(1);
        let n = texels(width);
        let halo = window_halo(params.winsize);
        if 5 * (n + 2 * halo) > max || 7 * n > max {
            return Err(Error::gpu(format!(
                "Farneback at width {width} with winsize {} needs {} texel wide textures; this adapter allows {max}",
                params.winsize,
                5 * (n + 2 * halo)
            )));
        }
        let pipes = Pipes::new(&ctx, &params)?;
        let scratch = PyramidScratch::new(&ctx, &pipes, &levels, &params, strip_rows)?;
        let slots: Vec<FrameSlot> = (0..SLOTS)
            .map(|_| FrameSlot::new(&ctx, &pipes, &levels, &scratch))
            .collect();
        let weights = window_weights(params.winsize, params.gaussian).0;
        let taps = taps_uniform(&ctx, "window taps", &weights);
        let level_scratch = (0..levels.len())
            .map(|k| LevelScratch::new(&ctx, &pipes, &levels, k, &params, strip_rows, &taps))
            .collect();
        let flow_out = ctx.storage_buffer("flow", (full * 8).next_multiple_of(16));
        let mut fb = FarnebackGpu {
            ctx,
            params,
            levels,
            pipes,
            strip_rows,
            scratch,
            slots,
            level_scratch,
            taps,
            flows: Vec::new(),
            flow_out,
            pad: Vec::new(),
        };
        let mut flows = Vec::new();
        for from in 0..SLOTS {
            for to in (0..SLOTS).filter(|&t| t != from) {
                let per_level = (0..fb.levels.len()).map(|k| LevelFlow::new(&fb, k, (from, to)));
                flows.push(((from, to), per_level.collect()));
            }
        }
        fb.flows = flows;
        Ok(fb)
    }

    /// The dispatches that compute `slot`'s expansion pyramid, in order.
    fn pyramid_steps(&self, slot: usize) -> Vec<Step<'_>> {
        let s = &self.slots[slot];
        let (w, h) = (self.levels[0].width, self.levels[0].height);
        let (by8, p, rows) = (|n: u32| n.div_ceil(8), &self.pipes, self.strip_rows);
        let mut steps = vec![Step(
            "level0",
            &p.level0,
            &s.level0,
            (by8(w.div_ceil(16)), h.div_ceil(rows)),
        )];
        for (k, l) in self.levels.iter().enumerate() {
            if k > 0 {
                let [v, hz] = &self.scratch.smooth[k - 1];
                steps.push(Step("vsmooth", &p.vsmooth, v, (by8(texels(w)), l.height)));
                steps.push(Step(
                    "hsmooth",
                    &p.hsmooth,
                    hz,
                    (by8(texels(l.width) + 2 * HALO), l.height),
                ));
            }
            steps.push(Step(
                "polyexp",
                &p.polyexp,
                &s.polyexp[k],
                (by8(l.width.div_ceil(16)), l.height.div_ceil(rows)),
            ));
        }
        steps
    }

    /// The per level bind groups of the ordered slot pair (`from`, `to`).
    fn pair(&self, from: usize, to: usize) -> Result<&[LevelFlow]> {
        self.flows
            .iter()
            .find(|(k, _)| *k == (from, to))
            .map(|(_, per_level)| per_level.as_slice())
            .ok_or_else(|| Error::param("slots", format!("need two distinct slots below {SLOTS}")))
    }

    /// The dispatches of the flow from slot `from` to slot `to` (from the initial flow written
    /// into the coarsest level's flow texture with `initial`), coarsest level first.
    fn flow_steps(&self, from: usize, to: usize, initial: bool) -> Result<Vec<Step<'_>>> {
        let per_level = self.pair(from, to)?;
        let by8 = |n: u32| n.div_ceil(8);
        let mut steps = Vec::new();
        for ((l, lf), s) in self
            .levels
            .iter()
            .zip(per_level)
            .zip(&self.level_scratch)
            .rev()
        {
            let n = texels(l.width);
            let halo = window_halo(self.params.winsize);
            let start = match (&lf.start_initial, initial) {
                (Some(bg), true) => bg,
                _ => &lf.start,
            };
            steps.push(Step("start", &self.pipes.start, start, (by8(n), l.height)));
            for i in 0..self.params.iterations {
                steps.push(Step(
                    "vwindow",
                    &self.pipes.vwin,
                    &s.vwin,
                    (by8(n + 2 * halo), l.height.div_ceil(self.strip_rows)),
                ));
                let last = i + 1 == self.params.iterations;
                steps.push(Step(
                    "hwindow",
                    &self.pipes.hwin,
                    if last { &lf.hlast } else { &lf.hmid },
                    (by8(n.div_ceil(FLOW_RUN)), l.height),
                ));
            }
        }
        Ok(steps)
    }

    /// The dispatches copying slot `from`'s expansion pyramid into slot `to`, one per level.
    fn copy_steps(&self, from: usize, to: usize) -> Result<Vec<Step<'_>>> {
        let per_level = self.pair(from, to)?;
        let steps = (self.levels.iter().zip(per_level))
            .map(|(l, lf)| {
                Step(
                    "copy",
                    &self.pipes.copy,
                    &lf.copy,
                    ((2 * l.width).div_ceil(8), l.height.div_ceil(8)),
                )
            })
            .collect();
        Ok(steps)
    }

    /// Records `steps` in one compute pass of `enc`, with a `gate` over entries in `steps`'
    /// order.
    fn encode(
        &self,
        enc: &mut wgpu::CommandEncoder,
        label: &str,
        steps: &[Step<'_>],
        gate: Option<Gate<'_>>,
    ) {
        let mut pass = compute_pass(enc, label);
        for (k, s) in steps.iter().enumerate() {
            self.ctx.dispatch_gated(&mut pass, (s.1, s.2), s.3, gate, k);
        }
    }

    /// The workgroups of [`FarnebackGpu::encode_flow`]'s dispatches, in the order of its gate
    /// entries (one per dispatch).
    pub fn flow_shapes(&self) -> Vec<(u32, u32)> {
        let steps = self.flow_steps(0, 1, false).unwrap_or_default();
        steps.iter().map(|s| s.3).collect()
    }

    /// The workgroups of [`FarnebackGpu::encode_copy`]'s dispatches (one per level).
    pub fn copy_shapes(&self) -> Vec<(u32, u32)> {
        let steps = self.copy_steps(0, 1).unwrap_or_default();
        steps.iter().map(|s| s.3).collect()
    }

    /// Records the flow from slot `from` to slot `to` into [`FarnebackGpu::flow_buffer`], gated
    /// by `gate` when given (entries as [`FarnebackGpu::flow_shapes`] lists them).
    pub fn encode_flow(
        &self,
        enc: &mut wgpu::CommandEncoder,
        (from, to): (usize, usize),
        gate: Option<Gate<'_>>,
    ) -> Result<()> {
        let steps = self.flow_steps(from, to, false)?;
        self.encode(enc, "farneback flow", &steps, gate);
        Ok(())
    }

    /// Records the copy of slot `from`'s expansion pyramid into slot `to` (a flow from `to` then
    /// starts from `from`'s frame), gated by `gate` when given (entries as
    /// [`FarnebackGpu::copy_shapes`] lists them).
    pub fn encode_copy(
        &self,
        enc: &mut wgpu::CommandEncoder,
        from: usize,
        to: usize,
        gate: Option<Gate<'_>>,
    ) -> Result<()> {
        let steps = self.copy_steps(from, to)?;
        self.encode(enc, "farneback copy", &steps, gate);
        Ok(())
    }

    /// Development aid: runs the pyramid of slot 0 and the flow from slot 0 to slot 1 (frames
    /// loaded before) one dispatch at a time, waiting for each, `rounds` times; returns per
    /// dispatch kind (in first-use order) the dispatches per pair and the ms per pair, each
    /// dispatch counted at its fastest round (the machine may be shared), as measured by `clock`
    /// (ms; e.g. wall time, or the process's CPU time on a shared machine).
    pub fn profile(
        &self,
        rounds: usize,
        clock: &dyn Fn() -> f64,
    ) -> Result<Vec<(&'static str, usize, f64)>> {
        let steps = [self.pyramid_steps(0), self.flow_steps(0, 1, false)?].concat();
        let mut best = vec![f64::MAX; steps.len()];
        for _ in 0..rounds.max(1) {
            for (s, b) in steps.iter().zip(best.iter_mut()) {
                let t = clock();
                let mut enc = self.ctx.encoder("farneback profile");
                self.encode(&mut enc, "farneback profile", std::slice::from_ref(s), None);
                self.ctx.queue.submit([enc.finish()]);
                self.ctx.wait()?;
                *b = b.min(clock() - t);
            }
        }
        let mut out: Vec<(&'static str, usize, f64)> = Vec::new();
        for (s, ms) in steps.iter().zip(best) {
            match out.iter_mut().find(|(k, _, _)| *k == s.0) {
                Some(e) => {
                    e.1 += 1;
                    e.2 += ms;
                }
                None => out.push((s.0, 1, ms)),
            }
        }
        Ok(out)
    }

    /// Uploads `gray` into `slot` and computes its expansion pyramid on the device.
    pub fn load<F: HostImage + ?Sized>(&mut self, slot: usize, gray: &F) -> Result<()> {
        if slot >= SLOTS {
            return Err(Error::param("slot", format!("must be below {SLOTS}")));
        }
        let size = (self.levels[0].width, self.levels[0].height);
        let bytes = gray.pixel_bytes(1, size, "Farneback (8-bit gray)")?;
        let buf = &self.slots[slot].gray;
        if bytes.len() % 4 == 0 {
            self.ctx.write(buf, 0, &bytes);
        } else {
            self.pad.clear();
            self.pad.extend_from_slice(&bytes);
            self.pad.resize(bytes.len().next_multiple_of(4), 0);
            self.ctx.write(buf, 0, &self.pad);
        }
        self.submit_pyramid(self.ctx.encoder("farneback pyramid"), slot);
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
            let msg = "smaller than the level-0 image";
            return Err(Error::param("gray buffer", msg));
        }
        let mut enc = self.ctx.encoder("farneback pyramid");
        enc.copy_buffer_to_buffer(gray, 0, &self.slots[slot].gray, 0, bytes);
        self.submit_pyramid(enc, slot);
        Ok(())
    }

    /// Records the expansion pyramid of `slot` after `enc`'s commands and submits them.
    fn submit_pyramid(&self, mut enc: wgpu::CommandEncoder, slot: usize) {
        let steps = self.pyramid_steps(slot);
        self.encode(&mut enc, "farneback pyramid", &steps, None);
        self.ctx.queue.submit([enc.finish()]);
    }

    /// Computes the flow from the frame in slot `from` to the frame in slot `to` into
    /// [`FarnebackGpu::flow_buffer`].
    pub fn flow_between(&mut self, from: usize, to: usize) -> Result<()> {
        let steps = self.flow_steps(from, to, false)?;
        let mut enc = self.ctx.encoder("farneback flow");
        self.encode(&mut enc, "farneback flow", &steps, None);
        self.ctx.queue.submit([enc.finish()]);
        Ok(())
    }

    /// As [`FarnebackGpu::flow_between`], starting from `initial` (CV_32FC2, full resolution) as
    /// OPTFLOW_USE_INITIAL_FLOW does: resized to the coarsest level with INTER_AREA and scaled.
    #[cfg(feature = "opencv")]
    pub fn flow_between_from(
        &mut self,
        from: usize,
        to: usize,
        initial: Option<&Mat>,
    ) -> Result<()> {
        let steps = self.flow_steps(from, to, initial.is_some())?;
        let mut enc = self.ctx.encoder("farneback flow");
        if let Some(init) = initial {
            let top = self
                .levels
                .last()
                .ok_or_else(|| Error::gpu("no pyramid levels"))?;
            let full = &self.levels[0];
            if init.typ() != opencv::core::CV_32FC2
                || (init.cols() as u32, init.rows() as u32) != (full.width, full.height)
            {
                let msg = format!("must be {}x{} CV_32FC2", full.width, full.height);
                return Err(Error::param("initial flow", msg));
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
            let values = scaled
                .data_typed::<opencv::core::Vec2f>()
                .cv(|| "initial flow values".into())?;
            let Some((top_flow, _)) = &self.level_scratch[self.levels.len() - 1].initial else {
                return Err(Error::gpu("no initial flow texture"));
            };
            let bytes = planar_flow(values, top.width as usize);
            self.ctx
                .write_texture(top_flow, &bytes, top_flow.width() * 16);
        }
        self.encode(&mut enc, "farneback flow", &steps, None);
        self.ctx.queue.submit([enc.finish()]);
        Ok(())
    }

    /// The full-resolution flow buffer (2 x f32 per pixel) of the last pair.
    pub fn flow_buffer(&self) -> &wgpu::Buffer {
        &self.flow_out
    }

    /// Reads back the flow of the last pair as CV_32FC2.
    #[cfg(feature = "opencv")]
    pub fn read_flow(&self) -> Result<Mat> {
        let (w, h) = (self.levels[0].width, self.levels[0].height);
        let bytes = self
            .ctx
            .read_back(&self.flow_out, u64::from(w) * u64::from(h) * 8)?;
        let floats: &[f32] = bytemuck::cast_slice(&bytes);
        let flat = Mat::new_rows_cols_with_data(h as i32, 2 * w as i32, floats);
        (flat.and_then(|m| m.reshape(2, h as i32)?.try_clone())).cv(|| "flow data".into())
    }

    /// The flow from `prev` to `next` (8-bit gray), read back as CV_32FC2.
    #[cfg(feature = "opencv")]
    pub fn flow(&mut self, prev: &Mat, next: &Mat) -> Result<Mat> {
        self.flow_from(prev, next, None)
    }

    /// As [`FarnebackGpu::flow`], optionally starting from an initial flow.
    #[cfg(feature = "opencv")]
    pub fn flow_from(&mut self, prev: &Mat, next: &Mat, initial: Option<&Mat>) -> Result<Mat> {
        self.load(0, prev)?;
        self.load(1, next)?;
        self.flow_between_from(0, 1, initial)?;
        self.read_flow()
    }
}

/// A flow field (`width` pixels per row) in the layout of the level flow textures: per row and
/// texel t, the x components of pixels 4 t .. 4 t + 3, then their y components (f32 bytes).
#[cfg(feature = "opencv")]
fn planar_flow(values: &[opencv::core::Vec2f], width: usize) -> Vec<u8> {
    let n = width.div_ceil(4);
    let mut out = vec![0f32; values.len().div_ceil(width.max(1)) * n * 8];
    for (i, v) in values.iter().enumerate() {
        let (y, x) = (i / width, i % width);
        let o = (y * n + x / 4) * 8 + x % 4;
        out[o] = v[0];
        out[o + 4] = v[1];
    }
    bytemuck::cast_slice(&out).to_vec()
}
