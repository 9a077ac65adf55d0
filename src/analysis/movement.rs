//! Movement: consecutive-pair movement measured every `stride` frames (each frame in between gets
//! an equal share), optionally derotated, and the stationary step fed the movement from its
//! reference. The opencv engine ([`MovementEngine`]) answers at once and the pass feeds the step
//! itself; the gpu engine ([`DeviceMovement`]) runs the step on the device too and hands the
//! records back later, which the pass replays through the same step (and checks against the
//! device's decisions). Engines hold frames in [`SLOTS`] slots; the pass keeps the anchor and the
//! reference loaded.

use super::checkpoint::MovementState;
use super::device::{DeviceMovement, Pixels, Record, Work, REFERENCE};
#[cfg(feature = "opencv")]
use super::ingest::prepare;
use super::sphere::Sphere;
use super::{analysis_size, MovementRequest, StationaryRequest};
use crate::error::{Error, Result};
use crate::gpu::GpuContext;
use crate::kernels::farneback::SLOTS;
#[cfg(feature = "opencv")]
use crate::kernels::farneback::{self, host::Expander, host::Expansion};
use crate::kernels::movement::checked;
#[cfg(feature = "opencv")]
use crate::kernels::movement::{self, RotationField};
#[cfg(feature = "opencv")]
use crate::kernels::remap::{self, Interp};
use crate::kernels::resize_area;
use crate::params::Backend;
#[cfg(feature = "opencv")]
use crate::params::Statistic;
use crate::source::Metadata;
#[cfg(feature = "opencv")]
use crate::source::{self, OpenOptions};
use crate::steps::StationarySampler;
#[cfg(feature = "opencv")]
use opencv::core::Mat;
use std::collections::VecDeque;
#[cfg(feature = "opencv")]
use std::path::Path;
use std::sync::Arc;

/// Flow + statistic between frames held in slots, answered at once.
pub(crate) trait MovementEngine: Send {
    /// Puts a frame's analysis pixels in `slot` (below [`SLOTS`]).
    fn load(&mut self, slot: usize, px: Pixels) -> Result<()>;
    /// Movement statistic (analysis pixels) from slot `from` to slot `to`.
    fn movement(&mut self, from: usize, to: usize) -> Result<f64>;
    /// The statistics of several slot pairs `(from, to)`, in order; an engine may measure them
    /// at once (each as [`MovementEngine::movement`] would).
    fn movements(&mut self, pairs: &[(usize, usize)]) -> Result<Vec<f64>> {
        pairs.iter().map(|&(a, b)| self.movement(a, b)).collect()
    }
}

/// How the opencv engine derotates: not at all, one pinhole rotation (`--derotate`), or one
/// rotation of the sphere over the horizon views.
#[cfg(feature = "opencv")]
enum Fit {
    None,
    Pinhole(RotationField),
    Sphere(Sphere),
}

/// The host Farneback (bit-identical to OpenCV's) and the host twin of the statistic. Each slot
/// holds its frame's pyramid of expansions, computed once when loaded and reused by every pair
/// the frame is in (the stationary reference's by every frame compared with it). On a 360° input
/// each slot holds the horizon views of its frame (cv::remap), and the statistic is taken over
/// every view's flow.
#[cfg(feature = "opencv")]
struct Opencv {
    expander: Expander,
    statistic: Statistic,
    /// Per slot: the frame's expansions, or its views'.
    frames: Vec<Option<Vec<Expansion>>>,
    fit: Fit,
}

#[cfg(feature = "opencv")]
impl MovementEngine for Opencv {
    fn load(&mut self, slot: usize, px: Pixels) -> Result<()> {
        match px {
            Pixels::Small(gray) => {
                let views = match &self.fit {
                    Fit::Sphere(sphere) => (sphere.tables.iter())
                        .map(|t| remap::opencv(&gray, t, Interp::Bilinear))
                        .collect::<Result<Vec<_>>>()?,
                    _ => vec![gray],
                };
                self.frames[slot] = None; // the slot's old expansions go before the new come
                let expanded = (views.iter())
                    .map(|v| self.expander.expand(v))
                    .collect::<Result<Vec<_>>>()?;
                self.frames[slot] = Some(expanded);
                Ok(())
            }
            Pixels::Staged(_) => Err(Error::param(
                "movement",
                "the opencv engine takes gray images, not device buffers",
            )),
        }
    }

