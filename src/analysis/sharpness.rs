//! Sharpness: one engine (gpu or opencv, behind [`SharpnessEngine`]) scores frames in batches,
//! in a worker thread that hands `(frame, scores per metric)` back in frame order. With a row
//! band (360° frames), both engines score the band as an image of its own.

use crate::error::{CvContext, Error, Result};
use crate::gpu::GpuContext;
use crate::kernels::sharpness::{score_gray, SharpnessGpu};
use crate::params::{Backend, Metric, Rows};
use crate::source::{Frame, Metadata};
use opencv::core::{Mat, Rect};
use opencv::prelude::{MatTraitConst, MatTraitConstManual};
use std::collections::VecDeque;
use std::sync::mpsc::{channel, sync_channel, Receiver, Sender, SyncSender};
use std::sync::Arc;
use std::thread::{Scope, ScopedJoinHandle};

/// Frames held at most at once by the opencv engine before scoring: one, so each frame is
/// scored as soon as it comes (the worker's queue still holds [`QUEUE`] frames).
const CPU_BATCH: usize = 1;

/// Frames the worker's queue holds (or one batch, where an engine's batch is larger), so that a
/// frame handed on while the worker scores does not hold up the pump.
const QUEUE: usize = 4;

/// Scores frames with every requested metric.
pub(crate) trait SharpnessEngine: Send {
    /// Frames scored together.
    fn batch(&self) -> usize;
    /// Starts scoring `frames`, after the frames submitted before.
    fn submit(&mut self, frames: &[Frame]) -> Result<()>;
    /// The scores of submitted frames that are done, in frame order, one vector per frame with
    /// one score per metric; with `all`, of every submitted frame (waits for them).
    fn take(&mut self, all: bool) -> Result<Vec<Vec<f64>>>;
    /// Also resizes every frame's device gray to `size` (resize_area) into small device buffers,
    /// one per batch position; `None` when the engine keeps no frames on a device.
    fn attach_resize(&mut self, _size: (u32, u32)) -> Result<Option<Vec<wgpu::Buffer>>> {
        Ok(None)
    }
    /// Uploads one frame and computes its gray and resized gray (into small buffer 0) without
    /// keeping its scores (priming a resumed movement state).
    fn stage(&mut self, _image: &Mat) -> Result<()> {
        Ok(())
    }
    /// Whether the engine scores a frame's 8-bit gray as well as its BGR image (the same
    /// scores), so the decode thread may hand on the gray it made.
    fn scores_gray(&self) -> bool {
        false
    }
}

/// The engine for `backend`: the gpu one when it can be made (else a warning and opencv),
/// scoring `rows` of every frame (None: all of it).
pub(crate) fn engine(
    backend: Backend,
    ctx: Option<&Arc<GpuContext>>,
    metrics: &[Metric],
    rows: Option<Rows>,
    meta: &Metadata,
) -> (Box<dyn SharpnessEngine>, Backend) {
    if let (Backend::Gpu, Some(ctx)) = (backend, ctx) {
        let height = rows.map_or(meta.height, |r| r.count);
        let runners = metrics
            .iter()
            .map(|&m| SharpnessGpu::new(ctx.clone(), m, meta.width, height))
            .collect::<Result<Vec<_>>>();
        match runners {
            Ok(r) => {
                let ahead = vec![VecDeque::new(); r.len()];
                return (Box::new(Gpu(r, ahead, rows)), Backend::Gpu);
            }
            Err(e) => log::warn!("{e}; using the opencv backend"),
        }
    }
    let cpu = Opencv {
        metrics: metrics.to_vec(),
        rows,
        scores: Vec::new(),
    };
    (Box::new(cpu), Backend::Opencv)
}

/// The bytes of rows `r` of an 8-bit BGR `image`: in place when it is continuous (decoded
/// frames are), else copied.
fn band_bytes(image: &Mat, r: Rows) -> Result<std::borrow::Cow<'_, [u8]>> {
    r.check(image.rows().max(0) as u32)?;
    if image.typ() != opencv::core::CV_8UC3 {
        let msg = format!(
            "frame of type {}: the gpu engine scores 8-bit BGR",
            image.typ()
        );
        return Err(Error::gpu(msg));
    }
    let rect = Rect::new(0, r.first as i32, image.cols(), r.count as i32);
    if image.is_continuous() {
        let bytes = image.data_bytes().cv(|| "frame bytes".into())?;
        let row = image.cols().max(0) as usize * 3;
        let (a, b) = (r.first as usize * row, (r.first + r.count) as usize * row);
        if let Some(band) = bytes.get(a..b) {
            return Ok(std::borrow::Cow::Borrowed(band));
        }
    }
    let roi = image.roi(rect).cv(|| "sharpness rows".into())?;
    let copy = roi.clone_pointee();
    Ok(std::borrow::Cow::Owned(
        copy.data_bytes().cv(|| "band bytes".into())?.to_vec(),
    ))
}

