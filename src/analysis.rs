//! Analysis: one decode pass over an input that yields the exact frame count, every frame's
//! timestamp and the requested per-frame scores: sharpness, camera movement between consecutive
//! frames, and the stationary sampler's reference-mode selection (which needs pixels because its
//! frame pairs depend on the threshold). Frames stream through in small batches (bounded memory);
//! when nothing needs pixels, frames are only grabbed, never converted.

use crate::error::{Error, Result};
use crate::fsutil::Fingerprint;
use crate::gpu::{Backend, GpuContext};
use crate::kernels::farneback::{self, FarnebackGpu, FarnebackParams, SLOTS};
use crate::kernels::movement::{self, Derotate, MovementGpu, RotationField, Statistic};
use crate::kernels::resize_area;
use crate::kernels::sharpness::{score_opencv, Metric, SharpnessGpu};
use crate::source::{self, Frame, FrameSource, Metadata, OpenOptions};
use opencv::core::Mat;
use opencv::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::mpsc::{channel, sync_channel, Receiver, Sender, SyncSender};
use std::sync::Arc;
use std::time::Instant;

/// What to compute.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Request {
    /// Sharpness metrics to score every frame with.
    pub sharpness: Vec<Metric>,
    /// Camera movement between consecutive frames.
    pub movement: Option<MovementRequest>,
    /// The stationary sampler's reference-mode run (requires `movement`).
    pub stationary: Option<StationaryRequest>,
}

/// How movement is measured.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MovementRequest {
    /// Farneback parameters.
    pub farneback: FarnebackParams,
    /// Statistic of the flow magnitudes.
    pub statistic: Statistic,
    /// Width of the analysis resolution (frames are converted to gray and resized with
    /// INTER_AREA; never upscaled).
    pub analysis_width: u32,
    /// Flow is measured between frames `stride` apart (every frame index divisible by it, and
    /// the last); each frame in between gets an equal share. 1 measures every pair.
    #[serde(default = "one")]
    pub stride: u32,
    /// Subtract the flow of the best-fitting camera rotation before taking the statistic (the
    /// movement then follows translation, which gives reconstructions their baseline).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub derotate: Option<Derotate>,
}

fn one() -> u32 {
    1
}

/// The stationary sampler's parameters (reference mode).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct StationaryRequest {
    /// Movement (full-resolution pixels) since the last keyframe that makes a new keyframe.
    pub threshold: f64,
    /// Frames after which the reference is re-anchored, carrying the accumulated movement.
    pub reset_delta: usize,
    /// First candidate frame.
    pub first: usize,
    /// Last candidate frame (inclusive).
    pub last: usize,
}

/// Movement between consecutive frames.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MovementSeries {
    /// Analysis width.
    pub width: u32,
    /// Analysis height.
    pub height: u32,
    /// Factor from analysis pixels to full-resolution pixels.
    pub scale_to_full: f64,
    /// values[i] = movement from frame i-1 to frame i in full-resolution pixels; values[0] = 0.
    pub values: Vec<f64>,
}

/// The analysis size for a `width` x `height` input: `analysis_width` wide (never wider than the
/// input), height scaled and rounded.
pub fn analysis_size(width: u32, height: u32, analysis_width: u32) -> (u32, u32) {
    let w = analysis_width.clamp(1, width.max(1));
    let h = ((f64::from(height) * f64::from(w) / f64::from(width.max(1))).round() as u32).max(1);
    (w, h)
}

/// What one pass produced.
#[derive(Debug, Clone)]
pub struct Analysis {
    /// Metadata with the decoded frame count.
    pub metadata: Metadata,
    /// Timestamp of every frame (None for image folders without a rate).
    pub timestamps_s: Option<Vec<f64>>,
    /// Scores per requested metric, one per frame.
    pub sharpness: Vec<(Metric, Vec<f64>)>,
    /// Movement between consecutive frames, when requested.
    pub movement: Option<MovementSeries>,
    /// Keyframes chosen by the stationary sampler, when requested.
    pub stationary: Option<Vec<usize>>,
    /// Decode problems (damaged stream, damaged images), one line each.
    pub problems: Vec<String>,
    /// Damaged frames that did not stop the input (image folders): their scores are those of a
    /// stand-in image, and they must never be selected.
    pub damaged: Vec<usize>,
    /// Backend that computed the scores.
    pub backend: Backend,
}

/// Frames queued between the decode thread and the analysis (bounds memory with the batch).
const DECODE_QUEUE: usize = 2;
/// Frames held at most at once by the opencv sharpness worker before scoring.
const CPU_BATCH: usize = 4;