    fn movement(&mut self, from: usize, to: usize) -> Result<f64> {
        let (a, b) = self.pair(from, to)?;
        self.measure(a, b)
    }

    /// Two pairs (a frame's consecutive movement and the one from the stationary reference)
    /// on two threads: the Farneback runs on one core, and the two are independent.
    fn movements(&mut self, pairs: &[(usize, usize)]) -> Result<Vec<f64>> {
        let &[(a0, b0), (a1, b1)] = pairs else {
            return pairs.iter().map(|&(a, b)| self.movement(a, b)).collect();
        };
        let (first, second) = (self.pair(a0, b0)?, self.pair(a1, b1)?);
        let this = &*self;
        std::thread::scope(|scope| {
            let other = scope.spawn(move || this.measure(second.0, second.1));
            let here = this.measure(first.0, first.1);
            let there = other
                .join()
                .unwrap_or_else(|_| Err(Error::param("movement", "a flow thread panicked")));
            Ok(vec![here?, there?])
        })
    }
}

#[cfg(feature = "opencv")]
impl Opencv {
    /// The expansions of the frames (or views) in slots `from` and `to`.
    fn pair(&self, from: usize, to: usize) -> Result<(&[Expansion], &[Expansion])> {
        match (&self.frames[from], &self.frames[to]) {
            (Some(a), Some(b)) => Ok((a, b)),
            _ => Err(Error::param("slots", "frame not loaded")),
        }
    }

    /// The statistic of the flow from `a` to `b` (of every view's flow, derotated together, on
    /// a 360° input).
    fn measure(&self, a: &[Expansion], b: &[Expansion]) -> Result<f64> {
        let flows = (a.iter().zip(b))
            .map(|(a, b)| farneback::host::flow(a, b))
            .collect::<Result<Vec<_>>>()?;
        match (&self.fit, flows.as_slice()) {
            (Fit::None, [f]) => movement::cpu_flow(f, self.statistic, None),
            (Fit::Pinhole(field), [f]) => movement::cpu_flow(f, self.statistic, Some(field)),
            (Fit::Sphere(sphere), _) => {
                let mut stacked = Vec::new();
                for f in &flows {
                    stacked.extend(movement::flow_values(f)?);
                }
                movement::cpu(&sphere.field.derotated(&stacked)?, self.statistic)
            }
            _ => Err(Error::param("movement", "one flow per frame expected")),
        }
    }
}

/// The engine measuring for a pass.
enum Engine {
    /// Answers at once (opencv, the tests' fakes).
    Host(Box<dyn MovementEngine>),
    /// Answers later, through records.
    Device(Box<DeviceMovement>),
}

impl Engine {
    fn load(&mut self, slot: usize, px: Pixels) -> Result<()> {
        match self {
            Engine::Host(e) => e.load(slot, px),
            Engine::Device(d) => d.load(slot, px),
        }
    }
}

/// The engine for `backend` at the analysis size `(w, h)`: the gpu one when it can be made (else
/// a warning and opencv).
fn engine(
    req: &MovementRequest,
    stationary: Option<&StationaryRequest>,
    backend: Backend,
    ctx: Option<&Arc<GpuContext>>,
    (w, h): (u32, u32),
    scale: f64,
) -> Result<(Engine, Backend)> {
    if let (Backend::Gpu, Some(ctx)) = (backend, ctx) {
        let sphere = req.sphere.map(|v| Sphere::new(v, (w, h))).transpose()?;
        match DeviceMovement::new(ctx, req, stationary, scale, (w, h), sphere) {
            Ok(e) => return Ok((Engine::Device(Box::new(e)), Backend::Gpu)),
            #[cfg(feature = "opencv")]
            Err(e) => log::warn!("{e}; movement uses the opencv backend"),
            #[cfg(not(feature = "opencv"))]
            Err(e) => return Err(e),
        }
    }
    host_engine(req, (w, h))
}

/// OpenCV's engine at the analysis size `(w, h)`.
#[cfg(feature = "opencv")]
fn host_engine(req: &MovementRequest, (w, h): (u32, u32)) -> Result<(Engine, Backend)> {
    let sphere = req.sphere.map(|v| Sphere::new(v, (w, h))).transpose()?;
    let fit = match (sphere, req.derotate) {
        (Some(s), _) => Fit::Sphere(s),
        (None, Some(d)) => Fit::Pinhole(RotationField::new(w, h, d)?),
        (None, None) => Fit::None,
    };
    let cpu = Opencv {
        expander: Expander::new(&req.farneback)?,
        statistic: req.statistic,
        frames: (0..SLOTS).map(|_| None).collect(),
        fit,
    };
    Ok((Engine::Host(Box::new(cpu)), Backend::Opencv))
}

