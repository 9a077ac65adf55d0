//! `movement`: a robust statistic of the per-pixel flow magnitude (median or trimmed mean),
//! computed on the device by exact radix selection (shaders/movement.wgsl); `cpu` is the twin on
//! the host (sorting the same f32 magnitudes of OpenCV's flow). With `Derotate`, the flow of the
//! best-fitting small camera rotation (least squares, `RotationField`) is subtracted first, so
//! the statistic measures the translation-induced (parallax) part of the motion.

use crate::error::{Error, Result};
use crate::gpu::{compute_pass, GpuContext};
pub use crate::params::{Derotate, Statistic};
use bytemuck::{Pod, Zeroable};
use nalgebra::{Matrix3, Vector3};
use std::sync::Arc;

/// WGSL source.
pub const WGSL: &str = include_str!("../../shaders/movement.wgsl");

/// A camera rotation between two frames as the 3x3 matrix (rows, f32 as the shader has it) that
/// maps a normalised ray (x, y, 1) of the first frame to its direction in the second.
pub type Rotation = [[f32; 3]; 3];

/// The identity rotation.
pub const IDENTITY: Rotation = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

/// Gauss-Newton steps after the first linear fit (each one more reduction over the flow).
pub const ROTATION_REFINEMENTS: usize = 2;

/// The image flow of a camera rotation on a `width` x `height` grid, and its least-squares fit
/// to a flow field. For normalised coordinates x = (i - cx) / f, y = (j - cy) / f, a rotation R
/// moves pixel (i, j) to f (R p).xy / (R p).z with p = (x, y, 1), whatever the depth. The fit is
/// linearised with the first-order fields e_x = (x y, 1 + y^2), e_y = (-(1 + x^2), -x y),
/// e_z = (y, -x) (normal matrix from the geometry only) and refined by `ROTATION_REFINEMENTS`
/// Gauss-Newton steps on the exact residual; `residual_magnitudes` is the host twin of the
/// shader's per-pixel |flow - rotation flow|.
#[derive(Debug, Clone)]
pub struct RotationField {
    width: u32,
    height: u32,
    f: f32,
    cx: f32,
    cy: f32,
    /// Inverse of the normal matrix sum(e_k . e_l) over the grid (geometry only).
    inverse: [[f64; 3]; 3],
}

impl RotationField {
    /// The field of a `width` x `height` grid seen with `derotate`'s field of view.
    pub fn new(width: u32, height: u32, derotate: Derotate) -> Result<RotationField> {
        derotate.validate()?;
        if width < 2 || height < 2 {
            return Err(Error::param("derotate", "the flow field is too small"));
        }
        let f = derotate.focal(width) as f32;
        let (cx, cy) = ((width - 1) as f32 * 0.5, (height - 1) as f32 * 0.5);
        let mut field = RotationField {
            width,
            height,
            f,
            cx,
            cy,
            inverse: [[0.0; 3]; 3],
        };
        let mut m = [[0.0f64; 3]; 3];
        for j in 0..height {
            for i in 0..width {
                let e = field.basis(i, j);
                for (k, ek) in e.iter().enumerate() {
                    for (l, el) in e.iter().enumerate() {
                        m[k][l] += f64::from(ek[0]) * f64::from(el[0])
                            + f64::from(ek[1]) * f64::from(el[1]);
                    }
                }
            }
        }
        field.inverse =
            invert3(&m).ok_or_else(|| Error::param("derotate", "the rotation fit is singular"))?;
        Ok(field)
    }

    /// (f, cx, cy) in grid pixels.
    pub fn intrinsics(&self) -> (f32, f32, f32) {
        (self.f, self.cx, self.cy)
    }

    /// Normalised coordinates of pixel (i, j).
    fn normalised(&self, i: u32, j: u32) -> (f32, f32) {
        ((i as f32 - self.cx) / self.f, (j as f32 - self.cy) / self.f)
    }

    /// First-order rotation fields (e_x, e_y, e_z) at pixel (i, j), in f32 as the shader has them.
    fn basis(&self, i: u32, j: u32) -> [[f32; 2]; 3] {
        let (x, y) = self.normalised(i, j);
        [[x * y, 1.0 + y * y], [-(1.0 + x * x), -(x * y)], [y, -x]]
    }

