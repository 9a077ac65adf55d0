//! Movement: consecutive-pair movement measured every `stride` frames (each frame in between gets
//! an equal share), optionally derotated, by one engine (gpu or opencv) behind
//! [`MovementEngine`]; the pass feeds the stationary step the movement from its reference.
//! Engines hold frames in [`SLOTS`] slots; the pass keeps the anchor and the reference loaded.

use super::checkpoint::MovementState;
use super::ingest::{prepare, Pixels};
use super::{analysis_size, MovementRequest, StationaryRequest};
use crate::error::{Error, Result};
use crate::gpu::{Backend, GpuContext};
use crate::kernels::farneback::{self, FarnebackGpu, FarnebackParams, SLOTS};
use crate::kernels::movement::{self, MovementGpu, RotationField, Statistic};
use crate::kernels::resize_area;
use crate::source::{self, Metadata, OpenOptions};
use crate::steps::Stationary;
use opencv::core::Mat;
use std::path::Path;
use std::sync::Arc;

/// Flow + statistic between frames held in slots.
pub(crate) trait MovementEngine {
    /// Puts a frame's analysis pixels in `slot` (below [`SLOTS`]).
    fn load(&mut self, slot: usize, px: Pixels) -> Result<()>;
    /// Movement statistic (analysis pixels) from slot `from` to slot `to`.
    fn movement(&mut self, from: usize, to: usize) -> Result<f64>;
    /// Whether frames may come as device buffers ([`MovementEngine::use_staged`]).
    fn on_device(&self) -> bool {
        false
    }
    /// Frames will come as [`Pixels::Staged`] indices into `buffers`.
    fn use_staged(&mut self, _buffers: Vec<wgpu::Buffer>) {}
}

/// The WGSL Farneback and movement kernels.
struct Gpu {
    flow: Box<FarnebackGpu>,
    stat: MovementGpu,
    statistic: Statistic,
    /// The sharpness engine's resized-gray buffers (empty unless frames stay on the device).
    staged: Vec<wgpu::Buffer>,
}

impl MovementEngine for Gpu {
    fn load(&mut self, slot: usize, px: Pixels) -> Result<()> {
        match px {
            Pixels::Small(gray) => self.flow.load(slot, &gray),
            Pixels::Staged(k) => {
                let buf = self
                    .staged
                    .get(k)
                    .ok_or_else(|| Error::param("movement", "no device gray staged"))?;
                self.flow.load_buffer(slot, buf)
            }
        }
    }

    fn movement(&mut self, from: usize, to: usize) -> Result<f64> {
        self.flow.flow_between(from, to)?;
        self.stat.compute(self.statistic)
    }

    fn on_device(&self) -> bool {
        true
    }

    fn use_staged(&mut self, buffers: Vec<wgpu::Buffer>) {
        self.staged = buffers;
    }
}

/// OpenCV's Farneback and the host twin of the statistic.
struct Opencv {
    params: FarnebackParams,
    statistic: Statistic,
    frames: Vec<Option<Mat>>,
    field: Option<RotationField>,
}

impl MovementEngine for Opencv {
    fn load(&mut self, slot: usize, px: Pixels) -> Result<()> {
        match px {
            Pixels::Small(gray) => {
                self.frames[slot] = Some(gray);
                Ok(())
            }
            Pixels::Staged(_) => Err(Error::param(
                "movement",
                "the opencv engine takes gray images, not device buffers",
            )),
        }
    }

    fn movement(&mut self, from: usize, to: usize) -> Result<f64> {
        let (Some(a), Some(b)) = (&self.frames[from], &self.frames[to]) else {
            return Err(Error::param("slots", "frame not loaded"));
        };
        let f = farneback::opencv(a, b, &self.params, None)?;
        movement::cpu_flow(&f, self.statistic, self.field.as_ref())
    }
}

/// The engine for `backend` at the analysis size `(w, h)`: the gpu one when it can be made (else
/// a warning and opencv).
fn engine(
    req: &MovementRequest,
    backend: Backend,
    ctx: Option<&Arc<GpuContext>>,
    (w, h): (u32, u32),
) -> Result<(Box<dyn MovementEngine>, Backend)> {
    let cpu = Opencv {
        params: req.farneback,
        statistic: req.statistic,
        frames: vec![None; SLOTS],
        field: req
            .derotate
            .map(|d| RotationField::new(w, h, d))
            .transpose()?,
    };
    if let (Backend::Gpu, Some(ctx)) = (backend, ctx) {
        let made = FarnebackGpu::new(ctx.clone(), req.farneback, w, h).and_then(|flow| {
            let stat = MovementGpu::new(ctx.clone(), flow.flow_buffer(), w, h, req.derotate)?;
            Ok(Gpu {
                flow: Box::new(flow),
                stat,
                statistic: req.statistic,
                staged: Vec::new(),
            })
        });
        match made {
            Ok(e) => return Ok((Box::new(e), Backend::Gpu)),
            Err(e) => log::warn!("{e}; movement uses the opencv backend"),
        }
    }
    Ok((Box::new(cpu), Backend::Opencv))
}