/// Scores frames in batches with one backend.
enum Scorer {
    Gpu(Vec<SharpnessGpu>),
    Opencv(Vec<Metric>),
}

impl Scorer {
    fn new(
        backend: Backend,
        ctx: Option<&Arc<GpuContext>>,
        metrics: &[Metric],
        meta: &Metadata,
    ) -> Result<(Scorer, Backend)> {
        if let (Backend::Gpu, Some(ctx)) = (backend, ctx) {
            let runners = metrics
                .iter()
                .map(|&m| SharpnessGpu::new(ctx.clone(), m, meta.width, meta.height))
                .collect::<Result<Vec<_>>>();
            match runners {
                Ok(r) => return Ok((Scorer::Gpu(r), Backend::Gpu)),
                Err(e) => log::warn!("{e}; using the opencv backend"),
            }
        }
        Ok((Scorer::Opencv(metrics.to_vec()), Backend::Opencv))
    }

    /// Makes the gpu scorer also resize every frame's device gray to `size` (resize_area) into
    /// small buffers, one per batch position; None for the opencv scorer.
    fn attach_resize(&mut self, size: (u32, u32)) -> Result<Option<Vec<wgpu::Buffer>>> {
        match self {
            Scorer::Gpu(runners) => match runners.first_mut() {
                Some(r) => r.attach_resize(size).map(Some),
                None => Ok(None),
            },
            Scorer::Opencv(_) => Ok(None),
        }
    }

    /// Uploads one frame and computes its gray and resized gray (into small buffer 0) without
    /// keeping its scores (for priming a resumed movement state).
    fn stage(&mut self, image: &Mat) -> Result<()> {
        if let Scorer::Gpu(runners) = self {
            if let Some(r) = runners.first_mut() {
                r.scores(&[image])?;
            }
        }
        Ok(())
    }

    fn batch(&self) -> usize {
        match self {
            Scorer::Gpu(r) => r.iter().map(|g| g.batch_size()).min().unwrap_or(1),
            Scorer::Opencv(_) => CPU_BATCH,
        }
    }

    /// The scores of `frames`: one vector per frame with one score per metric.
    fn score(&mut self, frames: &[Frame]) -> Result<Vec<Vec<f64>>> {
        let mut out = vec![Vec::new(); frames.len()];
        match self {
            Scorer::Gpu(runners) => {
                let mats: Vec<&Mat> = frames.iter().map(|f| &f.image).collect();
                for r in runners.iter_mut() {
                    for (o, v) in out.iter_mut().zip(r.scores(&mats)?) {
                        o.push(v);
                    }
                }
            }
            Scorer::Opencv(metrics) => {
                for (o, f) in out.iter_mut().zip(frames) {
                    for &m in metrics.iter() {
                        o.push(score_opencv(&f.image, m).map_err(|e| Error::Frame {
                            path: Default::default(),
                            index: f.index,
                            msg: e.to_string(),
                        })?);
                    }
                }
            }
        }
        Ok(out)
    }
}

/// Messages to the sharpness worker.
enum ToScorer {
    Frame(Frame),
    /// Score what is queued now (a checkpoint waits for it).
    Flush,
}

/// The sharpness worker: scores frames in batches in its own thread, in index order, and sends
/// `(frame index, scores per metric)` back.
fn scorer_worker(
    mut scorer: Scorer,
    rx: Receiver<ToScorer>,
    tx: Sender<(usize, Vec<f64>)>,
) -> Result<()> {
    let batch = scorer.batch();
    let mut pending: Vec<Frame> = Vec::with_capacity(batch);
    loop {
        let (full, end) = match rx.recv() {
            Ok(ToScorer::Frame(f)) => {
                pending.push(f);
                (pending.len() >= batch, false)
            }
            Ok(ToScorer::Flush) => (true, false),
            Err(_) => (true, true),
        };
        if full && !pending.is_empty() {
            let scores = scorer.score(&pending)?;
            for (f, s) in pending.drain(..).zip(scores) {
                if tx.send((f.index, s)).is_err() {
                    return Ok(());
                }
            }
        }
        if end {
            return Ok(());
        }
    }
}

/// One frame's pixels at the analysis resolution: an 8-bit gray Mat, or the index of the
/// device buffer the gpu scorer resized it into (valid until its next batch).
enum Pixels {
    Small(Mat),
    Staged(usize),
}

/// Flow + statistic between frames held in slots, on one backend.
enum Engine {
    Gpu {
        flow: Box<FarnebackGpu>,
        stat: MovementGpu,
        /// The scorer's resized-gray buffers (empty unless frames stay on the device).
        staged: Vec<wgpu::Buffer>,
    },
    Opencv {
        params: FarnebackParams,
        frames: Vec<Option<Mat>>,
        field: Option<RotationField>,
    },
}