/// The 8-bit gray of rows `r` of a BGR or gray frame, as an image of its own (its first and
/// last rows mirror inside it, as on the device).
fn band_gray(image: &Mat, r: Rows) -> Result<Mat> {
    r.check(image.rows().max(0) as u32)?;
    let rect = Rect::new(0, r.first as i32, image.cols(), r.count as i32);
    let roi = image.roi(rect).cv(|| "sharpness rows".into())?;
    if image.channels() == 1 {
        return Ok(roi.clone_pointee());
    }
    let mut gray = Mat::default();
    opencv::imgproc::cvt_color(&roi, &mut gray, opencv::imgproc::COLOR_BGR2GRAY, 0)
        .cv(|| "cvtColor BGR2GRAY".into())?;
    Ok(gray)
}

/// The WGSL kernels, one runner per metric, the scores of runners ahead of the others and the
/// rows scored.
struct Gpu(Vec<SharpnessGpu>, Vec<VecDeque<f64>>, Option<Rows>);

impl SharpnessEngine for Gpu {
    fn batch(&self) -> usize {
        self.0.iter().map(|g| g.batch_size()).min().unwrap_or(1)
    }

    fn submit(&mut self, frames: &[Frame]) -> Result<()> {
        let Some(rows) = self.2 else {
            let mats: Vec<&Mat> = frames.iter().map(|f| &f.image).collect();
            return self.0.iter_mut().try_for_each(|r| r.submit(&mats));
        };
        let bands = (frames.iter())
            .map(|f| band_bytes(&f.image, rows))
            .collect::<Result<Vec<_>>>()?;
        let bands: Vec<&[u8]> = bands.iter().map(|b| &**b).collect();
        self.0.iter_mut().try_for_each(|r| r.submit(&bands))
    }

    fn take(&mut self, all: bool) -> Result<Vec<Vec<f64>>> {
        for (r, ahead) in self.0.iter_mut().zip(self.1.iter_mut()) {
            ahead.extend(r.take(all)?);
        }
        let ready = self.1.iter().map(VecDeque::len).min().unwrap_or(0);
        Ok((0..ready)
            .map(|_| self.1.iter_mut().filter_map(VecDeque::pop_front).collect())
            .collect())
    }

    fn attach_resize(&mut self, size: (u32, u32)) -> Result<Option<Vec<wgpu::Buffer>>> {
        // A band's gray is not the frame's: the movement pass then resizes on the CPU.
        if self.2.is_some() {
            return Ok(None);
        }
        self.0
            .first_mut()
            .map(|r| r.attach_resize(size))
            .transpose()
    }

    fn stage(&mut self, image: &Mat) -> Result<()> {
        let Some(first) = self.0.first_mut() else {
            return Ok(());
        };
        match self.2 {
            Some(rows) => first.scores(&[&*band_bytes(image, rows)?]).map(drop),
            None => first.scores(&[image]).map(drop),
        }
    }
}

/// OpenCV's twins of the kernels, frame by frame, on `rows` of each, and the scores not taken
/// yet.
struct Opencv {
    metrics: Vec<Metric>,
    rows: Option<Rows>,
    scores: Vec<Vec<f64>>,
}

impl SharpnessEngine for Opencv {
    fn batch(&self) -> usize {
        CPU_BATCH
    }

    fn submit(&mut self, frames: &[Frame]) -> Result<()> {
        for f in frames {
            let at = |e: Error| Error::frame(std::path::PathBuf::new(), f.index, e.to_string());
            // Tenengrad alone on a whole BGR frame: gray and gradients in one pass.
            if self.rows.is_none() && f.image.channels() == 3 && self.metrics == [Metric::Tenengrad]
            {
                let score = crate::kernels::tenengrad::host_bgr(&f.image).map_err(at)?;
                self.scores.push(vec![score]);
                continue;
            }
            let converted = match (self.rows, f.image.channels()) {
                (Some(r), _) => Some(band_gray(&f.image, r).map_err(at)?),
                (None, 1) => None,
                (None, _) => Some(crate::kernels::gray::host(&f.image).map_err(at)?),
            };
            let gray = converted.as_ref().unwrap_or(&f.image);
            let scores = self
                .metrics
                .iter()
                .map(|&m| score_gray(gray, m).map_err(at));
            self.scores.push(scores.collect::<Result<_>>()?);
        }
        Ok(())
    }

    fn take(&mut self, _all: bool) -> Result<Vec<Vec<f64>>> {
        Ok(std::mem::take(&mut self.scores))
    }