/// Per-frame movement: consecutive movement (every `stride` frames, spread evenly over the
/// frames in between), and the stationary step fed with the movement from its reference.
pub(crate) struct MovementPass {
    engine: Box<dyn MovementEngine>,
    stride: usize,
    /// Analysis size.
    pub size: (i32, i32),
    /// Factor from analysis pixels to full-resolution pixels.
    pub scale: f64,
    /// values[i] = movement from frame i-1 to frame i (full-resolution pixels).
    pub values: Vec<f64>,
    /// (slot, frame index) of the last stride point.
    anchor: Option<(usize, usize)>,
    /// Slot of the stationary step's reference frame.
    reference: Option<usize>,
    /// The last frame, when it is not a stride point: loaded in a slot, or its pixels kept.
    last: Option<(Option<usize>, usize, Option<Pixels>)>,
    /// The stationary sampler's step, when requested.
    pub stationary: Option<Stationary>,
}

impl MovementPass {
    /// Checks `req`, then makes the engine for `backend`; returns the backend it uses.
    pub(crate) fn open(
        req: MovementRequest,
        stationary: Option<StationaryRequest>,
        backend: Backend,
        ctx: Option<&Arc<GpuContext>>,
        meta: &Metadata,
    ) -> Result<(MovementPass, Backend)> {
        req.farneback.validate()?;
        req.statistic.validate()?;
        if req.stride == 0 {
            return Err(Error::param("flow stride", "must be at least 1"));
        }
        let size = analysis_size(meta.width, meta.height, req.analysis_width);
        let (engine, used) = engine(&req, backend, ctx, size)?;
        Ok((MovementPass::new(&req, stationary, engine, meta), used))
    }

    /// A pass measuring with `engine` (`req` already checked).
    pub(crate) fn new(
        req: &MovementRequest,
        stationary: Option<StationaryRequest>,
        engine: Box<dyn MovementEngine>,
        meta: &Metadata,
    ) -> MovementPass {
        let (w, h) = analysis_size(meta.width, meta.height, req.analysis_width);
        MovementPass {
            engine,
            stride: req.stride as usize,
            size: (w as i32, h as i32),
            scale: f64::from(meta.width) / f64::from(w),
            values: Vec::new(),
            anchor: None,
            reference: None,
            last: None,
            stationary: stationary
                .map(|s| Stationary::new(s.threshold, s.reset_delta, s.first, s.last)),
        }
    }

    /// Whether frames may reach the engine as device buffers resized from `frame` (width,
    /// height) by resize_area: an engine on the device and an integer downscale (others keep
    /// the CPU prepare).
    pub(crate) fn can_stage(&self, frame: (u32, u32)) -> bool {
        self.engine.on_device()
            && resize_area::factors(frame, (self.size.0 as u32, self.size.1 as u32)).is_some()
    }

    /// Frames will come as [`Pixels::Staged`] indices into `buffers`.
    pub(crate) fn use_staged(&mut self, buffers: Vec<wgpu::Buffer>) {
        self.engine.use_staged(buffers);
    }

    /// A slot holding neither the anchor nor the reference.
    fn free_slot(&self) -> usize {
        let busy = [self.anchor.map(|a| a.0), self.reference];
        (0..SLOTS).find(|s| !busy.contains(&Some(*s))).unwrap_or(0)
    }

    /// Whether the state is complete through the last frame stepped (a checkpoint may be taken).
    pub(crate) fn at_stride_point(&self) -> bool {
        self.last.is_none()
    }

    /// The state a checkpoint keeps (none before the first frame).
    pub(crate) fn state(&self) -> Option<MovementState> {
        let (_, anchor) = self.anchor?;
        let st = self.stationary.as_ref();
        Some(MovementState {
            values: self.values.clone(),
            anchor,
            reference: st.and_then(Stationary::reference),
            accumulated: st.map_or(0.0, Stationary::accumulated),
            keys: st.map(|s| s.keys().to_vec()).unwrap_or_default(),
        })
    }

    /// Restores a checkpoint's state; the anchor and reference pixels follow through `prime`.
    pub(crate) fn restore(&mut self, st: &MovementState) {
        self.values = st.values.clone();
        if let Some(s) = self.stationary.as_mut() {
            s.restore(st.reference, st.accumulated, st.keys.clone());
        }
        self.anchor = None;
        self.reference = None;
        self.last = None;
    }