impl Engine {
    fn load(&mut self, slot: usize, px: Pixels) -> Result<()> {
        match (self, px) {
            (Engine::Gpu { flow, .. }, Pixels::Small(gray)) => flow.load(slot, &gray),
            (Engine::Gpu { flow, staged, .. }, Pixels::Staged(k)) => {
                let buf = staged
                    .get(k)
                    .ok_or_else(|| Error::param("movement", "no device gray staged"))?;
                flow.load_buffer(slot, buf)
            }
            (Engine::Opencv { frames, .. }, Pixels::Small(gray)) => {
                frames[slot] = Some(gray);
                Ok(())
            }
            (Engine::Opencv { .. }, Pixels::Staged(_)) => Err(Error::param(
                "movement",
                "the opencv engine takes gray images, not device buffers",
            )),
        }
    }

    /// Movement statistic (analysis pixels) from slot `from` to slot `to`.
    fn movement(&mut self, from: usize, to: usize, statistic: Statistic) -> Result<f64> {
        match self {
            Engine::Gpu { flow, stat, .. } => {
                flow.flow_between(from, to)?;
                stat.compute(statistic)
            }
            Engine::Opencv {
                params,
                frames,
                field,
            } => {
                let (Some(a), Some(b)) = (&frames[from], &frames[to]) else {
                    return Err(Error::param("slots", "frame not loaded"));
                };
                let f = farneback::opencv(a, b, params, None)?;
                movement::cpu_flow(&f, statistic, field.as_ref())
            }
        }
    }
}

/// The movement state a checkpoint keeps: everything `MovementPass` needs to go on after the
/// frame `anchor` (whose pixels, and those of `reference`, are decoded again on resume).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MovementState {
    /// Consecutive movement of frames 0..=anchor.
    pub values: Vec<f64>,
    /// The last frame flow was measured to (a stride point).
    pub anchor: usize,
    /// The stationary sampler's reference frame.
    pub reference: Option<usize>,
    /// Movement accumulated by the stationary sampler since its last keyframe.
    pub accumulated: f64,
    /// Keyframes chosen by the stationary sampler so far.
    pub keys: Vec<usize>,
}

/// Per-frame movement: consecutive movement (every `stride` frames, spread evenly over the
/// frames in between) and the stationary reference mode.
struct MovementPass {
    req: MovementRequest,
    stationary: Option<StationaryRequest>,
    engine: Engine,
    size: (i32, i32),
    scale: f64,
    values: Vec<f64>,
    /// (slot, frame index) of the last stride point.
    anchor: Option<(usize, usize)>,
    /// (slot, frame index) of the stationary reference.
    reference: Option<(usize, usize)>,
    /// The last frame, when it is not a stride point: loaded in a slot, or its pixels kept.
    last: Option<(Option<usize>, usize, Option<Pixels>)>,
    accumulated: f64,
    keys: Vec<usize>,
}

impl MovementPass {
    fn new(
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
        let (w, h) = analysis_size(meta.width, meta.height, req.analysis_width);
        let mut used = Backend::Opencv;
        let mut engine = Engine::Opencv {
            params: req.farneback,
            frames: vec![None; SLOTS],
            field: req
                .derotate
                .map(|d| RotationField::new(w, h, d))
                .transpose()?,
        };
        if let (Backend::Gpu, Some(ctx)) = (backend, ctx) {
            let made = FarnebackGpu::new(ctx.clone(), req.farneback, w, h).and_then(|flow| {
                let stat = MovementGpu::new(ctx.clone(), flow.flow_buffer(), w, h, req.derotate)?;
                Ok(Engine::Gpu {
                    flow: Box::new(flow),
                    stat,
                    staged: Vec::new(),
                })
            });
            match made {
                Ok(e) => {
                    engine = e;
                    used = Backend::Gpu;
                }
                Err(e) => log::warn!("{e}; movement uses the opencv backend"),
            }
        }
        Ok((
            MovementPass {
                req,
                stationary,
                engine,
                size: (w as i32, h as i32),
                scale: f64::from(meta.width) / f64::from(w),
                values: Vec::new(),
                anchor: None,
                reference: None,
                last: None,
                accumulated: 0.0,
                keys: Vec::new(),
            },
            used,
        ))
    }

    /// Gray at the analysis resolution (cv::cvtColor, then INTER_AREA unless the size matches).
    fn prepare(size: (i32, i32), image: &Mat) -> Result<Mat> {
        let gray = crate::kernels::gray::opencv(image)?;
        if (gray.cols(), gray.rows()) == size {
            Ok(gray)
        } else {
            farneback::resize_area(&gray, opencv::core::Size::new(size.0, size.1))
        }
    }

