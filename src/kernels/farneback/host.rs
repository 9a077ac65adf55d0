//! `farneback::host`: cv::calcOpticalFlowFarneback's CPU algorithm (without an initial flow) in
//! two halves, so that a frame's pyramid of polynomial expansions ([`Expander::expand`]) is computed once
//! and reused by every pair it is in ([`flow`]). Bit-identical to the OpenCV call: the level
//! images and the flow's level-to-level resize come from OpenCV itself (convertTo, GaussianBlur,
//! resize, the expansion's 6x6 inverse), and the expansion, the matrices and the window solve
//! repeat OpenCV's scalar code operation for operation (f32 where it computes in float, f64
//! where in double, the same order). Tested against the OpenCV call bit for bit.

#[cfg(target_arch = "x86_64")]
mod avx2;

use super::{levels, poly_moments, poly_taps, window_weights};
use crate::error::{CvContext, Error, Result};
use crate::params::FarnebackParams;
use opencv::core::{Mat, Size, Vec2f, CV_32F, CV_32FC2};
use opencv::prelude::*;

/// One pyramid level's polynomial expansion: 5 coefficients per pixel (OpenCV's R matrices).
struct LevelExpansion {
    width: usize,
    height: usize,
    r: Vec<f32>,
}

/// A frame's polynomial expansions at every pyramid level of `params` (index 0 = full size).
pub struct Expansion {
    params: FarnebackParams,
    levels: Vec<LevelExpansion>,
}

impl Expansion {
    /// Width and height of the frame.
    pub fn size(&self) -> (usize, usize) {
        self.levels.first().map_or((0, 0), |l| (l.width, l.height))
    }
}

/// The expansion kernel: FarnebackPrepareGaussian's taps from the centre out and its inverse
/// moments (ig11, ig03, ig33, ig55).
struct Weights {
    g: Vec<f32>,
    xg: Vec<f32>,
    xxg: Vec<f32>,
    ig: [f64; 4],
}

impl Weights {
    fn new(p: &FarnebackParams) -> Result<Weights> {
        let n = p.poly_n as usize;
        let [g, xg, xxg] = poly_taps(p.poly_n, p.poly_sigma);
        let gm = poly_moments(&g);
        let rows: Vec<Vec<f64>> = gm.iter().map(|r| r.to_vec()).collect();
        let m = Mat::from_slice_2d(&rows).cv(|| "farneback moments".into())?;
        let inv = m
            .inv(opencv::core::DECOMP_CHOLESKY)
            .and_then(|e| e.to_mat())
            .cv(|| "farneback moments inverse".into())?;
        let at = |r: i32, c: i32| -> Result<f64> {
            inv.at_2d::<f64>(r, c)
                .copied()
                .cv(|| "farneback moments inverse".into())
        };
        Ok(Weights {
            g: g[n..].to_vec(),
            xg: xg[n..].to_vec(),
            xxg: xxg[n..].to_vec(),
            ig: [at(1, 1)?, at(0, 3)?, at(3, 3)?, at(5, 5)?],
        })
    }
}

/// Expands frames with one parameter set (checked once, its expansion kernel computed once).
pub struct Expander {
    params: FarnebackParams,
    weights: Weights,
}

impl Expander {
    /// The expander for `p` (an error for parameters OpenCV would refuse).
    pub fn new(p: &FarnebackParams) -> Result<Expander> {
        p.validate()?;
        Ok(Expander {
            params: *p,
            weights: Weights::new(p)?,
        })
    }

