//! Analysis: one decode pass over an input that yields the exact frame count, every frame's
//! timestamp and the requested per-frame scores. Frames stream through in small batches (bounded
//! memory); when no scores are requested, frames are only grabbed, never converted.

use crate::error::Result;
use crate::gpu::{Backend, GpuContext};
use crate::kernels::sharpness::{score_opencv, Metric, SharpnessGpu};
use crate::source::{self, Frame, Metadata, OpenOptions};
use std::path::Path;
use std::sync::Arc;

/// What to compute.
#[derive(Debug, Clone, Default)]
pub struct Request {
    /// Sharpness metrics to score every frame with.
    pub sharpness: Vec<Metric>,
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
    if req.sharpness.is_empty() {
        while let Some((_, t)) = src.skip_frame()? {
            have_ts &= t.is_some();
            timestamps.extend(t);
            count += 1;
            bar.set_position(count as u64);
        }
    } else {
        let meta = src.metadata().clone();
        let (mut scorer, b) = Scorer::new(backend, ctx, &req.sharpness, &meta)?;
        used = b;
        let batch = scorer.batch();
        let mut pending: Vec<Frame> = Vec::with_capacity(batch);
        loop {
            let next = src.next_frame()?;
            let done = next.is_none();
            if let Some(f) = next {
                have_ts &= f.timestamp_s.is_some();
                timestamps.extend(f.timestamp_s);
                pending.push(f);
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
