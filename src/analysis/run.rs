//! The decode pass itself (built with OpenCV): opens the input, streams its frames through the
//! decode thread, the sharpness worker and the movement pass, saves and resumes checkpoints, and
//! assembles the [`Analysis`]. Guarantees the parent module's: one pass, bounded queues, the exact
//! frame count.

use super::checkpoint::{Collected, Saver};
use super::embedding::EmbeddingPass;
use super::ingest::{Decoded, HandOff, Ready};
use super::movement::MovementPass;
use super::sharpness::{SharpnessEngine, Worker};
use super::*;
use crate::embedding_file;
use crate::error::{Error, Result};
use crate::gpu::GpuContext;
use crate::source::{self, FrameSource, OpenOptions};
use indicatif::ProgressBar;
use std::path::Path;
use std::sync::mpsc::Receiver;
use std::sync::Arc;

#[cfg(test)]
#[path = "tests.rs"]
mod tests;

/// Runs one pass over `input`. `ctx` is the GPU context when the gpu backend is in use. With
/// `resume`, saves a checkpoint there periodically and resumes from it when it matches the input
/// and request. The decode thread, the sharpness worker and the movement pass (this thread)
/// overlap; queues between them are a few frames long.
pub fn analyse(
    input: &Path,
    opts: &OpenOptions,
    req: &Request,
    backend: Backend,
    ctx: Option<&Arc<GpuContext>>,
    quiet: bool,
    resume: Option<&Resume>,
) -> Result<Analysis> {
    let src = source::open(input, opts)?;
    analyse_source(src, input, req, backend, ctx, quiet, resume)
}

/// [`analyse`] of a source already opened on `input` and not read yet.
pub fn analyse_source(
    mut src: Box<dyn source::FrameSource>,
    input: &Path,
    req: &Request,
    backend: Backend,
    ctx: Option<&Arc<GpuContext>>,
    quiet: bool,
    resume: Option<&Resume>,
) -> Result<Analysis> {
    if req.stationary.is_some() && req.movement.is_none() {
        return Err(Error::param("stationary", "needs a movement request"));
    }
    if req.sharpness.is_empty() && req.movement.is_none() && req.descriptor.is_none() {
        return scan_only(src.as_mut(), input, quiet);
    }
    let engines = Engines::new(req, backend, ctx, src.metadata())?;
    run(src.as_mut(), input, req, engines, quiet, resume)
}

/// The engines of one analysis and the backend its scores are said to come from.
struct Engines {
    movement: Option<MovementPass>,
    embedding: Option<EmbeddingPass>,
    sharpness: Option<Box<dyn SharpnessEngine>>,
    backend: Backend,
}

impl Engines {
    /// The engines `req` needs on `backend` (each falls back to opencv on its own; the scores
    /// are then said to be opencv's).
    fn new(
        req: &Request,
        backend: Backend,
        ctx: Option<&Arc<GpuContext>>,
        meta: &Metadata,
    ) -> Result<Engines> {
        let opened = (req.movement)
            .map(|m| MovementPass::open(m, req.stationary, backend, ctx, meta))
            .transpose()?;
        let mut used = opened.as_ref().map_or(Backend::Opencv, |(_, b)| *b);
        let movement = opened.map(|(pass, _)| pass);
        let sharpness = (!req.sharpness.is_empty()).then(|| {
            let (s, b) = sharpness::engine(backend, ctx, &req.sharpness, req.sharpness_rows, meta);
            if movement.is_none() || b == Backend::Opencv {
                used = b;
            }
            s
        });
        let embedding = (req.descriptor)
            .map(|w| match &req.network {
                Some(model) => EmbeddingPass::network(model, req.runtime.unwrap_or_default()),
                None => {
                    EmbeddingPass::open(analysis_size(meta.width, meta.height, w), backend, ctx)
                }
            })
            .transpose()?;
        if let Some(e) = embedding
            .as_ref()
            .filter(|_| movement.is_none() && sharpness.is_none())
        {
            used = e.backend();
        }
        Ok(Engines {
            movement,
            embedding,
            sharpness,
            backend: used,
        })
    }
}