    /// The expansions of `gray` (8-bit, one channel) at every level, with the level images
    /// exactly as cv::calcOpticalFlowFarneback makes them (each level blurred from the
    /// full-size image, then resized).
    pub fn expand(&self, gray: &Mat) -> Result<Expansion> {
        let p = &self.params;
        let (w, h) = (gray.cols(), gray.rows());
        if w <= 0 || h <= 0 || gray.channels() != 1 {
            return Err(Error::param(
                "farneback",
                format!(
                    "expansion needs a one-channel image, got {w}x{h} with {} channels",
                    gray.channels()
                ),
            ));
        }
        let mut full = Mat::default();
        gray.convert_to(&mut full, CV_32F, 1.0, 0.0)
            .cv(|| "farneback convertTo".into())?;
        let mut out = Vec::new();
        for level in levels(w as u32, h as u32, p) {
            let sigma = (1.0 / level.scale - 1.0) * 0.5;
            let k = level.smooth.len() as i32;
            let mut blurred = Mat::default();
            opencv::imgproc::gaussian_blur(
                &full,
                &mut blurred,
                Size::new(k, k),
                sigma,
                sigma,
                opencv::core::BORDER_DEFAULT,
            )
            .cv(|| "farneback GaussianBlur".into())?;
            let (lw, lh) = (level.width as usize, level.height as usize);
            let image = resize_linear(&blurred, (lw, lh))?;
            let src = image
                .data_typed::<f32>()
                .cv(|| "farneback level image".into())?;
            out.push(LevelExpansion {
                width: lw,
                height: lh,
                r: poly_exp(src, (lw, lh), &self.weights),
            });
        }
        Ok(Expansion {
            params: *p,
            levels: out,
        })
    }
}

/// cv::resize(src, (width, height), INTER_LINEAR), as calcOpticalFlowFarneback calls it for the
/// level images and the flow from the level above.
fn resize_linear(src: &Mat, (width, height): (usize, usize)) -> Result<Mat> {
    let mut out = Mat::default();
    let size = Size::new(width as i32, height as i32);
    opencv::imgproc::resize(src, &mut out, size, 0.0, 0.0, opencv::imgproc::INTER_LINEAR)
        .cv(|| format!("farneback resize to {width}x{height}"))?;
    Ok(out)
}

/// The flow from `a`'s frame to `b`'s (CV_32FC2), as cv::calcOpticalFlowFarneback(a, b, flags
/// without OPTFLOW_USE_INITIAL_FLOW) computes it.
pub fn flow(a: &Expansion, b: &Expansion) -> Result<Mat> {
    if a.params != b.params || a.size() != b.size() || a.levels.len() != b.levels.len() {
        return Err(Error::param(
            "farneback",
            format!(
                "the two expansions differ: {:?} vs {:?} pixels, or their parameters",
                a.size(),
                b.size()
            ),
        ));
    }
    let p = &a.params;
    let mut prev: Option<Mat> = None;
    let mut matrices = Vec::new();
    for (r0, r1) in a.levels.iter().zip(&b.levels).rev() {
        let (w, h) = (r0.width, r0.height);
        let mut flow = vec![0f32; w * h * 2];
        if let Some(prev) = &prev {
            let resized = resize_linear(prev, (w, h))?;
            let mut scaled = Mat::default();
            resized
                .convert_to(&mut scaled, -1, 1.0 / p.pyr_scale, 0.0)
                .cv(|| "farneback flow scale".into())?;
            let v = scaled
                .data_typed::<Vec2f>()
                .cv(|| "farneback flow".into())?;
            for (d, s) in flow.chunks_exact_mut(2).zip(v) {
                d[0] = s[0];
                d[1] = s[1];
            }
        }
        let level = LevelPair::new(&r0.r, &r1.r, (w, h), avx2());
        matrices.resize(w * h * 5, 0f32);
        level.solve(&mut flow, &mut matrices, p);
        let mut mat = Mat::new_rows_cols_with_default(
            h as i32,
            w as i32,
            CV_32FC2,
            opencv::core::Scalar::all(0.0),
        )
        .cv(|| "farneback flow".into())?;
        let v = mat
            .data_typed_mut::<Vec2f>()
            .cv(|| "farneback flow".into())?;
        for (d, s) in v.iter_mut().zip(flow.chunks_exact(2)) {
            d[0] = s[0];
            d[1] = s[1];
        }
        prev = Some(mat);
    }
    prev.ok_or_else(|| Error::param("farneback", "no pyramid level"))
}