    /// Whether frames may reach the gpu engine as device buffers resized from `frame` (width,
    /// height) by resize_area: a gpu engine and an integer downscale (others keep `prepare`).
    fn can_stage(&self, frame: (u32, u32)) -> bool {
        matches!(self.engine, Engine::Gpu { .. })
            && resize_area::factors(frame, (self.size.0 as u32, self.size.1 as u32)).is_some()
    }

    /// Frames will come as [`Pixels::Staged`] indices into `buffers`.
    fn use_staged(&mut self, buffers: Vec<wgpu::Buffer>) {
        if let Engine::Gpu { staged, .. } = &mut self.engine {
            *staged = buffers;
        }
    }

    /// A slot holding neither the anchor nor the reference.
    fn free_slot(&self) -> usize {
        let busy = [self.anchor.map(|a| a.0), self.reference.map(|r| r.0)];
        (0..SLOTS).find(|s| !busy.contains(&Some(*s))).unwrap_or(0)
    }

    /// Whether the state is complete through the last frame stepped (a checkpoint may be taken).
    fn at_stride_point(&self) -> bool {
        self.last.is_none()
    }

    fn state(&self) -> Option<MovementState> {
        let (_, anchor) = self.anchor?;
        Some(MovementState {
            values: self.values.clone(),
            anchor,
            reference: self.reference.map(|r| r.1),
            accumulated: self.accumulated,
            keys: self.keys.clone(),
        })
    }

    /// Restores a checkpoint's state; the anchor and reference pixels follow through `prime`.
    fn restore(&mut self, st: &MovementState) {
        self.values = st.values.clone();
        self.accumulated = st.accumulated;
        self.keys = st.keys.clone();
        self.anchor = None;
        self.reference = None;
        self.last = None;
    }

    /// Loads the pixels of a restored anchor or reference frame.
    fn prime(&mut self, index: usize, small: Pixels, st: &MovementState) -> Result<()> {
        let slot = self.free_slot();
        self.engine.load(slot, small)?;
        if index == st.anchor {
            self.anchor = Some((slot, index));
        }
        if st.reference == Some(index) {
            self.reference = Some((slot, index));
        }
        Ok(())
    }

    /// Movement since the anchor, spread evenly over the frames after it, up to `slot`/`i`.
    fn measure_to(&mut self, slot: usize, i: usize) -> Result<Option<f64>> {
        let stat = self.req.statistic;
        match self.anchor {
            None => {
                self.values.push(0.0);
                self.anchor = Some((slot, i));
                Ok(None)
            }
            Some((a_slot, a)) => {
                let m = self.engine.movement(a_slot, slot, stat)? * self.scale;
                let per = m / (i - a) as f64;
                self.values.extend(std::iter::repeat_n(per, i - a));
                self.anchor = Some((slot, i));
                Ok((i - a == 1).then_some(m))
            }
        }
    }

    fn step(&mut self, i: usize, small: Pixels) -> Result<()> {
        let active = self
            .stationary
            .filter(|st| (st.first..=st.last).contains(&i));
        let stride_point = self.anchor.is_none() || i % self.req.stride as usize == 0;
        if !stride_point && active.is_none() {
            self.last = Some((None, i, Some(small)));
            return Ok(());
        }
        let cur = self.free_slot();
        self.engine.load(cur, small)?;
        self.last = None;
        let consecutive = if stride_point {
            self.measure_to(cur, i)?
        } else {
            self.last = Some((Some(cur), i, None));
            None
        };
        if let Some(st) = active {
            let stat = self.req.statistic;
            match self.reference {
                None => {
                    self.keys.push(i);
                    self.reference = Some((cur, i));
                    self.accumulated = 0.0;
                }
                Some((slot, index)) => {
                    let m = match consecutive {
                        Some(m) if index + 1 == i => m,
                        _ => self.engine.movement(slot, cur, stat)? * self.scale,
                    };
                    let total = self.accumulated + m;
                    if total >= st.threshold {
                        self.keys.push(i);
                        self.reference = Some((cur, i));
                        self.accumulated = 0.0;
                    } else if i - index >= st.reset_delta {
                        self.reference = Some((cur, i));
                        self.accumulated = total;
                    }
                }
            }
        }
        Ok(())
    }

    /// Measures the frames after the last stride point.
    fn finish(&mut self) -> Result<()> {
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
        Ok(self.engine.movement(0, 1, self.req.statistic)? * self.scale)
    }
}