/// The pass over `src` with `engines`: resumes from a fitting checkpoint, streams the frames
/// through the decode thread, the hand-off, the movement pass and the sharpness worker.
fn run(
    src: &mut dyn FrameSource,
    input: &Path,
    req: &Request,
    engines: Engines,
    quiet: bool,
    resume: Option<&Resume>,
) -> Result<Analysis> {
    let declared = src.metadata().frame_count as u64;
    let Engines {
        movement: mut moving,
        mut embedding,
        sharpness,
        backend,
    } = engines;
    let (mut done, state) = checkpoint::restore(resume, req, backend, input)
        .unwrap_or_else(|| (Collected::new(req.sharpness.len()), None));
    let embedded = embedding
        .as_ref()
        .map(|e| (e.size, e.backend(), e.runtime()));
    let mut sink = match (embedding.is_some(), &req.store) {
        (true, Some(p)) => Some(embedding_file::Writer::open(p, done.frames)?),
        (true, None) => {
            let msg = "embeddings need a series file to go to (Request::store)";
            return Err(Error::param("descriptor", msg));
        }
        (false, _) => None,
    };
    let prime = match (moving.as_mut(), &state) {
        (Some(m), Some(st)) => {
            m.restore(st);
            st.primed()
        }
        _ => Vec::new(),
    };
    let size = (src.metadata().width, src.metadata().height);
    let (hand_off, worker_engine) = hand_off(sharpness, moving.as_mut(), size);
    let small = moving
        .as_ref()
        .filter(|_| matches!(hand_off, HandOff::Cpu))
        .map(|m| m.size);
    let bar = crate::progress::bar(declared, "analyse", quiet);
    bar.set_position(done.frames as u64);
    bar.reset_eta();
    let saver = Saver::new(resume);
    let outcome = std::thread::scope(|scope| {
        let resume_at = done.frames;
        // The descriptor reads the colour frame: frames then keep it rather than their gray.
        let keep = ingest::Keep {
            small,
            image: !req.sharpness.is_empty() || req.descriptor.is_some(),
            gray: req.descriptor.is_none()
                && worker_engine.as_ref().is_some_and(|e| e.scores_gray()),
        };
        let frames = ingest::spawn_decoder(scope, src, resume_at, &prime, keep);
        // The consumers run on a thread of their own, which may lower its priority (the main
        // thread never does): see `priority`.
        let (moving, embedding, sink, done) = (
            moving.as_mut(),
            embedding.as_mut(),
            sink.as_mut(),
            &mut done,
        );
        let (state, bar) = (state.as_ref(), &bar);
        let consumer = scope.spawn(move || {
            let worker = worker_engine.map(|e| Worker::spawn(scope, e));
            let mut pump = Pump {
                req,
                backend,
                moving,
                embedding,
                sink,
                state,
                worker: worker.as_ref(),
                hand_off,
                done: &mut *done,
                saver,
                bar,
            };
            let run = pump.run(frames);
            match worker {
                Some(w) => w.finish(run, &mut done.scores, done.frames),
                None => run,
            }
        });
        consumer
            .join()
            .unwrap_or_else(|_| Err(Error::param("analysis", "the analysis thread panicked")))
    });
    let outcome = outcome.map_err(|e| with_path(e, input));
    bar.finish_and_clear();
    outcome?;
    if let Some(m) = moving.as_mut() {
        m.finish().map_err(|e| with_path(e, input))?;
    }
    let mut analysis = conclude(src, input, req, done, moving, backend);
    if let (Some(w), Some((size, backend, runtime)), Some(file)) = (sink, embedded, &req.store) {
        let (dim, count) = w.finish()?;
        analysis.embeddings = Some(Embedded {
            file: file.clone(),
            dim,
            count,
            runtime,
            size,
            backend,
        });
    }
    Ok(analysis)
}

/// How frames reach the movement pass: staged on the device when the sharpness engine can
/// resize there for a movement engine on the device (integer downscale of the frame `size`),
/// else prepared on the CPU. Returns the hand-off and the engine left for the worker thread.
fn hand_off(
    mut sharpness: Option<Box<dyn SharpnessEngine>>,
    moving: Option<&mut MovementPass>,
    size: (u32, u32),
) -> (HandOff, Option<Box<dyn SharpnessEngine>>) {
    if let (Some(s), Some(m)) = (sharpness.as_mut(), moving) {
        if m.can_stage(size) {
            match s.attach_resize((m.size.0 as u32, m.size.1 as u32)) {
                Ok(Some(buffers)) => {
                    m.use_staged(buffers);
                    if let Some(engine) = sharpness.take() {
                        let pending = Vec::with_capacity(engine.batch());
                        return (HandOff::Staged { engine, pending }, None);
                    }
                }
                Ok(None) => {}
                Err(e) => log::warn!("{e}; the analysis gray is resized on the CPU"),
            }
        }
    }
    (HandOff::Cpu, sharpness)
}

/// The analysis thread while frames stream through: every frame in order to the movement pass
/// and the sharpness worker, checkpoints when due.
struct Pump<'a, 'scope> {
    req: &'a Request,
    backend: Backend,
    moving: Option<&'a mut MovementPass>,
    embedding: Option<&'a mut EmbeddingPass>,
    /// Where each frame's embedding is appended.
    sink: Option<&'a mut embedding_file::Writer>,
    /// The restored movement state whose frames are primed.
    state: Option<&'a MovementState>,
    worker: Option<&'a Worker<'scope>>,
    hand_off: HandOff,
    done: &'a mut Collected,
    saver: Saver<'a>,
    bar: &'a ProgressBar,
}