/// Whether this CPU runs the AVX2 builds of the loops (checked once by the standard library).
fn avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    return std::arch::is_x86_feature_detected!("avx2");
    #[cfg(not(target_arch = "x86_64"))]
    return false;
}

/// [`poly_exp_generic`], compiled for AVX2 where the CPU has it. The two builds do the same f32
/// and f64 operations in the same order (vectorising element-wise loops reorders nothing, and
/// Rust never fuses a multiply and an add), so they give the same bits: `paths_agree` checks.
fn poly_exp(src: &[f32], size: (usize, usize), k: &Weights) -> Vec<f32> {
    #[cfg(target_arch = "x86_64")]
    if avx2() {
        // SAFETY: the CPU supports AVX2 (checked just above), the only requirement of
        // `poly_exp_avx2`'s `target_feature`.
        return unsafe { poly_exp_avx2(src, size, k) };
    }
    poly_exp_generic(src, size, k)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn poly_exp_avx2(src: &[f32], size: (usize, usize), k: &Weights) -> Vec<f32> {
    poly_exp_generic(src, size, k)
}

/// FarnebackPolyExp: the 5 coefficients (r2..r6, r1 not stored) of every pixel of `src`.
/// OpenCV's loop per pixel, reorganised so that each step runs along a row (vectorisable):
/// every pixel's sums take the same terms in the same order.
#[inline(always)]
fn poly_exp_generic(src: &[f32], (width, height): (usize, usize), k: &Weights) -> Vec<f32> {
    let n = k.g.len() - 1;
    let (g, xg, xxg) = (&k.g, &k.xg, &k.xxg);
    let [ig11, ig03, ig33, ig55] = k.ig;
    let mut dst = vec![0f32; width * height * 5];
    // A row's three vertical sums, each with n pixels of border on either side.
    let mut v = [(); 3].map(|_| vec![0f32; width + 2 * n]);
    // Its six horizontal sums (OpenCV's b1..b6), per pixel.
    let mut b = [(); 6].map(|_| vec![0f64; width]);
    for y in 0..height {
        let srow = &src[y * width..(y + 1) * width];
        {
            let [v0, v1, v2] = &mut v;
            let (v0, v1, v2) = (
                &mut v0[n..n + width],
                &mut v1[n..n + width],
                &mut v2[n..n + width],
            );
            for (((a, b), c), &s) in v0
                .iter_mut()
                .zip(v1.iter_mut())
                .zip(v2.iter_mut())
                .zip(srow)
            {
                *a = s * g[0];
                *b = 0.0;
                *c = 0.0;
            }
            for kk in 1..=n {
                let (g0, g1, g2) = (g[kk], xg[kk], xxg[kk]);
                let up = y.saturating_sub(kk);
                let down = (y + kk).min(height - 1);
                let s0 = &src[up * width..(up + 1) * width];
                let s1 = &src[down * width..(down + 1) * width];
                let sums = v0.iter_mut().zip(v1.iter_mut()).zip(v2.iter_mut());
                for (((r0, r1), r2), (&a, &b)) in sums.zip(s0.iter().zip(s1)) {
                    let p = a + b;
                    *r0 += g0 * p;
                    *r1 += g1 * (b - a);
                    *r2 += g2 * p;
                }
            }
        }
        // Replicate the first and last pixel into the border, as OpenCV's loop does.
        for r in &mut v {
            let (first, last) = (r[n], r[n + width - 1]);
            r[..n].fill(first);
            r[n + width..].fill(last);
        }
        let [v0, v1, v2] = &v;
        let [b1, b2, b3, b4, b5, b6] = &mut b;
        let g0 = g[0];
        for (x, ((((b1, b2), b3), b4), b5)) in b1
            .iter_mut()
            .zip(b2.iter_mut())
            .zip(b3.iter_mut())
            .zip(b4.iter_mut())
            .zip(b5.iter_mut())
            .enumerate()
        {
            *b1 = f64::from(v0[n + x] * g0);
            *b2 = 0.0;
            *b3 = f64::from(v1[n + x] * g0);
            *b4 = 0.0;
            *b5 = f64::from(v2[n + x] * g0);
        }
        b6.fill(0.0);
        for kk in 1..=n {
            let (gk, xgk, xxgk) = (g[kk], xg[kk], xxg[kk]);
            let (gk64, xxgk64) = (f64::from(gk), f64::from(xxgk));
            let (right, left) = (n + kk..n + kk + width, n - kk..n - kk + width);
            let (r0, l0) = (&v0[right.clone()], &v0[left.clone()]);
            let (r1, l1) = (&v1[right.clone()], &v1[left.clone()]);
            let (r2, l2) = (&v2[right], &v2[left]);
            for x in 0..width {
                let tg = f64::from(r0[x] + l0[x]);
                b1[x] += tg * gk64;
                b4[x] += tg * xxgk64;
                b2[x] += f64::from((r0[x] - l0[x]) * xgk);
                b3[x] += f64::from((r1[x] + l1[x]) * gk);
                b6[x] += f64::from((r1[x] - l1[x]) * xgk);
                b5[x] += f64::from((r2[x] + l2[x]) * gk);
            }
        }
        let drow = &mut dst[y * width * 5..(y + 1) * width * 5];
        for (x, d) in drow.chunks_exact_mut(5).enumerate() {
            d[1] = (b2[x] * ig11) as f32;
            d[0] = (b3[x] * ig11) as f32;
            d[3] = (b1[x] * ig03 + b4[x] * ig33) as f32;
            d[2] = (b1[x] * ig03 + b5[x] * ig33) as f32;
            d[4] = (b6[x] * ig55) as f32;
        }
    }
    dst
}

/// One level's two expansions.
struct LevelPair<'a> {
    r0: &'a [f32],
    r1: &'a [f32],
    width: usize,
    height: usize,
    /// Each column's border weight product (`xl * xh` of [`border_weight`]), for the AVX2 rows.
    column_weights: Vec<f32>,
    /// Whether the matrices run eight pixels at a time ([`avx2`]; only where the CPU has AVX2).
    simd: bool,
}