    /// The flow (grid pixels) the rotation `r` gives at pixel (i, j) (zero for `IDENTITY`).
    pub fn rotation_flow(&self, i: u32, j: u32, r: &Rotation) -> [f32; 2] {
        let (x, y) = self.normalised(i, j);
        let q = [
            r[0][0] * x + r[0][1] * y + r[0][2],
            r[1][0] * x + r[1][1] * y + r[1][2],
            r[2][0] * x + r[2][1] * y + r[2][2],
        ];
        [self.f * (q[0] / q[2] - x), self.f * (q[1] / q[2] - y)]
    }

    /// Host twin of the shader's `rotation_sums`: sum over pixels of e_k . (flow - rotation
    /// flow of `r`) / f, from an interleaved (dx, dy) flow in grid pixels.
    pub fn sums(&self, flow: &[f32], r: &Rotation) -> Result<[f64; 3]> {
        self.check(flow)?;
        let mut b = [0.0f64; 3];
        for j in 0..self.height {
            for i in 0..self.width {
                let p = 2 * (j * self.width + i) as usize;
                let [rx, ry] = self.rotation_flow(i, j, r);
                let (u, v) = ((flow[p] - rx) / self.f, (flow[p + 1] - ry) / self.f);
                for (bk, ek) in b.iter_mut().zip(self.basis(i, j)) {
                    *bk += f64::from(ek[0] * u + ek[1] * v);
                }
            }
        }
        Ok(b)
    }

    /// The first-order rotation vector (radians) of the least-squares fit to sums `b`.
    pub fn solve(&self, b: [f64; 3]) -> [f64; 3] {
        let r = &self.inverse;
        std::array::from_fn(|k| r[k][0] * b[0] + r[k][1] * b[1] + r[k][2] * b[2])
    }

    /// The least-squares rotation, given a function returning `sums` for a rotation (the host
    /// computes them itself, the device with a reduction): a linear fit, then the refinements.
    pub fn fit(&self, mut sums: impl FnMut(&Rotation) -> Result<[f64; 3]>) -> Result<Rotation> {
        let mut omega = self.solve(sums(&IDENTITY)?);
        for _ in 0..ROTATION_REFINEMENTS {
            let step = self.solve(sums(&matrix(omega))?);
            for (o, d) in omega.iter_mut().zip(step) {
                *o += d;
            }
        }
        Ok(matrix(omega))
    }

    /// Host fit of the rotation of an interleaved flow.
    pub fn fit_cpu(&self, flow: &[f32]) -> Result<Rotation> {
        self.fit(|r| self.sums(flow, r))
    }

    /// |flow - rotation flow of `r`| per pixel, in f32 as the shader computes it.
    pub fn residual_magnitudes(&self, flow: &[f32], r: &Rotation) -> Result<Vec<f32>> {
        self.check(flow)?;
        let mut out = Vec::with_capacity(flow.len() / 2);
        for j in 0..self.height {
            for i in 0..self.width {
                let p = 2 * (j * self.width + i) as usize;
                let [rx, ry] = self.rotation_flow(i, j, r);
                let (dx, dy) = (flow[p] - rx, flow[p + 1] - ry);
                out.push((dx * dx + dy * dy).sqrt());
            }
        }
        Ok(out)
    }

    fn check(&self, flow: &[f32]) -> Result<()> {
        if flow.len() != 2 * (self.width * self.height) as usize {
            return Err(Error::param(
                "derotate",
                format!(
                    "flow has {} values, the grid {}x{} needs {}",
                    flow.len(),
                    self.width,
                    self.height,
                    2 * self.width * self.height
                ),
            ));
        }
        Ok(())
    }
}

/// The rotation whose first-order image flow is sum_k omega_k e_k: the rotation by the angle
/// |omega| about the axis -omega (Rodrigues: I + sin t / t W + (1 - cos t) / t² W², W the cross
/// matrix of -omega).
pub fn matrix(omega: [f64; 3]) -> Rotation {
    let axis = -Vector3::from(omega);
    let t = axis.norm();
    let (s, k) = if t < 1e-12 {
        (1.0, 0.5)
    } else {
        (t.sin() / t, (1.0 - t.cos()) / (t * t))
    };
    let w = axis.cross_matrix();
    let r = Matrix3::identity() + w * s + w * w * k;
    std::array::from_fn(|i| std::array::from_fn(|j| r[(i, j)] as f32))
}