/// Where and how often a running analysis saves what it computed, to resume after a kill.
#[derive(Debug, Clone)]
pub struct Resume {
    /// The checkpoint file.
    pub path: PathBuf,
    /// The input's fingerprint (a checkpoint of another input is ignored).
    pub fingerprint: Fingerprint,
    /// Seconds between checkpoints.
    pub every_s: f64,
}

/// A running analysis's saved state: frames 0..`frames` are complete.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Checkpoint {
    /// Format version.
    pub version: u32,
    /// The input it belongs to.
    pub fingerprint: Fingerprint,
    /// What was being computed.
    pub request: Request,
    /// Backend that computed it.
    pub backend: Backend,
    /// Frames done.
    pub frames: usize,
    /// Their timestamps.
    pub timestamps_s: Vec<f64>,
    /// Whether every frame so far had a timestamp.
    pub have_timestamps: bool,
    /// Sharpness per metric, one score per frame done.
    pub sharpness: Vec<Vec<f64>>,
    /// Movement state after the last frame done.
    pub movement: Option<MovementState>,
}

const CHECKPOINT_VERSION: u32 = 1;

/// Whether `path` holds a checkpoint of keyframer's (any input, any version it can parse).
pub fn is_checkpoint(path: &Path) -> bool {
    crate::output::read_text(path)
        .ok()
        .and_then(|t| serde_json::from_str::<Checkpoint>(&t).ok())
        .is_some()
}

fn load_checkpoint(resume: &Resume, req: &Request) -> Option<Checkpoint> {
    let bytes = crate::output::read_text(&resume.path).ok()?.into_bytes();
    let c: Checkpoint = match serde_json::from_slice(&bytes) {
        Ok(c) => c,
        Err(e) => {
            log::warn!(
                "{}: unreadable checkpoint ({e}); starting over",
                resume.path.display()
            );
            return None;
        }
    };
    let fits = c.version == CHECKPOINT_VERSION
        && c.fingerprint == resume.fingerprint
        && &c.request == req
        && c.sharpness.len() == req.sharpness.len()
        && c.sharpness.iter().all(|s| s.len() == c.frames)
        && c.timestamps_s.len() == if c.have_timestamps { c.frames } else { 0 }
        && c.movement.is_some() == req.movement.is_some()
        && c.movement
            .as_ref()
            .is_none_or(|m| m.values.len() == c.frames && m.anchor + 1 == c.frames);
    if !fits {
        log::info!(
            "{}: checkpoint is for another input or request; starting over",
            resume.path.display()
        );
        return None;
    }
    Some(c)
}

/// Scores the `pending` frames with the staging scorer (which also leaves frame k's resized gray
/// in its small buffer k) and hands them on with their pixels and scores, in order.
#[allow(clippy::type_complexity)]
fn staged_batch(
    scorer: &mut Scorer,
    pending: &mut Vec<Frame>,
) -> Result<Vec<(Frame, Option<Pixels>, Option<Vec<f64>>)>> {
    let scores = scorer.score(pending)?;
    Ok(pending
        .drain(..)
        .zip(scores)
        .enumerate()
        .map(|(k, (f, s))| (f, Some(Pixels::Staged(k)), Some(s)))
        .collect())
}

/// Items from the decode thread.
enum Decoded {
    /// A frame to analyse (`image` is empty when no sharpness is requested).
    Frame(Frame, Option<Mat>),
    /// An already analysed frame whose pixels a resumed movement state needs again: its
    /// analysis gray, or the frame itself when frames are staged on the device.
    Prime(usize, Mat),
}

/// Decodes `src` in its own thread: frames before `resume_at` are skipped (grabbed) except
/// `prime`; every frame is converted to the analysis gray when `small` is given.
fn decode_worker(
    src: &mut dyn FrameSource,
    resume_at: usize,
    prime: &[usize],
    small: Option<(i32, i32)>,
    keep_image: bool,
    tx: SyncSender<Result<Decoded>>,
) {
    let mut next = 0usize;
    loop {
        let item = if next < resume_at && !prime.contains(&next) {
            match src.skip_frame() {
                Ok(Some(_)) => {
                    next += 1;
                    continue;
                }
                Ok(None) => return,
                Err(e) => Err(e),
            }
        } else {
            match src.next_frame() {
                Ok(None) => return,
                Ok(Some(mut f)) => {
                    next = f.index + 1;
                    let gray = small
                        .map(|s| MovementPass::prepare(s, &f.image))
                        .transpose();
                    gray.map(|g| {
                        if f.index < resume_at {
                            // Without `small` the frame itself goes (staged on the device).
                            Decoded::Prime(
                                f.index,
                                g.unwrap_or_else(|| std::mem::take(&mut f.image)),
                            )
                        } else {
                            if !keep_image {
                                f.image = Mat::default();
                            }
                            Decoded::Frame(f, g)
                        }
                    })
                }
                Err(e) => Err(e),
            }
        };
        let stop = item.is_err();
        if tx.send(item).is_err() || stop {
            return;
        }
    }
}