/// Weights of FarnebackUpdateMatrices' border rows and columns.
const BORDER: [f32; 5] = [0.14, 0.14, 0.4472, 0.4472, 0.4472];

/// cvFloor: the largest integer not above `v`; i32::MIN (out of every image) for a value
/// beyond i32 or not a number, as x86's conversion gives (OpenCV's and the AVX2 rows').
#[inline(always)]
fn floor(v: f32) -> i32 {
    if !(-2_147_483_648.0..2_147_483_648.0).contains(&v) {
        return i32::MIN;
    }
    let i = v as i32;
    i - i32::from(i as f32 > v)
}

/// OpenCV's border weights along one axis at `i` of `n`: `i < BORDER ? border[i] : 1` and `i >=
/// n - BORDER ? border[n - i - 1] : 1` (multiplied x then y, left to right, as OpenCV does).
#[inline(always)]
fn border_weight(i: usize, n: usize) -> (f32, f32) {
    let low = if i < 5 { BORDER[i] } else { 1.0 };
    let high = if i + 5 >= n { BORDER[n - i - 1] } else { 1.0 };
    (low, high)
}

/// The flow of one pixel from its averaged (G11, G12, G22, h1, h2): OpenCV's 2x2 solve with
/// its 1e-3 regularisation, in f64.
#[inline(always)]
fn solve_window([g11, g12, g22, h1, h2]: [f64; 5]) -> [f32; 2] {
    let idet = 1.0 / (g11 * g22 - g12 * g12 + 1e-3);
    [
        ((g11 * h2 - g12 * h1) * idet) as f32,
        ((g22 * h1 - g12 * h2) * idet) as f32,
    ]
}

