//! Analysis: one decode pass over an input that yields the exact frame count, every frame's
//! timestamp and the requested per-frame scores: sharpness, camera movement between consecutive
//! frames, and the stationary sampler's reference-mode selection (which needs pixels because its
//! frame pairs depend on the threshold). Frames stream through in small batches (bounded memory);
//! when nothing needs pixels, frames are only grabbed, never converted.

use crate::error::{Error, Result};
use crate::gpu::{Backend, GpuContext};
use crate::kernels::farneback::{self, FarnebackGpu, FarnebackParams, SLOTS};
use crate::kernels::movement::{self, MovementGpu, Statistic};
use crate::kernels::sharpness::{score_opencv, Metric, SharpnessGpu};
use crate::source::{self, Frame, Metadata, OpenOptions};
use opencv::core::Mat;
use opencv::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::sync::Arc;

/// What to compute.
#[derive(Debug, Clone, Default)]
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
    /// Decode problems (damaged stream), one line each.
    pub problems: Vec<String>,
    /// Backend that computed the scores.
    pub backend: Backend,
}

/// Frames held at most at once by the opencv path before scoring (the gpu path uses its batch).
const CPU_BATCH: usize = 8;

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

    fn batch(&self) -> usize {
        match self {
            Scorer::Gpu(r) => r.iter().map(|g| g.batch_size()).min().unwrap_or(1),
            Scorer::Opencv(_) => CPU_BATCH,
        }
    }

    /// Appends the scores of `frames` to `out` (one vector per metric).
    fn score(&mut self, frames: &[Frame], out: &mut [Vec<f64>]) -> Result<()> {
        let mats: Vec<&opencv::core::Mat> = frames.iter().map(|f| &f.image).collect();
        match self {
            Scorer::Gpu(runners) => {
                for (r, o) in runners.iter_mut().zip(out.iter_mut()) {
                    o.extend(r.scores(&mats)?);
                }
            }
            Scorer::Opencv(metrics) => {
                for (&m, o) in metrics.iter().zip(out.iter_mut()) {
                    for f in frames {
                        o.push(score_opencv(&f.image, m).map_err(|e| crate::Error::Frame {
                            path: Default::default(),
                            index: f.index,
                            msg: e.to_string(),
                        })?);
                    }
                }
            }
        }
        Ok(())
    }
}

/// Flow + statistic between frames held in slots, on one backend.
enum Engine {
    Gpu {
        flow: Box<FarnebackGpu>,
        stat: MovementGpu,
    },
    Opencv {
        params: FarnebackParams,
        frames: Vec<Option<Mat>>,
    },
}

impl Engine {
    fn load(&mut self, slot: usize, gray: Mat) -> Result<()> {
        match self {
            Engine::Gpu { flow, .. } => flow.load(slot, &gray),
            Engine::Opencv { frames, .. } => {
                frames[slot] = Some(gray);
                Ok(())
            }
        }
    }

    /// Movement statistic (analysis pixels) from slot `from` to slot `to`.
    fn movement(&mut self, from: usize, to: usize, statistic: Statistic) -> Result<f64> {
        match self {
            Engine::Gpu { flow, stat } => {
                flow.flow_between(from, to)?;
                stat.compute(statistic)
            }
            Engine::Opencv { params, frames } => {
                let (Some(a), Some(b)) = (&frames[from], &frames[to]) else {
                    return Err(Error::param("slots", "frame not loaded"));
                };
                let f = farneback::opencv(a, b, params, None)?;
                movement::cpu(&movement::magnitudes(&f)?, statistic)
            }
        }
    }
}