/// Runs one pass over `input`. `ctx` is the GPU context when the gpu backend is in use.
pub fn analyse(
    input: &Path,
    opts: &OpenOptions,
    req: &Request,
    backend: Backend,
    ctx: Option<&Arc<GpuContext>>,
    quiet: bool,
) -> Result<Analysis> {
    analyse_with(input, opts, req, backend, ctx, quiet, None)
}

/// As [`analyse`], saving a checkpoint to `resume` periodically and resuming from it when it
/// matches the input and request. The decode thread, the sharpness worker and the movement
/// pass (this thread) overlap; queues between them are a few frames long.
pub fn analyse_with(
    input: &Path,
    opts: &OpenOptions,
    req: &Request,
    backend: Backend,
    ctx: Option<&Arc<GpuContext>>,
    quiet: bool,
    resume: Option<&Resume>,
) -> Result<Analysis> {
    let mut src = source::open(input, opts)?;
    let declared = src.metadata().frame_count as u64;
    if req.stationary.is_some() && req.movement.is_none() {
        return Err(Error::param("stationary", "needs a movement request"));
    }
    if req.sharpness.is_empty() && req.movement.is_none() {
        return scan_only(src.as_mut(), input, declared, quiet);
    }
    let meta = src.metadata().clone();
    let mut used = Backend::Opencv;
    let mut moving = match req.movement {
        Some(m) => {
            let (pass, b) = MovementPass::new(m, req.stationary, backend, ctx, &meta)?;
            used = b;
            Some(pass)
        }
        None => None,
    };
    let mut scorer = if req.sharpness.is_empty() {
        None
    } else {
        let (s, b) = Scorer::new(backend, ctx, &req.sharpness, &meta)?;
        if moving.is_none() || b == Backend::Opencv {
            used = b;
        }
        Some(s)
    };
    let restored = resume.and_then(|r| load_checkpoint(r, req)).filter(|c| {
        let same = c.backend == used;
        if !same {
            log::info!(
                "the checkpoint was computed by the {} backend; starting over",
                c.backend
            );
        }
        same
    });
    let mut timestamps = Vec::new();
    let mut have_ts = true;
    let mut scores: Vec<Vec<f64>> = vec![Vec::new(); req.sharpness.len()];
    let mut resume_at = 0usize;
    let mut prime = Vec::new();
    if let Some(c) = &restored {
        log::info!(
            "resuming the analysis of {} at frame {} (checkpoint {})",
            input.display(),
            c.frames,
            resume
                .map(|r| r.path.display().to_string())
                .unwrap_or_default()
        );
        timestamps = c.timestamps_s.clone();
        have_ts = c.have_timestamps;
        scores = c.sharpness.clone();
        resume_at = c.frames;
        if let (Some(m), Some(st)) = (moving.as_mut(), &c.movement) {
            m.restore(st);
            prime = [Some(st.anchor), st.reference]
                .into_iter()
                .flatten()
                .collect();
        }
    }
    // gpu backend, integer downscale: each frame is uploaded once, its gray computed once on the
    // device for the sharpness kernel and resized there for Farneback; scoring and movement then
    // run batch by batch on this thread, in frame order.
    let mut staged = false;
    if let (Some(s), Some(m)) = (scorer.as_mut(), moving.as_mut()) {
        if m.can_stage((meta.width, meta.height)) {
            match s.attach_resize((m.size.0 as u32, m.size.1 as u32)) {
                Ok(Some(buffers)) => {
                    m.use_staged(buffers);
                    staged = true;
                }
                Ok(None) => {}
                Err(e) => log::warn!("{e}; the analysis gray is resized on the CPU"),
            }
        }
    }
    let small = moving.as_ref().filter(|_| !staged).map(|m| m.size);
    let mut inline = if staged { scorer.take() } else { None };
    let inline_batch = inline.as_ref().map_or(1, Scorer::batch);
    let bar = crate::progress::bar(declared, "analyse", quiet);
    bar.set_position(resume_at as u64);
    bar.reset_eta();
    let mut count = resume_at;
    let mut last_save = Instant::now();
    let outcome: Result<()> = std::thread::scope(|scope| {
        let (dtx, drx) = sync_channel::<Result<Decoded>>(DECODE_QUEUE);
        let keep_image = scorer.is_some() || inline.is_some();
        let src_ref = src.as_mut();
        let prime_ref = &prime;
        scope.spawn(move || decode_worker(src_ref, resume_at, prime_ref, small, keep_image, dtx));
        let (stx, srx) = sync_channel::<ToScorer>(scorer.as_ref().map_or(1, |s| s.batch()));
        let (rtx, rrx) = channel::<(usize, Vec<f64>)>();
        let worker = scorer.map(|s| scope.spawn(move || scorer_worker(s, srx, rtx)));
        let drain = |scores: &mut Vec<Vec<f64>>, upto: usize| -> Result<()> {
            if scores.is_empty() {
                return Ok(());
            }
            while scores.first().map_or(0, Vec::len) < upto {
                let Ok((_, s)) = rrx.recv() else {
                    return Err(Error::Gpu("the sharpness worker stopped".into()));
                };
                for (o, v) in scores.iter_mut().zip(s) {
                    o.push(v);
                }
            }
            while let Ok((_, s)) = rrx.try_recv() {
                for (o, v) in scores.iter_mut().zip(s) {
                    o.push(v);
                }
            }
            Ok(())
        };
        let run = (|| -> Result<()> {
            let mut pending: Vec<Frame> = Vec::with_capacity(inline_batch);
            // `None` marks the end of the input (the last staged batch is scored then).
            for item in drx.into_iter().map(Some).chain(std::iter::once(None)) {
                let ready: Vec<(Frame, Option<Pixels>, Option<Vec<f64>>)> = match item {
                    Some(item) => match item? {
                        Decoded::Prime(i, g) => {
                            if let (Some(m), Some(c)) = (moving.as_mut(), &restored) {
                                if let Some(st) = &c.movement {
                                    let px = match inline.as_mut() {
                                        Some(sc) => {
                                            sc.stage(&g)?;
                                            Pixels::Staged(0)
                                        }
                                        None => Pixels::Small(g),
                                    };
                                    m.prime(i, px, st)?;
                                }
                            }
                            continue;
                        }
                        Decoded::Frame(f, g) => match inline.as_mut() {
                            Some(_) if pending.len() + 1 < inline_batch => {
                                pending.push(f);
                                continue;
                            }
                            Some(sc) => {
                                pending.push(f);
                                staged_batch(sc, &mut pending)?
                            }
                            None => vec![(f, g.map(Pixels::Small), None)],
                        },
                    },
                    None => match inline.as_mut() {
                        Some(sc) if !pending.is_empty() => staged_batch(sc, &mut pending)?,
                        _ => break,
                    },
                };
                for (f, px, frame_scores) in ready {
                    let i = f.index;
                    have_ts &= f.timestamp_s.is_some();
                    timestamps.extend(f.timestamp_s);
                    if let (Some(m), Some(px)) = (moving.as_mut(), px) {
                        m.step(i, px)?;
                    }
                    if let Some(fs) = frame_scores {
                        for (o, v) in scores.iter_mut().zip(fs) {
                            o.push(v);
                        }
                    }
                    if worker.is_some() {
                        stx.send(ToScorer::Frame(f))
                            .map_err(|_| Error::Gpu("the sharpness worker stopped".into()))?;
                        drain(&mut scores, 0)?;
                    }
                    count = i + 1;
                    bar.set_position(count as u64);
                    let due = resume.filter(|r| {
                        r.every_s > 0.0 && last_save.elapsed().as_secs_f64() >= r.every_s
                    });
                    if let Some(r) = due {
                        if moving.as_ref().is_none_or(|m| m.at_stride_point()) {
                            if worker.is_some() {
                                stx.send(ToScorer::Flush).map_err(|_| {
                                    Error::Gpu("the sharpness worker stopped".into())
                                })?;
                                drain(&mut scores, count)?;
                            }
                            save_checkpoint(
                                r,
                                req,
                                used,
                                count,
                                &timestamps,
                                have_ts,
                                &scores,
                                moving.as_ref(),
                            )?;
                            last_save = Instant::now();
                        }
                    }
                }
            }
            Ok(())
        })();
        drop(stx);
        let worked = worker.map(|w| {
            w.join()
                .unwrap_or_else(|_| Err(Error::Gpu("the sharpness worker panicked".into())))
        });
        run?;
        if let Some(w) = worked {
            w?;
        }
        drain(&mut scores, count)?;
        Ok(())
    });
    let outcome = outcome.map_err(|e| with_path(e, input));
    bar.finish_and_clear();
    outcome?;
    if let Some(m) = moving.as_mut() {
        m.finish().map_err(|e| with_path(e, input))?;
    }
    let mut metadata = src.metadata().clone();
    finish_metadata(&mut metadata, input, count, have_ts, &timestamps);
    let problems = problems_of(src.as_ref(), input);
    Ok(Analysis {
        metadata,
        timestamps_s: have_ts.then_some(timestamps),
        sharpness: req.sharpness.iter().copied().zip(scores).collect(),
        movement: moving.as_ref().map(|m| MovementSeries {
            width: m.size.0 as u32,
            height: m.size.1 as u32,
            scale_to_full: m.scale,
            values: m.values.clone(),
        }),
        stationary: moving
            .as_ref()
            .filter(|m| m.stationary.is_some())
            .map(|m| m.keys.clone()),
        problems,
        damaged: damaged_of(src.as_ref()),
        backend: used,
    })
}