    fn scores_gray(&self) -> bool {
        true
    }
}

/// Messages to the worker.
enum ToWorker {
    Frame(Frame),
    /// Score what is queued now (a checkpoint waits for it).
    Flush,
}

/// The worker thread scoring frames in batches, and the scores per metric collected from it.
pub(crate) struct Worker<'scope> {
    tx: SyncSender<ToWorker>,
    rx: Receiver<(usize, Vec<f64>)>,
    thread: ScopedJoinHandle<'scope, Result<()>>,
}

impl<'scope> Worker<'scope> {
    /// Starts the worker; its queue holds one batch, and at least [`QUEUE`] frames.
    pub(crate) fn spawn<'env>(
        scope: &'scope Scope<'scope, 'env>,
        engine: Box<dyn SharpnessEngine>,
    ) -> Worker<'scope> {
        let (tx, wrx) = sync_channel::<ToWorker>(engine.batch().max(QUEUE));
        let (wtx, rx) = channel::<(usize, Vec<f64>)>();
        let thread = scope.spawn(move || work(engine, wrx, wtx));
        Worker { tx, rx, thread }
    }

    /// Queues `frame` and takes the scores that are ready into `scores`.
    pub(crate) fn send(&self, frame: Frame, scores: &mut [Vec<f64>]) -> Result<()> {
        self.tx
            .send(ToWorker::Frame(frame))
            .map_err(|_| stopped())?;
        drain(&self.rx, scores, 0)
    }

    /// Scores every queued frame; `scores` then hold `upto` frames.
    pub(crate) fn flush(&self, scores: &mut [Vec<f64>], upto: usize) -> Result<()> {
        self.tx.send(ToWorker::Flush).map_err(|_| stopped())?;
        drain(&self.rx, scores, upto)
    }

    /// Ends the worker after the frame loop (`run`), then takes the last scores: `scores` hold
    /// `upto` frames. The loop's error comes first, then the worker's.
    pub(crate) fn finish(
        self,
        run: Result<()>,
        scores: &mut [Vec<f64>],
        upto: usize,
    ) -> Result<()> {
        drop(self.tx);
        let worked = self
            .thread
            .join()
            .unwrap_or_else(|_| Err(Error::gpu("the sharpness worker panicked")));
        run?;
        worked?;
        drain(&self.rx, scores, upto)
    }
}

/// Takes scores from the worker until `scores` hold `upto` frames, then whatever is ready.
fn drain(rx: &Receiver<(usize, Vec<f64>)>, scores: &mut [Vec<f64>], upto: usize) -> Result<()> {
    if scores.is_empty() {
        return Ok(());
    }
    while scores.first().map_or(0, Vec::len) < upto {
        let Ok((_, s)) = rx.recv() else {
            return Err(stopped());
        };
        push_scores(scores, s);
    }
    while let Ok((_, s)) = rx.try_recv() {
        push_scores(scores, s);
    }
    Ok(())
}

/// Appends one frame's scores (one per metric) to the per-metric series.
pub(crate) fn push_scores(scores: &mut [Vec<f64>], frame: Vec<f64>) {
    for (o, v) in scores.iter_mut().zip(frame) {
        o.push(v);
    }
}

fn stopped() -> Error {
    Error::gpu("the sharpness worker stopped")
}

/// The worker's loop: scores frames in batches, in index order, and sends
/// `(frame index, scores per metric)` back as they come; a flush or the end waits for all.
fn work(
    mut engine: Box<dyn SharpnessEngine>,
    rx: Receiver<ToWorker>,
    tx: Sender<(usize, Vec<f64>)>,
) -> Result<()> {
    let batch = engine.batch();
    let mut pending: Vec<Frame> = Vec::with_capacity(batch);
    let mut queued: VecDeque<usize> = VecDeque::new();
    let mut input = super::priority::Consumer::new("sharpness worker");
    loop {
        let (full, all, end) = match input.recv(&rx) {
            Ok(ToWorker::Frame(f)) => {
                pending.push(f);
                (pending.len() >= batch, false, false)
            }
            Ok(ToWorker::Flush) => (true, true, false),
            Err(_) => (true, true, true),
        };
        if full && !pending.is_empty() {
            engine.submit(&pending)?;
            queued.extend(pending.drain(..).map(|f| f.index));
        }
        if !full {
            continue;
        }
        for s in engine.take(all)? {
            let Some(index) = queued.pop_front() else {
                return Err(Error::gpu("the sharpness engine returned extra scores"));
            };
            if tx.send((index, s)).is_err() {
                return Ok(());
            }
        }
        if end {
            return Ok(());
        }
    }
}