/// The flow of a row of pixels from their averaged matrices (`averaged`: G11 of every pixel,
/// then G12, G22, h1, h2).
#[inline(always)]
fn solve_row(row: &mut [f32], averaged: &[f64]) {
    let width = row.len() / 2;
    let (g11, rest) = averaged.split_at(width);
    let (g12, rest) = rest.split_at(width);
    let (g22, rest) = rest.split_at(width);
    let (h1, h2) = rest.split_at(width);
    let cells = g11.iter().zip(g12).zip(g22).zip(h1).zip(h2);
    for (f, ((((&g11, &g12), &g22), &h1), &h2)) in row.chunks_exact_mut(2).zip(cells) {
        f.copy_from_slice(&solve_window([g11, g12, g22, h1, h2]));
    }
}

impl<'a> LevelPair<'a> {
    /// The pair at one level; `simd` must only be true where the CPU has AVX2.
    fn new(r0: &'a [f32], r1: &'a [f32], (width, height): (usize, usize), simd: bool) -> Self {
        let column_weights = (0..width)
            .map(|x| {
                let (low, high) = border_weight(x, width);
                low * high
            })
            .collect();
        LevelPair {
            r0,
            r1,
            width,
            height,
            column_weights,
            simd: simd && cfg!(target_arch = "x86_64"),
        }
    }