#[allow(clippy::too_many_arguments)]
fn save_checkpoint(
    r: &Resume,
    req: &Request,
    backend: Backend,
    frames: usize,
    timestamps: &[f64],
    have_ts: bool,
    scores: &[Vec<f64>],
    moving: Option<&MovementPass>,
) -> Result<()> {
    let c = Checkpoint {
        version: CHECKPOINT_VERSION,
        fingerprint: r.fingerprint.clone(),
        request: req.clone(),
        backend,
        frames,
        timestamps_s: if have_ts {
            timestamps.to_vec()
        } else {
            Vec::new()
        },
        have_timestamps: have_ts,
        sharpness: scores
            .iter()
            .map(|s| s[..frames.min(s.len())].to_vec())
            .collect(),
        movement: moving.and_then(MovementPass::state),
    };
    let bytes = serde_json::to_vec(&c).map_err(|e| Error::Output {
        path: r.path.clone(),
        msg: e.to_string(),
    })?;
    crate::fsutil::write_atomic(&r.path, &bytes)?;
    log::debug!("checkpoint: {frames} frames -> {}", r.path.display());
    Ok(())
}

/// Frame count and timestamps only: frames are grabbed, never converted.
fn scan_only(
    src: &mut dyn FrameSource,
    input: &Path,
    declared: u64,
    quiet: bool,
) -> Result<Analysis> {
    let bar = crate::progress::bar(declared, "scan", quiet);
    let mut timestamps = Vec::new();
    let mut have_ts = true;
    let mut count = 0usize;
    while let Some((_, t)) = src.skip_frame()? {
        have_ts &= t.is_some();
        timestamps.extend(t);
        count += 1;
        bar.set_position(count as u64);
    }
    bar.finish_and_clear();
    let mut metadata = src.metadata().clone();
    finish_metadata(&mut metadata, input, count, have_ts, &timestamps);
    let problems = problems_of(src, input);
    Ok(Analysis {
        metadata,
        timestamps_s: have_ts.then_some(timestamps),
        sharpness: Vec::new(),
        movement: None,
        stationary: None,
        problems,
        damaged: damaged_of(src),
        backend: Backend::Opencv,
    })
}

