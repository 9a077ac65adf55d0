//! `movement`: a robust statistic of the per-pixel flow magnitude (median or trimmed mean),
//! computed on the device by exact radix selection (shaders/movement.wgsl) without a host round
//! trip: the passes leave the statistic, as the f64 the host would compute from the selected
//! values, in a results record; `cpu` is the twin on the host (sorting the same f32 magnitudes of
//! OpenCV's flow). With `Derotate`, the flow of the best-fitting small camera rotation (least
//! squares, `RotationField`) is subtracted first, so the statistic measures the
//! translation-induced (parallax) part of the motion.

use super::sphere::{SphereField, CLAMPS_PX, MAX_VIEWS};

/// A residual clamp that never applies (the shader's least-squares rounds).
const NO_CLAMP: f32 = 1e30;
use crate::error::{Error, Result};
use crate::gpu::{compute_pass, Gate, GpuContext};
use crate::params::{Derotate, Statistic};
use bytemuck::{Pod, Zeroable};
use nalgebra::{Matrix3, Vector3};
use std::sync::Arc;

/// WGSL source (after the f64 arithmetic it uses).
pub const WGSL: &str = concat!(
    include_str!("../../shaders/f64.wgsl"),
    include_str!("../../shaders/movement.wgsl")
);

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
    /// The normal matrix sum(e_k . e_l) over the grid (geometry only).
    normal: [[f64; 3]; 3],
    /// Its inverse.
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
            normal: [[0.0; 3]; 3],
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
        field.normal = m;
        Ok(field)
    }

    /// The normal matrix sum(e_k . e_l) over the grid.
    pub(crate) fn normal(&self) -> [[f64; 3]; 3] {
        self.normal
    }

    /// Width of the grid in pixels.
    pub(crate) fn size(&self) -> u32 {
        self.width
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
        self.sums_within(flow, r, f32::INFINITY)
    }

    /// [`RotationField::sums`] with every residual longer than `clamp` grid pixels shortened to
    /// it (Huber's modified residuals: a pixel whose flow failed pulls no harder than `clamp`).
    pub(crate) fn sums_within(&self, flow: &[f32], r: &Rotation, clamp: f32) -> Result<[f64; 3]> {
        let mut b = [0.0f64; 3];
        for (i, j, [dx, dy]) in self.residuals(flow, r)? {
            let m = (dx * dx + dy * dy).sqrt();
            let (dx, dy) = if m > clamp {
                (dx * (clamp / m), dy * (clamp / m))
            } else {
                (dx, dy)
            };
            let (u, v) = (dx / self.f, dy / self.f);
            for (bk, ek) in b.iter_mut().zip(self.basis(i, j)) {
                *bk += f64::from(ek[0] * u + ek[1] * v);
            }
        }
        Ok(b)
    }

    /// Per pixel (i, j) in row order: flow - rotation flow of `r`, from an interleaved flow.
    fn residuals<'a>(
        &'a self,
        flow: &'a [f32],
        r: &'a Rotation,
    ) -> Result<impl Iterator<Item = (u32, u32, [f32; 2])> + 'a> {
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
        let pixels = (0..self.height).flat_map(move |j| (0..self.width).map(move |i| (i, j)));
        Ok(pixels.zip(flow.chunks_exact(2)).map(|((i, j), d)| {
            let [rx, ry] = self.rotation_flow(i, j, r);
            (i, j, [d[0] - rx, d[1] - ry])
        }))
    }

    /// The first-order rotation vector (radians) of the least-squares fit to sums `b`.
    fn solve(&self, b: [f64; 3]) -> [f64; 3] {
        let r = &self.inverse;
        std::array::from_fn(|k| r[k][0] * b[0] + r[k][1] * b[1] + r[k][2] * b[2])
    }

    /// Host fit of the rotation of an interleaved flow: a linear fit, then the refinements.
    pub fn fit_cpu(&self, flow: &[f32]) -> Result<Rotation> {
        let mut omega = self.solve(self.sums(flow, &IDENTITY)?);
        for _ in 0..ROTATION_REFINEMENTS {
            let step = self.solve(self.sums(flow, &matrix(omega))?);
            for (o, d) in omega.iter_mut().zip(step) {
                *o += d;
            }
        }
        Ok(matrix(omega))
    }

    /// |flow - rotation flow of `r`| per pixel, in f32 as the shader computes it.
    pub fn residual_magnitudes(&self, flow: &[f32], r: &Rotation) -> Result<Vec<f32>> {
        let residuals = self.residuals(flow, r)?;
        Ok(residuals
            .map(|(_, _, [dx, dy])| (dx * dx + dy * dy).sqrt())
            .collect())
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
pub(crate) fn invert3(m: &[[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
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
#[cfg(feature = "opencv")]
pub fn flow_values(flow: &opencv::core::Mat) -> Result<Vec<f32>> {
    use opencv::prelude::*;
    let d = flow
        .data_typed::<opencv::core::Vec2f>()
        .map_err(|e| Error::param("flow", e.to_string()))?;
    Ok(d.iter().flat_map(|v| [v[0], v[1]]).collect())
}

/// Host twin of the whole device statistic: the statistic of the flow magnitudes of `flow`, or
/// of the residual magnitudes after the fitted rotation when `field` is given.
#[cfg(feature = "opencv")]
pub fn cpu_flow(
    flow: &opencv::core::Mat,
    stat: Statistic,
    field: Option<&RotationField>,
) -> Result<f64> {
    match field {
        None => statistic(magnitudes(flow)?, stat),
        Some(field) => {
            let v = flow_values(flow)?;
            let r = field.fit_cpu(&v)?;
            statistic(field.residual_magnitudes(&v, &r)?, stat)
        }
    }
}

/// Per-pixel magnitudes of a CV_32FC2 flow field, in f32 as the shader computes them.
#[cfg(feature = "opencv")]
pub fn magnitudes(flow: &opencv::core::Mat) -> Result<Vec<f32>> {
    let v = flow_values(flow)?;
    Ok(v.chunks_exact(2)
        .map(|d| (d[0] * d[0] + d[1] * d[1]).sqrt())
        .collect())
}

/// Host twin: the statistic of `values`.
pub fn cpu(values: &[f32], stat: Statistic) -> Result<f64> {
    statistic(values.to_vec(), stat)
}

/// [`cpu`] on values it may reorder. The median takes its two middle ranks by selection (the
/// values of those ranks in the total order are the sorted ones'); the trimmed mean sums the
/// kept ranks in ascending order, so it sorts.
fn statistic(mut v: Vec<f32>, stat: Statistic) -> Result<f64> {
    stat.validate()?;
    if v.is_empty() {
        return Err(Error::param("flow", "empty flow field"));
    }
    let (lo, hi) = stat.ranks(v.len() as u32);
    let (lo, hi) = (lo as usize, hi as usize);
    Ok(match stat {
        Statistic::Median => {
            let (_, low, above) = v.select_nth_unstable_by(lo, f32::total_cmp);
            let low = *low;
            // The median's ranks are lo and lo + 1 at most: the next rank is the least above.
            let high = match hi > lo {
                true => above.iter().copied().min_by(f32::total_cmp).unwrap_or(low),
                false => low,
            };
            (f64::from(low) + f64::from(high)) * 0.5
        }
        Statistic::TrimmedMean { .. } => {
            v.sort_by(f32::total_cmp);
            let s: f64 = v[lo..=hi].iter().map(|&x| f64::from(x)).sum();
            s / (hi - lo + 1) as f64
        }
    })
}

/// Words of one frame's results record: the consecutive movement (f64 bits, low word first) at
/// 0, the movement from the stationary reference at 2, the stationary decision at 4.
pub const RECORD_WORDS: u32 = 8;

/// Where a frame's passes find their record: shaders' `Frame` (written by the host per frame).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, Pod, Zeroable)]
pub struct FrameParams {
    /// Frame index.
    pub index: u32,
    /// Record of the frame in the results buffer.
    pub entry: u32,
    /// The stationary step's flags (kernels::stationary).
    pub flags: u32,
    /// Unused: pads the struct to a multiple of 16 bytes.
    pub pad: u32,
}

/// Constants of one statistic over one grid (shader `Consts`).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct Consts {
    n: u32,
    groups_x: u32,
    derotate: u32,
    width: u32,
    lo: u32,
    hi: u32,
    trimmed: u32,
    partials: u32,
    f: f32,
    cx: f32,
    cy: f32,
    view_rows: u32,
    inverse: [[f32; 4]; 3],
    clamps: [f32; 8],
    view_rot: [[f32; 4]; 3 * MAX_VIEWS],
}

/// (shift, bits, prefix shift) of the three radix rounds over bits 30..0.
const RADIX: [(u32, u32, u32); 3] = [(19, 12, 31), (7, 12, 19), (0, 7, 7)];
/// Histogram words: 3 rounds x 2 ranks x 4096 bins, then the counts of `sums`.
const HIST_WORDS: u64 = 3 * 2 * 4096 + 4;
/// Bytes of the selection state (shader `Sel`); the rotation rows start at byte 48, the views'
/// rotations (joint derotation) at 96.
const SEL_BYTES: u64 = 96 + 48 * MAX_VIEWS as u64;

type Pass = (Arc<wgpu::ComputePipeline>, wgpu::BindGroup);

fn pair(p: &Pass) -> (&wgpu::ComputePipeline, &wgpu::BindGroup) {
    (p.0.as_ref(), &p.1)
}

/// Where `finish` writes a statistic: a results buffer, the frame params naming the record, the
/// field of the record (0 consecutive, 1 from the reference).
pub struct Destination(wgpu::BindGroup);

/// Device statistic over one flow buffer (2 x f32 per pixel, `width` x `height` pixels).
pub struct MovementGpu {
    ctx: Arc<GpuContext>,
    n: u32,
    width: u32,
    /// Rows of one view (the grid's height unless several views are stacked).
    view_rows: u32,
    groups: (u32, u32),
    field: Option<RotationField>,
    /// The joint fit over stacked views (`field` is then one view's grid).
    joint: Option<SphereField>,
    consts: wgpu::Buffer,
    hist: wgpu::Buffer,
    partials: wgpu::Buffer,
    sel: wgpu::Buffer,
    finish: Arc<wgpu::ComputePipeline>,
    /// (pipeline, bind group) of init, rotation_sums, solve, sums.
    init: Pass,
    rotation_sums: Pass,
    solve: Pass,
    sums: Pass,
    /// Per radix round: histogram and pick.
    rounds: Vec<[Pass; 2]>,
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
        let field = derotate
            .map(|d| RotationField::new(width, height, d))
            .transpose()?;
        Self::build(ctx, flow, (width, height), height, field, None)
    }

    /// Binds the statistic to `flow` holding the stacked flows of `joint`'s views (view after
    /// view, each `size` x `size`); every statistic is taken after subtracting the rotation of
    /// the sphere fitted to all of them together.
    pub fn joint(ctx: Arc<GpuContext>, flow: &wgpu::Buffer, joint: &SphereField) -> Result<Self> {
        let size = joint.field().size();
        let height = size * joint.views() as u32;
        let field = Some(joint.field().clone());
        Self::build(ctx, flow, (size, height), size, field, Some(joint.clone()))
    }

    fn build(
        ctx: Arc<GpuContext>,
        flow: &wgpu::Buffer,
        (width, height): (u32, u32),
        view_rows: u32,
        field: Option<RotationField>,
        joint: Option<SphereField>,
    ) -> Result<Self> {
        let n = width * height;
        if n == 0 {
            return Err(Error::param("flow", "empty flow field"));
        }
        let total = n.div_ceil(256);
        let gx = total.min(65_535);
        let groups = (gx, total.div_ceil(gx));
        let pipe = |entry: &str| ctx.pipeline("movement", WGSL, entry);
        let consts = ctx.uniform("movement consts", &Consts::zeroed());
        let hist = ctx.storage_buffer("movement histogram", HIST_WORDS * 4);
        let partials =
            ctx.storage_buffer("movement partials", u64::from(groups.0 * groups.1) * 3 * 4);
        let sel = ctx.storage_buffer("movement selection", SEL_BYTES);
        let table = [
            (0, flow),
            (1, &hist),
            (3, &partials),
            (4, &consts),
            (6, &sel),
        ];
        // The pass `entry` with the bindings it uses, and its radix round's uniform (binding 5).
        let with = |entry: &str, used: &[u32], radix: Option<&wgpu::Buffer>| -> Result<Pass> {
            let p = pipe(entry)?;
            let binds: Vec<(u32, &wgpu::Buffer)> = (table.iter().copied())
                .filter(|(b, _)| used.contains(b))
                .chain(radix.map(|r| (5, r)))
                .collect();
            let bg = ctx.bind(entry, &p, &binds);
            Ok((p, bg))
        };
        let init = with("init", &[4, 6], None)?;
        let rotation_sums = with("rotation_sums", &[0, 3, 4, 6], None)?;
        let solve = with("solve", &[3, 4, 6], None)?;
        let sums = with("sums", &[0, 1, 3, 4, 6], None)?;
        let rounds = RADIX
            .iter()
            .enumerate()
            .map(|(k, &(shift, bits, prefix_shift))| {
                let radix = ctx.uniform("movement radix", &[shift, bits, prefix_shift, k as u32]);
                Ok([
                    with("histogram", &[0, 1, 4, 6], Some(&radix))?,
                    with("pick", &[1, 6], Some(&radix))?,
                ])
            })
            .collect::<Result<Vec<_>>>()?;
        let finish = pipe("finish")?;
        Ok(MovementGpu {
            ctx: ctx.clone(),
            n,
            width,
            view_rows,
            groups,
            field,
            joint,
            consts,
            hist,
            partials,
            sel,
            finish,
            init,
            rotation_sums,
            solve,
            sums,
            rounds,
        })
    }

    /// The destination of records `frame` names in `results`, field `field`.
    pub fn destination(
        &self,
        results: &wgpu::Buffer,
        frame: &wgpu::Buffer,
        field: u32,
    ) -> Destination {
        let target = self
            .ctx
            .uniform("movement destination", &[field, RECORD_WORDS, 0, 0]);
        Destination(self.ctx.bind(
            "finish",
            &self.finish,
            &[
                (1, &self.hist),
                (3, &self.partials),
                (4, &self.consts),
                (6, &self.sel),
                (7, results),
                (8, frame),
                (9, &target),
            ],
        ))
    }

    /// Sets the statistic the next passes take.
    pub fn prepare(&self, stat: Statistic) -> Result<()> {
        stat.validate()?;
        let (lo, hi) = stat.ranks(self.n);
        let (f, cx, cy) = self
            .field
            .as_ref()
            .map_or((1.0, 0.0, 0.0), |r| (r.f, r.cx, r.cy));
        let rows =
            |m: [[f64; 3]; 3]| m.map(|row| [row[0] as f32, row[1] as f32, row[2] as f32, 0.0]);
        let inverse = match (&self.joint, &self.field) {
            (Some(j), _) => rows(j.inverse()),
            (None, Some(r)) => rows(r.inverse),
            (None, None) => [[0.0; 4]; 3],
        };
        let mut view_rot = [[0.0f32; 4]; 3 * MAX_VIEWS];
        if let Some(j) = &self.joint {
            for k in 0..j.views() {
                for (i, row) in j.rotation(k).iter().enumerate() {
                    view_rot[3 * k + i] = [row[0], row[1], row[2], 0.0];
                }
            }
        }
        // Round 0 is least squares; the joint fit's refinements clamp (kernels::sphere).
        let mut clamps = [NO_CLAMP; 8];
        if self.joint.is_some() {
            clamps[1..=CLAMPS_PX.len()].copy_from_slice(&CLAMPS_PX);
        }
        let derotate = match (&self.joint, &self.field) {
            (Some(_), _) => 2,
            (None, Some(_)) => 1,
            (None, None) => 0,
        };
        let c = Consts {
            n: self.n,
            groups_x: self.groups.0,
            derotate,
            width: self.width,
            lo,
            hi,
            trimmed: u32::from(matches!(stat, Statistic::TrimmedMean { .. })),
            partials: self.groups.0 * self.groups.1,
            f,
            cx,
            cy,
            view_rows: self.view_rows,
            inverse,
            clamps,
            view_rot,
        };
        self.ctx.write(&self.consts, 0, bytemuck::bytes_of(&c));
        Ok(())
    }

    /// The workgroups of the passes, in the order of their gate entries: over the pixels, one.
    pub fn shapes(&self) -> [(u32, u32); 2] {
        [self.groups, (1, 1)]
    }

    /// Records the statistic `stat` (set by [`MovementGpu::prepare`]) of the bound flow into
    /// `dest`, gated by `gate` when given (entries as [`MovementGpu::shapes`] lists them);
    /// without `dest`, only the rotation fit.
    pub fn encode(
        &self,
        enc: &mut wgpu::CommandEncoder,
        stat: Statistic,
        dest: Option<&Destination>,
        gate: Option<Gate<'_>>,
    ) {
        enc.clear_buffer(&self.hist, 0, None);
        let mut pass = compute_pass(enc, "movement");
        let shapes = self.shapes();
        let mut run = |(p, bg): (&wgpu::ComputePipeline, &wgpu::BindGroup), wide: bool| {
            let shape = usize::from(!wide);
            self.ctx
                .dispatch_gated(&mut pass, (p, bg), shapes[shape], gate, shape);
        };
        run(pair(&self.init), false);
        if self.field.is_some() {
            let refinements = match self.joint {
                Some(_) => CLAMPS_PX.len(),
                None => ROTATION_REFINEMENTS,
            };
            for _ in 0..=refinements {
                run(pair(&self.rotation_sums), true);
                run(pair(&self.solve), false);
            }
        }
        let Some(dest) = dest else {
            return;
        };
        for [histogram, pick] in &self.rounds {
            run(pair(histogram), true);
            run(pair(pick), false);
        }
        if let Statistic::TrimmedMean { .. } = stat {
            run(pair(&self.sums), true);
        }
        run((&self.finish, &dest.0), false);
    }

    /// The least-squares rotation of the bound flow (None without derotation); waits for it.
    pub fn rotation(&self) -> Result<Option<Rotation>> {
        if self.field.is_none() {
            return Ok(None);
        }
        self.prepare(Statistic::Median)?;
        let mut enc = self.ctx.encoder("movement rotation");
        self.encode(&mut enc, Statistic::Median, None, None);
        self.ctx.queue.submit([enc.finish()]);
        let bytes = self.ctx.read_back(&self.sel, SEL_BYTES)?;
        let rows: &[f32] = bytemuck::cast_slice(&bytes[48..96]);
        Ok(Some(std::array::from_fn(|i| {
            std::array::from_fn(|j| rows[4 * i + j])
        })))
    }

    /// The statistic of the magnitudes in the bound flow buffer (submitted work must be queued),
    /// after subtracting the fitted rotation flow when derotating; waits for it.
    pub fn compute(&self, stat: Statistic) -> Result<f64> {
        self.prepare(stat)?;
        let results = self
            .ctx
            .storage_buffer("movement result", u64::from(RECORD_WORDS) * 4);
        let frame = self.ctx.buffer_init(
            "movement frame",
            wgpu::BufferUsages::STORAGE,
            bytemuck::bytes_of(&FrameParams::default()),
        );
        let mut enc = self.ctx.encoder("movement");
        let dest = self.destination(&results, &frame, 0);
        self.encode(&mut enc, stat, Some(&dest), None);
        self.ctx.queue.submit([enc.finish()]);
        let bytes = self.ctx.read_back(&results, 8)?;
        let v = bytes
            .get(..8)
            .and_then(|b| <[u8; 8]>::try_from(b).ok())
            .map(f64::from_le_bytes)
            .ok_or_else(|| Error::gpu("movement record too short"))?;
        checked(v)
    }
}

/// A statistic from the device: an error when the device marked it (NaN: the flow was not
/// finite).
pub fn checked(v: f64) -> Result<f64> {
    if v.is_nan() {
        return Err(Error::gpu(
            "movement histogram lost values (non-finite flow?)",
        ));
    }
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::cpu;
    use crate::params::Statistic;

    /// The median by selection equals the middle of the sorted values, for odd and even
    /// lengths, ties and zeros.
    #[test]
    fn median_by_selection_is_the_sorted_median() {
        let mut rng = fastrand::Rng::with_seed(35);
        for n in [1usize, 2, 3, 4, 7, 8, 100, 101, 57_600] {
            let v: Vec<f32> = (0..n)
                .map(|_| match rng.u8(0..4) {
                    0 => 0.0,
                    1 => 1.5,
                    _ => rng.f32() * 10.0,
                })
                .collect();
            let mut sorted = v.clone();
            sorted.sort_by(f32::total_cmp);
            let (lo, hi) = ((n - 1) / 2, n / 2);
            let want = (f64::from(sorted[lo]) + f64::from(sorted[hi])) * 0.5;
            let got = cpu(&v, Statistic::Median).unwrap();
            assert_eq!(got.to_bits(), want.to_bits(), "n = {n}");
        }
    }
}