    /// One level's flow iterations from the flow in `flow` (`m`: the matrices, any content),
    /// in the AVX2 build where the CPU has it (see [`poly_exp`]).
    fn solve(&self, flow: &mut [f32], m: &mut [f32], p: &FarnebackParams) {
        #[cfg(target_arch = "x86_64")]
        if avx2() {
            // SAFETY: the CPU supports AVX2 (checked just above), the only requirement of
            // `solve_avx2`'s `target_feature`.
            return unsafe { self.solve_avx2(flow, m, p) };
        }
        self.solve_generic(flow, m, p)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn solve_avx2(&self, flow: &mut [f32], m: &mut [f32], p: &FarnebackParams) {
        self.solve_generic(flow, m, p)
    }

    /// The iterations as calcOpticalFlowFarneback runs them: the matrices of the flow, then
    /// `iterations` window solves, each but the last followed by the matrices of its flow.
    #[inline(always)]
    fn solve_generic(&self, flow: &mut [f32], m: &mut [f32], p: &FarnebackParams) {
        self.update_matrices(flow, m, 0, self.height);
        for i in 0..p.iterations {
            let update = i + 1 < p.iterations;
            if p.gaussian {
                self.update_flow_gaussian(flow, m, p.winsize as usize, update);
            } else {
                self.update_flow_box(flow, m, p.winsize as usize, update);
            }
        }
    }

    /// FarnebackUpdateMatrices for rows `y0..y1`: the per-pixel matrices G and h from the flow.
    #[inline(always)]
    fn update_matrices(&self, flow: &[f32], m: &mut [f32], y0: usize, y1: usize) {
        let (width, height) = (self.width, self.height);
        let step = width * 5;
        // OpenCV's `(unsigned)(x - BORDER) >= (unsigned)(width - BORDER*2)`, wrapping alike.
        let inner_w = (width as u32).wrapping_sub(10);
        let inner_h = (height as u32).wrapping_sub(10);
        let (last_x, last_y) = (
            (width as u32).wrapping_sub(1),
            (height as u32).wrapping_sub(1),
        );
        for y in y0..y1 {
            let rows = y * step..(y + 1) * step;
            let frow = &flow[y * width * 2..(y + 1) * width * 2];
            let y_border = (y as u32).wrapping_sub(5) >= inner_h;
            let done = self.update_matrices_simd(frow, &mut m[rows.clone()], y);
            let cells = frow
                .chunks_exact(2)
                .zip(self.r0[rows.clone()].chunks_exact(5));
            let cells = cells.zip(m[rows].chunks_exact_mut(5)).enumerate();
            for (x, ((f, r0), out)) in cells.skip(done) {
                let (dx, dy) = (f[0], f[1]);
                let mut fx = x as f32 + dx;
                let mut fy = y as f32 + dy;
                let x1 = floor(fx);
                let y1 = floor(fy);
                fx -= x1 as f32;
                fy -= y1 as f32;
                let (mut r2, mut r3, mut r4, mut r5, mut r6);
                if (x1 as u32) < last_x && (y1 as u32) < last_y {
                    let a00 = (1.0 - fx) * (1.0 - fy);
                    let a01 = fx * (1.0 - fy);
                    let a10 = (1.0 - fx) * fy;
                    let a11 = fx * fy;
                    let at = y1 as usize * step + x1 as usize * 5;
                    let p = &self.r1[at..at + 10];
                    let q = &self.r1[at + step..at + step + 10];
                    let mix = |c: usize| a00 * p[c] + a01 * p[c + 5] + a10 * q[c] + a11 * q[c + 5];
                    r2 = mix(0);
                    r3 = mix(1);
                    r4 = mix(2);
                    r5 = mix(3);
                    r6 = mix(4);
                    r4 = (r0[2] + r4) * 0.5;
                    r5 = (r0[3] + r5) * 0.5;
                    r6 = (r0[4] + r6) * 0.25;
                } else {
                    r2 = 0.0;
                    r3 = 0.0;
                    r4 = r0[2];
                    r5 = r0[3];
                    r6 = r0[4] * 0.5;
                }
                r2 = (r0[0] - r2) * 0.5;
                r3 = (r0[1] - r3) * 0.5;
                r2 += r4 * dy + r6 * dx;
                r3 += r6 * dy + r5 * dx;
                if y_border || (x as u32).wrapping_sub(5) >= inner_w {
                    let ((xl, xh), (yl, yh)) = (border_weight(x, width), border_weight(y, height));
                    let scale = xl * xh * yl * yh;
                    r2 *= scale;
                    r3 *= scale;
                    r4 *= scale;
                    r5 *= scale;
                    r6 *= scale;
                }
                out[0] = r4 * r4 + r6 * r6;
                out[1] = (r4 + r5) * r6;
                out[2] = r5 * r5 + r6 * r6;
                out[3] = r4 * r2 + r6 * r3;
                out[4] = r6 * r2 + r5 * r3;
            }
        }
    }

    /// The first pixels of row `y`'s matrices, eight at a time, where [`LevelPair::simd`] says
    /// so: how many it did (the rest is the scalar loop's).
    #[inline(always)]
    fn update_matrices_simd(&self, flow: &[f32], out: &mut [f32], y: usize) -> usize {
        #[cfg(target_arch = "x86_64")]
        if self.simd {
            let (low, high) = border_weight(y, self.height);
            let row = avx2::MatricesRow {
                r0: &self.r0[y * self.width * 5..(y + 1) * self.width * 5],
                r1: self.r1,
                flow,
                column_weights: &self.column_weights,
                y,
                row_weights: (low, high),
                size: (self.width, self.height),
            };
            // SAFETY: `simd` is only true where the CPU has AVX2 (`LevelPair::new`'s contract).
            return unsafe { avx2::update_matrices_row(&row, out) };
        }
        let _ = (flow, out, y);
        0
    }

    /// After the flow of row `y`: the matrices of the rows the window has left behind, in
    /// OpenCV's stripes (`y0` is where the next stripe starts).
    #[inline(always)]
    fn update_behind(&self, flow: &[f32], m: &mut [f32], y: usize, block: usize, y0: &mut usize) {
        let height = self.height;
        let stripe = ((1 << 10) / self.width).max(block) as i64;
        let y1 = if y == height - 1 {
            height as i64
        } else {
            y as i64 - block as i64
        };
        if y1 == height as i64 || y1 >= *y0 as i64 + stripe {
            self.update_matrices(flow, m, *y0, y1 as usize);
            *y0 = y1 as usize;
        }
    }

    /// FarnebackUpdateFlow_Blur: the flow from the box-averaged matrices (sums in f64), then,
    /// with `update`, the matrices from the new flow.
    #[inline(always)]
    fn update_flow_box(&self, flow: &mut [f32], m: &mut [f32], block: usize, update: bool) {
        let (width, height) = (self.width, self.height);
        let half = block / 2;
        let scale = 1.0 / (block * block) as f64;
        let step = width * 5;
        // vsum[o + i] is OpenCV's vsum[i]; (half + 1) pixels of border on either side.
        let o = (half + 1) * 5;
        let mut vsum = vec![0f64; (width + half * 2 + 2) * 5];
        // One row's averaged (G11, G12, G22, h1, h2), each in its own run of `width`.
        let mut averaged = vec![0f64; width * 5];
        let edge = (half + 2) as f32;
        for (v, &s) in vsum[o..o + step].iter_mut().zip(&m[..step]) {
            *v = f64::from(s * edge);
        }
        for y in 1..half {
            let r = y.min(height - 1);
            for (v, &s) in vsum[o..o + step]
                .iter_mut()
                .zip(&m[r * step..(r + 1) * step])
            {
                *v += f64::from(s);
            }
        }
        let mut y0 = 0;
        for y in 0..height {
            let out = y.saturating_sub(half + 1);
            let inn = (y + half).min(height - 1);
            {
                let (s0, s1) = (
                    &m[out * step..(out + 1) * step],
                    &m[inn * step..(inn + 1) * step],
                );
                for ((v, &a), &b) in vsum[o..o + step].iter_mut().zip(s0).zip(s1) {
                    *v += f64::from(b - a);
                }
            }
            for x in 0..(half + 1) * 5 {
                vsum[o - 1 - x] = vsum[o + 4 - x];
                vsum[o + step + x] = vsum[o + step + x - 5];
            }
            let e = (half + 2) as f64;
            let mut s = [0f64; 5];
            for (c, v) in s.iter_mut().enumerate() {
                *v = vsum[o + c] * e;
            }
            for x in 1..half {
                for (c, v) in s.iter_mut().enumerate() {
                    *v += vsum[o + x * 5 + c];
                }
            }
            // The running sums along the row (in order: each pixel's adds the previous),
            // then the solves, which are independent (vectorised across pixels).
            // Pixel x adds vsum[x + half] and takes off vsum[x - half - 1] (OpenCV's indices;
            // ours are o / 5 pixels on, and o / 5 = half + 1).
            let adds = vsum[o + half * 5..o + half * 5 + step].chunks_exact(5);
            let subs = vsum[..step].chunks_exact(5);
            let (a0, rest) = averaged.split_at_mut(width);
            let (a1, rest) = rest.split_at_mut(width);
            let (a2, rest) = rest.split_at_mut(width);
            let (a3, a4) = rest.split_at_mut(width);
            let outs = a0.iter_mut().zip(a1).zip(a2).zip(a3).zip(a4);
            for ((add, sub), ((((a0, a1), a2), a3), a4)) in adds.zip(subs).zip(outs) {
                for (c, v) in s.iter_mut().enumerate() {
                    *v += add[c] - sub[c];
                }
                [*a0, *a1, *a2, *a3, *a4] = s.map(|v| v * scale);
            }
            let row = &mut flow[y * width * 2..(y + 1) * width * 2];
            solve_row(row, &averaged);
            if update {
                self.update_behind(flow, m, y, block, &mut y0);
            }
        }
    }

    /// FarnebackUpdateFlow_GaussianBlur: the flow from the Gaussian-averaged matrices (sums in
    /// f32), then, with `update`, the matrices from the new flow.
    #[inline(always)]
    fn update_flow_gaussian(&self, flow: &mut [f32], m: &mut [f32], block: usize, update: bool) {
        let (width, height) = (self.width, self.height);
        let half = block / 2;
        let (kernel, _) = window_weights(block as u32, true);
        let step = width * 5;
        let o = (half + 1) * 5;
        let mut vsum = vec![0f32; (width + half * 2 + 2) * 5];
        let mut hsum = vec![0f32; step];
        let mut y0 = 0;
        for y in 0..height {
            let row = |i: usize| &m[i * step..(i + 1) * step];
            for x in 0..step {
                let mut s0 = row(y)[x] * kernel[0];
                for (i, &k) in kernel.iter().enumerate().skip(1) {
                    let down = row((y + i).min(height - 1))[x];
                    let up = row(y.saturating_sub(i))[x];
                    s0 += (down + up) * k;
                }
                vsum[o + x] = s0;
            }
            for x in 0..half * 5 {
                vsum[o - 1 - x] = vsum[o + 4 - x];
                vsum[o + step + x] = vsum[o + step + x - 5];
            }
            for (x, h) in hsum.iter_mut().enumerate() {
                let c = o + x;
                let mut sum = vsum[c] * kernel[0];
                for (i, &k) in kernel.iter().enumerate().skip(1) {
                    sum += k * (vsum[c - i * 5] + vsum[c + i * 5]);
                }
                *h = sum;
            }
            let frow = &mut flow[y * width * 2..(y + 1) * width * 2];
            for (f, hs) in frow.chunks_exact_mut(2).zip(hsum.chunks_exact(5)) {
                let averaged = [0, 1, 2, 3, 4].map(|c| f64::from(hs[c]));
                f.copy_from_slice(&solve_window(averaged));
            }
            if update {
                self.update_behind(flow, m, y, block, &mut y0);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deterministic values in [0, 256) (a small LCG), for images and expansions.
    fn noise(n: usize, seed: u32) -> Vec<f32> {
        let mut s = seed;
        (0..n)
            .map(|_| {
                s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                (s >> 8) as f32 / (1 << 16) as f32
            })
            .collect()
    }

    fn bits(v: &[f32]) -> Vec<u32> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    /// The AVX2 builds (where this CPU has AVX2) and the generic ones give the same bits.
    #[test]
    fn paths_agree() {
        let (w, h) = (67, 41);
        for p in [
            FarnebackParams::default(),
            FarnebackParams {
                gaussian: true,
                poly_n: 7,
                poly_sigma: 1.5,
                winsize: 10,
                ..FarnebackParams::default()
            },
        ] {
            let k = Weights::new(&p).expect("weights");
            let src = noise(w * h, 7);
            let fast = poly_exp(&src, (w, h), &k);
            let generic = poly_exp_generic(&src, (w, h), &k);
            assert_eq!(bits(&fast), bits(&generic));
            let r1 = poly_exp_generic(&noise(w * h, 8), (w, h), &k);
            let fast_level = LevelPair::new(&generic, &r1, (w, h), avx2());
            let level = LevelPair::new(&generic, &r1, (w, h), false);
            // A flow of a few pixels either way, some of it pointing outside the image; then
            // the same with a few values far outside it (beyond i32) and not numbers.
            let calm: Vec<f32> = noise(w * h * 2, 9).iter().map(|v| v / 32.0 - 4.0).collect();
            let mut wild = calm.clone();
            for (i, v) in [3e9, -3e9, 1e20, f32::NAN, 66.5, -0.5]
                .into_iter()
                .enumerate()
            {
                wild[i * 97 + 3] = v;
            }
            for (case, start) in [("calm", calm), ("wild", wild)] {
                let (mut f1, mut f2) = (start.clone(), start);
                let (mut m1, mut m2) = (vec![0f32; w * h * 5], vec![0f32; w * h * 5]);
                fast_level.solve(&mut f1, &mut m1, &p);
                level.solve_generic(&mut f2, &mut m2, &p);
                assert_eq!(bits(&f1), bits(&f2), "{case} flow");
                assert_eq!(bits(&m1), bits(&m2), "{case} matrices");
                assert!(f1.iter().any(|v| *v != 0.0), "{case}");
                if case == "calm" {
                    assert!(f1.iter().all(|v| v.is_finite()));
                }
            }
        }
    }
}