/// Per-frame movement state: consecutive movement and the stationary reference mode.
struct MovementPass {
    req: MovementRequest,
    stationary: Option<StationaryRequest>,
    engine: Engine,
    size: (i32, i32),
    scale: f64,
    values: Vec<f64>,
    prev: Option<usize>,
    /// (slot, frame index) of the stationary reference.
    reference: Option<(usize, usize)>,
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
        let (w, h) = analysis_size(meta.width, meta.height, req.analysis_width);
        let mut used = Backend::Opencv;
        let mut engine = Engine::Opencv {
            params: req.farneback,
            frames: vec![None; SLOTS],
        };
        if let (Backend::Gpu, Some(ctx)) = (backend, ctx) {
            let made = FarnebackGpu::new(ctx.clone(), req.farneback, w, h).and_then(|flow| {
                let stat = MovementGpu::new(ctx.clone(), flow.flow_buffer(), w * h)?;
                Ok(Engine::Gpu {
                    flow: Box::new(flow),
                    stat,
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
                prev: None,
                reference: None,
                accumulated: 0.0,
                keys: Vec::new(),
            },
            used,
        ))
    }

    fn step(&mut self, frame: &Frame) -> Result<()> {
        let gray = crate::kernels::gray::opencv(&frame.image)?;
        let small = if (gray.cols(), gray.rows()) == self.size {
            gray
        } else {
            farneback::resize_area(&gray, opencv::core::Size::new(self.size.0, self.size.1))?
        };
        let busy = [self.prev, self.reference.map(|r| r.0)];
        let cur = (0..SLOTS).find(|s| !busy.contains(&Some(*s))).unwrap_or(0);
        self.engine.load(cur, small)?;
        let stat = self.req.statistic;
        let consecutive = match self.prev {
            Some(p) => self.engine.movement(p, cur, stat)? * self.scale,
            None => 0.0,
        };
        self.values.push(consecutive);
        let i = frame.index;
        if let Some(st) = self.stationary {
            if (st.first..=st.last).contains(&i) {
                match self.reference {
                    None => {
                        self.keys.push(i);
                        self.reference = Some((cur, i));
                        self.accumulated = 0.0;
                    }
                    Some((slot, index)) => {
                        let m = if Some(slot) == self.prev && index + 1 == i {
                            consecutive
                        } else {
                            self.engine.movement(slot, cur, stat)? * self.scale
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
        }
        self.prev = Some(cur);
        Ok(())
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
    let mut src = source::open(input, opts)?;
    let declared = src.metadata().frame_count as u64;
    let what = if req.sharpness.is_empty() {
        "scan"
    } else {
        "analyse"
    };
    let bar = crate::progress::bar(declared, what, quiet);
    let mut timestamps = Vec::new();
    let mut have_ts = true;
    let mut scores: Vec<Vec<f64>> = vec![Vec::new(); req.sharpness.len()];
    let mut used = Backend::Opencv;
    let mut count = 0usize;
    if req.stationary.is_some() && req.movement.is_none() {
        return Err(Error::param("stationary", "needs a movement request"));
    }
    let mut moving = match req.movement {
        Some(m) => {
            let (pass, b) = MovementPass::new(m, req.stationary, backend, ctx, src.metadata())?;
            used = b;
            Some(pass)
        }
        None => None,
    };
    if req.sharpness.is_empty() && moving.is_none() {
        while let Some((_, t)) = src.skip_frame()? {
            have_ts &= t.is_some();
            timestamps.extend(t);
            count += 1;
            bar.set_position(count as u64);
        }
    } else {
        let meta = src.metadata().clone();
        let (mut scorer, b) = Scorer::new(backend, ctx, &req.sharpness, &meta)?;
        if !req.sharpness.is_empty() {
            used = b;
        }
        let batch = scorer.batch();
        let mut pending: Vec<Frame> = Vec::with_capacity(batch);
        loop {
            let next = src.next_frame()?;
            let done = next.is_none();
            if let Some(f) = next {
                have_ts &= f.timestamp_s.is_some();
                timestamps.extend(f.timestamp_s);
                if let Some(m) = moving.as_mut() {
                    m.step(&f).map_err(|e| with_path(e, input))?;
                    if req.sharpness.is_empty() {
                        bar.set_position(count as u64 + 1);
                    }
                }
                if !req.sharpness.is_empty() {
                    pending.push(f);
                }
                count += 1;
            }
            if pending.len() == batch || (done && !pending.is_empty()) {
                scorer
                    .score(&pending, &mut scores)
                    .map_err(|e| with_path(e, input))?;
                pending.clear();
                bar.set_position(count as u64);
            }
            if done {
                break;
            }
        }
    }
    bar.finish_and_clear();
    let mut metadata = src.metadata().clone();
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
    let problems: Vec<String> = src.decode_failure().into_iter().map(|(_, m)| m).collect();
    for p in &problems {
        log::warn!("{}: {p}", input.display());
    }
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
        backend: used,
    })
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
    let mut seen = Vec::new();
    source::read_indices(src.as_mut(), &indices, |f| {
        seen.push(f.index);
        pass.step(&f)
    })?;
    Ok(seen
        .iter()
        .enumerate()
        .skip(1)
        .filter(|(k, &i)| seen[k - 1] + 1 == i)
        .map(|(k, _)| pass.values[k])
        .collect())
}