/// Without OpenCV only the gpu engine measures movement.
#[cfg(not(feature = "opencv"))]
fn host_engine(_req: &MovementRequest, _size: (u32, u32)) -> Result<(Engine, Backend)> {
    Err(Error::param(
        "backend",
        "this build has no OpenCV: movement needs the gpu backend",
    ))
}

/// The analysis size of `meta`'s frames for `req`, and the factor from it to full resolution.
fn analysis(req: &MovementRequest, meta: &Metadata) -> ((u32, u32), f64) {
    let size = analysis_size(meta.width, meta.height, req.analysis_width);
    (size, f64::from(meta.width) / f64::from(size.0))
}

/// A frame measured: at a stride point, the consecutive movement from the previous one (`from`,
/// none for the first frame); for a candidate, the stationary step.
struct Measured {
    index: usize,
    stride_point: bool,
    from: Option<usize>,
    candidate: bool,
}

impl Measured {
    /// Whether the consecutive movement is the one from the previous frame.
    fn measured_from_previous(&self) -> bool {
        self.from.is_some_and(|a| a + 1 == self.index)
    }
}

/// Per-frame movement: consecutive movement (every `stride` frames, spread evenly over the
/// frames in between), and the stationary step fed with the movement from its reference.
pub(crate) struct MovementPass {
    engine: Engine,
    stride: usize,
    /// Analysis size.
    pub size: (i32, i32),
    /// Frames are 360° ones measured on their horizon views (rendered from the analysis gray
    /// on the host side of the hand-off, never staged).
    sphere: bool,
    /// Factor from analysis pixels to full-resolution pixels.
    pub scale: f64,
    /// values[i] = movement from frame i-1 to frame i (full-resolution pixels).
    pub values: Vec<f64>,
    /// (slot, frame index) of the last stride point.
    anchor: Option<(usize, usize)>,
    /// Slot of the stationary step's reference frame ([`REFERENCE`] on the device).
    reference: Option<usize>,
    /// The last frame, when it is not a stride point: loaded in a slot, or its pixels kept.
    last: Option<(Option<usize>, usize, Option<Pixels>)>,
    /// The stationary sampler's step, when requested.
    pub stationary: Option<StationarySampler>,
    /// Frames submitted to the device engine whose records are still to come, in order.
    pending: VecDeque<Measured>,
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
        let (size, scale) = analysis(&req, meta);
        let (engine, used) = engine(&req, stationary.as_ref(), backend, ctx, size, scale)?;
        Ok((MovementPass::with(&req, stationary, engine, meta), used))
    }

    /// A pass measuring with `engine` (`req` already checked).
    #[cfg(test)]
    pub(crate) fn new(
        req: &MovementRequest,
        stationary: Option<StationaryRequest>,
        engine: Box<dyn MovementEngine>,
        meta: &Metadata,
    ) -> MovementPass {
        MovementPass::with(req, stationary, Engine::Host(engine), meta)
    }

    fn with(
        req: &MovementRequest,
        stationary: Option<StationaryRequest>,
        engine: Engine,
        meta: &Metadata,
    ) -> MovementPass {
        let ((w, h), scale) = analysis(req, meta);
        let reference = matches!(engine, Engine::Device(_)).then_some(REFERENCE);
        MovementPass {
            engine,
            stride: req.stride as usize,
            size: (w as i32, h as i32),
            sphere: req.sphere.is_some(),
            scale,
            values: Vec::new(),
            anchor: None,
            reference,
            last: None,
            stationary: stationary.map(StationarySampler::new),
            pending: VecDeque::new(),
        }
    }

    /// Whether frames may reach the engine as device buffers resized from `frame` (width,
    /// height) by resize_area: an engine on the device and an integer downscale (others keep
    /// the CPU prepare).
    pub(crate) fn can_stage(&self, frame: (u32, u32)) -> bool {
        matches!(self.engine, Engine::Device(_))
            && !self.sphere
            && resize_area::factors(frame, (self.size.0 as u32, self.size.1 as u32)).is_some()
    }

    /// Frames will come as [`Pixels::Staged`] indices into `buffers`.
    pub(crate) fn use_staged(&mut self, buffers: Vec<wgpu::Buffer>) {
        if let Engine::Device(d) = &mut self.engine {
            d.use_staged(buffers);
        }
    }

    /// A slot holding neither the anchor nor the reference.
    fn free_slot(&self) -> usize {
        let busy = [self.anchor.map(|a| a.0), self.reference];
        (0..SLOTS).find(|s| !busy.contains(&Some(*s))).unwrap_or(0)
    }

    /// Whether the frames stepped so far end at a stride point (a checkpoint may be taken once
    /// [`MovementPass::settle`]d).
    pub(crate) fn at_stride_point(&self) -> bool {
        self.last.is_none()
    }

    /// The state a checkpoint keeps (none before the first frame; settle first).
    pub(crate) fn state(&self) -> Option<MovementState> {
        let (_, anchor) = self.anchor?;
        let st = self.stationary.as_ref();
        Some(MovementState {
            values: self.values.clone(),
            anchor,
            reference: st.and_then(StationarySampler::reference),
            accumulated: st.map_or(0.0, StationarySampler::accumulated),
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
        self.last = None;
        self.pending.clear();
        match &self.engine {
            Engine::Host(_) => self.reference = None,
            Engine::Device(d) => d.restore(st.reference, st.accumulated),
        }
    }

    /// Loads the pixels of a restored anchor or reference frame.
    pub(crate) fn prime(&mut self, index: usize, px: Pixels, st: &MovementState) -> Result<()> {
        let slot = self.free_slot();
        self.engine.load(slot, px)?;
        if index == st.anchor {
            self.anchor = Some((slot, index));
        }
        if st.reference == Some(index) {
            match &mut self.engine {
                Engine::Host(_) => self.reference = Some(slot),
                Engine::Device(d) => d.keep(slot)?,
            }
        }
        Ok(())
    }

    /// Takes frame `i` (frames come in order).
    pub(crate) fn step(&mut self, i: usize, px: Pixels) -> Result<()> {
        let candidate = self.stationary.as_ref().is_some_and(|s| s.wants(i));
        let stride_point = self.anchor.is_none() || i.is_multiple_of(self.stride);
        if !stride_point && !candidate {
            self.last = Some((None, i, Some(px)));
            return Ok(());
        }
        let cur = self.free_slot();
        self.engine.load(cur, px)?;
        self.last = (!stride_point).then_some((Some(cur), i, None));
        let from = stride_point
            .then(|| self.anchor.replace((cur, i)))
            .flatten();
        let m = Measured {
            index: i,
            stride_point,
            from: from.map(|a| a.1),
            candidate,
        };
        self.measure(m, cur, from.map(|a| a.0))
    }

    /// Measures `m` (loaded in `cur`; the consecutive movement from `from`): at once with a host
    /// engine, else submitted to the device.
    fn measure(&mut self, m: Measured, cur: usize, from: Option<usize>) -> Result<()> {
        let e = match &mut self.engine {
            Engine::Host(e) => e,
            Engine::Device(d) => {
                d.submit(&Work {
                    index: m.index,
                    slot: cur,
                    from,
                    from_previous: m.measured_from_previous(),
                    candidate: m.candidate,
                })?;
                self.pending.push_back(m);
                return self.collect(false);
            }
        };
        // Both movements the frame needs are known before the step decides: measured together.
        let needed = reference_needed(self.stationary.as_ref(), &m, self.reference);
        let pairs: Vec<(usize, usize)> = from.into_iter().chain(needed).map(|s| (s, cur)).collect();
        let got = e.movements(&pairs)?;
        let consecutive = from.and(got.first().copied());
        let measured = needed.and(got.last().copied());
        push_values(&mut self.values, self.scale, &m, consecutive);
        let slot = self.reference;
        let from_ref = || match measured {
            Some(v) => Ok(v),
            None => {
                let slot = slot.ok_or_else(|| Error::param("stationary", "no reference loaded"))?;
                e.movement(slot, cur)
            }
        };
        if step(&mut self.stationary, &m, consecutive, self.scale, from_ref)? {
            self.reference = Some(cur);
        }
        Ok(())
    }

    /// Applies the device's records that have come back (every one with `all`: waits).
    fn collect(&mut self, all: bool) -> Result<()> {
        let Engine::Device(d) = &mut self.engine else {
            return Ok(());
        };
        for r in d.collect(all)? {
            let m = self
                .pending
                .pop_front()
                .ok_or_else(|| Error::gpu("a movement record without its frame"))?;
            self.replay(&m, &r)?;
        }
        Ok(())
    }

    /// Applies one record: the consecutive movement, and the stationary step fed what the device
    /// measured, which must decide as the device did.
    fn replay(&mut self, m: &Measured, r: &Record) -> Result<()> {
        let consecutive = m.from.map(|_| checked(r.consecutive)).transpose()?;
        push_values(&mut self.values, self.scale, m, consecutive);
        let from_ref = || checked(r.reference);
        let anchored = step(&mut self.stationary, m, consecutive, self.scale, from_ref)?;
        if m.candidate && anchored != (r.decision != 0) {
            return Err(Error::gpu(format!(
                "the device's stationary decision at frame {} differs from the host's",
                m.index
            )));
        }
        Ok(())
    }

    /// Applies every submitted measurement (a checkpoint may then be taken).
    pub(crate) fn settle(&mut self) -> Result<()> {
        self.collect(true)
    }

    /// Measures the frames after the last stride point, then settles.
    pub(crate) fn finish(&mut self) -> Result<()> {
        if let Some((slot, i, small)) = self.last.take() {
            let slot = match (slot, small) {
                (Some(s), _) => s,
                (None, Some(px)) => {
                    let s = self.free_slot();
                    self.engine.load(s, px)?;
                    s
                }
                (None, None) => return Err(Error::param("movement", "last frame lost")),
            };
            let from = self.anchor.replace((slot, i));
            let m = Measured {
                index: i,
                stride_point: true,
                from: from.map(|a| a.1),
                candidate: false,
            };
            self.measure(m, slot, from.map(|a| a.0))?;
        }
        self.settle()
    }

    /// Movement between two frames (for the `--auto` sample).
    #[cfg(feature = "opencv")]
    fn pair(&mut self, a: Mat, b: Mat) -> Result<f64> {
        self.engine.load(0, Pixels::Small(a))?;
        self.engine.load(1, Pixels::Small(b))?;
        let m = match &mut self.engine {
            Engine::Host(e) => e.movement(0, 1)?,
            Engine::Device(d) => d.movement(0, 1)?,
        };
        Ok(m * self.scale)
    }
}

/// Appends the consecutive movement measured at `m` (analysis pixels) to `values` in
/// full-resolution pixels, spread over the frames since its start.
fn push_values(values: &mut Vec<f64>, scale: f64, m: &Measured, consecutive: Option<f64>) {
    if !m.stride_point {
        return;
    }
    match (m.from, consecutive) {
        (Some(a), Some(c)) => {
            let per = c * scale / (m.index - a) as f64;
            values.extend(std::iter::repeat_n(per, m.index - a));
        }
        _ => values.push(0.0),
    }
}

/// The slot of the stationary reference (`slot`) when the step will ask frame `m` for the movement
/// from it: a candidate with a reference that [`step`] cannot answer with the consecutive movement.
fn reference_needed(
    stationary: Option<&StationarySampler>,
    m: &Measured,
    slot: Option<usize>,
) -> Option<usize> {
    let st = stationary.filter(|s| m.candidate && s.wants(m.index))?;
    let reference = st.reference()?;
    let quick = m.measured_from_previous() && reference + 1 == m.index;
    slot.filter(|_| !quick)
}

/// Feeds frame `m` to the stationary step when it is a candidate: the movement from its
/// reference is the consecutive one when that starts at the reference, else `from_reference`
/// (analysis pixels, asked only when needed). Returns whether `m` is now the reference.
fn step(
    stationary: &mut Option<StationarySampler>,
    m: &Measured,
    consecutive: Option<f64>,
    scale: f64,
    from_reference: impl FnOnce() -> Result<f64>,
) -> Result<bool> {
    let Some(st) = stationary.as_mut().filter(|_| m.candidate) else {
        return Ok(false);
    };
    let quick = consecutive.filter(|_| m.measured_from_previous());
    st.step(m.index, |reference| match quick {
        Some(c) if reference + 1 == m.index => Ok(c * scale),
        _ => Ok(from_reference()? * scale),
    })
}

/// Movement of `pairs` frame pairs (t, t+1) spread evenly over the input, in full-resolution
/// pixels: the sample `--auto` proposes thresholds from. Decodes sequentially (grab over the
/// frames in between).
#[cfg(feature = "opencv")]
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