fn finish_metadata(
    metadata: &mut Metadata,
    input: &Path,
    count: usize,
    have_ts: bool,
    timestamps: &[f64],
) {
    if metadata.frame_count != count {
        log::info!(
            "{}: the container declares {} frames, decoding found {count}",
            input.display(),
            metadata.frame_count
        );
        metadata.frame_count = count;
    }
    metadata.frame_count_exact = true;
    if let (true, Some(fps), Some(first), Some(last)) =
        (have_ts, metadata.fps, timestamps.first(), timestamps.last())
    {
        metadata.duration_s = Some(last - first + 1.0 / fps);
    }
}

fn problems_of(src: &dyn FrameSource, input: &Path) -> Vec<String> {
    let problems: Vec<String> = src.decode_failure().into_iter().map(|(_, m)| m).collect();
    for p in &problems {
        log::warn!("{}: {p}", input.display());
    }
    // Damaged images were logged by the source when met.
    src.damaged_frames()
        .into_iter()
        .map(|(_, m)| m)
        .chain(problems)
        .collect()
}

fn damaged_of(src: &dyn FrameSource) -> Vec<usize> {
    src.damaged_frames().into_iter().map(|(i, _)| i).collect()
}

fn with_path(e: crate::Error, input: &Path) -> crate::Error {
    match e {
        crate::Error::Frame { path, index, msg } if path.as_os_str().is_empty() => {
            crate::Error::Frame {
                path: input.to_path_buf(),
                index,
                msg,
            }
        }
        other => other,
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
    let (mut pass, _) = MovementPass::new(req, None, backend, ctx, &meta)?;
    let mut prev: Option<(usize, Mat)> = None;
    let mut out = Vec::new();
    source::read_indices(src.as_mut(), &indices, |f| {
        let small = MovementPass::prepare(pass.size, &f.image)?;
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