    /// Loads the pixels of a restored anchor or reference frame.
    pub(crate) fn prime(&mut self, index: usize, px: Pixels, st: &MovementState) -> Result<()> {
        let slot = self.free_slot();
        self.engine.load(slot, px)?;
        if index == st.anchor {
            self.anchor = Some((slot, index));
        }
        if st.reference == Some(index) {
            self.reference = Some(slot);
        }
        Ok(())
    }

    /// Movement since the anchor, spread evenly over the frames after it, up to `slot`/`i`;
    /// the movement itself when the anchor was the previous frame.
    fn measure_to(&mut self, slot: usize, i: usize) -> Result<Option<f64>> {
        let Some((a_slot, a)) = self.anchor else {
            self.values.push(0.0);
            self.anchor = Some((slot, i));
            return Ok(None);
        };
        let m = self.engine.movement(a_slot, slot)? * self.scale;
        let per = m / (i - a) as f64;
        self.values.extend(std::iter::repeat_n(per, i - a));
        self.anchor = Some((slot, i));
        Ok((i - a == 1).then_some(m))
    }

    /// Takes frame `i` (frames come in order).
    pub(crate) fn step(&mut self, i: usize, px: Pixels) -> Result<()> {
        let active = self.stationary.as_ref().is_some_and(|s| s.wants(i));
        let stride_point = self.anchor.is_none() || i % self.stride == 0;
        if !stride_point && !active {
            self.last = Some((None, i, Some(px)));
            return Ok(());
        }
        let cur = self.free_slot();
        self.engine.load(cur, px)?;
        self.last = None;
        let consecutive = if stride_point {
            self.measure_to(cur, i)?
        } else {
            self.last = Some((Some(cur), i, None));
            None
        };
        if active {
            self.stationary_step(cur, i, consecutive)?;
        }
        Ok(())
    }

    /// Feeds frame `i` (in `cur`) to the stationary step; `consecutive` is the movement from
    /// frame i-1 when just measured.
    fn stationary_step(&mut self, cur: usize, i: usize, consecutive: Option<f64>) -> Result<()> {
        let (engine, scale, slot) = (&mut self.engine, self.scale, self.reference);
        let Some(st) = self.stationary.as_mut() else {
            return Ok(());
        };
        let anchored = st.step(i, |reference| match consecutive {
            Some(m) if reference + 1 == i => Ok(m),
            _ => {
                let slot = slot.ok_or_else(|| Error::param("stationary", "no reference loaded"))?;
                Ok(engine.movement(slot, cur)? * scale)
            }
        })?;
        if anchored {
            self.reference = Some(cur);
        }
        Ok(())
    }

    /// Measures the frames after the last stride point.
    pub(crate) fn finish(&mut self) -> Result<()> {
        if let Some((slot, i, small)) = self.last.take() {
            let slot = match (slot, small) {
                (Some(s), _) => s,
                (None, Some(m)) => {
                    let s = self.free_slot();
                    self.engine.load(s, m)?;
                    s
                }
                (None, None) => return Err(Error::param("movement", "last frame lost")),
            };
            self.measure_to(slot, i)?;
        }
        Ok(())
    }

    /// Movement between two frames (for the `--auto` sample).
    fn pair(&mut self, a: Mat, b: Mat) -> Result<f64> {
        self.engine.load(0, Pixels::Small(a))?;
        self.engine.load(1, Pixels::Small(b))?;
        Ok(self.engine.movement(0, 1)? * self.scale)
    }
}

/// Movement of `pairs` frame pairs (t, t+1) spread evenly over the input, in full-resolution
/// pixels: the sample `--auto` proposes thresholds from. Decodes sequentially (grab over the
/// frames in between).
pub fn sample_movement(
    input: &Path,
    opts: &OpenOptions,
    req: MovementRequest,
    pairs: usize,
    backend: Backend,
    ctx: Option<&Arc<GpuContext>>,
) -> Result<Vec<f64>> {
    let mut src = source::open(input, opts)?;
    let meta = src.metadata().clone();
    let n = meta.frame_count;
    if n < 2 {
        return Ok(Vec::new());
    }
    let pairs = pairs.clamp(1, n / 2);
    let mut indices: Vec<usize> = (0..pairs)
        .flat_map(|k| {
            let t = k * (n - 2) / pairs.max(2).saturating_sub(1).max(1);
            [t.min(n - 2), t.min(n - 2) + 1]
        })
        .collect();
    indices.sort_unstable();
    indices.dedup();
    let (mut pass, _) = MovementPass::open(req, None, backend, ctx, &meta)?;
    let mut prev: Option<(usize, Mat)> = None;
    let mut out = Vec::new();
    source::read_indices(src.as_mut(), &indices, |f| {
        let small = prepare(pass.size, &f.image)?;
        if let Some((p, a)) = prev.take() {
            if p + 1 == f.index {
                out.push(pass.pair(a, small.clone())?);
            }
        }
        prev = Some((f.index, small));
        Ok(())
    })?;
    Ok(out)
}