impl Pump<'_, '_> {
    fn run(&mut self, frames: Receiver<Result<Decoded>>) -> Result<()> {
        let mut input = super::priority::Consumer::new("pump");
        while let Ok(item) = input.recv(&frames) {
            match item? {
                Decoded::Prime(i, image) => {
                    if let (Some(m), Some(st)) = (self.moving.as_deref_mut(), self.state) {
                        m.prime(i, self.hand_off.prime(image)?, st)?;
                    }
                }
                Decoded::Frame(f, gray) => {
                    let ready = self.hand_off.frame(f, gray)?;
                    let submitted = !ready.is_empty();
                    for r in ready {
                        self.take(r)?;
                    }
                    // Staged scores can only have landed after a batch went in.
                    if submitted {
                        self.scores(false)?;
                    }
                }
            }
        }
        for r in self.hand_off.end()? {
            self.take(r)?;
        }
        self.scores(true)
    }

    fn take(&mut self, r: Ready) -> Result<()> {
        let i = r.frame.index;
        self.done.push_timestamp(r.frame.timestamp_s);
        if let (Some(m), Some(px)) = (self.moving.as_deref_mut(), r.pixels) {
            m.step(i, px)?;
        }
        if let (Some(e), Some(sink)) = (self.embedding.as_deref_mut(), self.sink.as_deref_mut()) {
            sink.push(&e.frame(&r.frame.image)?)?;
        }
        if let Some(w) = self.worker {
            w.send(r.frame, &mut self.done.scores)?;
        }
        self.done.frames = i + 1;
        self.bar.set_position(self.done.frames as u64);
        let complete = self.moving.as_ref().is_none_or(|m| m.at_stride_point());
        if !(self.saver.due() && complete) {
            return Ok(());
        }
        if let Some(m) = self.moving.as_deref_mut() {
            m.settle()?;
        }
        if let Some(w) = self.worker {
            w.flush(&mut self.done.scores, self.done.frames)?;
        }
        self.scores(true)?;
        if let Some(sink) = self.sink.as_deref_mut() {
            sink.flush()?;
        }
        let movement = self.moving.as_ref().and_then(|m| m.state());
        self.saver.save(self.req, self.backend, self.done, movement)
    }

    /// Takes the staged scores that came back (with `all`, of every frame taken so far).
    fn scores(&mut self, all: bool) -> Result<()> {
        for s in self.hand_off.scores(all)? {
            sharpness::push_scores(&mut self.done.scores, s);
        }
        Ok(())
    }
}

/// The analysis of what `done` and `moving` hold, with the source's problems.
fn conclude(
    src: &dyn FrameSource,
    input: &Path,
    req: &Request,
    done: Collected,
    moving: Option<MovementPass>,
    backend: Backend,
) -> Analysis {
    let mut metadata = src.metadata().clone();
    finish_metadata(&mut metadata, input, &done);
    let (movement, stationary) = match moving {
        Some(m) => (
            Some(MovementSeries {
                width: m.size.0 as u32,
                height: m.size.1 as u32,
                scale_to_full: m.scale,
                values: m.values,
            }),
            m.stationary.map(|s| s.keys().to_vec()),
        ),
        None => (None, None),
    };
    Analysis {
        metadata,
        timestamps_s: done.have_ts.then_some(done.timestamps),
        sharpness: req.sharpness.iter().copied().zip(done.scores).collect(),
        movement,
        stationary,
        // Filled in by `run` from the series file.
        embeddings: None,
        problems: problems_of(src, input),
        damaged: src.damaged_frames().into_iter().map(|(i, _)| i).collect(),
        backend,
    }
}

/// Frame count and timestamps only: frames are grabbed, never converted.
fn scan_only(src: &mut dyn FrameSource, input: &Path, quiet: bool) -> Result<Analysis> {
    let bar = crate::progress::bar(src.metadata().frame_count as u64, "scan", quiet);
    let mut done = Collected::new(0);
    while let Some((_, t)) = src.skip_frame()? {
        done.push_timestamp(t);
        done.frames += 1;
        bar.set_position(done.frames as u64);
    }
    bar.finish_and_clear();
    let req = Request::default();
    Ok(conclude(src, input, &req, done, None, Backend::Opencv))
}

fn finish_metadata(metadata: &mut Metadata, input: &Path, done: &Collected) {
    let count = done.frames;
    if metadata.frame_count != count {
        log::info!(
            "{}: the container declares {} frames, decoding found {count}",
            input.display(),
            metadata.frame_count
        );
        metadata.frame_count = count;
    }
    metadata.frame_count_exact = true;
    if let (true, Some(fps), Some(first), Some(last)) = (
        done.have_ts,
        metadata.fps,
        done.timestamps.first(),
        done.timestamps.last(),
    ) {
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

fn with_path(e: Error, input: &Path) -> Error {
    match e {
        Error::Frame { path, index, msg } if path.as_os_str().is_empty() => {
            Error::frame(input, index, msg)
        }
        other => other,
    }
}