/// Inverse of a 3x3 matrix (None when singular: determinant not finite or below 1e-12).
fn invert3(m: &[[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
    let m = Matrix3::from_fn(|i, j| m[i][j]);
    let det = m.determinant();
    if !det.is_finite() || det.abs() < 1e-12 {
        return None;
    }
    let inv = m.try_inverse()?;
    Some(std::array::from_fn(|i| {
        std::array::from_fn(|j| inv[(i, j)])
    }))
}

/// The interleaved (dx, dy) values of a CV_32FC2 flow field.
pub fn flow_values(flow: &opencv::core::Mat) -> Result<Vec<f32>> {
    use opencv::prelude::*;
    let d = flow
        .data_typed::<opencv::core::Vec2f>()
        .map_err(|e| Error::param("flow", e.to_string()))?;
    Ok(d.iter().flat_map(|v| [v[0], v[1]]).collect())
}

/// Host twin of the whole device statistic: the statistic of the flow magnitudes of `flow`, or
/// of the residual magnitudes after the fitted rotation when `field` is given.
pub fn cpu_flow(
    flow: &opencv::core::Mat,
    stat: Statistic,
    field: Option<&RotationField>,
) -> Result<f64> {
    match field {
        None => cpu(&magnitudes(flow)?, stat),
        Some(field) => {
            let v = flow_values(flow)?;
            let r = field.fit_cpu(&v)?;
            cpu(&field.residual_magnitudes(&v, &r)?, stat)
        }
    }
}

/// Per-pixel magnitudes of a CV_32FC2 flow field, in f32 as the shader computes them.
pub fn magnitudes(flow: &opencv::core::Mat) -> Result<Vec<f32>> {
    use opencv::prelude::*;
    let d = flow
        .data_typed::<opencv::core::Vec2f>()
        .map_err(|e| Error::param("flow", e.to_string()))?;
    Ok(d.iter()
        .map(|v| (v[0] * v[0] + v[1] * v[1]).sqrt())
        .collect())
}

/// Host twin: the statistic of `values`.
pub fn cpu(values: &[f32], stat: Statistic) -> Result<f64> {
    stat.validate()?;
    if values.is_empty() {
        return Err(Error::param("flow", "empty flow field"));
    }
    let mut v = values.to_vec();
    v.sort_by(f32::total_cmp);
    let (lo, hi) = stat.ranks(v.len() as u32);
    Ok(match stat {
        Statistic::Median => (f64::from(v[lo as usize]) + f64::from(v[hi as usize])) * 0.5,
        Statistic::TrimmedMean { .. } => {
            let s: f64 = v[lo as usize..=hi as usize]
                .iter()
                .map(|&x| f64::from(x))
                .sum();
            s / f64::from(hi - lo + 1)
        }
    })
}

#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct Params {
    n: u32,
    groups_x: u32,
    shift: u32,
    mask: u32,
    prefix_shift: u32,
    prefix0: u32,
    prefix1: u32,
    lo_bits: u32,
    hi_bits: u32,
    /// 1: subtract the flow of rotation `rot` (grid `width` wide, focal `f`, centre cx, cy).
    derotate: u32,
    width: u32,
    pad0: u32,
    f: f32,
    cx: f32,
    cy: f32,
    pad1: f32,
    /// Rows of the rotation, padded to vec4.
    rot: [[f32; 4]; 3],
}

const BINS: usize = 4096;

/// The device passes of `MovementGpu` (entry points of shaders/movement.wgsl).
#[derive(Clone, Copy)]
enum Pass {
    Histogram,
    Sums,
    RotationSums,
}

/// Device statistic over one flow buffer (2 x f32 per pixel, `width` x `height` pixels).
pub struct MovementGpu {
    ctx: Arc<GpuContext>,
    n: u32,
    width: u32,
    groups: (u32, u32),
    hist_pipe: Arc<wgpu::ComputePipeline>,
    sums_pipe: Arc<wgpu::ComputePipeline>,
    rot_pipe: Arc<wgpu::ComputePipeline>,
    params: wgpu::Buffer,
    hist: wgpu::Buffer,
    counts: wgpu::Buffer,
    partials: wgpu::Buffer,
    hist_bg: wgpu::BindGroup,
    sums_bg: wgpu::BindGroup,
    rot_bg: wgpu::BindGroup,
    field: Option<RotationField>,
}

impl MovementGpu {
    /// Binds the statistic to `flow` holding `width` x `height` flow vectors; with `derotate`,
    /// every statistic is taken after subtracting the fitted rotation flow.
    pub fn new(
        ctx: Arc<GpuContext>,
        flow: &wgpu::Buffer,
        width: u32,
        height: u32,
        derotate: Option<Derotate>,
    ) -> Result<Self> {
        let n = width * height;
        if n == 0 {
            return Err(Error::param("flow", "empty flow field"));
        }
        let field = derotate
            .map(|d| RotationField::new(width, height, d))
            .transpose()?;
        let hist_pipe = ctx.pipeline("movement", WGSL, "histogram")?;
        let sums_pipe = ctx.pipeline("movement", WGSL, "sums")?;
        let rot_pipe = ctx.pipeline("movement", WGSL, "rotation_sums")?;
        let total = n.div_ceil(256);
        let gx = total.min(65_535);
        let groups = (gx, total.div_ceil(gx));
        let params = ctx.uniform("movement params", &Params::zeroed());
        let hist = ctx.storage_buffer("movement histogram", (2 * BINS * 4) as u64);
        let counts = ctx.storage_buffer("movement counts", 16);
        let partials =
            ctx.storage_buffer("movement partials", u64::from(groups.0 * groups.1) * 3 * 4);
        let hist_bg = ctx.bind(
            "movement histogram",
            &hist_pipe,
            &[(0, flow), (1, &hist), (4, &params)],
        );
        let sums_bg = ctx.bind(
            "movement sums",
            &sums_pipe,
            &[(0, flow), (2, &counts), (3, &partials), (4, &params)],
        );
        let rot_bg = ctx.bind(
            "movement rotation sums",
            &rot_pipe,
            &[(0, flow), (3, &partials), (4, &params)],
        );
        Ok(MovementGpu {
            ctx,
            n,
            width,
            groups,
            hist_pipe,
            sums_pipe,
            rot_pipe,
            params,
            hist,
            counts,
            partials,
            hist_bg,
            sums_bg,
            rot_bg,
            field,
        })
    }

    /// Parameters with the grid, the intrinsics and the rotation filled in (derotate set when a
    /// rotation is given).
    fn params(&self, rotation: Option<&Rotation>) -> Params {
        let (f, cx, cy) = self
            .field
            .as_ref()
            .map_or((1.0, 0.0, 0.0), |r| r.intrinsics());
        let r = rotation.unwrap_or(&IDENTITY);
        Params {
            n: self.n,
            groups_x: self.groups.0,
            shift: 0,
            mask: 0,
            prefix_shift: 31,
            prefix0: u32::MAX,
            prefix1: u32::MAX,
            lo_bits: 0,
            hi_bits: 0,
            derotate: u32::from(rotation.is_some()),
            width: self.width,
            pad0: 0,
            f,
            cx,
            cy,
            pad1: 0.0,
            rot: r.map(|row| [row[0], row[1], row[2], 0.0]),
        }
    }

    /// The least-squares rotation of the bound flow (None without derotation).
    pub fn rotation(&self) -> Result<Option<Rotation>> {
        let Some(field) = &self.field else {
            return Ok(None);
        };
        field.fit(|r| self.rotation_sums(r)).map(Some)
    }

    /// Device `sums` of the residual after rotation `r` (per-workgroup partials added in f64).
    fn rotation_sums(&self, r: &Rotation) -> Result<[f64; 3]> {
        self.run(&self.params(Some(r)), Pass::RotationSums);
        let parts = self.ctx.read_back(
            &self.partials,
            u64::from(self.groups.0 * self.groups.1) * 3 * 4,
        )?;
        let mut b = [0.0f64; 3];
        for chunk in bytemuck::cast_slice::<u8, f32>(&parts).chunks_exact(3) {
            for (bk, &v) in b.iter_mut().zip(chunk) {
                *bk += f64::from(v);
            }
        }
        Ok(b)
    }

    /// Writes `p` and runs one of the three passes over the flow.
    fn run(&self, p: &Params, which: Pass) {
        self.ctx
            .queue
            .write_buffer(&self.params, 0, bytemuck::bytes_of(p));
        let mut enc = self.ctx.encoder("movement");
        let (pipe, bg) = match which {
            Pass::Histogram => {
                enc.clear_buffer(&self.hist, 0, None);
                (&self.hist_pipe, &self.hist_bg)
            }
            Pass::Sums => {
                enc.clear_buffer(&self.counts, 0, None);
                (&self.sums_pipe, &self.sums_bg)
            }
            Pass::RotationSums => (&self.rot_pipe, &self.rot_bg),
        };
        self.ctx.dispatch(
            &mut compute_pass(&mut enc, "movement"),
            pipe,
            bg,
            self.groups,
        );
        self.ctx.queue.submit([enc.finish()]);
    }

    /// Bit patterns of the values at ranks `lo` and `hi` (0-based, ascending).
    fn select(&self, lo: u32, hi: u32, rotation: Option<&Rotation>) -> Result<[u32; 2]> {
        // (shift, mask bits, prefix_shift) of the three radix passes over bits 30..0.
        let passes = [(19u32, 12u32, 31u32), (7, 12, 19), (0, 7, 7)];
        let mut prefix = [0u32; 2];
        let mut rank = [lo, hi];
        for (shift, bits, prefix_shift) in passes {
            let p = Params {
                shift,
                mask: (1 << bits) - 1,
                prefix_shift,
                prefix0: prefix[0],
                prefix1: prefix[1],
                ..self.params(rotation)
            };
            self.run(&p, Pass::Histogram);
            let bytes = self.ctx.read_back(&self.hist, (2 * BINS * 4) as u64)?;
            let h: &[u32] = bytemuck::cast_slice(&bytes);
            for r in 0..2 {
                let mut before = 0u32;
                let mut found = None;
                for (b, &c) in h[r * BINS..r * BINS + (1 << bits)].iter().enumerate() {
                    if rank[r] < before + c {
                        found = Some(b as u32);
                        break;
                    }
                    before += c;
                }
                let b = found.ok_or_else(|| {
                    Error::Gpu("movement histogram lost values (non-finite flow?)".into())
                })?;
                rank[r] -= before;
                prefix[r] = (prefix[r] << bits) | b;
            }
        }
        Ok(prefix)
    }

    /// The statistic of the magnitudes in the bound flow buffer (submitted work must be queued),
    /// after subtracting the fitted rotation flow when derotating.
    pub fn compute(&self, stat: Statistic) -> Result<f64> {
        stat.validate()?;
        let (lo, hi) = stat.ranks(self.n);
        let rotation = self.rotation()?;
        let [lo_bits, hi_bits] = self.select(lo, hi, rotation.as_ref())?;
        let (vlo, vhi) = (
            f64::from(f32::from_bits(lo_bits)),
            f64::from(f32::from_bits(hi_bits)),
        );
        if let Statistic::Median = stat {
            return Ok((vlo + vhi) * 0.5);
        }
        if lo_bits == hi_bits {
            return Ok(vlo);
        }
        let p = Params {
            lo_bits,
            hi_bits,
            ..self.params(rotation.as_ref())
        };
        self.run(&p, Pass::Sums);
        let c = self.ctx.read_back(&self.counts, 16)?;
        let c: &[u32] = bytemuck::cast_slice(&c);
        let parts = self
            .ctx
            .read_back(&self.partials, u64::from(self.groups.0 * self.groups.1) * 4)?;
        let between: f64 = bytemuck::cast_slice::<u8, f32>(&parts)
            .iter()
            .map(|&v| f64::from(v))
            .sum();
        let take_lo = f64::from(c[1] - lo);
        let take_hi = f64::from(hi + 1 - c[2]);
        Ok((take_lo * vlo + between + take_hi * vhi) / f64::from(hi - lo + 1))
    }
}
